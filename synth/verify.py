"""What `synth verify` checks of a rendered dataset, beyond what every reader checks on open (`synth.dataset`):
every file's sha256 against the manifest, each image's size from its header, every expected frame and label
file listed, every object id of an instance map in its sequence's instances.json, and the manifest and rig.json
against the integrity record written with them.

Example::

    problems = verify_dataset("data/tiny")     # [] when the dataset is whole
"""
from __future__ import annotations

from pathlib import Path
from typing import Iterable

from corelib.hashing import changed_sections, json_sha256, section_digests, sha256_file
from synth.dataset import (INTEGRITY, MANIFEST, SCHEMA_VERSION, short_list, check_manifest_keys,
                           check_manifest_names, check_rig, rgb_suffix)
from synth.files import MAX_READ_BYTES, DatasetError, frame_stem, read_json, regular_file, within
from synth.label_kinds import expected_files, label_kinds
from synth.sizes import camera_sizes, size_problems

_MANIFEST_DEPTH, _RIG_DEPTH = 2, 3  # "splits.train", "sequences.seq_0003"; "cameras[CAM_FRONT].K"


def integrity_record(manifest: dict, rig: dict) -> dict:
    """What `verify` checks the manifest and rig.json against: per-section sha256 of both (so a
    change is named, e.g. ``splits.test`` or ``cameras[CAM_BACK].K``) and of the whole manifest."""
    body = {k: v for k, v in manifest.items() if k != INTEGRITY}
    return {"algorithm": "sha256 of canonical JSON (sorted keys, no spaces)",
            "manifest_sha256": json_sha256(body),
            "manifest_sections": section_digests(body, _MANIFEST_DEPTH),
            "rig_sections": section_digests(rig, _RIG_DEPTH)}


def integrity_problems(root: Path, manifest: dict) -> list[str]:
    """The manifest's and rig.json's content against the integrity record written with them."""
    mpath = root / MANIFEST
    rec = manifest.get(INTEGRITY)
    if not isinstance(rec, dict) or not isinstance(rec.get("manifest_sections"), dict):
        return [f"{mpath}: no integrity record (written by an older mcdp-synth); its content cannot be "
                "checked: render the dataset again"]
    problems = []
    body = {k: v for k, v in manifest.items() if k != INTEGRITY}
    changed = changed_sections(rec["manifest_sections"], section_digests(body, _MANIFEST_DEPTH))
    if changed:
        problems.append(f"{mpath}: changed since the render: {short_list(changed)}")
    elif json_sha256(body) != rec.get("manifest_sha256"):
        problems.append(f"{mpath}: content hash does not match its integrity record (the record was edited)")
    try:
        rig = read_json(within(root, root / "rig.json", "", "dataset root", "is a link to"))
    except DatasetError as exc:
        return problems + [str(exc)]
    try:
        check_rig(rig, manifest, root / "rig.json")
    except DatasetError as exc:
        problems.append(str(exc))
    changed = changed_sections(rec.get("rig_sections") or {}, section_digests(rig, _RIG_DEPTH))
    if changed:
        problems.append(f"{root / 'rig.json'}: changed since the render: {short_list(changed)}")
    return problems


def verify_dataset(root: str | Path, progress: bool = False) -> list[str]:
    """Every problem found (missing, truncated or altered file, unknown schema); [] when the dataset is whole."""
    root = Path(root)
    mpath = root / MANIFEST
    if not mpath.is_file():
        from synth.nuscenes.tables import is_nuscenes_root

        if is_nuscenes_root(root):
            return [f"{mpath}: missing: {root} is a nuScenes dataroot, not a synth dataset (synth verify checks it as "
                    "one: synth.verify.verify_nuscenes)"]
        return [f"{mpath}: missing"]
    try:
        manifest = read_json(within(root, mpath, "", "dataset root", "is a link to"))  # never through a link out
    except DatasetError as exc:
        return [str(exc)]
    ver = manifest.get("schema_version") if isinstance(manifest, dict) else None
    if ver != SCHEMA_VERSION:
        return [f"{mpath}: schema_version {repr(ver)[:40]} is not {SCHEMA_VERSION}"]
    try:
        check_manifest_keys(manifest, mpath)
        check_manifest_names(root, manifest, mpath)
    except DatasetError as exc:
        return [str(exc)]
    problems = integrity_problems(root, manifest)
    files: dict[str, str] = manifest.get("files", {})
    items: Iterable = files.items()
    if progress:
        from corelib.progress import progress_bar
        items = progress_bar(items, total=len(files), desc="verify", unit="file")
    base = root.resolve()
    sizes = camera_sizes(manifest)
    for rel, digest in items:
        p = root / rel
        if not p.is_file():
            problems.append(_absent(p))
        elif not p.resolve().is_relative_to(base):
            problems.append(f"{p}: is a link to {p.resolve()}, outside the dataset root")
        elif p.stat().st_size > MAX_READ_BYTES:  # refused by its size, never read to be hashed
            problems.append(f"{p}: {p.stat().st_size} bytes, more than any dataset file may hold ({MAX_READ_BYTES} "
                            "bytes); not read")
        elif sha256_file(p) != digest:
            problems.append(f"{p}: checksum mismatch (truncated or altered)")
        else:
            problems += size_problems(p, rel, sizes)
    # every expected frame file is listed
    cams = manifest.get("cameras", [])
    kinds = (manifest.get("labels") or {}).get("kinds") or []
    for seq, info in manifest.get("sequences", {}).items():
        n = int(info["frames"])
        expected = expected_files(kinds, seq, None, None, n)  # a label kind's per-sequence files
        for cam in cams:
            for f in range(n):
                expected += [f"{seq}/{cam}/{frame_stem(f)}{s}" for s in (rgb_suffix(manifest), ".depth.exr")]
                expected += expected_files(kinds, seq, cam, f, n)
        problems += [f"{root / rel}: not listed in the manifest" for rel in expected if rel not in files]
    for kind in label_kinds():  # each held label kind's own checks (the object ids of the instance maps)
        if kind.name in kinds and kind.verify is not None:
            problems += kind.verify(root, manifest)
    return problems


def verify_nuscenes(root: str | Path) -> tuple[list[str], str]:
    """A nuScenes dataroot (`synth.nuscenes.tables.is_nuscenes_root`; it has no manifest or checksums): its tables
    load with this project's reader (`synth.nuscenes.read.open_nuscenes`: every record it reads, the cameras and
    splits) and every camera image of its frames is a regular file. Returns (problems, a summary of what was read)."""
    from synth.nuscenes.read import open_nuscenes

    try:
        ds = open_nuscenes(root)
    except DatasetError as exc:
        return [str(exc)], ""
    problems, n = [], 0
    for seq in ds.sequences:
        for cam in ds.camera_names:
            for f in range(ds.n_frames(seq)):
                p, n = ds.rgb_path(seq, cam, f), n + 1
                if not p.is_file():
                    problems.append(_absent(p))
    summary = (f"a nuScenes dataroot (version {ds.version}): its tables load with mcdp-synth's nuScenes reader; "
               f"{len(ds.sequences)} scenes, {n} camera images present; no checksums to verify (read it with "
               "synth info / synth view / mcdp train, eval --data)")
    return problems, summary


def _absent(p: Path) -> str:
    """Why `p`, a listed file that is not a regular file, is a problem: missing, or there but of another kind (a
    FIFO, a folder, ...: `synth.files.regular_file`'s words)."""
    if not p.exists():
        return f"{p}: missing"
    try:
        regular_file(p)
    except DatasetError as exc:
        return str(exc)
    return f"{p}: not readable"
