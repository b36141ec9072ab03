"""The one definition of camera overlap, used by the manifest, the evaluator's overlap / non-overlap
split, the preview, the sweep report and `benchmarks/overlap_table.py`.

A valid pixel of camera i (ground-truth depth > 0, not ego body in i) *overlaps* neighbour j when
its ground-truth 3-D point

1. lies in front of j (z_j > `EPS_Z`),
2. projects inside j's image (0 <= u < W_j, 0 <= v < H_j; pixel centres at +0.5),
3. lands on a pixel that j's self-occlusion mask marks as scene, and
4. passes a z-test against j's ground-truth depth: z_j <= (1 + `Z_TOL`) * max(depth_j over the
   3x3 pixels around the landing pixel). The 3x3 maximum keeps slanted surfaces (the road far
   ahead changes depth by metres per pixel row at 96x64) and silhouette edges from failing by
   quantisation; a point hidden behind a nearer object in j fails. Sky (depth 0) never passes.

It is a property of the rig and the scene, never of a model.

Example::

    ov = overlap_mask(gt_i, K_i, T_i, gt_j, K_j, T_j, mask_i=m_i, mask_j=m_j)   # (H_i, W_i) bool
"""
from __future__ import annotations

import numpy as np

EPS_Z = 1e-6
Z_TOL = 0.05


def _arr(x, name: str, shape: tuple | None = None, dtype=np.float64) -> np.ndarray:
    a = np.asarray(x, dtype=dtype)
    if shape is not None and a.shape != shape:
        raise ValueError(f"{name} must have shape {shape}, got {a.shape}")
    return a


def overlap_mask(depth_i, K_i, T_ego_cam_i, depth_j, K_j, T_ego_cam_j, mask_i=None, mask_j=None,
                 z_tol: float = Z_TOL) -> np.ndarray:
    """Pixels of camera i that camera j sees (module docstring).

    Args:
        depth_i: (H_i, W_i) ground-truth z-depth of camera i (m), 0 = no surface.
        K_i: (3, 3) intrinsics of camera i at (H_i, W_i); T_ego_cam_i: (4, 4) camera i -> ego.
        depth_j: (H_j, W_j) ground-truth z-depth of camera j (m), 0 = no surface.
        K_j, T_ego_cam_j: the same for camera j at (H_j, W_j).
        mask_i, mask_j: optional (H, W) bool scene masks (True = scene, False = ego body).
        z_tol: relative z-test tolerance.

    Returns:
        (H_i, W_i) bool.
    """
    gi = _arr(depth_i, "depth_i")
    gj = _arr(depth_j, "depth_j")
    if gi.ndim != 2 or gj.ndim != 2:
        raise ValueError(f"depth_i and depth_j must have shape (H, W), got {gi.shape} and {gj.shape}")
    Ki, Kj = _arr(K_i, "K_i", (3, 3)), _arr(K_j, "K_j", (3, 3))
    Ti, Tj = _arr(T_ego_cam_i, "T_ego_cam_i", (4, 4)), _arr(T_ego_cam_j, "T_ego_cam_j", (4, 4))
    H, W = gi.shape
    valid = gi > 0
    if mask_i is not None:
        valid &= _arr(mask_i, "mask_i", (H, W), bool)
    mj = None if mask_j is None else _arr(mask_j, "mask_j", gj.shape, bool)
    v, u, pts = _points(gi, Ki, valid)
    seen = _seen_by_j(pts, np.linalg.inv(Tj) @ Ti, Kj, _near(gj), mj, z_tol)
    out = np.zeros((H, W), bool)
    out[v[seen], u[seen]] = True
    return out


def _points(depth: np.ndarray, K: np.ndarray, valid: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Pixel rows, columns and camera-frame 3-D points (3, N) of the `valid` pixels of a float64 depth map."""
    v, u = np.nonzero(valid)
    z = depth[v, u]
    pts = (np.linalg.inv(K) @ np.stack([u + 0.5, v + 0.5, np.ones_like(z)])) * z
    return v, u, pts


def _near(depth: np.ndarray) -> np.ndarray:
    """Maximum of `depth` over each pixel's 3x3 neighbourhood, 0 outside the image (no surface)."""
    H, W = depth.shape
    pad = np.pad(depth, 1, mode="constant")
    near = pad[:H, :W].copy()
    for dr in range(3):
        for dc in range(3):
            if dr or dc:
                np.maximum(near, pad[dr:dr + H, dc:dc + W], out=near)
    return near


def _seen_by_j(pts: np.ndarray, T_j_i: np.ndarray, K_j: np.ndarray, near_j: np.ndarray, mask_j, z_tol: float):
    """Indices into `pts` (camera i's points) that camera j sees: in front, inside, on scene, z-test."""
    Hj, Wj = near_j.shape
    pj = T_j_i[:3, :3] @ pts + T_j_i[:3, 3:4]
    zj = pj[2]
    front = zj > EPS_Z
    uvw = K_j @ pj
    zs = np.where(front, zj, 1.0)
    uj, vj = uvw[0] / zs, uvw[1] / zs
    idx = np.flatnonzero(front & (uj >= 0) & (uj < Wj) & (vj >= 0) & (vj < Hj))
    col = np.clip(np.floor(uj[idx]).astype(np.int64), 0, Wj - 1)
    row = np.clip(np.floor(vj[idx]).astype(np.int64), 0, Hj - 1)
    keep = np.ones(idx.size, bool) if mask_j is None else mask_j[row, col]
    near = near_j[row, col]
    keep &= (near > 0) & (zj[idx] <= (1.0 + z_tol) * near)
    return idx[keep]


def overlap_fraction_counts(depths: dict, masks: dict, cameras: list, neighbours,
                            z_tol: float = Z_TOL) -> dict[str, list[int]]:
    """For each ordered adjacent pair i->j: [valid pixels of i, of those overlapping j] (one rig frame).

    `depths` and `masks` are keyed by camera name; `cameras` are `synth.rig.CameraSpec`s. The same
    numbers as `overlap_mask` pair by pair; each camera's points and 3x3 depth maximum are computed
    once per frame, not once per pair and direction."""
    prep = {}
    for c in {k for pair in neighbours for k in pair}:
        cam = cameras[c]
        m = np.asarray(masks[cam.name]) > 127
        g = _arr(depths[cam.name], "depth")
        _, _, pts = _points(g, _arr(cam.K, "K", (3, 3)), (g > 0) & m)
        prep[c] = (pts, _near(g), m, _arr(cam.T_ego_cam, "T_ego_cam", (4, 4)))
    out = {}
    for a, b in neighbours:
        for i, j in ((a, b), (b, a)):
            (pts, _, _, Ti), (_, near_j, mj, Tj) = prep[i], prep[j]
            seen = _seen_by_j(pts, np.linalg.inv(Tj) @ Ti, _arr(cameras[j].K, "K", (3, 3)), near_j, mj, z_tol)
            out[f"{cameras[i].name}->{cameras[j].name}"] = [int(pts.shape[1]), int(seen.size)]
    return out
