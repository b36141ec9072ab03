"""The tables of a nuScenes dataroot scanned into the reader's records (`Scan`): each scene's key-frame
samples in prev/next order with their six cameras, ego poses and LIDAR_TOP sweep (`frames`), then the one rig
they share (`cameras`: sizes from the first image, calibration checked equal in every sample). It reads the
devkit's ``NuScenes`` or `synth.nuscenes.plain.PlainTables` alike; every problem is a `DatasetError` of one
line naming the table, token or file.

Example::

    scan = Scan(root, version, load_tables(root, version))
    frames, cameras = scan.frames(), scan.cameras("half")
"""
from __future__ import annotations

from pathlib import Path

import numpy as np

from synth.files import DatasetError, read_image, regular_file, within
from synth.nuscenes.geometry import check_intrinsic, pose_matrix
from synth.nuscenes.layout import LIDAR_CHANNEL, NUSCENES_CAMERAS
from synth.nuscenes.tables import get_record
from synth.rig import CameraSpec

RIG_TOL = 1e-9  # calibrated_sensor values that differ by more are two rigs


def _angles(K: np.ndarray, T: np.ndarray, width: int) -> tuple[float, float, float]:
    """(hfov, yaw, pitch) in degrees of a camera (yaw CCW from ego x, as synth.rig)."""
    axis = T[:3, :3] @ np.array([0.0, 0.0, 1.0])
    hfov = float(np.degrees(2 * np.arctan2(width / 2.0, K[0, 0])))
    return hfov, float(np.degrees(np.arctan2(axis[1], axis[0]))), float(np.degrees(np.arcsin(np.clip(axis[2], -1, 1))))



