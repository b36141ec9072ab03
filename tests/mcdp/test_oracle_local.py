"""ORACLE-local (`mcdp.methods.oracle_local`): the overlap's ground truth as input, filled and emptied."""
import copy
from pathlib import Path

import numpy as np
import pytest
import torch

from mcdp.inputs import DepthInput
from mcdp.methods.oracle_local import OVERLAP_TRUTH, given_channels
from mcdp.truth import overlap_truth, overlap_truth_at
from mcdp.predict import Predictor
from study.sweep.probes import CUT, Probed

TINY = Path(__file__).resolve().parents[2] / "configs" / "train" / "tiny"


def test_overlap_input_is_the_ground_truth_on_the_overlap_and_empty_without_neighbours(ds, no_neighbours, eval_frame):
    seq, f = eval_frame
    masks = [np.asarray(ds.mask(n), bool) for n in ds.camera_names]
    maps = overlap_truth(ds, masks, seq, f)
    assert sum(int((m > 0).sum()) for m in maps) > 0  # the tiny rig overlaps
    for name, m in zip(ds.camera_names, maps):
        gt = ds.read_depth(seq, name, f)
        on = m > 0
        assert np.array_equal(m[on], gt[on].astype(np.float32))  # the ground truth itself, where it is given
    lone = no_neighbours(ds)
    assert all(not (m > 0).any() for m in overlap_truth(lone, masks, seq, f))
    assert not overlap_truth_at(lone, masks, seq, f, (16, 24)).any()


def test_filled_differs_from_emptied_and_emptied_is_the_cut(ds, tmp_path, one_thread, trained, no_neighbours,
                                                            eval_frame):
    run = trained(ds, tmp_path / "o", "oracle_local")
    seq, f = eval_frame
    net = Predictor(run, ds, device="cpu")
    filled, emptied = Probed(net), Probed(net, CUT)
    assert net.network.reads_ground_truth() and net.network.uses_neighbours
    with torch.no_grad():  # a given-depth layer far from zero: the input must change the depth
        net.network.given_encoder.weight.normal_(std=1.0)
    a, b = filled.predict(seq, f), emptied.predict(seq, f)
    assert np.array_equal(a["init"], net.predict(seq, f)["init"])  # as trained = the predictor alone
    assert not np.allclose(a["init"], b["init"])
    # emptied = the same network given an all-zero overlap input (what a camera without neighbours gets)
    lone = Predictor(run, no_neighbours(ds), device="cpu")
    with torch.no_grad():
        lone.network.given_encoder.weight.copy_(net.network.given_encoder.weight)
    assert np.array_equal(lone.predict(seq, f)["init"], b["init"])


def _oracle_and_mono2(given_std: float = 0.0):
    """A randomly initialised ORACLE-local network (tiny preset) and the Mono2 network with the same encoder and
    decoder weights; the given-depth layers random (std `given_std`) or at their zero init (0)."""
    from corelib.configlib import load_config
    from mcdp.config import RunConfig
    from mcdp.methods import build_network

    with torch.random.fork_rng():
        torch.manual_seed(0)
        oracle = build_network(load_config(RunConfig, TINY / "oracle_local.yaml", []).model).eval()
        mono = build_network(load_config(RunConfig, TINY / "mono2.yaml", []).model).eval()
        if given_std:
            with torch.no_grad():
                for conv in (oracle.given_encoder, *oracle.given_heads):
                    conv.weight.normal_(std=given_std)
    missing, unexpected = mono.load_state_dict(oracle.state_dict(), strict=False)
    assert not missing and sorted(unexpected) == ["given_encoder.weight"] + [f"given_heads.{s}.weight"
                                                                    for s in range(oracle.cfg.scales)]
    return oracle, mono


def _inp(x, K, T, mask, nbr, given=None) -> DepthInput:
    """The network's input; ``given`` (B, N, 1, H, W) the overlap's depth, or None (no input)."""
    return DepthInput(x, K, T, mask, nbr, {} if given is None else {OVERLAP_TRUTH.name: given}, (OVERLAP_TRUTH,))


def test_an_oracle_local_checkpoint_from_before_the_rename_loads_its_layers(one_thread):
    """Its layers were named ``hint`` and ``hint_heads``: a state dict under those names loads into the renamed
    layers, value for value, and nothing is missing or left over."""
    oracle, _ = _oracle_and_mono2(given_std=0.5)
    old = {k.replace("given_encoder.", "hint.").replace("given_heads.", "hint_heads."): v.clone()
           for k, v in oracle.state_dict().items()}
    assert "hint.weight" in old and "given_encoder.weight" not in old
    fresh, _ = _oracle_and_mono2()
    assert not torch.equal(fresh.given_encoder.weight, oracle.given_encoder.weight)
    fresh.load_state_dict(old)  # strict
    for k, v in oracle.state_dict().items():
        assert torch.equal(fresh.state_dict()[k], v), k


