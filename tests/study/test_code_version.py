"""Every cached artefact records the code that made it (`corelib.version.code_version`); reused by other
code, it is still reused, with one warning line naming it and both versions. Nothing is rendered or trained."""
from __future__ import annotations

import json
from pathlib import Path

from corelib.configlib import config_hash
from corelib.version import code_version
from study.sweep.config import data_config_for, load_sweep_config, overlap_key, run_config_for
from study.sweep.stages import Counters

ROOT = Path(__file__).resolve().parents[2]
CI = ROOT / "configs" / "sweep" / "ci.yaml"
OLD = "0.0.1+src.0123456789ab"


def _warnings(lines: list[str]) -> list[str]:
    return [ln for ln in lines if "warning:" in ln]


def test_code_version_is_the_package_version_and_a_source_digest():
    import mcdp

    v = code_version()
    assert v.startswith(mcdp.__version__ + "+src.") and len(v.rsplit(".", 1)[1]) == 12 and v == code_version()


def test_a_dataset_made_by_other_code_is_reused_with_one_warning(tmp_path, write_dataset):
    from study.sweep.worlds import render_stage

    cfg = load_sweep_config(CI)
    o = cfg.overlaps[0]
    for version, warned in ((OLD, 1), (code_version(), 0), (None, 0)):
        out = tmp_path / str(version) / "data" / overlap_key(o)
        write_dataset(out, config_hash(data_config_for(cfg, o)), o, code_version=version)
        lines: list[str] = []
        counters = Counters()
        rec = render_stage(cfg, o, out.parents[1], counters, lines.append, False)
        assert rec["render_skipped"] and counters == {"render_skipped": 1}
        w = _warnings(lines)
        assert len(w) == warned, lines
        if warned:
            assert str(out) in w[0] and OLD in w[0] and code_version() in w[0]


def test_a_pretraining_made_by_other_code_is_reused_with_one_warning(tmp_path):
    from corelib.hashing import sha256_file
    from study.sweep.pretrain import MARKER, WEIGHTS, load_pretrain_config, resolved_configs, run_pretrain

    cfg = load_pretrain_config(ROOT / "configs" / "pretrain" / "tiny.yaml")
    h = resolved_configs(cfg)[2]
    out = tmp_path / "pre"
    out.mkdir()
    (out / WEIGHTS).write_bytes(b"weights")
    (out / MARKER).write_text(json.dumps({"config_hash": h, "sha256": sha256_file(out / WEIGHTS), "step": 2,
                                          "code_version": OLD}))
    lines: list[str] = []
    rec = run_pretrain(cfg, out, progress=False, log=lines.append)
    assert rec["step"] == 2
    w = _warnings(lines)
    assert len(w) == 1 and str(out) in w[0] and OLD in w[0] and code_version() in w[0]


def test_a_run_trained_by_other_code_is_skipped_with_one_warning(tmp_path):
    from study.sweep.stages import STATUS, _Run, _train, sweep_run_hash

    cfg = load_sweep_config(CI)
    rcfg = run_config_for(cfg, "mono2", 0)[0]
    run_dir = tmp_path / "run"
    for version, warned in ((OLD, 1), (code_version(), 0)):
        status = {"run_config_hash": sweep_run_hash(rcfg, {}), "data_hash": "d" * 64, "trained": True, "steps": 2,
                  "code_version": version}
        lines: list[str] = []
        counters = Counters()
        run = _Run(cfg, 0.2, {"config_hash": "d" * 64}, "mono2", 0, rcfg, sweep_run_hash(rcfg, status), run_dir,
                   status, "[t]", counters, lines.append, False)
        row: dict = {}
        assert _train(run, row) and row["train_skipped"] and counters == {"train_skipped": 1}
        w = _warnings(lines)
        assert len(w) == warned, lines
        if warned:
            assert str(run_dir) in w[0] and OLD in w[0] and code_version() in w[0]
    assert not (run_dir / STATUS).exists()  # a skipped run is not rewritten


def test_a_render_keeps_the_code_that_began_it_through_a_resume(tmp_path):
    from synth.config import load_data_config
    from synth.render import MARKER_DIR, began_with, prepare_output

    dcfg = load_data_config(ROOT / "configs" / "data" / "tiny.yaml")
    out = tmp_path / "d"
    prepare_output(dcfg, out)
    assert began_with(out) == code_version()
    marker = out / MARKER_DIR / "config.json"
    marker.write_text(json.dumps({**json.loads(marker.read_text()), "code_version": OLD}))
    prepare_output(dcfg, out)  # a resume by this code: the record stays the code that began it
    assert began_with(out) == OLD
