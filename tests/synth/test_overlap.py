"""The one overlap definition (synth.overlap): frustum, ego mask on both sides, z-test."""
from __future__ import annotations

import numpy as np
import pytest

from synth.overlap import overlap_mask


def two_camera_rig(shift_px=3, H=12, W=16, f=20.0, Z=10.0):
    """Two forward-looking cameras, j to the right of i by b = shift_px * Z / f; a wall at depth Z."""
    K = np.array([[f, 0, W / 2], [0, f, H / 2], [0, 0, 1.0]])
    b = shift_px * Z / f
    R = np.array([[0.0, 0, 1], [-1, 0, 0], [0, -1, 0]])  # OpenCV camera axes in ego (x fwd, y left, z up)
    T_i = np.eye(4)
    T_i[:3, :3] = R
    T_i[:3, 3] = [0, 0, 1.5]
    T_j = T_i.copy()
    T_j[:3, 3] = [0, -b, 1.5]  # to the right = -y in ego
    return K, T_i, T_j, np.full((H, W), Z)


def test_frustum_hand_computed_both_directions():
    K, T_i, T_j, gt = two_camera_rig(shift_px=3)
    ov = overlap_mask(gt, K, T_i, gt, K, T_j)
    # u_j = u_i - 3: columns 0..2 of camera i fall left of camera j's image
    assert ov[:, :3].sum() == 0 and ov[:, 3:].all()
    ov_j = overlap_mask(gt, K, T_j, gt, K, T_i)
    assert ov_j[:, 13:].sum() == 0 and ov_j[:, :13].all()


def test_ego_masks_of_both_cameras_and_missing_depth_exclude_pixels():
    K, T_i, T_j, gt = two_camera_rig(shift_px=3)
    gt0 = gt.copy()
    gt0[0, 5] = 0                       # no surface in i: never overlap
    mask_j = np.ones((12, 16), bool)
    mask_j[-2:, :] = False              # j's ego body on its two bottom rows
    mask_i = np.ones((12, 16), bool)
    mask_i[5, 7] = False                # i's own ego body
    ov = overlap_mask(gt0, K, T_i, gt, K, T_j, mask_i=mask_i, mask_j=mask_j)
    assert not ov[0, 5] and not ov[5, 7] and not ov[-2:].any()
    assert ov[:-2, 3:].sum() == 10 * 13 - 2


def test_a_point_hidden_behind_a_nearer_object_in_j_is_not_overlap():
    K, T_i, T_j, gt = two_camera_rig(shift_px=3)
    gt_j = gt.copy()
    gt_j[:, 4:9] = 4.0                  # j sees a pole at 4 m in front of the wall (10 m) on columns 4..8
    ov = overlap_mask(gt, K, T_i, gt_j, K, T_j)
    # i's columns u_i = u_j + 3: 3 + 4 .. 3 + 8 land on the pole in j, and the 3x3 maximum keeps the
    # pole's edge columns (j's 4 and 8, i's 7 and 11) overlapping: only i's columns 8..10 are hidden
    hidden = ~ov[:, 3:]
    assert hidden[:, 8 - 3:11 - 3].all() and hidden.sum() == 3 * 12
    # sky in j (no surface) hides nothing behind it: it fails the z-test
    gt_sky = gt.copy()
    gt_sky[:, :] = 0
    assert not overlap_mask(gt, K, T_i, gt_sky, K, T_j).any()


@pytest.mark.parametrize("tol, expect", [(0.0, False), (0.05, True)])
def test_the_z_test_tolerance_is_relative(tol, expect):
    K, T_i, T_j, gt = two_camera_rig(shift_px=0)
    gt_j = gt / 1.03                    # j's surface 3 % nearer than i's point
    assert overlap_mask(gt, K, T_i, gt_j, K, T_j, z_tol=tol).all() == expect


def test_shapes_are_checked_naming_the_argument():
    K, T_i, T_j, gt = two_camera_rig()
    with pytest.raises(ValueError, match="mask_j"):
        overlap_mask(gt, K, T_i, gt, K, T_j, mask_j=np.ones((3, 3), bool))
    with pytest.raises(ValueError, match="K_j"):
        overlap_mask(gt, K, T_i, gt, np.eye(4), T_j)
