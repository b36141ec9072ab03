"""The `mcdp` CLI in-process: train / eval / predict end to end, every tiny preset, and user errors (exit 2)."""
from __future__ import annotations

import json
import shutil
from pathlib import Path

import numpy as np
import pytest

import mcdp.trainer  # noqa: F401  torch/torchvision (and triton's LLVM) must load before the in-process
#                              GL renderer of the tiny_dataset fixture, whose llvmpipe LLVM otherwise clashes
#                              with triton's (segfault in `import torch.fx` inside torchvision.ops)
from study.method_commands import main

ROOT = Path(__file__).resolve().parents[2]
TINY = ROOT / "configs" / "train" / "tiny"
FULL = ROOT / "configs" / "train"
PRESETS = ["mono2", "mcdp_m0", "mcdp_m1_nocon", "mcdp_m1", "mcdp_m2"]


@pytest.fixture(scope="module")
def trained_run(tiny_dataset, tmp_path_factory):
    """A tiny mcdp_m1 run (2 steps) shared by the eval/predict tests."""
    run = tmp_path_factory.mktemp("cli") / "run"
    rc = main(["train", str(TINY / "mcdp_m1.yaml"), "--data", str(tiny_dataset), "--out", str(run), "--no-progress",
               "train.steps=2"])
    assert rc == 0
    return run


# --------------------------------------------------------------------------- presets
@pytest.mark.parametrize("preset", PRESETS)
def test_every_full_preset_has_the_required_keys(preset):
    from mcdp.config import RunConfig
    from corelib.configlib import load_config

    cfg = load_config(RunConfig, FULL / f"{preset}.yaml")
    tiny = load_config(RunConfig, TINY / f"{preset}.yaml")
    for c in (cfg, tiny):
        assert c.model.method == ("mono2" if preset == "mono2" else "mcdp")
        assert c.model.refine_steps == {"mono2": 0, "mcdp_m0": 0, "mcdp_m1_nocon": 1, "mcdp_m1": 1, "mcdp_m2": 2}[preset]
        assert (c.loss.consistency_weight > 0) == (preset not in ("mono2", "mcdp_m1_nocon"))
        assert c.model.neighbours == "both" and c.scale.source == "velocity"
    assert cfg.model.bases == 32 and cfg.train.lr == 1e-4 and (cfg.train.height, cfg.train.width) == (192, 320)


@pytest.mark.parametrize("preset", PRESETS)
def test_every_tiny_preset_trains_two_steps(preset, tiny_dataset, tmp_path, request):
    if preset == "mcdp_m1":  # trained_run is this very command (its exit status asserted there): not run twice
        run = request.getfixturevalue("trained_run")
    else:
        run = tmp_path / preset
        rc = main(["train", str(TINY / f"{preset}.yaml"), "--data", str(tiny_dataset), "--out", str(run),
                   "--no-progress", "train.steps=2"])
        assert rc == 0
    assert (run / "checkpoints" / "last.pt").is_file() and (run / "config.yaml").is_file()


# --------------------------------------------------------------------------- end to end
def test_eval_writes_metrics_for_every_stage_and_prints_tables(trained_run, tiny_dataset, tmp_path, capsys):
    out = tmp_path / "metrics.json"
    rc = main(["eval", str(trained_run), "--data", str(tiny_dataset), "--out", str(out), "--no-progress"])
    assert rc == 0
    m = json.loads(out.read_text())
    assert list(m["stages"]) == ["init", "refine1", "final"]
    st = m["stages"]["final"]
    for sc in ("none", "median", "rig_median"):
        for region in ("mean", "per_camera", "overlap", "non_overlap"):
            assert region in st[sc]
        assert np.isfinite(st[sc]["mean"]["abs_rel"])
    assert "per_pair" in st["dep_con"] and "mean" in st["dep_con"]
    assert m["run"]["oracle"] is False and m["run"]["scale_source"] == "velocity"
    assert m["split"] == "test"
    printed = capsys.readouterr().out
    assert "CAM_FRONT_LEFT" in printed and "scaling: rig_median" in printed


def test_eval_defaults_to_run_folder_and_val_split(trained_run, tiny_dataset):
    rc = main(["eval", str(trained_run), "--data", str(tiny_dataset), "--split", "val", "--no-progress",
               "eval.max_depth=60.0"])
    assert rc == 0
    m = json.loads((trained_run / "metrics_val.json").read_text())
    assert m["split"] == "val" and m["max_depth"] == 60.0


