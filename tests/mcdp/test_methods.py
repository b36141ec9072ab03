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
        methods.build_network(cfg.model)
    from study.sweep.config import SweepConfig

    with pytest.raises(ConfigError, match="unknown method"):
        load_config(SweepConfig, values={"methods": ["nosuch"]})


def presets(folder: str) -> list[Path]:
    """The method presets of one folder (every YAML but base.yaml and the pretraining's)."""
    return sorted(p for p in (ROOT / folder).glob("*.yaml") if p.stem not in ("base", "pretrain"))


@pytest.mark.parametrize("folder", ["configs/train", "configs/train/tiny"])
def test_each_preset_names_a_method_and_agrees_with_its_row(folder):
    """A preset is optional; one that exists is named for a registered method and, resolved on its own (``mcdp
    train PRESET``), is the config the sweep resolves for that method (the row's defaults under it): every row
    value holds in it, whether the preset writes it or inherits it from the config's defaults (lambda)."""
    for path in presets(folder):
        assert path.stem in methods.METHODS, f"{folder}/{path.name} names no registered method"
        row = methods.METHODS[path.stem]
        alone = config_to_dict(load_config(RunConfig, path))
        assert alone == config_to_dict(load_config(RunConfig, path, base=dict(row.defaults)))
        for key, value in row.defaults.items():
            section, leaf = key.split(".")
            assert alone[section][leaf] == value, f"{folder}/{path.name}: {key}"
        assert "consistency_weight" not in read_yaml(path).get("loss", {}) or \
            row.defaults["loss.consistency_weight"] != methods.PAPER_LAMBDA, \
            f"{folder}/{path.name} writes lambda again: it is LossConfig's default"


@pytest.mark.parametrize("folder", ["configs/train", "configs/train/tiny"])
def test_a_preset_is_base_yaml_under_its_row_plus_at_most_model_sizes(folder):
    """What a method needs of a preset is its row: ``base.yaml`` under the row's defaults is the preset's config
    for every full-size preset, and the tiny MCDP presets add only the sizes of their bases and weight networks
    (the network sizes the tiny CPU runs use), never another value of the row or of the training."""
    sizes = {"bases", "weight_channels", "weight_conv_channels", "weight_fc"}
    for path in presets(folder):
        row = methods.METHODS[path.stem]
        made = config_to_dict(load_config(RunConfig, ROOT / folder / "base.yaml", base=dict(row.defaults)))
        own = config_to_dict(load_config(RunConfig, path))
        differ = {f"{sec}.{k}" for sec in own if isinstance(own[sec], dict) for k in own[sec]
                  if own[sec][k] != made[sec].get(k)}
        if folder == "configs/train":
            assert not differ, (path.name, differ)
        else:
            assert differ <= {f"model.{k}" for k in sizes}, (path.name, differ)


def test_a_method_without_a_preset_trains_from_base_yaml_and_its_row(capsys):
    """The sweep resolves a registered method that has no preset file from ``base.yaml`` under its row, and
    ``mcdp train base.yaml --method NAME`` prints the same config (no hand-written preset is needed)."""
    import yaml

    from study.sweep.config import SweepConfig, run_config_for
    from study.method_commands import main

    row = methods.register(methods.Method("presetless", "No preset", {"model.refine_steps": 0,
                                                                      "loss.consistency_weight": 0.0},
                                          "mcdp.methods.depth_bases:MonoDepthModel"))
    try:
        sweep = load_config(SweepConfig, values={"methods": ["mono2", "presetless"],
                                                 "train_presets_dir": "configs/train/tiny"})
        cfg, preset = run_config_for(sweep, "presetless", seed=3)
        assert preset.name == "base.yaml" and cfg.model.method == "presetless" and cfg.train.seed == 3
        assert (cfg.train.height, cfg.train.width) == (64, 96)
        mono, _ = run_config_for(sweep, "mono2", seed=3)
        assert config_to_dict(mono)["train"] == config_to_dict(cfg)["train"]
        assert main(["train", "configs/train/tiny/base.yaml", "--method", row.name, "--print-config"]) == 0
        printed = yaml.safe_load(capsys.readouterr().out)
        assert printed == config_to_dict(load_config(RunConfig, ROOT / "configs/train/tiny/base.yaml",
                                                     base=dict(row.defaults)))
        assert printed["model"]["method"] == "presetless" and printed["model"]["refine_steps"] == 0
        assert main(["train", "configs/train/tiny/mono2.yaml", "--method", row.name, "--print-config"]) == 2
        assert "--method presetless: the preset sets model.method=mono2" in capsys.readouterr().err
        assert main(["train", "configs/train/tiny/base.yaml", "--method", "nosuch", "--print-config"]) == 2
        assert "--method nosuch: not a registered method" in capsys.readouterr().err
    finally:
        methods.unregister("presetless")


