"""Model-agnostic evaluation of multi-camera depth on a synth dataset split -> metrics.json.

``evaluate(ds, predict_fn, split, cfg)`` walks every rig sample (sequence,
frame) of a split, asks ``predict_fn(seq, frame)`` for depth at the dataset
resolution, and scores it against the rendered ground truth.

Protocol (DESIGN.md, "Evaluation protocol"):

- Valid pixels: ground truth in [min_depth, max_depth] and outside the ego-body
  self-occlusion mask (``metrics.valid_gt_mask``).
- Three scalings: ``none`` (metric), ``median`` (one scale per image),
  ``rig_median`` (one scale per rig sample, shared by all cameras). The scaled
  prediction is clamped to [min_depth, max_depth] afterwards (Monodepth2).
- Accumulation: per-image metrics averaged over images (the Monodepth2
  convention), per camera; "mean" = mean of the per-camera values.
  Images with no valid pixel in a region (e.g. no overlap pixel) are skipped
  for that region, not counted as zero.
- Overlap / non-overlap: a pixel of camera i is "overlap" if some neighbour
  (``ds.neighbours``) sees its GROUND-TRUTH 3D point: in front, inside the
  image, on a scene pixel of its mask, passing a z-test against its ground
  truth (``synth.overlap.overlap_mask``, the one definition the manifest uses
  too). The split is a property of rig and scene, not of the model.
  non_overlap = valid & ~overlap.
- Distance bands: the valid pixels of each image binned by their distance to the nearest overlap
  pixel of the same image, in fractions of the image width (``synth.overlap.distance_bands``:
  the overlap itself, then 0-0.10, 0.10-0.20, 0.20-0.35, > 0.35; an image without overlap pixel
  falls in the last band). How far information from the overlap travels, per band.
- Class groups and motion (a dataset with semantic labels only, `mcdp.label_regions`): the valid pixels of
  each class group (road, building, vehicle, parked / moving vehicle, vegetation, other) and of static /
  moving objects, as regions like the bands; and the share of moving (and, as their yardstick, parked)
  vehicles' pixels predicted beyond twice their depth (the "infinite depth" hole), pooled over images.
- Dep Con (paper): for every adjacent pair, both directions, the neighbour's
  prediction is splatted with the z-buffer (``geometry.splat_depth``, source
  pixels outside the neighbour's ego mask dropped) into the target camera, and
  mean |D^i - D_hat^i| / D_gt over target pixels that are valid and hit. It is
  computed on UNSCALED (metric, scaling "none", clamped) predictions only:
  median scaling per image would change the very consistency it measures.
  Per pair: mean over images; per camera: mean of the pairs targeting it;
  mean: mean over all ordered pairs.

metrics.json layout (the returned dict; floats may be NaN where nothing was
valid, e.g. a camera without neighbours has NaN overlap metrics)::

    {"split": str, "n_samples": int, "min_depth": float, "max_depth": float,
     "frame_stride": int, "skip_ends": bool, "cameras": [names in rig order],
     "ground_truth": {"kind": "dense z-depth (rendered)" | "lidar", ...},   # ds.ground_truth
     "stages": {stage: {                     # predict_fn's stages + "final" (= last stage)
        "none" | "median" | "rig_median": {
            "mean": {abs_rel, sq_rel, rmse, rmse_log, a1, a2, a3},
            "per_camera": {cam: {7 metrics}},
            "overlap": {7 metrics}, "non_overlap": {7 metrics},         # mean over cameras
            "bands": {band name: {7 metrics}},     # by distance to the overlap (synth.overlap.BAND_NAMES)
            "classes": {group: {7 metrics}},       # with semantic labels: road, building, vehicle,
                                                   # vehicle_parked, vehicle_moving, vegetation, other
            "motion": {"static" | "moving": {7 metrics}},
            "holes": {"ratio": 2.0, "moving": float, "parked": float, "moving_pixels": int, ...},
            "road_bands": {band name: {7 metrics}},  # the road class alone, by distance to the overlap
            "per_sequence": {region: {seq: {"sum": [per cam], "n": [per cam]}}},  # abs_rel (mcdp.per_sequence)
            "overlap_per_camera": {cam: {7 metrics}},                   # extra detail
            "non_overlap_per_camera": {cam: {7 metrics}}},
        "dep_con": {"mean": float,
                    "per_pair": {"SRC->TGT": float, ...},   # SRC's depth splatted into TGT
                    "per_camera": {cam: float}},            # mean of pairs "*->cam"
        "spread": {"ratio": float}}}}         # median over images of the prediction's p90/p10
                                              # on valid pixels (mcdp.diagnostics: < 1.25 = collapsed)

Example::

    ds = synth.open.open_dataset("data/tiny")
    m = evaluate(ds, lambda seq, f: {"init": model_depth(seq, f)}, "test", EvalConfig())
    print(mcdp.tables.format_tables(m))

The yardsticks' predictors (a constant depth, a flat road): `mcdp.priors`; labels' regions: `mcdp.label_regions`.
"""
from __future__ import annotations

