"""ORACLE-local: Monodepth2's network whose input also holds the ground-truth depth of the overlap pixels.

The yardstick of local propagation (docs/results/propagation.md): how much could the pixels outside
the overlap gain if the overlap's depth were known exactly, and a network were free to carry it
anywhere? The network is `mcdp.methods.mcdp.MonoDepthModel` (same encoder, decoder, training and losses as
Mono2) with two more input channels at frame t:

- ``1 / depth`` (1/m, clipped at 2) of every overlap pixel (`mcdp.oracle.overlap_truth`: the overlap as
  the evaluation defines it, from the ground truth), 0 elsewhere;
- the overlap's validity (1 on overlap pixels).

They enter through a 7x7 stride-2 convolution of their own (``hint``, zero at start, so a warm start
from the pretraining begins as Mono2), added to the encoder's first convolution before its batch norm.
Evaluated **filled** (as trained) and **emptied** (the sweep's cut: both channels 0, as for a camera
without neighbours); filled - emptied on non-overlap pixels is the most a perfect overlap delivers
locally at this budget. It reads ground truth at inference: a yardstick, never a method; every row
that carries it says ORACLE.

Example::

    model = build_depth_model(cfg.model)   # model.method=oracle_local
    out = model(rgb, K, T_ego_cam, mask, nbr, overlap_truth=gt_overlap)   # (B, N, 1, H, W) metres, 0 off it
"""
from __future__ import annotations

import torch
import torch.nn as nn

from mcdp.methods.mcdp import MonoDepthModel

#: the inverse-depth channel is clipped here (1/m: nothing nearer than 0.5 m is told apart)
MAX_INV_DEPTH = 2.0


def hint_channels(overlap_truth: torch.Tensor) -> torch.Tensor:
    """(B*N, 1, H, W) depth in metres on the overlap (0 elsewhere) -> (B*N, 2, H, W): [1/depth, valid]."""
    valid = (overlap_truth > 0).to(overlap_truth.dtype)
    inv = torch.where(valid > 0, 1.0 / overlap_truth.clamp(min=1e-3), torch.zeros_like(overlap_truth))
    return torch.cat([inv.clamp(max=MAX_INV_DEPTH), valid], 1)


class OracleLocalModel(MonoDepthModel):
    """Mono2 + the ground-truth depth of the overlap as input (module docstring)."""

    model = "oracle_local"
    reads_overlap_truth = True

    def __init__(self, cfg, params=None):
        super().__init__(cfg, params)
        self.hint = nn.Conv2d(2, 64, kernel_size=7, stride=2, padding=3, bias=False)
        nn.init.zeros_(self.hint.weight)

    @property
    def uses_neighbours(self) -> bool:
        """Its depth depends on what the other cameras see (the overlap's ground truth): the sweep also
        evaluates it emptied (cut)."""
        return True

    @classmethod
    def fresh_layers(cls, cfg) -> str:
        return "overlap-input layer"

    def encode(self, x: torch.Tensor, B: int, N: int, nbr: torch.Tensor, overlap_truth=None) -> list[torch.Tensor]:
        if overlap_truth is None or bool((nbr < 0).all()):  # emptied: as a camera without neighbours
            overlap_truth = torch.zeros(x.shape[0], 1, *x.shape[-2:], device=x.device, dtype=x.dtype)
        h = hint_channels(overlap_truth.reshape(x.shape[0], 1, *x.shape[-2:]).to(x.dtype))
        return self.encoder(x, extra=self.hint(h))
