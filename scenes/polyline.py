"""2D polyline maths for roads and routes (pure numpy).

A polyline is an (N, 2) float64 array of (x, y) world points in metres, N >= 2.
"Left" is the tangent rotated by +90 degrees (world z up), so with the ego frame
(x forward, y left) a positive lateral offset is to the left of the direction of
travel.

Example::

    from scenes.polyline import arc_length, offset_polyline
    line = np.array([[0.0, 0.0], [10.0, 0.0], [20.0, 5.0]])
    s = arc_length(line)                  # (3,) cumulative metres
    left = offset_polyline(line, 1.75)    # (3, 2), 1.75 m to the left
"""
from __future__ import annotations

import numpy as np


def check_polyline(polyline: np.ndarray, name: str = "polyline") -> np.ndarray:
    """Return `polyline` as (N, 2) float64 or raise ValueError naming `name`."""
    p = np.asarray(polyline, dtype=np.float64)
    if p.ndim != 2 or p.shape[1] != 2 or p.shape[0] < 2:
        raise ValueError(f"{name} must have shape (N, 2) with N >= 2, got {p.shape}")
    if not np.all(np.isfinite(p)):
        raise ValueError(f"{name} must be finite")
    seg = np.linalg.norm(np.diff(p, axis=0), axis=1)
    if np.any(seg <= 1e-9):
        raise ValueError(f"{name} has repeated consecutive points (zero-length segment)")
    return p


def arc_length(polyline: np.ndarray) -> np.ndarray:
    """Cumulative arc length (N,) in metres, starting at 0."""
    p = check_polyline(polyline)
    return np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(p, axis=0), axis=1))])


def segment_directions(polyline: np.ndarray) -> np.ndarray:
    """Unit direction of each segment, (N-1, 2)."""
    p = check_polyline(polyline)
    d = np.diff(p, axis=0)
    return d / np.linalg.norm(d, axis=1, keepdims=True)


def vertex_tangents(polyline: np.ndarray) -> np.ndarray:
    """Unit tangent at each vertex, (N, 2): mean of the adjacent segment directions."""
    d = segment_directions(polyline)
    t = np.concatenate([d[:1], d[:-1] + d[1:], d[-1:]], axis=0)
    n = np.linalg.norm(t, axis=1, keepdims=True)
    # a 180-degree reversal has no mean direction: fall back to the incoming segment
    bad = n[:, 0] < 1e-9
    if np.any(bad):
        t[bad] = np.concatenate([d[:1], d])[bad]
        n[bad] = 1.0
    return t / n


def left_normals(tangents: np.ndarray) -> np.ndarray:
    """Rotate unit tangents (N, 2) by +90 degrees: the left-hand normals."""
    t = np.asarray(tangents, dtype=np.float64)
    return np.stack([-t[:, 1], t[:, 0]], axis=1)


def offset_polyline(polyline: np.ndarray, offset_m: float) -> np.ndarray:
    """Polyline shifted sideways by `offset_m` (positive = left), mitred at vertices. (N, 2)."""
    p = check_polyline(polyline)
    d = segment_directions(p)
    t = vertex_tangents(p)
    nl = left_normals(t)
    # mitre: scale so the offset is exact for both adjacent segments
    seg_nl = left_normals(d)
    seg_for_vertex = np.concatenate([seg_nl[:1], seg_nl], axis=0)
    cos = np.clip(np.sum(nl * seg_for_vertex, axis=1), 0.25, 1.0)
    return p + nl * (float(offset_m) / cos)[:, None]


def interpolate(polyline: np.ndarray, s_query: np.ndarray) -> np.ndarray:
    """Points at arc lengths `s_query` (K,) metres along the polyline, (K, 2); clamped to the ends."""
    p = check_polyline(polyline)
    s = arc_length(p)
    q = np.clip(np.asarray(s_query, dtype=np.float64), 0.0, s[-1])
    return np.stack([np.interp(q, s, p[:, 0]), np.interp(q, s, p[:, 1])], axis=1)


def sub_polyline(polyline: np.ndarray, s0: float, s1: float) -> np.ndarray:
    """The part of the polyline between arc lengths s0 < s1 (clamped), (K, 2) with K >= 2."""
    p = check_polyline(polyline)
    s = arc_length(p)
    s0, s1 = float(np.clip(s0, 0.0, s[-1])), float(np.clip(s1, 0.0, s[-1]))
    if not s1 > s0 + 1e-6:
        raise ValueError(f"sub_polyline needs s0 < s1 inside [0, {s[-1]:.3f}], got {s0}, {s1}")
    inner = (s > s0 + 1e-6) & (s < s1 - 1e-6)
    return np.concatenate([interpolate(p, [s0]), p[inner], interpolate(p, [s1])], axis=0)


def distance_to_polyline(points: np.ndarray, polyline: np.ndarray) -> np.ndarray:
    """Euclidean distance (K,) from each 2D point (K, 2) to the polyline (its segments)."""
    p = check_polyline(polyline)
    q = np.asarray(points, dtype=np.float64).reshape(-1, 2)
    a = p[:-1][None]                       # (1, S, 2)
    ab = (p[1:] - p[:-1])[None]            # (1, S, 2)
    aq = q[:, None] - a                    # (K, S, 2)
    t = np.clip(np.sum(aq * ab, -1) / np.sum(ab * ab, -1), 0.0, 1.0)
    closest = a + t[..., None] * ab
    return np.min(np.linalg.norm(q[:, None] - closest, axis=-1), axis=1)
