"""The method contract: `DepthNetwork` (its docstring is the contract's one description), the
`LossContext` a method's own loss terms read, `GT_MEDIAN` (the ORACLE scale mode's input field), and
the conventions every method's outputs share.

Output -> depth (the ONLY place): `disp_to_depth` maps a sigmoid value
sig in (0, 1) to disparity disp = 1/max_depth + (1/min_depth - 1/max_depth) sig
and depth = 1 / disp (metres), so depth lies in [min_depth, max_depth]
(defaults 0.1 m and 100 m, `ModelConfig`).

Bases are combined in sigmoid (i.e. affine-disparity) space with softmax
weights: sig = sum_j w_j B_j, w = softmax(logits), initial logits 0 so
w_init = 1/n (paper eq. 1; `combine_bases`). Why disparity and not depth: a convex combination
of values in (0, 1) stays in (0, 1), so every weight vector gives a valid depth
in [min_depth, max_depth] without clamping; the smoothness loss and Monodepth2
already work on disparity; and far pixels (large depth) do not dominate the
combination.

Stages are named "init", "refine1", ..., "refine{m}" (`stage_names`; the evaluator adds
"final" = the last one); a refined stage (`is_refined`) is trained on ``loss.refine_scales`` scales.

Why these helpers live here and not in a family's module: they are the conventions of every method's
outputs, read also outside the networks (the training step's loss: `is_refined`, `resize_mask_to` for
the scene mask at each decoder scale; the ORACLE of the bases and the study's probes: `combine_bases`).
What one family alone uses stays in its module (`mcdp.methods.depth_bases.masked_median`, ``SLOTS``).
"""
from __future__ import annotations

from abc import ABCMeta, abstractmethod
from dataclasses import dataclass
from typing import Any

import torch
import torch.nn as nn
import torch.nn.functional as F

from mcdp.config import ModelConfig
from mcdp.inputs import DepthInput, InputField
from mcdp.truth import gt_median

def _read_gt_median(reader, seq: str, frame: int):
    return gt_median(reader.ds, reader.mask_full, seq, frame)


#: the ORACLE scale mode's input (``scale.source=oracle_gt_median``, the public reference code's scaling):
#: each camera's median ground-truth depth; every depth is multiplied by it / the init stage's median
GT_MEDIAN = InputField("gt_median", _read_gt_median, "(N,) metres", truth=True)


def disp_to_depth(sig: torch.Tensor, min_depth: float, max_depth: float) -> tuple[torch.Tensor, torch.Tensor]:
    """Network sigmoid output -> (disparity, depth in metres); the one output-to-depth map.

    Args:
        sig: (...) values in [0, 1].
        min_depth, max_depth: depth range in metres (sig=1 -> min_depth, sig=0 -> max_depth).
    Returns:
        disp (...) in [1/max_depth, 1/min_depth] and depth = 1/disp (...).
    """
    min_disp, max_disp = 1.0 / max_depth, 1.0 / min_depth
    disp = min_disp + (max_disp - min_disp) * sig
    return disp, 1.0 / disp


def combine_bases(bases: torch.Tensor, weights: torch.Tensor) -> torch.Tensor:
    """Linear combination of bases: (B, n, h, w), (B, n) -> (B, 1, h, w) (paper eq. 1).

    Per-pixel weights (`mcdp.methods.local`): ``weights`` (B, n, h', w'), each pixel's a convex combination,
    upsampled bilinearly to (h, w) (a convex combination of convex weight vectors stays convex)."""
    B, n, h, w = bases.shape
    if weights.dim() == 4:
        wts = weights.to(bases.dtype)
        if wts.shape[-2:] != (h, w):
            wts = F.interpolate(wts, size=(h, w), mode="bilinear", align_corners=False)
        return (wts * bases).sum(1, keepdim=True)
    return torch.bmm(weights.to(bases.dtype).unsqueeze(1), bases.reshape(B, n, h * w)).view(B, 1, h, w)


def stage_names(refine_steps: int) -> list[str]:
    return ["init"] + [f"refine{k}" for k in range(1, refine_steps + 1)]


def is_refined(stage: str) -> bool:
    """A refinement stage ("refine1", ...): its loss uses ``loss.refine_scales`` scales."""
    return stage.startswith("refine")


def resize_mask_to(mask: torch.Tensor, h: int, w: int) -> torch.Tensor:
    """(B, 1, H, W) 0/1 -> (B, 1, h, w): 1 only where (almost) all covered pixels are scene."""
    if mask.shape[-2:] == (h, w):
        return mask
    return (F.adaptive_avg_pool2d(mask, (h, w)) > 0.99).to(mask.dtype)


@dataclass(frozen=True)
class LossContext:
    """What a method's own loss terms (`DepthNetwork.loss_terms`) read of the training step besides the
    depth network's outputs and the batch; built by `mcdp.system.SelfSupervisedSystem` for every step.

    - ``cfg``: the `mcdp.config.RunConfig`;
    - ``params``: the method's own parameters (its registry row's ``params`` model validated from the run
      config's ``method_params`` section, `mcdp.methods.method_params`), or None for a method without any;
    - ``poses``: {-1, +1}: (B*N, 4, 4) T_src_tgt, the camera motions of the step's temporal warps
      (predicted, or the odometry's under ``scale.source=odometry``);
    - ``pairs``: ((P,), (P,)) int64, the directed adjacent camera pairs (tgt, src);
    - ``step``: the optimiser step the batch trains (0-based).
    """

    cfg: Any
    params: Any
    poses: dict
    pairs: tuple
    step: int = 0


