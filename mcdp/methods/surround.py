"""A SurroundDepth-style cross-view network (Wei et al., "SurroundDepth: Entangling Surrounding Views
for Self-Supervised Multi-Camera Depth Estimation", CoRL 2022), the method ``surround``: the rig's
overlap used at INFERENCE, by attention, without geometry.

Monodepth2's encoder and decoder (one sigmoid channel, stage "init"), with a cross-view transformer
block (`CrossViewBlock`) on the encoder's two coarsest feature maps (1/16: 256 channels, 1/32: 512
channels; SurroundDepth's CVT sits on every scale of its encoder, downsampled: the coarse scales are
where a token covers enough of the scene to find itself in a neighbour). Each block turns the N
cameras' feature maps of one rig into N*h*w tokens, adds a learned **camera embedding** (one vector
per camera index of the rig, as SurroundDepth's per-view embeddings) and a fixed 2-D sinusoidal
position inside the image, and lets every token attend to every token of every camera (one pre-norm
transformer layer: multi-head attention + MLP). No extrinsics, no depth: what links a pixel to its
neighbour's is learned from the images alone (geometry-free, unlike MCDP's warps). The block's result
is added to the features through a 1x1 convolution that starts at **zero**, so at its first step the
network is exactly its warm start (the shared pretraining's Monodepth2 head) and what it becomes is
what the attention learned.

**Cut** (``study.sweep.probes.Probed(pred, CUT)``, the neighbour table all -1): attention restricted to each camera
itself (a block-diagonal mask), so as trained - cut is what the other cameras contribute at inference.

Poses (SurroundDepth's joint pose): with ``scale.source=odometry`` (the sweep) the rig motion is given,
one rigid motion of the rig by construction; with a pose network (``velocity``) the shared pose network
predicts each camera's motion and `mcdp.rigid.rig_motion` averages them in the ego frame into one rigid
rig motion, moved back into every camera through the extrinsics (SurroundDepth fuses the cameras'
features before one pose decoder; averaging the decoded motions is the same constraint with Monodepth2's
pose network). SurroundDepth's SfM pseudo-depth pretraining is not built: the odometry / velocity scale
replaces what it is for (metric scale).

Sizes (`SurroundParams`, the run config's ``method_params`` section, e.g. ``method_params.d_model=256``;
left unset, the defaults below, and the run's hash is what it was before the section existed):
``d_model = 128`` token channels, ``heads = 4``, ``mlp_ratio = 2``, ``max_cameras = 16`` camera embeddings,
cross-view blocks at encoder ``levels = [3, 4]``. A checkpoint records them (its config), so evaluation and
prediction rebuild the network it trained.

Warm start (``model.init_from``): encoder and decoder from the shared pretraining exactly as for
``mono2``; the cross-view blocks (``cross_view.*``) start fresh and learn at ``train.weight_lr_mult``
x the rate (`mcdp.methods.depth_bases.DepthModel.fresh_parameters`).
"""
from __future__ import annotations

import math

import torch
import torch.nn as nn
import torch.nn.functional as F

from pydantic import Field, model_validator

from corelib.configlib import ConfigError, StrictModel
from mcdp.inputs import DepthInput
from mcdp.methods.depth_bases import MonoDepthModel
from mcdp.networks import ResnetEncoder


class SurroundParams(StrictModel):
    """SurroundDepth's sizes (``method_params``; module docstring). Bounded: a token is at most 1024 channels."""

    d_model: int = Field(128, ge=8, le=1024)
    heads: int = Field(4, ge=1, le=64)
    mlp_ratio: int = Field(2, ge=1, le=8)
    max_cameras: int = Field(16, ge=1, le=64)
    #: encoder levels with a cross-view block (0 = 1/2 ... 4 = 1/32), increasing
    levels: list[int] = Field(default_factory=lambda: [3, 4], min_length=1, max_length=5)

    @model_validator(mode="after")
    def _consistent(self):
        if self.d_model % 4 or self.d_model % self.heads:
            raise ValueError(f"d_model={self.d_model} must be a multiple of 4 (the position code) and of "
                             f"heads={self.heads}")
        if any(lv not in range(5) for lv in self.levels) or self.levels != sorted(set(self.levels)):
            raise ValueError(f"levels={self.levels} must be increasing encoder levels among 0-4")
        return self


