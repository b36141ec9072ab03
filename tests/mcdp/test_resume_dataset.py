"""Hardening, round four (issue 41), item 9: resuming ``mcdp train`` on another dataset (even another rig) was
silent and run.json lost the dataset the run was trained on. Now one warning line names both (and how the
rig differs), and run.json's ``datasets`` keeps every dataset with the step it started at."""
from __future__ import annotations

import json
import shutil
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
MONO2 = str(ROOT / "configs" / "train" / "tiny" / "mono2.yaml")


def test_resuming_on_another_dataset_and_rig_warns_and_run_json_records_both(tiny_dataset, tmp_path, capsys):
    from study.method_commands import main

    other = tmp_path / "other"
    shutil.copytree(tiny_dataset, other)
    rig = json.loads((other / "rig.json").read_text())
    rig["cameras"][0]["K"][0][0] *= 1.5  # another lens on CAM_FRONT
    (other / "rig.json").write_text(json.dumps(rig))
    run = tmp_path / "run"
    common = ["--out", str(run), "--no-progress", "train.val_every=100"]
    assert main(["train", MONO2, "--data", str(tiny_dataset), *common, "train.steps=1"]) == 0
    capsys.readouterr()
    assert main(["train", MONO2, "--data", str(other), *common, "train.steps=2"]) == 0
    err = capsys.readouterr().err
    warn = [line for line in err.splitlines() if "warning: resuming" in line]
    assert len(warn) == 1, err
    assert f"on {other.resolve()}, not on {tiny_dataset.resolve()}" in warn[0] and "CAM_FRONT K" in warn[0], warn
    rec = json.loads((run / "run.json").read_text())
    assert rec["datasets"] == [{"data": str(tiny_dataset.resolve()), "from_step": 0},
                               {"data": str(other.resolve()), "from_step": 1}]
    assert rec["data"] == str(other.resolve())


def test_resuming_on_the_same_dataset_says_nothing_and_keeps_one_entry(tiny_dataset, tmp_path, capsys):
    from study.method_commands import main

    run = tmp_path / "run"
    common = ["--data", str(tiny_dataset), "--out", str(run), "--no-progress", "train.val_every=100"]
    assert main(["train", MONO2, *common, "train.steps=1"]) == 0
    assert main(["train", MONO2, *common, "train.steps=2"]) == 0
    assert "warning: resuming" not in capsys.readouterr().err
    assert json.loads((run / "run.json").read_text())["datasets"] == [{"data": str(tiny_dataset.resolve()),
                                                                       "from_step": 0}]
