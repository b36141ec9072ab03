"""A sweep's checkpoint clean-up (keep_last / keep_best: false, the pretraining's trim) deletes only the files
the run recorded (sha256) when it wrote them, never through a link, and its removal record is append-only
(issue 41, item 1)."""
from __future__ import annotations

import json
import os
from pathlib import Path

import pytest

from mcdp.checkpoint_files import REMOVED, WRITTEN, record_removed, removable, removed_checkpoints
from mcdp.runs import atomic_torch_save
from study.sweep.config import SweepConfig
from study.sweep.cleanup import remove_best, trim_pretraining


def _write(run: Path, name: str, payload: dict, step: int = 2) -> None:
    """A checkpoint as the trainer writes it: the file, then its sha256 in written.json."""
    from mcdp.checkpoint_files import record_written

    record_written(run, name, *atomic_torch_save(payload, run / "checkpoints" / name), step)


def _status(run: Path) -> tuple[dict, Path]:
    st = {"trained": True, "eval_key": "k", "steps": 2, "checkpoint": str(run / "checkpoints" / "best.pt"),
          "checkpoint_step": 2}
    path = run / "sweep_status.json"
    path.write_text(json.dumps(st))
    return st, path


def test_written_record_holds_the_sha256_of_the_bytes_on_disk(tmp_path):
    import hashlib

    _write(tmp_path, "last.pt", {"a": 1})
    rec = json.loads((tmp_path / "checkpoints" / WRITTEN).read_text())["files"]["last.pt"]
    assert rec["sha256"] == hashlib.sha256((tmp_path / "checkpoints" / "last.pt").read_bytes()).hexdigest()
    assert removable(tmp_path, ["last.pt", "best.pt"]) == ({"last.pt": rec["bytes"]}, {})


def test_keep_best_false_deletes_the_runs_files_and_keeps_a_users_file_of_the_same_name(tmp_path):
    run = tmp_path / "run"
    _write(run, "best.pt", {"w": 1})
    (run / "checkpoints" / "last.pt").write_bytes(b"the user's own file")  # never written by the run
    status, path = _status(run)
    lines: list[str] = []
    status, removed = remove_best(run, status, path, "k", lines.append, "[t]")
    assert [n for n, _, _ in removed] == ["best.pt"] and not (run / "checkpoints" / "best.pt").exists()
    assert (run / "checkpoints" / "last.pt").read_bytes() == b"the user's own file"
    assert "last_removed" not in status and status["best_removed"] is True
    assert len(lines) == 1 and "kept checkpoints/last.pt" in lines[0] and "not the run's file" in lines[0]

    # a rerun with the user's own best.pt placed where the real one was: kept, and the record of the real
    # checkpoint's removal is not overwritten
    record = (run / "checkpoints" / REMOVED).read_text()
    (run / "checkpoints" / "best.pt").write_bytes(b"mine")
    status2, removed2 = remove_best(run, status, path, "k", lines.append, "[t]")
    assert removed2 == [] and (run / "checkpoints" / "best.pt").read_bytes() == b"mine"
    assert (run / "checkpoints" / REMOVED).read_text() == record


@pytest.mark.parametrize("link", ["folder", "file"])
def test_nothing_is_deleted_through_a_symlinked_checkpoints_folder_or_file(tmp_path, link):
    run, elsewhere = tmp_path / "sweep" / "run", tmp_path / "outside"
    _write(elsewhere, "best.pt", {"w": 1})  # a run's own files, recorded, but outside this folder
    _write(elsewhere, "last.pt", {"w": 2})
    run.mkdir(parents=True)
    if link == "folder":
        (run / "checkpoints").symlink_to(elsewhere / "checkpoints")
    else:
        (run / "checkpoints").mkdir()
        for n in ("best.pt", "last.pt", WRITTEN):
            (run / "checkpoints" / n).symlink_to(elsewhere / "checkpoints" / n)
    status, path = _status(run)
    lines: list[str] = []
    _, removed = remove_best(run, status, path, "k", lines.append, "[t]")
    trim_pretraining(SweepConfig(keep_last=False, keep_best=False), run, 2, lines.append)
    assert removed == [] and sorted(p.name for p in (elsewhere / "checkpoints").iterdir()) == \
        ["best.pt", "last.pt", WRITTEN]
    assert lines and all("kept checkpoints/" in ln for ln in lines), lines
    assert not (elsewhere / "checkpoints" / REMOVED).exists()


