"""The one rule for reading a file the project wrote or a user hands in: a regular file, reached without a
symbolic link, opened non-blocking (a FIFO never blocks), bounded by a size stated per kind of file (`LIMITS`),
read in chunks as large as the file (never a buffer of the bound), decoded with a one-line error naming the file
and what is wrong (`ReadRefused`). `tests/test_own_files.py` scans the library for plain ``open()`` /
``read_text()`` / ``read_bytes()`` of a project file outside this module and `synth.files` (a dataset's files,
the same rule with its own error class).

- `read_file` / `read_json_file`: the file's own name is never a link (``O_NOFOLLOW``); given ``root`` (the sweep
  folder, the results folder), no folder between the root and the file is one either (`corelib.nolinks`).
- `read_inside` / `read_text_inside`: a folder a command publishes from (docs/results/): links that stay inside
  it are followed, one out of it is refused.

Example::

    status = read_json_file(sweep / "runs/overlap_0.50/mono2_s0/sweep_status.json", root=sweep, kind="record")
    data = read_inside(Path("docs/results/train_step/page.md"), Path("docs/results/train_step"))
"""
from __future__ import annotations

import errno
import json
import os
import stat
from pathlib import Path

#: the largest file read by default (bytes): a results.json or a page is far smaller
MAX_BYTES = 64 * 2**20


#: the bound of each kind of file the project reads of its own (bytes); a file over it is refused unread
LIMITS = {
    "record": 16 * 2**20,      # a sweep's status / metrics / overlap record (per-sequence sums: a few MB)
    "results": 64 * 2**20,     # results.json / results.csv of a sweep
    "page": 8 * 2**20,         # a published page, a preface (tens of kB)
    "config": 1 * 2**20,       # a YAML preset, a recorded config
    "checkpoint": 16 * 2**30,  # a run's last.pt / best.pt, a pretraining (hundreds of MB)
    "hashed": 2**40,           # a file hashed as it streams (sha256 of a dataset's file): never held whole
}


class ReadRefused(ValueError):
    """A file that is not read (outside its folder, not a regular file, too large, unreadable); the message
    names it."""


class FileMissing(ReadRefused):
    """No file at that name (a record not written yet): a caller may read it as absent."""


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
        return _bounded_bytes(f, path, limit)


def _bounded_bytes(f, path, limit: int) -> bytes:
    """At most ``limit`` bytes of the open file ``f`` (`read_bounded`); `ReadRefused` naming ``path`` when it cannot
    be read or holds more (it grew while read)."""
    try:
        data = read_bounded(f, limit)
    except OSError as exc:
        raise ReadRefused(f"{path}: not readable ({exc.strerror or exc})") from None
    if len(data) > limit:
        raise ReadRefused(f"{path}: grew past {limit} bytes while read; refused")
    return data


def read_text_inside(path: str | Path, root: str | Path, limit: int = MAX_BYTES) -> str:
    """`read_inside` as UTF-8 text (`ReadRefused` naming the file and the byte otherwise)."""
    data = read_inside(path, root, limit)
    try:
        return data.decode("utf-8")
    except UnicodeDecodeError as exc:
        raise ReadRefused(f"{path}: not UTF-8 ({exc.reason} at byte {exc.start})") from None