class DepthNetwork(nn.Module, metaclass=ABCMeta):
    """The method contract: what the trainer, the predictor, the warm start and the reports read of every
    method's depth network, declared here (the one description of it), read as attributes and never probed
    with getattr. A method's network subclasses this (most subclass `mcdp.methods.depth_bases.DepthModel`),
    defines `forward` and overrides what differs; its registry row (`mcdp.methods.Method`) names it, and
    tests/mcdp/test_methods.py checks every registered network against this contract.

    Members:

    - ``__init__(cfg, params=None)``: ``cfg`` the `ModelConfig`; ``params`` the method's own parameters (its
      row's params class validated from the run config's ``method_params`` section, `mcdp.methods.method_params`;
      None for a method without any), kept as ``.params``: what sizes a network's own layers lives there
      (`mcdp.methods.surround.SurroundParams`), so a checkpoint's config rebuilds the same network;
    - ``check_config(cfg)`` (classmethod): ConfigError naming the key for a model config it cannot be built
      from; ``check_rig(params, n_cameras)`` (classmethod): the same for a rig its ``params`` cannot take,
      checked before a run folder is made;
    - ``inputs``: the optional input fields it reads (`mcdp.inputs.InputField`, e.g. ORACLE-local's overlap ground
      truth): the data reader and the predictor fill these and no other, and the network runs with any of them
      absent (``inp.get(FIELD)`` is None: the cut empties those that carry other cameras' content, a caller may
      fill none; tests/mcdp/test_methods.py runs every registered row so); ``reads_ground_truth()``
      (classmethod): one of them reads ground truth, so the network is an ORACLE (its row's role is "yardstick");
    - ``n_out``: decoder depth channels (instance attribute; 1 = one sigmoid channel);
    - ``has_bases``: n bases combined by weights (the warm start copies the pretraining's basis channels;
      False: its mono head); ``stages``: stage names, the last is evaluated;
    - ``uses_neighbours``: the depth reads other cameras at inference (the sweep evaluates it cut too);
    - ``joint_pose``: the pose network moves the rig as one (it is given the extrinsics);
    - ``fresh_parameters()``: the layers no pretraining initialises (they learn at ``train.weight_lr_mult``);
      ``fresh_layers(cfg)`` (classmethod): what they are, in words, for reports ("" when there are none);
    - ``loss_terms(outputs, batch, ctx)``: the method's own loss terms, ``{name: weighted scalar}`` added to
      the step's loss and logged under their names (``batch``: the step's `mcdp.inputs.RigBatch`;
      `LossContext`: what the step gives them besides; none by default);
    - ``forward(inp, scales=None, refine_scales=None)`` (abstract): ``inp`` a `mcdp.inputs.DepthInput`;
      returns ``{("sig" | "disp" | "depth", stage, scale): (B*N, 1, h, w), ("weights", stage): ...,
      "stages": [...], "scale": (B*N,)}`` as `mcdp.methods.depth_bases.DepthModel.forward` documents. A run
      scaled by the ORACLE (``scale.source=oracle_gt_median``) also fills `GT_MEDIAN`, whatever the network.
    """

    params = None
    has_bases = False
    joint_pose = False
    inputs: tuple[InputField, ...] = ()
    n_out = 1

    @classmethod
    def check_config(cls, cfg: ModelConfig) -> None:
        """ConfigError, naming the key, for a model config this network cannot be built from; any by default."""

    @classmethod
    def check_rig(cls, params, n_cameras: int) -> None:
        """ConfigError, naming the key, when the network built with ``params`` cannot take a rig of ``n_cameras``
        cameras (checked before training starts: `mcdp.methods.check_run`); any rig by default."""

    @classmethod
    def reads_ground_truth(cls) -> bool:
        """Whether an input field it reads holds ground truth (an ORACLE: every row that carries it says so)."""
        return any(f.truth for f in cls.inputs)

    @property
    def uses_neighbours(self) -> bool:
        return False

    def fresh_parameters(self) -> list[nn.Parameter]:
        return []

    @classmethod
    def fresh_layers(cls, cfg: ModelConfig) -> str:
        """`fresh_parameters` of the network built from ``cfg``, named for a report ("weight networks");
        "" when nothing starts fresh. A classmethod: the report reads it without building the network."""
        return ""

    def loss_terms(self, outputs: dict, batch, ctx: LossContext) -> dict:
        """This method's own loss terms for one step: {name: scalar, already weighted}; none by default."""
        return {}

    @abstractmethod
    def forward(self, inp: DepthInput, scales: int | None = None, refine_scales: int | None = None) -> dict:
        """Every stage's depth for the rigs of ``inp`` (class docstring)."""
