"""Self-supervised losses of MCDP: photometric (SSIM + L1) with auto-masking, smoothness, depth consistency.

Every loss takes an explicit mask (B, 1, H, W) and excludes masked pixels from
numerator AND denominator (``masked_mean``); the self-occlusion (ego body) mask
is never counted as zero-loss pixels. Images are expected in [0, 1].

Example::

    warped, valid = geometry.warp_by_depth(img_prev, depth, K, K, T_prev_cur, padding_mode="border")
    loss, per_pixel, used = reprojection_loss(img, [warped], [valid], [img_prev], mask)
    total = loss + 1e-3 * smoothness_loss(1.0 / depth, img, mask) \
        + lam * consistency_loss(depth, depth_hat, hit, mask)
"""
from __future__ import annotations

from typing import Optional, Sequence

import torch
import torch.nn.functional as F

__all__ = [
    "ssim_dissimilarity",
    "photometric_error",
    "masked_mean",
    "reprojection_loss",
    "smoothness_loss",
    "consistency_loss",
    "INVALID_ERROR",
    "min_reprojection",
    "used_pixels",
]

#: photometric error given to pixels whose warp is invalid, so any valid source wins the minimum
INVALID_ERROR = 1.0e4


def _check4(x, name: str, channels: Optional[int] = None, like: Optional[torch.Tensor] = None, doc: str = "") -> None:
    if not isinstance(x, torch.Tensor):
        raise TypeError(f"{name} must be a torch.Tensor, got {type(x).__name__}")
    if x.ndim != 4 or (channels is not None and x.shape[1] != channels):
        raise ValueError(f"{name} must have shape {doc}, got {tuple(x.shape)}")
    if like is not None and (x.shape[0] != like.shape[0] or x.shape[-2:] != like.shape[-2:]):
        raise ValueError(
            f"{name} must have shape {doc} matching batch and size of {tuple(like.shape)}, got {tuple(x.shape)}"
        )


# --------------------------------------------------------------------------- photometric
def _box3(t: torch.Tensor) -> torch.Tensor:
    """3x3 mean of a padded (B, C, H+2, W+2) tensor -> (B, C, H, W): ``F.avg_pool2d(t, 3, 1)`` as two
    separable sums of shifted views. Same values to float rounding; on a CPU about 9x faster than
    avg_pool2d forward and backward (whose kernels are not vectorised for a 3x3 window at stride 1;
    benchmarks/train_step.py, docs/results/train_step.md).
    """
    h = t[..., :, :-2] + t[..., :, 1:-1] + t[..., :, 2:]
    return (h[..., :-2, :] + h[..., 1:-1, :] + h[..., 2:, :]) * (1.0 / 9.0)


def ssim_dissimilarity(x: torch.Tensor, y: torch.Tensor) -> torch.Tensor:
    """Monodepth2 SSIM dissimilarity: clamp((1 - SSIM(x, y)) / 2, 0, 1).

    3x3 mean (``_box3``) over reflection-padded inputs, C1 = 0.01^2, C2 = 0.03^2.

    Args:
        x, y: (B, C, H, W) images in [0, 1], same shape.

    Returns:
        (B, C, H, W) per-pixel, per-channel dissimilarity in [0, 1]; 0 for x == y.
    """
    _check4(x, "x", doc="(B, C, H, W)")
    if not isinstance(y, torch.Tensor) or y.shape != x.shape:
        raise ValueError(f"y must have the shape of x {tuple(x.shape)}, got {tuple(getattr(y, 'shape', ()))}")
    C1, C2 = 0.01 ** 2, 0.03 ** 2
    x = F.pad(x, (1, 1, 1, 1), mode="reflect")
    y = F.pad(y, (1, 1, 1, 1), mode="reflect")
    mu_x = _box3(x)
    mu_y = _box3(y)
    sigma_x = _box3(x * x) - mu_x ** 2
    sigma_y = _box3(y * y) - mu_y ** 2
    sigma_xy = _box3(x * y) - mu_x * mu_y
    n = (2 * mu_x * mu_y + C1) * (2 * sigma_xy + C2)
    d = (mu_x ** 2 + mu_y ** 2 + C1) * (sigma_x + sigma_y + C2)
    return torch.clamp((1 - n / d) / 2, 0, 1)


