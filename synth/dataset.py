"""Dataset contract v1: the reader used by `mcdp`, its checks, and `verify` (file I/O: `synth.files`).

Layout (docs/DATASET.md)::

    <dataset>/
      manifest.json          written LAST (schema_version, generator version, resolved config,
                             seed, cameras, image size (and each camera's, where one differs), fps,
                             splits, overlap, sha256 of every file)
      rig.json               cameras [{name, width, height, K, T_ego_cam, hfov_deg, yaw_deg; model, dist: a lens
                             other than pinhole (`synth.camera`)}], neighbours
      masks/<CAM>.png        uint8, 255 = scene, 0 = ego body (each file at its camera's size)
      <seq>/ego.json         per frame: timestamp_s, T_world_ego (4x4), lighting
      <seq>/<CAM>/<frame:06d>.png         RGB uint8 sRGB (.jpg: a JPEG, with the manifest's ``rgb.format`` jpeg)
      <seq>/<CAM>/<frame:06d>.depth.exr   float32 depth in metres (channel "Z"), 0 = no surface: z-depth, or range
                                          for a lens whose depth kind is range (Kannala-Brandt; `synth.camera`)
      labels (manifest ``labels.kinds``; `synth.label_reader`): <frame>.semantic.png, <frame>.instance.png,
      <seq>/instances.json, <frame>.flow.exr + .flow_valid.png (frames 0..F-2), <frame>.movers.png (the last
      three only with labels.flow=true, off by default), <seq>/world_mesh.npz (labels.mesh=true, off by default)

A sequence is written into ``<seq>.partial/`` and renamed to ``<seq>/`` when complete,
so a folder named like a sequence is always whole. A reader refuses a dataset without
a manifest, with an unknown schema_version, or (`synth.open.open_dataset(..., verify=True)`) whose checksums do not
match, with a `DatasetError` that names the file.

Example::

    ds = open_dataset("data/tiny")
    rgb = ds.read_rgb(ds.split("train")[0], "CAM_FRONT", 0)
"""
from __future__ import annotations

from pathlib import Path

import numpy as np

from synth import camera
from synth.files import (RGB_SUFFIXES, DatasetError, frame_stem, is_plain_name, read_depth_exr, read_image, read_json,
                         read_png, read_regular, short_list, within)
from synth.label_reader import LabelReader, check_labels_record
from synth.rig import MAX_CAMERA_PX, CameraSpec
from synth.sizes import SharedSize, camera_sizes

SCHEMA_VERSION = 1
GENERATOR = "mcdp-synth"
MANIFEST = "manifest.json"
# ----------------------------------------------------------------------------- reader

