"""What a run wrote into RUN/checkpoints/, and the removal of only those files: the checkpoints' writer
(`write_checkpoint`: the file, whole, and its record) beside the reader of its record (`removable`).

Two records beside the checkpoints:

    RUN/checkpoints/written.json  {"files": {name: {"sha256", "bytes", "step"}}}: each checkpoint the run's
                                  trainer wrote, with the sha256 of the bytes it wrote (`record_written`)
    RUN/checkpoints/removed.json  {"files": {name: the latest removal}, "removals": [every removal, in order]}:
                                  append-only (`record_removed`); a rerun adds to it, never replaces an entry

`removable` is the rule of every clean-up (a sweep's ``keep_last`` / ``keep_best: false``, the pretraining's
trim): a file is deleted only when it is a regular file, reached without a symbolic link (neither
``checkpoints/`` nor the file may be a link, nor, given the ``root`` the run lies in (the sweep's folder), any
folder between the root and the run: `corelib.nolinks`), whose sha256 is the one the run recorded when it wrote
it. A file of the user's put under the same name, or a link, is kept, and the caller says so in one line; the
removal record is written through the same descriptor, so it never lands outside the root either.

Example::

    ok, kept = removable(run_dir, ["best.pt", "last.pt"], root=sweep)   # {name: bytes}, {name: why it is kept}
    record_removed(run_dir, {n: {"step": 2, "reason": "by ..."} for n in ok}, ok, root=sweep)
    unlink_checkpoints(run_dir, ok, root=sweep)
"""
from __future__ import annotations

import hashlib
import io
import json
import os
import stat
from pathlib import Path

from corelib.atomic import atomic_write_at, atomic_write_bytes, atomic_write_json

#: the record of the checkpoints deleted after use (`record_removed`)
REMOVED = "removed.json"
#: the record of the checkpoints the run's trainer wrote (`record_written`)
WRITTEN = "written.json"
#: the largest record read (bytes); it names a few files
_MAX_RECORD_BYTES = 1 << 20


class RecordError(ValueError):
    """A record in RUN/checkpoints/ that cannot be read or is not ours; the message names it."""


def _open_folder(run_dir: str | Path, root: str | Path | None = None) -> int:
    """A descriptor of RUN/checkpoints/, opened without following a link: neither checkpoints/ nor, given
    ``root``, any folder from ``root`` down to it (`corelib.nolinks.open_folder`: `LinkRefused` names the link;
    an OSError when checkpoints/ itself is one)."""
    if root is None:
        return os.open(Path(run_dir) / "checkpoints", os.O_RDONLY | os.O_DIRECTORY | os.O_NOFOLLOW)
    from corelib.nolinks import open_folder

    return open_folder(root, Path(run_dir) / "checkpoints")


def _read_at(fd: int, name: str, limit: int) -> bytes | None:
    """The bytes of the regular file ``name`` in the folder ``fd`` (never through a link, never blocking on a
    FIFO); None when there is no such file. RecordError for anything else, or a file over ``limit`` bytes."""
    try:
        f = os.open(name, os.O_RDONLY | os.O_NOFOLLOW | os.O_NONBLOCK, dir_fd=fd)
    except FileNotFoundError:
        return None
    except OSError as exc:
        raise RecordError(f"checkpoints/{name}: not a regular file reached without a link "
                          f"({exc.strerror or exc})") from None
    with os.fdopen(f, "rb") as fh:
        st = os.fstat(fh.fileno())
        if not stat.S_ISREG(st.st_mode):
            raise RecordError(f"checkpoints/{name}: not a regular file")
        if st.st_size > limit:
            raise RecordError(f"checkpoints/{name}: {st.st_size} bytes, more than such a file may hold ({limit})")
        return fh.read(limit + 1)


