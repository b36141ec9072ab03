"""Hardening, round four (issue 41), item 7: an empty split is said, never met silently.

``synth render`` with fewer than 3 sequences warns in one line that val / test will be empty; ``mcdp train``
says there is no val split (it reported "best val loss inf"); ``mcdp eval`` (a 20-line traceback) and ``mcdp
predict`` (0 files, exit 0) refuse an empty split in one line, exit 2, before a model is loaded.
"""
from __future__ import annotations

import json
import shutil
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
MONO2 = ROOT / "configs" / "train" / "tiny" / "mono2.yaml"


def _without(tiny_dataset, tmp_path, split: str) -> Path:
    """A copy of the tiny dataset whose `split` is empty (its sequence moved to train), as a 2-sequence render's."""
    d = tmp_path / "data"
    shutil.copytree(tiny_dataset, d)
    m = json.loads((d / "manifest.json").read_text())
    m["splits"]["train"] = sorted(m["splits"]["train"] + m["splits"][split])
    m["splits"][split] = []
    (d / "manifest.json").write_text(json.dumps(m))
    return d


def test_render_with_two_sequences_warns_that_val_and_test_are_empty(tmp_path, capsys):
    from synth.cli import main

    out = tmp_path / "d"
    assert main(["render", str(ROOT / "configs/data/tiny.yaml"), "--out", str(out), "--no-progress",
                 "dataset.sequences=2", "dataset.frames=3"]) == 0
    err = capsys.readouterr().err
    lines = [line for line in err.splitlines() if "warning" in line]
    assert len(lines) == 1 and "leave the val and test split(s) empty" in lines[0], err
    assert json.loads((out / "manifest.json").read_text())["splits"]["val"] == []


def test_three_sequences_fill_every_split_without_a_warning(tiny_config):
    from synth.config import empty_split_warning
    from synth.render import assign_splits

    assert tiny_config.dataset.sequences == 3
    assert empty_split_warning(assign_splits(tiny_config), 3) is None
    one = tiny_config.model_copy(update={"dataset": tiny_config.dataset.model_copy(update={"sequences": 1})})
    assert "val and test" in empty_split_warning(assign_splits(one), 1)


def test_train_without_a_val_split_says_so_instead_of_best_val_loss_inf(tiny_dataset, tmp_path, capsys):
    from study.method_commands import main

    d = _without(tiny_dataset, tmp_path, "val")
    run = tmp_path / "run"
    assert main(["train", str(MONO2), "--data", str(d), "--out", str(run), "--no-progress", "train.steps=2",
                 "train.val_every=1"]) == 0
    err = capsys.readouterr().err
    assert "inf" not in err, err
    warn = [line for line in err.splitlines() if "warning" in line and "val" in line]
    assert len(warn) == 1 and f"{d} has no val rig sample" in warn[0], err
    assert "no val split, no best.pt" in err.splitlines()[-1], err
    assert (run / "checkpoints" / "last.pt").is_file() and not (run / "checkpoints" / "best.pt").exists()


@pytest.mark.parametrize("command", ["eval", "predict"])
def test_eval_and_predict_refuse_an_empty_split_in_one_line_before_loading_a_model(tiny_dataset, tmp_path, capsys,
                                                                                   monkeypatch, command):
    import mcdp.predict
    from study.method_commands import main

    d = _without(tiny_dataset, tmp_path, "test")
    monkeypatch.setattr(mcdp.predict, "Predictor", lambda *a, **k: pytest.fail("a model was loaded"))
    out = tmp_path / ("m.json" if command == "eval" else "pred")
    capsys.readouterr()
    assert main([command, str(tmp_path / "norun"), "--data", str(d), "--out", str(out)]) == 2
    err = capsys.readouterr().err.strip()
    assert err.splitlines() == [f"mcdp {command}: error: dataset {d}: split 'test' has no sequence, nothing to do "
                                "(render more dataset.sequences, or use --split train / val)"], err
    assert not out.exists()
