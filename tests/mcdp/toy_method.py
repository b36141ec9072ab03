"""A toy method, written as a user adds one: this module (its network, its own loss term, its parameters) plus
one registry row (`mcdp.methods.register`, in tests/mcdp/test_toy_method.py). Nothing of the trainer, the
system, the evaluator or the study is edited for it.

The network is Monodepth2's (so the shared pretraining warm-starts its encoder and decoder) with one fresh
layer of its own, ``toy_gain`` (a learned per-image scale of the sigmoid output, starting at 1, so the warm
start's depth is unchanged at step 0). Its own loss term pulls the full-resolution disparity towards its
mean, weighted by ``method_params.flatness_weight``.

`ToyInputDepth` is a second toy: one that needs an input of its own, ``EGO_SPEED`` (the ego car's speed over
the last frame, metres per frame, one value per camera, read from the dataset's odometry; no ground truth),
declared here as a `mcdp.inputs.InputField` and read by its network; the data reader and the predictor fill it
because the network declares it.
"""
from __future__ import annotations

import numpy as np
import torch
import torch.nn as nn
from pydantic import Field

from corelib.configlib import StrictModel
from mcdp.config import Float
from mcdp.inputs import DepthInput, InputField
from mcdp.methods.base import LossContext
from mcdp.methods.depth_bases import MonoDepthModel


class ToyParams(StrictModel):
    """The toy method's own parameters (the run config's ``method_params`` section)."""

    flatness_weight: Float = Field(1e-2, ge=0, le=1000.0, allow_inf_nan=False)


class ToyDepth(MonoDepthModel):
    """Monodepth2 + one fresh layer; the contract's members it changes: ``fresh_parameters`` / ``fresh_layers``,
    ``loss_terms``."""

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


def read_ego_speed(reader, seq: str, frame: int) -> np.ndarray:
    """(N,) float32: the ego car's displacement from frame - 1 (or 0) to ``frame``, metres, for every camera."""
    T = np.asarray(reader.ds.T_world_ego(seq), dtype=np.float64)
    a, b = T[max(int(frame) - 1, 0)], T[int(frame)]
    return np.full(len(reader.cam_names), float(np.linalg.norm(b[:3, 3] - a[:3, 3])), dtype=np.float32)


EGO_SPEED = InputField("ego_speed", read_ego_speed, "(N,) metres per frame")


class ToyInputDepth(MonoDepthModel):
    """Monodepth2 whose coarsest encoder features are offset by ``speed_gain`` x the ego speed (a fresh layer at
    0, so it starts as its warm start): a network with an input of its own."""

    inputs = (EGO_SPEED,)

    def __init__(self, cfg, params=None):
        super().__init__(cfg, params)
        self.speed_gain = nn.Parameter(torch.zeros(1))

    @classmethod
    def fresh_layers(cls, cfg) -> str:
        return "speed gain"

    def encode(self, x: torch.Tensor, B: int, N: int, inp: DepthInput) -> list[torch.Tensor]:
        feats = self.encoder(x)
        speed = inp.get(EGO_SPEED)
        if speed is not None:
            feats[-1] = feats[-1] + self.speed_gain * speed.reshape(B * N, 1, 1, 1).to(feats[-1].dtype)
        return feats
