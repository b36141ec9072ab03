"""The yardsticks that ride on the as-trained pass as extra stages (`study.sweep.probes.Probed`): each reads ground truth,
so each is a yardstick, never a method. Their rows are in `study.sweep.variants` (``adds_stage`` / ``predict_stage``).

- **ORACLE weights** (a network with bases only): ``oracle``, this run's bases at per-image weights fitted to the
  ground truth on every valid pixel (`mcdp.oracle.fit_oracle_weights`: the best its bases can express), and
  ``oracle_overlap``, fitted on the overlap pixels only (what one global weight vector per image could carry from a
  perfectly known overlap to the rest).
- **hand-built propagator** (a network that reads no other camera only): ``oracle_spread``, the last stage's depth
  corrected from the overlap's ground truth alone (`mcdp.oracle.spread_from_overlap`): how much the overlap could
  tell the rest of the image through a simple propagator that needs no training, whatever the budget.

Every stage reads the ground truth within the probe's ``oracle_range`` (metres) and works at the training size: once
per sample (the probe's ``sample_memo``), taken from the evaluation's own reading of the sample when the sweep shares
it (``Probed.truths``, `mcdp.evaluate.TruthCache`); both ORACLE fits of a sample run as one batch.
"""
from __future__ import annotations

from typing import TYPE_CHECKING

if TYPE_CHECKING:
    import torch

ORACLE, ORACLE_OVL, SPREAD = "oracle", "oracle_overlap", "oracle_spread"


def has_bases(pred, oracle_range) -> bool:
    """The ORACLE weights' stages apply: a ground-truth range and a network with bases (``n_out > 1``)."""
    return oracle_range is not None and pred.n_out > 1


def reads_no_other_camera(pred, oracle_range) -> bool:
    """The propagator's stage applies: a ground-truth range and a network that reads no other camera."""
    return oracle_range is not None and not pred.network.uses_neighbours


def _truth(probe, seq: str, frame: int, size: tuple[int, int]):
    """(ground truth, its valid pixels, the overlap pixels), (N, 1, h, w) at ``size``, on the predictor's device:
    read once per sample (the probe's ``sample_memo``), from the evaluation's own reading of it when the probe has
    one (``probe.truths``, `mcdp.evaluate.TruthCache`, of the same dataset), else from the dataset
    (`mcdp.truth.ground_truth_at`, `mcdp.truth.overlap_at`: the same values)."""
    pred = probe.pred
    key = ("truth", seq, frame, tuple(size), probe.oracle_range)
    memo = probe.sample_memo
    if key not in memo:
        shared = probe.truths
        if shared is not None and shared.ds is pred.ds:
            gt, valid, ov = _truth_from(shared.get(seq, frame), pred.reader.mask_full, size, probe.oracle_range)
        else:
            from mcdp.truth import ground_truth_at, overlap_at

            gt, valid = ground_truth_at(pred.ds, pred.reader.mask_full, seq, frame, size, probe.oracle_range)
            ov = overlap_at(pred.ds, pred.reader.mask_full, seq, frame, size)
        memo[key] = (gt.to(pred.device), valid.to(pred.device), ov.to(pred.device))
    return memo[key]


def _truth_from(truth, masks, size: tuple[int, int], depth_range: tuple[float, float]):
    """`_truth`'s three maps from an evaluation's `mcdp.eval_truth.SampleTruth` (its depth as read, float64, and its
    overlap), by the very operations of `mcdp.truth.ground_truth_at` and `mcdp.truth.overlap_at`."""
    import numpy as np
    import torch
    import torch.nn.functional as F

    lo, hi = depth_range
    gts, valids, ovs = [], [], []
    for c, depth in enumerate(truth.gts):
        g = torch.from_numpy(depth.astype("float32"))[None, None]
        v = (g >= lo) & (g <= hi) & torch.as_tensor(masks[c], dtype=torch.bool)[None, None]
        gts.append(F.interpolate(g, size=size, mode="nearest"))
        valids.append(F.interpolate(v.float(), size=size, mode="nearest") > 0.5)
        m = np.where(truth.overlaps[c], depth, 0.0).astype(np.float32)
        ovs.append(F.interpolate(torch.from_numpy(m)[None, None], size=size, mode="nearest") > 0)
    return torch.cat(gts), torch.cat(valids), torch.cat(ovs)