def _open_no_link(path: Path, root: Path | None, link_ok: bool = False) -> int:
    """A non-blocking descriptor of ``path``, its own name never followed as a link (``link_ok``: a path the user
    named may be one); given ``root``, every folder from the root down to it reached without a link
    (`corelib.nolinks.open_folder`)."""
    from corelib.atomic import LinkRefused

    flags = os.O_RDONLY | os.O_NONBLOCK | (0 if link_ok else os.O_NOFOLLOW)
    dfd = None
    if root is not None:
        from corelib.nolinks import open_folder

        try:
            dfd = open_folder(root, path.parent)
        except LinkRefused as exc:
            raise ReadRefused(f"{path}: {exc.filename} is a symbolic link; a folder's own files are read only "
                              "without following one") from None
        except FileNotFoundError:
            raise FileMissing(f"{path}: no such file") from None
        except (OSError, ValueError) as exc:
            raise ReadRefused(f"{path}: not readable ({getattr(exc, 'strerror', None) or exc})") from None
    try:
        return os.open(path.name if dfd is not None else path, flags, dir_fd=dfd)
    except FileNotFoundError:
        raise FileMissing(f"{path}: no such file") from None
    except OSError as exc:
        if exc.errno == errno.ELOOP:
            raise ReadRefused(f"{path}: is a symbolic link; a file the project wrote is read only as itself, "
                              "never through a link") from None
        raise ReadRefused(f"{path}: not readable ({exc.strerror or exc})") from None
    finally:
        if dfd is not None:
            os.close(dfd)


def open_file(path: str | Path, root: str | Path | None = None, kind: str = "record", link_ok: bool = False):
    """The regular file ``path`` open for reading in binary (the module's rule: no link unless ``link_ok``,
    non-blocking, at most ``LIMITS[kind]`` bytes by its size), for a reader that streams it (a hash, a
    checkpoint); `FileMissing` when there is none, `ReadRefused` naming it otherwise. The caller closes it."""
    path = Path(path)
    limit = LIMITS[kind]
    f = os.fdopen(_open_no_link(path, Path(root) if root is not None else None, link_ok), "rb")
    try:
        st = os.fstat(f.fileno())
        if not stat.S_ISREG(st.st_mode):
            raise ReadRefused(f"{path}: is {_kind(st.st_mode)}, not a regular file; refused without reading it")
        if st.st_size > limit:
            raise ReadRefused(f"{path}: {st.st_size} bytes, more than a {kind} may hold ({limit}); refused unread")
        os.set_blocking(f.fileno(), True)  # a regular file: blocking reads from here on
        return f
    except BaseException:
        f.close()
        raise


def read_file(path: str | Path, root: str | Path | None = None, kind: str = "record", link_ok: bool = False) -> bytes:
    """The bytes of the regular file ``path`` (`open_file`'s rule, read in chunks as large as the file);
    `FileMissing` when there is none, `ReadRefused` naming it otherwise."""
    path = Path(path)
    limit = LIMITS[kind]
    with open_file(path, root, kind, link_ok) as f:
        return _bounded_bytes(f, path, limit)


def read_text_file(path: str | Path, root: str | Path | None = None, kind: str = "page",
                   link_ok: bool = False) -> str:
    """`read_file` as UTF-8 text (`ReadRefused` naming the file and the byte otherwise)."""
    data = read_file(path, root, kind, link_ok)
    try:
        return data.decode("utf-8")
    except UnicodeDecodeError as exc:
        raise ReadRefused(f"{path}: not UTF-8 ({exc.reason} at byte {exc.start})") from None


def read_json_file(path: str | Path, root: str | Path | None = None, kind: str = "record", link_ok: bool = False):
    """The JSON value of `read_file`'s bytes; `ReadRefused` naming the file for bytes that are not UTF-8 JSON
    (NaN and Infinity are read, as the sweep writes them)."""
    return decode_json(read_file(path, root, kind, link_ok), path, ReadRefused)


def decode_json(data: bytes, path, error: type[Exception]):
    """The JSON value of ``data`` read from ``path``; ``error`` naming the file for bytes that are not UTF-8 JSON
    (NaN and Infinity are read), the one decoder of the readers of JSON files (`read_json_file`,
    `synth.files.read_json`)."""
    try:
        return json.loads(data.decode("utf-8"))
    except UnicodeDecodeError as exc:
        raise error(f"{path}: not UTF-8 text (byte {exc.start}), so not valid JSON") from None
    except json.JSONDecodeError as exc:
        raise error(f"{path}: not valid JSON ({exc})") from None
    except RecursionError:
        raise error(f"{path}: JSON nested too deep") from None
