"""The pose network of the self-supervised system: Monodepth2's pose network shared across cameras (and
frames), and the joint pose of a rig that moves as one (SurroundDepth's scheme). The maths it builds on
(axis-angle rotations, rigid transforms, the rig motion) is `mcdp.rigid`.

Example::

    motions = PoseModel()(rgb)                          # {-1, +1: (B, N, 4, 4) T_src_tgt}
    motions = PoseModel()(rgb, T_ego_cam)               # every camera moves with one rigid rig motion
"""
from __future__ import annotations

import torch
import torch.nn as nn

from mcdp.networks import PoseNet
from mcdp.rigid import pose_from_axisangle, rig_motion


class PoseModel(nn.Module):
    """Monodepth2 pose network shared across cameras (and frames).

    forward(rgb (B, N, 3 frames, 3, H, W)) -> {offset: (B, N, 4, 4) T_src_tgt}
    for offset in (-1, +1): maps frame-t camera points into the camera at t+offset.
    Pairs are fed in temporal order ([t-1, t] and [t, t+1]); the -1 motion is inverted,
    as in Monodepth2.
    """

    def __init__(self, pretrained: str | None = None):
        super().__init__()
        self.net = PoseNet(pretrained)

    def forward(self, rgb: torch.Tensor, T_ego_cam: torch.Tensor | None = None) -> dict[int, torch.Tensor]:
        """``T_ego_cam`` (B, N, 4, 4) given: **joint** pose (SurroundDepth's scheme, `mcdp.methods.surround`): the
        cameras' predictions are moved into the ego frame, averaged into one rigid motion of the rig and
        moved back through the extrinsics, so every camera moves as one rig."""
        B, N, _, C, H, W = rgb.shape
        a = torch.cat([rgb[:, :, 0], rgb[:, :, 1]], 0).reshape(2 * B * N, C, H, W)  # earlier frames
        b = torch.cat([rgb[:, :, 1], rgb[:, :, 2]], 0).reshape(2 * B * N, C, H, W)  # later frames
        axisangle, translation = self.net(a, b)  # (2BN, 3) each
        aa_m, aa_p = axisangle.float().split(B * N)
        t_m, t_p = translation.float().split(B * N)
        if T_ego_cam is None:
            return {
                -1: pose_from_axisangle(aa_m, t_m, invert=True).view(B, N, 4, 4),
                1: pose_from_axisangle(aa_p, t_p, invert=False).view(B, N, 4, 4),
            }
        return {-1: rig_motion(aa_m, t_m, T_ego_cam, invert=True), 1: rig_motion(aa_p, t_p, T_ego_cam)}
