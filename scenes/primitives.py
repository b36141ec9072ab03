"""Mesh primitives for procedural scenes: boxes, cylinders, cones, spheres, quads, ribbons.

Every function returns a `scenes.model.Mesh` with float32 attributes, unit
normals, one texture `layer` and one linear-RGB `tint` for all its vertices.
Faces are flat shaded (each face has its own vertices), so a vertex normal is
exactly its face normal, and triangles are counter-clockwise seen from the side
their normal points to (the outside).

Texture coordinates are in metres times `uv_scale` (a float, or (su, sv)), so a
texture tiles at a physical scale whatever the object size. Texture convention
(shared with the renderer): a texture layer `tex` (S, S, 3) is sampled at
column `u * S`, row `v * S`, modulo S (repeat wrap, no flip). On vertical
surfaces u grows to the right as seen from outside and v grows DOWNWARD
(v = -(z - z_bottom) * sv), so textures are ordinary top-down images and a
tile's bottom edge sits on the object's bottom edge (facade floors line up).

Example::

    from scenes.primitives import box
    from scenes.textures import LAYER
    T = np.eye(4); T[:3, 3] = (10.0, 5.0, 6.0)
    bldg = box((12.0, 8.0, 12.0), LAYER["brick"], T=T, uv_scale=0.5)   # 12 triangles
"""
from __future__ import annotations

from typing import Sequence

import numpy as np

from scenes.model import Mesh
from scenes.polyline import check_polyline, left_normals, offset_polyline, segment_directions, arc_length
from scenes.meshing import (UV, check_uv_scale, cross3, finish_mesh, check_positive, wall_uvs, from_quads,
                            from_triangles)


# ---------------------------------------------------------------------------- primitives
def box(size_xyz: Sequence[float], layer: int, tint=(1.0, 1.0, 1.0), T: np.ndarray | None = None,
        uv_scale: UV = 1.0, faces: str = "+x-x+y-y+z-z") -> Mesh:
    """Axis-aligned box centred at the origin (before `T`), 12 triangles.

    size_xyz: (3,) edge lengths in metres (x, y, z).
    layer:    texture layer index; tint: (3,) linear RGB multiplier.
    T:        optional (4, 4) rigid transform applied last (box frame -> world).
    uv_scale: tiles per metre (float or (su, sv)); vertical faces: u from the face's left
              edge seen from outside, v = -(z - z_min) (tile bottom on the box bottom);
              horizontal faces: u = x - x_min, v = y - y_min.
    faces:    which faces to emit, e.g. "+x-x+y-y+z" omits the bottom (never seen on the ground).
    """
    s = np.asarray(size_xyz, dtype=np.float64)
    if s.shape != (3,) or not np.all(np.isfinite(s)) or np.any(s <= 0):
        raise ValueError(f"size_xyz must be 3 positive lengths in metres, got {size_xyz!r}")
    su, sv = check_uv_scale(uv_scale)
    hx, hy, hz = s / 2
    allf = {
        "+x": ([[hx, -hy, -hz], [hx, hy, -hz], [hx, hy, hz], [hx, -hy, hz]], [1, 0, 0]),
        "-x": ([[-hx, hy, -hz], [-hx, -hy, -hz], [-hx, -hy, hz], [-hx, hy, hz]], [-1, 0, 0]),
        "+y": ([[hx, hy, -hz], [-hx, hy, -hz], [-hx, hy, hz], [hx, hy, hz]], [0, 1, 0]),
        "-y": ([[-hx, -hy, -hz], [hx, -hy, -hz], [hx, -hy, hz], [-hx, -hy, hz]], [0, -1, 0]),
        "+z": ([[-hx, -hy, hz], [hx, -hy, hz], [hx, hy, hz], [-hx, hy, hz]], [0, 0, 1]),
        "-z": ([[-hx, hy, -hz], [hx, hy, -hz], [hx, -hy, -hz], [-hx, -hy, -hz]], [0, 0, -1]),
    }
    names = [faces[i:i + 2] for i in range(0, len(faces), 2)]
    if not names or any(n not in allf for n in names) or len(set(names)) != len(names):
        raise ValueError(f"faces must be a string of distinct '+x', '-x', '+y', '-y', '+z', '-z', got {faces!r}")
    c = np.array([allf[n][0] for n in names], dtype=np.float64)
    nrm = np.array([allf[n][1] for n in names], dtype=np.float64)
    uv = np.zeros((len(names), 4, 2))
    vert = nrm[:, 2] == 0
    if np.any(vert):
        uv[vert] = wall_uvs(c[vert], nrm[vert], -hz, su, sv)
    hor = ~vert
    uv[hor, :, 0] = (c[hor, :, 0] + hx) * su
    uv[hor, :, 1] = (c[hor, :, 1] + hy) * sv
    return finish_mesh(from_quads(c, uv, nrm, layer, tint), T)


