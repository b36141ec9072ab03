"""Progress written to a stream that is not a terminal is one plain line per interval, never tqdm's
carriage-return frames (issue 41, item 15); every progress bar of the project comes from corelib.progress."""
from __future__ import annotations

import io
import re
from pathlib import Path

import corelib.progress as progress
from corelib.progress import LineProgress, progress_bar

ROOT = Path(__file__).resolve().parents[2]


def test_a_file_gets_plain_lines_not_carriage_return_frames(monkeypatch):
    out = io.StringIO()
    bar = progress_bar(total=1000, desc="train", unit="step", file=out)
    assert isinstance(bar, LineProgress)
    for _ in range(1000):
        bar.update(1)
        bar.set_postfix(loss="0.1234")
    bar.close()
    text = out.getvalue()
    assert "\r" not in text and "\x1b" not in text
    assert text.splitlines() == [text.splitlines()[0]]  # 1000 updates in well under INTERVAL_S: the closing line
    assert re.fullmatch(r"train: 1000/1000 step \(100 %\), \d+ s, loss=0\.1234", text.splitlines()[0]), text


def test_one_line_per_interval_and_iteration(monkeypatch):
    monkeypatch.setattr(progress, "INTERVAL_S", 0.0)
    out = io.StringIO()
    assert list(progress_bar(["a", "b", "c"], desc="verify", unit="file", file=out)) == ["a", "b", "c"]
    lines = out.getvalue().splitlines()
    assert lines[0].startswith("verify: 1/3 file (33 %)") and lines[-1].startswith("verify: 3/3 file (100 %)")
    assert len(lines) == 4  # one per update (interval 0) and the closing one


def test_every_progress_bar_comes_from_corelib_progress():
    users = [p.relative_to(ROOT).as_posix() for d in ("synth", "mcdp", "study", "corelib")
             for p in sorted((ROOT / d).rglob("*.py"))
             if "import tqdm" in p.read_text() or "from tqdm" in p.read_text()]
    users.remove("corelib/progress.py")
    assert users == [], f"tqdm used directly (use corelib.progress.progress_bar): {users}"
