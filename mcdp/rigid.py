"""Rigid motions: axis-angle rotations and rigid transforms, a camera's motion from ego odometry, and one
rigid rig motion from every camera's predicted motion (SurroundDepth's joint pose). Pure tensor maths, no
network: the pose network that predicts the motions is `mcdp.pose.PoseModel`; the self-supervised step
(`mcdp.system`) reads these directly under ``scale.source=odometry``.

Example::

    T = pose_from_axisangle(aa, t)                      # (B, 4, 4)
    motion = odometry_camera_motion(T_world_ego, T_ego_cam, +1)   # (B, N, 4, 4) T_src_tgt
"""
from __future__ import annotations

import torch


def rotation_from_axisangle(axisangle: torch.Tensor) -> torch.Tensor:
    """Rodrigues: (B, 3) axis * angle (radians) -> (B, 3, 3) rotation."""
    angle = axisangle.norm(dim=1, keepdim=True).clamp(min=1e-7)  # (B, 1)
    axis = axisangle / angle
    x, y, z = axis[:, 0], axis[:, 1], axis[:, 2]
    c, s = torch.cos(angle[:, 0]), torch.sin(angle[:, 0])
    C = 1 - c
    R = torch.stack(
        [
            c + x * x * C, x * y * C - z * s, x * z * C + y * s,
            y * x * C + z * s, c + y * y * C, y * z * C - x * s,
            z * x * C - y * s, z * y * C + x * s, c + z * z * C,
        ],
        dim=1,
    ).view(-1, 3, 3)
    return R


def pose_from_axisangle(axisangle: torch.Tensor, translation: torch.Tensor, invert: bool = False) -> torch.Tensor:
    """(B, 3), (B, 3) -> (B, 4, 4) rigid transform [R | t] (or its inverse)."""
    R = rotation_from_axisangle(axisangle)
    T = torch.zeros(axisangle.shape[0], 4, 4, dtype=axisangle.dtype, device=axisangle.device)
    T[:, 3, 3] = 1.0
    if invert:
        Rt = R.transpose(1, 2)
        T[:, :3, :3] = Rt
        T[:, :3, 3] = -(Rt @ translation.unsqueeze(-1)).squeeze(-1)
    else:
        T[:, :3, :3] = R
        T[:, :3, 3] = translation
    return T


def odometry_camera_motion(T_world_ego: torch.Tensor, T_ego_cam: torch.Tensor, offset: int) -> torch.Tensor:
    """Camera motion from ego odometry: T_cam(t+n)_cam(t) for every camera.

    T_cam(t+n)_cam(t) = inv(T_ego_cam) @ inv(T_world_ego[t+n]) @ T_world_ego[t] @ T_ego_cam
    maps points in the camera frame at t into the same camera at t+n (the rig is rigid).

    Args:
        T_world_ego: (B, 3, 4, 4) ego poses at t-1, t, t+1.
        T_ego_cam: (B, N, 4, 4).
        offset: -1 or +1.
    Returns:
        (B, N, 4, 4) T_src_tgt with src = frame t+offset, tgt = frame t.
    """
    Tw = T_world_ego.double()
    T_egon_ego0 = torch.linalg.inv(Tw[:, 1 + offset]) @ Tw[:, 1]  # (B, 4, 4)
    Tc = T_ego_cam.double()
    out = torch.linalg.inv(Tc) @ T_egon_ego0[:, None] @ Tc  # (B, N, 4, 4)
    return out.to(T_ego_cam.dtype)


def rig_motion(aa: torch.Tensor, t: torch.Tensor, T_ego_cam: torch.Tensor, invert: bool = False) -> torch.Tensor:
    """One rigid rig motion from every camera's predicted motion [R(aa) | t] (camera frames, (B*N, 3) each):
    in the ego frame camera j's motion is R_ec R R_ec^T (axis-angle R_ec aa) with translation
    R_ec t + t_ec - R_ego t_ec; the axis-angles and translations are averaged over the cameras and the
    result is moved back into every camera, (B, N, 4, 4) (inverted, as the -1 motion, if ``invert``)."""
    B, N = T_ego_cam.shape[:2]
    X = T_ego_cam.float()
    R_ec, t_ec = X[..., :3, :3], X[..., :3, 3]  # (B, N, 3, 3), (B, N, 3)
    aa_e = (R_ec @ aa.view(B, N, 3, 1)).squeeze(-1)  # (B, N, 3)
    R_e = rotation_from_axisangle(aa_e.reshape(B * N, 3)).view(B, N, 3, 3)
    t_e = (R_ec @ t.view(B, N, 3, 1)).squeeze(-1) + t_ec - (R_e @ t_ec.unsqueeze(-1)).squeeze(-1)
    M_ego = pose_from_axisangle(aa_e.mean(1), t_e.mean(1))  # (B, 4, 4)
    M = torch.linalg.inv(X) @ M_ego[:, None] @ X  # (B, N, 4, 4)
    return torch.linalg.inv(M) if invert else M