def _ring(radius: float, segments: int) -> tuple[np.ndarray, np.ndarray]:
    a = np.linspace(0.0, 2 * np.pi, segments + 1)
    return radius * np.cos(a), radius * np.sin(a)


def _check_segments(segments: int, minimum: int = 3) -> int:
    if isinstance(segments, bool) or not isinstance(segments, (int, np.integer)) or segments < minimum:
        raise ValueError(f"segments must be an int >= {minimum}, got {segments!r}")
    return int(segments)


def cylinder(radius: float, height: float, layer: int, segments: int = 12, tint=(1.0, 1.0, 1.0),
             T: np.ndarray | None = None, uv_scale: UV = 1.0, caps: bool = True) -> Mesh:
    """Vertical prism approximating a cylinder: base disc at z = 0, top at z = `height`.

    radius, height: metres (> 0). segments: sides (>= 3); 2*segments triangles for the side
    plus 2*(segments-2) for the caps. uv: u = arc length, v = -z (times uv_scale).
    Rotate with `T` for a horizontal cylinder (e.g. a wheel).
    """
    r = check_positive("radius", radius)
    h = check_positive("height", height)
    n = _check_segments(segments)
    su, sv = check_uv_scale(uv_scale)
    x, y = _ring(r, n)
    c = np.zeros((n, 4, 3))
    c[:, 0, :2] = np.stack([x[:-1], y[:-1]], 1)
    c[:, 1, :2] = np.stack([x[1:], y[1:]], 1)
    c[:, 2, :2] = c[:, 1, :2]
    c[:, 3, :2] = c[:, 0, :2]
    c[:, 2:, 2] = h
    mid = 0.5 * (c[:, 0] + c[:, 1])
    mid[:, 2] = 0.0
    arc = 2 * np.pi * r / n
    uv = np.zeros((n, 4, 2))
    u0 = np.arange(n) * arc
    uv[:, 0, 0] = uv[:, 3, 0] = u0 * su
    uv[:, 1, 0] = uv[:, 2, 0] = (u0 + arc) * su
    uv[:, 2:, 1] = -h * sv
    parts = [from_quads(c, uv, mid, layer, tint)]
    if caps:
        parts.append(_disc(x[:-1], y[:-1], h, +1, layer, tint, su, sv))
        parts.append(_disc(x[:-1], y[:-1], 0.0, -1, layer, tint, su, sv))
    return finish_mesh(Mesh.merge(parts), T)


def _disc(x: np.ndarray, y: np.ndarray, z: float, up: int, layer, tint, su, sv) -> Mesh:
    """Convex polygon fan at height z facing +z (up=1) or -z (up=-1)."""
    n = len(x)
    tri = np.zeros((n - 2, 3, 3))
    tri[:, 0, :2] = [x[0], y[0]]
    tri[:, 1, :2] = np.stack([x[1:-1], y[1:-1]], 1)
    tri[:, 2, :2] = np.stack([x[2:], y[2:]], 1)
    tri[..., 2] = z
    uv = np.stack([tri[..., 0] * su, tri[..., 1] * sv], -1)
    return from_triangles(tri, uv, np.array([0.0, 0.0, float(up)]), layer, tint)


