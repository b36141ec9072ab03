"""The MCDP depth model (depth bases + iterative weight refinement) and its Monodepth2 baseline, one family
in one module: `MonoDepthModel` is `DepthModel` with one sigmoid channel (``has_bases = False``: the same
code), and `DepthModel` is the class most other methods' networks subclass.

One `DepthModel` serves every camera of the rig: the B x N images go through
the encoder and decoder at once, and each refinement step's weight network is
shared across cameras (and independent across steps, paper sec. 3.2).

The bases are combined as `mcdp.methods.base` specifies (`combine_bases`: sigmoid space, softmax
weights, w_init = 1/n; the output -> depth map `disp_to_depth`). Each refinement step k adds its
weight network's output to the logits of step k-1 (residual refinement), so a fresh step starts
from the previous weights.

Stages are named "init", "refine1", ..., "refine{m}" (`mcdp.methods.base.stage_names`). Method
``mono2`` has one sigmoid channel and only "init" (`MonoDepthModel`). The shared pretraining
(``model.mono_head``, `study.sweep.pretrain`) adds a one-channel Monodepth2 head as the decoder's last
channel: stages "mono" (that head) and "init" (the n bases at weights 1/n), trained together on one
trunk.

Example::

    net = DepthModel(cfg.model)   # MonoDepthModel for model.method=mono2 (mcdp.methods.build_network)
    out = net(DepthInput(rgb, K, T_ego_cam, mask, nbr))   # shapes in DepthModel.forward
    depth = out["depth", "refine1", 0]                   # (B*N, 1, H, W) metres
"""
from __future__ import annotations

import torch
import torch.nn as nn
import torch.nn.functional as F

from corelib.configlib import ConfigError
from mcdp.config import ModelConfig
from mcdp.geometry import scale_intrinsics, warp_by_depth
from mcdp.inputs import DepthInput
from mcdp.methods.base import GT_MEDIAN, DepthNetwork, combine_bases, disp_to_depth, is_refined, resize_mask_to, stage_names
from mcdp.networks import DepthDecoder, ResnetEncoder, WeightNet

SLOTS = {"left": (0,), "right": (1,), "both": (0, 1)}


def masked_median(x: torch.Tensor, mask: torch.Tensor) -> torch.Tensor:
    """Per-image median over mask pixels: (B, 1, H, W), (B, 1, H, W) -> (B,)."""
    v = torch.where(mask > 0, x, torch.full_like(x, float("nan"))).flatten(1)
    med = v.nanmedian(dim=1).values
    return torch.nan_to_num(med, nan=1.0)


