"""MCDP-local: MCDP with per-pixel basis weights, a mechanism built to carry the overlap to the rest
of the image (docs/results/propagation.md).

MCDP's weight network (`mcdp.networks.WeightNet`) pools its feature map to one vector per image, so
whatever the overlap shows reaches the non-overlap pixels only through n global numbers per image
and stage. Here the weight network keeps its spatial map:

- the same input as MCDP's (the target's reduced features, each neighbour's warped into the target
  with the previous stage's depth, and the validity of each), plus, per neighbour, its **depth warped
  into the target** (SGDE-style): ``log(D_j(p_j) / z_j(p))``, the log ratio of the depth the
  neighbour predicts where the target's pixel lands in it to the depth the target's point has in the
  neighbour's frame (0 where both agree; zero outside the overlap, like every warped input);
- the same three stride-2 convolutions, then two 3x3 convolutions at the coarsest level, so that
  the receptive field of each weight vector spans the tiny training width (96 px): the overlap at an
  image's edge can reach its far side;
- the three fully connected layers become 1x1 convolutions (the same layers applied at every cell,
  `LocalWeightNet.head`), so each cell of the map gets its own change of the n basis logits; the
  logits are soft-maxed per cell, and the weights are upsampled bilinearly to each depth scale
  (`mcdp.methods.base.combine_bases`).

With a spatially constant feature map, the head gives every cell what MCDP's pooled head gives the
image (tested): the only difference is that the map is not averaged away.

Example::

    net = build_network(cfg.model)   # model.method=mcdp_local
    out = net(DepthInput(rgb, K, T_ego_cam, mask, nbr))
    out["weights", "refine1"].shape        # (B*N, n, h/16, w/16): per-cell basis weights
"""
from __future__ import annotations

import torch
import torch.nn as nn

from mcdp.camera import range_items, unproject_lens
from mcdp.geometry import depth_to_points, transform_points, warp_by_depth
from mcdp.methods.depth_bases import DepthModel
from mcdp.networks import PyramidReduce, conv_bn_relu

#: the warped-depth log ratio is clipped to this magnitude (a factor e^2 ~ 7.4 either way)
LOG_RATIO_MAX = 2.0


class LocalWeightNet(nn.Module):
    """Per-pixel weight network of one refinement step (shared across cameras).

    ``reduce`` as `mcdp.networks.WeightNet`; ``forward(x)``: x (B, c_red * (1 + S) + 2 S, H/2, W/2)
    (own features, S warped neighbour features, S validities, S warped-depth log ratios) ->
    (B, n, H/16, W/16) change of the basis-weight logits per cell. The last layer starts near zero
    (``init_std``) so a fresh step starts from the previous weights.
    """

    def __init__(self, c_levels, n_slots: int, n_bases: int, c_red: int = 32, c_conv: int = 64, c_fc: int = 128,
                 init_std: float = 1e-3):
        super().__init__()
        self.reduce = PyramidReduce(c_levels, c_red)
        c_in = c_red * (1 + n_slots) + 2 * n_slots
        self.convs = nn.Sequential(
            conv_bn_relu(c_in, c_conv, 3, stride=2),
            conv_bn_relu(c_conv, c_conv, 3, stride=2),
            conv_bn_relu(c_conv, c_conv, 3, stride=2),
        )
        self.spread = nn.Sequential(conv_bn_relu(c_conv, c_conv, 3), conv_bn_relu(c_conv, c_conv, 3))
        self.head = nn.Sequential(
            nn.Conv2d(c_conv, c_fc, 1),
            nn.ReLU(inplace=True),
            nn.Conv2d(c_fc, c_fc, 1),
            nn.ReLU(inplace=True),
            nn.Conv2d(c_fc, n_bases, 1),
        )
        nn.init.normal_(self.head[-1].weight, std=init_std)
        nn.init.zeros_(self.head[-1].bias)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return self.head(self.spread(self.convs(x)))  # (B, n, h', w')


class LocalDepthModel(DepthModel):
    """MCDP with per-pixel basis weights fed the neighbours' warped features and depth (module docstring)."""

    weight_net_class = LocalWeightNet

    def _neighbour_features(self, red, mask_h, depth_h, K_h, T_ego_cam, T_cam_ego, nbr, device_type, lens=None):
        """MCDP's inputs (`DepthModel._neighbour_features`) + one warped-depth log ratio per neighbour slot (with a
        lens, `mcdp.camera.Lens`: both depths of the neighbour's depth kind)."""
        parts, valids = super()._neighbour_features(red, mask_h, depth_h, K_h, T_ego_cam, T_cam_ego, nbr,
                                                    device_type, lens)
        B, N = K_h.shape[:2]
        BN, (h, w) = B * N, depth_h.shape[-2:]
        idx = nbr.clamp(min=0)
        d_src = depth_h.reshape(B, N, 1, h, w)
        ratios = []
        for slot, valid in zip(self.slots, valids):
            j = idx[:, slot]
            T_src_tgt = (T_cam_ego[:, j] @ T_ego_cam).reshape(BN, 4, 4).float()
            K_t, K_s = K_h.reshape(BN, 3, 3).float(), K_h[:, j].reshape(BN, 3, 3).float()
            with torch.autocast(device_type, enabled=False):
                if lens is None:
                    d_nbr, _ = warp_by_depth(d_src[:, j].reshape(BN, 1, h, w).float(), depth_h.float(), K_t, K_s, T_src_tgt)
                    z_in_nbr = transform_points(T_src_tgt, depth_to_points(depth_h.float(), K_t))[:, 2:3]
                else:  # the neighbour's depth of its kind (range: the point's norm) against what it sees there
                    lt, ls = lens.of(), lens.of(j)
                    d_nbr, _ = warp_by_depth(d_src[:, j].reshape(BN, 1, h, w).float(), depth_h.float(), K_t, K_s,
                                             T_src_tgt, lens_tgt=lt, lens_src=ls)
                    p = transform_points(T_src_tgt, unproject_lens(depth_h.float(), K_t, lt))
                    z_in_nbr = torch.where(range_items(ls, BN, p.device).view(BN, 1, 1, 1), p.norm(dim=1, keepdim=True),
                                           p[:, 2:3])
                r = torch.log(d_nbr.clamp(min=1e-3) / z_in_nbr.clamp(min=1e-3)).clamp(-LOG_RATIO_MAX, LOG_RATIO_MAX)
            ratios.append(r.to(red.dtype) * valid)
        return parts, valids + ratios