def cone(radius: float, height: float, layer: int, segments: int = 8, tint=(1.0, 1.0, 1.0),
         T: np.ndarray | None = None, uv_scale: UV = 1.0, base: bool = True) -> Mesh:
    """Cone with its base disc at z = 0 (radius metres) and apex at z = `height`.

    segments side triangles (+ segments-2 for the base when `base`). uv: u = arc length at
    the base, v = -z (times uv_scale). Good for conifer crowns.
    """
    r = check_positive("radius", radius)
    h = check_positive("height", height)
    n = _check_segments(segments)
    su, sv = check_uv_scale(uv_scale)
    x, y = _ring(r, n)
    tri = np.zeros((n, 3, 3))
    tri[:, 0, :2] = np.stack([x[:-1], y[:-1]], 1)
    tri[:, 1, :2] = np.stack([x[1:], y[1:]], 1)
    tri[:, 2, 2] = h
    arc = 2 * np.pi * r / n
    u0 = np.arange(n) * arc
    uv = np.zeros((n, 3, 2))
    uv[:, 0, 0] = u0 * su
    uv[:, 1, 0] = (u0 + arc) * su
    uv[:, 2, 0] = (u0 + arc / 2) * su
    uv[:, 2, 1] = -h * sv
    hint = 0.5 * (tri[:, 0] + tri[:, 1])
    hint[:, 2] = r * r / h  # outward and upward
    parts = [from_triangles(tri, uv, hint, layer, tint)]
    if base:
        parts.append(_disc(x[:-1], y[:-1], 0.0, -1, layer, tint, su, sv))
    return finish_mesh(Mesh.merge(parts), T)


def sphere_low(radii: float | Sequence[float], layer: int, segments: int = 8, rings: int = 5,
               tint=(1.0, 1.0, 1.0), T: np.ndarray | None = None, uv_scale: UV = 1.0) -> Mesh:
    """Low-poly ellipsoid centred at the origin (before `T`), flat shaded.

    radii: a radius or (rx, ry, rz) in metres. segments around z (>= 3), rings from pole to
    pole (>= 2); 2*segments*(rings-1) triangles. Good for deciduous tree crowns and bushes.
    """
    rr = np.broadcast_to(np.asarray(radii, dtype=np.float64), (3,))
    if not np.all(np.isfinite(rr)) or np.any(rr <= 0):
        raise ValueError(f"radii must be > 0 (a float or (rx, ry, rz)), got {radii!r}")
    n = _check_segments(segments)
    m = _check_segments(rings, 2)
    su, sv = check_uv_scale(uv_scale)
    th = np.linspace(0.0, np.pi, m + 1)          # polar angle from +z
    ph = np.linspace(0.0, 2 * np.pi, n + 1)
    P = np.stack([np.sin(th)[:, None] * np.cos(ph)[None], np.sin(th)[:, None] * np.sin(ph)[None],
                  np.cos(th)[:, None] * np.ones_like(ph)[None]], -1) * rr  # (m+1, n+1, 3)
    U = (ph * rr[:2].mean())[None, :].repeat(m + 1, 0) * su
    V = -(P[..., 2] + rr[2]) * sv
    UVg = np.stack([U, V], -1)
    tris, uvs = [], []
    for i in range(m):
        a, b = P[i, :-1], P[i, 1:]
        c, d = P[i + 1, :-1], P[i + 1, 1:]
        ua, ub, uc, ud = UVg[i, :-1], UVg[i, 1:], UVg[i + 1, :-1], UVg[i + 1, 1:]
        if i > 0:  # upper triangle (degenerate at the north pole)
            tris.append(np.stack([a, c, b], 1))
            uvs.append(np.stack([ua, uc, ub], 1))
        if i < m - 1:  # lower triangle (degenerate at the south pole)
            tris.append(np.stack([b, c, d], 1))
            uvs.append(np.stack([ub, uc, ud], 1))
    tri = np.concatenate(tris)
    uv = np.concatenate(uvs)
    hint = tri.mean(axis=1) / rr ** 2  # ellipsoid gradient: outward
    return finish_mesh(from_triangles(tri, uv, hint, layer, tint), T)


