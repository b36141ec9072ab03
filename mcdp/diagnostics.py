"""Depth-collapse diagnostics: the spread of predicted depth, and when it means "collapsed".

Self-supervised depth can degenerate to a constant map, or saturate at a bound
of its range (``model.min_depth`` / ``model.max_depth``), while its loss still
looks plausible. The trainer logs `depth_spread` of every logged step and warns
with `collapse_reason`; the evaluator stores the spread of the test predictions so
that the sweep report can flag a run that ended collapsed.

- ratio: per image, the 90th over the 10th percentile of depth on scene pixels;
  the median over images. Ground truth of our scenes: 4-10 (road near, buildings
  far); a constant map: 1.
- at_min / at_max: fraction of scene pixels within 2 % of the range's bounds.
"""
from __future__ import annotations

import numpy as np
import torch

#: a p90/p10 ratio below this is a constant depth map
COLLAPSE_RATIO = 1.25
#: more than this fraction of pixels at one bound of the depth range is a saturated network
SATURATED_FRACTION = 0.5


def depth_spread(depth: torch.Tensor, mask: torch.Tensor | None = None, min_depth: float | None = None,
                 max_depth: float | None = None) -> dict:
    """Spread statistics of a batch of depth maps.

    Args:
        depth: (B, 1, H, W) metres (torch tensor; no gradient is kept).
        mask: optional (B, 1, H, W), > 0 = scene pixel.
        min_depth, max_depth: the model's range, for the at-bound fractions (optional).

    Returns:
        {"ratio": median_b p90/p10, "at_min": fraction, "at_max": fraction} (floats;
        the fractions are 0 when no bound is given).
    """
    d = depth.detach().float().flatten(1)
    m = torch.ones_like(d, dtype=torch.bool) if mask is None else (mask.detach().flatten(1) > 0)
    ratios, at_min, at_max, n = [], 0.0, 0.0, 0
    for b in range(d.shape[0]):
        v = d[b][m[b]]
        if v.numel() < 10:
            continue
        q = torch.quantile(v, torch.tensor([0.1, 0.9], dtype=v.dtype, device=v.device))
        ratios.append(float(q[1] / q[0].clamp(min=1e-6)))
        if min_depth is not None:
            at_min += float((v <= min_depth * 1.02).sum())
        if max_depth is not None:
            at_max += float((v >= max_depth * 0.98).sum())
        n += v.numel()
    return {
        "ratio": float(np.median(ratios)) if ratios else float("nan"),
        "at_min": at_min / max(n, 1),
        "at_max": at_max / max(n, 1),
    }


def collapse_reason(spread: dict) -> str | None:
    """A short sentence when the spread says the depth collapsed, else None."""
    if spread.get("at_min", 0.0) > SATURATED_FRACTION:
        return f"{spread['at_min']:.0%} of pixels at model.min_depth (sigmoid saturated)"
    if spread.get("at_max", 0.0) > SATURATED_FRACTION:
        return f"{spread['at_max']:.0%} of pixels at model.max_depth (sigmoid saturated)"
    r = spread.get("ratio", float("nan"))
    if np.isfinite(r) and r < COLLAPSE_RATIO:
        return f"depth is nearly constant (p90/p10 = {r:.2f} < {COLLAPSE_RATIO})"
    return None
