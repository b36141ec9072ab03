"""Dataset contract v1: file I/O, the reader used by `mcdp`, and `verify`.

Layout (docs/DATASET.md)::

    <dataset>/
      manifest.json          written LAST (schema_version, generator version, resolved config,
                             seed, cameras, image size, fps, splits, overlap, sha256 of every file)
      rig.json               cameras [{name, width, height, K, T_ego_cam, hfov_deg, yaw_deg}], neighbours
      masks/<CAM>.png        uint8, 255 = scene, 0 = ego body
      <seq>/ego.json         per frame: timestamp_s, T_world_ego (4x4), lighting
      <seq>/<CAM>/<frame:06d>.png         RGB uint8 sRGB
      <seq>/<CAM>/<frame:06d>.depth.exr   float32 z-depth in metres (channel "Z"), 0 = no surface

A sequence is written into ``<seq>.partial/`` and renamed to ``<seq>/`` when complete,
so a folder named like a sequence is always whole. A reader refuses a dataset without
a manifest, with an unknown schema_version, or (``verify=True``) whose checksums do not
match, with a `DatasetError` that names the file.

Example::

    ds = open_dataset("data/tiny")
    rgb = ds.read_rgb(ds.split("train")[0], "CAM_FRONT", 0)
"""
from __future__ import annotations

import hashlib
import json
import os
import re
from pathlib import Path
from typing import Iterable

import cv2
import numpy as np

from synth.rig import CameraSpec

SCHEMA_VERSION = 1
GENERATOR = "mcdp-synth"
MANIFEST = "manifest.json"
DEPTH_CHANNEL = "Z"


class DatasetError(RuntimeError):
    """The dataset on disk is missing, incomplete, of another version or corrupt; the message names the file."""


# ----------------------------------------------------------------------------- file I/O

def sha256_file(path: str | Path, chunk: int = 1 << 20) -> str:
    h = hashlib.sha256()
    with open(path, "rb") as f:
        while True:
            b = f.read(chunk)
            if not b:
                break
            h.update(b)
    return h.hexdigest()


def write_json(path: str | Path, obj) -> None:
    """Atomic JSON write (tmp file + rename)."""
    path = Path(path)
    tmp = path.with_name(path.name + ".tmp")
    tmp.write_text(json.dumps(obj, indent=1, sort_keys=False))
    os.replace(tmp, path)


def read_json(path: str | Path):
    path = Path(path)
    try:
        return json.loads(path.read_text())
    except FileNotFoundError:
        raise DatasetError(f"{path}: file is missing") from None
    except json.JSONDecodeError as exc:
        raise DatasetError(f"{path}: not valid JSON ({exc})") from None


def write_png(path: str | Path, img: np.ndarray, compression: int = 3) -> None:
    """Write uint8 RGB (H, W, 3) or gray (H, W) as PNG."""
    if img.dtype != np.uint8:
        raise ValueError(f"write_png: expected uint8, got {img.dtype}")
    arr = img[:, :, ::-1] if img.ndim == 3 else img
    if not cv2.imwrite(str(path), np.ascontiguousarray(arr), [cv2.IMWRITE_PNG_COMPRESSION, int(compression)]):
        raise OSError(f"could not write {path}")


def read_png(path: str | Path, gray: bool = False) -> np.ndarray:
    flag = cv2.IMREAD_GRAYSCALE if gray else cv2.IMREAD_COLOR
    img = cv2.imread(str(path), flag)
    if img is None:
        raise DatasetError(f"{path}: missing or not a readable PNG")
    return img if gray else np.ascontiguousarray(img[:, :, ::-1])


def write_depth_exr(path: str | Path, depth: np.ndarray) -> None:
    """Write (H, W) float32 z-depth in metres as a single-channel ("Z") ZIP-compressed OpenEXR."""
    import OpenEXR

    if depth.ndim != 2 or depth.dtype != np.float32:
        raise ValueError(f"write_depth_exr: expected (H, W) float32, got {depth.shape} {depth.dtype}")
    header = {"compression": OpenEXR.ZIP_COMPRESSION, "type": OpenEXR.scanlineimage}
    with OpenEXR.File(header, {DEPTH_CHANNEL: np.ascontiguousarray(depth)}) as f:
        f.write(str(path))