@pytest.mark.parametrize("name", list(methods.METHODS))
def test_every_registered_network_keeps_the_contract(name):
    """Conformance: each method's network (its config from the tiny base under its row) is a DepthNetwork whose
    declared members have the documented types, and whose forward returns every stage's depth at full
    resolution."""
    from mcdp.inputs import DepthInput, InputField
    from mcdp.methods.base import DepthNetwork

    row = methods.METHODS[name]
    cfg = load_config(RunConfig, ROOT / "configs" / "train" / "tiny" / "base.yaml", base=dict(row.defaults))
    net = methods.build_network(cfg.model).eval()
    assert isinstance(net, DepthNetwork) and type(net) is methods.network_class(row)
    assert isinstance(net.n_out, int) and net.n_out >= 1 and (net.n_out > 1) == net.has_bases
    for member in ("uses_neighbours", "joint_pose", "has_bases"):
        assert isinstance(getattr(net, member), bool), member
    assert isinstance(type(net).reads_ground_truth(), bool)
    assert isinstance(net.inputs, tuple) and all(isinstance(f, InputField) for f in net.inputs)
    fresh = net.fresh_parameters()
    assert all(isinstance(p, nn.Parameter) for p in fresh)
    # what a report says starts fresh (read without building the network) is what does
    words = type(net).fresh_layers(methods.model_config(row))
    assert isinstance(words, str) and bool(words) == bool(fresh), (words, len(fresh))
    N, H, W = 2, 64, 96
    K = torch.tensor([[80.0, 0, 48], [0, 80, 32], [0, 0, 1]]).expand(1, N, 3, 3)
    T = torch.eye(4).expand(1, N, 4, 4).clone()
    T[0, 1, :3, 3] = torch.tensor([0.0, 0.5, 0.0])
    with torch.no_grad():
        out = net(DepthInput(torch.rand(1, N, 3, H, W), K, T, torch.ones(1, N, 1, H, W),
                             torch.tensor([[1, -1], [-1, 0]])), scales=1)
    assert list(out["stages"]) == list(net.stages)
    for st in net.stages:
        d = out["depth", st, 0]
        assert d.shape == (N, 1, H, W) and torch.isfinite(d).all() and (d > 0).all()


@pytest.mark.parametrize("name", list(methods.METHODS))
def test_every_registered_network_runs_with_any_declared_field_absent(name, fake_dataset):
    """The contract (`mcdp.methods.base.DepthNetwork`, ``inputs``): a network runs with any of its declared fields
    absent (emptied by the cut, or never filled) as with all of them filled; `GT_MEDIAN`, which a run scaled by the
    ORACLE gives any network, counts as declared. The fields are read from a dataset (the tests' fake) as the data
    reader and the predictor read them (`mcdp.inputs.read_fields`, `DepthInput.filled`)."""
    from mcdp.data import RigReader, neighbour_table
    from mcdp.inputs import DepthInput, read_fields
    from mcdp.methods.base import GT_MEDIAN

    row = methods.METHODS[name]
    cfg = load_config(RunConfig, ROOT / "configs" / "train" / "tiny" / "base.yaml", base=dict(row.defaults))
    net = methods.build_network(cfg.model).eval()
    declared = tuple(net.inputs) + ((GT_MEDIAN,) if GT_MEDIAN not in net.inputs else ())
    ds = fake_dataset()
    reader = RigReader(ds, cfg.train.height, cfg.train.width)
    values = {k: v[None] for k, v in read_fields(declared, reader, "s0", 1).items()}
    rig = [torch.from_numpy(a)[None] for a in (reader.rgb("s0", 1), reader.K, reader.T_ego_cam, reader.mask)]
    nbr = neighbour_table(ds.neighbours, len(ds.camera_names))
    for absent in [None, *declared, "all"]:
        given = {} if absent == "all" else {k: v for k, v in values.items() if absent is None or k != absent.name}
        inp = DepthInput.filled(*rig, nbr, given, declared)
        for x in (inp, inp.cut()):
            with torch.no_grad():
                out = net(x, scales=1)
            d = out["depth", net.stages[-1], 0]
            assert d.shape == (2, 1, cfg.train.height, cfg.train.width), (absent, d.shape)
            assert torch.isfinite(d).all() and (d > 0).all(), (name, absent)


def test_a_network_must_define_forward():
    """The contract's one abstract member: a subclass without ``forward`` cannot be built."""
    from mcdp.methods.base import DepthNetwork

    class NoForward(DepthNetwork):
        pass

    with pytest.raises(TypeError, match="abstract"):
        NoForward()


