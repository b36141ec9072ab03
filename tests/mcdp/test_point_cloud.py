"""`mcdp predict --ply`'s point cloud puts each camera where it was when it fired: with per-camera poses (a rig
rendered with ``rig.trigger``, or nuScenes) the points move by exactly the pose's offset."""
from types import SimpleNamespace

import numpy as np

from mcdp.predict import rig_point_cloud
from synth.camera import Intrinsics


def _ds():
    K = np.array([[10.0, 0, 4], [0, 10.0, 3], [0, 0, 1]])
    cams = [SimpleNamespace(name=n, K=K, intrinsics=Intrinsics("pinhole", K), T_ego_cam=np.eye(4)) for n in ("A", "B")]
    return SimpleNamespace(cameras=cams, mask=lambda name: np.ones((6, 8), np.uint8))


def test_each_camera_points_move_with_its_own_pose():
    ds = _ds()
    depths = [np.full((6, 8), 5.0, np.float32), np.full((6, 8), 7.0, np.float32)]
    rgbs = [np.zeros((6, 8, 3), np.uint8), np.full((6, 8, 3), 255, np.uint8)]
    static, cols = rig_point_cloud(ds, depths, rgbs, stride=1)
    poses = np.stack([np.eye(4), np.eye(4)])
    poses[1, :3, 3] = (0.3, 0.0, 0.0)  # camera B fired later, 0.3 m further along
    moved, cols2 = rig_point_cloud(ds, depths, rgbs, stride=1, poses=poses)
    assert static.shape == moved.shape == (96, 3) and np.array_equal(cols, cols2)
    b = cols[:, 0] == 255
    np.testing.assert_allclose(moved[~b], static[~b])
    np.testing.assert_allclose(moved[b] - static[b], np.tile([0.3, 0.0, 0.0], (48, 1)), atol=1e-6)
    np.testing.assert_allclose(static[~b][:, 2], 5.0)
    np.testing.assert_allclose(static[b][:, 2], 7.0)
