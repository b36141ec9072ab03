"""Model-agnostic evaluation of multi-camera depth on a synth dataset split -> metrics.json.

``evaluate(ds, predict_fn, split, cfg)`` walks every rig sample (sequence,
frame) of a split, asks ``predict_fn(seq, frame)`` for depth at the dataset
resolution, and scores it against the rendered ground truth.
``evaluate_passes(ds, {name: predict_fn}, ...)`` scores several passes (a sweep's variants) at once.

Each thing is done once: a sample's ground truth, valid pixels, overlap, labels and regions are read once
(`mcdp.eval_truth`) for every pass and stage scored on it (and for a predictor's own ground-truth stages,
through a shared `TruthCache`); a stage whose depth equals an earlier one of the sample (the added "final", a cut
pass's init) is scored once; a camera's metrics over every region and scaling are one product of its per-pixel
terms with its region matrix, summed over images as they come (no per-image dicts are kept).

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
- Lenses (issue 59): the overlap, the bands and Dep Con go through each camera's true lens (``EvalRig.cams``;
  z-test and z-buffer in each camera's depth kind), whatever a run assumed (``model.lens``). Metrics are of the
  depth kind the dataset stores: z-depth (pinhole, radtan) or RANGE (kannala_brandt: no z-depth beyond 90 deg);
  a pixel's abs_rel, rmse_log and a1-a3 are the same either way, sq_rel and rmse are metres of range
  (docs/DESIGN.md, "Evaluation protocol"). metrics.json's ``lenses`` names each camera's kind.

metrics.json layout (the returned dict; floats may be NaN where nothing was
valid, e.g. a camera without neighbours has NaN overlap metrics)::

    {"split": str, "n_samples": int, "min_depth": float, "max_depth": float,
     "frame_stride": int, "skip_ends": bool, "cameras": [names in rig order],
     "ground_truth": {"kind": "dense z-depth (rendered)" | "dense depth (...range...)" | "lidar", ...},  # ds
     "lenses": {cam: {"model": row name, "depth_kind": "z_depth" | "range"}},  # a rig with a lens only
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
    both = evaluate_passes(ds, {"a": predict_a, "b": predict_b}, "test", EvalConfig())   # {"a": m_a, "b": m_b}

The yardsticks' predictors (a constant depth, a flat road): `mcdp.priors`; labels' regions: `mcdp.label_regions`.
"""
from __future__ import annotations

from typing import Callable, Mapping, NamedTuple

import numpy as np
import torch

from mcdp.config import EvalConfig
from synth.overlap import BAND_NAMES
from synth.protocol import DatasetReader

from . import geometry
from . import label_regions as LR
from . import metrics as MT
from .eval_truth import BANDS, REGIONS, TruthCache, EvalRig, SampleTruth  # noqa: F401 (REGIONS: re-exported)
from .per_sequence import METRIC as PS_METRIC, REGIONS as PS_REGIONS, per_sequence_arrays
from .metrics import clamp_depth, dep_con, metric_names, metric_terms, ratio_of_medians

__all__ = ["EvalConfig", "SCALINGS", "TruthCache", "evaluate", "evaluate_passes"]

SCALINGS = ("none", "median", "rig_median")


# --------------------------------------------------------------------------- helpers
def _nanmean(a: np.ndarray, axis: int) -> np.ndarray:
    """np.nanmean along ``axis``, NaN where every value is NaN (without its warning)."""
    a = np.asarray(a, dtype=np.float64)
    ok = ~np.isnan(a)
    n = ok.sum(axis)
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.where(n > 0, np.where(ok, a, 0.0).sum(axis) / np.maximum(n, 1), np.nan)


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