def _fitted(probe, seq: str, frame: int, out: dict, overlap_only: bool) -> "torch.Tensor":
    """The run's bases at per-image weights fitted to the ground truth (on the overlap pixels only: no overlap
    pixel gives 1/n), times the network's scale."""
    from mcdp.methods.base import combine_bases

    net = probe.pred.network
    bases = out["bases"][0]  # (N, n, h, w)
    wts = _weights(probe, seq, frame, bases, overlap_only)
    if not overlap_only:
        probe.accumulate("oracle_weight_move", (wts - 1.0 / wts.shape[1]).abs().mean(1).sum())
    return net.to_depth(combine_bases(bases.float(), wts))[1] * out["scale"].view(-1, 1, 1, 1)


def _weights(probe, seq: str, frame: int, bases, overlap_only: bool) -> "torch.Tensor":
    """(N, n) ORACLE weights of one sample (`mcdp.oracle.fit_oracle_weights`); when both ORACLE stages ride on the
    pass, both fits run as one batch of 2N images, kept in the probe's ``sample_memo`` for the second stage: each
    image's loss, gradient and Adam step are its own, so the weights are those of two separate fits."""
    from mcdp.oracle import fit_oracle_weights

    memo = probe.sample_memo
    if ("oracle_weights", overlap_only) not in memo:
        gt, valid, ov = _truth(probe, seq, frame, tuple(bases.shape[-2:]))
        both = {ORACLE, ORACLE_OVL} <= {v.name for v in probe.extra}
        kinds = (False, True) if both else (overlap_only,)
        wts = fit_oracle_weights(torch_cat([bases] * len(kinds)), torch_cat([gt] * len(kinds)),
                                 torch_cat([valid & ov if k else valid for k in kinds]), probe.pred.network.to_depth)
        for k, w in zip(kinds, wts.split(bases.shape[0])):
            memo["oracle_weights", k] = w
    return memo["oracle_weights", overlap_only]


def torch_cat(tensors: list) -> "torch.Tensor":
    """``torch.cat`` of ``tensors``; one tensor as it is."""
    import torch

    return tensors[0] if len(tensors) == 1 else torch.cat(tensors)


def oracle_depth(probe, seq: str, frame: int, out: dict, depth) -> "torch.Tensor":
    """Stage ``oracle``: the bases at the weights fitted on every valid pixel (their move from 1/n is recorded as
    ``oracle_weight_move``)."""
    return _fitted(probe, seq, frame, out, overlap_only=False)


def oracle_overlap_depth(probe, seq: str, frame: int, out: dict, depth) -> "torch.Tensor":
    """Stage ``oracle_overlap``: the bases at the weights fitted on the overlap pixels only."""
    return _fitted(probe, seq, frame, out, overlap_only=True)


def spread_depth(probe, seq: str, frame: int, out: dict, depth) -> "torch.Tensor":
    """Stage ``oracle_spread``: ``depth`` (N, 1, h, w) corrected from the overlap's ground truth (within the ORACLE
    depth range, scene pixels) by `mcdp.oracle.spread_from_overlap`."""
    import torch

    from mcdp.oracle import spread_from_overlap

    gt, valid, ov = _truth(probe, seq, frame, tuple(depth.shape[-2:]))
    known = torch.where(valid & ov, gt, torch.zeros_like(gt)).to(depth.device)
    return spread_from_overlap(depth.float(), known)


def oracle_columns(base: dict, own: dict, entry: dict) -> None:
    """Variant ``oracle``'s columns on the as-trained row: its abs_rel and the refinement's headroom to it."""
    base["oracle.median.mean.abs_rel"] = own.get("median.mean.abs_rel", float("nan"))
    init = base.get("init.median.mean.abs_rel", base.get("median.mean.abs_rel", float("nan")))
    gap = init - base["oracle.median.mean.abs_rel"]
    base["refine.headroom"] = gap
    base["refine.headroom_closed"] = ((init - base.get("median.mean.abs_rel", float("nan"))) / gap
                                      if gap > 1e-9 else float("nan"))
