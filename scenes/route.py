"""Analytic 2D paths (straight lines and circular arcs) for the ego and other vehicles.

A `Path` is evaluated exactly at any arc length s (metres): position, heading
(radians, counter-clockwise from world +x), so poses sampled at constant speed
have exact speed and smoothly varying heading, also inside turns. Beyond its ends
a path continues straight.

Example::

    from scenes.route import Path
    p = Path((0.0, -5.25), 0.0, [("line", 40.0), ("arc", 17.0, -1 / 11.0), ("line", 60.0)])
    xy, yaw = p.pose(np.array([0.0, 50.0]))   # (2, 2) metres, (2,) radians
"""
from __future__ import annotations

import numpy as np


class Path:
    """Chain of pieces starting at `start_xy` with heading `start_yaw` (radians).

    pieces: ("line", length_m) or ("arc", length_m, curvature_1pm) with curvature = 1/R,
    positive = turning left (counter-clockwise), negative = right.
    """

    def __init__(self, start_xy, start_yaw: float, pieces: list[tuple]) -> None:
        p0 = np.asarray(start_xy, dtype=np.float64)
        if p0.shape != (2,) or not np.all(np.isfinite(p0)):
            raise ValueError(f"start_xy must be 2 finite numbers, got {start_xy!r}")
        if not pieces:
            raise ValueError("pieces must hold at least one piece")
        self.pieces: list[tuple[float, float]] = []  # (length, curvature)
        for pc in pieces:
            if pc[0] == "line" and len(pc) == 2:
                length, k = float(pc[1]), 0.0
            elif pc[0] == "arc" and len(pc) == 3:
                length, k = float(pc[1]), float(pc[2])
            else:
                raise ValueError(f"piece must be ('line', length) or ('arc', length, curvature), got {pc!r}")
            if not length > 0:
                raise ValueError(f"piece length must be > 0, got {pc!r}")
            self.pieces.append((length, k))
        # state (x, y, yaw, s) at the start of each piece
        self._starts = []
        x, y, yaw, s = float(p0[0]), float(p0[1]), float(start_yaw), 0.0
        for length, k in self.pieces:
            self._starts.append((x, y, yaw, s))
            (x, y), yaw = self._advance(x, y, yaw, length, k)
            s += length
        self._end = (x, y, yaw, s)
        self.length = s

    @staticmethod
    def _advance(x, y, yaw, ds, k):
        ds = np.asarray(ds, dtype=np.float64)
        if k == 0.0:
            return (x + ds * np.cos(yaw), y + ds * np.sin(yaw)), yaw + 0.0 * ds
        yaw1 = yaw + k * ds
        return (x + (np.sin(yaw1) - np.sin(yaw)) / k, y - (np.cos(yaw1) - np.cos(yaw)) / k), yaw1

    def pose(self, s: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Positions (K, 2) metres and headings (K,) radians at arc lengths s (K,) (any real s)."""
        s = np.atleast_1d(np.asarray(s, dtype=np.float64))
        xy = np.zeros((len(s), 2))
        yaw = np.zeros(len(s))
        done = np.zeros(len(s), bool)
        before = s < 0
        if np.any(before):
            x, y, a, _ = self._starts[0]
            (px, py), pa = self._advance(x, y, a, s[before], 0.0)
            xy[before, 0], xy[before, 1], yaw[before] = px, py, pa
            done |= before
        for (length, k), (x, y, a, s0) in zip(self.pieces, self._starts):
            m = ~done & (s <= s0 + length)
            if np.any(m):
                (px, py), pa = self._advance(x, y, a, s[m] - s0, k)
                xy[m, 0], xy[m, 1], yaw[m] = px, py, pa
                done |= m
        if np.any(~done):
            x, y, a, s0 = self._end
            (px, py), pa = self._advance(x, y, a, s[~done] - s0, 0.0)
            xy[~done, 0], xy[~done, 1], yaw[~done] = px, py, pa
        return xy, yaw

    def polyline(self, s0: float, s1: float, step_m: float = 2.0, offset_m: float = 0.0) -> np.ndarray:
        """Sampled points (N, 2) from s0 to s1, shifted `offset_m` to the left; includes piece joints."""
        if not s1 > s0:
            raise ValueError(f"polyline needs s0 < s1, got {s0}, {s1}")
        joints = [st[3] for st in self._starts[1:]] + [self.length]
        s = np.unique(np.concatenate([np.linspace(s0, s1, max(2, int(np.ceil((s1 - s0) / step_m)) + 1)),
                                      [j for j in joints if s0 < j < s1]]))
        xy, yaw = self.pose(s)
        return xy + offset_m * np.stack([-np.sin(yaw), np.cos(yaw)], 1)


def poses_4x4(xy: np.ndarray, yaw: np.ndarray, z: float = 0.0) -> np.ndarray:
    """(K, 4, 4) float64 transforms with rotation yaw about +z and translation (x, y, z)."""
    k = len(yaw)
    T = np.tile(np.eye(4), (k, 1, 1))
    c, s = np.cos(yaw), np.sin(yaw)
    T[:, 0, 0], T[:, 0, 1], T[:, 1, 0], T[:, 1, 1] = c, -s, s, c
    T[:, 0, 3], T[:, 1, 3], T[:, 2, 3] = xy[:, 0], xy[:, 1], z
    return T
