"""Flat-shaded meshes from quads and triangles, with the argument checks every primitive shares.

`from_quads` / `from_triangles` build a `scenes.model.Mesh` whose triangles are counter-clockwise
seen from the side their (hint) normal points to; the conventions are those of
`scenes.primitives` (its module docstring).

Example::

    m = from_quads(corners, uvs, normals, LAYER["asphalt"])    # corners (Q, 4, 3), uvs (Q, 4, 2)
"""
from __future__ import annotations

from typing import Sequence

import numpy as np

from scenes.model import Mesh

UV = float | Sequence[float]
_EYE3 = np.eye(3)
_ROW3 = np.array([0.0, 0.0, 0.0, 1.0])


def cross3(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Cross product over the last axis (np.cross is slow on the small arrays used here)."""
    a, b = np.broadcast_arrays(np.asarray(a, dtype=np.float64), np.asarray(b, dtype=np.float64))
    return np.stack([a[..., 1] * b[..., 2] - a[..., 2] * b[..., 1],
                     a[..., 2] * b[..., 0] - a[..., 0] * b[..., 2],
                     a[..., 0] * b[..., 1] - a[..., 1] * b[..., 0]], axis=-1)


# ---------------------------------------------------------------------------- checks
def check_layer(layer: int) -> int:
    if isinstance(layer, bool) or not isinstance(layer, (int, np.integer)) or layer < 0:
        raise ValueError(f"layer must be a non-negative int, got {layer!r}")
    return int(layer)


def check_tint(tint) -> np.ndarray:
    t = np.asarray(tint, dtype=np.float64)
    if t.shape != (3,) or not np.all(np.isfinite(t)) or np.any(t < 0):
        raise ValueError(f"tint must be 3 non-negative finite numbers (linear RGB), got {tint!r}")
    return t


def check_T(T) -> np.ndarray | None:
    if T is None:
        return None
    T = np.asarray(T, dtype=np.float64)
    if T.shape != (4, 4) or not np.all(np.isfinite(T)):
        raise ValueError(f"T must be a finite (4, 4) rigid transform, got shape {T.shape}")
    R = T[:3, :3]
    # np.allclose's tests without its overhead (x is finite here): |x - y| <= atol + 1e-5 |y|, with
    # atol 1e-6 for the rotation and allclose's default 1e-8 for the last row, as before
    if np.any(np.abs(R @ R.T - _EYE3) > 1e-6 + 1e-5 * _EYE3) or np.any(np.abs(T[3] - _ROW3) > 1e-8 + 1e-5 * _ROW3):
        raise ValueError("T must be rigid: orthonormal rotation and last row (0, 0, 0, 1)")
    return T


def check_uv_scale(uv_scale: UV) -> tuple[float, float]:
    s = np.broadcast_to(np.asarray(uv_scale, dtype=np.float64), (2,))
    if not np.all(np.isfinite(s)) or np.any(s <= 0):
        raise ValueError(f"uv_scale must be > 0 (a float or (su, sv)), got {uv_scale!r}")
    return float(s[0]), float(s[1])


def check_positive(name: str, value: float) -> float:
    v = float(value)
    if not (np.isfinite(v) and v > 0):
        raise ValueError(f"{name} must be a finite number > 0, got {value!r}")
    return v


# ---------------------------------------------------------------------------- builders
def _faces(corners, uvs, hint_normals, m: int):
    """(corners (K, m, 3), uvs (K, m, 2), hint normals (K, 3), K) as float64, shapes checked."""
    c = np.asarray(corners, dtype=np.float64)
    if c.ndim != 3 or c.shape[1:] != (m, 3):
        raise ValueError(f"corners must have shape (K, {m}, 3), got {c.shape}")
    k = len(c)
    uv = np.asarray(uvs, dtype=np.float64)
    if uv.shape != (k, m, 2):
        raise ValueError(f"uvs must have shape {(k, m, 2)}, got {uv.shape}")
    return c, uv, np.broadcast_to(np.asarray(hint_normals, dtype=np.float64), (k, 3)), k


def _unit_normals(n: np.ndarray, what: str) -> np.ndarray:
    ln = np.linalg.norm(n, axis=1, keepdims=True)
    if np.any(ln < 1e-12):
        raise ValueError(f"a {what} is degenerate (zero area)")
    return n / ln


def from_quads(corners: np.ndarray, uvs: np.ndarray, hint_normals: np.ndarray, layer: int,
               tint=(1.0, 1.0, 1.0)) -> Mesh:
    """Flat-shaded mesh from K quads.

    corners:      (K, 4, 3) metres, in cyclic order around each quad (planar or nearly).
    uvs:          (K, 4, 2) texture coordinates of the corners.
    hint_normals: (K, 3) any vector on the outward side; the exact normal is taken from
                  the quad's diagonals and the winding made counter-clockwise around it.
    """
    c, uv, h, k = _faces(corners, uvs, hint_normals, 4)
    n = _unit_normals(cross3(c[:, 2] - c[:, 0], c[:, 3] - c[:, 1]), "quad")
    n *= np.where(np.sum(n * h, axis=1) < 0, -1.0, 1.0)[:, None]
    base = (np.arange(k) * 4)[:, None]
    # diagonal-cross normal and corner order agree iff the cyclic order is CCW around n
    tri = np.array([[0, 1, 2], [0, 2, 3]])
    ccw = np.sum(cross3(c[:, 1] - c[:, 0], c[:, 2] - c[:, 0]) * n, axis=1) >= 0
    ccw2 = np.sum(cross3(c[:, 2] - c[:, 0], c[:, 3] - c[:, 0]) * n, axis=1) >= 0
    ccw = ccw | ccw2  # a triangle may be degenerate (e.g. a ribbon's folded mitre); use the other
    idx = np.where(ccw[:, None, None], tri[None], tri[None, :, ::-1])  # (K, 2, 3)
    idx = (idx + base[:, :, None]).reshape(-1, 3)
    layer = check_layer(layer)
    t = check_tint(tint)
    nv = 4 * k
    return Mesh(c.reshape(-1, 3), np.repeat(n, 4, axis=0), uv.reshape(-1, 2),
                np.full(nv, layer, np.int32), np.tile(t, (nv, 1)), idx)


def from_triangles(corners: np.ndarray, uvs: np.ndarray, hint_normals: np.ndarray, layer: int,
                   tint=(1.0, 1.0, 1.0)) -> Mesh:
    """Flat-shaded mesh from K triangles: corners (K, 3, 3), uvs (K, 3, 2), hint_normals (K, 3)."""
    c, uv, h, k = _faces(corners, uvs, hint_normals, 3)
    n = _unit_normals(cross3(c[:, 1] - c[:, 0], c[:, 2] - c[:, 0]), "triangle")
    flip = np.sum(n * h, axis=1) < 0
    n[flip] *= -1.0
    idx = np.arange(3 * k).reshape(k, 3)
    idx[flip] = idx[flip][:, ::-1]
    layer = check_layer(layer)
    t = check_tint(tint)
    nv = 3 * k
    return Mesh(c.reshape(-1, 3), np.repeat(n, 3, axis=0), uv.reshape(-1, 2),
                np.full(nv, layer, np.int32), np.tile(t, (nv, 1)), idx)


def finish_mesh(mesh: Mesh, T) -> Mesh:
    T = check_T(T)
    return mesh if T is None else mesh.transformed(T)


def wall_uvs(c: np.ndarray, outward: np.ndarray, z0: float, su: float, sv: float) -> np.ndarray:
    """uvs (K, 4, 2) for vertical quads: u along the face to the right seen from outside, v = -(z - z0)."""
    right = cross3([0.0, 0.0, 1.0], outward)  # looking along -n with z up: right = (-n) x up = up x n
    right /= np.maximum(np.linalg.norm(right, axis=-1, keepdims=True), 1e-12)
    # u = 0 at the face's left-most corner
    proj = np.einsum("kcj,kj->kc", c, right)
    u = (proj - proj.min(axis=1, keepdims=True)) * su
    v = -(c[..., 2] - z0) * sv
    return np.stack([u, v], axis=-1)