def _splat_pairs(depths, pairs, Ks, T_c_c, shapes, scene_masks, lens=None):
    """For each ordered pair (j, i): depths[j] splatted into camera i (float64 torch, one batched call), through
    ``lens`` (`EvalRig.lens`; None: the pinhole path): depths of each camera's kind, the splat of the target's.

    Returns lists of (H_i, W_i) splatted depth and bool hit, in ``pairs`` order.
    """
    if not pairs:
        return [], []
    t = lambda a: torch.as_tensor(np.asarray(a, dtype=np.float64))  # noqa: E731
    same = len({shapes[j] for j, _ in pairs}) == 1 and len({shapes[i] for _, i in pairs}) == 1
    groups = [pairs] if same else [[p] for p in pairs]  # cameras of different sizes: one call per pair

    def lens_of(cams):
        return None if lens is None else (tuple(lens[0][c] for c in cams), t(lens[1][list(cams)]))
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
            lens_src=lens_of([j for j, _ in grp]), lens_tgt=lens_of([i for _, i in grp]),
        )
        d_out += list(d[:, 0].numpy())
        h_out += list(hit[:, 0].numpy() > 0)
    return d_out, h_out


class _Scored(NamedTuple):
    """One stage's scores of one sample: ``vals`` (scalings, regions, cameras, metrics) per-image metrics (NaN:
    nothing to score), ``dc`` (pairs,) Dep Con per ordered pair, ``spreads`` the p90/p10 of the cameras with >= 10
    valid pixels, ``holes`` (scalings, kinds, 2) [pixels beyond HOLE_RATIO x their depth, pixels] (None: no labels)."""

    vals: np.ndarray
    dc: np.ndarray
    spreads: list
    holes: np.ndarray | None


def _score(preds: list, truth: SampleTruth, rig: EvalRig, cfg: EvalConfig) -> _Scored:
    """One stage's per-image metrics of one sample, every scaling and region of a camera in one product of its
    per-pixel terms (rows: metric-major, then scaling) with the region matrix; its Dep Con, spreads and holes."""
    table = MT.METRICS  # read when called: a metric is one row there
    n_m, roots = len(table), np.array([m.root_after_mean for m in table])
    vals = np.full((len(SCALINGS), len(truth.regions), len(rig.names), n_m), np.nan)
    holes = None if rig.labels is None else np.zeros((len(SCALINGS), len(LR.HOLE_KINDS), 2), np.int64)
    hole_regions = [truth.regions.index(r) for r in LR.HOLE_REGIONS] if holes is not None else []
    p_v = [p[v] for p, v in zip(preds, truth.valids)]
    spreads = []
    for p in p_v:  # collapse diagnostic (mcdp.diagnostics): p90/p10 of the prediction
        if p.size >= 10:
            q10, q90 = np.percentile(p, [10, 90])
            spreads.append(float(q90 / max(q10, 1e-6)))
    rig_scale = ratio_of_medians(np.concatenate(truth.g_v), np.concatenate(p_v))
    for c, (g, p) in enumerate(zip(truth.g_v, p_v)):
        if g.size == 0:
            continue
        scales = (1.0, ratio_of_medians(g, p), rig_scale)  # SCALINGS order
        ks = [k for k, s in enumerate(scales) if not np.isnan(s)]
        if not ks:
            continue
        n_s = len(ks)
        p_sc = clamp_depth(np.stack([p * scales[k] for k in ks]), cfg.min_depth, cfg.max_depth)  # (S, N)
        rows = metric_terms(np.tile(g, n_s), p_sc.reshape(-1), np.tile(truth.lg_v[c], n_s)).reshape(n_m * n_s, -1)
        if holes is not None:
            rows = np.concatenate([rows, (p_sc > LR.HOLE_RATIO * g).astype(np.float64)])
        # (rows, regions); torch's product runs on the evaluation's torch threads (numpy's BLAS would spawn its own)
        sums = (torch.from_numpy(np.ascontiguousarray(rows)) @ torch.from_numpy(truth.R[c]).T).numpy()
        n = truth.counts[c]
        with np.errstate(invalid="ignore", divide="ignore"):
            means = (sums[: n_m * n_s] / n).reshape(n_m, n_s, -1)
        means[..., n == 0] = np.nan
        means[roots] = np.sqrt(means[roots])
        vals[ks, :, c, :] = means.transpose(1, 2, 0)
        for h, r in enumerate(hole_regions):
            holes[ks, h, 0] += np.rint(sums[n_m * n_s:, r]).astype(np.int64)
            holes[ks, h, 1] += int(n[r])
    # Dep Con: unscaled (metric) predictions, clamped like the "none" metrics
    metric_preds = [clamp_depth(p, cfg.min_depth, cfg.max_depth) for p in preds]
    d_hats, hits = _splat_pairs(metric_preds, rig.pairs, rig.Ks, truth.T_c_c, rig.shapes, rig.masks, rig.lens)
    dc = np.array([dep_con(metric_preds[i], d_hat, truth.gts[i], truth.valids[i] & hit)
                   for (j, i), d_hat, hit in zip(rig.pairs, d_hats, hits)], dtype=np.float64)
    return _Scored(vals, dc, spreads, holes)


