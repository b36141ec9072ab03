"""Poses at a continuous time (`scenes.timeline`): the frame's own pose at an integer index, the motion model's
pose between frames for a route's lines and arcs, and the last interval's motion continued beyond the ends."""
from __future__ import annotations

import numpy as np
import pytest

from scenes.route import poses_4x4
from scenes.timeline import pose_at, se3_exp, se3_log


def _route_poses(t: np.ndarray, speed: float = 12.0) -> np.ndarray:
    r, w = 25.0, speed / 25.0  # a circle of radius 25 m driven at `speed`
    yaw = w * t
    xy = np.stack([r * np.sin(yaw), r * (1 - np.cos(yaw))], 1)
    return poses_4x4(xy, yaw)


def test_an_integer_index_is_the_frame_itself():
    T = _route_poses(np.arange(4) / 10.0)
    for f in range(4):
        assert np.array_equal(pose_at(T, f), T[f])
        assert pose_at(T, float(f)).tobytes() == T[f].tobytes()


@pytest.mark.parametrize("x", [0.25, 1.5, 2.9])
def test_between_frames_on_an_arc_the_model_pose(x):
    fps = 10.0
    T = _route_poses(np.arange(4) / fps)
    want = _route_poses(np.array([x / fps]))[0]
    assert np.abs(pose_at(T, x) - want).max() < 1e-9


def test_beyond_the_ends_the_motion_continues():
    fps = 10.0
    T = _route_poses(np.arange(3) / fps)
    for x in (-0.4, 2.5):
        want = _route_poses(np.array([x / fps]))[0]
        assert np.abs(pose_at(T, x) - want).max() < 1e-9


def test_on_a_line_translation_is_linear_and_one_frame_is_constant():
    T = poses_4x4(np.array([[0.0, 0.0], [1.5, 0.0]]), np.zeros(2))
    assert np.allclose(pose_at(T, 0.4)[:3, 3], [0.6, 0.0, 0.0])
    assert np.array_equal(pose_at(T[:1], 0.7), T[0])


def test_exp_inverts_log_and_refuses_a_half_turn():
    T = _route_poses(np.array([0.37]))[0]
    T[:3, 3] += [0.1, -0.2, 0.3]
    assert np.abs(se3_exp(*se3_log(T)) - T).max() < 1e-12
    flip = np.diag([-1.0, -1.0, 1.0, 1.0])
    with pytest.raises(ValueError, match="cannot be interpolated"):
        se3_log(flip)
    with pytest.raises(ValueError, match="finite"):
        pose_at(T[None], float("nan"))
