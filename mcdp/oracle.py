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
