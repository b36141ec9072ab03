"""Where things lie in a nuScenes dataroot: the names that the export (`synth.nuscenes.export`) writes and
the reader (`synth.nuscenes.read`) looks for, so neither spells them alone; and what an export owns there
(`prepare_output` refuses any other folder and removes a previous export's files). Layout written (and
nothing outside ``NS_ROOT``)::

    NS_ROOT/
      <version>/*.json                  the 13 tables the devkit loads, written LAST (into
                                        <version>.partial/, each file tmp + rename, then the folder
                                        is renamed); annotation tables are empty lists
      samples/<CHANNEL>/<seq>__<CHANNEL>__<timestamp_us>.jpg      every frame is a key frame
      samples/LIDAR_TOP/<seq>__LIDAR_TOP__<timestamp_us>.pcd.bin  float32 (x, y, z, intensity, ring)
      maps/<token>.png                  placeholder semantic-prior mask (all background): the devkit
                                        needs one map record with an existing file
      mcdp_synth/export.json            what was exported from what: source dataset, channel map,
                                        LiDAR config, pixel-centre convention, per sample_data the
                                        sequence / frame / camera and the exact depth file
      mcdp_synth/splits.json            {train, val, test: [scene names]} (our sequence ids)
      mcdp_synth/masks/<CHANNEL>.png    self-occlusion masks (255 = scene, 0 = ego body)
      mcdp_synth/depth/<CHANNEL>/<seq>__<CHANNEL>__<timestamp_us>.depth.exr   exact z-depth (copied bytes)
      lidarseg/<version>/*.bin, mcdp_synth/labels/...  a dataset's labels (`synth.nuscenes.lidarseg`)

Example::

    splits = read_json(root / SPLITS_FILE)          # {train, val, test: [scene names]} of our export
"""
from __future__ import annotations

import shutil
from pathlib import Path

from synth.files import DatasetError, read_json

FORMAT = "mcdp-synth-nuscenes-export"  # export.json's "format"
EXPORT_DIR = "mcdp_synth"  # our own files beside nuScenes' (the devkit ignores them)
MARKER = f"{EXPORT_DIR}/export.json"
SPLITS_FILE = f"{EXPORT_DIR}/splits.json"
MASKS_DIR = f"{EXPORT_DIR}/masks"
LIDARSEG_DIR = "lidarseg"
# nuScenes' camera channels, clockwise from the front as in nuScenes: the rig order of the export and reader
NUSCENES_CAMERAS = ("CAM_FRONT", "CAM_FRONT_RIGHT", "CAM_BACK_RIGHT", "CAM_BACK", "CAM_BACK_LEFT", "CAM_FRONT_LEFT")
LIDAR_CHANNEL = "LIDAR_TOP"
# what an export owns at the top of NS_ROOT (anything else there makes a re-export refuse)
OWNED = ("samples", "sweeps", "maps", EXPORT_DIR, LIDARSEG_DIR)
LOCK = ".lock"  # held while an export writes the folder (a second writer is refused, naming the pid)


class ExportError(RuntimeError):
    """The export cannot be written (refused output folder, bad source); the message names the file."""


def prepare_output(out: Path, config_hash: str, version: str, clean: bool = True) -> None:
    """Refuse anything but a new/empty folder or a previous export of the same dataset (then remove what
    that export wrote, version tables first, so a half-written re-export is never loadable)."""
    if out.exists() and not out.is_dir():
        raise ExportError(f"{out}: exists and is not a folder")
    if out.is_symlink():
        raise ExportError(f"{out}: is a symlink; give the real folder")
    if not out.is_dir() or not any(p.name != LOCK for p in out.iterdir()):
        return
    marker = out / MARKER
    if not marker.is_file():
        raise ExportError(f"{out}: folder is not empty and holds no nuScenes export of a synth dataset "
                          f"(no {MARKER}); choose an empty or new folder")
    try:
        prev = read_json(marker)
    except DatasetError as exc:
        raise ExportError(str(exc)) from None
    if not isinstance(prev, dict) or prev.get("format") != FORMAT:
        raise ExportError(f"{marker}: not an export marker of {FORMAT}; refusing to overwrite {out}")
    prev_hash = (prev.get("source") or {}).get("config_hash")
    if prev_hash != config_hash:
        raise ExportError(f"{out}: holds the export of another dataset (config_hash {str(prev_hash)[:12]}..., "
                          f"this one {config_hash[:12]}...); choose another --out")
    versions = {str(v) for v in [prev.get("version"), version] if v}
    owned = set(OWNED) | versions | {f"{v}.partial" for v in versions} | {LOCK}
    for p in sorted(out.iterdir()):
        if p.name not in owned:
            raise ExportError(f"{p}: not part of the previous export in {out}; refusing to overwrite it")
        if p.is_symlink():
            raise ExportError(f"{p}: is a symlink; an export writes inside {out} only")
    if not clean:
        return
    for name in sorted(versions) + sorted(f"{v}.partial" for v in versions) + list(OWNED):
        p = out / name
        if p.is_dir():
            shutil.rmtree(p)
        elif p.exists():
            p.unlink()