class DepthModel(DepthNetwork):
    """Depth network (+ bases and weight networks for MCDP), shared across cameras.

    Args:
        cfg: `ModelConfig`; refused (`check_config`) when this network cannot be built from it.
        params: the method's own parameters (`mcdp.methods.method_params`), or None (MCDP and Mono2 have none).

    ``n_out``: the decoder's depth channels: ``model.bases`` (MCDP), 1 (`MonoDepthModel`).
    """

    #: n depth bases combined by weights (MCDP); False: Monodepth2's one sigmoid channel
    has_bases = True
    #: the weight network of each refinement step: one weight vector per image (`mcdp.methods.local`: per pixel)
    weight_net_class = WeightNet

    @classmethod
    def check_config(cls, cfg: ModelConfig) -> None:
        """ConfigError, naming the key, for a model config this network cannot be built from."""
        if not cls.has_bases and cfg.refine_steps > 0:
            raise ConfigError(f"model.refine_steps must be 0 for model.method={cfg.method} (refinement needs "
                              "depth bases)")
        if not cls.has_bases and cfg.mono_head:
            raise ConfigError(f"model.mono_head (the shared pretraining's extra head) needs a model with depth "
                              f"bases, not model.method={cfg.method}")

    def __init__(self, cfg: ModelConfig, params=None):
        super().__init__()
        self.check_config(cfg)
        self.cfg = cfg
        self.params = params
        self.n_out = cfg.bases if self.has_bases else 1
        self.stages = (["mono"] if cfg.mono_head else []) + stage_names(cfg.refine_steps)
        self.slots = SLOTS[cfg.neighbours]
        self.encoder = ResnetEncoder(1, cfg.pretrained, cfg.encoder_layers)
        init_sig = None
        if cfg.init_depth is not None:  # invert disp_to_depth at init_depth
            min_disp, max_disp = 1.0 / cfg.max_depth, 1.0 / cfg.min_depth
            init_sig = (1.0 / cfg.init_depth - min_disp) / (max_disp - min_disp)
        n_dec = self.n_out + (1 if cfg.mono_head else 0)  # the mono head is the last channel
        self.decoder = DepthDecoder(self.encoder.num_ch_enc, n_out=n_dec, scales=cfg.scales, init_sigmoid=init_sig)
        c_levels = self.encoder.num_ch_enc[:3]  # features at 1/2, 1/4, 1/8: 64, 64, 128 channels
        self.weight_nets = nn.ModuleList(
            [
                self.weight_net_class(
                    c_levels,
                    len(self.slots),
                    self.n_out,
                    c_red=cfg.weight_channels,
                    c_conv=cfg.weight_conv_channels,
                    c_fc=cfg.weight_fc,
                    init_std=cfg.weight_init_std,
                )
                for _ in range(cfg.refine_steps)
            ]
        )

    @property
    def uses_neighbours(self) -> bool:
        """Whether a camera's depth depends on its neighbours' images at inference (then the sweep also
        evaluates it with them cut: ``study.sweep.probes.Probed(pred, CUT)``): MCDP with refinement steps,
        `mcdp.methods.surround`."""
        return len(self.weight_nets) > 0

    def fresh_parameters(self) -> list[nn.Parameter]:
        """Parameters no pretraining initialises (`mcdp.warmstart` copies only ``encoder.*`` and
        ``decoder.*``); they learn at ``train.weight_lr_mult`` x the rate."""
        return [p for name, p in self.named_parameters() if not name.startswith(("encoder.", "decoder."))]

    @classmethod
    def fresh_layers(cls, cfg: ModelConfig) -> str:
        return "weight networks" if cls.has_bases and cfg.refine_steps > 0 else ""

    def encode(self, x: torch.Tensor, B: int, N: int, inp: DepthInput) -> list[torch.Tensor]:
        """Encoder features of the B*N images x (BN, 3, H, W); a method may mix the cameras here
        (`mcdp.methods.surround`: ``inp.nbr`` all -1 when the neighbours are cut) or read its own input
        fields (`mcdp.methods.oracle_local`)."""
        return self.encoder(x)

    def to_depth(self, sig: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """(disp, depth) of a (combined) sigmoid map with this model's depth range."""
        return disp_to_depth(sig, self.cfg.min_depth, self.cfg.max_depth)

    def forward(self, inp: DepthInput, scales: int | None = None, refine_scales: int | None = None) -> dict:
        """Predict every stage's depth for a batch of rigs.

        Args:
            inp: `mcdp.inputs.DepthInput`: rgb (B, N, 3, H, W) frame-t images in [0, 1] (may be
                colour-augmented), K (B, N, 3, 3) at H x W, T_ego_cam (B, N, 4, 4), mask (B, N, 1, H, W) 1 =
                scene, nbr (N, 2) [left, right] neighbour indices, -1 = none; its field `GT_MEDIAN` (B, N), in
                an ORACLE-scaled run only: every depth is multiplied by median(GT) / median(init depth) per
                image (the public reference code's scaling).
            scales: decoder scales returned for "init" (default ``model.scales``; 1 = full resolution only).
            refine_scales: scales returned for refined stages (default = ``scales``).

        Returns:
            dict with, for every stage name st and scale s (images flattened to B*N):
              ("sig", st, s): (B*N, 1, H/2^s, W/2^s) combined sigmoid output,
              ("disp", st, s): same shape, disparity of the *unscaled* depth,
              ("depth", st, s): (B*N, 1, H, W) metres, upsampled from scale s,
              ("weights", st): (B*N, n) basis weights,
              "stages": list of stage names, "scale": (B*N,) depth scale applied (1 unless oracle).
        """
        rgb, mask = inp.rgb, inp.mask
        B, N, _, H, W = rgb.shape
        BN = B * N
        x = rgb.reshape(BN, 3, H, W)
        feats = self.encode(x, B, N, inp)
        bases = self.decoder(feats)  # {s: (BN, n, h, w)}
        n = self.n_out
        mono = None
        if self.cfg.mono_head:  # pretraining: a Monodepth2 head beside the n bases, same trunk
            mono = {s: b[:, n:] for s, b in bases.items()}
            bases = {s: b[:, :n] for s, b in bases.items()}
        n_init = self.cfg.scales if scales is None else min(int(scales), self.cfg.scales)
        n_ref = n_init if refine_scales is None else min(int(refine_scales), self.cfg.scales)
        out: dict = {"stages": self.stages, "bases": bases}

        def emit(stage: str, weights: torch.Tensor | None, scale: torch.Tensor) -> None:
            out["weights", stage] = weights
            for s in range(n_ref if is_refined(stage) else n_init):
                if weights is None:
                    sig = mono[s]
                else:
                    sig = combine_bases(bases[s], weights) if n > 1 else bases[s]
                disp, _ = self.to_depth(sig)
                out["sig", stage, s] = sig
                out["disp", stage, s] = disp
                up = sig if s == 0 else F.interpolate(sig, size=(H, W), mode="bilinear", align_corners=False)
                out["depth", stage, s] = self.to_depth(up)[1] * scale.view(BN, 1, 1, 1)

        logits = torch.zeros(BN, n, device=rgb.device, dtype=bases[0].dtype)
        scale = torch.ones(BN, device=rgb.device, dtype=torch.float32)
        mask_f = mask.reshape(BN, 1, H, W)
        oracle_gt_median = inp.get(GT_MEDIAN)
        if oracle_gt_median is not None:
            with torch.no_grad():
                sig0 = combine_bases(bases[0], torch.softmax(logits, 1)) if n > 1 else bases[0]
                med = masked_median(self.to_depth(sig0.float())[1], mask_f.float())
                scale = oracle_gt_median.reshape(BN).to(med.dtype) / med.clamp(min=1e-6)
        out["scale"] = scale
        if mono is not None:
            emit("mono", None, scale)
        emit("init", torch.softmax(logits, 1), scale)
        if not self.weight_nets:
            return out
        if not self.cfg.feature_ego_mask:  # the no-masks ablation of the weight networks' features (ModelConfig)
            mask_f = torch.ones_like(mask_f)
        self._refine(out, feats, bases, logits, scale, inp.K, inp.T_ego_cam, mask_f, inp.nbr, emit, rgb.device.type,
                     inp.lens)
        return out

    def _refine(self, out: dict, feats: list, bases: dict, logits: torch.Tensor, scale: torch.Tensor, K: torch.Tensor,
                T_ego_cam: torch.Tensor, mask_f: torch.Tensor, nbr: torch.Tensor, emit, device_type: str,
                lens=None) -> None:
        """The refinement steps: each weight network reads the target's reduced features and its neighbours',
        warped into it with the previous stage's depth, and moves the basis weights' logits; `emit` writes
        each refined stage into `out`. mask_f: (B*N, 1, H, W); K, T_ego_cam: (B, N, ...); lens: the cameras'
        `mcdp.camera.Lens` (None: pinhole)."""
        B, N = K.shape[:2]
        BN, (H, W), n = B * N, mask_f.shape[-2:], self.n_out
        # Feature pyramid at 1/2 resolution (paper: 1/2, 1/4, 1/8 resized to 1/2), reduced by each
        # step's PyramidReduce; ego body zeroed.
        h, w = feats[0].shape[-2:]
        mask_h = resize_mask_to(mask_f, h, w)  # (BN, 1, h, w)
        K_h = scale_intrinsics(K.reshape(BN, 3, 3), w / W, h / H).reshape(B, N, 3, 3)
        T_ego_cam = T_ego_cam.float()
        T_cam_ego = torch.linalg.inv(T_ego_cam)
        refine_stages = stage_names(self.cfg.refine_steps)
        for k, weight_net in enumerate(self.weight_nets, start=1):
            prev = refine_stages[k - 1]
            # The depth that places the neighbours' features is taken as given: the
            # refinement loss should change the weights, not move the previous
            # stage's depth through sampling coordinates.
            if 1 in bases:  # the decoder's 1/2-scale output is at the feature resolution
                sig_h = combine_bases(bases[1], out["weights", prev]) if n > 1 else bases[1]
            else:
                sig_h = F.interpolate(out["sig", prev, 0], size=(h, w), mode="bilinear", align_corners=False)
            depth_h = (self.to_depth(sig_h)[1] * scale.view(BN, 1, 1, 1)).detach()
            red = weight_net.reduce(feats[:3]) * mask_h  # (BN, c, h, w)
            parts, valids = self._neighbour_features(red, mask_h, depth_h, K_h, T_ego_cam, T_cam_ego, nbr,
                                                     device_type, lens)
            delta = weight_net(torch.cat(parts + valids, 1))  # (BN, n), or (BN, n, h', w') per pixel
            if delta.dim() == 4 and logits.dim() == 2:
                logits = logits[:, :, None, None]
            logits = logits + delta
            emit(refine_stages[k], torch.softmax(logits, 1), scale)

    def _neighbour_features(self, red: torch.Tensor, mask_h: torch.Tensor, depth_h: torch.Tensor, K_h: torch.Tensor,
                            T_ego_cam: torch.Tensor, T_cam_ego: torch.Tensor, nbr: torch.Tensor,
                            device_type: str, lens=None) -> tuple[list, list]:
        """([own features, each slot's warped neighbour features], [each slot's validity]) at the feature
        resolution: a neighbour's reduced features (and ego mask) warped into the target camera with `depth_h`
        through the rig extrinsics; valid where it lands on the neighbour's scene pixels and a neighbour exists
        (`nbr` -1: none, e.g. cut). lens: the cameras' `mcdp.camera.Lens` (None: pinhole)."""
        B, N = K_h.shape[:2]
        BN, (c, h, w) = B * N, red.shape[1:]
        has = (nbr >= 0).float()  # (N, 2)
        idx = nbr.clamp(min=0)  # (N, 2)
        red_src = torch.cat([red, mask_h], 1).reshape(B, N, c + 1, h, w)
        parts, valids = [red], []
        for slot in self.slots:
            j = idx[:, slot]  # (N,)
            src = red_src[:, j].reshape(BN, c + 1, h, w)
            T_src_tgt = (T_cam_ego[:, j] @ T_ego_cam).reshape(BN, 4, 4)
            with torch.autocast(device_type, enabled=False):  # geometry in float32 under AMP
                warped, valid = warp_by_depth(
                    src.float(), depth_h.float(), K_h.reshape(BN, 3, 3).float(),
                    K_h[:, j].reshape(BN, 3, 3).float(), T_src_tgt.float(),
                    lens_tgt=None if lens is None else lens.of(),
                    lens_src=None if lens is None else lens.of(j),
                )
            warped = warped.to(red.dtype)
            valid = valid.to(red.dtype)
            valid = valid * (warped[:, c:] > 0.99).to(valid.dtype) * has[:, slot].repeat(B).view(BN, 1, 1, 1)
            valid = valid * mask_h
            parts.append(warped[:, :c] * valid)
            valids.append(valid)
        return parts, valids


class MonoDepthModel(DepthModel):
    """Monodepth2: the same encoder and decoder with one sigmoid depth channel, stage "init" only."""

    has_bases = False
