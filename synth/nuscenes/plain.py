"""The devkit's parts that the reader uses, without the devkit: its records from the JSON tables alone
(`PlainTables`) and its arithmetic step by step (`rotation_matrix`, `lidar_xyz`, `view_points`), so both
give the same bits (tests/synth/test_nuscenes_read.py compares them).

Where nuscenes-devkit cannot be installed (beside the ``viz`` extra: rerun-sdk needs numpy >= 2, the devkit
1.2.0 numpy < 2), `synth.nuscenes.tables.load_tables` and `synth.nuscenes.geometry` fall back to these, so
`synth view` can record a dataroot.

Example::

    nusc = PlainTables(root, "v1.0-mini")
    sd = nusc.get("sample_data", nusc.sample[0]["data"]["CAM_FRONT"])
"""
from __future__ import annotations

from pathlib import Path

import numpy as np

from synth.files import DatasetError, read_json


class PlainTables:
    """The part of the devkit's ``NuScenes`` that the reader uses (`synth.nuscenes.scan`), from the JSON
    tables alone: ``sensor``, ``scene``, ``get(table, token)``, ``dataroot``, ``version``, and the reverse
    index the devkit adds (``sample_data["channel"]``, ``sample["data"][channel]`` = the key-frame sample_data)."""

    TABLES = ("sensor", "calibrated_sensor", "ego_pose", "scene", "sample", "sample_data")

    def __init__(self, root: Path, version: str) -> None:
        self.dataroot, self.version = str(root), version
        self._by_token: dict[str, dict[str, dict]] = {}
        for name in self.TABLES:
            f = root / version / f"{name}.json"
            rows = read_json(f, root, f"the {name} table")
            if not isinstance(rows, list) or not all(isinstance(r, dict) and "token" in r for r in rows):
                raise DatasetError(f"{f}: must be a list of records with a token")
            setattr(self, name, rows)
            self._by_token[name] = {r["token"]: r for r in rows}
        for sd in self.sample_data:
            cs = self.get("calibrated_sensor", sd["calibrated_sensor_token"])
            sd["channel"] = self.get("sensor", cs["sensor_token"])["channel"]
        for s in self.sample:
            s["data"] = {}
        for sd in self.sample_data:
            if sd.get("is_key_frame"):
                self.get("sample", sd["sample_token"])["data"][sd["channel"]] = sd["token"]

    def get(self, table: str, token) -> dict:
        return self._by_token[table][token]  # KeyError for a missing token, as the devkit


def rotation_matrix(q: np.ndarray) -> np.ndarray:
    """pyquaternion's ``Quaternion(q).rotation_matrix`` step by step: [w, x, y, z] normalised first."""
    q = np.array(q, dtype=float)
    ss = np.dot(q, q)
    if not abs(1.0 - ss) < 1e-14 and ss > 0:
        q = q / np.sqrt(ss)
    w, x, y, z = q
    qm = np.array([[w, -x, -y, -z], [x, w, -z, y], [y, z, w, -x], [z, -y, x, w]])
    qb = np.array([[w, -x, -y, -z], [x, w, z, -y], [y, -z, w, x], [z, y, -x, w]])
    return np.dot(qm, qb.conj().transpose())[1:][:, 1:]


def lidar_xyz(path: Path) -> np.ndarray:
    """The devkit's ``LidarPointCloud.from_file(path).points[:3]``: (3, N) float32 of a ``.bin``."""
    if not str(path).endswith(".bin"):
        raise AssertionError(f"Unsupported filetype {path}")
    return np.fromfile(str(path), dtype=np.float32).reshape((-1, 5))[:, :3].T


def view_points(pc: np.ndarray, K: np.ndarray) -> np.ndarray:
    """The devkit's ``view_points(pc, K, normalize=True)[:2]`` step by step."""
    pad = np.eye(4)
    pad[:3, :3] = K
    uvw = np.dot(pad, np.concatenate((pc, np.ones((1, pc.shape[1])))))[:3, :]
    return (uvw / uvw[2:3, :].repeat(3, 0).reshape(3, pc.shape[1]))[:2]
