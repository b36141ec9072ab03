"""The method registry (mcdp/methods/__init__.py): every registered network keeps the contract, the built-in presets
agree with their registry entries, a method's own weights live in its ``method_params`` section. (That a new
method is one module plus one registry row: tests/mcdp/test_toy_method.py.)"""
from __future__ import annotations

from pathlib import Path

import pytest
import torch
import torch.nn as nn

from corelib.configlib import ConfigError, config_to_dict, load_config, read_yaml
from mcdp import methods
from mcdp.config import RunConfig

ROOT = Path(__file__).resolve().parents[2]


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
    from mcdp.methods.base import DepthNetwork

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
               "check_config", "check_rig", "stages")
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


# --------------------------------------------------------------------------- a method's own parameters
def fsm_cfg(*overrides: str) -> RunConfig:
    return load_config(RunConfig, ROOT / "configs/train/tiny/fsm.yaml", list(overrides))


def test_a_methods_own_weights_live_in_its_method_params_section():
    """FSM's weights come from ``method_params`` validated against its row's params model: today's values
    by default, a set key changes only that weight, and a wrong key or value is one ConfigError naming it."""
    from mcdp.methods.fsm import FsmParams

    p = methods.method_params(fsm_cfg())
    assert isinstance(p, FsmParams) and (p.spatial_weight, p.pose_translation_weight, p.pose_rotation_weight) == (
        0.1, 1.0, 1.0)
    p = methods.method_params(fsm_cfg("method_params.spatial_weight=0.25"))
    assert (p.spatial_weight, p.pose_rotation_weight) == (0.25, 1.0)
    with pytest.raises(ConfigError, match=r"^method_params\.spatial_wieght: unknown key for method 'fsm' \(its "
                                          r"parameters: pose_rotation_weight, pose_translation_weight, spatial_weight\)$"):
        methods.check_run(fsm_cfg("method_params.spatial_wieght=0.2"))
    with pytest.raises(ConfigError, match=r"^method_params\.spatial_weight: .*greater than or equal to 0"):
        methods.method_params(fsm_cfg("method_params.spatial_weight=-1"))
    mono = load_config(RunConfig, ROOT / "configs/train/tiny/mono2.yaml", ["method_params.spatial_weight=0.2"])
    with pytest.raises(ConfigError, match=r"^method_params\.spatial_weight: method 'mono2' has no parameters"):
        methods.method_params(mono)
    assert methods.method_params(load_config(RunConfig, ROOT / "configs/train/tiny/mono2.yaml")) is None


def test_an_empty_method_params_section_leaves_the_run_hash_and_resume_as_they_were():
    """The section is an added key: empty, it is not hashed (every existing run keeps its hash) and a checkpoint
    saved before it existed resumes; set, it enters the hash."""
    from corelib.configlib import config_hash, hashed_dict
    from mcdp.config import resume_conflicts, upgrade_config_dict

    cfg = fsm_cfg()
    assert "method_params" not in hashed_dict(cfg)
    assert config_hash(cfg) != config_hash(fsm_cfg("method_params.spatial_weight=0.2"))
    old = {k: v for k, v in config_to_dict(cfg).items() if k != "method_params"}  # a config saved before
    assert resume_conflicts(upgrade_config_dict(old), config_to_dict(cfg)) == []
    assert resume_conflicts(upgrade_config_dict(old), config_to_dict(fsm_cfg("method_params.spatial_weight=0.2"))) \
        == ["method_params.spatial_weight"]


def test_fsm_reads_its_weights_from_the_loss_context():
    """The spatial term is its weight times the unweighted term: doubling method_params.spatial_weight doubles it."""
    from mcdp.data import directed_pairs
    from mcdp.methods.base import LossContext
    from mcdp.methods.fsm import FsmDepthModel, FsmParams

    torch.manual_seed(0)
    N, H, W = 2, 16, 24
    K = torch.tensor([[20.0, 0, 12], [0, 20, 8], [0, 0, 1]]).expand(1, N, 3, 3)
    T = torch.eye(4).expand(1, N, 4, 4).clone()
    T[0, 1, 0, 3] = 0.3  # the second camera 30 cm to the side: they overlap
    batch = {"rgb": torch.rand(1, N, 3, 3, H, W), "mask": torch.ones(1, N, 1, H, W), "K": K, "T_ego_cam": T}
    outputs = {"stages": ["init"], ("depth", "init", 0): torch.full((N, 1, H, W), 5.0)}
    poses = {o: torch.eye(4).expand(N, 4, 4) for o in (-1, 1)}
    cfg = fsm_cfg()
    net = FsmDepthModel.__new__(FsmDepthModel)  # loss_terms reads no layer: no network needs building
    terms = {w: FsmDepthModel.loss_terms(net, outputs, batch, LossContext(
        cfg, FsmParams(spatial_weight=w), poses, directed_pairs([(0, 1)]), 0)) for w in (0.1, 0.2)}
    assert float(terms[0.1]["fsm/spatial"]) > 0
    assert float(terms[0.2]["fsm/spatial"]) == pytest.approx(2 * float(terms[0.1]["fsm/spatial"]), rel=1e-6)
