"""The overlap experiment's instruments: the cut evaluation, the ORACLE weights of the bases, the
refinement-acting record, the weight networks' own learning rate, and lambda's one default."""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import torch

from corelib.configlib import load_config
from mcdp.config import LossConfig, RunConfig
from mcdp.methods.base import combine_bases, disp_to_depth
from mcdp.oracle import fit_oracle_weights, si_log_error
from mcdp.predict import Predictor
from mcdp.trainer import Trainer
from study.probes import CUT, TRAINED, Probed

ROOT = Path(__file__).resolve().parents[2]
TINY = ROOT / "configs" / "train" / "tiny"


def trained(ds, run: Path, preset: str, *overrides: str) -> Path:
    cfg = load_config(RunConfig, TINY / f"{preset}.yaml", ["train.steps=1", "train.val_every=1", *overrides])
    tr = Trainer(cfg, ds, run, progress=False, tensorboard=False)
    try:
        tr.train()
    finally:
        tr.close()
    return run


class NoNeighbours:
    """The dataset with an empty neighbour table (a rig whose cameras do not overlap)."""

    def __init__(self, ds):
        self._ds = ds
        self.neighbours = []

    def __getattr__(self, name):
        return getattr(self._ds, name)


def probe(run, ds, variant=TRAINED, **kw) -> Probed:
    """The run's predictor evaluated as one variant of the overlap experiment (`study.probes`)."""
    return Probed(Predictor(run, ds, device="cpu"), variant, **kw)


def _frame(ds):
    seq = ds.split("test")[0]
    return seq, 1


def test_cut_equals_normal_for_mono2(ds, tmp_path, one_thread):
    run = trained(ds, tmp_path / "m", "mono2")
    seq, f = _frame(ds)
    a = Predictor(run, ds, device="cpu").predict(seq, f)
    b = probe(run, ds, CUT).predict(seq, f)
    assert list(a) == list(b) == ["init"]
    assert np.array_equal(a["init"], b["init"])


def test_cut_equals_normal_without_neighbours_and_differs_with_them(ds, tmp_path, one_thread):
    # a last layer far from zero: the weight network's output depends on what the neighbours show
    run = trained(ds, tmp_path / "m1", "mcdp_m1", "model.weight_init_std=1.0")
    seq, f = _frame(ds)
    lone = NoNeighbours(ds)
    a = Predictor(run, lone, device="cpu").predict(seq, f)
    b = probe(run, lone, CUT).predict(seq, f)
    for st in ("init", "refine1"):
        assert np.array_equal(a[st], b[st]), st
    full = probe(run, ds)
    cut = probe(run, ds, CUT)
    pa, pb = full.predict(seq, f), cut.predict(seq, f)
    assert np.array_equal(pa["init"], pb["init"])  # the bases do not see the neighbours
    assert not np.array_equal(pa["refine1"], pb["refine1"])  # the refinement does
    # the acting record: the weights moved away from 1/n, differently with and without neighbours
    # (a fresh decoder's bases are nearly equal, so the depth moves little: only > 0 is asserted)
    assert full.refinement["images"] == cut.refinement["images"] == len(ds.camera_names)
    assert full.refinement["weight_move"] > 1e-2 and cut.refinement["weight_move"] > 1e-2
    assert full.refinement["weight_move"] != cut.refinement["weight_move"]
    assert full.refinement["depth_change_m"] > 0


def test_refinement_record_of_a_method_without_refinement(ds, tmp_path, one_thread):
    run = trained(ds, tmp_path / "m", "mono2")
    p = probe(run, ds)
    p.predict(*_frame(ds))
    assert p.refinement["images"] == len(ds.camera_names)
    assert np.isnan(p.refinement["weight_move"]) and np.isnan(p.refinement["depth_change_m"])


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_oracle_weights_recover_a_basis_that_is_the_ground_truth(seed):
    g = torch.Generator().manual_seed(seed)
    B, n, h, w = 3, 8, 16, 24
    to_depth = lambda s: disp_to_depth(s, 0.1, 100.0)  # noqa: E731
    gt = 2.0 + 30.0 * torch.rand(B, 1, h, w, generator=g)
    min_disp, max_disp = 1 / 100.0, 1 / 0.1
    sig_gt = (1.0 / gt - min_disp) / (max_disp - min_disp)
    bases = torch.rand(B, n, h, w, generator=g) * 0.2
    k = int(torch.randint(n, (1,), generator=g))
    bases[:, k : k + 1] = sig_gt
    valid = torch.ones(B, 1, h, w, dtype=torch.bool)
    uniform = to_depth(combine_bases(bases, torch.full((B, n), 1.0 / n)))[1]
    wts = fit_oracle_weights(bases, gt, valid, to_depth, steps=200)
    fit = to_depth(combine_bases(bases, wts))[1]
    e0, e1 = si_log_error(uniform, gt, valid), si_log_error(fit, gt, valid)
    assert (e1 < 0.02 * e0).all(), (e0, e1)
    assert (wts[:, k] > 0.9).all()
    assert torch.allclose(wts.sum(1), torch.ones(B))


