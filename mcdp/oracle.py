"""ORACLE yardstick of MCDP's depth bases: the best depth a run's own bases can express.

MCDP predicts depth as a softmax-weighted combination of n bases (`mcdp.methods.base.combine_bases`);
its weight networks choose the n weights per image. How much could a perfect choice gain?
`fit_oracle_weights` answers per image: it fits the n softmax logits to the GROUND TRUTH
(Adam on the scale-invariant log error over valid pixels), with the bases fixed. The result is a
yardstick, not a method: it reads ground truth, and every output that carries it is labelled
ORACLE. ``init -> oracle`` is the headroom of the bases; the fraction of it that the refinement
closes, ``(init - final) / (init - oracle)``, says how much of that headroom the weight
networks found.

The scale-invariant log error (Eigen et al. 2014, lambda = 1) ignores a global scale, so the
fit matches the evaluation's median scaling: it rewards structure, not scale.
"""
from __future__ import annotations

import torch
import torch.nn.functional as F

from mcdp.methods.base import combine_bases


def si_log_error(pred: torch.Tensor, gt: torch.Tensor, valid: torch.Tensor) -> torch.Tensor:
    """Scale-invariant log error per image: (B, 1, H, W) x3 -> (B,) = var(log pred - log gt) on valid pixels."""
    v = valid.float()
    n = v.flatten(1).sum(1).clamp(min=1.0)
    d = (torch.log(pred.clamp(min=1e-6)) - torch.log(gt.clamp(min=1e-6))) * v
    mean = d.flatten(1).sum(1) / n
    return (d.square().flatten(1).sum(1) / n) - mean.square()


def ground_truth_at(ds, masks, seq: str, frame: int, size: tuple[int, int],
                    depth_range: tuple[float, float]) -> tuple[torch.Tensor, torch.Tensor]:
    """ORACLE input: every camera's ground truth at ``size`` (nearest) and its valid pixels.

    Args:
        ds: a dataset (``camera_names``, ``read_depth``); masks: per camera (H, W) bool scene masks.
        depth_range: (min, max) metres that count, as in the evaluation.
    Returns:
        gt (N, 1, h, w) metres, valid (N, 1, h, w) bool.
    """
    lo, hi = depth_range
    gts, valids = [], []
    for c, name in enumerate(ds.camera_names):
        g = torch.from_numpy(ds.read_depth(seq, name, frame).astype("float32"))[None, None]
        v = (g >= lo) & (g <= hi) & torch.as_tensor(masks[c], dtype=torch.bool)[None, None]
        gts.append(F.interpolate(g, size=size, mode="nearest"))
        valids.append(F.interpolate(v.float(), size=size, mode="nearest") > 0.5)
    return torch.cat(gts), torch.cat(valids)


@torch.enable_grad()
def fit_oracle_weights(
    bases: torch.Tensor,
    gt: torch.Tensor,
    valid: torch.Tensor,
    to_depth,
    steps: int = 100,
    lr: float = 0.1,
) -> torch.Tensor:
    """Per-image softmax weights of the bases that best explain the ground truth (ORACLE).

    Args:
        bases: (B, n, h, w) sigmoid-space bases (detached; not changed).
        gt: (B, 1, H, W) ground-truth depth in metres (H, W may differ from h, w: the combined depth
            is upsampled bilinearly, as predictions are for evaluation).
        valid: (B, 1, H, W) bool, pixels that count.
        to_depth: sig -> (disp, depth), the model's output map.
        steps, lr: Adam steps and rate on the (B, n) logits, which start at 0 (weights 1/n).

    Returns:
        (B, n) weights (softmax of the fitted logits). An image without a valid pixel keeps 1/n.
    """
    bases = bases.detach().float()
    B, n = bases.shape[:2]
    logits = torch.zeros(B, n, dtype=torch.float32, device=bases.device, requires_grad=True)
    opt = torch.optim.Adam([logits], lr=lr)
    size = tuple(gt.shape[-2:])
    for _ in range(int(steps)):
        sig = combine_bases(bases, torch.softmax(logits, 1))
        depth = to_depth(sig)[1]
        if tuple(depth.shape[-2:]) != size:
            depth = F.interpolate(depth, size=size, mode="bilinear", align_corners=False)
        loss = si_log_error(depth, gt, valid).sum()
        opt.zero_grad(set_to_none=True)
        loss.backward()
        opt.step()
    has = valid.flatten(1).any(1)
    w = torch.softmax(logits.detach(), 1)
    return torch.where(has[:, None], w, torch.full_like(w, 1.0 / n))