def photometric_error(pred: torch.Tensor, target: torch.Tensor, alpha: float = 0.85) -> torch.Tensor:
    """Per-pixel photometric error: alpha * mean_c SSIM-dissim + (1 - alpha) * mean_c |pred - target|.

    Args:
        pred, target: (B, C, H, W) images in [0, 1].
        alpha: SSIM weight (Monodepth2: 0.85).

    Returns:
        (B, 1, H, W) error (>= 0; 0 where pred == target in the 3x3 neighbourhood).
    """
    _check4(pred, "pred", doc="(B, C, H, W)")
    if not isinstance(target, torch.Tensor) or target.shape != pred.shape:
        raise ValueError(
            f"target must have the shape of pred {tuple(pred.shape)}, got {tuple(getattr(target, 'shape', ()))}"
        )
    l1 = (pred - target).abs().mean(1, keepdim=True)
    if alpha == 0:
        return l1
    ssim = ssim_dissimilarity(pred, target).mean(1, keepdim=True)
    return alpha * ssim + (1 - alpha) * l1


def masked_mean(x: torch.Tensor, mask: torch.Tensor) -> torch.Tensor:
    """Mean of x over the pixels where mask > 0; masked pixels are excluded entirely.

    Pixels with mask <= 0 contribute neither to the sum nor to the count (and
    may hold NaN/inf without harm). An empty mask gives 0 that still carries a
    (zero) gradient, so ``loss.backward()`` works.

    Args:
        x: (B, C, H, W) values (C is usually 1).
        mask: (B, 1, H, W) or (B, C, H, W); a (B, 1, H, W) mask applies to all channels.

    Returns:
        scalar tensor.
    """
    _check4(x, "x", doc="(B, C, H, W)")
    _check4(mask, "mask", like=x, doc="(B, 1, H, W)")
    if mask.shape[1] not in (1, x.shape[1]):
        raise ValueError(f"mask must have 1 or {x.shape[1]} channels, got {mask.shape[1]}")
    m = (mask > 0).expand_as(x)
    total = torch.where(m, x, torch.zeros((), dtype=x.dtype, device=x.device)).sum()
    count = m.sum().clamp(min=1).to(x.dtype)
    return total / count


def reprojection_loss(
    target: torch.Tensor,
    warped_list: Sequence[torch.Tensor],
    valid_list: Sequence[torch.Tensor],
    sources_list: Optional[Sequence[torch.Tensor]],
    mask: torch.Tensor,
    automask: bool = True,
    alpha: float = 0.85,
    out_of_view: str = "border",
    ident: Optional[torch.Tensor] = None,
    reduce: str = "min",
):
    """Monodepth2 photometric loss: per-pixel minimum over sources, with auto-masking.

    ``out_of_view="identity"`` (the trainer's default, `LossConfig.out_of_view`) is
    `identity_floored_error` averaged over all scene pixels; the rest of this docstring
    describes ``"border"``.

    For each source s, e_s = photometric_error(warped_s, target). A source counts
    at a pixel where valid_s > 0 (in front of it, inside its image, off its ego
    body), so another source wins the minimum there. Where NO source is valid
    the pixel keeps the minimum of the border-padded errors e_s, as in
    Monodepth2. Auto-masking (Monodepth2): a pixel that some source sees is
    used only if its reprojection error is strictly below the identity error
    min_s photometric_error(source_s, target) (static scene, objects moving
    with the camera); a pixel no source sees is always used (`used_pixels`).
    The loss is the mean over the used pixels (ego body never counted).

    Args:
        target: (B, 3, H, W) target image.
        warped_list: S tensors (B, 3, H, W): sources warped into the target (border padding).
        valid_list: S tensors (B, 1, H, W) float 0/1 from ``warp_by_depth``.
        sources_list: S tensors (B, 3, H, W) unwarped sources (may be None if automask=False, or
            when ``ident`` is given).
        mask: (B, 1, H, W) scene mask (0 = ego body / not to be used).
        automask: apply auto-masking.
        alpha: SSIM weight.
        out_of_view: ``"identity"`` or ``"border"`` (above).
        ident: (B, 1, H, W) the identity error min_s photometric_error(source_s, target), when
            the caller has it already: it does not depend on depth, so the training step computes
            it once per batch (not once per stage and scale) and passes it here (with ``reduce="mean"``: the
            sources' mean identity error).
        reduce: ``min`` or ``mean`` over the sources (`identity_floored_error`; ``mean`` needs
            ``out_of_view="identity"``).

    Returns:
        loss: scalar, masked_mean(per_pixel, used).
        per_pixel: (B, 1, H, W) minimum reprojection error.
        used: (B, 1, H, W) float 0/1 (`used_pixels`).
    """
    _check4(target, "target", doc="(B, C, H, W)")
    B, C, H, W = target.shape
    if len(warped_list) == 0:
        raise ValueError("warped_list must hold at least one warped source")
    if len(valid_list) != len(warped_list):
        raise ValueError(f"valid_list has {len(valid_list)} entries, warped_list {len(warped_list)}")
    if out_of_view not in ("identity", "border"):
        raise ValueError(f"out_of_view must be 'identity' or 'border', got {out_of_view!r}")
    if reduce != "min" and out_of_view != "identity":
        raise ValueError(f"reduce={reduce!r} needs out_of_view='identity' (the mean over the sources that see a pixel)")
    if (automask or out_of_view == "identity") and ident is None:
        if sources_list is None or len(sources_list) != len(warped_list):
            n = None if sources_list is None else len(sources_list)
            raise ValueError(f"sources_list must hold {len(warped_list)} source images for auto-masking, got {n}")
    _check4(mask, "mask", channels=1, like=target, doc=f"({B}, 1, {H}, {W})")

    for s, (w, v) in enumerate(zip(warped_list, valid_list)):
        _check4(w, f"warped_list[{s}]", channels=C, like=target, doc=f"({B}, {C}, {H}, {W})")
        _check4(v, f"valid_list[{s}]", channels=1, like=target, doc=f"({B}, 1, {H}, {W})")
    errors = [photometric_error(w, target, alpha) for w in warped_list]
    if not (automask or out_of_view == "identity"):
        ident = None
    elif ident is not None:
        _check4(ident, "ident", channels=1, like=target, doc=f"({B}, 1, {H}, {W})")
    else:
        idents = []
        for s, src in enumerate(sources_list):
            _check4(src, f"sources_list[{s}]", channels=C, like=target, doc=f"({B}, {C}, {H}, {W})")
            idents.append(photometric_error(src, target, alpha))
        ident = torch.cat(idents, 1)
        ident = ident.min(1, keepdim=True).values if reduce == "min" else ident.mean(1, keepdim=True)
    if out_of_view == "identity":
        per_pixel, used = identity_floored_error(errors, valid_list, ident, automask, reduce)
        used = used * (mask > 0).to(used.dtype)
        return masked_mean(per_pixel, mask), per_pixel, used
    reproj, seen = min_reprojection(errors, valid_list)
    used = used_pixels(reproj, seen, ident, mask)
    return masked_mean(reproj, used), reproj, used