def test_oracle_weights_keep_uniform_without_valid_pixels():
    bases = torch.rand(2, 4, 8, 8)
    wts = fit_oracle_weights(bases, torch.full((2, 1, 8, 8), 5.0), torch.zeros(2, 1, 8, 8, dtype=torch.bool),
                             lambda s: disp_to_depth(s, 0.1, 100.0), steps=5)
    assert torch.allclose(wts, torch.full((2, 4), 0.25))


def test_oracle_stage_is_extra_and_labelled(ds, tmp_path, one_thread):
    run = trained(ds, tmp_path / "m1", "mcdp_m1")
    p = probe(run, ds, oracle_range=(0.5, 80.0))
    out = p.predict(*_frame(ds))
    assert list(out) == ["init", "refine1", "final", "oracle", "oracle_overlap"]
    assert np.array_equal(out["final"], out["refine1"])
    assert p.refinement["oracle_weight_move"] > 0


def test_lambda_default_is_the_papers_and_one_source():
    from mcdp.methods import METHODS, PAPER_LAMBDA

    assert LossConfig().consistency_weight == 1e-3 == PAPER_LAMBDA
    assert "Default 1e-3, the paper's" in LossConfig.__doc__ and "1e-4" in LossConfig.__doc__
    for m in ("mcdp_m0", "mcdp_m1", "mcdp_m2"):
        assert METHODS[m].defaults["loss.consistency_weight"] == PAPER_LAMBDA
        for d in (TINY, TINY.parent):
            assert load_config(RunConfig, d / f"{m}.yaml", []).loss.consistency_weight == PAPER_LAMBDA


def test_weight_networks_learn_at_their_own_rate(ds, tmp_path, one_thread):
    cfg = load_config(RunConfig, TINY / "mcdp_m1.yaml", ["train.steps=1", "train.lr=3e-4", "train.weight_lr_mult=10"])
    tr = Trainer(cfg, ds, tmp_path / "r", progress=False, tensorboard=False)
    try:
        tr.train()
        groups = tr.optimizer.param_groups
        assert len(groups) == 2
        assert groups[0]["lr"] == pytest.approx(tr.lr_at(0)) or groups[0]["lr"] < 3e-4  # (decayed at the end)
        assert groups[1]["lr"] == pytest.approx(10 * groups[0]["lr"])
        wn = {id(p) for p in tr.depth.weight_nets.parameters()}
        assert {id(p) for p in groups[1]["params"]} == wn
        assert not wn & {id(p) for p in groups[0]["params"]}
    finally:
        tr.close()


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_overlap_oracle_on_ground_truth_bases_is_exact_on_the_overlap(seed):
    """The ORACLE of the overlap fits on overlap pixels only: a basis equal to the ground truth THERE (and
    wrong elsewhere) is found, its error on the overlap is near zero, and the other pixels do not count."""
    g = torch.Generator().manual_seed(seed)
    B, n, h, w = 2, 6, 16, 24
    to_depth = lambda s: disp_to_depth(s, 0.1, 100.0)  # noqa: E731
    gt = 2.0 + 30.0 * torch.rand(B, 1, h, w, generator=g)
    sig_gt = (1.0 / gt - 1 / 100.0) / (1 / 0.1 - 1 / 100.0)
    ov = torch.zeros(B, 1, h, w, dtype=torch.bool)
    ov[..., : w // 4] = True  # the overlap: a strip at the left edge
    bases = torch.rand(B, n, h, w, generator=g) * 0.2
    k = int(torch.randint(n, (1,), generator=g))
    bases[:, k : k + 1] = torch.where(ov, sig_gt, torch.rand(B, 1, h, w, generator=g) * 0.2)
    wts = fit_oracle_weights(bases, gt, ov, to_depth, steps=200)
    fit = to_depth(combine_bases(bases, wts))[1]
    uniform = to_depth(combine_bases(bases, torch.full((B, n), 1.0 / n)))[1]
    e0, e1 = si_log_error(uniform, gt, ov), si_log_error(fit, gt, ov)
    assert (e1 < 0.02 * e0).all(), (e0, e1)  # near-zero (scale-invariant) error on the overlap
    assert (wts[:, k] > 0.9).all()
    everywhere = fit_oracle_weights(bases, gt, torch.ones_like(ov), to_depth, steps=200)
    assert not torch.allclose(everywhere, wts, atol=0.05)  # fitted on all pixels, the wrong rest counts