def test_nothing_probes_a_network_with_getattr():
    """The contract's members are declared (DepthNetwork): no module reads them with getattr / hasattr."""
    import re

    members = ("n_out", "has_bases", "uses_neighbours", "joint_pose", "reads_ground_truth", "inputs",
               "fresh_parameters", "check_config", "check_rig", "stages")
    pat = re.compile(r"(getattr|hasattr)\([^)]*[\"'](" + "|".join(members) + r")[\"']")
    hits = [f"{p.relative_to(ROOT)}:{i}" for pkg in ("mcdp", "study", "synth", "benchmarks")
            for p in (ROOT / pkg).rglob("*.py") for i, line in enumerate(p.read_text().splitlines(), 1)
            if pat.search(line)]
    assert not hits, hits


def test_a_network_outside_the_contract_is_refused():
    m = methods.Method("plain", "Plain", {}, nn.Identity)
    with pytest.raises(TypeError, match="DepthNetwork"):
        methods.network_class(m)


def test_inference_knows_no_experiment():
    """`mcdp.predict.Predictor` only predicts: the cut, the ORACLE weights and the refinement record live in
    `study.sweep.probes` (issue 31); nothing of the experiment is an argument or a member of the predictor."""
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
    """FSM's weights come from ``method_params`` validated against its row's params class: today's values
    by default, a set key changes only that weight, and a wrong key or value is one ConfigError naming it."""
    from mcdp.methods.fsm import FsmParams

    p = methods.method_params(fsm_cfg())
    assert isinstance(p, FsmParams) and (p.spatial_weight, p.pose_translation_weight, p.pose_rotation_weight) == (
        0.1, 1.0, 1.0)
    p = methods.method_params(fsm_cfg("method_params.spatial_weight=0.25"))
    assert (p.spatial_weight, p.pose_rotation_weight) == (0.25, 1.0)
    with pytest.raises(ConfigError, match=r"^method_params\.spatial_wieght: unknown key for method 'fsm' \(its "
                                          r"parameters: pose_rotation_weight, pose_translation_weight, spatial_weight, "
                                          r"spatio_temporal\)$"):
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
    from mcdp.inputs import RigBatch
    from mcdp.methods.base import LossContext
    from mcdp.methods.fsm import FsmDepthModel, FsmParams

    torch.manual_seed(0)
    N, H, W = 2, 16, 24
    K = torch.tensor([[20.0, 0, 12], [0, 20, 8], [0, 0, 1]]).expand(1, N, 3, 3)
    T = torch.eye(4).expand(1, N, 4, 4).clone()
    T[0, 1, 0, 3] = 0.3  # the second camera 30 cm to the side: they overlap
    batch = RigBatch(torch.rand(1, N, 3, 3, H, W), K, T, torch.ones(1, N, 1, H, W), torch.eye(4).repeat(1, 3, 1, 1),
                     torch.zeros(1, dtype=torch.long), torch.ones(1, dtype=torch.long))
    outputs = {"stages": ["init"], ("depth", "init", 0): torch.full((N, 1, H, W), 5.0)}
    poses = {o: torch.eye(4).expand(N, 4, 4) for o in (-1, 1)}
    cfg = fsm_cfg()
    net = FsmDepthModel.__new__(FsmDepthModel)  # loss_terms reads no layer: no network needs building
    terms = {w: FsmDepthModel.loss_terms(net, outputs, batch, LossContext(
        cfg, FsmParams(spatial_weight=w), poses, directed_pairs([(0, 1)]), 0)) for w in (0.1, 0.2)}
    assert float(terms[0.1]["fsm/spatial"]) > 0
    assert float(terms[0.2]["fsm/spatial"]) == pytest.approx(2 * float(terms[0.1]["fsm/spatial"]), rel=1e-6)


def test_a_rows_role_is_derived_from_its_network():
    """A row's role is not restated: "yardstick" exactly when its network reads ground truth (``reads_ground_truth()``,
    an input field with ``truth=True``), "baseline" for the row that says ``baseline=True``, else "method"."""
    from mcdp.inputs import InputField
    from mcdp.methods.depth_bases import MonoDepthModel

    assert {n: r.role for n, r in methods.METHODS.items() if r.role != "method"} == {"mono2": "baseline",
                                                                                    "oracle_local": "yardstick"}

    class Peeks(MonoDepthModel):
        inputs = (InputField("gt_peek", lambda r, s, f: None, truth=True),)

    assert methods.Method("peeks", "Peeks", build=Peeks).role == "yardstick"  # no flag says so: its input does
    assert methods.Method("plain", "Plain", build=MonoDepthModel).role == "method"
