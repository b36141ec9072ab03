"""Hardening, round two (issue 20, item 6): the worker processes of `synth render --workers` and of a
sweep's parallel runs die with their parent on SIGTERM, SIGHUP, SIGINT and kill -9 (`corelib.procs`; SIGINT
to the parent alone: it ends its workers itself, since they did not get it).

Each test starts the real command in a subprocess, waits until its spawned workers run, signals the
parent only (not its process group: what `kill PID` or an OOM killer does) and checks the process
table: every worker is gone (or a zombie awaiting its reaper) within seconds.
"""
from __future__ import annotations

import os
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
pytestmark = [pytest.mark.skipif(not sys.platform.startswith("linux"), reason="PR_SET_PDEATHSIG is Linux-only"),
              pytest.mark.slow]  # processes killed and waited for: `pytest -m "not slow"` skips it


def _stat(pid: int) -> tuple[int, str] | None:
    """(ppid, state) of a live process, None once it is gone."""
    try:
        text = Path(f"/proc/{pid}/stat").read_text()
    except OSError:
        return None
    fields = text.rsplit(")", 1)[1].split()
    return int(fields[1]), fields[0]


def _spawned_children(pid: int) -> list[int]:
    kids = []
    for d in Path("/proc").iterdir():
        if d.name.isdigit():
            st = _stat(int(d.name))
            try:
                cmd = (d / "cmdline").read_bytes()
            except OSError:
                continue
            if st and st[0] == pid and st[1] != "Z" and b"spawn_main" in cmd:
                kids.append(int(d.name))
    return kids


def _alive(pids: list[int]) -> list[int]:
    return [p for p in pids if (st := _stat(p)) is not None and st[1] != "Z"]


def _kill_parent_and_check(argv: list[str], n_workers: int, sig: int, tmp_path: Path, default_signals,
                           wait_s: float = 240, ready: str | None = None) -> None:
    """Start ``argv``; once ``n_workers`` spawned children run (and stderr says ``ready`` that many times:
    the workers of the stage under test, not an earlier stage's), signal the parent only; it exits (130
    after SIGINT) and every one of those workers is gone."""
    env = {**os.environ, "OMP_NUM_THREADS": "1"}
    err = tmp_path / "err"
    proc = subprocess.Popen(argv, preexec_fn=default_signals, cwd=ROOT, env=env, stdout=subprocess.DEVNULL,
                            stderr=open(err, "w"))
    kids: list[int] = []
    try:
        t0 = time.monotonic()
        while len(kids) < n_workers or (ready is not None and err.read_text().count(ready) < n_workers):
            assert proc.poll() is None, err.read_text()[-2000:]
            assert time.monotonic() - t0 < wait_s, f"workers never started: {kids}"
            time.sleep(0.5)
            kids = _spawned_children(proc.pid)
        time.sleep(1.0)  # the workers are past their initializer
        os.kill(proc.pid, sig)
        proc.wait(timeout=120)  # a loaded machine (fsync of its first files) can take tens of seconds
        assert sig != signal.SIGINT or proc.returncode == 130, (proc.returncode, err.read_text()[-2000:])
        t1 = time.monotonic()
        while _alive(kids) and time.monotonic() - t1 < 20:
            time.sleep(0.2)
        assert _alive(kids) == [], f"workers {kids} outlived their parent (signal {sig})"
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
        for pid in _alive(kids):  # a failing test leaves no orphan behind either
            os.kill(pid, signal.SIGKILL)


@pytest.mark.parametrize("sig", [signal.SIGKILL, signal.SIGTERM, signal.SIGHUP, signal.SIGINT])
def test_render_workers_die_with_the_render(tmp_path, sig, default_signals):
    argv = [sys.executable, "-m", "synth.cli", "render", "configs/data/tiny.yaml", "--out", str(tmp_path / "d"),
            "--workers", "2", "--no-progress", "dataset.sequences=6", "dataset.frames=200"]
    _kill_parent_and_check(argv, 3, sig, tmp_path, default_signals)  # the progress queue's manager + 2 workers


SWEEP = ["pretrain=null", "methods=[mono2]", "overlaps=[0.2]", "seeds=[0,1]", "jobs=2", "preview=false",
         "train_overrides=[train.steps=100000,train.val_every=100000,train.ckpt_every=100000,model.min_depth=2.0]"]


@pytest.fixture(scope="module")
def sweep_data(tmp_path_factory):
    """The sweep's dataset (overlap 0.20), rendered once in process as its render stage does: each test's
    sweep reuses a copy of it and gets to its runs' workers without rendering it again."""
    from corelib.rundir import claim
    from study.sweep.config import load_sweep_config
    from study.sweep.stages import Counters
    from study.sweep.worlds import render_stage

    sweep_dir = tmp_path_factory.mktemp("orphans") / "s"
    claim(sweep_dir, "sweep").release()  # what the sweep writes first: the marker of a sweep folder
    render_stage(load_sweep_config(ROOT / "configs" / "sweep" / "ci.yaml", SWEEP), 0.2, sweep_dir, Counters(),
                 lambda *a: None, False)
    return sweep_dir


@pytest.mark.parametrize("sig", [signal.SIGKILL, signal.SIGTERM, signal.SIGHUP, signal.SIGINT])
def test_sweep_run_workers_die_with_the_sweep(sweep_data, tmp_path, sig, default_signals):
    shutil.copytree(sweep_data, tmp_path / "s")
    argv = [sys.executable, "-m", "study.cli", "sweep", "configs/sweep/ci.yaml", "--out", str(tmp_path / "s"),
            "--no-progress", *SWEEP]
    _kill_parent_and_check(argv, 2, sig, tmp_path, default_signals, wait_s=600,
                           ready="training 100000 steps")  # the runs' workers
    assert "overlap_0.20: dataset" in (tmp_path / "err").read_text() and "reused" in (tmp_path / "err").read_text()
