"""The bar of issue 31: adding a method is one module (tests/mcdp/toy_method.py: its network, its own loss term,
its parameters) plus one registry row (the `toy` fixture below), with zero edits to the trainer, the system, the
evaluator, the study or README.md (issue 50: the README points to ``mcdp presets methods``). The toy trains warm-started from a pretraining, its own term is in the logged loss and
moves the gradient by its own weight, and ``mcdp eval`` / ``mcdp predict`` run on it."""
from __future__ import annotations

import dataclasses
import importlib.util
import sys
from pathlib import Path

import pytest
import torch

from corelib.configlib import config_to_dict, load_config
from mcdp import methods
from mcdp.config import RunConfig
from mcdp.data import collate

# the toy's module, imported from its file as a user's own module would be (tests/ is no package on sys.path);
# in sys.modules as an import puts it (pydantic resolves ToyParams' annotations there)
_spec = importlib.util.spec_from_file_location("toy_method", Path(__file__).with_name("toy_method.py"))
toy_method = sys.modules.setdefault("toy_method", importlib.util.module_from_spec(_spec))
_spec.loader.exec_module(toy_method)
ToyDepth, ToyParams = toy_method.ToyDepth, toy_method.ToyParams
EGO_SPEED, ToyInputDepth = toy_method.EGO_SPEED, toy_method.ToyInputDepth

ROOT = Path(__file__).resolve().parents[2]
TINY = ROOT / "configs" / "train" / "tiny"


@pytest.fixture
def toy():
    """The toy's one registry row, registered for one test and removed after it (the registry is global)."""
    row = methods.register(methods.Method("toy", "Toy net", {"model.method": "toy", "model.refine_steps": 0,
                                                             "loss.consistency_weight": 0.0}, ToyDepth,
                                          params=ToyParams))
    yield row
    methods.unregister("toy")


def toy_cfg(row, *overrides: str) -> RunConfig:
    """The run config the sweep would build for the toy: its row's defaults under the tiny Mono2 preset."""
    return load_config(RunConfig, TINY / "mono2.yaml", ["train.steps=2", *overrides], {"model.method": "toy"},
                       base=dict(row.defaults))


def fake_pretraining(path: Path) -> dict:
    """A shared pretraining file as `study.sweep.pretrain` writes it (8 bases + the mono head), random weights."""
    from mcdp.methods.depth_bases import DepthModel
    from mcdp.warmstart import FORMAT, VERSION

    cfg = load_config(RunConfig, TINY / "mcdp_m0.yaml", ["model.bases=8", "model.mono_head=true"])
    torch.manual_seed(123)
    sd = DepthModel(cfg.model).state_dict()
    torch.save({"format": FORMAT, "version": VERSION, "config_hash": "abc", "model": config_to_dict(cfg.model),
                "depth_model": sd, "step": 7}, path)
    return sd


def test_the_toy_method_trains_warm_started_with_its_own_term_and_evaluates(toy, ds, tiny_dataset, tmp_path,
                                                                            one_thread):
    from tensorboard.backend.event_processing.event_accumulator import EventAccumulator

    from mcdp.system import SelfSupervisedSystem
    from mcdp.trainer import Trainer
    from study.method_commands import main

    src = fake_pretraining(tmp_path / "pretrained.pt")
    run = tmp_path / "run"
    cfg = toy_cfg(toy, f"model.init_from={tmp_path / 'pretrained.pt'}", "method_params.flatness_weight=0.5")
    tr = Trainer(cfg, ds, run, progress=False, tensorboard=True)
    try:
        net = tr.depth
        assert isinstance(net, ToyDepth) and tr.system.params == ToyParams(flatness_weight=0.5)
        # the warm start loaded the pretraining: its trunk, and its mono head as the toy's one channel
        sd = net.state_dict()
        assert tr.init_from["step"] == 7
        assert torch.equal(sd["encoder.net.conv1.weight"], src["encoder.net.conv1.weight"])
        assert torch.equal(sd["decoder.dispconv.0.weight"], src["decoder.dispconv.0.weight"][8:9])
        assert [p is net.toy_gain for p in net.fresh_parameters()] == [True]  # its own layer starts fresh
        # its own term is in the step's loss with its own weight, and moves the gradient
        batch = tr.to_device(collate([tr.train_set[0]]))
        without = SelfSupervisedSystem(toy_cfg(toy, "method_params.flatness_weight=0"), ds.neighbours,
                                       len(ds.camera_names)).to(tr.device)
        without.load_state_dict(tr.system.state_dict())
        grads, losses = [], []
        for system in (tr.system, without):
            system.zero_grad()
            _, ls = system.process_batch(batch, 0, train=False)
            ls["loss"].backward()
            grads.append(system.depth.decoder.dispconv[0].weight.grad.clone())
            losses.append(ls)
        tr.system.zero_grad()
        with_term, no_term = losses
        assert float(with_term["toy/flatness"]) > 0 and float(no_term["toy/flatness"]) == 0
        assert float(with_term["loss"] - no_term["loss"]) == pytest.approx(float(with_term["toy/flatness"]),
                                                                            rel=1e-4)
        assert not torch.allclose(grads[0], grads[1])
        summary = tr.train()
    finally:
        tr.close()
    assert summary["steps"] == 2 and all(torch.isfinite(torch.tensor(summary["losses"])))
    acc = EventAccumulator(str(run / "tensorboard"))
    acc.Reload()
    assert "train/toy/flatness" in acc.Tags()["scalars"]  # logged under its own name
    # the commands know it by its checkpoint's config and its registry row alone
    assert main(["eval", str(run), "--data", str(tiny_dataset), "--no-progress"]) == 0
    assert (run / "metrics_test.json").is_file()
    assert main(["predict", str(run), "--data", str(tiny_dataset), "--out", str(tmp_path / "pred"),
                 "--max-samples", "1"]) == 0
    assert any((tmp_path / "pred").rglob("*"))