def read_depth_exr(path: str | Path) -> np.ndarray:
    """(H, W) float32 z-depth in metres, 0 = no surface."""
    import OpenEXR

    try:
        with OpenEXR.File(str(path)) as f:
            ch = f.channels()
            if DEPTH_CHANNEL not in ch:
                raise DatasetError(f"{path}: no '{DEPTH_CHANNEL}' channel (has {sorted(ch)})")
            return np.ascontiguousarray(ch[DEPTH_CHANNEL].pixels, dtype=np.float32)
    except DatasetError:
        raise
    except Exception as exc:
        raise DatasetError(f"{path}: missing or not a readable EXR depth map ({exc})") from None


def frame_stem(frame: int) -> str:
    return f"{frame:06d}"


# ----------------------------------------------------------------------------- reader

class Dataset:
    """Read access to a finished dataset (see module docstring). Never reads depth unless asked."""

    def __init__(self, root: Path, manifest: dict, rig: dict) -> None:
        self.root = root
        self.manifest = manifest
        self.cameras = [CameraSpec.from_json(c) for c in rig["cameras"]]
        self.camera_names = [c.name for c in self.cameras]
        self.neighbours = [tuple(p) for p in rig["neighbours"]]
        self._ego_cache: dict[str, list] = {}
        self._mask_cache: dict[str, np.ndarray] = {}

    @property
    def width(self) -> int:
        return self.cameras[0].width

    @property
    def height(self) -> int:
        return self.cameras[0].height

    @property
    def fps(self) -> float:
        return float(self.manifest["fps"])

    def split(self, name: str) -> list[str]:
        splits = self.manifest["splits"]
        if name not in splits:
            raise DatasetError(f"{self.root / MANIFEST}: no split {name!r} (has {sorted(splits)})")
        return list(splits[name])

    @property
    def sequences(self) -> list[str]:
        return sorted(self.manifest["sequences"])

    def n_frames(self, seq: str) -> int:
        return int(self.manifest["sequences"][seq]["frames"])

    def ego(self, seq: str) -> list[dict]:
        if seq not in self._ego_cache:
            self._ego_cache[seq] = read_json(self.root / seq / "ego.json")["frames"]
        return self._ego_cache[seq]

    def T_world_ego(self, seq: str) -> np.ndarray:
        return np.asarray([f["T_world_ego"] for f in self.ego(seq)], np.float64)

    def rgb_path(self, seq: str, cam: str, frame: int) -> Path:
        return self.root / seq / cam / f"{frame_stem(frame)}.png"

    def depth_path(self, seq: str, cam: str, frame: int) -> Path:
        return self.root / seq / cam / f"{frame_stem(frame)}.depth.exr"

    def read_rgb(self, seq: str, cam: str, frame: int) -> np.ndarray:
        return read_png(self.rgb_path(seq, cam, frame))

    def read_depth(self, seq: str, cam: str, frame: int) -> np.ndarray:
        return read_depth_exr(self.depth_path(seq, cam, frame))

    def mask(self, cam: str) -> np.ndarray:
        """(H, W) bool, True = scene, False = ego body."""
        if cam not in self._mask_cache:
            self._mask_cache[cam] = read_png(self.root / "masks" / f"{cam}.png", gray=True) > 127
        return self._mask_cache[cam]

    @property
    def has_depth(self) -> bool:
        return bool(self.manifest.get("has_depth", True))


_PLAIN_NAME = re.compile(r"^[A-Za-z0-9][A-Za-z0-9._-]{0,127}$")


def _plain(name, field: str, mpath: Path) -> str:
    if not isinstance(name, str) or not _PLAIN_NAME.match(name) or name in (".", ".."):
        raise DatasetError(f"{mpath}: {field} {str(name)[:80]!r} is not a plain name (letters, digits, . _ -; "
                           "no path separators, no '..')")
    return name


