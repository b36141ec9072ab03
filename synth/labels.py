"""Per-frame labels from what the renderer read back: semantic classes, object ids, forward optical flow and
the moving-object mask (the class table and each object's class: `scenes.labels`).

Forward flow t -> t+1 of a camera is computed, not rendered: each pixel with depth at t is lifted to 3-D,
moved with what it belongs to (the world for static surfaces; its object's pose t -> t+1 for a mover; the
camera itself for the ego body) and projected into the same camera at t+1. It is valid where that point
lands inside the image, in front of the camera, and is what the camera sees there at t+1: the rendered
depth at one of the four pixel centres around it is within `Z_TOL` of the point's and carries the same
object id (otherwise the point left the image or is hidden at t+1). Every lens row alike (issue 59): the
point is the camera table's ray times the depth of the camera's kind, it is projected through the camera
(`synth.camera.project`: "in front" is where the lens images it) and compared in that kind (z-depth, or range
for kannala_brandt); flow is recomputed so, never remapped from the faces a lens image is formed from.

Example::

    sem = semantic_map(out["layer"], out["instance"], out["ego"], out["depth"], classes_of_instances)
    flow, valid = forward_flow(depth0, inst0, ego0, K, T_wc0, T_wc1, motion, depth1, inst1)
"""
from __future__ import annotations

import numpy as np

from scenes.labels import CLASS, MATERIAL_CLASS
from synth import camera
from synth.protocol import pixel_rays

#: flow validity: |z_rendered(t+1) - z_moved| <= Z_TOL_REL z + Z_TOL_ABS (metres), at one of 4 neighbours
Z_TOL_REL = 0.03
Z_TOL_ABS = 0.02
_NO_SURFACE = CLASS["sky"]


def semantic_map(layer: np.ndarray, instance: np.ndarray, ego: np.ndarray, depth: np.ndarray,
                 instance_classes: np.ndarray) -> np.ndarray:
    """(H, W) uint8 class index: the material's class, the object's where it has one (a mover, a named
    class), ``ego`` on the ego body and ``sky`` exactly where there is no depth."""
    lut = np.append(MATERIAL_CLASS, np.uint8(_NO_SURFACE))  # layer -1 (no surface) -> the last entry
    cls = lut[np.where(layer < 0, len(MATERIAL_CLASS), np.clip(layer, 0, len(MATERIAL_CLASS) - 1))]
    obj = instance > 0
    if obj.any():
        own = instance_classes[np.clip(instance, 0, len(instance_classes) - 1)]
        named = obj & (own != _NO_SURFACE)
        cls = np.where(named, own, cls)
    cls = np.where(ego, np.uint8(CLASS["ego"]), cls)
    return np.where(depth > 0, cls, np.uint8(_NO_SURFACE)).astype(np.uint8)


def instance_map(instance: np.ndarray, ego: np.ndarray, depth: np.ndarray) -> np.ndarray:
    """(H, W) uint16 object id: 0 on stuff, the ego body and where there is no surface."""
    return np.where(ego | (depth <= 0), 0, instance).astype(np.uint16)


def forward_flow(depth0: np.ndarray, inst0: np.ndarray, ego0: np.ndarray, K, T_world_cam0: np.ndarray,
                 T_world_cam1: np.ndarray, motion: dict[int, np.ndarray], depth1: np.ndarray,
                 inst1: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Forward flow of one camera t -> t+1: ((H, W, 2) float32 pixels (du, dv), (H, W) bool valid).

    depth0 / inst0 / ego0: the camera's depth (of its depth kind), object ids and ego flag at t; depth1 / inst1 at
    t+1. K: a pinhole (3, 3) K or a `synth.camera.Intrinsics` (any lens row).
    motion: {object id: 4x4 world(t+1) <- world(t)} of the movers (T_world_obj(t+1) inv(T_world_obj(t)));
    every other surface is static, except the ego body, which moves with the camera (flow 0).
    """
    H, W = depth0.shape
    u, v = np.meshgrid(np.arange(W) + 0.5, np.arange(H) + 0.5)  # pixel centres
    z = depth0.astype(np.float64)
    pinhole = camera.model(K).name == "pinhole"
    if pinhole:
        rays = pixel_rays(K if not isinstance(K, camera.Intrinsics) else K.K, W, H)
    else:  # z = 1 or unit rays by the depth kind; a pixel without a ray (NaN) has no depth: the point 0
        rays = np.nan_to_num(np.ascontiguousarray(camera.rays(K, H, W).T).reshape(H, W, 3), nan=0.0)
    p0 = rays * z[..., None]  # camera-frame points at t
    T_c1_w = np.linalg.inv(T_world_cam1)
    M_static = T_c1_w @ T_world_cam0
    p1 = p0 @ M_static[:3, :3].T + M_static[:3, 3]
    for obj, M in motion.items():
        sel = inst0 == obj
        if sel.any():
            Mo = T_c1_w @ M @ T_world_cam0
            p1[sel] = p0[sel] @ Mo[:3, :3].T + Mo[:3, 3]
    p1[ego0] = p0[ego0]  # the body is fixed to the camera
    if pinhole:
        z1 = p1[..., 2]
        front = z1 > 1e-6
        uv1, _ = camera.project(K, p1.reshape(-1, 3).T)  # the camera table (front: its validity, z > 1e-6)
    else:  # the moved point's depth of the camera's kind; front: where the lens images it
        z1 = p1[..., 2] if camera.depth_kind(K) == "z_depth" else np.linalg.norm(p1, axis=-1)
        uv1, ok1 = camera.project(K, p1.reshape(-1, 3).T)
        front = ok1.reshape(H, W)
    u1 = np.where(front, uv1[0].reshape(H, W), -1.0)
    v1 = np.where(front, uv1[1].reshape(H, W), -1.0)
    flow = np.stack([u1 - u, v1 - v], -1).astype(np.float32)
    valid = (z > 0) & front & (u1 >= 0) & (u1 < W) & (v1 >= 0) & (v1 < H)
    seen = np.zeros_like(valid)
    i0 = np.floor(u1 - 0.5).astype(np.int64)
    j0 = np.floor(v1 - 0.5).astype(np.int64)
    tol = Z_TOL_REL * z1 + Z_TOL_ABS
    for dj in (0, 1):
        for di in (0, 1):
            i, j = np.clip(i0 + di, 0, W - 1), np.clip(j0 + dj, 0, H - 1)
            d = depth1[j, i]
            seen |= (d > 0) & (np.abs(d - z1) <= tol) & (inst1[j, i] == inst0)
    valid &= seen
    flow[~valid] = 0.0
    return flow, valid


def mover_motion(T_world_obj: dict[int, np.ndarray], frame: float, to: float | None = None) -> dict[int, np.ndarray]:
    """{object id: world(to) <- world(frame)} of movers given their (F, 4, 4) poses by id; `frame` and `to`
    (default frame + 1) are continuous frame indices (`scenes.timeline.pose_at`: at integers, the stored poses)."""
    from scenes.timeline import pose_at

    to = frame + 1 if to is None else to
    return {obj: pose_at(T, to) @ np.linalg.inv(pose_at(T, frame)) for obj, T in T_world_obj.items()}
