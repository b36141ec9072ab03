"""Untrusted input (issue: hardening): what a user hands the tools cannot run code, escape a root or
flood the terminal; divergence stops training and keeps only finite checkpoints.

Covered here: manifest names and symlinks, YAML aliases and oversized configs, NaN gradients and
validation losses, a lr = 1 run (the largest train.lr accepted). The pickle checkpoint probe is in tests/mcdp/test_trainer.py.
"""
from __future__ import annotations

import json
import math
import shutil
from pathlib import Path

import pytest
import torch

ROOT = Path(__file__).resolve().parents[1]
TINY_TRAIN = ROOT / "configs" / "train" / "tiny"


def _copy(tiny_dataset, tmp_path) -> Path:
    d = tmp_path / "data"
    shutil.copytree(tiny_dataset, d)
    return d


def _edit_manifest(d: Path, fn) -> None:
    m = json.loads((d / "manifest.json").read_text())
    fn(m)
    (d / "manifest.json").write_text(json.dumps(m))


def _rename_seq(m, new):
    old = m["splits"]["test"][0]
    m["sequences"][new] = m["sequences"].pop(old)
    m["splits"]["test"] = [new]


# --------------------------------------------------------------------------- manifests
@pytest.mark.parametrize("edit, field", [
    (lambda m: _rename_seq(m, "../outside/x"), "sequence name"),
    (lambda m: _rename_seq(m, "/etc"), "sequence name"),
    (lambda m: m["splits"].update(test=["seq_99999"]), "splits.test"),
    (lambda m: m["cameras"].__setitem__(0, "../CAM"), "camera name"),
    (lambda m: m["files"].update({"../../evil.png": "0" * 64}), "files entry"),
])
def test_a_manifest_name_that_is_not_plain_is_refused_naming_the_field(tree_hash, tiny_dataset, tmp_path, capsys, edit, field):
    from synth.cli import main as synth_main
    from synth.open import open_dataset
    from synth.files import DatasetError

    d = _copy(tiny_dataset, tmp_path)
    _edit_manifest(d, edit)
    with pytest.raises(DatasetError, match=field):
        open_dataset(d)
    before = tree_hash(tmp_path)
    capsys.readouterr()
    assert synth_main(["verify", str(d)]) != 0
    out = capsys.readouterr()
    text = out.out + out.err
    assert field in text and len(text.splitlines()) <= 5
    assert tree_hash(tmp_path) == before


def test_mcdp_predict_refuses_a_manifest_whose_sequence_leaves_the_root(tiny_dataset, tmp_path, capsys, mono2_run):
    from study.method_commands import main

    d = _copy(tiny_dataset, tmp_path)
    _edit_manifest(d, lambda m: _rename_seq(m, "../outside/x"))
    run = mono2_run  # a run trained on the clean copy
    capsys.readouterr()
    assert main(["predict", str(run), "--data", str(d), "--out", str(tmp_path / "pred")]) == 2
    assert "sequence name" in capsys.readouterr().err
    assert not (tmp_path / "outside").exists()


def test_a_sequence_folder_symlinked_outside_the_root_is_refused(tiny_dataset, tmp_path):
    from synth.open import open_dataset
    from synth.files import DatasetError

    d = _copy(tiny_dataset, tmp_path / "in")
    seq = json.loads((d / "manifest.json").read_text())["splits"]["test"][0]
    outside = tmp_path / "elsewhere"
    shutil.move(str(d / seq), outside)
    (d / seq).symlink_to(outside, target_is_directory=True)
    with pytest.raises(DatasetError, match="outside the dataset root"):
        open_dataset(d)


# --------------------------------------------------------------------------- configs
def test_a_yaml_alias_bomb_is_refused_in_a_few_lines(tmp_path, capsys):
    from study.method_commands import main

    bomb = ["a: &a [x, x, x, x, x, x, x, x, x, x]"]
    for i in range(1, 9):
        bomb.append(f"{chr(97 + i)}: &{chr(97 + i)} [" + ", ".join([f"*{chr(96 + i)}"] * 10) + "]")
    bomb.append("model: {method: mono2}")
    cfg = tmp_path / "bomb.yaml"
    cfg.write_text("\n".join(bomb) + "\n")
    assert main(["train", str(cfg), "--data", str(tmp_path), "--out", str(tmp_path / "run")]) == 2
    err = capsys.readouterr().err
    assert "aliases" in err and str(cfg) in err and len(err) < 600 and len(err.splitlines()) <= 3
    assert not (tmp_path / "run").exists()


def test_an_oversized_config_is_refused_before_it_is_parsed(tmp_path, capsys):
    from study.method_commands import main

    big = tmp_path / "big.yaml"
    big.write_text("model: {method: mono2}\n" + "# " + "x" * (2 << 20) + "\n")
    assert main(["train", str(big), "--data", str(tmp_path), "--out", str(tmp_path / "run")]) == 2
    err = capsys.readouterr().err
    assert "bytes" in err and str(big) in err and len(err) < 400


def test_a_long_bad_override_gives_a_bounded_message(capsys):
    from study.method_commands import main

    assert main(["train", str(TINY_TRAIN / "mono2.yaml"), "--data", "x", "--out", "y", "train.lr=[" + "1," * 5000]) == 2
    assert len(capsys.readouterr().err) < 800