class Dataset(LabelReader, SharedSize):
    """Read access to a finished dataset (see module docstring), a `synth.protocol.DatasetReader` (its labels:
    `synth.label_reader`); beyond it, the generator's record: `manifest`, `config_hash`, `overlap`. Never
    reads depth unless asked."""

    def __init__(self, root: Path, manifest: dict, rig: dict) -> None:
        self.root = root
        self._real_root = root.resolve()
        self.manifest = manifest
        self.cameras = [CameraSpec.from_json(c) for c in rig["cameras"]]  # checked by check_rig
        self.camera_names = [c.name for c in self.cameras]
        self.neighbours = [tuple(p) for p in rig["neighbours"]]
        self._ego_cache: dict[str, list] = {}
        self._mask_cache: dict[str, np.ndarray] = {}
        self._sizes = {c.name: (c.width, c.height) for c in self.cameras}
        self.rgb_suffix = rgb_suffix(manifest)  # checked by check_manifest_keys

    format = "synth"  # `synth.protocol.DatasetReader.format`

    @property
    def fps(self) -> float:
        return float(self.manifest["fps"])

    @property
    def config_hash(self) -> str | None:
        """The hash of the generator config the dataset was rendered with (`corelib.configlib.config_hash`)."""
        return self.manifest.get("config_hash")

    @property
    def code_version(self) -> str | None:
        """The code that rendered the dataset (`corelib.version.code_version`; None before it was recorded)."""
        v = self.manifest.get("code_version")
        return v if isinstance(v, str) else None

    @property
    def overlap(self) -> dict:
        """The rig's overlap record: target, mode, per-pair measured pixel overlap (docs/DATASET.md)."""
        return self.manifest.get("overlap", {})

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

    def inside(self, p: Path) -> Path:
        """`p`, a file of the dataset, when it resolves inside the root; a file symlinked out of the
        dataset is never read (DatasetError naming it)."""
        return within(self.root, p, "", "dataset root", "is a link to")

    def read_bytes(self, p: Path) -> bytes:
        """The bytes of the dataset's file `p` (for a copy), refused outside the root (`inside`)."""
        return read_regular(self.inside(p))

    def ego(self, seq: str) -> list[dict]:
        if seq not in self._ego_cache:
            self._ego_cache[seq] = read_json(self.inside(self.root / seq / "ego.json"))["frames"]
        return self._ego_cache[seq]

    def T_world_ego(self, seq: str) -> np.ndarray:
        return np.asarray([f["T_world_ego"] for f in self.ego(seq)], np.float64)

    def camera_poses(self, seq: str) -> tuple[np.ndarray, np.ndarray]:
        """(F, N) each camera's timestamp_s and (F, N, 4, 4) its pose at that time in the ego frame of its frame's
        time (`synth.trigger.camera_poses`; a synchronous rig: the frame's time and the static T_ego_cam)."""
        from synth.trigger import camera_poses

        cache = self.__dict__.setdefault("_pose_cache", {})
        if seq not in cache:
            trigger = self.manifest.get("trigger", {}).get("mode") if isinstance(self.manifest.get("trigger"), dict) \
                else None  # checked by check_trigger_record
            cache[seq] = camera_poses(self.ego(seq), self.cameras, self.root / seq / "ego.json", trigger)
        return cache[seq]

    def rgb_path(self, seq: str, cam: str, frame: int) -> Path:
        return self.root / seq / cam / f"{frame_stem(frame)}{self.rgb_suffix}"

    def depth_path(self, seq: str, cam: str, frame: int) -> Path:
        return self.root / seq / cam / f"{frame_stem(frame)}.depth.exr"

    def _size(self, cam: str) -> tuple[int, int]:
        """(width, height) of camera `cam`'s images; DatasetError for a camera the dataset lacks."""
        if cam not in self._sizes:
            raise DatasetError(f"{self.root}: no camera {str(cam)[:40]!r} (cameras {', '.join(self.camera_names)})")
        return self._sizes[cam]

    def _sized(self, arr: np.ndarray, path: Path, what: str, cam: str) -> np.ndarray:
        w, h = self._size(cam)
        if arr.shape[:2] != (h, w):
            raise DatasetError(f"{path}: {what} is {arr.shape[1]}x{arr.shape[0]}, {cam}'s images are {w}x{h}")
        return arr

    def read_rgb(self, seq: str, cam: str, frame: int) -> np.ndarray:
        """(H, W, 3) uint8 RGB at the camera's size."""
        p = self.inside(self.rgb_path(seq, cam, frame))
        return self._sized(read_png(p) if self.rgb_suffix == ".png" else read_image(p), p, "the image", cam)

    def read_depth(self, seq: str, cam: str, frame: int) -> np.ndarray:
        """(H, W) float32 depth in metres at the camera's size, of its lens's depth kind (z-depth; range for
        Kannala-Brandt: `synth.camera.depth_kind`), 0 = no surface; finite and >= 0, else DatasetError."""
        p = self.inside(self.depth_path(seq, cam, frame))
        d = self._sized(read_depth_exr(p, self._size(cam)), p, "the depth map", cam)
        if not np.isfinite(d).all() or (d < 0).any():
            raise DatasetError(f"{p}: depth holds non-finite or negative values (the contract: finite, >= 0, "
                               "0 = no surface)")
        return d

    def mask(self, cam: str) -> np.ndarray:
        """(H, W) bool at the camera's size, True = scene, False = ego body."""
        if cam not in self._mask_cache:
            p = self.inside(self.root / "masks" / f"{cam}.png")
            self._mask_cache[cam] = self._sized(read_png(p, gray=True), p, "the mask", cam) > 127
        return self._mask_cache[cam]

    @property
    def has_depth(self) -> bool:
        return bool(self.manifest.get("has_depth", True))

    @property
    def ground_truth(self) -> dict:
        """Provenance of `read_depth` (the evaluator copies it into metrics.json): "dense z-depth (rendered)", or,
        where a camera's lens gives range (`synth.camera.depth_kind`), "dense depth (rendered; z-depth or range by
        each camera's lens)"."""
        kinds = {camera.depth_kind(c.intrinsics) for c in self.cameras}
        kind = "dense z-depth (rendered)" if kinds == {"z_depth"} else \
            "dense depth (rendered; z-depth or range by each camera's lens)"
        return {"kind": kind, "source": "<seq>/<CAM>/<frame>.depth.exr"}


