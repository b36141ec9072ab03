"""Synthetic spinning LiDAR sampled from the rendered ground-truth geometry (the six exact depth maps).

Model: a rotating multi-beam sensor (default: 32 beams like the HDL-32E of nuScenes' LIDAR_TOP,
elevations evenly spaced from -30.67 to +10.67 deg) fires one ray per beam and azimuth step from its
mount point on the ego; the whole sweep is instantaneous at the frame time (no motion during the
spin, no rolling shutter). The scene it sees is the union of the six cameras' depth maps turned into
triangle meshes: every 2x2 block of pixel centres with depth, back-projected with ``K`` (pixel centres
at +0.5) and ``T_ego_cam``, gives two triangles. Each lidar ray is intersected exactly with those
triangles (Moller-Trumbore) and keeps the nearest hit, so a return lies exactly on its beam and on
the surface the cameras see, interpolated between pixel centres (planar within a 2x2 pixel block).
Cameras that fire at their own times (``rig.trigger``): pass each with ``T_ego_cam`` its own pose in the ego
frame of the frame time (`synth.dataset.Dataset.camera_poses`, as the nuScenes export does), so every mesh is
registered in that one frame and a static surface seen by two cameras gives one return, as when synchronous.

Not meshed (no return there): sky (depth 0), ego body (mask), and triangles across a depth
discontinuity, i.e. that would meet the camera ray at a grazing angle below ``min_grazing_deg``
(a silhouette edge and very oblique, far road look alike in a depth map: far road at low camera
resolution is lost). Surfaces that no camera sees but the lidar would (its mount differs from the
cameras') are missing, so a ray may pass them and hit what lies behind. Hits inside the ego's
footprint (the car itself, the road under it) are dropped.

Points are returned in the lidar frame as nuScenes stores them: LIDAR_TOP has x right, y forward,
z up (``R_EGO_LIDAR`` rotates it into our ego frame, x forward, y left, z up); five float32 per point
(x, y, z, intensity, ring). ``intensity`` is a proxy: the luma (0..255) of the camera image at the hit
(no reflectance model). ``ring`` is the beam index, 0 = lowest elevation. `labelled_sweep` also gives each
point the label (e.g. semantic class) of the camera pixel its hit lies nearest to.

Example::

    cfg = LidarConfig(azimuth_res_deg=0.4)
    pts = simulate_sweep(cfg, ds.cameras, {c: ds.read_depth(seq, c, f) for c in ds.camera_names},
                         {c: ds.mask(c) for c in ds.camera_names})          # (N, 5) float32
"""
from __future__ import annotations

import math

import numpy as np
from pydantic import Field, model_validator

from corelib.configlib import StrictModel
from synth.protocol import pixel_rays
from synth.rig import CameraSpec

# LIDAR_TOP axes in the ego frame: lidar x = ego -y (right), lidar y = ego x (forward), lidar z = ego z.
R_EGO_LIDAR = np.array([[0.0, 1.0, 0.0], [-1.0, 0.0, 0.0], [0.0, 0.0, 1.0]])

# the ego body's footprint in the ego frame (synth.ego_body.ego_body_mesh: x -1.0..3.6, |y| <= 0.925), +0.1 m
EGO_FOOTPRINT = ((-1.1, 3.7), (-1.03, 1.03))


class LidarConfig(StrictModel):
    """Beam pattern and mount of the synthetic LIDAR_TOP (defaults: HDL-32E, nuScenes-like mount)."""

    beams: int = Field(32, ge=1, le=256)
    elevation_min_deg: float = Field(-30.67, ge=-89.0, le=89.0)
    elevation_max_deg: float = Field(10.67, ge=-89.0, le=89.0)
    azimuth_res_deg: float = Field(0.2, ge=0.01, le=10.0, description="azimuth step of one beam's spin")
    min_range_m: float = Field(1.0, ge=0.0, le=50.0)
    max_range_m: float = Field(70.0, gt=1.0, le=1000.0)
    mount_xyz_m: tuple[float, float, float] = Field((0.94, 0.0, 1.84), strict=False,
                                                    description="ego frame (x fwd, y left, z up)")
    min_grazing_deg: float = Field(1.0, ge=0.0, le=45.0, description="drop depth-map triangles seen more obliquely")
    drop_ego_footprint: bool = True

    @model_validator(mode="after")
    def _check(self) -> "LidarConfig":
        if self.elevation_max_deg < self.elevation_min_deg:
            raise ValueError("lidar.elevation_max_deg must be >= lidar.elevation_min_deg")
        if self.max_range_m <= self.min_range_m:
            raise ValueError("lidar.max_range_m must be > lidar.min_range_m")
        if not all(-10.0 <= v <= 10.0 for v in self.mount_xyz_m):  # NaN fails the comparison too
            raise ValueError(f"lidar.mount_xyz_m must be 3 finite numbers within 10 m of the ego origin, got "
                             f"{self.mount_xyz_m}")
        return self

    def elevations_rad(self) -> np.ndarray:
        if self.beams == 1:
            return np.array([math.radians(self.elevation_min_deg)])
        return np.radians(np.linspace(self.elevation_min_deg, self.elevation_max_deg, self.beams))

    def n_azimuth(self) -> int:
        return int(round(360.0 / self.azimuth_res_deg))

    def T_ego_lidar(self) -> np.ndarray:
        T = np.eye(4)
        T[:3, :3] = R_EGO_LIDAR
        T[:3, 3] = self.mount_xyz_m
        return T


