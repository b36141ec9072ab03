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
from mcdp.model import DepthNetwork, disp_to_depth

ROOT = Path(__file__).resolve().parents[2]


class ToyDepth(DepthNetwork):
    """The smallest depth network with the contract (`mcdp.model.DepthNetwork`): one conv, one stage, every scale."""

    model = "toy"

    def __init__(self, cfg: ModelConfig):
        super().__init__()
        self.cfg, self.stages = cfg, ["init"]
        self.conv = nn.Conv2d(3, 1, 3, padding=1)

    def forward(self, rgb, K, T_ego_cam, mask, nbr, oracle_gt_median=None, scales=None, refine_scales=None,
                overlap_truth=None):
        B, N, _, H, W = rgb.shape
        sig = torch.sigmoid(self.conv(rgb.reshape(B * N, 3, H, W)))
        out = {"stages": self.stages, "scale": torch.ones(B * N)}
        for s in range(self.cfg.scales if scales is None else min(scales, self.cfg.scales)):
            sig_s = F.avg_pool2d(sig, 2 ** s) if s else sig
            out["disp", "init", s] = disp_to_depth(sig_s, self.cfg.min_depth, self.cfg.max_depth)[0]
            up = F.interpolate(sig_s, size=(H, W), mode="bilinear", align_corners=False) if s else sig_s
            out["depth", "init", s] = disp_to_depth(up, self.cfg.min_depth, self.cfg.max_depth)[1]
        return out

    def loss_terms(self, outputs, batch, ctx):
        """The toy method's own loss term: a pull of the full-resolution disparity towards its mean (weighted)."""
        disp = outputs["disp", "init", 0]
        return {"toy/flatness": TOY_WEIGHT * (disp - disp.mean()).abs().mean()}


TOY_WEIGHT = 1e-2


@pytest.fixture
def toy():
    m = methods.register(methods.Method("toy", "Toy net", {"model.method": "toy", "model.refine_steps": 0,
                                                           "loss.consistency_weight": 0.0}, ToyDepth))
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


@pytest.mark.parametrize("name", list(methods.METHODS))
def test_every_registered_network_keeps_the_contract(name):
    """Conformance: each method's network (tiny preset) is a DepthNetwork whose declared members have the
    documented types, and whose forward returns every stage's depth at full resolution."""
    from mcdp.model import DepthNetwork

    cfg = load_config(RunConfig, ROOT / "configs" / "train" / "tiny" / f"{name}.yaml")
    net = methods.build_depth_model(cfg.model).eval()
    assert isinstance(net, DepthNetwork) and type(net).model == methods.METHODS[name].model
    assert isinstance(net.n_out, int) and net.n_out >= 1 and (net.n_out > 1) == net.has_bases
    for member in ("uses_neighbours", "joint_pose", "reads_overlap_truth", "has_bases"):
        assert isinstance(getattr(net, member), bool), member
    fresh = net.fresh_parameters()
    assert all(isinstance(p, nn.Parameter) for p in fresh)
    # what a report says starts fresh (read without building the network) is what does
    words = type(net).fresh_layers(methods.model_config(methods.METHODS[name]))
    assert isinstance(words, str) and bool(words) == bool(fresh), (words, len(fresh))
    N, H, W = 2, 64, 96
    K = torch.tensor([[80.0, 0, 48], [0, 80, 32], [0, 0, 1]]).expand(1, N, 3, 3)
    T = torch.eye(4).expand(1, N, 4, 4).clone()
    T[0, 1, :3, 3] = torch.tensor([0.0, 0.5, 0.0])
    with torch.no_grad():
        out = net(torch.rand(1, N, 3, H, W), K, T, torch.ones(1, N, 1, H, W), torch.tensor([[1, -1], [-1, 0]]),
                  scales=1)
    assert list(out["stages"]) == list(net.stages)
    for st in net.stages:
        d = out["depth", st, 0]
        assert d.shape == (N, 1, H, W) and torch.isfinite(d).all() and (d > 0).all()


def test_nothing_probes_a_network_with_getattr():
    """The contract's members are declared (DepthNetwork): no module reads them with getattr / hasattr."""
    import re

    members = ("n_out", "has_bases", "uses_neighbours", "joint_pose", "reads_overlap_truth", "fresh_parameters",
               "check_config", "stages")
    pat = re.compile(r"(getattr|hasattr)\([^)]*[\"'](" + "|".join(members) + r")[\"']")
    hits = [f"{p.relative_to(ROOT)}:{i}" for pkg in ("mcdp", "study", "synth", "benchmarks")
            for p in (ROOT / pkg).rglob("*.py") for i, line in enumerate(p.read_text().splitlines(), 1)
            if pat.search(line)]
    assert not hits, hits


def test_a_network_outside_the_contract_is_refused():
    m = methods.Method("plain", "Plain", {"model.method": "plain"}, nn.Identity)
    with pytest.raises(TypeError, match="DepthNetwork"):
        methods.network_class(m)


def test_inference_knows_no_experiment():
    """`mcdp.predict.Predictor` only predicts: the cut, the ORACLE weights and the refinement record live in
    `study.probes` (issue 31); nothing of the experiment is an argument or a member of the predictor."""
    import inspect
    import re

    from mcdp.predict import Predictor

    assert list(inspect.signature(Predictor.__init__).parameters) == ["self", "run_dir", "ds", "checkpoint", "device"]
    src = inspect.getsource(Predictor)
    for pat in (r"\bcut\b", r"oracle_weights", r"self\.reference", r"\brefinement\b", r"\bkept\b"):
        assert not re.search(pat, src), pat