def test_the_pretrainings_trim_deletes_only_what_it_wrote(tmp_path):
    run = tmp_path / "pretrain" / "run"
    _write(run, "last.pt", {"w": 1})
    (run / "checkpoints" / "best.pt").write_bytes(b"a user's file")
    lines: list[str] = []
    trim_pretraining(SweepConfig(keep_last=False, keep_best=False), run, 2, lines.append)
    assert not (run / "checkpoints" / "last.pt").exists() and (run / "checkpoints" / "best.pt").is_file()
    assert any("removed checkpoints/last.pt" in ln for ln in lines)
    assert any("kept checkpoints/best.pt" in ln for ln in lines)
    assert set(removed_checkpoints(run)) == {"last.pt"}


def test_the_removal_record_is_append_only(tmp_path):
    run = tmp_path
    (run / "checkpoints").mkdir()
    # a record of the older layout (files only) is kept as the first removals
    (run / "checkpoints" / REMOVED).write_text(json.dumps({"files": {"best.pt": {"step": 2, "bytes": 9,
                                                                                 "reason": "first"}}}))
    record_removed(run, {"best.pt": {"step": 5, "reason": "second"}}, {"best.pt": 7})
    rec = json.loads((run / "checkpoints" / REMOVED).read_text())
    assert [(r["file"], r["reason"]) for r in rec["removals"]] == [("best.pt", "first"), ("best.pt", "second")]
    assert removed_checkpoints(run)["best.pt"]["reason"] == "second"


def test_an_unreadable_removal_record_is_never_replaced_and_nothing_is_deleted(tmp_path):
    run = tmp_path
    _write(run, "last.pt", {"w": 1})
    (run / "checkpoints" / REMOVED).write_bytes(b"\xff not json")
    ok, kept = removable(run, ["last.pt"])
    assert ok == {} and REMOVED in kept["last.pt"]
    lines: list[str] = []
    trim_pretraining(SweepConfig(keep_last=False, keep_best=False), run, 2, lines.append)
    assert (run / "checkpoints" / "last.pt").is_file()
    assert (run / "checkpoints" / REMOVED).read_bytes() == b"\xff not json"


def test_a_fifo_under_a_checkpoints_name_is_kept_without_blocking(tmp_path):
    run = tmp_path
    _write(run, "last.pt", {"w": 1})
    os.mkfifo(run / "checkpoints" / "best.pt")
    ok, kept = removable(run, ["last.pt", "best.pt"])
    assert set(ok) == {"last.pt"} and "not a regular file" in kept["best.pt"]


@pytest.mark.parametrize("linked", ["runs", "runs/overlap_0.50", "runs/overlap_0.50/mono2_s0"])
def test_nothing_is_deleted_or_recorded_below_a_linked_folder_of_the_sweep(tmp_path, linked):
    """Issue 49, item 1: given the sweep's folder as ``root``, a link at any level between it and checkpoints/
    (not only checkpoints/ itself) keeps every file, the kept line naming the link, and no record is written."""
    from corelib.atomic import LinkRefused

    sweep, other = tmp_path / "sweep", tmp_path / "other"
    rel = Path("runs/overlap_0.50/mono2_s0")
    _write(other / rel, "best.pt", {"w": 1})
    _write(other / rel, "last.pt", {"w": 2})
    (sweep / linked).parent.mkdir(parents=True, exist_ok=True)
    (sweep / linked).symlink_to(other / linked, target_is_directory=True)
    run = sweep / rel
    status, path = _status(run)  # written through the link by the test, as the other sweep left it
    before = path.read_text()
    lines: list[str] = []
    _, removed = remove_best(run, status, path, "k", lines.append, "[t]", root=sweep)
    trim_pretraining(SweepConfig(keep_last=False, keep_best=False), run, 2, lines.append, root=sweep)
    assert removed == [] and sorted(p.name for p in (other / rel / "checkpoints").iterdir()) == \
        ["best.pt", "last.pt", WRITTEN]
    assert path.read_text() == before
    assert lines and all(f"{sweep / linked} is a symbolic link: nothing is deleted through it" in ln
                         for ln in lines), lines
    assert removable(run, ["best.pt"]) == ({"best.pt": (other / rel / "checkpoints" / "best.pt").stat().st_size}, {})
    with pytest.raises(LinkRefused):  # without root only checkpoints/ is guarded (above); with it, the whole way
        record_removed(run, {"best.pt": {"step": 2, "reason": "x"}}, {"best.pt": 1}, root=sweep)
    assert not (other / rel / "checkpoints" / REMOVED).exists()
