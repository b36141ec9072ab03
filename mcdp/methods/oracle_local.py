"""ORACLE-local: Monodepth2's network whose input also holds the ground-truth depth of the overlap pixels.

The yardstick of local propagation (docs/results/propagation.md): how much could the pixels outside
the overlap gain if the overlap's depth were known exactly, and a network were free to carry it
anywhere? The network is `mcdp.methods.depth_bases.MonoDepthModel` (same encoder, decoder, training and losses as
Mono2) with two more input channels at frame t:

- ``1 / depth`` (1/m, clipped at 2) of every overlap pixel (its input field `OVERLAP_TRUTH`, read by
  `mcdp.truth.overlap_truth`: the overlap as the evaluation defines it, from the ground truth), 0 elsewhere;
- the overlap's validity (1 on overlap pixels).

They enter at every scale, as depth completion networks take given depth (NLSPN, PromptDA-style prompts):

- at the encoder: a 7x7 stride-2 convolution of their own (``given_encoder``), added to the encoder's first
  convolution before its batch norm;
- at every decoder output scale, full resolution included: a 3x3 convolution per scale (``given_heads``) of
  the channels resized (nearest) to that scale, added to the output's logit;
- and the given depth is kept where it is given (NLSPN's ``preserve_input``, CSPN's replacement step): at
  every scale, a given pixel's output is the given depth itself, so the network reproduces the depth it is
  handed exactly at full resolution (the copy test of docs/results/propagation.md holds by construction)
  and learns only what the given depth tells the pixels around it.

Every new layer is zero at start and has no bias, so a warm start from the pretraining begins as Mono2, and
an emptied input (all zeros) leaves Mono2's network: the new layers add nothing and nothing is replaced.
(Checkpoints from before these layers were renamed, ``hint`` and ``hint_heads``, load under the new names.)
Evaluated **filled** (as trained) and **emptied** (the sweep's cut: both channels 0, as for a camera
without neighbours); filled - emptied on non-overlap pixels is the most a perfect overlap delivers
locally at this budget. It reads ground truth at inference: a yardstick, never a method; every row
that carries it says ORACLE.

Example::

    net = build_network(cfg.model)   # model.method=oracle_local
    out = net(DepthInput(rgb, K, T_ego_cam, mask, nbr, {"overlap_truth": gt_overlap}, (OVERLAP_TRUTH,)))
    # gt_overlap: (B, N, 1, H, W) metres on the overlap, 0 off it; absent (or cut): emptied
"""
from __future__ import annotations

import torch
import torch.nn as nn
import torch.nn.functional as F

from mcdp.inputs import DepthInput, InputField
from mcdp.methods.depth_bases import MonoDepthModel
from mcdp.truth import overlap_truth_at

#: the inverse-depth channel is clipped here (1/m: nothing nearer than 0.5 m is told apart)
MAX_INV_DEPTH = 2.0

def _read_overlap_truth(reader, seq: str, frame: int) -> torch.Tensor:
    return overlap_truth_at(reader.ds, reader.mask_full, seq, frame, (reader.height, reader.width))


#: ORACLE-local's input field: each camera's overlap pixels' ground-truth depth at the training size, 0 elsewhere
OVERLAP_TRUTH = InputField("overlap_truth", _read_overlap_truth, "(N, 1, H, W) metres on the overlap, 0 elsewhere",
                      neighbours=True, truth=True)

#: the layers' names before they were renamed -> now (old checkpoints load under the new names)
_RENAMED = {"hint.": "given_encoder.", "hint_heads.": "given_heads."}


def given_channels(overlap_truth: torch.Tensor) -> torch.Tensor:
    """(B*N, 1, H, W) depth in metres on the overlap (0 elsewhere) -> (B*N, 2, H, W): [1/depth, valid]."""
    valid = (overlap_truth > 0).to(overlap_truth.dtype)
    inv = torch.where(valid > 0, 1.0 / overlap_truth.clamp(min=1e-3), torch.zeros_like(overlap_truth))
    return torch.cat([inv.clamp(max=MAX_INV_DEPTH), valid], 1)