def _read_record(fd: int, name: str) -> dict:
    data = _read_at(fd, name, _MAX_RECORD_BYTES)
    if data is None:
        return {}
    try:
        rec = json.loads(data.decode("utf-8"))
    except (UnicodeDecodeError, ValueError, RecursionError):
        raise RecordError(f"checkpoints/{name}: not a JSON record") from None
    if not isinstance(rec, dict) or not isinstance(rec.get("files", {}), dict):
        raise RecordError(f"checkpoints/{name}: not a record of files (no 'files' table)")
    return rec


def _record(run_dir: str | Path, name: str) -> dict:
    fd = _open_folder(run_dir)
    try:
        return _read_record(fd, name)
    finally:
        os.close(fd)


# --------------------------------------------------------------------------- written
def record_written(run_dir: str | Path, name: str, sha256: str, nbytes: int, step: int) -> None:
    """Record that the run wrote checkpoints/``name`` with these bytes (after the checkpoint is in place: an
    interruption between the two leaves the older record, whose file is then kept, never deleted)."""
    try:
        rec = _record(run_dir, WRITTEN)
    except (OSError, RecordError):
        rec = {}  # unreadable or a link: written anew below (atomic_write_json replaces a link, never follows it)
    files = {k: v for k, v in (rec.get("files") or {}).items() if isinstance(v, dict)}
    files[name] = {"sha256": sha256, "bytes": int(nbytes), "step": int(step)}
    atomic_write_json(Path(run_dir) / "checkpoints" / WRITTEN, {"files": files})


# --------------------------------------------------------------------------- removable
def atomic_torch_save(obj, path: Path) -> tuple[str, int]:
    """torch.save to ``path.tmp`` then os.replace: a crash never leaves a half-written checkpoint.
    Returns (sha256, bytes) of what was written (`mcdp.checkpoint_files.record_written`)."""
    import torch

    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    buf = io.BytesIO()  # serialised in memory: a full disk then fails in one plain write, not inside torch
    torch.save(obj, buf)
    data = buf.getbuffer()
    atomic_write_bytes(path, data)
    return hashlib.sha256(data).hexdigest(), len(data)


def write_checkpoint(run_dir: str | Path, name: str, state: dict, step: int, weights_only: bool = False) -> Path:
    """Write ``RUN/checkpoints/<name>`` whole (`atomic_torch_save`) and record its sha256 (`record_written`: a
    clean-up deletes only such files); ``weights_only`` drops the optimiser, scaler and RNG states (best.pt)."""
    path = Path(run_dir) / "checkpoints" / name
    if weights_only:
        state = {k: v for k, v in state.items() if k not in ("optimizer", "scaler", "torch_rng")}
    record_written(run_dir, name, *atomic_torch_save(state, path), step)
    return path


def _sha256_at(fd: int, name: str) -> tuple[str, int] | str:
    """(sha256, bytes) of the regular file ``name`` in ``fd`` opened without following a link; a reason otherwise."""
    try:
        st = os.stat(name, dir_fd=fd, follow_symlinks=False)
    except FileNotFoundError:
        return "not there"
    if stat.S_ISLNK(st.st_mode):
        return "a symbolic link (never followed to delete)"
    if not stat.S_ISREG(st.st_mode):
        return "not a regular file"
    try:
        f = os.open(name, os.O_RDONLY | os.O_NOFOLLOW | os.O_NONBLOCK, dir_fd=fd)
    except OSError as exc:
        return f"not readable ({exc.strerror or exc})"
    h, n = hashlib.sha256(), 0
    with os.fdopen(f, "rb") as fh:
        if not stat.S_ISREG(os.fstat(fh.fileno()).st_mode):
            return "not a regular file"
        while chunk := fh.read(1 << 20):
            h.update(chunk)
            n += len(chunk)
    return h.hexdigest(), n