# --------------------------------------------------------------------------- divergence
def test_lr_1_stops_naming_the_step_and_keeps_only_finite_checkpoints(tiny_dataset, tmp_path, capsys):
    from study.method_commands import main
    from mcdp.runs import load_checkpoint

    run = tmp_path / "run"
    code = main(["train", str(TINY_TRAIN / "mono2.yaml"), "--data", str(tiny_dataset), "--out", str(run),
                 "--no-progress", "train.lr=1.0", "train.steps=30", "train.ckpt_every=1", "train.val_every=1"])
    err = capsys.readouterr().err
    assert code == 3 and "at step" in err, err
    for name in ("last.pt", "best.pt"):
        p = run / "checkpoints" / name
        if p.exists():
            sd = load_checkpoint(p)["depth_model"]
            assert all(torch.isfinite(v).all() for v in sd.values() if v.is_floating_point()), name


def test_a_non_finite_gradient_stops_before_the_weights_change(tiny_dataset, tmp_path):
    from mcdp.config import RunConfig
    from mcdp.trainer import Trainer, TrainingDiverged
    from corelib.configlib import load_config
    from synth.open import open_dataset

    cfg = load_config(RunConfig, TINY_TRAIN / "mono2.yaml", ["train.steps=3"])
    tr = Trainer(cfg, open_dataset(tiny_dataset), tmp_path / "run", progress=False, tensorboard=False)
    try:
        p = tr.depth.decoder.dispconv[0].weight
        before = p.detach().clone()
        p.register_hook(lambda g: g * float("nan"))
        with pytest.raises(TrainingDiverged, match=r"gradient of .*dispconv\.0\.weight is not finite at step 0"):
            tr.train()
        assert torch.equal(p.detach(), before)
    finally:
        tr.close()


def test_a_nan_validation_loss_stops_training(tiny_dataset, tmp_path, monkeypatch):
    from mcdp.config import RunConfig
    from mcdp.trainer import Trainer, TrainingDiverged
    from corelib.configlib import load_config
    from synth.open import open_dataset

    cfg = load_config(RunConfig, TINY_TRAIN / "mono2.yaml", ["train.steps=4", "train.val_every=2"])
    tr = Trainer(cfg, open_dataset(tiny_dataset), tmp_path / "run", progress=False, tensorboard=False)
    monkeypatch.setattr(tr, "validate", lambda: math.nan)
    try:
        with pytest.raises(TrainingDiverged, match="validation loss is nan at step 2"):
            tr.train()
        assert not (tmp_path / "run" / "checkpoints" / "best.pt").exists()
    finally:
        tr.close()


# --------------------------------------------------------------------------- output folders
def test_train_refuses_a_folder_of_the_users_own_files(tree_hash, tiny_dataset, tmp_path, capsys):
    from study.method_commands import main

    mine = tmp_path / "mine"
    mine.mkdir()
    (mine / "config.yaml").write_text("my: own\n")
    before = tree_hash(mine)
    assert main(["train", str(TINY_TRAIN / "mono2.yaml"), "--data", str(tiny_dataset), "--out", str(mine),
                 "--no-progress", "train.steps=1"]) == 2
    err = capsys.readouterr().err
    assert "not empty and is not an mcdp run folder" in err and "config.yaml" in err
    assert tree_hash(mine) == before


@pytest.mark.parametrize("command", ["predict", "sweep"])
def test_predict_and_sweep_refuse_a_folder_of_the_users_own_files(tree_hash, tiny_dataset, tmp_path, capsys, command,
                                                                  request):
    from study.cli import main  # the `mcdp` console script: mcdp's commands + the study's sweep

    mine = tmp_path / "mine"
    mine.mkdir()
    (mine / "notes.txt").write_text("mine")
    before = tree_hash(mine)
    if command == "predict":
        run = request.getfixturevalue("mono2_run")  # trained once, copied here (conftest)
        args = ["predict", str(run), "--data", str(tiny_dataset), "--out", str(mine)]
    else:
        args = ["sweep", str(ROOT / "configs/sweep/ci.yaml"), "--out", str(mine), "--no-progress"]
    capsys.readouterr()
    assert main(args) == 2
    assert "not empty and is not an mcdp" in capsys.readouterr().err
    assert tree_hash(mine) == before


def test_a_second_writer_of_the_same_folder_is_refused_naming_the_pid(tiny_dataset, tmp_path):
    import os

    from mcdp.config import RunConfig
    from corelib.rundir import FolderError
    from mcdp.trainer import Trainer
    from corelib.configlib import load_config
    from synth.open import open_dataset

    ds = open_dataset(tiny_dataset)
    cfg = load_config(RunConfig, TINY_TRAIN / "mono2.yaml", ["train.steps=1"])
    first = Trainer(cfg, ds, tmp_path / "run", progress=False, tensorboard=False)
    try:
        with pytest.raises(FolderError, match=f"another process \\(pid {os.getpid()}\\)"):
            Trainer(cfg, ds, tmp_path / "run", progress=False, tensorboard=False)
    finally:
        first.close()
    again = Trainer(cfg, ds, tmp_path / "run", progress=False, tensorboard=False)  # released: fine now
    again.close()