def sinusoid_2d(h: int, w: int, d: int, device=None) -> torch.Tensor:
    """(h*w, d) fixed position code of a pixel in an h x w map: sin/cos of y and x at d/4 frequencies each,
    on coordinates normalised to [0, 1] (the same code at any resolution)."""
    f = torch.exp(torch.arange(d // 4, device=device, dtype=torch.float32) * (-math.log(100.0) / max(d // 4 - 1, 1)))
    y = (torch.arange(h, device=device, dtype=torch.float32) + 0.5) / h
    x = (torch.arange(w, device=device, dtype=torch.float32) + 0.5) / w
    ay = (y[:, None] * f[None] * 2 * math.pi)[:, None].expand(h, w, -1)
    ax = (x[:, None] * f[None] * 2 * math.pi)[None].expand(h, w, -1)
    return torch.cat([ay.sin(), ay.cos(), ax.sin(), ax.cos()], -1).reshape(h * w, d)


class CrossViewBlock(nn.Module):
    """One transformer layer over the tokens of all cameras of a rig at one feature level.

    forward(f (B*N, c, h, w), B, N, cut) -> (B*N, c, h, w): f + out(block(tokens)), ``out`` zero at init.
    """

    def __init__(self, channels: int, p: SurroundParams):
        super().__init__()
        d = self.d = p.d_model
        self.heads = p.heads
        self.inp = nn.Conv2d(channels, d, 1)
        self.camera = nn.Parameter(torch.randn(p.max_cameras, d) * 0.02)
        self.norm1 = nn.LayerNorm(d)
        self.qkv = nn.Linear(d, 3 * d)
        self.proj = nn.Linear(d, d)
        self.norm2 = nn.LayerNorm(d)
        self.mlp = nn.Sequential(nn.Linear(d, p.mlp_ratio * d), nn.GELU(), nn.Linear(p.mlp_ratio * d, d))
        self.out = nn.Conv2d(d, channels, 1)
        nn.init.zeros_(self.out.weight)
        nn.init.zeros_(self.out.bias)

    def forward(self, f: torch.Tensor, B: int, N: int, cut: bool) -> torch.Tensor:
        BN, c, h, w = f.shape
        d, T = self.d, N * h * w
        x = self.inp(f).reshape(B, N, d, h * w).transpose(2, 3)  # (B, N, hw, d)
        x = x + self.camera[:N].view(1, N, 1, d).to(x.dtype) + sinusoid_2d(h, w, d, f.device).to(x.dtype)[None, None]
        x = x.reshape(B, T, d)
        q, k, v = self.qkv(self.norm1(x)).view(B, T, 3, self.heads, d // self.heads).permute(2, 0, 3, 1, 4)
        allowed = None
        if cut:  # each camera attends to itself only
            cam = torch.arange(N, device=f.device).repeat_interleave(h * w)
            allowed = cam[:, None] == cam[None, :]
        a = F.scaled_dot_product_attention(q, k, v, attn_mask=allowed)  # (B, heads, T, d / heads)
        x = x + self.proj(a.transpose(1, 2).reshape(B, T, d))
        x = x + self.mlp(self.norm2(x))
        x = x.view(B, N, h * w, d).transpose(2, 3).reshape(BN, d, h, w)
        return f + self.out(x)


class SurroundDepthModel(MonoDepthModel):
    """Monodepth2's network with cross-view attention between the cameras' encoder features."""

    #: with a pose network (scale.source velocity): one rigid rig motion (`mcdp.rigid.rig_motion`)
    joint_pose = True

    @classmethod
    def check_config(cls, cfg) -> None:
        super().check_config(cfg)
        if cfg.neighbours != "both":
            raise ConfigError(f"model.neighbours={cfg.neighbours}: model.method=surround attends to every camera; "
                              "leave model.neighbours at its default (both)")

    def __init__(self, cfg, params: SurroundParams | None = None):
        super().__init__(cfg, params if params is not None else SurroundParams())
        self.cross_view = nn.ModuleDict({str(lv): CrossViewBlock(self.encoder.num_ch_enc[lv], self.params)
                                         for lv in self.params.levels})

    @property
    def uses_neighbours(self) -> bool:
        return True

    @classmethod
    def check_rig(cls, params, n_cameras: int) -> None:
        p = params if params is not None else SurroundParams()
        if n_cameras > p.max_cameras:
            raise ConfigError(f"method_params.max_cameras={p.max_cameras}: model.method=surround has camera embeddings "
                              f"for at most that many cameras, the rig has {n_cameras}; set "
                              f"method_params.max_cameras={n_cameras} (at most 64)")

    @classmethod
    def fresh_layers(cls, cfg) -> str:
        return "cross-view blocks"

    def encode(self, x: torch.Tensor, B: int, N: int, inp: DepthInput) -> list[torch.Tensor]:
        if N > self.params.max_cameras:
            raise ValueError(f"model.method=surround has camera embeddings for at most {self.params.max_cameras} "
                             f"cameras (method_params.max_cameras), the rig has {N}")
        feats = self.encoder(x)
        cut = bool((inp.nbr < 0).all())
        for lv, block in self.cross_view.items():
            feats[int(lv)] = block(feats[int(lv)], B, N, cut)
        return feats
