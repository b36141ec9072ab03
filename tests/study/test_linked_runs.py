"""A run reached through a symbolic link is read only (issue 49, item 1): a sweep's rerun with keep_best: false
deleted the best.pt of another sweep's run linked into it (``runs/``, ``runs/overlap_0.50/`` or the run's folder a
link) and rewrote that run's removed.json and sweep_status.json, since O_NOFOLLOW guarded ``checkpoints/`` only.

No training here: the run's records are written as a trained and evaluated run leaves them, and the stages that
train and evaluate are replaced by their skip paths (which read, never write)."""
from __future__ import annotations

import json
import os
from pathlib import Path

import pytest

from corelib.configlib import ConfigError
from mcdp.checkpoint_files import REMOVED, record_written
from mcdp.runs import atomic_torch_save
from study.sweep import stages
from study.sweep.config import load_sweep_config
from study.sweep.records import Counters

ROOT = Path(__file__).resolve().parents[2]
CI = ROOT / "configs" / "sweep" / "ci.yaml"  # keep_last: false, keep_best: false
RUN = ("runs", "overlap_0.50", "mono2_s0")
DATA = {"path": "unused", "config_hash": "d" * 16, "overlap": 0.5}


def _evaluated_run(run: Path) -> None:
    """A run folder as a sweep with keep_best: true leaves it: best.pt (recorded as the run's own), its status
    (trained, evaluated under the eval key "k"), and a removal record from that sweep's keep_last: false."""
    record_written(run, "best.pt", *atomic_torch_save({"w": 1}, run / "checkpoints" / "best.pt"), 2)
    (run / "checkpoints" / REMOVED).write_text(json.dumps({"files": {"last.pt": {"step": 2, "bytes": 9,
                                                                                "reason": "the other sweep's"}}}))
    (run / stages.STATUS).write_text(json.dumps({"trained": True, "eval_key": "k", "steps": 2,
                                                 "checkpoint": str(run / "checkpoints" / "best.pt"),
                                                 "checkpoint_step": 2, "data_hash": DATA["config_hash"]}))


def _sweep_with_linked_run(tmp_path: Path, level: int | None) -> tuple[Path, Path, Path | None]:
    """(the new sweep's folder, the folder holding the evaluated run, the link) for the run linked in at
    ``RUN[:level]`` (1: runs/, 2: runs/overlap_0.50/, 3: the run's folder; None: the run is the sweep's own)."""
    sweep, other = tmp_path / "sweep", tmp_path / "other_sweep"
    sweep.mkdir()
    if level is None:
        _evaluated_run(sweep.joinpath(*RUN))
        return sweep, sweep, None
    _evaluated_run(other.joinpath(*RUN))
    link = sweep.joinpath(*RUN[:level])
    link.parent.mkdir(parents=True, exist_ok=True)
    link.symlink_to(other.joinpath(*RUN[:level]), target_is_directory=True)
    return sweep, other, link


def _rerun(monkeypatch, sweep: Path, lines: list[str]) -> dict:
    """`study.sweep.stages.run_stage` of the linked run, its training and evaluation found done (their skip paths)."""
    import synth.open

    monkeypatch.setattr(synth.open, "open_dataset", lambda path: None)
    monkeypatch.setattr(stages, "_train", lambda run, row: True)
    monkeypatch.setattr(stages, "_evaluate", lambda run, row: ({}, "k"))
    monkeypatch.setattr(stages, "_fill_row", lambda row, status, passes: None)
    monkeypatch.setattr(stages, "_row_line", lambda tag, row: f"{tag}: (row)")
    return stages.run_stage(load_sweep_config(CI), 0.5, DATA, "mono2", 0, sweep, Counters(), lines.append, False)


@pytest.mark.parametrize("level", [1, 2, 3], ids=["runs", "overlap", "run"])
def test_a_rerun_with_keep_best_false_leaves_a_linked_run_untouched_and_says_so(tmp_path, monkeypatch, level,
                                                                                tree_hash):
    sweep, other, link = _sweep_with_linked_run(tmp_path, level)
    run = other.joinpath(*RUN)
    before = tree_hash(other)
    removed = (run / "checkpoints" / REMOVED).read_text()
    lines: list[str] = []
    _rerun(monkeypatch, sweep, lines)
    assert (run / "checkpoints" / "best.pt").is_file(), "best.pt deleted through the link"
    assert (run / "checkpoints" / REMOVED).read_text() == removed and "best_removed" not in \
        json.loads((run / stages.STATUS).read_text())
    assert tree_hash(other) == before
    said = [ln for ln in lines if "read only" in ln]
    assert len(said) == 1 and f"{link} is a symbolic link (to {os.readlink(link)})" in said[0], lines
    assert "nothing is written or deleted through the link" in said[0] and "removed" not in " ".join(lines)


def test_the_sweeps_own_run_is_still_cleaned_up_from_the_sweeps_root(tmp_path, monkeypatch):
    sweep, _, _ = _sweep_with_linked_run(tmp_path, None)
    run = sweep.joinpath(*RUN)
    lines: list[str] = []
    _rerun(monkeypatch, sweep, lines)
    assert not (run / "checkpoints" / "best.pt").exists()
    rec = json.loads((run / "checkpoints" / REMOVED).read_text())
    assert [r["file"] for r in rec["removals"]] == ["last.pt", "best.pt"]  # appended to the earlier record
    assert json.loads((run / stages.STATUS).read_text())["best_removed"] is True
    assert any("removed checkpoints/best.pt" in ln for ln in lines) and not any("read only" in ln for ln in lines)


@pytest.mark.parametrize("level", [1, 2, 3], ids=["runs", "overlap", "run"])
def test_a_linked_run_that_would_be_trained_again_is_refused_naming_the_link(tmp_path, monkeypatch, level,
                                                                             tree_hash):
    import synth.open

    sweep, other, link = _sweep_with_linked_run(tmp_path, level)
    status = other.joinpath(*RUN, stages.STATUS)
    status.write_text(json.dumps({**json.loads(status.read_text()), "run_config_hash": "another config"}))
    before = tree_hash(other)
    monkeypatch.setattr(synth.open, "open_dataset", lambda path: None)
    with pytest.raises(ConfigError) as e:
        stages.run_stage(load_sweep_config(CI), 0.5, DATA, "mono2", 0, sweep, Counters(), lambda s: None, False)
    msg = str(e.value)
    assert len(msg.splitlines()) == 1 and f"{link} is a symbolic link" in msg and "trained again" in msg, msg
    assert "copy the run into it instead of linking it" in msg
    assert tree_hash(other) == before


def test_a_status_or_metrics_write_below_a_link_is_refused_naming_it(tmp_path):
    from corelib.atomic import LinkRefused
    from study.sweep.records import write_json

    sweep, other, link = _sweep_with_linked_run(tmp_path, 2)
    status = sweep.joinpath(*RUN, stages.STATUS)
    old = status.read_text()
    for path in (status, stages.metrics_path(sweep.joinpath(*RUN), "trained")):
        with pytest.raises(LinkRefused) as e:
            write_json(path, {"x": 1}, root=sweep)
        assert e.value.filename == str(link) and str(link) in str(e.value)
    assert status.read_text() == old and not other.joinpath(*RUN, "metrics_test.json").exists()
    write_json(sweep / "runs" / "overlap_0.20" / "mono2_s0" / stages.STATUS, {"x": 1}, root=sweep)  # its own: made
    assert json.loads((sweep / "runs" / "overlap_0.20" / "mono2_s0" / stages.STATUS).read_text()) == {"x": 1}