from typing import Callable, Mapping

import numpy as np
import torch

from mcdp.config import EvalConfig
from synth.overlap import BAND_NAMES, distance_bands, overlap_union
from synth.protocol import DatasetReader

from . import geometry
from . import label_regions as LR
from .per_sequence import per_sequence
from .truth import camera_poses_at
from .metrics import (
    metric_names,
    metric_terms,
    ratio_of_medians,
    reduce_terms,
    clamp_depth,
    dep_con,
    nan_metrics,
    valid_gt_mask,
)

__all__ = ["EvalConfig", "SCALINGS", "evaluate"]

SCALINGS = ("none", "median", "rig_median")
#: band regions: pixels binned by their distance to the nearest overlap pixel of the same image
#: (`synth.overlap.distance_bands`; "band0" is the overlap itself)
BANDS = tuple(f"band{k}" for k in range(len(BAND_NAMES)))
REGIONS = ("all", "overlap", "non_overlap") + BANDS


# --------------------------------------------------------------------------- helpers
def _nanmean(values) -> float:
    a = np.asarray(list(values), dtype=np.float64)
    if a.size == 0 or np.all(np.isnan(a)):
        return float("nan")
    return float(np.nanmean(a))


def _mean_dicts(dicts) -> dict:
    dicts = list(dicts)
    return {k: _nanmean(d[k] for d in dicts) for k in metric_names()} if dicts else nan_metrics()


def eval_frames(n_frames: int, cfg: EvalConfig) -> range:
    """The frames of a sequence the evaluation scores (every `frame_stride`-th, without the ends if `skip_ends`)."""
    if cfg.skip_ends:
        return range(1, n_frames - 1, cfg.frame_stride)
    return range(0, n_frames, cfg.frame_stride)


def _as_stack(pred, names, shapes, stage: str) -> list:
    """predict_fn output for one stage -> list of (H_c, W_c) float64 arrays."""
    if hasattr(pred, "detach"):
        pred = pred.detach().cpu().numpy()
    if isinstance(pred, np.ndarray):
        if pred.ndim != 3 or pred.shape[0] != len(names):
            raise ValueError(
                f"predict_fn stage {stage!r} must be an array (Ncam={len(names)}, H, W), got shape {pred.shape}"
            )
        arrs = [pred[c] for c in range(len(names))]
    else:
        arrs = list(pred)
        if len(arrs) != len(names):
            raise ValueError(f"predict_fn stage {stage!r} has {len(arrs)} cameras, expected {len(names)}")
    out = []
    for c, (a, shp) in enumerate(zip(arrs, shapes)):
        a = np.asarray(a.detach().cpu().numpy() if hasattr(a, "detach") else a, dtype=np.float64)
        if a.shape != shp:
            raise ValueError(
                f"predict_fn stage {stage!r}, camera {names[c]}: depth must have the dataset resolution "
                f"{shp} (upsample before returning), got {a.shape}"
            )
        out.append(a)
    return out


def _splat_pairs(depths, pairs, Ks, T_c_c, shapes, scene_masks):
    """For each ordered pair (j, i): depths[j] splatted into camera i (float64 torch, one batched call).

    Returns lists of (H_i, W_i) splatted depth and bool hit, in ``pairs`` order.
    """
    if not pairs:
        return [], []
    t = lambda a: torch.as_tensor(np.asarray(a, dtype=np.float64))  # noqa: E731
    same = len({shapes[j] for j, _ in pairs}) == 1 and len({shapes[i] for _, i in pairs}) == 1
    groups = [pairs] if same else [[p] for p in pairs]  # cameras of different sizes: one call per pair
    d_out, h_out = [], []
    for grp in groups:
        Hi, Wi = shapes[grp[0][1]]
        d, hit = geometry.splat_depth(
            torch.stack([t(depths[j]) for j, _ in grp])[:, None],
            torch.stack([t(Ks[j]) for j, _ in grp]),
            torch.stack([t(Ks[i]) for _, i in grp]),
            torch.stack([t(T_c_c[(i, j)]) for j, i in grp]),
            Hi, Wi,
            valid_src=torch.stack([t(scene_masks[j]) for j, _ in grp])[:, None],
        )
        d_out += list(d[:, 0].numpy())
        h_out += list(hit[:, 0].numpy() > 0)
    return d_out, h_out