def _plain(name, field: str, mpath: Path) -> str:
    if not is_plain_name(name):
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


def dataset_containing(path: str | Path) -> Path | None:
    """The dataset folder (manifest.json beside rig.json) or nuScenes dataroot (`is_nuscenes_root`) that one
    of `path`'s parent folders is, or None: an output named inside one would change it behind its manifest
    or tables (every writer checks this before it writes anything)."""
    from synth.nuscenes.tables import is_nuscenes_root

    for parent in Path(path).resolve().parents:
        if ((parent / MANIFEST).is_file() and (parent / "rig.json").is_file()) or is_nuscenes_root(parent):
            return parent
    return None


INTEGRITY = "integrity"
_REQUIRED_KEYS = {"schema_version": int, "generator": str, "cameras": list, "image_size": dict, "fps": (int, float),
                  "splits": dict, "sequences": dict, "files": dict}
_OPTIONAL_KEYS = {"generator_version", "code_version", "config", "config_hash", "seed", "has_depth", "families",
                  "overlap", "camera_sizes", "labels", "trigger", "rgb", "shutter", INTEGRITY}


def rgb_suffix(manifest: dict, mpath: Path | None = None) -> str:
    """The suffix of the dataset's RGB images: its manifest's ``rgb.format`` (`synth.manifest.rgb_record`) in
    `RGB_SUFFIXES`, ``.png`` without the key (every dataset rendered before JPEG); DatasetError naming the key."""
    rec = manifest.get("rgb", {"format": "png"})
    fmt = rec.get("format") if isinstance(rec, dict) else None
    if not isinstance(fmt, str) or fmt not in RGB_SUFFIXES:
        raise DatasetError(f"{mpath or MANIFEST}: rgb.format must be one of {', '.join(RGB_SUFFIXES)}, got "
                           f"{str(fmt)[:40]!r}")
    q = rec.get("quality")
    if fmt == "jpeg" and not (isinstance(q, int) and not isinstance(q, bool) and 1 <= q <= 100):
        raise DatasetError(f"{mpath or MANIFEST}: rgb.quality must be an integer in 1..100, got {str(q)[:40]!r}")
    return RGB_SUFFIXES[fmt]


def check_manifest_keys(manifest, mpath: Path) -> None:
    """The manifest's top-level keys are those of schema 1 with the right types; DatasetError naming the key."""
    if not isinstance(manifest, dict):
        raise DatasetError(f"{mpath}: must be a JSON object")
    for key, typ in _REQUIRED_KEYS.items():
        if key not in manifest:
            raise DatasetError(f"{mpath}: missing key {key!r}")
        if not isinstance(manifest[key], typ) or isinstance(manifest[key], bool):
            raise DatasetError(f"{mpath}: key {key!r} has the wrong type ({type(manifest[key]).__name__})")
    extra = sorted(set(manifest) - set(_REQUIRED_KEYS) - _OPTIONAL_KEYS)
    if extra:
        raise DatasetError(f"{mpath}: unknown key(s) {short_list([repr(k[:40]) for k in extra], 4)} "
                           f"(schema {SCHEMA_VERSION} knows {short_list(sorted(_REQUIRED_KEYS), 20)} and "
                           f"{short_list(sorted(_OPTIONAL_KEYS), 20)})")
    for seq, info in manifest["sequences"].items():
        frames = info.get("frames") if isinstance(info, dict) else None
        if not isinstance(frames, int) or isinstance(frames, bool) or frames < 1:
            raise DatasetError(f"{mpath}: sequences.{str(seq)[:40]}.frames must be a positive integer")
    if "labels" in manifest:
        check_labels_record(manifest["labels"], mpath)
    if "trigger" in manifest:
        from synth.trigger import check_trigger_record
        check_trigger_record(manifest["trigger"], manifest["cameras"], mpath)
    rgb_suffix(manifest, mpath)
    if "shutter" in manifest:
        from synth.shutter import check_shutter_record
        check_shutter_record(manifest["shutter"], mpath)
    for key in ("width", "height"):
        if not _pixels(manifest["image_size"].get(key)):
            raise DatasetError(f"{mpath}: image_size.{key} must be an integer in [1, {MAX_CAMERA_PX}] (a camera's "
                               f"largest side), got {str(manifest['image_size'].get(key))[:40]}")
    if "camera_sizes" in manifest:
        sizes = manifest["camera_sizes"]
        if not isinstance(sizes, dict) or sorted(map(str, sizes)) != sorted(map(str, manifest["cameras"])):
            raise DatasetError(f"{mpath}: camera_sizes must give [width, height] of every camera of 'cameras'")
        for cam, wh in sizes.items():
            if not (isinstance(wh, list) and len(wh) == 2 and all(_pixels(v) for v in wh)):
                raise DatasetError(f"{mpath}: camera_sizes.{str(cam)[:40]} must be [width, height], integers in "
                                   f"[1, {MAX_CAMERA_PX}] (a camera's largest side), got {str(wh)[:40]}")


