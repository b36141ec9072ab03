"""Files that are whole or absent: write to a temporary name beside the target, flush, fsync, rename.

A reader never sees a half-written file under the final name, whatever stops the writer (a
crash, Ctrl-C, a full disk). A full disk is reported as `DiskFullError`: one line that names
the file and says how to resume.

Example::

    atomic_write_bytes(path, png_bytes)
    with atomic_path(path) as tmp:      # for libraries that write to a file name themselves
        exr.write(str(tmp))
"""
from __future__ import annotations

import errno
import json
import os
from contextlib import contextmanager
from pathlib import Path
from typing import Iterator


class DiskFullError(OSError):
    """No space left while writing `filename`; nothing half-written is left under that name."""

    def __init__(self, path: str | Path):
        super().__init__(errno.ENOSPC, "no space left on device", str(path))

    def __reduce__(self):  # crosses process boundaries (a render worker's error) intact
        return (DiskFullError, (self.filename,))

    def __str__(self) -> str:
        return (f"{self.filename}: no space left on device; nothing half-written was kept: free space and run "
                "the same command again to resume")


def is_disk_full(exc: BaseException) -> bool:
    return isinstance(exc, OSError) and exc.errno in (errno.ENOSPC, errno.EDQUOT)


def disk_full_message(exc: OSError) -> str:
    """One line for any ENOSPC error, naming the file when the OS gave it."""
    return str(exc if isinstance(exc, DiskFullError) else DiskFullError(exc.filename or "(unnamed file)"))


def _tmp_name(path: Path) -> Path:
    return path.with_name(f".{path.name}.tmp{os.getpid()}")


def _fsync(path: Path) -> None:
    fd = os.open(path, os.O_RDONLY)
    try:
        os.fsync(fd)
    finally:
        os.close(fd)


@contextmanager
def atomic_path(path: str | Path, fsync: bool = True) -> Iterator[Path]:
    """Yield a temporary path beside `path`; on success it is fsynced and renamed onto `path`,
    on any error it is removed (ENOSPC raised as `DiskFullError` naming `path`)."""
    path = Path(path)
    tmp = _tmp_name(path)
    try:
        yield tmp
        if fsync:
            _fsync(tmp)
        os.replace(tmp, path)
    except BaseException as exc:
        try:
            tmp.unlink()
        except FileNotFoundError:
            pass
        if is_disk_full(exc) and not isinstance(exc, DiskFullError):
            raise DiskFullError(path) from None
        raise


def atomic_write_bytes(path: str | Path, data: bytes, fsync: bool = True) -> None:
    with atomic_path(path, fsync=False) as tmp:
        with open(tmp, "wb") as f:
            f.write(data)
            f.flush()
            if fsync:
                os.fsync(f.fileno())


def atomic_write_text(path: str | Path, text: str, fsync: bool = True) -> None:
    atomic_write_bytes(path, text.encode("utf-8"), fsync=fsync)


def atomic_write_json(path: str | Path, obj, fsync: bool = True, **dumps) -> None:
    """JSON (``indent=1`` unless given) written whole or not at all."""
    dumps.setdefault("indent", 1)
    atomic_write_text(path, json.dumps(obj, **dumps), fsync=fsync)