def check_manifest_names(root: Path, manifest: dict, mpath: Path) -> None:
    """Every name a manifest gives (sequences, splits, cameras, files) is a plain relative name, and every
    sequence / camera folder resolves inside the dataset root (symlinks too); DatasetError naming the field."""
    seqs = manifest.get("sequences", {})
    if not isinstance(seqs, dict):
        raise DatasetError(f"{mpath}: sequences must be a mapping")
    for seq in seqs:
        _plain(seq, "sequence name", mpath)
    for split, names in (manifest.get("splits") or {}).items():
        _plain(split, "split name", mpath)
        for seq in names if isinstance(names, list) else [names]:
            if _plain(seq, f"splits.{split} entry", mpath) not in seqs:
                raise DatasetError(f"{mpath}: splits.{split} names {seq!r}, which is not in sequences")
    cams = manifest.get("cameras", [])
    for cam in cams:
        _plain(cam, "camera name", mpath)
    for rel in manifest.get("files", {}):
        parts = rel.split("/") if isinstance(rel, str) else [rel]
        for part in parts:
            _plain(part, "files entry", mpath)
    base = root.resolve()
    for seq in seqs:
        for sub in [Path(seq)] + [Path(seq) / c for c in cams]:
            p = (root / sub)
            if p.exists() and not p.resolve().is_relative_to(base):
                raise DatasetError(f"{p}: resolves to {p.resolve()}, outside the dataset root {base}")


def open_dataset(path: str | Path, verify: bool = False) -> Dataset:
    """Open a dataset folder; `verify=True` also checks every file's sha256."""
    root = Path(path)
    if not root.is_dir():
        raise DatasetError(f"{root}: dataset folder does not exist")
    mpath = root / MANIFEST
    if not mpath.is_file():
        raise DatasetError(f"{mpath}: missing; the dataset is incomplete (interrupted render?) or not a dataset")
    manifest = read_json(mpath)
    ver = manifest.get("schema_version")
    if ver != SCHEMA_VERSION:
        raise DatasetError(f"{mpath}: schema_version {ver!r} is not supported (this reader knows {SCHEMA_VERSION})")
    check_manifest_names(root, manifest, mpath)
    rig = read_json(root / "rig.json")
    if verify:
        problems = verify_dataset(root)
        if problems:
            raise DatasetError("; ".join(problems[:5]) + (f" (+{len(problems) - 5} more)" if len(problems) > 5 else ""))
    return Dataset(root, manifest, rig)


def verify_dataset(root: str | Path, progress: bool = False) -> list[str]:
    """Every problem found (missing, truncated or altered file, unknown schema); [] when the dataset is whole."""
    root = Path(root)
    mpath = root / MANIFEST
    if not mpath.is_file():
        return [f"{mpath}: missing"]
    try:
        manifest = read_json(mpath)
    except DatasetError as exc:
        return [str(exc)]
    if manifest.get("schema_version") != SCHEMA_VERSION:
        return [f"{mpath}: schema_version {manifest.get('schema_version')!r} is not {SCHEMA_VERSION}"]
    try:
        check_manifest_names(root, manifest, mpath)
    except DatasetError as exc:
        return [str(exc)]
    problems = []
    files: dict[str, str] = manifest.get("files", {})
    items: Iterable = files.items()
    if progress:
        from tqdm import tqdm
        items = tqdm(items, total=len(files), desc="verify", unit="file")
    for rel, digest in items:
        p = root / rel
        if not p.is_file():
            problems.append(f"{p}: missing")
        elif sha256_file(p) != digest:
            problems.append(f"{p}: checksum mismatch (truncated or altered)")
    # every expected frame file is listed
    cams = manifest.get("cameras", [])
    for seq, info in manifest.get("sequences", {}).items():
        for cam in cams:
            for f in range(int(info["frames"])):
                for suffix in (".png", ".depth.exr"):
                    rel = f"{seq}/{cam}/{frame_stem(f)}{suffix}"
                    if rel not in files:
                        problems.append(f"{root / rel}: not listed in the manifest")
    return problems