class Scan:
    """The tables read into the reader's records: the scenes' key frames (`frames`), then the rig (`cameras`)."""

    def __init__(self, root: Path, version: str, nusc) -> None:
        self.root, self.nusc, self.tab = root, nusc, root / version
        channels = {s["channel"] for s in nusc.sensor}
        for ch in NUSCENES_CAMERAS:
            if ch not in channels:
                raise DatasetError(f"{self.tab / 'sensor.json'}: no camera channel {ch} (has {sorted(channels)}); "
                                   f"the rig needs {', '.join(NUSCENES_CAMERAS)}")
        self.calib: dict[str, tuple] = {}  # channel -> (values, token) of the first sample's calibrated_sensor
        self.first_file: dict[str, Path] = {}  # channel -> its first image, and the sizes its sample_data give
        self.sizes: dict[str, set] = {}
        self.n_lidar = self.n_samples = 0

    def frames(self) -> dict[str, list[dict]]:
        """Scene name -> its key frames in prev/next order (``timestamp_s`` from the scene's first)."""
        tab, frames = self.tab, {}
        for scene in sorted(self.nusc.scene, key=lambda s: s["name"]):
            name = scene["name"]
            if name in frames:
                raise DatasetError(f"{tab / 'scene.json'}: two scenes named {name!r}")
            out = [self._frame(s, scene) for s in self._samples(scene)]
            t0 = out[0]["timestamp_s"]
            for fr in out:
                fr["timestamp_s"] -= t0
            frames[name] = out
        if not frames:
            raise DatasetError(f"{tab / 'scene.json'}: no scene")
        if 0 < self.n_lidar < self.n_samples:
            missing = next(f["sample_token"] for fs in frames.values() for f in fs if "lidar" not in f)
            raise DatasetError(f"{tab / 'sample_data.json'}: sample {missing} has no key-frame {LIDAR_CHANNEL} "
                               "(others have)")
        return frames

    def _samples(self, scene: dict) -> list[dict]:
        """The scene's samples along the next chain."""
        name, tab = scene["name"], self.tab
        recs, tok, seen = [], scene.get("first_sample_token"), set()
        while tok:
            if tok in seen:
                raise DatasetError(f"{tab / 'sample.json'}: scene {name}: the next chain loops at sample {tok}")
            seen.add(tok)
            s = get_record(self.nusc, "sample", tok, f"scene {name} ({scene['token']})")
            recs.append(s)
            tok = s.get("next")
        if not recs:
            raise DatasetError(f"{tab / 'scene.json'}: scene {name} has no sample")
        return recs

    def _frame(self, s: dict, scene: dict) -> dict:
        """One sample: its six cameras, the ego pose of CAM_FRONT, its LiDAR sweep if any."""
        self.n_samples += 1
        fr = {"sample_token": s["token"], "scene_token": scene["token"], "cams": {}}
        for ch in NUSCENES_CAMERAS:
            if ch not in s["data"]:
                raise DatasetError(f"{self.tab / 'sample_data.json'}: sample {s['token']} (scene {scene['name']}) "
                                   f"has no key-frame {ch} sample_data")
            fr["cams"][ch] = self._camera(ch, s, scene["name"])
        front = fr["cams"]["CAM_FRONT"]
        fr["T_world_ego"] = front["T_world_ego"]
        fr["timestamp_s"] = front["timestamp"] / 1e6
        if LIDAR_CHANNEL in s["data"]:
            fr["lidar"] = self._lidar(s)
            self.n_lidar += 1
        return fr

    def _camera(self, ch: str, s: dict, name: str) -> dict:
        """Camera `ch` of sample `s`: its file, time and ego pose; its calibration is the rig's (checked)."""
        nusc, tab, calib = self.nusc, self.tab, self.calib
        sd = get_record(nusc, "sample_data", s["data"][ch], f"sample {s['token']}")
        who = f"sample_data {sd['token']} ({ch})"
        cs = get_record(nusc, "calibrated_sensor", sd["calibrated_sensor_token"], who)
        pose = get_record(nusc, "ego_pose", sd["ego_pose_token"], who)
        vals = (np.asarray(cs.get("camera_intrinsic"), np.float64), np.asarray(cs["rotation"], np.float64),
                np.asarray(cs["translation"], np.float64))
        if ch not in calib:
            check_intrinsic(vals[0], f"{tab / 'calibrated_sensor.json'}: calibrated_sensor {cs['token']} ({ch})")
            pose_matrix(vals[1], vals[2], f"{tab / 'calibrated_sensor.json'}: calibrated_sensor {cs['token']} ({ch})")
            calib[ch] = (vals, cs["token"])
        elif cs["token"] != calib[ch][1] and not all(
                a.shape == b.shape and np.allclose(a, b, rtol=0, atol=RIG_TOL) for a, b in zip(vals, calib[ch][0])):
            raise DatasetError(f"{tab / 'calibrated_sensor.json'}: {ch} calibration {cs['token']} (sample "
                               f"{s['token']}, scene {name}) differs from {calib[ch][1]}; one rig is "
                               "modelled: open a dataroot of one vehicle / calibration")
        path = self.root / sd["filename"]
        if not path.is_file():
            raise DatasetError(f"{path}: image file is missing ({who})")
        self.first_file.setdefault(ch, path)
        if sd.get("width") and sd.get("height"):
            self.sizes.setdefault(ch, set()).add((int(sd["width"]), int(sd["height"])))
        return {"token": sd["token"], "filename": sd["filename"], "timestamp": sd["timestamp"],
                "T_world_ego": pose_matrix(pose["rotation"], pose["translation"], f"ego_pose {pose['token']}")}

    def _lidar(self, s: dict) -> dict:
        """Sample `s`'s LIDAR_TOP sweep: its file, the LiDAR's calibration and the ego pose at its time."""
        sd = get_record(self.nusc, "sample_data", s["data"][LIDAR_CHANNEL], f"sample {s['token']}")
        who = f"sample_data {sd['token']} ({LIDAR_CHANNEL})"
        cs = get_record(self.nusc, "calibrated_sensor", sd["calibrated_sensor_token"], who)
        pose = get_record(self.nusc, "ego_pose", sd["ego_pose_token"], who)
        path = self.root / sd["filename"]
        if not path.is_file() and not path.exists():
            raise DatasetError(f"{path}: LiDAR file is missing ({who})")
        regular_file(path, self.root, who)
        return {"token": sd["token"], "filename": sd["filename"],
                "T_ego_lidar": pose_matrix(cs["rotation"], cs["translation"], f"calibrated_sensor {cs['token']}"),
                "T_world_ego": pose_matrix(pose["rotation"], pose["translation"], f"ego_pose {pose['token']}")}

    def cameras(self, pixel_centre: str) -> list[CameraSpec]:
        """The rig in `NUSCENES_CAMERAS`: the first image's size (every sample_data must agree), the calibration."""
        cameras = []
        for ch in NUSCENES_CAMERAS:
            first = self.first_file[ch]
            h, w = read_image(within(self.root, first, ch)).shape[:2]
            other = sorted(self.sizes.get(ch, set()) - {(w, h)})
            if other:
                raise DatasetError(f"{self.tab / 'sample_data.json'}: {ch} sample_data give size "
                                   f"{other[0][0]}x{other[0][1]}, the first image {first} is {w}x{h}")
            (K, rot, trans), cs_token = self.calib[ch]
            K = K.copy()
            if pixel_centre == "integer":
                K[0, 2] += 0.5
                K[1, 2] += 0.5
            T = pose_matrix(rot, trans, f"calibrated_sensor {cs_token}")
            cameras.append(CameraSpec(ch, int(w), int(h), K, T, *_angles(K, T, w)))
        return cameras
