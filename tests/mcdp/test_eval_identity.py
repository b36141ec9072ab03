"""The evaluation that reads each sample's ground truth once and scores every region and scaling of a camera in one
array product (`mcdp.evaluate.evaluate_passes`, `study.sweep.probes.run_probes` as the sweep runs it) gives the numbers
of the evaluation it replaced, kept here as the reference (`reference_evaluate`: per image, per region, per camera,
a Python loop over dicts; each pass evaluated on its own, the ORACLE stages reading their own ground truth): every
key of the metrics dict, every value to 1e-6 relative, NaN where the reference has NaN."""
from __future__ import annotations

import math
from typing import Callable, NamedTuple

import numpy as np
import pytest
import torch

from mcdp import evaluate as E
from mcdp import label_regions as LR
from mcdp.config import EvalConfig
from mcdp.metrics import (clamp_depth, dep_con, metric_names, metric_terms, nan_metrics, ratio_of_medians,
                          reduce_terms, valid_gt_mask)
from mcdp.truth import camera_poses_at
from synth.overlap import BAND_NAMES, distance_bands, overlap_union

BANDS = tuple(f"band{k}" for k in range(len(BAND_NAMES)))


# --------------------------------------------------------------------------- the reference (the replaced evaluator)
def _nanmean(values) -> float:
    a = np.asarray(list(values), dtype=np.float64)
    return float("nan") if a.size == 0 or np.all(np.isnan(a)) else float(np.nanmean(a))


def _mean_dicts(dicts) -> dict:
    dicts = list(dicts)
    return {k: _nanmean(d[k] for d in dicts) for k in metric_names()} if dicts else nan_metrics()


def _per_sequence(per_image, seqs) -> dict:
    out = {}
    for region in ("all", "overlap", "non_overlap"):
        rec = {}
        cams = per_image[region]
        for c, values in enumerate(cams):
            for seq, m in zip(seqs, values):
                r = rec.setdefault(seq, {"sum": [0.0] * len(cams), "n": [0] * len(cams)})
                v = m.get("abs_rel", math.nan)
                if math.isfinite(v):
                    r["sum"][c] += float(v)
                    r["n"][c] += 1
        out[region] = rec
    return out


def _truth(ds, rig, seq, f, cfg) -> dict:
    t = {"gts": [np.asarray(ds.read_depth(seq, n, f), dtype=np.float64) for n in rig.names]}
    t["valids"] = [valid_gt_mask(g, m, cfg.min_depth, cfg.max_depth) for g, m in zip(t["gts"], rig.masks)]
    Ts = camera_poses_at(ds, seq, f)
    t["T_c_c"] = {(i, j): np.linalg.inv(Ts[i]) @ Ts[j] for j, i in rig.pairs}
    ovs = [overlap_union(i, t["gts"], rig.Ks, Ts, rig.masks, rig.nbrs[i]) for i in range(len(rig.names))]
    t["g_v"] = [g[v] for g, v in zip(t["gts"], t["valids"])]
    t["lg_v"] = [np.log(g) for g in t["g_v"]]
    ov_v = [o[v] for o, v in zip(ovs, t["valids"])]
    sel = {"all": [None] * len(rig.names), "overlap": ov_v, "non_overlap": [~o for o in ov_v]}
    bands_v = [distance_bands(o)[v] for o, v in zip(ovs, t["valids"])]
    for k, name in enumerate(BANDS):
        sel[name] = [b == k for b in bands_v]
    if rig.labels is not None:
        sels = [rig.labels.selectors(np.asarray(ds.read_semantic(seq, n, f))[v]) for n, v in zip(rig.names, t["valids"])]
        for r in rig.labels.regions:
            sel[r] = [s[r] for s in sels]
        for b in BANDS:
            sel[f"road_{b}"] = [bd & s["class_road"] for bd, s in zip(sel[b], sels)]
        t["label_sel"] = sels
    t["sel"] = sel
    return t


