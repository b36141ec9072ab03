"""Files that are whole or absent: write to a temporary name beside the target, flush, fsync, rename.

A reader never sees a half-written file under the final name, whatever stops the writer (a
crash, Ctrl-C, a full disk). A writer never writes through a link: a symbolic link at the final name is
replaced by the file (the rename is onto the link itself, never onto what it points to), and a folder a
writer makes for its files (`make_folder`) is refused, in one line naming it, when it is a link
(`LinkRefused`). A full disk is reported as `DiskFullError`: one line that names
the file and says how to resume. Any other error of the operating system names the final file,
never the temporary one; `file_error_message` says it in one line (permission denied, read-only
file system, a name too long, ...). A name that is legal but too long for its temporary name
gets a shortened temporary name, so any file the file system can hold can be written.

The temporary file of a writer killed with SIGKILL stays behind; `remove_stale_temps` (called when
a command locks its output folder, `corelib.rundir.lock_folder`, or checks its output file,
`corelib.rundir.check_output_file`) removes those of processes that no longer run.

Example::

    atomic_write_bytes(path, png_bytes)
    with atomic_path(path) as tmp:      # for libraries that write to a file name themselves
        exr.write(str(tmp))
    with atomic_pipe(path) as name:     # for libraries that write from their own threads and hang on an
        rec.save(name); ...; rec.disconnect()   # error of theirs (Rerun's file sink on a full disk)
"""
from __future__ import annotations

import errno
import hashlib
import json
import os
import re
import threading
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


#: errors of the operating system that a user's input causes (a path, a folder's permissions or mount):
#: reported in one line naming the file, exit code 2 (`corelib.exitcodes.USAGE`), no traceback
USER_ERRNOS = {errno.EACCES: "permission denied", errno.EPERM: "operation not permitted",
               errno.EROFS: "read-only file system", errno.ENAMETOOLONG: "file name too long",
               errno.ENOTDIR: "a part of the path is a file, not a folder", errno.EISDIR: "is a folder",
               errno.ELOOP: "too many levels of symbolic links", errno.ENOENT: "no such file or folder",
               errno.EEXIST: "already exists"}


@contextmanager
def naming(path: str | Path) -> Iterator[None]:
    """Give an OSError raised in the block without a file name (a ``write`` or ``flush`` on an open file
    object: ENOSPC, EIO) the name `path`, so that its one line names the file."""
    try:
        yield
    except OSError as exc:
        if exc.filename is not None or exc.errno is None:
            raise
        if is_disk_full(exc):
            raise DiskFullError(path) from None
        raise OSError(exc.errno, exc.strerror, str(path)) from None


class LinkRefused(OSError):
    """A folder a writer would write into is a symbolic link: nothing is written through it."""

    def __init__(self, path: str | Path):
        super().__init__(errno.ELOOP, "is a symbolic link", str(path))

    def __reduce__(self):
        return (LinkRefused, (self.filename,))

    def __str__(self) -> str:
        return (f"{self.filename} is a symbolic link; nothing is written through a link: remove the link (or "
                "use another output folder) and run the command again")


def make_folder(folder: str | Path) -> Path:
    """Create ``folder`` (and its parents) for a writer's files; `LinkRefused` when ``folder`` itself is a
    symbolic link (to a folder or not), so its files never land where the link points."""
    folder = Path(folder)
    if folder.is_symlink():
        raise LinkRefused(folder)
    folder.mkdir(parents=True, exist_ok=True)
    if folder.is_symlink():  # made a link between the two
        raise LinkRefused(folder)
    return folder


def is_user_file_error(exc: BaseException) -> bool:
    """An OSError a user can cause (`USER_ERRNOS`): permissions, a read-only mount, a name too long, ..."""
    return isinstance(exc, OSError) and not is_disk_full(exc) and exc.errno in USER_ERRNOS


