"""Folders inside a root folder, reached without following a symbolic link anywhere below the root.

``O_NOFOLLOW`` guards the last component of a path only: ``SWEEP/runs/overlap_0.50/mono2_s0/checkpoints``
opened with it still goes through a link at ``runs/`` or ``overlap_0.50/`` to a folder outside the sweep.
`open_folder` walks every component from the root, each opened relative to the one before (``dir_fd``)
with ``O_NOFOLLOW | O_DIRECTORY``, so what is written or deleted through its descriptor lies in the root's
own tree; a link on the way is refused (`corelib.atomic.LinkRefused`, naming it). The root itself may be a
link: the user named it. `linked_part` says which component is a link, for a caller that treats such a
folder as read only; `write_json_in` writes a record whole (`corelib.atomic.atomic_write_at`) the same way.

Example::

    fd = open_folder(sweep, "runs/overlap_0.50/mono2_s0/checkpoints")   # LinkRefused: SWEEP/runs is a link
    try:
        os.unlink("best.pt", dir_fd=fd)
    finally:
        os.close(fd)
"""
from __future__ import annotations

import errno
import json
import os
import stat
from pathlib import Path

from corelib.atomic import LinkRefused, atomic_write_at

_FLAGS = os.O_RDONLY | os.O_DIRECTORY | os.O_NOFOLLOW


def _parts(root: Path, path: str | Path) -> tuple[str, ...]:
    """The components of ``path`` below ``root`` (``path`` absolute under root, or relative to it)."""
    path = Path(path)
    try:
        rel = path.relative_to(root)
    except ValueError:
        rel = path  # relative to the root
    if rel.is_absolute() or ".." in rel.parts:
        raise ValueError(f"{path} is not inside {root}")
    return rel.parts


def open_folder(root: str | Path, path: str | Path, create: bool = False) -> int:
    """A descriptor (``O_RDONLY``) of the folder ``path`` (below ``root``, or relative to it), every component
    opened without following a link. `LinkRefused` names the first component that is a link;
    FileNotFoundError names the first that is missing, unless ``create`` (then it is made, mode 0o777)."""
    root = Path(root)
    fd = os.open(root, os.O_RDONLY | os.O_DIRECTORY)
    where = root
    try:
        for part in _parts(root, path):
            where = where / part
            try:
                nxt = os.open(part, _FLAGS, dir_fd=fd)
            except FileNotFoundError:
                if not create:
                    raise FileNotFoundError(errno.ENOENT, os.strerror(errno.ENOENT), str(where)) from None
                try:
                    os.mkdir(part, dir_fd=fd)
                except FileExistsError:
                    pass  # made between the two, or a dangling link: the open below says which
                nxt = _open_part(fd, part, where)
            except OSError as exc:
                nxt = _refused(fd, part, where, exc)
            os.close(fd)
            fd = nxt
        return fd
    except BaseException:
        os.close(fd)
        raise


def _open_part(fd: int, part: str, where: Path) -> int:
    try:
        return os.open(part, _FLAGS, dir_fd=fd)
    except OSError as exc:
        return _refused(fd, part, where, exc)


def _refused(fd: int, part: str, where: Path, exc: OSError) -> int:
    """Raise for a component that did not open as a folder: `LinkRefused` for a link, else the OSError
    naming ``where``."""
    try:
        is_link = stat.S_ISLNK(os.stat(part, dir_fd=fd, follow_symlinks=False).st_mode)
    except OSError:
        is_link = False
    if is_link:
        raise LinkRefused(where) from None
    raise OSError(exc.errno, exc.strerror, str(where)) from None


def linked_part(root: str | Path, path: str | Path) -> Path | None:
    """The first component of ``path`` below ``root`` that is a symbolic link (``root``/...), None when there
    is none (a component that does not exist ends the search: what is made below it is the root's own)."""
    root = Path(root)
    where = root
    for part in _parts(root, path):
        where = where / part
        try:
            if stat.S_ISLNK(os.lstat(where).st_mode):
                return where
        except FileNotFoundError:
            return None
    return None


def write_json_in(root: str | Path, path: str | Path, obj, **dumps) -> None:
    """Write ``obj`` as JSON (``indent=1`` unless given) to the file ``path`` below ``root``, whole or not at all,
    its folders reached (and made) without following a link (`open_folder`; `LinkRefused` names a link)."""
    root = Path(root)
    full = root.joinpath(*_parts(root, path))  # ``path`` under the root as given (sweeps/x/runs/...), or relative to it
    dumps.setdefault("indent", 1)
    fd = open_folder(root, full.parent, create=True)
    try:
        atomic_write_at(fd, full.name, json.dumps(obj, **dumps).encode("utf-8"), full)
    finally:
        os.close(fd)
