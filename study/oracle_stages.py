"""The yardsticks that ride on the as-trained pass as extra stages (`study.probes.Probed`): each reads ground truth,
so each is a yardstick, never a method. Their rows are in `study.variants` (``adds_stage`` / ``predict_stage``).

- **ORACLE weights** (a network with bases only): ``oracle``, this run's bases at per-image weights fitted to the
  ground truth on every valid pixel (`mcdp.oracle.fit_oracle_weights`: the best its bases can express), and
  ``oracle_overlap``, fitted on the overlap pixels only (what one global weight vector per image could carry from a
  perfectly known overlap to the rest).
- **hand-built propagator** (a network that reads no other camera only): ``oracle_spread``, the last stage's depth
  corrected from the overlap's ground truth alone (`mcdp.oracle.spread_from_overlap`): how much the overlap could
  tell the rest of the image through a simple propagator that needs no training, whatever the budget.

Every stage reads the ground truth within the probe's ``oracle_range`` (metres) and works at the training size.
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
    """(ground truth, its valid pixels, the overlap pixels), (N, 1, h, w) at ``size``, on the predictor's device."""
    from mcdp.truth import ground_truth_at, overlap_at

    pred = probe.pred
    gt, valid = ground_truth_at(pred.ds, pred.reader.mask_full, seq, frame, size, probe.oracle_range)
    ov = overlap_at(pred.ds, pred.reader.mask_full, seq, frame, size)
    return gt.to(pred.device), valid.to(pred.device), ov.to(pred.device)


def _fitted(probe, seq: str, frame: int, out: dict, overlap_only: bool) -> "torch.Tensor":
    """The run's bases at per-image weights fitted to the ground truth (on the overlap pixels only: no overlap
    pixel gives 1/n), times the network's scale."""
    from mcdp.methods.base import combine_bases
    from mcdp.oracle import fit_oracle_weights

    net = probe.pred.network
    bases = out["bases"][0]  # (N, n, h, w)
    gt, valid, ov = _truth(probe, seq, frame, tuple(bases.shape[-2:]))
    wts = fit_oracle_weights(bases, gt, valid & ov if overlap_only else valid, net.to_depth)
    if not overlap_only:
        probe.accumulate("oracle_weight_move", (wts - 1.0 / wts.shape[1]).abs().mean(1).sum())
    return net.to_depth(combine_bases(bases.float(), wts))[1] * out["scale"].view(-1, 1, 1, 1)


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