def file_error_message(exc: OSError) -> str:
    """One line for a `is_user_file_error` error: the file (both, for a rename) and what the OS said."""
    if isinstance(exc, LinkRefused):
        return str(exc)
    what = USER_ERRNOS.get(exc.errno, exc.strerror or type(exc).__name__)
    names = [str(n) for n in (exc.filename, exc.filename2) if n is not None]
    where = " -> ".join(names) if names else "(the operating system named no file)"
    if exc.errno == errno.ENAMETOOLONG:
        what += f" (this file system allows {_name_max(Path(names[-1]).parent) if names else 255} bytes per name)"
    elif exc.errno in (errno.EACCES, errno.EPERM, errno.EROFS):
        what += ": choose a folder you can write (or read), or change its permissions"
    return f"{where}: {what}"


def _name_max(folder: Path) -> int:
    """The longest file name (bytes) in `folder`'s file system (its nearest existing parent's)."""
    for f in (folder, *folder.parents):
        try:
            return int(os.pathconf(f, "PC_NAME_MAX"))
        except (OSError, ValueError):
            continue
    return 255


_TMP_RE = re.compile(r"^\..+\.tmp(\d+)$")


def _tmp_name(path: Path) -> Path:
    """``.NAME.tmpPID`` beside `path`; when that is longer than the file system allows, a shortened
    ``.PREFIX~HASH.tmpPID`` (a legal NAME stays writable)."""
    name = f".{path.name}.tmp{os.getpid()}"
    if len(os.fsencode(name)) <= 143 or len(os.fsencode(name)) <= _name_max(path.parent):
        return path.with_name(name)
    digest = hashlib.sha256(os.fsencode(path.name)).hexdigest()[:16]
    prefix = os.fsencode(path.name)[:64].decode("utf-8", "ignore")
    return path.with_name(f".{prefix}~{digest}.tmp{os.getpid()}")


def _pid_alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except OSError:  # another user's process (EPERM): alive
        return True
    return True


def remove_stale_temps(folder: str | Path, recursive: bool = True, name: str | None = None) -> list[Path]:
    """Remove the temporary files (``.NAME.tmpPID``) that writers killed with SIGKILL left in `folder` (and
    below, if `recursive`; only those of ``name``, if given): files whose process no longer runs. A live
    writer's are kept. Returns what was removed."""
    folder = Path(folder)
    removed: list[Path] = []
    stack = [folder]
    while stack:
        try:
            entries = list(os.scandir(stack.pop()))
        except OSError:
            continue
        for e in entries:
            if recursive and e.is_dir(follow_symlinks=False):
                stack.append(Path(e.path))
                continue
            m = _TMP_RE.match(e.name)
            if (m is None or not e.is_file(follow_symlinks=False)
                    or (name is not None and not e.name.startswith(f".{name}.tmp"))):
                continue
            pid = int(m.group(1))
            if pid != os.getpid() and not _pid_alive(pid):
                try:
                    os.unlink(e.path)
                    removed.append(Path(e.path))
                except OSError:
                    pass
    return removed


def check_writable(path: str | Path) -> None:
    """Raise, before any work, the OSError that writing `path` atomically would raise: a name longer than
    the file system allows, a part of the path that is a file, a folder that cannot be written (read-only
    file system, permissions). Nothing is left behind; folders that do not exist yet are not created."""
    path = Path(path)
    missing = [path.name]
    folder = path.parent
    while not (folder.exists() or folder.is_symlink()) and folder != folder.parent:
        missing.append(folder.name)
        folder = folder.parent
    limit = _name_max(folder)
    for part in missing:
        if len(os.fsencode(part)) > limit:
            raise OSError(errno.ENAMETOOLONG, os.strerror(errno.ENAMETOOLONG), str(path))
    if not folder.is_dir():
        raise OSError(errno.ENOTDIR, os.strerror(errno.ENOTDIR), str(folder))
    probe = folder / f".mcdp-write-probe.tmp{os.getpid()}"
    try:
        os.close(os.open(probe, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o600))
        os.unlink(probe)
    except FileExistsError:
        pass
    except OSError as exc:
        raise OSError(exc.errno, exc.strerror, str(path if folder == path.parent else folder)) from None


def _fsync(path: Path) -> None:
    fd = os.open(path, os.O_RDONLY)
    try:
        os.fsync(fd)
    finally:
        os.close(fd)


