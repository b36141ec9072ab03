import math

import numpy as np
import pytest

from synth.overlap import overlap_mask
from synth.rig import (CAMERA_NAMES, CameraConfig, RigConfig, build_rig, intrinsics_from_hfov, rotation_ego_cam,
                       solve_layout)


def test_rotation_conventions():
    # yaw 0 camera looks along ego +x, its x axis (right) is ego -y, its y axis (down) is ego -z
    R = rotation_ego_cam(0.0, 0.0)
    np.testing.assert_allclose(R @ [0, 0, 1], [1, 0, 0], atol=1e-12)
    np.testing.assert_allclose(R @ [1, 0, 0], [0, -1, 0], atol=1e-12)
    np.testing.assert_allclose(R @ [0, 1, 0], [0, 0, -1], atol=1e-12)
    # yaw +90 deg looks left (+y); pitch up tilts the optical axis up
    np.testing.assert_allclose(rotation_ego_cam(math.pi / 2, 0) @ [0, 0, 1], [0, 1, 0], atol=1e-12)
    assert (rotation_ego_cam(0, 0.2) @ [0, 0, 1])[2] > 0
    assert np.allclose(R.T @ R, np.eye(3)) and np.isclose(np.linalg.det(R), 1)


def test_intrinsics_hfov():
    K = intrinsics_from_hfov(320, 192, 90.0)
    assert K[0, 0] == pytest.approx(160.0) and K[0, 2] == 160.0 and K[1, 2] == 96.0
    # the image edge (u = 0) is at hfov/2
    assert math.degrees(math.atan((K[0, 2] - 0) / K[0, 0])) == pytest.approx(45.0)


@pytest.mark.parametrize("o", [0.1, 0.2, 0.3, 0.4, 0.5, 0.6])
def test_overlap_solver(o):
    hfov, s = solve_layout(o, "spacing", 70.0)
    assert hfov == 70.0 and (hfov - s) / hfov == pytest.approx(o)
    hfov, s = solve_layout(o, "fov", 70.0)
    assert s == 60.0 and (hfov - s) / hfov == pytest.approx(o)
    rig = build_rig(RigConfig(overlap=o, overlap_mode="fov"), CameraConfig())
    assert all(v == pytest.approx(o) for v in rig.pair_target_overlap().values())
    rig = build_rig(RigConfig(overlap=o, overlap_mode="spacing"), CameraConfig())
    t = rig.pair_target_overlap()
    for pair in ["CAM_FRONT-CAM_FRONT_RIGHT", "CAM_BACK_RIGHT-CAM_BACK", "CAM_BACK-CAM_BACK_LEFT",
                 "CAM_FRONT_LEFT-CAM_FRONT"]:
        assert t[pair] == pytest.approx(o)
    assert rig.names == list(CAMERA_NAMES)


def test_overlap_of_a_far_wall_is_the_geometric_overlap():
    # a far wall of constant depth: the pixel fraction seen by the neighbour ~ the hfov overlap
    rig = build_rig(RigConfig(overlap=0.3, overlap_mode="fov"), CameraConfig(width=200, height=100))
    a, b = rig.cameras[0], rig.cameras[1]
    far = np.full((100, 200), 1e4, np.float32)
    frac = overlap_mask(far, a.K, a.T_ego_cam, np.full((100, 200), 1e9), b.K, b.T_ego_cam).mean()
    # far wall: translation is negligible, the boundary is where FR's left edge (yaw -60 + hfov/2) falls
    u_edge = a.K[0, 2] + a.K[0, 0] * math.tan(math.radians(60.0 - a.hfov_deg / 2))
    assert frac == pytest.approx((a.width - u_edge) / a.width, abs=0.02)
