"""A sweep says what it will write to disk and refuses one the disk cannot hold (`study.sweep.disk`)."""
from __future__ import annotations

import os
import sys
from pathlib import Path

import pytest

from corelib.configlib import ConfigError

ROOT = Path(__file__).resolve().parents[2]
CI = ROOT / "configs" / "sweep" / "ci.yaml"
MONO2 = ROOT / "configs" / "train" / "tiny" / "mono2.yaml"


def _cfg(*overrides: str):
    from study.sweep.config import load_sweep_config

    return load_sweep_config(CI, list(overrides), None)


def test_the_estimate_is_the_size_of_a_checkpoint_the_trainer_writes(tiny_dataset, tmp_path):
    """last.pt of a real one-step run is the meta-device estimate to within 2 % (its config and records)."""
    from mcdp.config import RunConfig
    from corelib.configlib import load_config
    from study.sweep.disk import checkpoint_bytes
    from study.method_commands import main

    run = tmp_path / "run"
    assert main(["train", str(MONO2), "--data", str(tiny_dataset), "--out", str(run), "--no-progress",
                 "train.steps=1"]) == 0
    last, best = checkpoint_bytes(load_config(RunConfig, MONO2, ["train.steps=1"]))
    written = (run / "checkpoints" / "last.pt").stat().st_size
    assert abs(written - last) / written < 0.02, (written, last)
    assert 2.9 < last / best < 3.1  # the weights and Adam's two moments: a frozen network would read less


def test_the_estimate_counts_what_the_keep_keys_keep(monkeypatch):
    from study.sweep import disk
    monkeypatch.setattr(disk, "checkpoint_bytes", lambda rcfg, n_cameras=6: (300, 100))
    runs = 2 * 7  # ci.yaml: 2 overlaps x 7 methods x 1 seed
    both = disk.estimate(_cfg("keep_last=true", "keep_best=true"), 3000)
    assert both["runs"] == runs and both["renders"] == 1000
    # every run keeps both, and the pretraining its pretrained.pt, last.pt and best.pt
    assert both["checkpoints"] == runs * 400 + (100 + 300 + 100)
    neither = disk.estimate(_cfg(), 3000)  # ci.yaml: keep_last and keep_best false, two jobs at once
    assert neither["checkpoints"] == 2 * 400 + 100
    assert neither["total"] == neither["checkpoints"] + 1000


def test_a_sweep_larger_than_the_free_space_is_refused_naming_the_keys(monkeypatch, tmp_path):
    from study.sweep import disk
    monkeypatch.setattr(disk, "checkpoint_bytes", lambda rcfg, n_cameras=6: (3_000_000, 1_000_000))
    monkeypatch.setattr(disk, "free_bytes", lambda out: 5_000_000)
    cfg = _cfg("keep_last=true", "keep_best=true")
    with pytest.raises(ConfigError) as exc:
        disk.check_disk(cfg, tmp_path / "sweep", 0, yes=False)
    msg = str(exc.value)
    assert f"--out {tmp_path / 'sweep'}" in msg and "set keep_last: false and keep_best: false," in msg, msg
    assert "--yes" in msg, msg
    assert "5 MB" not in msg and "0.005 GB are free" in msg, msg
    assert "still to write" in disk.check_disk(cfg, tmp_path / "sweep", 0, yes=True)
    # a file's apparent size under the folder is not what was written (issue 61, item 7): a sparse one is refused
    (tmp_path / "sweep").mkdir()
    with open(tmp_path / "sweep" / "done.bin", "wb") as f:
        f.truncate(70_000_000)  # sparse: its size, not its blocks
    with pytest.raises(ConfigError):
        disk.check_disk(cfg, tmp_path / "sweep", 0, yes=False)


def test_a_link_under_the_folder_is_not_followed(tmp_path):
    from study.sweep.disk import bytes_under

    (tmp_path / "big").write_bytes(b"\0" * 10_000)
    (tmp_path / "sweep").mkdir()
    (tmp_path / "sweep" / "own").write_bytes(b"\0" * 100)
    os.symlink(tmp_path / "big", tmp_path / "sweep" / "link")
    os.symlink(tmp_path, tmp_path / "sweep" / "dirlink")
    # the blocks the files hold (the link's own: none, its target's name fits in the inode), not what a link
    # points to; the folder link is not entered
    assert bytes_under(tmp_path / "sweep") == os.lstat(tmp_path / "sweep" / "own").st_blocks * 512 \
        + os.lstat(tmp_path / "sweep" / "link").st_blocks * 512
    assert bytes_under(tmp_path / "absent") == 0


@pytest.mark.slow  # a whole `mcdp sweep` as a subprocess on a real tmpfs
def test_the_command_refuses_a_sweep_on_a_small_disk_before_writing(tmp_path, small_disk):
    mnt = tmp_path / "mnt"
    mnt.mkdir()
    env = {**os.environ, "PYTHONPATH": str(ROOT), "OMP_NUM_THREADS": "1"}
    res, left = small_disk([sys.executable, "-m", "mcdp", "sweep", str(CI), "--out", str(mnt / "sweep"),
                            "--no-progress"], mnt, size="64m", timeout=300, env=env)
    err = res.stderr.strip().splitlines()
    assert res.returncode == 2, res.stderr[-2000:]
    assert "Traceback" not in res.stderr and "0.0671 GB are free there" in err[-1], err
    assert "set keep_" not in err[-1] and "fewer seeds" in err[-1], err  # ci.yaml keeps neither already
    assert left == []  # refused before anything was written