class _Rig:
    """What `evaluate` reads of the rig once: camera names, sizes, K, T_ego_cam, scene masks, and the ordered
    neighbour pairs (src j, tgt i) with their relative poses T_ci_cj."""

    def __init__(self, ds: DatasetReader) -> None:
        self.names = list(ds.camera_names)
        specs = list(ds.cameras)
        self.shapes = [(int(s.height), int(s.width)) for s in specs]
        self.Ks = [np.asarray(s.K, dtype=np.float64) for s in specs]
        self.Ts = [np.asarray(s.T_ego_cam, dtype=np.float64) for s in specs]
        self.masks = [np.asarray(ds.mask(n), dtype=bool) for n in self.names]
        for c, (m, shp) in enumerate(zip(self.masks, self.shapes)):
            if m.shape != shp:
                raise ValueError(f"ds.mask({self.names[c]!r}) has shape {m.shape}, camera is {shp}")
        self.pairs = []  # ordered (src j, tgt i)
        for a, b in ds.neighbours:
            self.pairs += [(int(a), int(b)), (int(b), int(a))]
        self.nbrs = {i: sorted({j for j, t in self.pairs if t == i}) for i in range(len(self.names))}
        self.T_c_c = {(i, j): np.linalg.inv(self.Ts[i]) @ self.Ts[j] for j, i in self.pairs}  # T_ci_cj
        self.pair_key = {(j, i): f"{self.names[j]}->{self.names[i]}" for j, i in self.pairs}
        self.labels = LR.LabelIndex.of(ds)  # None: no semantic labels, no class / motion regions


class _Truth:
    """One sample's ground truth: depth per camera, its valid pixels, and those pixels' depth, log depth and
    region selectors (all / seen by a neighbour / not), gathered once (metrics only look at valid pixels)."""

    def __init__(self, ds: DatasetReader, rig: _Rig, seq: str, f: int, cfg: EvalConfig) -> None:
        self.gts = [np.asarray(ds.read_depth(seq, n, f), dtype=np.float64) for n in rig.names]
        for c, g in enumerate(self.gts):
            if g.shape != rig.shapes[c]:
                raise ValueError(f"ds.read_depth({seq!r}, {rig.names[c]!r}, {f}) has shape {g.shape}, expected "
                                 f"{rig.shapes[c]}")
        self.valids = [valid_gt_mask(g, m, cfg.min_depth, cfg.max_depth) for g, m in zip(self.gts, rig.masks)]
        Ts = camera_poses_at(ds, seq, f)  # each camera's own pose at its trigger time: the static rig when synchronous
        self.T_c_c = {(i, j): np.linalg.inv(Ts[i]) @ Ts[j] for j, i in rig.pairs}  # T_ci_cj of this frame (Dep Con)
        overlaps = [overlap_union(i, self.gts, rig.Ks, Ts, rig.masks, rig.nbrs[i]) for i in range(len(rig.names))]
        self.g_v = [g[v] for g, v in zip(self.gts, self.valids)]  # 1-D, float64
        self.lg_v = [np.log(g) for g in self.g_v]
        ov_v = [o[v] for o, v in zip(overlaps, self.valids)]
        self.region_sel = {"all": [None] * len(rig.names), "overlap": ov_v, "non_overlap": [~o for o in ov_v]}
        bands_v = [distance_bands(o)[v] for o, v in zip(overlaps, self.valids)]
        for k, name in enumerate(BANDS):
            self.region_sel[name] = [b == k for b in bands_v]
        self.overlaps = overlaps  # (H, W) bool per camera: the ORACLE of the overlap reads it
        if rig.labels is not None:  # class groups and motion, on the valid pixels
            sels = [rig.labels.selectors(np.asarray(ds.read_semantic(seq, n, f))[v])
                    for n, v in zip(rig.names, self.valids)]
            for r in LR.REGIONS:
                self.region_sel[r] = [s[r] for s in sels]
            for b in BANDS:  # the road alone by distance to the overlap: what the neighbours share most
                self.region_sel[f"road_{b}"] = [bd & s["class_road"] for bd, s in zip(self.region_sel[b], sels)]
            self.label_sel = sels