def _score(preds, t, rig, cfg, acc, dc_acc, spreads, holes) -> None:
    n_cam = len(rig.names)
    p_v = [p[v] for p, v in zip(preds, t["valids"])]
    for p in p_v:
        if p.size >= 10:
            q10, q90 = np.percentile(p, [10, 90])
            spreads.append(float(q90 / max(q10, 1e-6)))
    g_v = t["g_v"]
    rig_scale = ratio_of_medians(np.concatenate(g_v), np.concatenate(p_v))
    scales = {"none": [1.0] * n_cam, "median": [ratio_of_medians(g, p) for g, p in zip(g_v, p_v)],
              "rig_median": [rig_scale] * n_cam}
    for sc in E.SCALINGS:
        for c in range(n_cam):
            s_c = scales[sc][c]
            if g_v[c].size == 0 or np.isnan(s_c):
                for r in t["sel"]:
                    acc[sc][r][c].append(nan_metrics())
                continue
            p_sc = clamp_depth(p_v[c] * s_c, cfg.min_depth, cfg.max_depth)
            terms = metric_terms(g_v[c], p_sc, t["lg_v"][c])
            for r, sel in t["sel"].items():
                acc[sc][r][c].append(reduce_terms(terms, sel[c]))
            if rig.labels is not None:
                for kind, (n_far, n) in LR.hole_counts(p_sc, g_v[c], t["label_sel"][c]).items():
                    h = holes.setdefault(sc, {}).setdefault(kind, [0, 0])
                    h[0] += n_far
                    h[1] += n
    metric_preds = [clamp_depth(p, cfg.min_depth, cfg.max_depth) for p in preds]
    d_hats, hits = E._splat_pairs(metric_preds, rig.pairs, rig.Ks, t["T_c_c"], rig.shapes, rig.masks)
    for (j, i), d_hat, hit in zip(rig.pairs, d_hats, hits):
        dc_acc[(j, i)].append(dep_con(metric_preds[i], d_hat, t["gts"][i], t["valids"][i] & hit))


def _summary(rig, acc, dc_acc, spreads, holes, seqs) -> dict:
    names, st = rig.names, {}
    for sc in E.SCALINGS:
        per = {r: {names[c]: _mean_dicts(acc[sc][r][c]) for c in range(len(names))} for r in acc[sc]}
        st[sc] = {"mean": _mean_dicts(per["all"].values()), "per_camera": per["all"],
                  "overlap": _mean_dicts(per["overlap"].values()), "non_overlap": _mean_dicts(per["non_overlap"].values()),
                  "overlap_per_camera": per["overlap"], "non_overlap_per_camera": per["non_overlap"],
                  "bands": {name: _mean_dicts(per[b].values()) for b, name in zip(BANDS, BAND_NAMES)},
                  "per_sequence": _per_sequence(acc[sc], seqs)}
        if rig.labels is not None:
            st[sc]["classes"] = {g: _mean_dicts(per[f"class_{g}"].values()) for g in rig.labels.groups}
            st[sc]["motion"] = {m: _mean_dicts(per[m].values()) for m in LR.MOTIONS}
            st[sc]["holes"] = LR.hole_summary(holes.get(sc, {}))
            st[sc]["road_bands"] = {name: _mean_dicts(per[f"road_{b}"].values()) for b, name in zip(BANDS, BAND_NAMES)}
    per_pair = {rig.pair_key[p]: _nanmean(v) for p, v in dc_acc.items()}
    per_cam = {names[i]: _nanmean(per_pair[rig.pair_key[(j, i)]] for j in rig.nbrs[i]) for i in range(len(names))}
    st["dep_con"] = {"mean": _nanmean(per_pair.values()), "per_pair": per_pair, "per_camera": per_cam}
    st["spread"] = {"ratio": float(np.median(spreads)) if spreads else float("nan")}
    return st


