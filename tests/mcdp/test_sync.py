"""model.sync (issue 48, item 1): with cameras that fire at their own times, a cross-camera warp of the
trainer goes through each camera's own pose (compensate) or the static rig (assume); synchronous data: equal."""
import numpy as np
import pytest
import torch

from mcdp.data import RigReader
from mcdp.geometry import depth_to_points, transform_points
from synth.config import DataConfig
from synth.rig import build_rig

SPEED, H, W = 15.0, 32, 48  # m/s along the ego's x; a small image
OFFSETS = np.array([0.0, 0.02, 0.0, 0.0, 0.0, 0.0])  # CAM_FRONT_RIGHT fires 20 ms after CAM_FRONT
N_WALL, C_WALL = np.array([1.0, 0.3, 0.0]) / np.hypot(1.0, 0.3), 30.0  # static scene: the wall n . p = c


class _Rig:
    """A reader of one static scene (a wall) seen by a rig on an ego driving straight at SPEED."""

    def __init__(self, offsets):
        cfg = DataConfig(camera={"width": W, "height": H})
        self.cameras = list(build_rig(cfg.rig, cfg.camera).cameras)
        self.camera_names = [c.name for c in self.cameras]
        self.offsets = offsets

    def mask(self, name):
        return np.ones((H, W), bool)

    def n_frames(self, seq):
        return 3

    def T_world_cam(self, c, f):
        T = np.eye(4)
        T[0, 3] = SPEED * (f / 10.0 + self.offsets[c])
        return T @ self.cameras[c].T_ego_cam

    def camera_poses(self, seq):
        ts = np.array([[f / 10.0 + o for o in self.offsets] for f in range(3)])
        T = np.stack([[self._own(c, f) for c in range(6)] for f in range(3)])
        return ts, T

    def _own(self, c, f):
        T_world_ego_f = np.eye(4)
        T_world_ego_f[0, 3] = SPEED * f / 10.0
        return np.linalg.inv(T_world_ego_f) @ self.T_world_cam(c, f)

    def depth(self, c, f):
        """Camera c's exact z-depth of the wall at its own time, (H, W)."""
        T = self.T_world_cam(c, f)
        v, u = np.mgrid[0:H, 0:W] + 0.5
        rays = np.stack([u, v, np.ones_like(u)], -1) @ np.linalg.inv(self.cameras[c].K).T  # z = 1
        d = rays @ T[:3, :3].T @ N_WALL
        return (C_WALL - T[:3, 3] @ N_WALL) / d


def _warp_error(ds, sync: str, f: int = 1) -> tuple[float, np.ndarray]:
    """Camera 0's exact depth of the wall warped into camera 1 with the trainer's poses (`RigReader.T_ego_cam_at`):
    the largest distance (m) of the warped points from the wall as camera 1 sees it at its own time, and the
    warped points in the world (3, H*W) by camera 1's true pose."""
    T = torch.from_numpy(RigReader(ds, H, W, sync=sync).T_ego_cam_at("s", f)).double()
    K0 = torch.from_numpy(ds.cameras[0].K)[None]
    p0 = depth_to_points(torch.from_numpy(ds.depth(0, f))[None, None], K0)  # (1, 3, H, W) in camera 0
    p1 = transform_points((torch.linalg.inv(T[1]) @ T[0])[None], p0)[0].reshape(3, -1).numpy()
    T1 = ds.T_world_cam(1, f)
    world = T1[:3, :3] @ p1 + T1[:3, 3:]  # where the warp puts the points in the world, seen from camera 1
    return float(np.abs(world.T @ N_WALL - C_WALL).max()), world


def test_compensate_warps_through_each_cameras_own_pose():
    ds = _Rig(OFFSETS)
    err, _ = _warp_error(ds, "compensate")
    assert err < 1e-5  # the static wall, warped between cameras 20 ms apart, lands on itself (float32 poses)


def test_assume_misses_by_the_ego_speed_times_the_offset():
    ds = _Rig(OFFSETS)
    _, own = _warp_error(ds, "compensate")
    _, assumed = _warp_error(ds, "assume")
    shift = np.linalg.norm(assumed - own, axis=0)
    assert shift == pytest.approx(np.full(shift.shape, SPEED * 0.02), rel=1e-5)  # 0.30 m: 15 m/s x 20 ms
    err, _ = _warp_error(ds, "assume")
    assert err == pytest.approx(SPEED * 0.02 * N_WALL[0], rel=1e-4)  # off the wall by its normal's share


def test_synchronous_both_are_the_static_rig_itself():
    ds = _Rig(np.zeros(6))
    static = RigReader(ds, H, W).T_ego_cam
    for sync in ("compensate", "assume"):
        assert np.allclose(RigReader(ds, H, W, sync=sync).T_ego_cam_at("s", 1), static, atol=1e-6)
    assert _warp_error(ds, "assume")[0] < 1e-4
    with pytest.raises(ValueError, match="model.sync"):
        RigReader(ds, H, W, sync="ignore")