def overlap_truth(ds, masks, seq: str, frame: int) -> list:
    """Per camera, (H, W) float32 at the dataset resolution: the ground-truth depth of its overlap pixels
    (`synth.overlap.overlap_mask` with every neighbour, as the evaluation splits its regions), 0 elsewhere
    (a camera without neighbours: 0 everywhere). ORACLE input: it reads ground truth."""
    import numpy as np

    from synth.overlap import neighbours_of, overlap_union

    names, cams = list(ds.camera_names), list(ds.cameras)
    gts = [np.asarray(ds.read_depth(seq, n, frame), np.float64) for n in names]
    Ks, Ts = [c.K for c in cams], [c.T_ego_cam for c in cams]
    nbrs = neighbours_of(ds.neighbours, len(names))
    return [np.where(overlap_union(i, gts, Ks, Ts, masks, nbrs[i]), gts[i], 0.0).astype(np.float32)
            for i in range(len(names))]


def overlap_truth_at(ds, masks, seq: str, frame: int, size: tuple[int, int]) -> torch.Tensor:
    """(N, 1, h, w) float32: `overlap_truth` at ``size`` (nearest: a depth, never a blend of two)."""
    maps = overlap_truth(ds, masks, seq, frame)
    return torch.cat([F.interpolate(torch.from_numpy(m)[None, None], size=size, mode="nearest") for m in maps])


def overlap_at(ds, masks, seq: str, frame: int, size: tuple[int, int]) -> torch.Tensor:
    """(N, 1, h, w) bool: each camera's overlap pixels at ``size`` (nearest). ORACLE input."""
    return overlap_truth_at(ds, masks, seq, frame, size) > 0


#: the hand-built propagator's length scale (image widths): how far an overlap pixel's own error is carried
SPREAD_LENGTH = 0.05
#: the propagator's prior weight of the global ratio, in overlap pixels at distance 0 (`spread_from_overlap`)
SPREAD_PRIOR = 1.0


def spread_from_overlap(pred: torch.Tensor, known: torch.Tensor, chunk: int = 4096) -> torch.Tensor:
    """ORACLE hand-built propagator: a prediction corrected from the ground truth of the overlap alone.

    On the known (overlap) pixels i, r_i = log(gt_i / pred_i). Every other pixel x is multiplied by
    exp(g + rho(x)): g = median_i r_i, the overlap's robust scale correction, carried to the whole image;
    rho(x) = sum_i k_i (r_i - g) / (sum_i k_i + `SPREAD_PRIOR`), k_i = exp(-d_i^2 / (2 `SPREAD_LENGTH`^2)) with
    d_i the distance to pixel i in image widths, the overlap's local errors carried a few percent of the width
    and fading to the global correction beyond. Known pixels take their ground truth. A simple propagator that
    needs no training (the overlap's scale everywhere, its local structure nearby); it reads ground truth: a
    yardstick. Exact when pred = c * gt.

    Args:
        pred: (B, 1, H, W) predicted depth, metres (> 0).
        known: (B, 1, H, W) ground-truth depth of the known pixels, metres; 0 (or less) elsewhere.
    Returns:
        (B, 1, H, W): the corrected depth; an image without a known pixel is unchanged.
    """
    B, _, H, W = pred.shape
    out = pred.clone().float()
    yy, xx = torch.meshgrid(torch.arange(H, dtype=torch.float32), torch.arange(W, dtype=torch.float32),
                            indexing="ij")
    xy = torch.stack([xx.flatten(), yy.flatten()], 1).to(pred.device) / float(W)  # (HW, 2) in widths
    for b in range(B):
        p = pred[b, 0].float().flatten().clamp(min=1e-6)
        g = known[b, 0].float().flatten()
        k = g > 0
        if not bool(k.any()):
            continue
        r = torch.log(g[k]) - torch.log(p[k])  # (K,)
        glob = r.median()
        res, src = r - glob, xy[k]
        rho = torch.empty_like(p)
        for i in range(0, p.numel(), chunk):
            w = torch.exp(-torch.cdist(xy[i:i + chunk], src).square() / (2 * SPREAD_LENGTH ** 2))
            rho[i:i + chunk] = (w @ res) / (w.sum(1) + SPREAD_PRIOR)
        corrected = p * torch.exp(glob + rho)
        out[b, 0] = torch.where(k, g, corrected).view(H, W)
    return out.to(pred.dtype)