def reference_evaluate(ds, predict_fn, split="test", cfg=None) -> dict:
    """The evaluation as it was before the ground truth was shared and the scoring vectorised (one pass)."""
    cfg = cfg or EvalConfig()
    rig = E.EvalRig(ds)
    samples = [(seq, f) for seq in ds.split(split) for f in E.eval_frames(ds.n_frames(seq), cfg)]
    regions = E.REGIONS + ((rig.labels.regions + tuple(f"road_{b}" for b in BANDS)) if rig.labels is not None else ())
    stages, acc, dc_acc, spread_acc, hole_acc = None, {}, {}, {}, {}
    for seq, f in samples:
        t = _truth(ds, rig, seq, f, cfg)
        raw = dict(predict_fn(seq, f))
        keys, alias = list(raw), None
        if "final" not in raw:
            alias = keys[-1]
            keys.append("final")
        if stages is None:
            stages = keys
            acc = {s: {sc: {r: [[] for _ in rig.names] for r in regions} for sc in E.SCALINGS} for s in stages}
            dc_acc = {s: {p: [] for p in rig.pairs} for s in stages}
            spread_acc = {s: [] for s in stages}
            hole_acc = {s: {} for s in stages}
        for stage in stages:
            if stage == "final" and alias is not None:
                for sc in E.SCALINGS:
                    for r in regions:
                        for c in range(len(rig.names)):
                            acc[stage][sc][r][c].append(acc[alias][sc][r][c][-1])
                for p in rig.pairs:
                    dc_acc[stage][p].append(dc_acc[alias][p][-1])
                spread_acc[stage], hole_acc[stage] = spread_acc[alias], hole_acc[alias]
                continue
            preds = E._as_stack(raw[stage], rig.names, rig.shapes, stage)
            _score(preds, t, rig, cfg, acc[stage], dc_acc[stage], spread_acc[stage], hole_acc[stage])
    seqs = [seq for seq, _ in samples]
    return {"split": split, "n_samples": len(samples), "min_depth": float(cfg.min_depth),
            "max_depth": float(cfg.max_depth), "frame_stride": int(cfg.frame_stride), "skip_ends": bool(cfg.skip_ends),
            "cameras": rig.names, "ground_truth": dict(ds.ground_truth or {"kind": "unknown"}),
            "stages": {s: _summary(rig, acc[s], dc_acc[s], spread_acc[s], hole_acc[s], seqs) for s in stages}}


# --------------------------------------------------------------------------- the comparison
def differences(a, b, path: str = "", rel: float = 1e-6) -> list[str]:
    """Where two metrics dicts differ: a key present in one only, a NaN in one only, a value beyond ``rel``."""
    out: list[str] = []
    if isinstance(a, dict) and isinstance(b, dict):
        if set(a) != set(b):
            return [f"{path}: keys {sorted(set(a) ^ set(b))}"]
        for k in a:
            out += differences(a[k], b[k], f"{path}.{k}", rel)
    elif isinstance(a, (list, tuple)) and isinstance(b, (list, tuple)):
        if len(a) != len(b):
            return [f"{path}: {len(a)} against {len(b)} entries"]
        for i, (x, y) in enumerate(zip(a, b)):
            out += differences(x, y, f"{path}[{i}]", rel)
    elif isinstance(a, float) or isinstance(b, float):
        x, y = float(a), float(b)
        if math.isnan(x) or math.isnan(y):
            if not (math.isnan(x) and math.isnan(y)):
                out.append(f"{path}: {x!r} against {y!r}")
        elif abs(x - y) > rel * max(abs(x), abs(y)):
            out.append(f"{path}: {x!r} against {y!r}")
    elif a != b or type(a) is not type(b):
        out.append(f"{path}: {a!r} against {b!r}")
    return out


def leaves(d) -> int:
    if isinstance(d, dict):
        return sum(leaves(v) for v in d.values())
    if isinstance(d, (list, tuple)):
        return sum(leaves(v) for v in d)
    return 1