def beam_directions(cfg: LidarConfig) -> np.ndarray:
    """(beams, n_azimuth, 3) unit ray directions in the lidar frame; azimuth 0 along lidar +x, counter-clockwise."""
    el = cfg.elevations_rad()[:, None]
    az = np.arange(cfg.n_azimuth()) * (2 * math.pi / cfg.n_azimuth())
    az = az[None, :]
    return np.stack(np.broadcast_arrays(np.cos(el) * np.cos(az), np.cos(el) * np.sin(az), np.sin(el)), -1)


def _camera_triangles(cam: CameraSpec, depth: np.ndarray, valid: np.ndarray, T_lidar_ego: np.ndarray,
                      min_grazing_rad: float, gray: np.ndarray | None, label: np.ndarray | None = None):
    """Triangles of one camera's depth mesh in the lidar frame: (T, 3, 3) vertices, (T, 3) gray or None,
    (T, 3) label of each vertex's pixel or None."""
    H, W = depth.shape
    rays = pixel_rays(cam.intrinsics, W, H)  # (H, W, 3): z = 1, or unit for a range camera (its depth kind)
    valid = valid & np.isfinite(rays).all(-1)  # a lens pixel without a ray
    P_cam = np.nan_to_num(rays) * depth[..., None].astype(np.float64)
    T = T_lidar_ego @ cam.T_ego_cam
    P = P_cam @ T[:3, :3].T + T[:3, 3]
    idx = np.arange(H * W).reshape(H, W)
    a, b, c, d = idx[:-1, :-1].ravel(), idx[:-1, 1:].ravel(), idx[1:, :-1].ravel(), idx[1:, 1:].ravel()
    tri = np.concatenate([np.stack([a, b, c], 1), np.stack([b, d, c], 1)])
    ok = valid.ravel()[tri].all(1)
    tri = tri[ok]
    Pc = P_cam.reshape(-1, 3)[tri]  # (T, 3, 3) camera frame
    n = np.cross(Pc[:, 1] - Pc[:, 0], Pc[:, 2] - Pc[:, 0])
    centroid = Pc.mean(1)
    cosang = np.abs((n * centroid).sum(1)) / (np.linalg.norm(n, axis=1) * np.linalg.norm(centroid, axis=1) + 1e-12)
    keep = cosang >= math.sin(min_grazing_rad)
    tri = tri[keep]
    g = None if gray is None else gray.reshape(-1).astype(np.float64)[tri]
    lab = None if label is None else label.reshape(-1)[tri]
    return P.reshape(-1, 3)[tri], g, lab


def simulate_sweep(cfg: LidarConfig, cameras: list[CameraSpec], depths: dict[str, np.ndarray],
                   masks: dict[str, np.ndarray], grays: dict[str, np.ndarray] | None = None) -> np.ndarray:
    """One instantaneous sweep: (N, 5) float32 (x, y, z, intensity, ring) in the lidar frame, sorted by
    (ring, azimuth). `depths`: z-depth per camera (0 = sky), `masks`: True = scene, `grays`: optional
    (H, W) luma 0..255 per camera for the intensity proxy (0 without)."""
    return labelled_sweep(cfg, cameras, depths, masks, grays)[0]


