"""The method registry (mcdp/methods.py): a new method (its network and its own loss term) is one
module plus one registry line; the built-in presets agree with their registry entries."""
from __future__ import annotations

from pathlib import Path

import pytest
import torch
import torch.nn as nn
import torch.nn.functional as F

from corelib.configlib import ConfigError, config_to_dict, load_config, read_yaml
from mcdp import methods
from mcdp.config import ModelConfig, RunConfig
from mcdp.data import collate
from mcdp.model import disp_to_depth

ROOT = Path(__file__).resolve().parents[2]


class ToyDepth(nn.Module):
    """The smallest depth network with DepthModel's contract: one conv, one stage, every scale."""

    def __init__(self, cfg: ModelConfig):
        super().__init__()
        self.cfg, self.stages = cfg, ["init"]
        self.conv = nn.Conv2d(3, 1, 3, padding=1)

    def forward(self, rgb, K, T_ego_cam, mask, nbr, oracle_gt_median=None, scales=None, refine_scales=None):
        B, N, _, H, W = rgb.shape
        sig = torch.sigmoid(self.conv(rgb.reshape(B * N, 3, H, W)))
        out = {"stages": self.stages, "scale": torch.ones(B * N)}
        for s in range(self.cfg.scales if scales is None else min(scales, self.cfg.scales)):
            sig_s = F.avg_pool2d(sig, 2 ** s) if s else sig
            out["disp", "init", s] = disp_to_depth(sig_s, self.cfg.min_depth, self.cfg.max_depth)[0]
            up = F.interpolate(sig_s, size=(H, W), mode="bilinear", align_corners=False) if s else sig_s
            out["depth", "init", s] = disp_to_depth(up, self.cfg.min_depth, self.cfg.max_depth)[1]
        return out


TOY_WEIGHT = 1e-2


def toy_loss(outputs: dict, batch: dict, cfg: RunConfig) -> dict:
    """The toy method's own loss term: a pull of the full-resolution disparity towards its mean (weighted)."""
    disp = outputs["disp", "init", 0]
    return {"toy/flatness": TOY_WEIGHT * (disp - disp.mean()).abs().mean()}


@pytest.fixture
def toy():
    m = methods.register(methods.Method("toy", "Toy net", {"model.method": "toy", "model.refine_steps": 0,
                                                           "loss.consistency_weight": 0.0}, ToyDepth,
                                        loss_terms=toy_loss))
    yield m
    methods.METHODS.pop("toy")


def test_a_registered_toy_method_trains_two_steps_and_evaluates(toy, tiny_dataset, tmp_path):
    from mcdp.evaluate import EvalConfig, evaluate
    from mcdp.predict import Predictor
    from mcdp.trainer import Trainer
    from synth.dataset import open_dataset
    from study.config import SweepConfig

    ds = open_dataset(tiny_dataset)
    cfg = load_config(RunConfig, ROOT / "configs/train/tiny/mono2.yaml", ["train.steps=2", "train.threads=1"],
                      {"model.method": "toy"})
    tr = Trainer(cfg, ds, tmp_path / "run", progress=False, tensorboard=False)
    try:
        assert isinstance(tr.depth, ToyDepth)
        summary = tr.train()
    finally:
        tr.close()
    assert summary["steps"] == 2 and all(torch.isfinite(torch.tensor(summary["losses"])))
    # its own loss term is in the step's loss, logged under its name
    batch = next(iter(torch.utils.data.DataLoader(tr.train_set, batch_size=1, collate_fn=collate)))
    with torch.no_grad():
        out, losses = tr.system.process_batch(batch, 0, train=False)
    assert losses["toy/flatness"].item() > 0
    assert losses["loss"].item() == pytest.approx(
        losses["stage/init"].item() + losses["toy/flatness"].item() + cfg.scale.velocity_weight
        * losses["pose/velocity"].item(), rel=1e-6)
    pred = Predictor(tmp_path / "run", ds, "last")
    metrics = evaluate(ds, pred.predict, "test", EvalConfig(), progress=False)
    assert metrics["stages"]["final"]["median"]["mean"]["abs_rel"] > 0
    # the study knows it by its registry line alone: sweeps accept it, reports label it, in table order
    assert SweepConfig(methods=["toy", "mono2"]).methods == ["mono2", "toy"]
    assert methods.label("toy") == "Toy net"


def test_an_unregistered_model_is_refused_naming_the_key():
    cfg = load_config(RunConfig, ROOT / "configs/train/tiny/mono2.yaml", values={"model.method": "nosuch"})
    with pytest.raises(ConfigError, match="model.method 'nosuch' is not a registered"):
        methods.build_depth_model(cfg.model)
    from study.config import SweepConfig

    with pytest.raises(ConfigError, match="unknown method"):
        load_config(SweepConfig, values={"methods": ["nosuch"]})


@pytest.mark.parametrize("folder", ["configs/train", "configs/train/tiny"])
@pytest.mark.parametrize("name", list(methods.METHODS))
def test_each_preset_agrees_with_its_registry_entry(folder, name):
    """A preset resolved on its own (``mcdp train PRESET``) is the config the sweep resolves for its method
    (the registry's defaults under it): every registry value holds in it, whether the preset writes it
    (model.method, refine_steps) or inherits it from the config's defaults (lambda)."""
    path = ROOT / folder / f"{name}.yaml"
    alone = config_to_dict(load_config(RunConfig, path))
    assert alone == config_to_dict(load_config(RunConfig, path, base=dict(methods.METHODS[name].defaults)))
    for key, value in methods.METHODS[name].defaults.items():
        section, leaf = key.split(".")
        assert alone[section][leaf] == value, f"{folder}/{name}.yaml: {key}"
    assert "consistency_weight" not in read_yaml(path).get("loss", {}) or \
        methods.METHODS[name].defaults["loss.consistency_weight"] != methods.PAPER_LAMBDA, \
        f"{folder}/{name}.yaml writes lambda again: it is LossConfig's default"
