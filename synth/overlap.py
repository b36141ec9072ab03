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
    (H, W), (Hj, Wj) = gi.shape, gj.shape
    valid = gi > 0
    if mask_i is not None:
        valid &= _arr(mask_i, "mask_i", (H, W), bool)
    v, u = np.nonzero(valid)
    z = gi[v, u]
    pts = (np.linalg.inv(Ki) @ np.stack([u + 0.5, v + 0.5, np.ones_like(z)])) * z
    T_j_i = np.linalg.inv(Tj) @ Ti
    pj = T_j_i[:3, :3] @ pts + T_j_i[:3, 3:4]
    zj = pj[2]
    front = zj > EPS_Z
    uvw = Kj @ pj
    zs = np.where(front, zj, 1.0)
    uj, vj = uvw[0] / zs, uvw[1] / zs
    ok = front & (uj >= 0) & (uj < Wj) & (vj >= 0) & (vj < Hj)
    col = np.clip(np.floor(np.where(ok, uj, 0)).astype(np.int64), 0, Wj - 1)
    row = np.clip(np.floor(np.where(ok, vj, 0)).astype(np.int64), 0, Hj - 1)
    if mask_j is not None:
        ok &= _arr(mask_j, "mask_j", (Hj, Wj), bool)[row, col]
    pad = np.pad(gj, 1, mode="constant")  # 0 outside the image: no surface
    near = np.max(np.stack([pad[row + dr, col + dc] for dr in range(3) for dc in range(3)]), axis=0)
    ok &= (near > 0) & (zj <= (1.0 + z_tol) * near)
    out = np.zeros((H, W), bool)
    out[v[ok], u[ok]] = True
    return out


def overlap_fraction_counts(depths: dict, masks: dict, cameras: list, neighbours) -> dict[str, list[int]]:
    """For each ordered adjacent pair i->j: [valid pixels of i, of those overlapping j] (one rig frame).

    `depths` and `masks` are keyed by camera name; `cameras` are `synth.rig.CameraSpec`s."""
    out = {}
    for a, b in neighbours:
        for i, j in ((a, b), (b, a)):
            ci, cj = cameras[i], cameras[j]
            mi, mj = masks[ci.name] > 127, masks[cj.name] > 127
            valid = (depths[ci.name] > 0) & mi
            ov = overlap_mask(depths[ci.name], ci.K, ci.T_ego_cam, depths[cj.name], cj.K, cj.T_ego_cam,
                              mask_i=mi, mask_j=mj)
            out[f"{ci.name}->{cj.name}"] = [int(valid.sum()), int(ov.sum())]
    return out