def min_reprojection(errors: Sequence[torch.Tensor], valid_list: Sequence[torch.Tensor]):
    """(reproj, seen): per-pixel minimum of S (B, 1, H, W) errors over the valid sources and
    whether any source is valid; where none is, the minimum over all of them (border-padded
    warps, as Monodepth2 samples them)."""
    e = torch.cat(list(errors), 1)
    v = torch.cat([x > 0 for x in valid_list], 1)
    seen = v.any(1, keepdim=True)
    best_valid = torch.where(v, e, torch.full_like(e, INVALID_ERROR)).min(1, keepdim=True).values
    return torch.where(seen, best_valid, e.min(1, keepdim=True).values), seen


def identity_floored_error(errors: Sequence[torch.Tensor], valid_list: Sequence[torch.Tensor], ident: torch.Tensor,
                           automask: bool = True, reduce: str = "min"):
    """Monodepth2's per-pixel loss with out-of-view pixels scored at their identity error.

    e = min over the sources that see the pixel of their reprojection error; a pixel
    that no source sees gets the identity error ``ident`` (the error of the unwarped
    source: what "no motion" explains), and with auto-masking every pixel gets
    min(e, ident), as Monodepth2 does by concatenating the identity errors into the
    minimum. The loss is then the mean over ALL scene pixels, so no depth can lower
    it by sending pixels out of view or by making them worse than the identity: both
    score ident, the largest value a pixel can contribute.

    Args:
        errors: S tensors (B, 1, H, W), reprojection error per source.
        valid_list: S tensors (B, 1, H, W) 0/1, the source sees the pixel.
        ident: (B, 1, H, W) min over sources of the identity error (no gradient needed).
        automask: take the minimum with ``ident`` at seen pixels too.
        reduce: ``min`` (Monodepth2's per-pixel minimum over the sources) or ``mean`` (its ``--avg_reprojection``
            ablation: the mean over the sources that see the pixel; the caller passes the sources' mean
            identity error as ``ident``, as Monodepth2 averages its identity errors then).

    Returns:
        per_pixel (B, 1, H, W) and used (B, 1, H, W) float 0/1: pixels where the
        reprojection (not the identity) gives the value, i.e. those that carry gradient.
    """
    if reduce not in ("min", "mean"):
        raise ValueError(f"reduce must be 'min' or 'mean', got {reduce!r}")
    e = torch.cat(list(errors), 1)
    v = torch.cat([x > 0 for x in valid_list], 1)
    seen = v.any(1, keepdim=True)
    if reduce == "min":
        best = torch.where(v, e, torch.full_like(e, INVALID_ERROR)).min(1, keepdim=True).values
    else:  # the mean over the sources that see the pixel (an unseen pixel takes ``ident`` below)
        vf = v.to(e.dtype)
        best = (e * vf).sum(1, keepdim=True) / vf.sum(1, keepdim=True).clamp(min=1.0)
    ident = ident.detach().to(best.dtype)
    if automask:
        use = seen & (best < ident)
    else:
        use = seen
    return torch.where(use, best, ident), use.to(best.dtype)


