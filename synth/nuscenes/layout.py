"""Where things lie in a nuScenes dataroot: the names that the export (`synth.nuscenes.export`) writes and
the reader (`synth.nuscenes.read`) looks for, so neither spells them alone.

Example::

    splits = read_json(root / SPLITS_FILE)          # {train, val, test: [scene names]} of our export
"""
from __future__ import annotations

EXPORT_DIR = "mcdp_synth"  # our own files beside nuScenes' (the devkit ignores them)
MARKER = f"{EXPORT_DIR}/export.json"
SPLITS_FILE = f"{EXPORT_DIR}/splits.json"
MASKS_DIR = f"{EXPORT_DIR}/masks"
LIDARSEG_DIR = "lidarseg"
# nuScenes' camera channels, clockwise from the front as in nuScenes: the rig order of the export and reader
NUSCENES_CAMERAS = ("CAM_FRONT", "CAM_FRONT_RIGHT", "CAM_BACK_RIGHT", "CAM_BACK", "CAM_BACK_LEFT", "CAM_FRONT_LEFT")
LIDAR_CHANNEL = "LIDAR_TOP"