class OracleLocalModel(MonoDepthModel):
    """Mono2 + the ground-truth depth of the overlap as input (module docstring)."""

    inputs = (OVERLAP_TRUTH,)

    def __init__(self, cfg, params=None):
        super().__init__(cfg, params)
        self.given_encoder = nn.Conv2d(2, 64, kernel_size=7, stride=2, padding=3, bias=False)
        self.given_heads = nn.ModuleList(nn.Conv2d(2, 1, kernel_size=3, padding=1, bias=False)
                                         for _ in range(self.cfg.scales))
        for conv in (self.given_encoder, *self.given_heads):
            nn.init.zeros_(conv.weight)
        self._register_load_state_dict_pre_hook(_rename_old_keys)

    @property
    def uses_neighbours(self) -> bool:
        """Its depth depends on what the other cameras see (the overlap's ground truth): the sweep also
        evaluates it emptied (cut)."""
        return True

    @classmethod
    def fresh_layers(cls, cfg) -> str:
        return "overlap-input layers"

    @staticmethod
    def _given(x: torch.Tensor, inp: DepthInput) -> torch.Tensor:
        """(B*N, 1, H, W) the overlap's given depth, zeros when emptied (no input, or the neighbours cut)."""
        truth = inp.get(OVERLAP_TRUTH)
        if truth is None or bool((inp.nbr < 0).all()):  # emptied: as a camera without neighbours
            return torch.zeros(x.shape[0], 1, *x.shape[-2:], device=x.device, dtype=x.dtype)
        return truth.reshape(x.shape[0], 1, *x.shape[-2:]).to(x.dtype)

    def encode(self, x: torch.Tensor, B: int, N: int, inp: DepthInput) -> list[torch.Tensor]:
        return self.encoder(x, extra=self.given_encoder(given_channels(self._given(x, inp))))

    def forward(self, inp: DepthInput, scales: int | None = None, refine_scales: int | None = None) -> dict:
        """`mcdp.methods.depth_bases.DepthModel.forward`, then every output scale takes the given depth (module
        docstring)."""
        out = super().forward(inp, scales, refine_scales)
        B, N, _, H, W = inp.rgb.shape
        given = self._given(inp.rgb.reshape(B * N, 3, H, W), inp)
        if not bool((given > 0).any()):
            return out  # emptied: the new layers would add zeros and nothing is replaced
        scale = out["scale"].view(-1, 1, 1, 1)
        min_disp, max_disp = 1.0 / self.cfg.max_depth, 1.0 / self.cfg.min_depth
        for key in [k for k in out if isinstance(k, tuple) and k[0] == "sig"]:
            _, stage, s = key
            sig = out[key]
            g = F.interpolate(given, size=sig.shape[-2:], mode="nearest")
            logit = torch.logit(sig.float().clamp(1e-6, 1 - 1e-6))
            new = torch.sigmoid(logit + self.given_heads[s](given_channels(g).to(sig.dtype)).float())
            valid = g > 0
            # the given depth (unscaled, as the network's own) as the output's value: its sigmoid-space inverse
            target = ((1.0 / (g.float() / scale).clamp(min=1e-3) - min_disp) / (max_disp - min_disp)).clamp(0, 1)
            new = torch.where(valid, target, new).to(sig.dtype)
            out[key] = new
            out["disp", stage, s] = self.to_depth(new)[0]
            up = new if s == 0 else F.interpolate(new, size=(H, W), mode="bilinear", align_corners=False)
            out["depth", stage, s] = self.to_depth(up)[1] * scale
        return out


def _rename_old_keys(state_dict, prefix, *_args) -> None:
    """A load_state_dict pre-hook: an ORACLE-local checkpoint from before the layers' rename loads as it was."""
    for key in [k for k in state_dict if k.startswith(prefix)]:
        rest = key[len(prefix):]
        for old, new in _RENAMED.items():
            if rest.startswith(old):
                state_dict[prefix + new + rest[len(old):]] = state_dict.pop(key)
