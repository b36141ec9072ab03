"""The pre-stated analysis as validated preset keys (issue 60, item 1): `plan.overlap` and `plan.delta` in every
committed sweep preset whose results are a page, refused in one line naming the key when inconsistent, saved with
the run, and read by the report from the recorded config (`study.primary.plan_of`)."""
from __future__ import annotations

from pathlib import Path

import pytest

from corelib.configlib import ConfigError, config_to_dict
from study.config import load_sweep_config
from study.primary import plan_of
from study.results_files import read_results

ROOT = Path(__file__).resolve().parents[2]
#: presets without a plan: the smoke sweep (no primary comparison) and the calibration sweep (its own issue)
NO_PLAN = {"ci.yaml", "cpu_calibration.yaml", "smoke.yaml"}


def test_every_page_preset_states_its_plan_and_it_is_saved_with_the_run():
    presets = sorted(p for p in (ROOT / "configs" / "sweep").glob("*.yaml") if p.name not in NO_PLAN)
    assert len(presets) >= 11
    for p in presets:
        cfg = load_sweep_config(str(p), [])
        assert cfg.plan is not None, p.name
        assert any(abs(cfg.plan.overlap - o) < 1e-9 for o in cfg.overlaps), p.name
        saved = config_to_dict(cfg)["plan"]
        assert saved["overlap"] == cfg.plan.overlap and saved["delta"] == cfg.plan.delta, p.name
    assert load_sweep_config("configs/sweep/cpu_sensor.yaml", []).plan.overlap == 0.30


@pytest.mark.parametrize("override, key", [("plan.overlap=0.30", "plan.overlap"), ("plan.delta=-1", "delta"),
                                           ("plan.first_look=20", "plan.first_look"), ("plan.typo=1", "typo")])
def test_an_inconsistent_plan_is_refused_naming_the_key(override, key):
    with pytest.raises(ConfigError) as err:
        load_sweep_config("configs/sweep/cpu_lcon.yaml", [override])
    assert key in str(err.value)


def test_the_report_reads_the_recorded_plan_and_defaults_for_sweeps_recorded_before_it():
    """The committed results recorded no plan.overlap / delta: they read as the values they were analysed with
    (overlap 0.10, or the one overlap a sweep without 0.10 ran: the sensor sweeps' 0.30; delta 0.005), the same
    values their presets now state, so every page rebuilds byte for byte (tests/test_results_docs.py)."""
    lcon = read_results(ROOT / "docs/results/lcon_main/results.json")
    assert plan_of(lcon)["overlap"] == 0.10 and plan_of(lcon)["delta"] == 0.005 and plan_of(lcon)["worlds"] == 14
    sensor = read_results(ROOT / "docs/results/sensor_ideal/results.json")
    assert plan_of(sensor)["overlap"] == 0.30
    stated = {"sweep_config": {"plan": {"overlap": 0.30, "delta": 0.01}}, "overlaps": [0.10, 0.30]}
    assert plan_of(stated)["overlap"] == 0.30 and plan_of(stated)["delta"] == 0.01
    for name, preset in (("lcon_main", "cpu_lcon"), ("propagation", "cpu_propagation"), ("sensor_ideal", "cpu_sensor")):
        cfg = load_sweep_config(f"configs/sweep/{preset}.yaml", [])
        got = plan_of(read_results(ROOT / f"docs/results/{name}/results.json"))
        assert (got["overlap"], got["delta"]) == (cfg.plan.overlap, cfg.plan.delta), name
