"""Untrusted files (issue 32, hardening round three): every file a command reads from a dataset or a
nuScenes dataroot is its own (inside the root, not through a link out of it) and a regular file (a FIFO
or a device is refused, never opened for a blocking read); `synth merge` copies no link; numbers read
from a dataroot's tables are validated; outputs never land inside a dataset or dataroot; a dead worker
does not hang its parent. Each refusal is one line naming the file, exit 2, nothing written.
"""
from __future__ import annotations

import json
import os
import shutil
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]


def _shard(tiny_dataset, tmp_path) -> Path:
    """A shard folder: the finished tiny dataset without its manifest (a render of every sequence)."""
    d = tmp_path / "shA"
    shutil.copytree(tiny_dataset, d)
    (d / "manifest.json").unlink()
    return d


def _first_seq(d: Path) -> str:
    return sorted(p.name for p in d.glob("seq_*"))[0]


def _link_depth(d: Path, secret: Path) -> Path:
    p = d / _first_seq(d) / "CAM_FRONT" / "000000.depth.exr"
    shutil.copyfile(p, secret)
    os.chmod(secret, 0o600)
    p.unlink()
    p.symlink_to(secret)
    return p


def _link_seq(d: Path, secret: Path) -> Path:
    p = d / _first_seq(d)
    shutil.move(str(p), secret)
    p.symlink_to(secret, target_is_directory=True)
    return p


def _link_rig(d: Path, secret: Path) -> Path:
    p = d / "rig.json"
    shutil.move(str(p), secret)
    p.symlink_to(secret)
    return p


def _link_mask(d: Path, secret: Path) -> Path:
    p = d / "masks" / "CAM_FRONT.png"
    shutil.move(str(p), secret)
    p.symlink_to(secret)
    return p


def _fifo_png(d: Path, secret: Path) -> Path:
    p = d / _first_seq(d) / "CAM_BACK" / "000001.png"
    p.unlink()
    os.mkfifo(p)
    return p


# --------------------------------------------------------------------------- finding 1: merge
@pytest.mark.parametrize("plant", [_link_depth, _link_seq, _link_rig, _link_mask, _fifo_png])
def test_merge_copies_no_link_and_no_special_file(tiny_dataset, tmp_path, capsys, plant):
    from synth.cli import main as synth_main

    shard = _shard(tiny_dataset, tmp_path)
    bad = plant(shard, tmp_path / "secret")
    out = tmp_path / "MG"
    capsys.readouterr()
    assert synth_main(["merge", "--out", str(out), str(shard)]) == 2
    err = capsys.readouterr().err
    assert str(bad) in err and len(err.splitlines()) == 1, err
    assert not out.exists()  # checked before anything is written
