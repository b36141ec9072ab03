"""Open a nuScenes dataroot (ours from `synth export --format nuscenes`, or the real one) as a `Dataset`.

`open_nuscenes(root)` loads the tables (`synth.nuscenes.tables`: with the official devkit, the ``nuscenes``
extra; where it is not installed, as beside the ``viz`` extra, as plain JSON with the devkit's arithmetic
in numpy, `synth.nuscenes.plain`), scans them into records (`synth.nuscenes.scan`), finds the masks, splits
and fps, and returns a `synth.nuscenes.dataset.NuScenesDataset` with the interface `mcdp` uses
(`synth.protocol.DatasetReader`): cameras, neighbours, splits, sequences, ego poses, RGB, depth, masks.
`synth.open.open_dataset` calls it for a folder that looks like a dataroot (`is_nuscenes_root`).
docs/NUSCENES.md, "Reading a nuScenes dataroot", has the mapping and its limits; in short:

- sequences = scenes (name = scene name), frames = the scene's key-frame samples in prev/next order;
- cameras = the six CAM_* channels in rig order (`synth.nuscenes.layout.NUSCENES_CAMERAS`, the export's
  order), ring neighbours; K = ``camera_intrinsic`` (+0.5 on cx, cy for a dataroot without our
  ``mcdp_synth/export.json``: nuScenes is taken to use integer pixel centres, ours puts them at +0.5),
  T_ego_cam = ``calibrated_sensor`` (must be the same for every sample: one rig);
- T_world_ego = the ego_pose of each sample's CAM_FRONT sample_data; `camera_poses` each camera's own
  (its sample_data's timestamp and ego_pose, in the ego frame of CAM_FRONT's: cameras that fire apart);
- depth = the sample's LIDAR_TOP sweep projected into the camera with the devkit's chain
  (lidar -> ego at lidar time -> global -> ego at camera time -> camera), z at pixel
  (floor(u), floor(v)) in our +0.5-centre K, nearest point per pixel, kept in
  [`LIDAR_MIN_DEPTH`, `LIDAR_MAX_DEPTH`] m (`synth.nuscenes.dataset`), 0 elsewhere;
- masks = ``mcdp_synth/masks/<CHANNEL>.png``, else ``masks=`` folder, else all scene (one warning).

Every problem is a `DatasetError` of one line naming the token, file or channel.

Example::

    ds = open_nuscenes("NS_ROOT")          # or synth.open.open_dataset("NS_ROOT")
    d = ds.read_depth(ds.split("test")[0], "CAM_FRONT", 1)   # sparse LiDAR z-depth, 0 = none
"""
from __future__ import annotations

import warnings
from pathlib import Path

import numpy as np

from synth.files import DatasetError, read_json, read_png, within
from synth.nuscenes.dataset import NuScenesDataset
from synth.nuscenes.layout import MARKER, MASKS_DIR
from synth.nuscenes.scan import Scan
from synth.nuscenes.tables import load_tables, read_splits, resolve_version
from synth.rig import CameraSpec

NO_MASKS = "no self-occlusion masks: every pixel counts as scene"


def _masks(root: Path, cameras: list[CameraSpec], masks) -> tuple[dict[str, np.ndarray], str]:
    ours = root / MASKS_DIR
    if ours.is_dir():
        folder, source = within(root, ours, "the masks folder"), MASKS_DIR
    elif masks is not None:
        folder, source = Path(masks), str(masks)
        if not folder.is_dir():
            raise DatasetError(f"{folder}: masks folder does not exist")
    else:
        warnings.warn(f"{root}: {ours} is missing and no masks= folder was given: {NO_MASKS}", stacklevel=3)
        return {c.name: np.ones((c.height, c.width), bool) for c in cameras}, "none (all scene)"
    out = {}
    for c in cameras:
        p = folder / f"{c.name}.png"
        m = read_png(within(root, p, "a mask") if folder == ours else p, gray=True)
        if m.shape != (c.height, c.width):
            raise DatasetError(f"{p}: the mask is {m.shape[1]}x{m.shape[0]}, the {c.name} images are "
                               f"{c.width}x{c.height}")
        out[c.name] = m > 127
    return out, source


def open_nuscenes(root: str | Path, version: str | None = None, masks: str | Path | None = None,
                  pixel_centre: str | None = None) -> NuScenesDataset:
    """Open a nuScenes dataroot through the devkit (module docstring).

    Args:
        root: the dataroot (holds ``samples/`` and the version folder).
        version: e.g. ``v1.0-mini``; None = the one folder holding ``sample.json`` (several: refused).
        masks: folder of ``<CHANNEL>.png`` self-occlusion masks (255 = scene), used when the dataroot has
            no ``mcdp_synth/masks``; neither: every pixel is scene (one warning).
        pixel_centre: ``"half"`` (camera_intrinsic puts pixel centres at +0.5, our export) or ``"integer"``
            (OpenCV / nuScenes: K gets +0.5 on cx, cy); None = ``half`` if ``mcdp_synth/export.json``
            exists, else ``integer``.
    """
    root = Path(root)
    if not root.is_dir():
        raise DatasetError(f"{root}: dataset folder does not exist")
    version = resolve_version(root, version)
    export, pixel_centre = _export_record(root, pixel_centre)
    scan = Scan(root, version, load_tables(root, version))
    frames = scan.frames()
    cameras = scan.cameras(pixel_centre)
    m, mask_source = _masks(root, cameras, masks)
    splits, split_source = read_splits(root, list(frames), version)
    return NuScenesDataset(root, version, cameras, frames, splits, split_source, _fps(export, frames), m, mask_source,
                           scan.n_lidar > 0, pixel_centre)


def _export_record(root: Path, pixel_centre: str | None) -> tuple[dict | None, str]:
    """Our export's ``mcdp_synth/export.json`` (None: not our export) and the pixel-centre convention."""
    marker = root / MARKER
    export = None
    if marker.exists() or marker.is_symlink():
        export = read_json(marker, root, "the export record")
    if pixel_centre is None:
        pixel_centre = "half" if export is not None else "integer"
    if pixel_centre not in ("half", "integer"):
        raise DatasetError(f"pixel_centre must be 'half' or 'integer', got {pixel_centre!r}")
    return export, pixel_centre


def _fps(export: dict | None, frames: dict[str, list[dict]]) -> float:
    """Our export's fps, else 1 / the median time between key frames (NaN without two frames)."""
    if export is not None and isinstance(export.get("fps"), (int, float)):
        return float(export["fps"])
    dts = [b["timestamp_s"] - a["timestamp_s"] for fs in frames.values() for a, b in zip(fs, fs[1:])]
    return float(1.0 / np.median(dts)) if dts and np.median(dts) > 0 else float("nan")