def quad(corners: np.ndarray, layer: int, uvs: np.ndarray | None = None, tint=(1.0, 1.0, 1.0),
         uv_scale: UV = 1.0, double_sided: bool = False) -> Mesh:
    """One planar quad from 4 corners (4, 3) in cyclic counter-clockwise order seen from the front.

    The normal is (c2 - c0) x (c3 - c1), normalised (the side the CCW order is seen from).
    uvs: optional (4, 2); default = metres in the quad's plane from c0 (u along c0->c1, v along
    normal x u, i.e. towards the c3 side, so c3 is "down" in the texture) times uv_scale.
    `double_sided` adds the back face (for thin signs).
    """
    c = np.asarray(corners, dtype=np.float64)
    if c.shape != (4, 3) or not np.all(np.isfinite(c)):
        raise ValueError(f"corners must be a finite (4, 3) array, got shape {c.shape}")
    n = cross3(c[2] - c[0], c[3] - c[1])
    if np.linalg.norm(n) < 1e-12:
        raise ValueError("corners span zero area")
    n /= np.linalg.norm(n)
    su, sv = check_uv_scale(uv_scale)
    if uvs is None:
        e1 = c[1] - c[0]
        e1 /= np.linalg.norm(e1)
        e2 = cross3(n, e1)  # in-plane, towards c3 side when CCW
        d = c - c[0]
        uv = np.stack([d @ e1 * su, d @ e2 * sv], 1)
    else:
        uv = np.asarray(uvs, dtype=np.float64)
        if uv.shape != (4, 2):
            raise ValueError(f"uvs must have shape (4, 2), got {uv.shape}")
    parts = [from_quads(c[None], uv[None], n[None], layer, tint)]
    if double_sided:
        parts.append(from_quads(c[None, ::-1].copy(), uv[None, ::-1].copy(), -n[None], layer, tint))
    return Mesh.merge(parts)


def ground_strip(polyline: np.ndarray, half_width: float, z: float, layer: int, tint=(1.0, 1.0, 1.0),
                 uv_scale: UV = 1.0, lateral_offset: float = 0.0, u_offset: float = 0.0) -> Mesh:
    """Flat horizontal ribbon along a 2D polyline, normals +z, CCW seen from above.

    polyline:       (N, 2) metres, the ribbon's centre (before `lateral_offset`).
    half_width:     metres; the ribbon spans [offset - half_width, offset + half_width] sideways.
    z:              height of the ribbon (e.g. 0 for asphalt, 0.01 for markings, 0.15 sidewalk).
    lateral_offset: metres to the left of the polyline (negative = right).
    uv:             u = (arc length + u_offset) * su, v = lateral position across the ribbon
                    (0 on its right edge) * sv. Corners are mitred, so curves have no gaps.
    Area = arc length * 2 * half_width for straight polylines.
    """
    p = check_polyline(polyline)
    hw = check_positive("half_width", half_width)
    su, sv = check_uv_scale(uv_scale)
    right = offset_polyline(p, float(lateral_offset) - hw)
    left = offset_polyline(p, float(lateral_offset) + hw)
    s = arc_length(p) + float(u_offset)
    k = len(p) - 1
    c = np.zeros((k, 4, 3))
    c[:, 0, :2], c[:, 1, :2] = right[:-1], right[1:]
    c[:, 2, :2], c[:, 3, :2] = left[1:], left[:-1]
    c[..., 2] = float(z)
    uv = np.zeros((k, 4, 2))
    uv[:, 0, 0] = uv[:, 3, 0] = s[:-1] * su
    uv[:, 1, 0] = uv[:, 2, 0] = s[1:] * su
    uv[:, 2:, 1] = 2 * hw * sv
    # all normals are +z: set directly (a mitred quad on a sharp bend may be slightly twisted)
    m = from_quads(c, uv, np.array([0.0, 0.0, 1.0]), layer, tint)
    m.normals[:] = np.array([0.0, 0.0, 1.0], np.float32)
    return _fix_ccw_up(m)


