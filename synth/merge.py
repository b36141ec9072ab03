"""Merge shard folders rendered with one config into one dataset, copying only a shard's own files.

A shard is untrusted input like any dataset: every folder and file that the merge copies (``rig.json``,
``masks/*.png``, each complete sequence folder) is checked before anything is written, and each must
be the shard's own: a symbolic link (to a file or a folder, inside or outside the shard) or a file
that is not a regular file (a FIFO, a device) is refused with one line naming it (`DatasetError`,
exit 2) and the output is left untouched. The copy itself opens every file with ``O_NOFOLLOW`` and
checks it is still a regular file, so a link put in place after the check is refused too; a
sequence is copied into ``<seq>.partial/`` and renamed when whole.

Example::

    merge_datasets([Path("shard0"), Path("shard1")], Path("data/full"))   # synth merge --out data/full shard0 shard1
"""
from __future__ import annotations

import os
import shutil
import stat
from pathlib import Path

from corelib.atomic import atomic_path
from corelib.configlib import build_config
from corelib.rundir import lock_folder
from synth.config import DataConfig
from synth.files import DatasetError, OutputFolderError, read_json
from synth.render import MARKER_DIR, complete_sequences, finalize, make_rig, prepare_output, sequence_id

_COPY_CHUNK = 1 << 20


def _own(p: Path, folder: bool = False) -> None:
    """`p` is a plain folder (`folder`) or regular file of the shard itself, never a link; else DatasetError."""
    try:
        st = os.lstat(p)
    except OSError as exc:
        raise DatasetError(f"{p}: missing or not readable ({exc.strerror or exc})") from None
    if stat.S_ISLNK(st.st_mode):
        raise DatasetError(f"{p}: is a symbolic link (to {os.readlink(p)[:200]}); merge copies only a shard's own "
                           "files, never through a link")
    ok = stat.S_ISDIR(st.st_mode) if folder else stat.S_ISREG(st.st_mode)
    if not ok:
        raise DatasetError(f"{p}: is not a {'folder' if folder else 'regular file'}; merge copies only a shard's "
                           "regular files and folders")


def _own_tree(top: Path) -> list[Path]:
    """The files under the shard folder `top` (relative to it), every folder and file checked by `_own`."""
    _own(top, folder=True)
    files = []
    for dirpath, dirnames, filenames in os.walk(top, followlinks=False):
        d = Path(dirpath)
        for name in sorted(dirnames):  # os.walk lists a link to a folder among the folders
            _own(d / name, folder=True)
        for name in sorted(filenames):
            _own(d / name)
            files.append((d / name).relative_to(top))
    return files


def _copy_own(src: Path, dst: Path) -> None:
    """Copy the regular file `src` (opened without following a link) to `dst`."""
    try:
        fd = os.open(src, os.O_RDONLY | os.O_NOFOLLOW | os.O_NONBLOCK)
    except OSError as exc:
        raise DatasetError(f"{src}: is a symbolic link or not readable ({exc.strerror or exc}); merge copies only "
                           "a shard's own files") from None
    with os.fdopen(fd, "rb") as f:
        if not stat.S_ISREG(os.fstat(f.fileno()).st_mode):
            raise DatasetError(f"{src}: is not a regular file; merge copies only a shard's regular files")
        with open(dst, "wb") as g:
            shutil.copyfileobj(f, g, _COPY_CHUNK)


def _copy_whole(src: Path, dst: Path) -> None:
    """A shard's file copied whole or not at all (a temporary name, then a rename)."""
    with atomic_path(dst) as tmp:
        _copy_own(src, tmp)


def _plan(src: Path, n: int) -> dict:
    """What merge copies from shard `src`, every file checked (`_own`) before anything is written."""
    _own(src / "rig.json")
    masks = []
    if (src / "masks").exists() or (src / "masks").is_symlink():
        _own(src / "masks", folder=True)
        masks = sorted(m for m in (src / "masks").iterdir() if m.suffix == ".png")
        for m in masks:
            _own(m)
    seqs = {i: _own_tree(src / sequence_id(i)) for i in complete_sequences(src, n)}
    return {"masks": masks, "sequences": seqs}


def merge_datasets(cfg_sources: list[Path], out: Path) -> dict:
    """Merge shard folders (same config) into `out` and write the manifest when complete."""
    if not cfg_sources:
        raise ValueError("merge needs at least one shard folder")
    first = read_json(cfg_sources[0] / MARKER_DIR / "config.json")
    cfg = build_config(DataConfig, first["config"], str(cfg_sources[0]))
    for src in cfg_sources[1:]:
        other = read_json(src / MARKER_DIR / "config.json")
        if other["config_hash"] != first["config_hash"]:
            raise OutputFolderError(f"shard {src} was rendered with another config than {cfg_sources[0]}")
    plans = [(src, _plan(src, cfg.dataset.sequences)) for src in cfg_sources]  # before anything is written
    prepare_output(cfg, out)
    lock = lock_folder(out, f"{MARKER_DIR}/lock")  # one writer per folder
    try:
        rig = make_rig(cfg)
        for src, plan in plans:
            if not (out / "rig.json").is_file():
                _copy_whole(src / "rig.json", out / "rig.json")
            (out / "masks").mkdir(exist_ok=True)
            for m in plan["masks"]:
                if not (out / "masks" / m.name).is_file():
                    _copy_whole(m, out / "masks" / m.name)
            for i, files in plan["sequences"].items():
                _copy_sequence(src / sequence_id(i), files, out, sequence_id(i))
        manifest = finalize(cfg, out, rig)
    finally:
        lock.release()
    done = set(complete_sequences(out, cfg.dataset.sequences))
    return {"complete": manifest is not None, "sequences": len(done), "expected": cfg.dataset.sequences,
            "missing": [sequence_id(i) for i in range(cfg.dataset.sequences) if i not in done]}


def merge_statement(res: dict, out: Path) -> str:
    """One line on what `merge_datasets` returned (``res``): the dataset is complete, or which sequences it lacks."""
    if res["complete"]:
        return f"synth merge: {out}: complete, {res['sequences']} sequences; manifest written"
    from synth.dataset import short_list

    return (f"synth merge: {out}: incomplete, {res['sequences']} of {res['expected']} sequences; missing "
            f"{short_list(res['missing'])}: merge the shards that hold them (synth render --shard K/N) into it; "
            "no manifest yet")


def _copy_sequence(src: Path, files: list[Path], out: Path, name: str) -> None:
    """The sequence folder `src` copied into ``<name>.partial`` and renamed to `name` when whole."""
    dst = out / name
    if dst.exists():
        return
    tmp = out / f"{name}.partial"
    if tmp.exists():
        shutil.rmtree(tmp)
    try:
        for rel in files:
            (tmp / rel).parent.mkdir(parents=True, exist_ok=True)
            _copy_own(src / rel, tmp / rel)
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise
    os.sync()  # the copy on disk before the rename seals it
    os.replace(tmp, dst)
