"""Poses at a continuous time: between (and just beyond) a sequence's frames.

A `Scene` keeps the ego's and each mover's pose at the frame times ``f / fps`` only (the motion models that
made them, a route and a speed, are not kept), so a pose at ``t = (f + x) / fps`` is interpolated from the
frames around it. The interpolation is the screw motion (the constant body-frame twist) that takes frame
``i``'s pose to frame ``i + 1``'s: ``T(x) = T_i exp(s log(T_i^-1 T_i+1))``, ``s = x - i``. Every vehicle of
`scenes` drives at a constant speed along lines and circular arcs (`scenes.route`), and a constant body-frame
twist *is* constant speed along a line or an arc, so within one piece of a route the interpolated pose is the
motion model's own pose at ``t`` (to rounding); only an interval that straddles a line-arc joint is
approximated (by the one arc through both frame poses: centimetres at 10 fps). Before frame 0 and after the
last frame the first / last interval's twist is extrapolated (the same model, continued).

An integer frame index returns that frame's stored pose itself, so every render at the frame times
(synchronous cameras) is byte-identical to one made without this module.

Example::

    T = pose_at(scene.T_world_ego, 3.25)        # the ego a quarter of a frame after frame 3
    Ts = scene.mover_poses_at(3.25)             # every mover at that time
"""
from __future__ import annotations

import math

import numpy as np

_SMALL = 1e-6  # rotation angle (rad) below which the series forms of exp / log are used


def _hat(w: np.ndarray) -> np.ndarray:
    return np.array([[0.0, -w[2], w[1]], [w[2], 0.0, -w[0]], [-w[1], w[0], 0.0]])


def _coeffs(theta: float) -> tuple[float, float, float]:
    """a = sin t / t, b = (1 - cos t) / t^2, c = (t - sin t) / t^3 (series near 0)."""
    if theta < _SMALL:
        t2 = theta * theta
        return 1.0 - t2 / 6.0, 0.5 - t2 / 24.0, 1.0 / 6.0 - t2 / 120.0
    return (math.sin(theta) / theta, (1.0 - math.cos(theta)) / theta ** 2,
            (theta - math.sin(theta)) / theta ** 3)


def se3_log(T: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(omega, v): the twist whose exponential is the rigid 4x4 `T` (rotation angle < pi)."""
    R, t = T[:3, :3], T[:3, 3]
    cos = float(np.clip((np.trace(R) - 1.0) / 2.0, -1.0, 1.0))
    theta = math.acos(cos)
    if theta > math.pi - 1e-3:
        raise ValueError(f"a rotation of {math.degrees(theta):.1f} deg between two frames cannot be interpolated")
    a, b, _ = _coeffs(theta)
    W = (R - R.T) / (2.0 * a)  # hat(omega)
    w = np.array([W[2, 1], W[0, 2], W[1, 0]])
    # V^-1 = I - W/2 + (1 - a / (2 b)) / theta^2 W^2
    k = (1.0 / 12.0 + theta ** 2 / 720.0) if theta < _SMALL else (1.0 - a / (2.0 * b)) / theta ** 2
    V_inv = np.eye(3) - 0.5 * W + k * (W @ W)
    return w, V_inv @ t


def se3_exp(w: np.ndarray, v: np.ndarray) -> np.ndarray:
    """The rigid 4x4 transform exp of the twist (omega, v)."""
    theta = float(np.linalg.norm(w))
    a, b, c = _coeffs(theta)
    W = _hat(w)
    W2 = W @ W
    T = np.eye(4)
    T[:3, :3] = np.eye(3) + a * W + b * W2
    T[:3, 3] = (np.eye(3) + b * W + c * W2) @ v
    return T


def pose_at(T: np.ndarray, x: float) -> np.ndarray:
    """The pose of a (F, 4, 4) per-frame trajectory at the continuous frame index `x` (module docstring):
    ``T[x]`` itself at an integer ``0 <= x < F``; interpolated between frames, extrapolated beyond them."""
    F = len(T)
    if not math.isfinite(x):
        raise ValueError(f"frame index must be finite, got {x}")
    if float(x).is_integer() and 0 <= x < F:
        return T[int(x)]
    if F < 2:
        return T[0]  # one pose: nothing is known of the motion
    i = min(max(int(math.floor(x)), 0), F - 2)
    w, v = se3_log(np.linalg.inv(T[i]) @ T[i + 1])
    s = float(x) - i
    return T[i] @ se3_exp(s * w, s * v)