class _Stage:
    """One stage's scores over the samples of a pass, summed as they come (`_summary` reduces them)."""

    def __init__(self) -> None:
        self.tot = self.cnt = self.holes = None
        self.ps: list[np.ndarray] = []   # per image: (scalings, PS_REGIONS, cameras) abs_rel (mcdp.per_sequence)
        self.dc: list[np.ndarray] = []
        self.spreads: list[float] = []

    def add(self, s: _Scored, ps_regions: list[int], metric: int | None) -> None:
        ok = ~np.isnan(s.vals)
        if self.tot is None:
            self.tot, self.cnt = np.zeros_like(s.vals), np.zeros(s.vals.shape, np.int64)
            self.holes = None if s.holes is None else np.zeros_like(s.holes)
        self.tot += np.where(ok, s.vals, 0.0)
        self.cnt += ok
        nan = np.full((len(SCALINGS), len(ps_regions), s.vals.shape[2]), np.nan)
        self.ps.append(nan if metric is None else s.vals[:, ps_regions][..., metric])
        self.dc.append(s.dc)
        self.spreads += s.spreads
        if s.holes is not None:
            self.holes += s.holes


def _metrics(v: np.ndarray) -> dict:
    return {k: float(x) for k, x in zip(metric_names(), v)}


def _summary(rig: EvalRig, regions: tuple, st: _Stage, seqs: list) -> dict:
    """One stage's entry of metrics.json from its summed per-image values (means over images, then cameras)."""
    names, out = rig.names, {}
    with np.errstate(invalid="ignore", divide="ignore"):
        per = np.where(st.cnt > 0, st.tot / np.maximum(st.cnt, 1), np.nan)  # (scalings, regions, cameras, metrics)
    cams = _nanmean(per, axis=2)
    at = {r: k for k, r in enumerate(regions)}
    ps = np.stack(st.ps)  # (images, scalings, PS_REGIONS, cameras)
    for k, sc in enumerate(SCALINGS):
        def mean(r, k=k):
            return _metrics(cams[k, at[r]])

        def per_cam(r, k=k):
            return {names[c]: _metrics(per[k, at[r], c]) for c in range(len(names))}

        out[sc] = {"mean": mean("all"), "per_camera": per_cam("all"), "overlap": mean("overlap"),
                   "non_overlap": mean("non_overlap"), "overlap_per_camera": per_cam("overlap"),
                   "non_overlap_per_camera": per_cam("non_overlap"),
                   "bands": {name: mean(b) for b, name in zip(BANDS, BAND_NAMES)},
                   "per_sequence": per_sequence_arrays({r: ps[:, k, j] for j, r in enumerate(PS_REGIONS)}, seqs)}
        if rig.labels is not None:
            out[sc]["classes"] = {g: mean(f"class_{g}") for g in rig.labels.groups}
            out[sc]["motion"] = {m: mean(m) for m in LR.MOTIONS}
            out[sc]["holes"] = LR.hole_summary({kind: st.holes[k, h].tolist() for h, kind in enumerate(LR.HOLE_KINDS)})
            out[sc]["road_bands"] = {name: mean(f"road_{b}") for b, name in zip(BANDS, BAND_NAMES)}
    pairs = _nanmean(np.stack(st.dc), axis=0) if rig.pairs else np.zeros(0)
    per_pair = {rig.pair_key[p]: float(v) for p, v in zip(rig.pairs, pairs)}
    per_cam = {names[i]: float(_nanmean(np.array([per_pair[rig.pair_key[(j, i)]] for j in rig.nbrs[i]]), axis=0))
               for i in range(len(names))}
    out["dep_con"] = {"mean": float(_nanmean(pairs, axis=0)), "per_pair": per_pair, "per_camera": per_cam}
    out["spread"] = {"ratio": float(np.median(st.spreads)) if st.spreads else float("nan")}
    return out