def labelled_sweep(cfg: LidarConfig, cameras: list[CameraSpec], depths: dict[str, np.ndarray],
                   masks: dict[str, np.ndarray], grays: dict[str, np.ndarray] | None = None,
                   labels: dict[str, np.ndarray] | None = None) -> tuple[np.ndarray, np.ndarray | None]:
    """`simulate_sweep`'s points and, with `labels` ((H, W) integer map per camera, e.g. semantic classes),
    each point's label: that of the pixel its hit lies nearest to (the triangle's vertex of largest
    barycentric weight), (N,) of the maps' dtype; None without `labels`."""
    T_lidar_ego = np.linalg.inv(cfg.T_ego_lidar())
    verts, gvals, lvals = [], [], []
    for cam in cameras:
        d = np.asarray(depths[cam.name])
        valid = (d > 0) & np.asarray(masks[cam.name], bool)
        V, g, lab = _camera_triangles(cam, d, valid, T_lidar_ego, math.radians(cfg.min_grazing_deg),
                                      None if grays is None else np.asarray(grays[cam.name]),
                                      None if labels is None else np.asarray(labels[cam.name]))
        verts.append(V)
        gvals.append(g if g is not None else np.zeros((len(V), 3)))
        lvals.append(lab)
    V = np.concatenate(verts) if verts else np.zeros((0, 3, 3))
    G = np.concatenate(gvals) if gvals else np.zeros((0, 3))
    L = None if labels is None else (np.concatenate(lvals) if lvals else np.zeros((0, 3), np.uint8))
    n_az = cfg.n_azimuth()
    empty = np.zeros((0, 5), np.float32)
    no_labels = None if L is None else L[:0, 0]
    if len(V) == 0:
        return empty, no_labels
    el_beams = cfg.elevations_rad()
    # angular bounding box of every triangle as seen from the lidar origin
    r = np.linalg.norm(V, axis=2)
    el = np.arcsin(np.clip(V[..., 2] / np.maximum(r, 1e-12), -1, 1))
    az = np.arctan2(V[..., 1], V[..., 0])
    az_rel = (az - az[:, :1] + math.pi) % (2 * math.pi) - math.pi  # unwrap around vertex 0
    az_lo, az_hi = az[:, 0] + az_rel.min(1), az[:, 0] + az_rel.max(1)
    step = 2 * math.pi / n_az
    j0, j1 = np.ceil(az_lo / step - 1e-9).astype(np.int64), np.floor(az_hi / step + 1e-9).astype(np.int64)
    eps = 1e-9
    k0 = np.searchsorted(el_beams, el.min(1) - eps, side="left")
    k1 = np.searchsorted(el_beams, el.max(1) + eps, side="right") - 1
    nj, nk = np.maximum(j1 - j0 + 1, 0), np.maximum(k1 - k0 + 1, 0)
    # a triangle spanning more than half the sky is a triangle around the lidar (never in practice): skip it
    nj = np.where(az_hi - az_lo > math.pi, 0, nj)
    count = nj * nk
    if count.sum() == 0:
        return empty, no_labels
    t_idx = np.repeat(np.arange(len(V)), count)
    offs = np.arange(count.sum()) - np.repeat(np.cumsum(count) - count, count)
    jj = j0[t_idx] + offs % nj[t_idx]
    kk = k0[t_idx] + offs // nj[t_idx]
    jj = jj % n_az
    beam_dirs = beam_directions(cfg)
    dirs = beam_dirs[kk, jj]  # (C, 3)
    # Moller-Trumbore, ray origin 0
    v0, v1, v2 = V[t_idx, 0], V[t_idx, 1], V[t_idx, 2]
    e1, e2 = v1 - v0, v2 - v0
    p = np.cross(dirs, e2)
    det = (e1 * p).sum(1)
    ok = np.abs(det) > 1e-12
    inv = np.where(ok, 1.0 / np.where(ok, det, 1.0), 0.0)
    s = -v0
    bu = (s * p).sum(1) * inv
    q = np.cross(s, e1)
    bv = (dirs * q).sum(1) * inv
    t = (e2 * q).sum(1) * inv
    tol = 1e-9
    hit = ok & (bu >= -tol) & (bv >= -tol) & (bu + bv <= 1 + tol) & (t >= cfg.min_range_m) & (t <= cfg.max_range_m)
    if not hit.any():
        return empty, no_labels
    ray = (kk * n_az + jj)[hit]
    t, bu, bv, ti = t[hit], bu[hit], bv[hit], t_idx[hit]
    order = np.lexsort((t, ray))
    first = np.ones(len(order), bool)
    first[1:] = ray[order][1:] != ray[order][:-1]
    sel = order[first]
    ray, t, bu, bv, ti = ray[sel], t[sel], bu[sel], bv[sel], ti[sel]
    k, j = ray // n_az, ray % n_az
    xyz = beam_dirs[k, j] * t[:, None]
    inten = (1 - bu - bv) * G[ti, 0] + bu * G[ti, 1] + bv * G[ti, 2]
    out = np.concatenate([xyz, inten[:, None], k[:, None].astype(np.float64)], 1)
    lab = None if L is None else L[ti, np.argmax(np.stack([1 - bu - bv, bu, bv], 1), axis=1)]
    if cfg.drop_ego_footprint:
        ego = xyz @ R_EGO_LIDAR.T + np.asarray(cfg.mount_xyz_m)
        (x0, x1), (y0, y1) = EGO_FOOTPRINT
        inside = (ego[:, 0] > x0) & (ego[:, 0] < x1) & (ego[:, 1] > y0) & (ego[:, 1] < y1)
        out = out[~inside]
        lab = None if lab is None else lab[~inside]
    return out.astype(np.float32), lab


def luma(rgb: np.ndarray) -> np.ndarray:
    """(H, W) float luma 0..255 of an sRGB uint8 image (Rec. 601 weights), the intensity proxy."""
    return rgb[..., :3].astype(np.float64) @ np.array([0.299, 0.587, 0.114])
