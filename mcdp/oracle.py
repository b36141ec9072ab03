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


def fit_oracle_weights(
    bases: torch.Tensor,
    gt: torch.Tensor,
    valid: torch.Tensor,
    to_depth,
    steps: int = 100,
    lr: float = 0.1,
) -> torch.Tensor:
    """Per-image softmax weights of the bases that best explain the ground truth (ORACLE).

    The fit of `fit_oracle_weights_autograd` (the definition: Adam on the logits, the scale-invariant log error of
    the combined depth on the valid pixels), computed on what it needs: only the valid pixels of each image (packed
    into the next power of two of their count, `_width`), the loss's gradient in closed form (no autograd graph), and the ground
    truth's log read once, not at every step. ``to_depth`` must be the model's affine disparity map (`disp_to_depth`:
    disp = a + c sig, depth = 1 / disp; checked); another map, or bases and ground truth of different sizes, take
    the autograd path. The same optimisation summed in another order: the weights agree with the autograd path's
    to rounding carried through 100 Adam steps (a few 1e-5 relative on the recipe's world; docs/results/world_cost.md,
    tests/mcdp/test_oracle_fit.py), not bit for bit.

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
    affine = _affine_disparity(to_depth)
    if affine is None or tuple(gt.shape[-2:]) != tuple(bases.shape[-2:]):
        return fit_oracle_weights_autograd(bases, gt, valid, to_depth, steps, lr)
    a, c = affine
    bases = bases.detach().float()
    B, n = bases.shape[:2]
    keep = valid.reshape(B, -1).to(bases.device)
    counts = keep.sum(1)
    widths = [_width(int(k)) for k in counts.tolist()]
    perm = sorted(range(B), key=lambda b: widths[b])  # the images of one width side by side: row ranges, no gathers
    groups, start = [], 0
    for width in sorted(set(widths)):
        rows = [b for b in perm if widths[b] == width]
        if width > 0:
            groups.append((slice(start, start + len(rows)),
                           *_packed(bases, gt.detach().float(), keep, counts, rows, width, a, c)))
        start += len(rows)
    logits = torch.zeros(B, n, dtype=torch.float32, device=bases.device, requires_grad=True)  # in ``perm`` order
    opt = torch.optim.Adam([logits], lr=lr)  # elementwise: each image's step is its own
    grad = torch.zeros_like(logits)
    with torch.no_grad():
        for _ in range(int(steps)):
            w = torch.softmax(logits, 1)
            for rows, bv, bv_t, nlg, pad, inv_m, coef in groups:
                wr = w[rows]
                disp = torch.bmm(wr[:, None], bv)[:, 0]  # (b, P): a + c sig (the weights sum to 1); padding ~a
                d = torch.sub(nlg, torch.log(disp)).mul_(pad)  # log depth - log gt, 0 on padding
                mean = d.sum(1, keepdim=True).mul_(inv_m)
                # loss = sum_b [sum d^2 / m - mean^2]; dloss/ddisp = 2 (d - mean) / m * (-1 / disp)
                g = d.sub_(mean).mul_(pad).div_(disp).mul_(coef)
                gw = torch.bmm(g[:, None], bv_t)[:, 0]  # (b, n): the weights' gradient
                grad[rows] = wr * (gw - (wr * gw).sum(1, keepdim=True))  # through the softmax
            logits.grad = grad
            opt.step()
    w = torch.empty(B, n, dtype=torch.float32, device=bases.device)
    w[torch.tensor(perm, device=bases.device)] = torch.softmax(logits.detach(), 1)
    has = counts > 0
    return torch.where(has[:, None], w, torch.full_like(w, 1.0 / n))


def _width(count: int) -> int:
    """The packed width of an image with ``count`` valid pixels: the next power of two (at least 1024), a function of
    the image alone, so that an image's fit is the same bits whatever else is in its batch (the images of one width
    are computed together, each row on its own)."""
    return 0 if count == 0 else max(1024, 1 << (count - 1).bit_length())


def _packed(bases, gt, keep, counts, rows: list[int], width: int, a: float, c: float) -> tuple:
    """What the fit reads of the images ``rows`` (all of packed width ``width``): their valid pixels in pixel order,
    then zeros: (a + c x bases (b, n, P), its transpose (b, P, n), -log gt (b, P), 1 on a valid pixel (b, P),
    1 / valid count and -2 / valid count (b, 1))."""
    idx = torch.tensor(rows, device=bases.device)
    b, n = len(rows), bases.shape[1]
    k = keep[idx]
    order = torch.sort((~k).to(torch.uint8), dim=1, stable=True).indices  # each image's valid pixels first
    if order.shape[1] < width:
        order = torch.cat([order, order[:, :1].expand(b, width - order.shape[1])], 1)
    order = order[:, :width]
    m = counts[idx].float()[:, None]
    pad = (torch.arange(width, device=bases.device)[None] < m).float()
    bv = (torch.gather(bases[idx].reshape(b, n, -1), 2, order[:, None].expand(b, n, width)) * c + a) * pad[:, None]
    bv = bv + (1.0 - pad[:, None]) * a  # padding: disp a, a finite log (masked out)
    nlg = -torch.gather(torch.log(gt[idx].clamp(min=1e-6)).reshape(b, -1), 1, order) * pad
    return bv, bv.transpose(1, 2).contiguous(), nlg, pad, 1.0 / m, -2.0 / m


def _affine_disparity(to_depth) -> tuple[float, float] | None:
    """(a, c) when ``to_depth`` maps sig to disp = a + c sig and depth = 1 / disp (`mcdp.methods.base.disp_to_depth`);
    None for any other map."""
    sig = torch.tensor([0.0, 0.25, 0.5, 1.0], dtype=torch.float64)
    try:
        disp, depth = to_depth(sig)
    except Exception:  # noqa: BLE001 (a map that takes only float32, or another shape: the autograd path)
        return None
    if not (isinstance(disp, torch.Tensor) and isinstance(depth, torch.Tensor) and disp.shape == sig.shape
            and disp.dtype == torch.float64 and depth.dtype == torch.float64):
        return None
    a, c = float(disp[0]), float(disp[3] - disp[0])
    if not (a > 0 and c > 0) or not torch.allclose(disp, a + c * sig, rtol=1e-12, atol=0.0):
        return None
    if not torch.allclose(depth * disp, torch.ones_like(disp), rtol=1e-12, atol=0.0):
        return None
    return a, c


@torch.enable_grad()
def fit_oracle_weights_autograd(
    bases: torch.Tensor,
    gt: torch.Tensor,
    valid: torch.Tensor,
    to_depth,
    steps: int = 100,
    lr: float = 0.1,
) -> torch.Tensor:
    """`fit_oracle_weights` by its definition: every pixel, autograd through ``to_depth`` (any map), the ground truth
    upsampled to when sizes differ. The reference the fast path is tested against, and its fallback."""
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
