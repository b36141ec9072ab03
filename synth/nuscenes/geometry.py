"""nuScenes' conventions as arithmetic: the rotation quaternion both ways (`rotation_matrix`, `pose_matrix`
for the reader; `rotation_to_quaternion` for the export), a table's ``camera_intrinsic`` checked
(`check_intrinsic`), a LIDAR_TOP file's points (`lidar_xyz`) and the pinhole projection (`view_points`).

Each of `rotation_matrix`, `lidar_xyz` and `view_points` is the devkit's own (pyquaternion, nuscenes-devkit)
where it is installed, else its twin in `synth.nuscenes.plain`, which gives the same bits.

Example::

    T = pose_matrix(cs["rotation"], cs["translation"], f"calibrated_sensor {cs['token']}")
    assert np.allclose(rotation_to_quaternion(T[:3, :3]), cs["rotation"])
"""
from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from synth.files import DatasetError, regular_file
from synth.nuscenes import plain

MAX_FOCAL_PX = 1e5  # a focal length above this (a 0.06 deg field of view at 100 px) is an error in the table


def rotation_matrix(q: np.ndarray) -> np.ndarray:
    """3x3 rotation of a quaternion [w, x, y, z] (normalised first): pyquaternion's ``rotation_matrix``,
    or the same formula where pyquaternion (a devkit dependency) is not installed."""
    try:
        from pyquaternion import Quaternion
    except ImportError:
        return plain.rotation_matrix(q)
    return Quaternion(q).rotation_matrix


def rotation_to_quaternion(R: np.ndarray) -> list[float]:
    """Unit quaternion [w, x, y, z] (nuScenes / pyquaternion order) of a 3x3 rotation, w >= 0: the inverse of
    `rotation_matrix` (the export writes calibrated_sensor and ego_pose with it)."""
    R = np.asarray(R, np.float64)
    tr = R[0, 0] + R[1, 1] + R[2, 2]
    if tr > 0:
        s = 2.0 * math.sqrt(tr + 1.0)
        q = [0.25 * s, (R[2, 1] - R[1, 2]) / s, (R[0, 2] - R[2, 0]) / s, (R[1, 0] - R[0, 1]) / s]
    elif R[0, 0] > R[1, 1] and R[0, 0] > R[2, 2]:
        s = 2.0 * math.sqrt(1.0 + R[0, 0] - R[1, 1] - R[2, 2])
        q = [(R[2, 1] - R[1, 2]) / s, 0.25 * s, (R[0, 1] + R[1, 0]) / s, (R[0, 2] + R[2, 0]) / s]
    elif R[1, 1] > R[2, 2]:
        s = 2.0 * math.sqrt(1.0 + R[1, 1] - R[0, 0] - R[2, 2])
        q = [(R[0, 2] - R[2, 0]) / s, (R[0, 1] + R[1, 0]) / s, 0.25 * s, (R[1, 2] + R[2, 1]) / s]
    else:
        s = 2.0 * math.sqrt(1.0 + R[2, 2] - R[0, 0] - R[1, 1])
        q = [(R[1, 0] - R[0, 1]) / s, (R[0, 2] + R[2, 0]) / s, (R[1, 2] + R[2, 1]) / s, 0.25 * s]
    q = np.asarray(q)
    q = q / np.linalg.norm(q)
    if q[0] < 0:
        q = -q
    return [float(x) for x in q]


def check_intrinsic(K: np.ndarray, where: str) -> np.ndarray:
    """`K` when it is a pinhole camera_intrinsic: 3x3, finite, fx and fy in (0, `MAX_FOCAL_PX`], last row
    [0, 0, 1]; else DatasetError naming `where` (the table and token) and the value."""
    if K.shape != (3, 3):
        raise DatasetError(f"{where}: camera_intrinsic must be 3x3, got shape {K.shape}")
    if not np.isfinite(K).all():
        raise DatasetError(f"{where}: camera_intrinsic holds a non-finite value (NaN or inf)")
    for name, f in (("fx", K[0, 0]), ("fy", K[1, 1])):
        if not 0 < f <= MAX_FOCAL_PX:
            raise DatasetError(f"{where}: camera_intrinsic {name} = {float(f):.6g} px; a focal length must be in "
                               f"(0, {MAX_FOCAL_PX:.0e}] px")
    if not np.allclose(K[2], [0.0, 0.0, 1.0], rtol=0, atol=1e-9):
        raise DatasetError(f"{where}: camera_intrinsic's last row must be [0, 0, 1]")
    return K


def pose_matrix(rotation, translation, where: str) -> np.ndarray:
    """4x4 of a nuScenes pose record (rotation [w, x, y, z], translation); DatasetError naming `where`."""
    try:
        q = np.asarray(rotation, np.float64)
        t = np.asarray(translation, np.float64)
        if q.shape != (4,) or t.shape != (3,) or not (np.isfinite(q).all() and np.isfinite(t).all()) or \
                not abs(np.linalg.norm(q) - 1.0) < 1e-3:
            raise ValueError
    except (TypeError, ValueError):
        raise DatasetError(f"{where}: rotation must be a unit quaternion [w, x, y, z] and translation 3 finite "
                           "numbers") from None
    T = np.eye(4)
    T[:3, :3] = rotation_matrix(q)
    T[:3, 3] = t
    return T


def lidar_xyz(path: Path) -> np.ndarray:
    """(3, N) float32 x, y, z of a LIDAR_TOP ``.bin`` (5 float32 per point): the devkit's
    ``LidarPointCloud.from_file``, or the same read without the devkit."""
    regular_file(path)
    try:
        from nuscenes.utils.data_classes import LidarPointCloud
    except ImportError:
        return plain.lidar_xyz(path)
    return LidarPointCloud.from_file(str(path)).points[:3]


def view_points(pc: np.ndarray, K: np.ndarray) -> np.ndarray:
    """(2, N) pixel coordinates of camera-frame points (3, N): the devkit's ``view_points(..., normalize=True)``
    or the same product without the devkit."""
    try:
        from nuscenes.utils.geometry_utils import view_points
    except ImportError:
        return plain.view_points(pc, K)
    return view_points(pc, K, normalize=True)[:2]
