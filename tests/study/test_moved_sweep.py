"""Caches keyed on what made the artefact, not on where it lies: a sweep folder copied elsewhere resumes
without rendering, pretraining, training or evaluating anything, and reports the same numbers."""
from __future__ import annotations

import json
import shutil
from pathlib import Path

import pytest

from corelib.configlib import config_hash
from mcdp.runs import run_hash
from study import cli as study_cli
from study.sweep import config as sweep
pytestmark = pytest.mark.slow  # a whole sweep copied and resumed: `pytest -m "not slow"` skips it

ROOT = Path(__file__).resolve().parents[2]
CI = ROOT / "configs" / "sweep" / "ci.yaml"


def test_the_run_hash_of_a_run_in_two_folders_is_equal(tmp_path):
    """model.init_from enters the run hash by the weights' content: the same bytes in two folders give one
    hash (the plain config hash, which holds the path, differs), other bytes another."""
    cfg = sweep.load_sweep_config(CI)
    paths = []
    for name, data in (("a", b"weights"), ("b", b"weights"), ("c", b"other weights")):
        p = tmp_path / name / "pretrain" / "0123456789ab" / "pretrained.pt"
        p.parent.mkdir(parents=True)
        p.write_bytes(data)
        paths.append(str(p))
    a, b, c = (sweep.run_config_for(cfg, "mono2", 0, p)[0] for p in paths)
    assert config_hash(a) != config_hash(b)
    assert run_hash(a) == run_hash(b) != run_hash(c)
    plain = sweep.run_config_for(cfg, "mono2", 0)[0]  # no warm start: the config hash itself
    assert run_hash(plain) == config_hash(plain)


def test_a_copied_sweep_folder_resumes_without_redoing_anything(mini_sweep, tmp_path, capsys):
    src, dst = mini_sweep.out, tmp_path / "there" / "moved"  # the smallest sweep with a pretraining (conftest)
    first = json.loads((src / "results.json").read_text())
    assert first["counters"]["trained"] == 1 and first["pretrain"] is not None
    shutil.copytree(src, dst)
    capsys.readouterr()
    assert study_cli.main(["sweep", str(CI), "--out", str(dst), *mini_sweep.args]) == 0
    err = capsys.readouterr().err
    assert f"[pretrain] {dst / 'pretrain'}" in err and "reused" in err and "warning:" not in err  # same code
    res = json.loads((dst / "results.json").read_text())
    c = res["counters"]
    assert (c["rendered"], c["trained"], c["evaluated"], c["reference_evaluated"]) == (0, 0, 0, 0)
    assert (c["render_skipped"], c["train_skipped"], c["eval_skipped"], c["reference_skipped"]) == (1, 1, 1, 1)
    assert res["pretrain"]["sha256"] == first["pretrain"]["sha256"]
    assert res["pretrain"]["train_s"] == first["pretrain"]["train_s"]  # the recorded pretraining, not a new one
    assert res["pretrain"]["weights"].startswith(str(dst))  # the copy's own pretraining, not the original's
    assert [r["run_config_hash"] for r in res["rows"]] == [r["run_config_hash"] for r in first["rows"]]
    assert json.dumps([r["evaluations"] for r in res["rows"]], sort_keys=True) == \
        json.dumps([r["evaluations"] for r in first["rows"]], sort_keys=True)
    for key in ("measured", "reference", "prior", "config_hash"):
        assert [d[key] for d in res["data"]] == [d[key] for d in first["data"]], key


def test_a_run_recorded_under_the_path_hash_of_its_day_keeps_it(tmp_path):
    """A run whose sweep_status.json holds the earlier key (config_hash, with init_from's path) is reused
    under that key where it lies; any other status gets the path-free key."""
    from study.sweep.stages import sweep_run_hash

    w = tmp_path / "pretrained.pt"
    w.write_bytes(b"weights")
    rcfg = sweep.run_config_for(sweep.load_sweep_config(CI), "mono2", 0, str(w))[0]
    assert sweep_run_hash(rcfg, {"run_config_hash": config_hash(rcfg)}) == config_hash(rcfg)
    assert sweep_run_hash(rcfg, {}) == sweep_run_hash(rcfg, {"run_config_hash": "other"}) == run_hash(rcfg)