@contextmanager
def atomic_path(path: str | Path, fsync: bool = True) -> Iterator[Path]:
    """Yield a temporary path beside `path`; on success it is fsynced and renamed onto `path` (a symbolic link
    there is replaced, never written through), on any error it is removed (ENOSPC raised as `DiskFullError`
    naming `path`)."""
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
        except OSError:
            pass
        if is_disk_full(exc) and not isinstance(exc, DiskFullError):
            raise DiskFullError(path) from None
        if isinstance(exc, OSError) and exc.errno is not None and str(tmp) in (exc.filename, exc.filename2):
            raise OSError(exc.errno, exc.strerror, str(path)) from None  # the user's name, not the temporary one
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


def atomic_write_at(dir_fd: int, name: str, data: bytes, path: str | Path, fsync: bool = True) -> None:
    """`atomic_write_bytes` of the file ``name`` in the open folder ``dir_fd`` (`corelib.nolinks.open_folder`:
    reached without a link), its temporary file made there too (``O_EXCL | O_NOFOLLOW``); ``path`` is the
    file's name in messages (`DiskFullError`, an OSError)."""
    tmp = _tmp_name(Path(path)).name
    try:
        fd = os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_EXCL | os.O_NOFOLLOW, 0o666, dir_fd=dir_fd)
        with open(fd, "wb") as f:
            f.write(data)
            f.flush()
            if fsync:
                os.fsync(f.fileno())
        os.replace(tmp, name, src_dir_fd=dir_fd, dst_dir_fd=dir_fd)
    except BaseException as exc:
        try:
            os.unlink(tmp, dir_fd=dir_fd)
        except OSError:
            pass
        if is_disk_full(exc) and not isinstance(exc, DiskFullError):
            raise DiskFullError(path) from None
        if isinstance(exc, OSError) and exc.errno is not None:
            raise OSError(exc.errno, exc.strerror, str(path)) from None
        raise


@contextmanager
def atomic_pipe(path: str | Path, fsync: bool = True) -> Iterator[str]:
    """For a library that writes a file by name from a thread of its own and cannot report a failed write
    (Rerun's file sink: its flush and disconnect wait forever once a write failed, e.g. on a full disk):
    yields a name (``/dev/fd/N``, the write end of a pipe) to hand it. A thread of ours copies what arrives
    into `atomic_path`'s temporary file beside `path`; after a failed write it goes on reading (and
    dropping) the stream, so the library never blocks nor sees an error. The library must have closed the
    name when the block ends (Rerun: ``disconnect``); then the copy's error is raised (a full disk as
    `DiskFullError` naming `path`) and the temporary removed, or the file renamed onto `path` when whole."""
    with atomic_path(path, fsync=False) as tmp:
        r, w = os.pipe()
        failed: list[BaseException] = []

        def copy() -> None:
            try:
                dst = open(tmp, "wb")
            except BaseException as exc:  # noqa: BLE001 (raised below, in the caller's thread)
                failed.append(exc)
                dst = None
            try:
                while chunk := os.read(r, 1 << 20):
                    if dst is not None and not failed:
                        try:
                            dst.write(chunk)
                        except BaseException as exc:  # noqa: BLE001
                            failed.append(exc)
                if dst is not None and not failed:
                    dst.flush()
                    if fsync:
                        os.fsync(dst.fileno())
            except BaseException as exc:  # noqa: BLE001
                failed.append(exc)
            finally:
                os.close(r)
                if dst is not None:
                    try:
                        dst.close()
                    except BaseException as exc:  # noqa: BLE001
                        failed.append(exc)

        copier = threading.Thread(target=copy, name=f"atomic_pipe {path}", daemon=True)
        copier.start()
        try:
            yield f"/dev/fd/{w}"
        finally:
            os.close(w)  # the library's own copy of the write end is closed: end of the stream
            copier.join()
        if failed:
            exc = failed[0]
            if isinstance(exc, OSError) and exc.filename is None and exc.errno is not None:
                raise OSError(exc.errno, exc.strerror, str(tmp)) from None  # atomic_path names `path`
            raise exc
