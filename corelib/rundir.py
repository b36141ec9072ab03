"""Output folders the tools own: a marker written first, and an exclusive lock while a process writes.

`claim(folder, kind)` is called by every command that writes a folder (``mcdp train``'s run
folder, ``mcdp predict --out``, ``mcdp sweep --out``):

- a folder that does not exist or is empty is created and marked (``.mcdp``: its kind, written
  first, atomically);
- a non-empty folder is accepted only when it carries the marker of the same kind (or, for
  folders written before markers existed, one of the kind's own files, ``legacy``); anything
  else, such as a folder with the user's own files, is refused before a byte is written;
- an exclusive lock on ``.lock`` (`filelock.FileLock`: ``flock`` on Unix) is held until
  `FolderLock.release` (or process exit): a second process writing the same folder is refused at once,
  naming the holder's pid, which the holder writes into the lock file when it gets the lock (a refused
  attempt leaves the file as it is).

`check_output_file(path, is_ours, what)` does the same for a single file a command writes (``synth
preview --out``, ``mcdp eval --out``): new, or a regular file the command recognises as its own,
in a folder that can be written (`corelib.atomic.check_writable`), before any work.

Both remove the temporary files that a writer killed with SIGKILL left behind
(`corelib.atomic.remove_stale_temps`: the whole folder under the lock, the file's own beside it).

Example::

    lock = claim(Path("runs/m2"), "run", legacy=("run.json",))
    try:
        ...
    finally:
        lock.release()
"""
from __future__ import annotations

import os
import stat
from pathlib import Path
from typing import Callable

from filelock import FileLock, Timeout

from corelib.atomic import atomic_write_json, check_writable, naming, remove_stale_temps
from corelib.readfile import read_file, read_json_file

MARKER = ".mcdp"
LOCK = ".lock"


class FolderError(ValueError):
    """An output folder that is not ours, or is being written by another process; the message says which."""


class FolderLock:
    def __init__(self, folder: Path, lock: FileLock):
        self.folder, self._lock = folder, lock

    def release(self) -> None:
        if self._lock is not None:
            try:
                self._lock.release(force=True)
            finally:
                self._lock = None


def _write_pid(fd: int) -> None:
    """`FileLock`'s on_acquired hook: this process's pid into the lock file it now holds."""
    os.ftruncate(fd, 0)
    os.pwrite(fd, str(os.getpid()).encode(), 0)


def _kind_of(folder: Path) -> str | None:
    try:
        return str(read_json_file(folder / MARKER, kind="record").get("kind"))
    except (OSError, ValueError, AttributeError):  # ValueError: corelib.readfile.ReadRefused too
        return None


def claim(folder: str | Path, kind: str, legacy: tuple[str, ...] = ()) -> FolderLock:
    """Create or accept ``folder`` as an mcdp ``kind`` folder and lock it (module docstring)."""
    folder = Path(folder)
    if folder.exists() and not folder.is_dir():
        raise FolderError(f"{folder} is a file, not a folder; use a new --out")
    entries = sorted(p.name for p in folder.iterdir()) if folder.is_dir() else []
    ours = [e for e in entries if e not in (MARKER, LOCK)]
    if ours:
        have = _kind_of(folder)
        if have is None and not any((folder / name).exists() for name in legacy):
            raise FolderError(f"{folder} is not empty and is not an mcdp {kind} folder ({', '.join(ours[:4])}"
                              + (", ..." if len(ours) > 4 else "") + "); nothing was written: use a new --out")
        if have is not None and have != kind:
            raise FolderError(f"{folder} is an mcdp {have} folder, not a {kind} folder; use a new --out")
    folder.mkdir(parents=True, exist_ok=True)
    lock = lock_folder(folder)
    if _kind_of(folder) is None:
        atomic_write_json(folder / MARKER, {"kind": kind})
    return lock


def lock_folder(folder: str | Path, lock_file: str | Path = LOCK) -> FolderLock:
    """An exclusive, non-blocking lock on ``folder/lock_file`` (created; it holds the pid). FolderError
    naming the holder's pid when another process has it; released by `FolderLock.release` or exit."""
    folder = Path(folder)
    path = folder / lock_file
    # thread_local=False: the process holds it, whichever thread releases; on_acquired: the pid is written
    # under the lock (it also keeps the lock native: no soft-lock fallback whose marker the pid would clobber)
    lock = FileLock(path, timeout=0, thread_local=False, on_acquired=_write_pid)
    try:  # the pid is the first write: a disk full from the start fails here, naming the lock file
        with naming(path):
            lock.acquire()
    except Timeout:
        try:
            holder = read_file(path, kind="record").decode(errors="replace").strip()[:20] or "?"
        except (OSError, ValueError):  # a FIFO or a link put there: corelib.readfile.ReadRefused
            holder = "?"
        raise FolderError(f"{folder} is being written by another process (pid {holder}); wait for it or use "
                          "another --out") from None
    except BaseException:
        if lock.is_locked:
            lock.release(force=True)
        raise
    remove_stale_temps(folder)  # what a writer killed with SIGKILL left; no other writer runs here now
    return FolderLock(folder, lock)


def check_output_file(path: str | Path, is_ours: Callable[[Path], bool], what: str, flag: str = "--out") -> Path:
    """Accept ``path`` as a file to (over)write: it does not exist yet (in an existing folder, or one to be
    created), or it is a regular file that ``is_ours`` recognises as a ``what`` written earlier. A symlink,
    a folder, a device, FIFO or socket, and a file of anyone else are refused (FolderError naming the path)
    before the command writes or computes anything."""
    path = Path(path)
    try:
        st = path.lstat()
    except FileNotFoundError:
        for parent in path.parents:
            if parent.exists() or parent.is_symlink():
                if not parent.is_dir():
                    raise FolderError(f"{flag} {path}: {parent} is not a folder") from None
                break
        return _writable(path)
    if stat.S_ISLNK(st.st_mode):
        raise FolderError(f"{flag} {path} is a symlink; nothing was written: give a new file name, not a link")
    if stat.S_ISDIR(st.st_mode):
        raise FolderError(f"{flag} {path} is a folder; {flag} names the {what} file to write")
    if not stat.S_ISREG(st.st_mode):
        raise FolderError(f"{flag} {path} is not a regular file (a device, FIFO or socket); nothing was written: "
                          "choose a new file name")
    if not is_ours(path):
        raise FolderError(f"{flag} {path} exists and is not a {what}; nothing was written: choose a new file name")
    return _writable(path)


def _writable(path: Path) -> Path:
    """``path`` once its folder is known to be writable (the OSError otherwise, naming it), with the
    temporary files of an earlier writer of it that was killed removed."""
    check_writable(path)
    if path.parent.is_dir():
        remove_stale_temps(path.parent, recursive=False, name=path.name)
    return path
