"""The trainer's validation: the val loss that picks best.pt, and depth metrics for TensorBoard only.

`validation_loss` is the final stage's L_p + lambda L_con on the fixed val rig samples
(`val_indices`), no ground truth: the step's own ``stage/<final>`` loss
(`mcdp.system`), read as the training step computes it, never re-weighted here (a method's own terms
and the velocity term are not in it). Where the dataset has depth, the final stage's
depth of those samples is also scored (`DepthAccumulator`, logged as ``val/depth_<metric>``): abs_rel, sq_rel, rmse,
rmse_log, a1..a3 (`mcdp.metrics`), pixels of every camera pooled, at dataset resolution (the prediction
resized bilinearly), clamped and masked as `mcdp.evaluate` does (``eval.min_depth`` / ``max_depth``, the
scene mask), unscaled (metric: the scale the run learned). Model selection never reads them (best.pt
stays chosen by the val loss, without ground truth); `mcdp eval` remains the measurement.

Example::

    v, depth = validation_loss(system, val_set, idx, step, dist, device, (ds, cfg.eval))
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


def val_indices(n: int, k: int) -> list[int]:
    """The fixed val samples every validation reads: ``k`` of the ``n`` samples of the val split, evenly spread
    (the first and the last included); [] for an empty split."""
    k = min(n, k)
    return sorted({int(round(i * (n - 1) / max(k - 1, 1))) for i in range(k)}) if n else []


@torch.no_grad()
def validation_loss(system, val_set, idx: list[int], step: int, dist, device, depth_of=None) -> tuple[float, dict]:
    """The val loss over the val samples ``idx`` of ``val_set`` (a `mcdp.data.RigDataset`) at ``step``: the
    step's own ``stage/<final>`` loss of ``system`` (a `mcdp.system.SelfSupervisedSystem`, in eval mode here
    and back in train mode after), each rank its share (``dist``: `mcdp.distributed.Dist`), the mean over all.
    With ``depth_of`` (the dataset with ground truth and the `mcdp.config.EvalConfig`), this rank's samples'
    depth metrics too (`DepthAccumulator`; one process: all of them), else {}. Returns (loss, metrics)."""
    acc = DepthAccumulator() if depth_of is not None else None
    nets = [n for n in (system.depth, system.pose) if n is not None]
    for n in nets:
        n.eval()
    vals = []
    final = system.depth.stages[-1]
    for i in idx[dist.rank::dist.world]:
        batch = collate([val_set[i]]).to(device, non_blocking=True)
        outputs, losses = system.process_batch(batch, step, train=False)
        if acc is not None:
            seq, frame = val_set.seqs[int(batch.seq_index[0])], int(batch.frame[0])
            acc.add(depth_of[0], seq, frame, outputs["depth", final, 0][:, 0].float().cpu().numpy(), depth_of[1])
        vals.append(float(losses[f"stage/{final}"]))
    for n in nets:
        n.train()
    total, count = dist.sum_([float(np.sum(vals)), float(len(vals))], device)
    return total / count, (acc.metrics(acc.sums) if acc is not None else {})


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
