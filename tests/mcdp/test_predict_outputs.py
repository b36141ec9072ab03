"""`mcdp predict --out PRED --rrd X` claims every output before it writes any (issue 41, item 10): a refused
--out (a folder of the user's own files) leaves no recording behind. The recording itself is faked here (the
viz extra is not in this environment; tests/mcdp/test_recording.py checks the real one)."""
from __future__ import annotations

import sys
import types
from pathlib import Path

import pytest

import mcdp.trainer  # noqa: F401  torch before the in-process GL renderer (tests/mcdp/test_cli.py)
from study.method_commands import main

TINY = Path(__file__).resolve().parents[2] / "configs" / "train" / "tiny"


@pytest.fixture(scope="module")
def run(tiny_dataset, tmp_path_factory):
    run = tmp_path_factory.mktemp("pred") / "run"
    assert main(["train", str(TINY / "mono2.yaml"), "--data", str(tiny_dataset), "--out", str(run),
                 "--no-progress", "train.steps=1", "train.threads=1"]) == 0
    return run


@pytest.fixture
def fake_rerun(monkeypatch):
    """A recorder that writes the .rrd file it is given (as the real one does), and the viz extra 'present'."""
    import synth.view

    written: list[Path] = []

    def record_predictions(pred, samples, path, progress=False, rebuild=None):
        Path(path).write_bytes(b"a recording")
        written.append(Path(path))
        return {"bytes": 11, "bytes_per_rig_frame": 11.0}

    monkeypatch.setattr(synth.view, "import_rerun", lambda: None)
    monkeypatch.setitem(sys.modules, "mcdp.recording", types.SimpleNamespace(record_predictions=record_predictions))
    return written


def test_a_refused_out_leaves_no_recording(run, tiny_dataset, tmp_path, capsys, fake_rerun):
    out = tmp_path / "mine"
    out.mkdir()
    (out / "notes.txt").write_text("the user's own file")
    rrd = tmp_path / "p.rrd"
    rc = main(["predict", str(run), "--data", str(tiny_dataset), "--out", str(out), "--rrd", str(rrd),
               "--max-samples", "1"])
    err = capsys.readouterr().err.strip().splitlines()
    assert rc == 2 and str(out) in err[-1] and "not an mcdp predict folder" in err[-1], err
    assert not rrd.exists() and fake_rerun == []
    assert sorted(p.name for p in out.iterdir()) == ["notes.txt"]


def test_both_outputs_are_written_once_claimed(run, tiny_dataset, tmp_path, capsys, fake_rerun):
    out, rrd = tmp_path / "pred", tmp_path / "p.rrd"
    assert main(["predict", str(run), "--data", str(tiny_dataset), "--out", str(out), "--rrd", str(rrd),
                 "--max-samples", "1"]) == 0
    assert rrd.read_bytes() == b"a recording" and (out / "predict.json").is_file()