@pytest.fixture
def toy_input():
    """A toy that needs an input of its own (`tests.mcdp.toy_method.EGO_SPEED`): its module and this row, nothing
    else (its row names no ``model.method``: the row's name is it)."""
    row = methods.register(methods.Method("toy_input", "Toy with an input", {"model.refine_steps": 0,
                                                                             "loss.consistency_weight": 0.0},
                                          ToyInputDepth))
    yield row
    methods.unregister("toy_input")


def test_a_toy_with_an_input_of_its_own_gets_it_in_training_and_inference(toy_input, ds, tmp_path, one_thread):
    """Its field is in every training sample and in the predictor's input (and in no other method's), it moves
    the depth, and a gradient reaches the layer that reads it; the cut keeps it (it carries no other camera)."""
    from mcdp.predict import Predictor
    from mcdp.trainer import Trainer

    cfg = load_config(RunConfig, TINY / "base.yaml", ["train.steps=2", "scale.source=odometry"],
                      base=dict(toy_input.defaults))
    assert methods.fields_of(cfg) == (EGO_SPEED,)
    assert methods.fields_of(load_config(RunConfig, TINY / "mono2.yaml")) == ()
    run = tmp_path / "run"
    tr = Trainer(cfg, ds, run, progress=False, tensorboard=False)
    try:
        item = tr.train_set[0]
        assert list(item["fields"]) == ["ego_speed"] and item["fields"]["ego_speed"].shape == (len(ds.camera_names),)
        assert float(item["fields"]["ego_speed"][0]) > 0.1  # the tiny render drives ~2 m per frame
        batch = tr.to_device(collate([tr.train_set[0], tr.train_set[1]]))
        assert batch.fields["ego_speed"].shape == (2, len(ds.camera_names))
        _, losses = tr.system.process_batch(batch, 0, train=True)
        losses["loss"].backward()
        assert float(tr.depth.speed_gain.grad.abs()) > 0  # the loss reaches the layer that reads the input
        tr.system.zero_grad()
        tr.train()
    finally:
        tr.close()
    pred = Predictor(run, ds, "last")
    inp = pred.inputs(ds.split("test")[0], 1)
    assert set(inp.network_input.fields) == {"ego_speed"} and inp.cut().network_input.fields.keys() == {"ego_speed"}
    with torch.no_grad():
        pred.network.speed_gain.fill_(1.0)
        a = pred.forward(inp)["depth", "init", 0]
        faster = dict(inp.network_input.fields, ego_speed=inp.network_input.fields["ego_speed"] * 3)
        b = pred.forward(dataclasses.replace(inp, network_input=dataclasses.replace(inp.network_input,
                                                                                     fields=faster)))["depth", "init", 0]
    assert not torch.allclose(a, b)  # the input reaches the depth


def test_the_toy_row_is_what_the_study_and_the_report_read(toy):
    """Sweeps accept it, reports label it in table order and read its network's members for the warm start."""
    from study.sweep.config import SweepConfig
    from study.sweep.pretrain import warm_start_line

    assert SweepConfig(methods=["toy", "mono2"]).methods == ["mono2", "toy"]
    assert methods.label("toy") == "Toy net"
    assert warm_start_line(["toy"]) == "Toy net starts from its mono head; Toy net's gain start fresh"
    methods.check_run(toy_cfg(toy))


def test_the_toy_needs_no_edit_of_the_readme_and_no_role_of_its_own(toy, toy_input, capsys):
    """Its module and its row are all: README.md and its guide list no method to keep in step (they point to ``mcdp presets
    methods``, which lists the toys from their rows), and a row's role is derived from its network (neither toy
    reads ground truth: both are methods)."""
    import re

    from study.method_commands import main

    # the README is a front page; its user guide holds what it held (issue 60): both are read
    readme = (ROOT / "README.md").read_text() + (ROOT / "docs" / "GUIDE.md").read_text()
    assert "mcdp presets methods" in readme and not re.search(r"`model\.method`\s*\(`\w+`\s*\|", readme)
    assert "toy" not in re.findall(r"`(\w+)`", readme)
    assert main(["presets", "methods"]) == 0
    listed = {ln.split()[0]: ln for ln in capsys.readouterr().out.splitlines()[1:]}
    assert listed["toy"].endswith("Toy net (method)") and "model.method=toy " in listed["toy"]
    assert listed["toy_input"].endswith("Toy with an input (method)") and "model.method=toy_input" in listed["toy_input"]
    assert toy.role == toy_input.role == "method" and not ToyInputDepth.reads_ground_truth()


def test_the_toy_row_does_not_outlive_its_fixture():
    """Run after the tests above (file order): their fixture's teardown removed the row, so no other test
    sees a toy method in the global registry."""
    assert "toy" not in methods.METHODS and "toy_input" not in methods.METHODS
    assert all(m.defaults["model.method"] not in ("toy", "toy_input") for m in methods.METHODS.values())