def _fix_ccw_up(m: Mesh) -> Mesh:
    """Reorder triangles of a horizontal mesh so every one is CCW seen from +z."""
    p = m.positions[m.indices.astype(np.int64)]
    cz = cross3(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0])[:, 2]
    idx = m.indices.copy()
    idx[cz < 0] = idx[cz < 0][:, ::-1]
    m.indices = idx
    return m


def sweep(polyline: np.ndarray, profile: np.ndarray, layer: int, tint=(1.0, 1.0, 1.0),
          uv_scale: UV = 1.0, u_offset: float = 0.0) -> Mesh:
    """Extrude a 2D cross-section along a 2D polyline (kerbs, barriers, hedges, walls).

    polyline: (N, 2) metres. profile: (P, 2) points (d, z): d = lateral offset (metres, left of
    the polyline positive), z = height. Each profile edge p_k -> p_{k+1} becomes a surface whose
    normal points to the edge's right in the (d, z) plane drawn with d to the right and z up,
    i.e. the 2D normal (dz, -dd): list a solid's outline COUNTER-CLOCKWISE (in that drawing) for
    outward normals, e.g. a kerb + sidewalk on the road's right edge (road at d > -3.5):
    [(-3.5, 0), (-3.5, 0.15), (-6.5, 0.15), (-6.5, 0)].
    uv: u = (arc length + u_offset) * su along the polyline, v = -(profile length) * sv.
    """
    p = check_polyline(polyline)
    prof = np.asarray(profile, dtype=np.float64)
    if prof.ndim != 2 or prof.shape[1] != 2 or len(prof) < 2:
        raise ValueError(f"profile must have shape (P, 2) with P >= 2, got {prof.shape}")
    su, sv = check_uv_scale(uv_scale)
    s = arc_length(p) + float(u_offset)
    seg_left = left_normals(segment_directions(p))             # (N-1, 2)
    offs = [offset_polyline(p, d) for d in prof[:, 0]]          # P x (N, 2)
    plen = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(prof, axis=0), axis=1))])
    quads, uvs, hints = [], [], []
    k = len(p) - 1
    for j in range(len(prof) - 1):
        (d0, z0), (d1, z1) = prof[j], prof[j + 1]
        if np.hypot(d1 - d0, z1 - z0) < 1e-9:
            continue
        a, b = offs[j], offs[j + 1]
        c = np.zeros((k, 4, 3))
        c[:, 0, :2], c[:, 1, :2], c[:, 2, :2], c[:, 3, :2] = a[:-1], a[1:], b[1:], b[:-1]
        c[:, 0, 2] = c[:, 1, 2] = z0
        c[:, 2, 2] = c[:, 3, 2] = z1
        nd, nz = (z1 - z0), -(d1 - d0)
        hint = np.concatenate([seg_left * nd, np.full((k, 1), nz)], axis=1)
        uv = np.zeros((k, 4, 2))
        uv[:, 0, 0] = uv[:, 3, 0] = s[:-1] * su
        uv[:, 1, 0] = uv[:, 2, 0] = s[1:] * su
        uv[:, 0, 1] = uv[:, 1, 1] = -plen[j] * sv
        uv[:, 2, 1] = uv[:, 3, 1] = -plen[j + 1] * sv
        quads.append(c), uvs.append(uv), hints.append(hint)
    if not quads:
        raise ValueError("profile has no edge of non-zero length")
    return from_quads(np.concatenate(quads), np.concatenate(uvs), np.concatenate(hints), layer, tint)


