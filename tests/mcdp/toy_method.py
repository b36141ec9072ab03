"""A toy method, written as a user adds one: this module (its network, its own loss term, its parameters) plus
one registry row (`mcdp.methods.register`, in tests/mcdp/test_toy_method.py). Nothing of the trainer, the
system, the evaluator or the study is edited for it.

The network is Monodepth2's (so the shared pretraining warm-starts its encoder and decoder) with one fresh
layer of its own, ``toy_gain`` (a learned per-image scale of the sigmoid output, starting at 1, so the warm
start's depth is unchanged at step 0). Its own loss term pulls the full-resolution disparity towards its
mean, weighted by ``method_params.flatness_weight``.
"""
from __future__ import annotations

import torch
import torch.nn as nn
from pydantic import Field

from corelib.configlib import StrictModel
from mcdp.config import Float
from mcdp.methods.base import LossContext
from mcdp.methods.mcdp import MonoDepthModel


class ToyParams(StrictModel):
    """The toy method's own parameters (the run config's ``method_params`` section)."""

    flatness_weight: Float = Field(1e-2, ge=0, le=1000.0, allow_inf_nan=False)


class ToyDepth(MonoDepthModel):
    """Monodepth2 + one fresh layer; the contract's members it changes: ``model``, ``fresh_parameters`` /
    ``fresh_layers``, ``loss_terms``."""

    model = "toy"

    def __init__(self, cfg, params=None):
        super().__init__(cfg, params)
        self.toy_gain = nn.Parameter(torch.ones(1))

    @classmethod
    def fresh_layers(cls, cfg) -> str:
        return "gain"

    def to_depth(self, sig: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        return super().to_depth((sig * self.toy_gain).clamp(0, 1))

    def loss_terms(self, outputs: dict, batch: dict, ctx: LossContext) -> dict:
        disp = outputs["disp", self.stages[-1], 0]
        return {"toy/flatness": ctx.params.flatness_weight * (disp - disp.mean()).abs().mean()}