def test_the_comparison_sees_a_change():
    a = {"x": {"abs_rel": 0.1, "a1": float("nan"), "n": [1, 2]}}
    assert differences(a, {"x": {"abs_rel": 0.1 * (1 + 5e-7), "a1": float("nan"), "n": [1, 2]}}) == []
    assert differences(a, {"x": {"abs_rel": 0.1 * (1 + 2e-6), "a1": float("nan"), "n": [1, 2]}}) != []
    assert differences(a, {"x": {"abs_rel": 0.1, "a1": 0.5, "n": [1, 2]}}) == [".x.a1: nan against 0.5"]
    assert differences(a, {"x": {"abs_rel": 0.1, "a1": float("nan"), "n": [1, 3]}}) == [".x.n[1]: 2 against 3"]
    assert differences(a, {"x": {"abs_rel": 0.1, "n": [1, 2]}}) == [".x: keys ['a1']"]


def _noisy(ds, seed: int, nan_camera: bool = False):
    """Two stages of the fake wall's depth times seeded noise (one far off), the last camera NaN in ``nan_camera``."""
    def fn(seq, frame):
        rng = np.random.default_rng([seed, frame, len(seq), ord(seq[-1])])
        shape = (len(ds.camera_names), ds.H, ds.W)
        init = ds.Z_WALL * rng.uniform(0.3, 3.0, shape)
        ref = ds.Z_WALL * rng.uniform(0.9, 1.1, shape)
        if nan_camera:
            ref[-1] = np.nan
        return {"init": init.astype(np.float32), "refine1": ref.astype(np.float32)}
    return fn


@pytest.mark.parametrize("nan_camera", [False, True])
def test_one_pass_gives_the_reference_numbers_on_the_fake_wall(fake_dataset, one_thread, nan_camera):
    ds = fake_dataset(n_frames=5)
    fn = _noisy(ds, 3, nan_camera)
    new, ref = E.evaluate(ds, fn, "test", EvalConfig(), progress=False), reference_evaluate(ds, fn)
    assert differences(new, ref) == []
    assert leaves(new) > 1000
    assert new["stages"]["final"]["none"]["mean"]["abs_rel"] > 0.01  # not a trivial, perfect prediction


def test_passes_read_each_sample_once_and_score_as_alone(fake_dataset, one_thread):
    """Two passes evaluated together: the ground truth read once per sample and camera (not once per pass), each
    pass's numbers those of the reference on its own; a pass whose stages equal the other's scores the same."""
    ds = fake_dataset(n_frames=5)
    a, b = _noisy(ds, 1), _noisy(ds, 2)
    out = E.evaluate_passes(ds, {"a": a, "b": b, "a_again": a}, "test", EvalConfig(), progress=False)
    assert list(out) == ["a", "b", "a_again"]
    assert len(ds.depth_reads) == out["a"]["n_samples"] * len(ds.camera_names) == 12
    assert differences(out["a"], reference_evaluate(ds, a)) == []
    assert differences(out["b"], reference_evaluate(ds, b)) == []
    assert differences(out["a_again"], out["a"], rel=0.0) == []
    assert out["a"]["stages"]["init"]["none"]["mean"] != out["b"]["stages"]["init"]["none"]["mean"]


@pytest.fixture
def perturbed(untrained, ds, tmp_path):
    """`perturbed(preset)`: the predictor of a seed-0 network of the tiny `preset`, every weight nudged (seed 1)
    so that its refinement moves the weights and its stages differ."""
    def make(preset):
        pred = untrained(ds, tmp_path / f"{preset}.pt", preset)
        with torch.no_grad(), torch.random.fork_rng():
            torch.manual_seed(1)
            for p in pred.network.parameters():
                p.add_(0.05 * torch.randn_like(p))
        return pred
    return make