def _rig_inputs():
    """A 2-camera rig sample at 64 x 96 and its overlap's given depth: a strip at the facing edge of each camera
    and a few scattered pixels, 1 - 60 m (inside the network's depth range), 0 elsewhere."""
    g = torch.Generator().manual_seed(0)
    x = torch.rand(1, 2, 3, 64, 96, generator=g)
    K = torch.tensor([[80.0, 0, 48], [0, 80, 32], [0, 0, 1]]).expand(1, 2, 3, 3)
    T = torch.eye(4).expand(1, 2, 4, 4)
    mask = torch.ones(1, 2, 1, 64, 96)
    nbr = torch.tensor([[1, -1], [-1, 0]])
    where = torch.zeros(1, 2, 1, 64, 96, dtype=torch.bool)
    where[0, 0, 0, :, 80:] = True
    where[0, 1, 0, :, :16] = True
    where |= torch.rand(1, 2, 1, 64, 96, generator=g) < 0.02
    given = torch.where(where, 1.0 + 59.0 * torch.rand(1, 2, 1, 64, 96, generator=g), torch.zeros(()))
    return x, K, T, mask, nbr, given


def test_fresh_given_depth_layers_start_as_mono2(one_thread):
    """Zero-initialised given-depth layers (a warm start): the network is Mono2's except on the hinted pixels, which
    take the given depth (preserve_input); the pixels whose depth differs from Mono2's are exactly the hinted ones."""
    oracle, mono = _oracle_and_mono2()
    x, K, T, mask, nbr, given = _rig_inputs()
    with torch.no_grad():
        a = oracle(_inp(x, K, T, mask, nbr, given), scales=1)["depth", "init", 0]
        b = mono(_inp(x, K, T, mask, nbr), scales=1)["depth", "init", 0]
    g = given.reshape(2, 1, 64, 96)
    hinted = g > 0
    assert 0 < int(hinted.sum()) < hinted.numel()
    torch.testing.assert_close(a[~hinted], b[~hinted], rtol=1e-6, atol=0)  # off the hint: Mono2
    torch.testing.assert_close(a[hinted], g[hinted], rtol=1e-4, atol=0)  # on it: the given depth
    assert torch.equal(~torch.isclose(a, b, rtol=1e-5, atol=0), hinted)  # and nothing else moved


def test_filled_keeps_the_given_depth_at_every_scale(one_thread):
    """Hint layers far from zero: at every hinted pixel the full-resolution depth is the given depth, at every
    decoder scale the output is the given depth (resized nearest) there, and the pixels that were not handed
    a depth are not forced to anything: the hint moves them (through the given-depth layers), differently from the
    hinted ones."""
    oracle, mono = _oracle_and_mono2(given_std=0.5)
    x, K, T, mask, nbr, given = _rig_inputs()
    with torch.no_grad():
        out = oracle(_inp(x, K, T, mask, nbr, given))
        ref = mono(_inp(x, K, T, mask, nbr))
    g = given.reshape(2, 1, 64, 96)
    hinted = g > 0
    d = out["depth", "init", 0]
    torch.testing.assert_close(d[hinted], g[hinted], rtol=1e-4, atol=0)
    assert oracle.cfg.scales == 4
    for s in range(oracle.cfg.scales):
        disp = out["disp", "init", s]
        gs = torch.nn.functional.interpolate(g, size=disp.shape[-2:], mode="nearest")
        assert int((gs > 0).sum()) > 0, s
        torch.testing.assert_close(1.0 / disp[gs > 0], gs[gs > 0], rtol=1e-4, atol=0)  # scale 1/2^s: the hint
    # the other pixels: moved by the hint (not Mono2's depth), not forced (a "given" 0 m would read as the
    # network's min_depth), their logit the network's own plus the scale's given-depth head
    assert not torch.allclose(d[~hinted], ref["depth", "init", 0][~hinted], rtol=1e-3)
    assert (d[~hinted] > 1.01 * oracle.cfg.min_depth).all()
    heads_off = copy.deepcopy(oracle)
    with torch.no_grad():
        for conv in heads_off.given_heads:
            conv.weight.zero_()
        own = heads_off(_inp(x, K, T, mask, nbr, given), scales=1)["sig", "init", 0]
        want = torch.sigmoid(torch.logit(own.clamp(1e-6, 1 - 1e-6)) + oracle.given_heads[0](given_channels(g)))
    torch.testing.assert_close(out["sig", "init", 0][~hinted], want[~hinted], rtol=1e-5, atol=1e-7)


