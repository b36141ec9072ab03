"""ORACLE-local (`mcdp.methods.oracle_local`): the overlap's ground truth as input, filled and emptied."""
import numpy as np
import torch

from mcdp.oracle import overlap_truth, overlap_truth_at
from mcdp.predict import Predictor
from study.probes import CUT, Probed

from tests.mcdp.test_refinement import NoNeighbours, _frame, trained


def test_overlap_input_is_the_ground_truth_on_the_overlap_and_empty_without_neighbours(ds):
    seq, f = _frame(ds)
    masks = [np.asarray(ds.mask(n), bool) for n in ds.camera_names]
    maps = overlap_truth(ds, masks, seq, f)
    assert sum(int((m > 0).sum()) for m in maps) > 0  # the tiny rig overlaps
    for name, m in zip(ds.camera_names, maps):
        gt = ds.read_depth(seq, name, f)
        on = m > 0
        assert np.array_equal(m[on], gt[on].astype(np.float32))  # the ground truth itself, where it is given
    lone = NoNeighbours(ds)
    assert all(not (m > 0).any() for m in overlap_truth(lone, masks, seq, f))
    assert not overlap_truth_at(lone, masks, seq, f, (16, 24)).any()


def test_filled_differs_from_emptied_and_emptied_is_the_cut(ds, tmp_path, one_thread):
    run = trained(ds, tmp_path / "o", "oracle_local")
    seq, f = _frame(ds)
    net = Predictor(run, ds, device="cpu")
    filled, emptied = Probed(net), Probed(net, CUT)
    assert net.model.reads_overlap_truth and net.model.uses_neighbours
    with torch.no_grad():  # a hint layer far from zero: the input must change the depth
        net.model.hint.weight.normal_(std=1.0)
    a, b = filled.predict(seq, f), emptied.predict(seq, f)
    assert np.array_equal(a["init"], net.predict(seq, f)["init"])  # as trained = the predictor alone
    assert not np.allclose(a["init"], b["init"])
    # emptied = the same network given an all-zero overlap input (what a camera without neighbours gets)
    lone = Predictor(run, NoNeighbours(ds), device="cpu")
    with torch.no_grad():
        lone.model.hint.weight.copy_(net.model.hint.weight)
    assert np.array_equal(lone.predict(seq, f)["init"], b["init"])


def test_a_fresh_hint_layer_starts_as_mono2(ds, tmp_path, one_thread):
    """Zero-initialised, the overlap input changes nothing before training (a warm start begins as Mono2)."""
    from corelib.configlib import load_config
    from mcdp.config import RunConfig
    from mcdp.methods import build_depth_model
    from tests.mcdp.test_refinement import TINY

    cfg = load_config(RunConfig, TINY / "oracle_local.yaml", [])
    m = build_depth_model(cfg.model).eval()
    x = torch.rand(1, 2, 3, 64, 96)
    K = torch.tensor([[80.0, 0, 48], [0, 80, 32], [0, 0, 1]]).expand(1, 2, 3, 3)
    T = torch.eye(4).expand(1, 2, 4, 4)
    mask = torch.ones(1, 2, 1, 64, 96)
    nbr = torch.tensor([[1, -1], [-1, 0]])
    with torch.no_grad():
        a = m(x, K, T, mask, nbr, scales=1, overlap_truth=torch.rand(1, 2, 1, 64, 96) * 20)
        b = m(x, K, T, mask, nbr, scales=1)
    assert torch.equal(a["depth", "init", 0], b["depth", "init", 0])