class _Pass:
    """One pass (one ``predict_fn``) of `evaluate_passes`: its stages, checked sample by sample, and their scores."""

    def __init__(self) -> None:
        self.stages: list[str] | None = None
        self.acc: dict[str, _Stage] = {}

    def add(self, seq: str, f: int, raw: Mapping, truth: SampleTruth, rig: EvalRig, cfg: EvalConfig, done: list) -> None:
        """Score one sample's stages ``raw``; ``done``: the sample's (predictions, scores) so far, of every pass (a
        stage bitwise equal to one of them, e.g. "final" or a cut pass's init, is scored once)."""
        raw = dict(raw)
        if not raw:
            raise ValueError(f"predict_fn({seq!r}, {f}) returned no stage")
        keys = list(raw) + ([] if "final" in raw else ["final"])  # "final" added here = the last stage
        if self.stages is None:
            self.stages, self.acc = keys, {s: _Stage() for s in keys}
        elif keys != self.stages:
            raise ValueError(f"predict_fn({seq!r}, {f}) returned stages {keys}, earlier samples {self.stages}")
        names = metric_names()
        metric = names.index(PS_METRIC) if PS_METRIC in names else None
        ps_regions = [truth.regions.index(r) for r in PS_REGIONS]
        scored = None
        for stage in keys:
            if stage in raw:  # else "final" added: the last stage's scores again
                preds = _as_stack(raw[stage], rig.names, rig.shapes, stage)
                scored = next((s for p, s in done if all(np.array_equal(a, b) for a, b in zip(p, preds))), None)
                if scored is None:
                    scored = _score(preds, truth, rig, cfg)
                    done.append((preds, scored))
            self.acc[stage].add(scored, ps_regions, metric)


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
    return evaluate_passes(ds, {"": predict_fn}, split, cfg, progress)[""]


def evaluate_passes(ds: DatasetReader, passes: Mapping[str, Callable], split: str = "test",
                    cfg: EvalConfig | None = None, progress: bool = True, truths: TruthCache | None = None) -> dict:
    """`evaluate` of several passes over one split at once, {name: metrics.json dict} in ``passes`` order: sample by
    sample, the ground truth is read once (``truths``: shared with a predictor's ground-truth stages; None: a cache
    of its own) and each pass's ``predict_fn(seq, frame)`` is called in turn, then scored on it."""
    cfg = cfg if cfg is not None else EvalConfig()
    truths = truths if truths is not None else TruthCache(ds, cfg)
    rig = truths.rig
    samples = [(seq, f) for seq in ds.split(split) for f in eval_frames(ds.n_frames(seq), cfg)]
    if not samples:
        raise ValueError(f"split {split!r} has no frame to evaluate (skip_ends={cfg.skip_ends})")
    state = {name: _Pass() for name in passes}
    it = samples
    if progress:
        from corelib.progress import progress_bar

        it = progress_bar(samples, desc=f"eval {split}", unit="sample")
    regions: tuple = ()
    for seq, f in it:
        truth = truths.get(seq, f)
        regions = truth.regions
        done: list = []
        for name, fn in passes.items():
            state[name].add(seq, f, fn(seq, f), truth, rig, cfg, done)
    seqs = [seq for seq, _ in samples]
    lenses = {} if rig.lens is None else {"lenses": {n: {"model": c.model, "depth_kind": k}  # what the metrics are of
                                                     for n, c, k in zip(rig.names, rig.cams, rig.kinds)}}
    return {name: {"split": split, "n_samples": len(samples), "min_depth": float(cfg.min_depth),
                   "max_depth": float(cfg.max_depth), "frame_stride": int(cfg.frame_stride),
                   "skip_ends": bool(cfg.skip_ends), "cameras": list(rig.names),
                   "ground_truth": dict(ds.ground_truth or {"kind": "unknown"}),  # read_depth's provenance
                   **lenses, "stages": {s: _summary(rig, regions, p.acc[s], seqs) for s in p.stages}}
            for name, p in state.items()}
