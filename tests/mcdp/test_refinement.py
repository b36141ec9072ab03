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
from study.sweep.probes import CUT, TRAINED, Probed
from study.sweep.variants import stages_on

ROOT = Path(__file__).resolve().parents[2]
TINY = ROOT / "configs" / "train" / "tiny"


def probe(run, ds, variant=TRAINED, **kw) -> Probed:
    """The run's predictor evaluated as one variant of the overlap experiment (`study.sweep.probes`), given an
    ``oracle_range`` with the stages of the variant table that ride on it (`study.sweep.variants.stages_on`)."""
    pred = Predictor(run, ds, device="cpu")
    rng = kw.get("oracle_range")
    return Probed(pred, variant, **kw, stages=stages_on(variant, pred, rng) if rng is not None else ())


def test_cut_equals_normal_for_mono2(ds, tmp_path, one_thread, trained, eval_frame):
    run = trained(ds, tmp_path / "m", "mono2")
    seq, f = eval_frame
    a = Predictor(run, ds, device="cpu").predict(seq, f)
    b = probe(run, ds, CUT).predict(seq, f)
    assert list(a) == list(b) == ["init"]
    assert np.array_equal(a["init"], b["init"])


def test_cut_equals_normal_without_neighbours_and_differs_with_them(ds, tmp_path, one_thread, trained, no_neighbours,
                                                                    eval_frame):
    # a last layer far from zero: the weight network's output depends on what the neighbours show
    run = trained(ds, tmp_path / "m1", "mcdp_m1", "model.weight_init_std=1.0")
    seq, f = eval_frame
    lone = no_neighbours(ds)
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


def test_refinement_record_of_a_method_without_refinement(ds, tmp_path, one_thread, trained, eval_frame):
    run = trained(ds, tmp_path / "m", "mono2")
    p = probe(run, ds)
    p.predict(*eval_frame)
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


def test_oracle_stage_is_extra_and_labelled(ds, tmp_path, one_thread, trained, eval_frame):
    run = trained(ds, tmp_path / "m1", "mcdp_m1")
    p = probe(run, ds, oracle_range=(0.5, 80.0))
    out = p.predict(*eval_frame)
    assert list(out) == ["init", "refine1", "final", "oracle", "oracle_overlap"]
    assert np.array_equal(out["final"], out["refine1"])
    assert p.refinement["oracle_weight_move"] > 0


def test_the_propagator_is_an_extra_stage_of_a_network_that_reads_no_other_camera(ds, tmp_path, one_thread, untrained,
                                                                                  eval_frame):
    """oracle_spread (the hand-built propagator): after "final" (= the network's last stage, not the propagator)
    in the as-trained probe of a network that reads no other camera, given an ORACLE range; the ground truth on
    the overlap pixels, the prediction corrected from them elsewhere. Not in a cut probe, nor for a network that
    reads its neighbours."""
    from mcdp.oracle import spread_from_overlap
    from mcdp.truth import ground_truth_at, overlap_at

    rng = (0.5, 80.0)
    mono = untrained(ds, tmp_path / "mono2.pt", "mono2")
    assert not mono.network.uses_neighbours
    def with_stages(pred, variant=TRAINED):  # the as-trained probe with the table's stages that apply to the run
        return Probed(pred, variant, oracle_range=rng, stages=stages_on(variant, pred, rng))

    p = with_stages(mono)
    assert p.stages == ["init", "final", "oracle_spread"]
    seq, f = eval_frame
    out = p.predict(seq, f)
    assert list(out) == p.stages
    plain = mono.predict(seq, f)["init"]
    assert np.array_equal(out["init"], plain) and np.array_equal(out["final"], plain)
    assert not np.allclose(out["final"], out["oracle_spread"], rtol=1e-2)
    # the propagator itself: the network's depth corrected by spread_from_overlap from the overlap's ground truth
    size = (mono.cfg.train.height, mono.cfg.train.width)
    assert size == (ds.cameras[0].height, ds.cameras[0].width)  # training size = dataset size: no resampling
    gt, valid = ground_truth_at(ds, mono.reader.mask_full, seq, f, size, rng)
    known = valid & overlap_at(ds, mono.reader.mask_full, seq, f, size)
    assert int(known.sum()) > 0
    want = spread_from_overlap(torch.from_numpy(plain)[:, None], torch.where(known, gt, torch.zeros_like(gt)))
    np.testing.assert_allclose(out["oracle_spread"], want[:, 0].numpy(), rtol=1e-5)
    np.testing.assert_allclose(out["oracle_spread"][known[:, 0].numpy()], gt[known].numpy(), rtol=1e-6)
    # no propagator: without an ORACLE range, in a cut probe, for networks that read their neighbours
    assert Probed(mono).stages == ["init"] and with_stages(mono, CUT).stages == ["init"]
    local = untrained(ds, tmp_path / "oracle_local.pt", "oracle_local")
    assert local.network.uses_neighbours
    lp = with_stages(local)
    assert lp.stages == ["init"] and list(lp.predict(seq, f)) == ["init"]
    m1 = untrained(ds, tmp_path / "m1.pt", "mcdp_m1")
    assert with_stages(m1).stages == ["init", "refine1", "final", "oracle", "oracle_overlap"]
    m0 = untrained(ds, tmp_path / "m0.pt", "mcdp_m0")  # bases without refinement: reads no other camera
    assert with_stages(m0).stages == ["init", "final", "oracle", "oracle_overlap", "oracle_spread"]