def removable(run_dir: str | Path, names, root: str | Path | None = None) -> tuple[dict[str, int], dict[str, str]]:
    """({name: bytes} of the ``names`` that may be deleted (module docstring), {name: why it is kept}) for
    the files of ``names`` present in RUN/checkpoints/ (a name that is not there is in neither); with ``root``,
    none when a folder between ``root`` and RUN/checkpoints/ is a link (each kept, the reason naming it)."""
    from corelib.atomic import LinkRefused

    try:
        fd = _open_folder(run_dir, root)
    except FileNotFoundError:
        return {}, {}
    except LinkRefused as exc:
        return {}, {n: f"{exc.filename} is a symbolic link: nothing is deleted through it" for n in names}
    except OSError as exc:
        why = "a symbolic link" if Path(run_dir, "checkpoints").is_symlink() else (exc.strerror or str(exc))
        return {}, {n: f"checkpoints/ is {why}: nothing is deleted through it" for n in names}
    try:
        try:
            written = _read_record(fd, WRITTEN).get("files") or {}
            _read_record(fd, REMOVED)  # an unreadable removal record is never replaced: nothing is removed
        except RecordError as exc:
            return {}, {n: str(exc) for n in names}
        ok, kept = {}, {}
        for n in names:
            got = _sha256_at(fd, n)
            if got == "not there":
                continue
            if isinstance(got, str):
                kept[n] = got
            elif not isinstance(written.get(n), dict) or written[n].get("sha256") != got[0]:
                kept[n] = (f"its sha256 is not the one this run recorded when it wrote checkpoints/{n} "
                           f"({WRITTEN}): not the run's file")
            else:
                ok[n] = got[1]
        return ok, kept
    finally:
        os.close(fd)


def kept_line(kept: dict[str, str]) -> str:
    """The one log line of the files a clean-up left where they are."""
    return "kept " + "; ".join(f"checkpoints/{n}: {why}" for n, why in kept.items())


def unlink_checkpoints(run_dir: str | Path, names, root: str | Path | None = None) -> None:
    """Delete RUN/checkpoints/``names`` (checked by `removable`), through a descriptor of the folder opened
    without following a link (from ``root``, when given)."""
    fd = _open_folder(run_dir, root)
    try:
        for n in names:
            st = os.stat(n, dir_fd=fd, follow_symlinks=False)
            if stat.S_ISREG(st.st_mode):
                os.unlink(n, dir_fd=fd)
    finally:
        os.close(fd)


# --------------------------------------------------------------------------- removed
def removed_checkpoints(run_dir: str | Path) -> dict[str, dict]:
    """{file name: {"step", "bytes", "reason"}} of the checkpoints recorded as removed from ``run_dir``
    (`record_removed`, the latest removal of each name); {} when none is or the record is unreadable."""
    try:
        files = _record(run_dir, REMOVED).get("files") or {}
    except (OSError, RecordError):
        return {}
    return {k: v for k, v in files.items() if isinstance(v, dict)}


def record_removed(run_dir: str | Path, files: dict[str, dict], sizes: dict[str, int],
                   root: str | Path | None = None) -> None:
    """Append ``files`` ({name: {"step": int | None, "reason": the end of a sentence, "by ... once ..."}}), with
    their ``sizes``, to RUN/checkpoints/removed.json before the caller deletes them: an interruption between
    the two leaves a file that is still there, never a folder that looks whole without it. Every earlier
    entry is kept (a record of an older layout, ``files`` only, becomes the first ``removals``). Read and
    written through one descriptor of RUN/checkpoints/ (from ``root``, when given: never through a link)."""
    fd = _open_folder(run_dir, root)  # OSError (LinkRefused): the caller has not deleted anything
    try:
        rec = _read_record(fd, REMOVED)  # RecordError: likewise
        old = {k: v for k, v in (rec.get("files") or {}).items() if isinstance(v, dict)}
        removals = rec.get("removals")
        removals = list(removals) if isinstance(removals, list) else [{"file": k, **v} for k, v in old.items()]
        for name, info in files.items():
            entry = {"step": info.get("step"), "bytes": sizes.get(name), "reason": info.get("reason")}
            old[name] = entry
            removals.append({"file": name, **entry})
        atomic_write_at(fd, REMOVED, json.dumps({"files": old, "removals": removals}, indent=1).encode("utf-8"),
                        Path(run_dir) / "checkpoints" / REMOVED)
    finally:
        os.close(fd)