def gable_roof(size_xy: Sequence[float], height: float, roof_layer: int, gable_layer: int,
               roof_tint=(1.0, 1.0, 1.0), gable_tint=(1.0, 1.0, 1.0), T: np.ndarray | None = None,
               uv_scale: UV = 1.0, overhang: float = 0.3) -> Mesh:
    """Pitched (gable) roof: a triangular prism with its ridge along x, base at z = 0.

    size_xy: (2,) footprint of the walls (x = ridge direction, y = across), metres; the
    roof slopes overhang the walls by `overhang` metres on every side. height: ridge height
    above z = 0. Two sloped quads (`roof_layer`) + two gable triangles (`gable_layer`,
    flush with the walls) = 6 triangles. Place it on top of a `box` with `T`.
    """
    sz = np.asarray(size_xy, dtype=np.float64)
    if sz.shape != (2,) or np.any(sz <= 0) or not np.all(np.isfinite(sz)):
        raise ValueError(f"size_xy must be 2 positive lengths in metres, got {size_xy!r}")
    h = check_positive("height", height)
    o = float(overhang)
    if not (0 <= o < 5):
        raise ValueError(f"overhang must be in [0, 5) metres, got {overhang!r}")
    su, sv = check_uv_scale(uv_scale)
    hx, hy = sz / 2
    # slopes extended outward by the overhang, dropping along the same pitch
    drop = o * h / hy
    ex, ey, ez = hx + o, hy + o, -drop
    slope_len = float(np.hypot(ey, h - ez))
    quads = np.array([
        [[-ex, -ey, ez], [ex, -ey, ez], [ex, 0, h], [-ex, 0, h]],
        [[ex, ey, ez], [-ex, ey, ez], [-ex, 0, h], [ex, 0, h]],
    ])
    uvq = np.array([[[0, 0], [2 * ex, 0], [2 * ex, -slope_len], [0, -slope_len]]] * 2, dtype=np.float64)
    uvq[..., 0] *= su
    uvq[..., 1] *= sv
    roof = from_quads(quads, uvq, np.array([[0, -h, hy], [0, h, hy]], dtype=np.float64), roof_layer, roof_tint)
    tris = np.array([
        [[hx, -hy, 0], [hx, hy, 0], [hx, 0, h]],
        [[-hx, hy, 0], [-hx, -hy, 0], [-hx, 0, h]],
    ])
    uvt = np.array([[[0, 0], [2 * hy, 0], [hy, -h]]] * 2, dtype=np.float64)
    uvt[..., 0] *= su
    uvt[..., 1] *= sv
    gables = from_triangles(tris, uvt, np.array([[1.0, 0, 0], [-1.0, 0, 0]]), gable_layer, gable_tint)
    # the underside of the overhang: seen from street level below the eaves
    under = from_quads(quads[:, ::-1].copy(), uvq[:, ::-1].copy(), np.array([[0, h, -hy], [0, -h, -hy]], dtype=np.float64),
                       roof_layer, np.asarray(roof_tint, dtype=np.float64) * 0.6)
    return finish_mesh(Mesh.merge([roof, gables, under]), T)


def pose_2d(x: float, y: float, yaw: float, z: float = 0.0) -> np.ndarray:
    """(4, 4) float64 transform: rotation by `yaw` radians about +z, then translation (x, y, z)."""
    c, s = np.cos(yaw), np.sin(yaw)
    T = np.eye(4)
    T[:2, :2] = [[c, -s], [s, c]]
    T[:3, 3] = (x, y, z)
    return T