def _score(preds: list, truth: _Truth, rig: _Rig, cfg: EvalConfig, acc: dict, dc_acc: dict, spreads: list,
           holes: dict) -> None:
    """Append one stage's per-image metrics of one sample (per scaling, region, camera) to `acc`, its Dep Con
    per pair to `dc_acc`, its prediction spreads to `spreads` and its hole counts (with labels) to `holes`."""
    n_cam = len(rig.names)
    p_v = [p[v] for p, v in zip(preds, truth.valids)]
    for p in p_v:  # collapse diagnostic (mcdp.diagnostics): p90/p10 of the prediction
        if p.size >= 10:
            q10, q90 = np.percentile(p, [10, 90])
            spreads.append(float(q90 / max(q10, 1e-6)))
    g_v = truth.g_v
    rig_scale = ratio_of_medians(np.concatenate(g_v), np.concatenate(p_v))
    scales = {
        "none": [1.0] * n_cam,
        "median": [ratio_of_medians(g, p) for g, p in zip(g_v, p_v)],
        "rig_median": [rig_scale] * n_cam,
    }
    for sc in SCALINGS:
        for c in range(n_cam):
            s_c = scales[sc][c]
            if g_v[c].size == 0 or np.isnan(s_c):
                for r in truth.region_sel:
                    acc[sc][r][c].append(nan_metrics())
                continue
            p_sc = clamp_depth(p_v[c] * s_c, cfg.min_depth, cfg.max_depth)
            terms = metric_terms(g_v[c], p_sc, truth.lg_v[c])
            for r, sel in truth.region_sel.items():
                acc[sc][r][c].append(reduce_terms(terms, sel[c]))
            if rig.labels is not None:
                for kind, (n_far, n) in LR.hole_counts(p_sc, g_v[c], truth.label_sel[c]).items():
                    h = holes.setdefault(sc, {}).setdefault(kind, [0, 0])
                    h[0] += n_far
                    h[1] += n
    # Dep Con: unscaled (metric) predictions, clamped like the "none" metrics
    metric_preds = [clamp_depth(p, cfg.min_depth, cfg.max_depth) for p in preds]
    d_hats, hits = _splat_pairs(metric_preds, rig.pairs, rig.Ks, truth.T_c_c, rig.shapes, rig.masks)
    for (j, i), d_hat, hit in zip(rig.pairs, d_hats, hits):
        dc_acc[(j, i)].append(dep_con(metric_preds[i], d_hat, truth.gts[i], truth.valids[i] & hit))


def _summary(rig: _Rig, acc: dict, dc_acc: dict, spreads: list, holes: dict, seqs: list) -> dict:
    """One stage's entry of metrics.json from its per-image values (means over images, then cameras)."""
    names, st = rig.names, {}
    for sc in SCALINGS:
        per = {r: {names[c]: _mean_dicts(acc[sc][r][c]) for c in range(len(names))} for r in acc[sc]}
        st[sc] = {
            "mean": _mean_dicts(per["all"].values()),
            "per_camera": per["all"],
            "overlap": _mean_dicts(per["overlap"].values()),
            "non_overlap": _mean_dicts(per["non_overlap"].values()),
            "overlap_per_camera": per["overlap"],
            "non_overlap_per_camera": per["non_overlap"],
            "bands": {name: _mean_dicts(per[b].values()) for b, name in zip(BANDS, BAND_NAMES)},
            "per_sequence": per_sequence(acc[sc], seqs),
        }
        if rig.labels is not None:
            st[sc]["classes"] = {g: _mean_dicts(per[f"class_{g}"].values()) for g in LR.GROUPS}
            st[sc]["motion"] = {m: _mean_dicts(per[m].values()) for m in LR.MOTIONS}
            st[sc]["holes"] = LR.hole_summary(holes.get(sc, {}))
            st[sc]["road_bands"] = {name: _mean_dicts(per[f"road_{b}"].values()) for b, name in zip(BANDS, BAND_NAMES)}
    per_pair = {rig.pair_key[p]: _nanmean(v) for p, v in dc_acc.items()}
    per_cam = {names[i]: _nanmean(per_pair[rig.pair_key[(j, i)]] for j in rig.nbrs[i]) for i in range(len(names))}
    st["dep_con"] = {"mean": _nanmean(per_pair.values()), "per_pair": per_pair, "per_camera": per_cam}
    st["spread"] = {"ratio": float(np.median(spreads)) if spreads else float("nan")}
    return st