@pytest.mark.parametrize("cut", ["no overlap input", "neighbours cut"])
def test_emptied_is_exactly_mono2(one_thread, cut):
    """Emptied (no overlap input, or the neighbours cut: nbr all -1), the network is exactly Mono2's with the
    same encoder and decoder weights, at every scale, even with given-depth layers far from zero."""
    oracle, mono = _oracle_and_mono2(given_std=0.5)
    x, K, T, mask, nbr, given = _rig_inputs()
    if cut == "neighbours cut":
        nbr = torch.full_like(nbr, -1)
    with torch.no_grad():
        a = oracle(_inp(x, K, T, mask, nbr, None if cut == "no overlap input" else given))
        b = mono(_inp(x, K, T, mask, nbr))
    keys = [k for k in b if isinstance(k, tuple) and k[0] in ("sig", "disp", "depth")]
    assert len(keys) == 3 * oracle.cfg.scales and sorted(keys) == sorted(k for k in a if isinstance(k, tuple)
                                                                         and k[0] in ("sig", "disp", "depth"))
    for k in keys:
        assert torch.equal(a[k], b[k]), k


def test_the_copy_test_scores_exactly_the_hinted_pixels(ds):
    """The copy test's figure (ORACLE-local filled, overlap abs_rel) is computed on exactly the pixels handed to
    the network: the evaluation's overlap region (overlap, valid ground truth in the evaluation's depth range,
    scene mask) is the set of pixels where `overlap_truth` is > 0 and in that range, on every test image; a
    predictor that is the ground truth there and wrong elsewhere scores 0 on the overlap (scaling none)."""
    from mcdp.config import EVAL_MAX_DEPTH, EVAL_MIN_DEPTH, EvalConfig
    from mcdp.evaluate import eval_frames, EvalRig, SampleTruth, evaluate

    cfg = EvalConfig()
    assert (cfg.min_depth, cfg.max_depth) == (EVAL_MIN_DEPTH, EVAL_MAX_DEPTH)
    masks = [np.asarray(ds.mask(n), bool) for n in ds.camera_names]
    rig = EvalRig(ds)
    n_hinted = n_images = 0
    for seq in ds.split("test"):
        for f in eval_frames(ds.n_frames(seq), cfg):
            truth = SampleTruth(ds, rig, seq, f, cfg)
            for c, m in enumerate(overlap_truth(ds, masks, seq, f)):
                hinted = (m > 0) & (m >= EVAL_MIN_DEPTH) & (m <= EVAL_MAX_DEPTH) & masks[c]
                assert np.array_equal(hinted, truth.overlaps[c] & truth.valids[c]), (seq, f, c)
                n_hinted += int(hinted.sum())
                n_images += 1
    assert n_images >= 2 and n_hinted > 0

    def copy_on_the_hint(seq, f):
        maps = overlap_truth(ds, masks, seq, f)
        gts = [np.asarray(ds.read_depth(seq, n, f), np.float32) for n in ds.camera_names]
        return {"init": np.stack([np.where(m > 0, gt, 3.0 * gt + 7.0) for m, gt in zip(maps, gts)])}

    st = evaluate(ds, copy_on_the_hint, "test", cfg, progress=False)["stages"]["init"]["none"]
    assert st["overlap"]["abs_rel"] == 0.0 and st["overlap"]["a1"] == 1.0
    assert st["non_overlap"]["abs_rel"] > 0.5


def test_an_oracle_local_network_passes_the_copy_test(ds, tmp_path, one_thread, untrained):
    """End to end: an ORACLE-local network (random, given-depth layers far from zero) predicted as the sweep evaluates it
    (`study.sweep.probes`) scores ~0 abs_rel (scaling none) on the evaluation's overlap pixels, not elsewhere."""
    from mcdp.evaluate import evaluate

    pred = untrained(ds, tmp_path / "o.pt", "oracle_local")
    assert (pred.cfg.train.height, pred.cfg.train.width) == (ds.cameras[0].height, ds.cameras[0].width)
    with torch.no_grad(), torch.random.fork_rng():
        torch.manual_seed(1)
        for conv in (pred.network.given_encoder, *pred.network.given_heads):
            conv.weight.normal_(std=0.5)
    st = evaluate(ds, Probed(pred).predict, "test", progress=False)["stages"]["init"]["none"]
    assert st["overlap"]["abs_rel"] < 1e-5
    assert st["non_overlap"]["abs_rel"] > 0.05