def test_predict_writes_grids_exr_and_ply(trained_run, tiny_dataset, tmp_path):
    from synth.open import open_dataset
    from synth.files import read_depth_exr

    out = tmp_path / "pred"
    rc = main(["predict", str(trained_run), "--data", str(tiny_dataset), "--out", str(out), "--max-samples", "2",
               "--ply"])
    assert rc == 0
    ds = open_dataset(tiny_dataset)
    seq = ds.split("test")[0]
    grid = out / seq / "000000_grid.png"
    assert grid.is_file()
    import cv2

    img = cv2.imread(str(grid))
    assert img.shape == (3 * ds.height, 6 * ds.width, 3)  # RGB row + init + refine1
    d = read_depth_exr(out / seq / "CAM_FRONT" / "000001.depth.exr")
    assert d.shape == (ds.height, ds.width) and d.dtype == np.float32 and float(d.min()) > 0
    ply = (out / seq / "000000.ply").read_bytes()
    assert ply.startswith(b"ply\nformat binary_little_endian 1.0\nelement vertex ")
    n = int(ply.split(b"element vertex ")[1].split(b"\n")[0])
    assert n > 1000 and ply.endswith(ply[-15:]) and len(ply.split(b"end_header\n", 1)[1]) == n * 15


def test_oracle_runs_are_labelled(tiny_dataset, tmp_path, capsys):
    run = tmp_path / "oracle"
    assert main(["train", str(TINY / "mono2.yaml"), "--data", str(tiny_dataset), "--out", str(run), "--no-progress",
                 "train.steps=1", "scale.source=oracle_gt_median"]) == 0
    assert "ORACLE" in capsys.readouterr().err
    out = tmp_path / "m.json"
    assert main(["eval", str(run), "--data", str(tiny_dataset), "--out", str(out), "--no-progress"]) == 0
    cap = capsys.readouterr()
    assert "ORACLE" in cap.out and "ORACLE" in cap.err
    m = json.loads(out.read_text())
    assert m["run"]["oracle"] is True and m["run"]["scale_source"] == "oracle_gt_median"


# --------------------------------------------------------------------------- user errors -> exit 2, no traceback
def _err(capsys, argv) -> str:
    rc = main(argv)
    cap = capsys.readouterr()
    assert rc == 2, cap.err
    assert "Traceback" not in cap.err
    return cap.err


def test_missing_dataset_is_a_clear_error(tmp_path, capsys):
    err = _err(capsys, ["train", str(TINY / "mono2.yaml"), "--data", str(tmp_path / "nope"), "--out",
                        str(tmp_path / "run")])
    assert "nope" in err and "does not exist" in err


def test_dataset_of_another_schema_version_is_refused(tiny_dataset, tmp_path, capsys):
    data = tmp_path / "old"
    shutil.copytree(tiny_dataset, data)
    man = json.loads((data / "manifest.json").read_text())
    man["schema_version"] = 99
    (data / "manifest.json").write_text(json.dumps(man))
    err = _err(capsys, ["train", str(TINY / "mono2.yaml"), "--data", str(data), "--out", str(tmp_path / "run")])
    assert "schema_version 99" in err and "manifest.json" in err


def test_bad_override_and_missing_preset_name_the_problem(tiny_dataset, tmp_path, capsys):
    err = _err(capsys, ["train", str(TINY / "mono2.yaml"), "--data", str(tiny_dataset), "--out", str(tmp_path / "r"),
                        "model.basez=3"])
    assert "model.basez" in err and "unknown key" in err
    err = _err(capsys, ["train", str(TINY / "mono2.yaml"), "--data", str(tiny_dataset), "--out", str(tmp_path / "r"),
                        "train.height=50"])
    assert "multiple of 32" in err
    err = _err(capsys, ["train", str(tmp_path / "nope.yaml"), "--data", str(tiny_dataset), "--out", str(tmp_path / "r")])
    assert "nope.yaml does not exist" in err


def test_conflicting_resume_names_the_keys(trained_run, tiny_dataset, capsys):
    err = _err(capsys, ["train", str(TINY / "mcdp_m1.yaml"), "--data", str(tiny_dataset), "--out", str(trained_run),
                        "train.steps=3", "model.refine_steps=2"])
    assert "model.refine_steps: checkpoint has 1, requested 2" in err


def test_eval_without_depth_or_run_is_a_clear_error(trained_run, tiny_dataset, tmp_path, capsys):
    data = tmp_path / "nodepth"
    shutil.copytree(tiny_dataset, data)
    for p in data.rglob("*.depth.exr"):
        p.unlink()
    err = _err(capsys, ["eval", str(trained_run), "--data", str(data), "--no-progress"])
    assert "no ground-truth depth" in err
    err = _err(capsys, ["eval", str(tmp_path / "norun"), "--data", str(tiny_dataset)])
    assert "norun" in err and "does not exist" in err


def test_usage_errors_return_2(capsys):
    assert main([]) == 2
    assert main(["train"]) == 2
    assert main(["frobnicate"]) == 2