def _pixels(v) -> bool:
    """An image side a manifest may claim: a positive integer at most the config's bound (`MAX_CAMERA_PX`)."""
    return isinstance(v, int) and not isinstance(v, bool) and 0 < v <= MAX_CAMERA_PX


def _matrix(v, n: int) -> bool:
    try:
        a = np.asarray(v, dtype=np.float64)
    except (TypeError, ValueError):
        return False
    return a.shape == (n, n) and bool(np.isfinite(a).all())


def check_rig(rig, manifest: dict, rpath: Path) -> None:
    """rig.json agrees with the contract and the manifest (camera names, sizes, K, T_ego_cam, neighbours)."""
    if not isinstance(rig, dict) or not isinstance(rig.get("cameras"), list) or not rig["cameras"]:
        raise DatasetError(f"{rpath}: 'cameras' must be a non-empty list")
    names = [c.get("name") if isinstance(c, dict) else None for c in rig["cameras"]]
    if names != manifest["cameras"]:
        raise DatasetError(f"{rpath}: camera names {short_list([str(n)[:20] for n in names])} differ from the "
                           f"manifest's cameras {short_list(manifest['cameras'])}")
    sizes, source = camera_sizes(manifest), "camera_sizes" if "camera_sizes" in manifest else "image_size"
    for c in rig["cameras"]:
        field = f"cameras[{c['name']}]"
        for k, key in enumerate(("width", "height")):
            want = sizes[c["name"]][k]
            if c.get(key) != want:
                where = f"camera_sizes.{c['name']}" if source == "camera_sizes" else f"image_size.{key}"
                raise DatasetError(f"{rpath}: {field}.{key} is {str(c.get(key))[:20]}, the manifest's "
                                   f"{where} gives {str(want)[:20]}")
        if not _matrix(c.get("K"), 3):
            raise DatasetError(f"{rpath}: {field}.K must be a finite 3x3 matrix")
        if not _matrix(c.get("T_ego_cam"), 4):
            raise DatasetError(f"{rpath}: {field}.T_ego_cam must be a finite 4x4 matrix")
        if "model" in c or "dist" in c:  # a lens other than pinhole (issue 59): the camera table's row and parameters
            try:
                if not isinstance(c.get("model"), str):
                    raise ValueError(f"model must be a camera model's name, got {str(c.get('model'))[:40]}")
                camera.Intrinsics.from_json({"model": c.get("model"), "K": c["K"], "dist": c.get("dist")})
            except (ValueError, TypeError) as e:
                raise DatasetError(f"{rpath}: {field}: {str(e)[:300]}") from None
    n = len(names)
    nb = rig.get("neighbours")
    if not isinstance(nb, list) or not all(isinstance(p, list) and len(p) == 2 and all(
            isinstance(i, int) and 0 <= i < n for i in p) for p in nb):
        raise DatasetError(f"{rpath}: 'neighbours' must be a list of [i, j] camera indices below {n}")


def open_synth(path: str | Path) -> Dataset:
    """Open a folder rendered by this package (`synth.open.open_dataset` opens any format and verifies)."""
    root = Path(path)
    if not root.is_dir():
        raise DatasetError(f"{root}: dataset folder does not exist")
    mpath = root / MANIFEST
    if not mpath.is_file():
        raise DatasetError(f"{mpath}: missing; the dataset is incomplete (interrupted render?) or not a dataset")
    manifest = read_json(within(root, mpath, "", "dataset root", "is a link to"))
    ver = manifest.get("schema_version") if isinstance(manifest, dict) else None
    if ver != SCHEMA_VERSION:
        raise DatasetError(f"{mpath}: schema_version {repr(ver)[:40]} is not supported (this reader knows "
                           f"{SCHEMA_VERSION})")
    check_manifest_keys(manifest, mpath)
    check_manifest_names(root, manifest, mpath)
    rig = read_json(within(root, root / "rig.json", "", "dataset root", "is a link to"))
    check_rig(rig, manifest, root / "rig.json")
    return Dataset(root, manifest, rig)
