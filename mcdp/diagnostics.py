"""Training's guards: the spread of predicted depth and when it means "collapsed" (`CollapseGuard`), a
non-finite loss or gradient (`TrainingDiverged`), fp16 steps skipped in a row (`SkipGuard`).

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


#: steps a fresh network may stay a constant map before the collapse guard warns
COLLAPSE_GRACE_STEPS = 100
#: logged checks in a row that must show a collapse before the guard warns
COLLAPSE_STREAK = 5


class TrainingDiverged(RuntimeError):
    """The loss became NaN/inf; training stopped (the last checkpoint is intact)."""


class CollapseGuard:
    """When the trainer warns that depth collapsed: a fresh network starts as a constant (model.init_depth), so
    only once the depth has spread out, or after `COLLAPSE_GRACE_STEPS` steps that never left the constant start;
    and only when `COLLAPSE_STREAK` logged checks in a row agree (one odd batch is not a collapse)."""

    def __init__(self) -> None:
        self.armed = False
        self.streak = 0

    def warn_now(self, reason: str | None, step: int) -> bool:
        """Record one check (`collapse_reason`'s answer at `step`); True exactly when the warning is due."""
        if reason is None:
            self.armed = True
            self.streak = 0
            return False
        self.streak += 1
        return (self.armed or step >= COLLAPSE_GRACE_STEPS) and self.streak == COLLAPSE_STREAK

    def check(self, depth: torch.Tensor, mask: torch.Tensor, min_depth: float, max_depth: float,
              step: int) -> tuple[dict, str | None]:
        """One logged step's check of the final stage's depth (B*N, 1, h, w) on its scene ``mask`` (any shape of
        as many pixels): (`depth_spread` with ``collapsed``: `collapse_reason`'s answer, the reason when the
        warning is due at ``step`` (`warn_now`), else None)."""
        spread = depth_spread(depth, mask.reshape(depth.shape), min_depth, max_depth)
        reason = collapse_reason(spread)
        return dict(spread, collapsed=reason), (reason if self.warn_now(reason, step) else None)


#: fp16 steps in a row the GradScaler may skip (non-finite gradients) before training stops
FP16_SKIP_LIMIT = 20


class SkipGuard:
    """fp16 training: the GradScaler skips a step whose gradients are not finite (and lowers its scale); this
    counts such steps in a row, and says when `FP16_SKIP_LIMIT` of them stop training."""

    def __init__(self) -> None:
        self.skipped = 0

    def record(self, scale_before: float, scale_after: float, step: int) -> str | None:
        """Record one step; the message of a `TrainingDiverged` when the limit is reached, else None."""
        self.skipped = self.skipped + 1 if scale_after < scale_before else 0
        if self.skipped < FP16_SKIP_LIMIT:
            return None
        return (f"fp16: the gradients were not finite for {self.skipped} steps in a row (up to step {step}); "
                "the weights did not change in them")


def gradient_divergence(named_parameters, step: int) -> str | None:
    """The message of a `TrainingDiverged` when a gradient is NaN/inf (naming the first such parameter), else
    None."""
    named = [(n, p) for n, p in named_parameters if p.grad is not None]
    if not named or torch.isfinite(torch.nn.utils.get_total_norm([p.grad for _, p in named])):
        return None
    name = next((n for n, p in named if not torch.isfinite(p.grad).all()), "?")
    return f"the gradient of {name} is not finite at step {step} (loss was finite); the weights were not updated"


def loss_divergence(losses: dict, step: int) -> str:
    """The message of a `TrainingDiverged` for a non-finite loss: its value and every scalar term's."""
    bad = {k: float(v.detach()) for k, v in losses.items() if not k.startswith("_") and v.numel() == 1}
    return (f"loss is {float(losses['loss'].detach())} at step {step}; terms: "
            + ", ".join(f"{k}={v:.4g}" for k, v in bad.items()))