@pytest.mark.slow  # about 3 s each: every pass twice, four ORACLE fits of 100 steps per sample
@pytest.mark.parametrize("preset", ["mcdp_m2", "mono2"])
def test_the_sweeps_passes_give_the_reference_numbers(ds, perturbed, one_thread, preset):
    """`study.sweep.stages.evaluate_run`'s evaluation (every pass sample by sample, the ORACLE stages reading the shared
    truth, both ORACLE fits in one batch) against each pass evaluated alone by the reference, on the tiny dataset
    with labels: MCDP (m = 2) as trained (+ ORACLE, ORACLE-overlap) and cut, Mono2 (+ the propagator)."""
    from study.sweep.probes import run_probes
    from study.sweep.variants import VARIANTS

    pred = perturbed(preset)
    cfg = EvalConfig(frame_stride=2)
    rng = (cfg.min_depth, cfg.max_depth)
    truths = E.TruthCache(ds, cfg)
    new = run_probes(VARIANTS.values(), pred, rng,
                     lambda fns: E.evaluate_passes(ds, fns, "test", cfg, progress=False, truths=truths), truths=truths)
    old = {}
    for name, probe in _alone(pred, rng).items():
        old[name] = reference_evaluate(ds, probe.predict, "test", cfg)
        old[name]["refinement"] = probe.refinement
    assert list(new) == list(old) == (["trained", "cut"] if preset == "mcdp_m2" else ["trained"])
    assert differences(new, old) == []
    stages = set(new["trained"]["stages"])
    assert stages >= ({"oracle", "oracle_overlap"} if preset == "mcdp_m2" else {"oracle_spread"})
    assert "class_road" not in stages and "classes" in new["trained"]["stages"]["final"]["median"]  # labels scored
    if preset == "mcdp_m2":
        assert new["trained"]["refinement"]["weight_move"] > 0 and new["cut"]["refinement"]["cut_change_m"] > 0


class _Stage(NamedTuple):
    name: str
    predict_stage: Callable


def _old_truth(probe, seq, frame, size):
    from mcdp.truth import ground_truth_at, overlap_at

    pred = probe.pred
    gt, valid = ground_truth_at(pred.ds, pred.reader.mask_full, seq, frame, size, probe.oracle_range)
    return gt, valid, overlap_at(pred.ds, pred.reader.mask_full, seq, frame, size)


def _old_fitted(probe, seq, frame, out, overlap_only: bool):
    from mcdp.methods.base import combine_bases
    from mcdp.oracle import fit_oracle_weights

    net, bases = probe.pred.network, out["bases"][0]
    gt, valid, ov = _old_truth(probe, seq, frame, tuple(bases.shape[-2:]))
    wts = fit_oracle_weights(bases, gt, valid & ov if overlap_only else valid, net.to_depth)
    if not overlap_only:
        probe.accumulate("oracle_weight_move", (wts - 1.0 / wts.shape[1]).abs().mean(1).sum())
    return net.to_depth(combine_bases(bases.float(), wts))[1] * out["scale"].view(-1, 1, 1, 1)


def _old_spread(probe, seq, frame, out, depth):
    from mcdp.oracle import spread_from_overlap

    gt, valid, ov = _old_truth(probe, seq, frame, tuple(depth.shape[-2:]))
    return spread_from_overlap(depth.float(), torch.where(valid & ov, gt, torch.zeros_like(gt)))


#: the ORACLE stages as they were: each reads its own ground truth from the dataset and fits alone
OLD_STAGES = {"oracle": lambda p, s, f, out, d: _old_fitted(p, s, f, out, False),
              "oracle_overlap": lambda p, s, f, out, d: _old_fitted(p, s, f, out, True),
              "oracle_spread": _old_spread}


def _alone(pred, oracle_range) -> dict:
    """The sweep's probes as the replaced loop made them: each pass evaluated alone, its stages reading the dataset."""
    from study.sweep.probes import CUT, TRAINED, Probed
    from study.sweep.variants import stages_on

    def old(variant):
        return [_Stage(v.name, OLD_STAGES[v.name]) for v in stages_on(variant, pred, oracle_range)]

    trained = Probed(pred, oracle_range=oracle_range, keep=True, stages=old(TRAINED))
    probes = {TRAINED: trained}
    if pred.network.uses_neighbours:
        probes[CUT] = Probed(pred, CUT, oracle_range=oracle_range, reference=trained, stages=old(CUT))
    return probes