# --------------------------------------------------------------------------- evaluation
def evaluate(
    ds: DatasetReader,
    predict_fn: Callable[[str, int], Mapping[str, np.ndarray]],
    split: str = "test",
    cfg: EvalConfig | None = None,
    progress: bool = True,
) -> dict:
    """Evaluate depth predictions over a dataset split; returns the metrics.json dict (module docstring).

    Args:
        ds: the dataset (`synth.protocol.DatasetReader`; reads camera_names, cameras, neighbours,
            split, n_frames, read_depth, mask, ground_truth).
        predict_fn: ``(seq, frame) -> {stage: (Ncam, H, W) float depth in metres}``
            at the dataset resolution (or a list of Ncam (H_c, W_c) arrays, each camera at its own
            size, when the cameras' sizes differ), cameras in rig order, stages in order
            (the last one is also reported as "final").
        split: "train" | "val" | "test".
        cfg: EvalConfig (defaults if None).
        progress: show a tqdm progress bar.

    Returns:
        dict, layout in the module docstring.

    Raises:
        ValueError: the split has no evaluable frame, or predict_fn returns the
            wrong shapes / an inconsistent set of stages.
    """
    cfg = cfg if cfg is not None else EvalConfig()
    rig = _Rig(ds)
    samples = [(seq, f) for seq in ds.split(split) for f in eval_frames(ds.n_frames(seq), cfg)]
    if not samples:
        raise ValueError(f"split {split!r} has no frame to evaluate (skip_ends={cfg.skip_ends})")

    stages: list[str] | None = None
    # acc[stage][scaling][region][cam] -> list of per-image metric dicts
    acc: dict = {}
    dc_acc: dict = {}
    regions = REGIONS + ((LR.REGIONS + tuple(f"road_{b}" for b in BANDS)) if rig.labels is not None else ())
    it = samples
    if progress:
        from corelib.progress import progress_bar

        it = progress_bar(samples, desc=f"eval {split}", unit="sample")
    for seq, f in it:
        truth = _Truth(ds, rig, seq, f, cfg)
        raw = dict(predict_fn(seq, f))
        if not raw:
            raise ValueError(f"predict_fn({seq!r}, {f}) returned no stage")
        keys = list(raw)
        alias = None  # "final" added here = the last stage: copy its results instead of recomputing
        if "final" not in raw:
            alias = keys[-1]
            keys.append("final")
        if stages is None:
            stages = keys
            acc = {s: {sc: {r: [[] for _ in rig.names] for r in regions} for sc in SCALINGS} for s in stages}
            dc_acc = {s: {p: [] for p in rig.pairs} for s in stages}
            spread_acc = {s: [] for s in stages}
            hole_acc: dict = {s: {} for s in stages}
        elif keys != stages:
            raise ValueError(f"predict_fn({seq!r}, {f}) returned stages {keys}, earlier samples {stages}")

        for stage in stages:
            if stage == "final" and alias is not None:
                for sc in SCALINGS:
                    for r in regions:
                        for c in range(len(rig.names)):
                            acc[stage][sc][r][c].append(acc[alias][sc][r][c][-1])
                for p in rig.pairs:
                    dc_acc[stage][p].append(dc_acc[alias][p][-1])
                spread_acc[stage] = spread_acc[alias]
                hole_acc[stage] = hole_acc[alias]
                continue
            preds = _as_stack(raw[stage], rig.names, rig.shapes, stage)
            _score(preds, truth, rig, cfg, acc[stage], dc_acc[stage], spread_acc[stage], hole_acc[stage])

    seqs = [seq for seq, _ in samples]
    out_stages = {stage: _summary(rig, acc[stage], dc_acc[stage], spread_acc[stage], hole_acc[stage], seqs)
                  for stage in stages}
    return {
        "split": split,
        "n_samples": len(samples),
        "min_depth": float(cfg.min_depth),
        "max_depth": float(cfg.max_depth),
        "frame_stride": int(cfg.frame_stride),
        "skip_ends": bool(cfg.skip_ends),
        "cameras": rig.names,
        "ground_truth": dict(ds.ground_truth or {"kind": "unknown"}),  # read_depth's provenance
        "stages": out_stages,
    }
