"""The trainer's validation: the val loss that picks best.pt, and depth metrics for TensorBoard only.

`validation_loss` is the final stage's L_p + lambda L_con on the fixed val rig samples
(`mcdp.trainer.Trainer.val_indices`), no ground truth: the step's own ``stage/<final>`` loss
(`mcdp.system`), read as the training step computes it, never re-weighted here (a method's own terms
and the velocity term are not in it). Where the dataset has depth, the final stage's
depth of those samples is also scored (`DepthAccumulator`, logged as ``val/depth_<metric>``): abs_rel, sq_rel, rmse,
rmse_log, a1..a3 (`mcdp.metrics`), pixels of every camera pooled, at dataset resolution (the prediction
resized bilinearly), clamped and masked as `mcdp.evaluate` does (``eval.min_depth`` / ``max_depth``, the
scene mask), unscaled (metric: the scale the run learned). Model selection never reads them (best.pt
stays chosen by the val loss, without ground truth); `mcdp eval` remains the measurement.

Example::

    v = validation_loss(trainer, trainer.val_indices())
    acc = DepthAccumulator()
    acc.add(ds, seq, frame, depth_nhw, cfg.eval)     # (N, h, w) metres, training size
    acc.metrics(sums)                                 # {"abs_rel": ..., ...}
"""
from __future__ import annotations

import cv2
import numpy as np
import torch

from mcdp.data import collate
from mcdp.metrics import clamp_depth, metric_names, metric_terms, metrics_from_means, nan_metrics, valid_gt_mask


@torch.no_grad()
def validation_loss(t, idx: list[int]) -> float:
    """The val loss of trainer ``t`` over the val samples ``idx`` (each rank its share; the mean over all)
    at ``t.step``; the networks are back in train mode after. With ground truth (rank 0, TensorBoard on),
    rank 0's samples' depth metrics are logged too (one process: all of them)."""
    acc = DepthAccumulator() if t.ds.has_depth and t.dist.is_main and t.log.enabled else None
    nets = [n for n in (t.depth, t.pose) if n is not None]
    for n in nets:
        n.eval()
    vals = []
    final = t.depth.stages[-1]
    for i in idx[t.dist.rank::t.dist.world]:
        batch = t.to_device(collate([t.val_set[i]]))
        outputs, losses = t.system.process_batch(batch, t.step, train=False)
        if acc is not None:
            seq, frame = t.val_set.seqs[int(batch.seq_index[0])], int(batch.frame[0])
            acc.add(t.ds, seq, frame, outputs["depth", final, 0][:, 0].float().cpu().numpy(), t.cfg.eval)
        vals.append(float(losses[f"stage/{final}"]))
    for n in nets:
        n.train()
    total, count = t.dist.sum_([float(np.sum(vals)), float(len(vals))], t.device)
    if acc is not None:
        t.log.scalars({f"val/depth_{k}": v for k, v in acc.metrics(acc.sums).items()}, t.step)
    return total / count


class DepthAccumulator:
    """Sums of the per-pixel metric terms over val samples (`sums`: 7 term sums, then the pixel count)."""

    def __init__(self) -> None:
        self.sums = np.zeros(len(metric_names()) + 1, dtype=np.float64)

    def add(self, ds, seq: str, frame: int, depth: np.ndarray, cfg) -> None:
        """Score one rig sample: ``depth`` (N, h, w) predicted metres in ``ds.camera_names`` order."""
        for c, name in enumerate(ds.camera_names):
            gt = np.asarray(ds.read_depth(seq, name, frame), dtype=np.float64)
            pred = cv2.resize(np.asarray(depth[c], dtype=np.float32), (gt.shape[1], gt.shape[0]),
                              interpolation=cv2.INTER_LINEAR)
            valid = valid_gt_mask(gt, ds.mask(name), cfg.min_depth, cfg.max_depth)
            if not valid.any():
                continue
            p = clamp_depth(pred[valid], cfg.min_depth, cfg.max_depth)
            self.sums[:-1] += metric_terms(gt[valid], p).sum(axis=1)
            self.sums[-1] += int(valid.sum())

    @staticmethod
    def metrics(sums) -> dict:
        """Metrics from (all ranks') summed `sums`; NaN without a valid pixel."""
        sums = np.asarray(sums, dtype=np.float64)
        if not sums[-1] > 0:
            return nan_metrics()
        return metrics_from_means(sums[:-1] / sums[-1])
