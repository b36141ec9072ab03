"""corelib.rundir's folder lock (filelock): one writer per folder, the refusal names the holder's pid,
and the lock goes with its holder, released or killed."""
from __future__ import annotations

import os
import signal
import subprocess
import sys
from pathlib import Path

import pytest

from corelib.rundir import FolderError, lock_folder

ROOT = Path(__file__).resolve().parents[2]
HOLD = ("import sys; from corelib.rundir import lock_folder; l = lock_folder(sys.argv[1]); "
        "print('locked', flush=True); sys.stdin.read()")


def _holder(folder: Path) -> subprocess.Popen:
    p = subprocess.Popen([sys.executable, "-c", HOLD, str(folder)], cwd=ROOT, text=True,
                         env={**os.environ, "PYTHONPATH": str(ROOT)}, stdin=subprocess.PIPE, stdout=subprocess.PIPE)
    assert p.stdout.readline().strip() == "locked"
    return p


def test_a_second_writer_is_refused_naming_the_holders_pid_and_leaves_it_in_the_file(tmp_path):
    held = lock_folder(tmp_path)
    try:
        assert (tmp_path / ".lock").read_text() == str(os.getpid())
        for _ in range(2):  # a refused attempt does not erase the pid the next one reports
            with pytest.raises(FolderError, match=rf"another process \(pid {os.getpid()}\)"):
                lock_folder(tmp_path)
        assert (tmp_path / ".lock").read_text() == str(os.getpid())
    finally:
        held.release()
    again = lock_folder(tmp_path)  # released: free again
    again.release()
    again.release()  # twice is harmless


def test_the_lock_of_another_process_holds_until_it_exits_even_killed(tmp_path):
    p = _holder(tmp_path)
    try:
        with pytest.raises(FolderError, match=rf"\(pid {p.pid}\)"):
            lock_folder(tmp_path)
    finally:
        p.send_signal(signal.SIGKILL)
        p.wait(timeout=30)
    lock_folder(tmp_path).release()  # the kernel dropped the killed holder's lock
    assert (tmp_path / ".lock").read_text() == str(os.getpid())
