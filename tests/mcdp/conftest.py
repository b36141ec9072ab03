"""Fixtures shared by the mcdp tests."""
from __future__ import annotations

from pathlib import Path

import pytest
import torch

TINY = Path(__file__).resolve().parents[2] / "configs" / "train" / "tiny"


@pytest.fixture
def one_thread():
    """Run a test on one torch thread (deterministic, no oversubscription on shared CPUs)."""
    n = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(n)


@pytest.fixture(scope="module")
def ds(tiny_dataset):
    """The tiny dataset (tests/conftest.py), opened."""
    from synth.open import open_dataset

    return open_dataset(tiny_dataset)


# --------------------------------------------------------------------------- runs and networks of the tiny presets
def _trained(ds, run: Path, preset: str, *overrides: str) -> Path:
    """`run` trained one step (validated at it) from the tiny preset `preset` with `overrides`, in process."""
    from corelib.configlib import load_config
    from mcdp.config import RunConfig
    from mcdp.trainer import Trainer

    cfg = load_config(RunConfig, TINY / f"{preset}.yaml", ["train.steps=1", "train.val_every=1", *overrides])
    tr = Trainer(cfg, ds, run, progress=False, tensorboard=False)
    try:
        tr.train()
    finally:
        tr.close()
    return run


def _untrained(ds, path: Path, preset: str, *overrides: str):
    """The predictor of a randomly initialised (seed 0) network of a tiny preset, from a checkpoint written at
    ``path``: what a trained run's predictor is, without the training (the probe's plumbing, fast)."""
    from corelib.configlib import config_to_dict, load_config
    from mcdp.config import RunConfig
    from mcdp.methods import build_network, method_params
    from mcdp.predict import Predictor
    from mcdp.runs import CHECKPOINT_VERSION, atomic_torch_save

    cfg = load_config(RunConfig, TINY / f"{preset}.yaml", list(overrides))
    with torch.random.fork_rng():
        torch.manual_seed(0)
        net = build_network(cfg.model, method_params(cfg))
    atomic_torch_save({"version": CHECKPOINT_VERSION, "step": 0, "config": config_to_dict(cfg),
                       "depth_model": net.state_dict(), "cameras": list(ds.camera_names)}, path)
    return Predictor(None, ds, checkpoint=str(path), device="cpu")


class NoNeighbours:
    """The dataset with an empty neighbour table (a rig whose cameras do not overlap)."""

    def __init__(self, ds):
        self._ds = ds
        self.neighbours = []

    def __getattr__(self, name):
        return getattr(self._ds, name)


@pytest.fixture
def trained():
    """`trained(ds, run, preset, *overrides)`: a run folder of the tiny `preset` trained one step."""
    return _trained


@pytest.fixture
def untrained():
    """`untrained(ds, path, preset, *overrides)`: the predictor of a seed-0 network of the tiny `preset`."""
    return _untrained


@pytest.fixture
def no_neighbours():
    """`no_neighbours(ds)`: the dataset with an empty neighbour table."""
    return NoNeighbours


@pytest.fixture
def eval_frame(ds):
    """(sequence, frame) of the tiny dataset that the probes predict: frame 1 of its first test sequence."""
    return ds.split("test")[0], 1


def _fake_pretraining(path: Path, bases: int = 8, mono_head: bool = True) -> dict:
    """A shared pretraining file at `path` as `study.sweep.pretrain` writes it (the tiny MCDP m = 0 network with `bases`
    bases and, with `mono_head`, the mono head; random weights of seed 123, step 7); returns its state dict."""
    from corelib.configlib import config_to_dict, load_config
    from mcdp.config import RunConfig
    from mcdp.methods.depth_bases import DepthModel
    from mcdp.warmstart import FORMAT, VERSION

    cfg = load_config(RunConfig, TINY / "mcdp_m0.yaml", [f"model.bases={bases}",
                                                          f"model.mono_head={str(mono_head).lower()}"])
    torch.manual_seed(123)
    model = DepthModel(cfg.model)
    sd = model.state_dict()
    torch.save({"format": FORMAT, "version": VERSION, "config_hash": "abc", "model": config_to_dict(cfg.model),
                "depth_model": sd, "step": 7}, path)
    return sd


@pytest.fixture
def fake_pretraining():
    """`fake_pretraining(path, bases=8, mono_head=True)`: a random shared pretraining file; its state dict."""
    return _fake_pretraining
