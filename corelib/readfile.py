"""The readers' rule for a folder a command publishes from (a sweep folder, docs/results/): only regular files
that lie inside the folder (a symbolic link out of it is never followed), of a bounded size, opened so that a
FIFO never blocks; anything else is `ReadRefused`, one line naming the file. `synth.files` holds the same rule
for a dataset's files.

Example::

    data = read_inside(Path("docs/results/train_step/page.md"), Path("docs/results/train_step"))
"""
from __future__ import annotations

import os
import stat
from pathlib import Path

#: the largest file read by default (bytes): a results.json or a page is far smaller
MAX_BYTES = 64 * 2**20


class ReadRefused(ValueError):
    """A file that is not read (outside its folder, not a regular file, too large, unreadable); the message
    names it."""


def _kind(mode: int) -> str:
    return ("a folder" if stat.S_ISDIR(mode) else "a FIFO (named pipe)" if stat.S_ISFIFO(mode)
            else "a device" if stat.S_ISCHR(mode) or stat.S_ISBLK(mode) else "a socket" if stat.S_ISSOCK(mode)
            else "not a regular file")


#: the most one read asks for at once: a buffer of the bound itself (2 GiB for a dataset file) is asked of the
#: allocator before a byte is read, and fails under an address-space limit whatever the file's size
CHUNK_BYTES = 16 * 2**20


def read_bounded(f, limit: int) -> bytes:
    """At most ``limit + 1`` bytes of the open binary file ``f`` (one more than the bound, so the caller sees a
    file that holds more), read in chunks of at most `CHUNK_BYTES`: the memory asked for follows the file,
    never the bound (the first asks for the size the file has, plus one)."""
    chunks, total = [], 0
    want = os.fstat(f.fileno()).st_size + 1
    while total <= limit:
        chunk = f.read(max(1, min(want, CHUNK_BYTES, limit + 1 - total)))
        want = CHUNK_BYTES
        if not chunk:
            break
        chunks.append(chunk)
        total += len(chunk)
    return b"".join(chunks)


def inside(path: str | Path, root: str | Path) -> Path:
    """``path`` when it resolves inside ``root`` (a link out of it, ``../``: `ReadRefused` naming both)."""
    path, root = Path(path), Path(root)
    real, real_root = path.resolve(), root.resolve()
    if not real.is_relative_to(real_root):
        raise ReadRefused(f"{path}: resolves to {real}, outside {root}; only the files inside it are read")
    return path


def read_inside(path: str | Path, root: str | Path, limit: int = MAX_BYTES) -> bytes:
    """The bytes of the regular file ``path`` inside ``root`` (module docstring), at most ``limit``."""
    path = inside(path, root)
    try:
        fd = os.open(path, os.O_RDONLY | os.O_NONBLOCK)
    except FileNotFoundError:
        raise ReadRefused(f"{path}: no such file") from None
    except OSError as exc:
        raise ReadRefused(f"{path}: not readable ({exc.strerror or exc})") from None
    with os.fdopen(fd, "rb") as f:
        st = os.fstat(f.fileno())
        if not stat.S_ISREG(st.st_mode):
            raise ReadRefused(f"{path}: is {_kind(st.st_mode)}, not a regular file; refused without reading it")
        if st.st_size > limit:
            raise ReadRefused(f"{path}: {st.st_size} bytes, more than such a file may hold ({limit}); refused")
        try:
            data = read_bounded(f, limit)
        except OSError as exc:
            raise ReadRefused(f"{path}: not readable ({exc.strerror or exc})") from None
    if len(data) > limit:
        raise ReadRefused(f"{path}: more than {limit} bytes; refused")
    return data


def read_text_inside(path: str | Path, root: str | Path, limit: int = MAX_BYTES) -> str:
    """`read_inside` as UTF-8 text (`ReadRefused` naming the file and the byte otherwise)."""
    data = read_inside(path, root, limit)
    try:
        return data.decode("utf-8")
    except UnicodeDecodeError as exc:
        raise ReadRefused(f"{path}: not UTF-8 ({exc.reason} at byte {exc.start})") from None
