"""Depth evaluation metrics (Monodepth2 definitions), scalings, Dep Con and overlap masks.

All computations run in float64 numpy; inputs may be numpy arrays or torch
tensors (converted with ``.detach().cpu()``). Depths are z-depth in metres,
0 = no ground truth. Protocol (DESIGN.md): pixels with ground truth in
[min_depth, max_depth] outside the self-occlusion mask; predictions are scaled
(``none`` | ``median`` per image | ``rig_median`` one scale per rig sample) and
THEN clamped to [min_depth, max_depth], as in Monodepth2.

A metric is one `Metric` row of `METRICS` (its name, its per-pixel term, whether a root is taken after the
mean, and which way is better); everything that reads or words a metric reads that table when it runs. The
committed sweep reports tabulate every metric, so after adding one republish them (`python
scripts/republish.py`).

Example (run as a doctest in the fast tier, tests/test_doctests.py)::

    >>> import numpy as np
    >>> gt = np.array([[2.0, 4.0], [8.0, 10.0]])
    >>> pred = gt / 2                                  # right up to scale
    >>> valid = valid_gt_mask(gt, None)
    >>> s = median_scale(gt, pred, valid)
    >>> s
    2.0
    >>> m = depth_metrics(gt, clamp_depth(pred * s), valid)
    >>> m["abs_rel"], m["a1"]
    (0.0, 1.0)
    >>> better("a1"), better("none.non_overlap.abs_rel"), better("dep_con.mean")
    ('higher', 'lower', 'lower')
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Callable, Sequence

import numpy as np

from mcdp.config import EVAL_MAX_DEPTH, EVAL_MIN_DEPTH

__all__ = [
    "METRICS",
    "metric_names",
    "Metric",
    "better",
    "check_metrics",
    "depth_metrics",
    "nan_metrics",
    "valid_gt_mask",
    "clamp_depth",
    "median_scale",
    "rig_median_scale",
    "dep_con",
]

class Pixels:
    """What the metrics' per-pixel terms read, computed once: 1-D float64 ground truth `g` and prediction `p`
    (> 0), ``log_g``, the error ``d = g - p``, ``d2 = d * d`` and ``thresh = max(g / p, p / g)``."""

    def __init__(self, g: np.ndarray, p: np.ndarray, log_g: np.ndarray | None = None) -> None:
        self.g, self.p = g, p
        self.log_g = np.log(g) if log_g is None else log_g
        self.d = g - p
        self.d2 = self.d * self.d
        self.thresh = np.maximum(g / p, p / g)


#: the two directions a metric can have (`Metric.better`)
DIRECTIONS = ("lower", "higher")


@dataclass(frozen=True)
class Metric:
    """One depth metric: its per-pixel term (averaged over the pixels of a region), whether the metric
    is the square root of that mean, and which way is better (``better``: "lower" for an error such as abs_rel,
    "higher" for an accuracy such as a1). The evaluator (`mcdp.evaluate`, per region and image) and the trainer's
    validation (`mcdp.validation`, pooled sums) both read `METRICS`, and every report wording that says better or
    worse reads ``better`` (`better`), so a metric is one entry there."""

    name: str
    term: Callable[[Pixels], np.ndarray]
    root_after_mean: bool = False
    better: str = "lower"

    def __post_init__(self) -> None:
        if self.better not in DIRECTIONS:
            raise ValueError(f"Metric {self.name!r}: better={self.better!r}, must be 'lower' or 'higher'")
        if not self.name or "." in self.name:
            raise ValueError(f"Metric {self.name!r}: a name is non-empty and holds no '.' (results keys are dotted)")


def check_metrics(table: Sequence[Metric]) -> tuple[Metric, ...]:
    """``table`` as a tuple, or ValueError naming the first metric name given twice (a name is a metrics dict's
    key, a results column and a report's column: one identity)."""
    seen: set[str] = set()
    for m in table:
        if m.name in seen:
            raise ValueError(f"METRICS: metric {m.name!r} is given twice (each metric is one row of mcdp.metrics.METRICS)")
        seen.add(m.name)
    return tuple(table)


#: every metric, in table order (Monodepth2's definitions)
METRICS: tuple[Metric, ...] = check_metrics((
    Metric("abs_rel", lambda x: np.abs(x.d) / x.g),
    Metric("sq_rel", lambda x: x.d2 / x.g),
    Metric("rmse", lambda x: x.d2, root_after_mean=True),
    Metric("rmse_log", lambda x: (x.log_g - np.log(x.p)) ** 2, root_after_mean=True),
    Metric("a1", lambda x: x.thresh < 1.25, better="higher"),
    Metric("a2", lambda x: x.thresh < 1.25 ** 2, better="higher"),
    Metric("a3", lambda x: x.thresh < 1.25 ** 3, better="higher"),
))

#: measures beside `METRICS` that a results key may name, and their direction: Dep Con (the paper's consistency
#: error, `dep_con`) is an error
OTHER_MEASURES = {"dep_con": "lower"}


def metric_names() -> tuple[str, ...]:
    """The keys of every metrics dict, in table order: read from `METRICS` when called, so that a metric is one
    entry there and nothing else (tests/mcdp/test_metrics.py adds a toy one); ValueError if a name is given twice."""
    return tuple(m.name for m in check_metrics(METRICS))


def better(key: str) -> str:
    """Which way is better, "lower" or "higher", for a metric name or a results key that names one (a dotted
    column such as "none.non_overlap.a1": the metric is its last part; "dep_con.mean": a measure of
    `OTHER_MEASURES`, its first). KeyError for a key that names no metric."""
    parts = key.split(".")
    for m in METRICS:
        if m.name == parts[-1]:
            return m.better
    if parts[0] in OTHER_MEASURES:
        return OTHER_MEASURES[parts[0]]
    raise KeyError(f"{key!r} names no metric of mcdp.metrics.METRICS (nor {', '.join(OTHER_MEASURES)})")


def better_words(key: str) -> str:
    """"lower is better" or "higher is better", for the report's headings (`better`)."""
    return f"{better(key)} is better"


def _np(x, name: str, dtype=np.float64) -> np.ndarray:
    if hasattr(x, "detach"):  # torch tensor, without importing torch here
        x = x.detach().cpu().numpy()
    try:
        return np.asarray(x, dtype=dtype)
    except (TypeError, ValueError) as exc:
        raise TypeError(f"{name} must be an array or tensor, got {type(x).__name__}") from exc


def _same_shape(ref: np.ndarray, ref_name: str, **others: np.ndarray) -> None:
    for name, arr in others.items():
        if arr.shape != ref.shape:
            raise ValueError(f"{name} must have the shape of {ref_name} {ref.shape}, got {arr.shape}")


def nan_metrics() -> dict:
    """Metrics dict with every value NaN (for an empty evaluation set)."""
    return {k: float("nan") for k in metric_names()}


def depth_metrics(gt, pred, valid) -> dict:
    """Standard depth metrics over the valid pixels.

    abs_rel = mean |g - p| / g, sq_rel = mean (g - p)^2 / g, rmse = sqrt mean (g - p)^2,
    rmse_log = sqrt mean (ln g - ln p)^2, a_k = fraction with max(g/p, p/g) < 1.25^k.

    Args:
        gt: (...) ground-truth depth in metres (> 0 on valid pixels).
        pred: (...) predicted depth in metres, same shape (> 0 on valid pixels:
            clamp it first, see ``clamp_depth``).
        valid: (...) bool mask, same shape.

    Returns:
        dict with keys ``metric_names()`` (python floats); all NaN if no pixel is valid.

    Raises:
        ValueError: shapes differ, or gt/pred is not positive and finite on a valid pixel.
    """
    g = _np(gt, "gt")
    p = _np(pred, "pred")
    v = _np(valid, "valid", dtype=bool)
    _same_shape(g, "gt", pred=p, valid=v)
    if not v.any():
        return nan_metrics()
    g, p = g[v], p[v]
    if not (np.all(g > 0) and np.all(np.isfinite(g))):
        raise ValueError("gt must be positive and finite on valid pixels")
    if not (np.all(p > 0) and np.all(np.isfinite(p))):
        raise ValueError("pred must be positive and finite on valid pixels (clamp it to [min_depth, max_depth])")
    return reduce_terms(metric_terms(g, p), None)


def metric_terms(g: np.ndarray, p: np.ndarray, log_g: np.ndarray | None = None) -> np.ndarray:
    """Per-pixel terms (len(METRICS), N) of every metric (`METRICS` order) for 1-D float64 g, p > 0."""
    x = Pixels(g, p, log_g)
    return np.stack([m.term(x) for m in METRICS])


def metrics_from_means(means: np.ndarray) -> dict:
    """The metrics dict from the per-metric means of their terms (the root taken where a metric asks)."""
    return {m.name: float(np.sqrt(v) if m.root_after_mean else v) for m, v in zip(METRICS, means)}


def reduce_terms(terms: np.ndarray, sel: np.ndarray | None) -> dict:
    """Metrics dict from per-pixel terms (len(METRICS), N) over the pixels selected by bool ``sel`` (None =
    all)."""
    if terms.shape[1] == 0 or (sel is not None and not sel.any()):
        return nan_metrics()
    return metrics_from_means((terms if sel is None else terms[:, sel]).mean(axis=1))


def valid_gt_mask(gt, scene_mask, min_depth: float = EVAL_MIN_DEPTH, max_depth: float = EVAL_MAX_DEPTH) -> np.ndarray:
    """Pixels that count in the evaluation: min_depth <= gt <= max_depth and scene_mask.

    Args:
        gt: (H, W) (or any shape) ground-truth depth in metres, 0 = none.
        scene_mask: same shape, True = scene, False = ego body (or None: all scene).
        min_depth, max_depth: evaluation range in metres.

    Returns:
        bool array of gt's shape.
    """
    g = _np(gt, "gt")
    ok = (g >= min_depth) & (g <= max_depth) & np.isfinite(g)
    if scene_mask is not None:
        m = _np(scene_mask, "scene_mask", dtype=bool)
        _same_shape(g, "gt", scene_mask=m)
        ok &= m
    return ok


def clamp_depth(pred, min_depth: float = EVAL_MIN_DEPTH, max_depth: float = EVAL_MAX_DEPTH) -> np.ndarray:
    """Clamp (scaled) predictions to [min_depth, max_depth] (float64 numpy); NaN -> max_depth."""
    p = _np(pred, "pred")
    return np.clip(np.nan_to_num(p, nan=max_depth), min_depth, max_depth)


def median_scale(gt, pred, valid) -> float:
    """Per-image median scaling factor median(gt[valid]) / median(pred[valid]).

    Args:
        gt, pred: (H, W) depths in metres; valid: (H, W) bool.

    Returns:
        float; NaN if no pixel is valid (or the prediction median is not positive).
    """
    g = _np(gt, "gt")
    p = _np(pred, "pred")
    v = _np(valid, "valid", dtype=bool)
    _same_shape(g, "gt", pred=p, valid=v)
    return ratio_of_medians(g[v], p[v])


def ratio_of_medians(g: np.ndarray, p: np.ndarray) -> float:
    if g.size == 0:
        return float("nan")
    mp = float(np.median(p))
    if not mp > 0:
        return float("nan")
    return float(np.median(g)) / mp


def rig_median_scale(gts: Sequence, preds: Sequence, valids: Sequence) -> float:
    """One median scale for a whole rig sample: pixels of all cameras pooled together.

    Args:
        gts, preds, valids: equal-length lists (one entry per camera) of (H_c, W_c) arrays.

    Returns:
        float median(all gt) / median(all pred) over the valid pixels of every
        camera; NaN if there are none.
    """
    if not (len(gts) == len(preds) == len(valids)):
        raise ValueError(f"gts, preds and valids must have equal lengths, got {len(gts)}, {len(preds)}, {len(valids)}")
    gs, ps = [], []
    for c, (g, p, v) in enumerate(zip(gts, preds, valids)):
        g, p, v = _np(g, f"gts[{c}]"), _np(p, f"preds[{c}]"), _np(v, f"valids[{c}]", dtype=bool)
        _same_shape(g, f"gts[{c}]", **{f"preds[{c}]": p, f"valids[{c}]": v})
        gs.append(g[v])
        ps.append(p[v])
    if not gs:
        return float("nan")
    return ratio_of_medians(np.concatenate(gs), np.concatenate(ps))


def dep_con(depth_i, depth_hat_i, gt_i, valid) -> float:
    """Paper's Dep Con: mean over valid pixels of |D^i - D_hat^i| / D_gt^i.

    D_hat^i is neighbour j's predicted depth forward-projected (z-buffered,
    ``geometry.splat_depth``) into camera i. ``valid`` should be the evaluation
    mask of camera i AND the splat's hit mask (the overlap as seen by the model).

    Args:
        depth_i: (H, W) camera i's predicted depth (m).
        depth_hat_i: (H, W) neighbour's depth splatted into camera i (m).
        gt_i: (H, W) camera i's ground truth (m, > 0 on valid).
        valid: (H, W) bool.

    Returns:
        float; NaN if no pixel is valid.
    """
    d = _np(depth_i, "depth_i")
    dh = _np(depth_hat_i, "depth_hat_i")
    g = _np(gt_i, "gt_i")
    v = _np(valid, "valid", dtype=bool)
    _same_shape(d, "depth_i", depth_hat_i=dh, gt_i=g, valid=v)
    if not v.any():
        return float("nan")
    if not np.all(g[v] > 0):
        raise ValueError("gt_i must be positive on valid pixels")
    return float(np.mean(np.abs(d[v] - dh[v]) / g[v]))