def used_pixels(reproj: torch.Tensor, seen: torch.Tensor, ident: Optional[torch.Tensor], mask: torch.Tensor):
    """Float 0/1 (B, 1, H, W): scene pixels that the loss averages over.

    Auto-masking drops pixels whose reprojection error does not beat the identity
    error - but only pixels that some source sees: a pixel warped out of every
    source's view is always counted with its border error. Otherwise a depth
    that sends every pixel out of view would score 0 (observed: CPU runs
    collapsed to a constant depth and their val loss read 0.0).
    """
    used = mask > 0
    if ident is not None:
        used = used & (~seen | (reproj.detach() < ident.detach()))
    return used.to(reproj.dtype)


# --------------------------------------------------------------------------- smoothness
def smoothness_loss(disp: torch.Tensor, img: torch.Tensor, mask: Optional[torch.Tensor] = None) -> torch.Tensor:
    """Edge-aware smoothness of mean-normalised disparity (Monodepth2).

    d = disp / mean(disp) (mean per image, over mask pixels if a mask is given);
    loss = mean |d_x| exp(-mean_c |I_x|) + mean |d_y| exp(-mean_c |I_y|), where
    with a mask only gradients between two mask pixels are averaged.

    Args:
        disp: (B, 1, H, W) disparity (e.g. 1 / depth), > 0.
        img: (B, C, H, W) image in [0, 1].
        mask: optional (B, 1, H, W) scene mask.

    Returns:
        scalar tensor (0 for a constant disparity).
    """
    _check4(disp, "disp", channels=1, doc="(B, 1, H, W)")
    _check4(img, "img", like=disp, doc=f"({disp.shape[0]}, C, {disp.shape[2]}, {disp.shape[3]})")
    if mask is None:
        mean_disp = disp.mean((2, 3), keepdim=True)
    else:
        _check4(mask, "mask", channels=1, like=disp, doc=f"{tuple(disp.shape)}")
        m = (mask > 0).to(disp.dtype)
        mean_disp = (disp * m).sum((2, 3), keepdim=True) / m.sum((2, 3), keepdim=True).clamp(min=1)
    d = disp / (mean_disp + 1e-7)
    gdx = (d[..., :, :-1] - d[..., :, 1:]).abs()
    gdy = (d[..., :-1, :] - d[..., 1:, :]).abs()
    gix = (img[..., :, :-1] - img[..., :, 1:]).abs().mean(1, keepdim=True)
    giy = (img[..., :-1, :] - img[..., 1:, :]).abs().mean(1, keepdim=True)
    sx = gdx * torch.exp(-gix)
    sy = gdy * torch.exp(-giy)
    if mask is None:
        return sx.mean() + sy.mean()
    mx = m[..., :, :-1] * m[..., :, 1:]
    my = m[..., :-1, :] * m[..., 1:, :]
    return masked_mean(sx, mx) + masked_mean(sy, my)


# --------------------------------------------------------------------------- consistency
def consistency_loss(
    depth_tgt: torch.Tensor, depth_splat: torch.Tensor, hit: torch.Tensor, mask: torch.Tensor
) -> torch.Tensor:
    """Depth consistency L_con (paper eq. L_con): L1 between own and splatted neighbour depth.

    mean of |depth_tgt - depth_splat| over pixels with hit > 0 and mask > 0
    (``masked_mean``; 0 if there are none). Both depths are z-depth in metres in
    the target camera; ``depth_splat, hit`` come from ``geometry.splat_depth``.

    Args:
        depth_tgt: (B, 1, H, W) target camera depth.
        depth_splat: (B, 1, H, W) neighbour depth splatted into the target camera.
        hit: (B, 1, H, W) float 0/1 from splat_depth.
        mask: (B, 1, H, W) scene mask of the target camera.

    Returns:
        scalar tensor (metres).
    """
    _check4(depth_tgt, "depth_tgt", channels=1, doc="(B, 1, H, W)")
    doc = f"{tuple(depth_tgt.shape)}"
    _check4(depth_splat, "depth_splat", channels=1, like=depth_tgt, doc=doc)
    _check4(hit, "hit", channels=1, like=depth_tgt, doc=doc)
    _check4(mask, "mask", channels=1, like=depth_tgt, doc=doc)
    m = ((hit > 0) & (mask > 0)).to(depth_tgt.dtype)
    return masked_mean((depth_tgt - depth_splat).abs(), m)
