"""The pre-stated analysis as validated preset keys (issue 60, item 1): the primary arms, metric, scaling, region
and overlap, `plan.delta`, the stopping rule and the tuning/test split in every committed sweep preset whose
results are a page, refused in one line naming the key when inconsistent, saved with
the run, and read by the report from the recorded config (`study.report.sections.primary.plan_of`)."""
from __future__ import annotations

from pathlib import Path

import pytest

import yaml

from corelib.configlib import ConfigError, config_to_dict
from study.sweep.config import load_sweep_config
from study.report.sections.primary import plan_of
from study.results.files import read_results

ROOT = Path(__file__).resolve().parents[2]
#: presets without a plan: the smoke sweep (no primary comparison; tests run it at other overlaps and methods) and
#: the calibration sweep (its own issue; its arms are anchors, not methods)
NO_PLAN = {"ci.yaml", "cpu_calibration.yaml", "smoke.yaml"}
#: every key a committed preset states in its plan block (``worlds`` / ``first_look`` / ``why``: with two looks)
PLAN_KEYS = {"arms", "metric", "scaling", "region", "overlap", "delta", "stopping", "tuning_worlds"}


def test_every_page_preset_states_its_plan_and_it_is_saved_with_the_run():
    presets = sorted(p for p in (ROOT / "configs" / "sweep").glob("*.yaml") if p.name not in NO_PLAN)
    assert len(presets) >= 11
    for p in presets:
        cfg = load_sweep_config(str(p), [])
        assert cfg.plan is not None, p.name
        assert any(abs(cfg.plan.overlap - o) < 1e-9 for o in cfg.overlaps), p.name
        saved = config_to_dict(cfg)["plan"]
        assert saved["overlap"] == cfg.plan.overlap and saved["delta"] == cfg.plan.delta, p.name
        stated = yaml.safe_load(p.read_text())["plan"]
        assert PLAN_KEYS <= set(stated), f"{p.name}: plan lacks {sorted(PLAN_KEYS - set(stated))}"
        assert {k: saved[k] for k in PLAN_KEYS} == {k: getattr(cfg.plan, k) for k in PLAN_KEYS}, p.name
        assert all(a in cfg.methods for a in cfg.plan.arms or []), p.name
    assert load_sweep_config("configs/sweep/cpu_sensor.yaml", []).plan.overlap == 0.30


@pytest.mark.parametrize("overrides, key", [
    (["plan.overlap=0.30"], "plan.overlap"), (["plan.delta=-1"], "delta"), (["plan.first_look=20"], "plan.first_look"),
    (["plan.typo=1"], "typo"), (["methods=[mcdp_m2]"], "plan.arms"), (["plan.arms=[mono2,mcdp_m2]"], "plan.arms"),
    (["plan.arms=[mcdp_m2,mcdp_m2]"], "plan.arms"), (["plan.metric=abs_rell"], "plan.metric"),
    (["plan.region=sky"], "region"), (["plan.scaling=mean"], "scaling"), (["plan.stopping=one_look"], "plan.stopping"),
    (["plan.tuning_worlds=[3,3]"], "plan.tuning_worlds")])
def test_an_inconsistent_plan_is_refused_in_one_line_naming_the_key(overrides, key):
    with pytest.raises(ConfigError) as err:
        load_sweep_config("configs/sweep/cpu_lcon.yaml", overrides)
    msg = str(err.value)
    assert key in msg, msg
    if key.startswith("plan."):  # our own checks: one line under the header that names the file and overrides
        assert msg.startswith("invalid config (") and len(msg.splitlines()) == 2 and key in msg.splitlines()[1], msg


def test_the_sensor_plan_names_its_arms_and_all_pixels_and_an_old_run_reads_the_pages_defaults():
    from study.report.sections import sensor
    from study.report.sections.primary import primary_key

    cfg = load_sweep_config("configs/sweep/cpu_sensor.yaml", [])
    assert cfg.plan.arms == ["fsm", "mcdp_m2"] and cfg.plan.region == "all"
    old = read_results(ROOT / "docs/results/sensor14_ideal/results.json")  # recorded {overlap: 0.3} only
    got = sensor.plan(old)
    assert got["arms"] == list(sensor.CONTRAST) and got["region"] == "all" and primary_key(got) == sensor.FIGURES[0][0]
    assert plan_of(old)["region"] == "non_overlap"  # the key's own default, for a page without defaults
    stated = {"sweep_config": {"plan": {"arms": ["mono2", "mcdp_m2"], "region": "non_overlap"}},
              "overlaps": [0.3], "methods": ["mono2", "mcdp_m2"]}
    assert sensor.contrast_arms(stated) == ("mono2", "mcdp_m2")
    assert sensor.figures(stated)[0] == ("median.non_overlap.abs_rel", "abs_rel (median)")


def test_the_report_reads_the_recorded_plan_and_defaults_for_sweeps_recorded_before_it():
    """The committed results recorded no plan.overlap / delta: they read as the values they were analysed with
    (overlap 0.10, or the one overlap a sweep without 0.10 ran: the sensor sweeps' 0.30; delta 0.005), the same
    values their presets now state, so every page rebuilds byte for byte (tests/test_results_docs.py)."""
    lcon = read_results(ROOT / "docs/results/lcon_main/results.json")
    assert plan_of(lcon)["overlap"] == 0.10 and plan_of(lcon)["delta"] == 0.005 and plan_of(lcon)["worlds"] == 14
    assert plan_of(lcon)["stopping"] == "obrien_fleming" and plan_of(lcon)["arms"] is None  # read as lcon_arms
    sensor = read_results(ROOT / "docs/results/sensor_ideal/results.json")
    assert plan_of(sensor)["overlap"] == 0.30
    stated = {"sweep_config": {"plan": {"overlap": 0.30, "delta": 0.01}}, "overlaps": [0.10, 0.30]}
    assert plan_of(stated)["overlap"] == 0.30 and plan_of(stated)["delta"] == 0.01
    for name, preset in (("lcon_main", "cpu_lcon"), ("propagation", "cpu_propagation"), ("sensor_ideal", "cpu_sensor")):
        cfg = load_sweep_config(f"configs/sweep/{preset}.yaml", [])
        got = plan_of(read_results(ROOT / f"docs/results/{name}/results.json"))
        assert (got["overlap"], got["delta"]) == (cfg.plan.overlap, cfg.plan.delta), name