def _spread_reference(pred: torch.Tensor, known: torch.Tensor, length: float, prior: float) -> torch.Tensor:
    """`spread_from_overlap` as its docstring writes it, in float64, every pixel against every known one: on the
    known pixels r_i = log(gt_i / pred_i), g = median r_i; elsewhere pred * exp(g + rho), rho = sum_i k_i (r_i - g)
    / (sum_i k_i + prior), k_i = exp(-d_i^2 / (2 length^2)), d_i in image widths; known pixels: their truth."""
    out = pred.double().clone()
    H, W = pred.shape[-2:]
    yy, xx = np.mgrid[0:H, 0:W]
    xy = np.stack([xx.ravel(), yy.ravel()], 1) / W
    for b in range(pred.shape[0]):
        p, g = pred[b, 0].double().numpy().ravel(), known[b, 0].double().numpy().ravel()
        k = g > 0
        if not k.any():
            continue
        r = np.log(g[k]) - np.log(p[k])
        assert r.size % 2 == 1  # one middle value: the median is that of any convention
        glob = float(np.median(r))
        kern = np.exp(-((xy[:, None, :] - xy[None, k, :]) ** 2).sum(-1) / (2 * length ** 2))
        rho = kern @ (r - glob) / (kern.sum(1) + prior)
        out[b, 0] = torch.from_numpy(np.where(k, g, p * np.exp(glob + rho)).reshape(H, W))
    return out


@pytest.mark.parametrize("seed", [0, 1])
def test_the_spread_correction_is_exact_for_a_scale_error_and_keeps_the_known_pixels(seed):
    from mcdp.oracle import SPREAD_LENGTH, SPREAD_PRIOR, spread_from_overlap

    g = torch.Generator().manual_seed(seed)
    B, H, W = 3, 12, 20
    gt = 1.0 + 50.0 * torch.rand(B, 1, H, W, generator=g)
    where = torch.zeros(B, 1, H, W, dtype=torch.bool)
    where[..., : W // 5] = True  # an overlap strip at the left edge...
    where |= torch.rand(B, 1, H, W, generator=g) < 0.05  # ...and a few pixels elsewhere
    for b in range(B):  # an odd number of known pixels per image (`_spread_reference`)
        if int(where[b].sum()) % 2 == 0:
            where[b, 0, 0, -1] = ~where[b, 0, 0, -1]
    known = torch.where(where, gt, torch.zeros_like(gt))
    # a pure scale error (log ratio constant): corrected exactly everywhere
    for c in (0.3, 2.5):
        torch.testing.assert_close(spread_from_overlap(c * gt, known), gt, rtol=1e-4, atol=0)
    # any prediction: the known pixels take their ground truth exactly, the rest the documented correction,
    # and the input is left as it was
    pred = 1.0 + 50.0 * torch.rand(B, 1, H, W, generator=g)
    before = pred.clone()
    out = spread_from_overlap(pred, known)
    assert out.dtype == pred.dtype and out.shape == pred.shape and torch.equal(pred, before)
    assert torch.equal(out[where], gt[where])
    torch.testing.assert_close(out.double(), _spread_reference(pred, known, SPREAD_LENGTH, SPREAD_PRIOR),
                               rtol=1e-4, atol=0)
    assert not torch.allclose(out[~where], pred[~where], rtol=1e-2)
    torch.testing.assert_close(spread_from_overlap(pred, known, chunk=7), out, rtol=1e-5, atol=0)  # chunks


def test_an_image_without_a_known_pixel_is_unchanged():
    from mcdp.oracle import spread_from_overlap

    g = torch.Generator().manual_seed(0)
    pred = 1.0 + 50.0 * torch.rand(2, 1, 8, 10, generator=g)
    known = torch.zeros_like(pred)
    known[0, 0, 3, 4] = 7.0  # image 0 has one known pixel, image 1 none
    out = spread_from_overlap(pred, known)
    assert torch.equal(out[1], pred[1])
    assert torch.equal(spread_from_overlap(pred, torch.zeros_like(pred)), pred)
    # one known pixel: its ratio everywhere in its image
    torch.testing.assert_close(out[0], pred[0] * 7.0 / pred[0, 0, 3, 4], rtol=1e-5, atol=0)


def test_far_from_the_overlap_the_correction_is_its_median_ratio_and_near_it_its_local_error():
    """An overlap strip (the left 8 columns of 64) whose upper 20 rows say x2 (and one pixel x100) and lower 12
    rows x0.5: far from it every pixel takes the median ratio x2 (robust: neither the x0.5 rows nor the outlier
    move it); beside the x0.5 rows a pixel takes about their ratio, and along its row the correction goes
    monotonically from that local error to the global one."""
    from mcdp.oracle import SPREAD_LENGTH, spread_from_overlap

    pred = torch.full((1, 1, 32, 64), 10.0)
    known = torch.zeros_like(pred)
    known[0, 0, :20, :8] = 20.0
    known[0, 0, 20:, :8] = 5.0
    known[0, 0, 0, 0] = 1000.0
    out = spread_from_overlap(pred, known)[0, 0]
    assert (64 - 8) / 64 > 10 * SPREAD_LENGTH  # the far column: beyond the reach of the local errors
    torch.testing.assert_close(out[:, -1], torch.full((32,), 20.0), rtol=1e-6, atol=0)
    assert 0.5 * 0.9 < float(out[28, 8]) / 10.0 < 0.5 * 1.2  # the local x0.5, beside those rows
    assert float(out[5, 8]) == pytest.approx(20.0, rel=1e-2)  # beside the x2 rows: x2
    row = out[28, 8:]
    assert bool((row[1:] >= row[:-1] - 1e-5).all()) and float(row[-1]) == pytest.approx(20.0, rel=1e-6)


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
