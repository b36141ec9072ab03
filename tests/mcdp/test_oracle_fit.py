"""The ORACLE weight fit (`mcdp.oracle.fit_oracle_weights`): on the valid pixels only, packed, with the loss's
gradient in closed form, it is the optimisation of its definition (`fit_oracle_weights_autograd`: every pixel,
autograd) summed in another order. Where the bases determine the weights, both give the same weights to rounding;
where they do not (two equal bases), both reach the same loss and the weights along the undetermined direction are
rounding carried by Adam in either (the autograd fit in float64 moves them as much). An image's weights are the same
bits alone or in any batch, and under 1 or 2 torch threads."""
from __future__ import annotations

import pytest
import torch

from mcdp.methods.base import combine_bases, disp_to_depth
from mcdp.oracle import _affine_disparity, fit_oracle_weights, fit_oracle_weights_autograd, si_log_error

MIN_D, MAX_D = 0.1, 100.0


def to_depth(sig):
    return disp_to_depth(sig, MIN_D, MAX_D)


def _problem(seed: int, B: int = 5, n: int = 4, h: int = 24, w: int = 32, equal_bases: bool = False):
    """Smooth random bases, a ground truth made of them at random weights (times a scale and noise), and valid
    pixels of very different counts per image (one image without any)."""
    g = torch.Generator().manual_seed(seed)
    yy, xx = torch.meshgrid(torch.linspace(0, 1, h), torch.linspace(0, 1, w), indexing="ij")
    freq = torch.rand(B, n, 2, generator=g) * 3
    phase = torch.rand(B, n, 1, 1, generator=g) * 6
    bases = 0.2 + 0.6 * torch.sigmoid(torch.sin(freq[..., 0, None, None] * 6 * xx + phase)
                                      + torch.cos(freq[..., 1, None, None] * 6 * yy))  # (B, n, h, w)
    if equal_bases:
        bases[:, 1] = bases[:, 0]
    true_w = torch.softmax(torch.randn(B, n, generator=g) * 2, 1)
    gt = to_depth(combine_bases(bases, true_w))[1] * (1.5 + torch.rand(B, 1, 1, 1, generator=g))
    gt = gt * torch.exp(0.02 * torch.randn(gt.shape, generator=g))
    frac = torch.tensor([0.9, 0.5, 0.1, 0.02, 0.0])[:B]
    valid = torch.rand(B, 1, h, w, generator=g) < frac[:, None, None, None]
    return bases, gt, valid


def _loss(bases, gt, valid, wts):
    return si_log_error(to_depth(combine_bases(bases.double(), wts.double()))[1], gt.double(), valid)


@pytest.mark.parametrize("seed", [0, 1])
def test_the_fit_is_its_definition_where_the_bases_determine_the_weights(one_thread, seed):
    bases, gt, valid = _problem(seed)
    fast, ref = fit_oracle_weights(bases, gt, valid, to_depth), fit_oracle_weights_autograd(bases, gt, valid, to_depth)
    assert fast.shape == ref.shape == (5, 4)
    assert torch.equal(fast[4], torch.full((4,), 0.25))  # no valid pixel: 1/n, as the definition
    torch.testing.assert_close(fast, ref, rtol=1e-4, atol=1e-6)
    torch.testing.assert_close(_loss(bases, gt, valid, fast), _loss(bases, gt, valid, ref), rtol=1e-6, atol=1e-12)
    assert (fast[:4] - 0.25).abs().max() > 0.05  # the fit moved the weights


def test_equal_bases_the_same_loss_the_undetermined_weights_are_rounding(one_thread):
    bases, gt, valid = _problem(2, equal_bases=True)
    fast, ref = fit_oracle_weights(bases, gt, valid, to_depth), fit_oracle_weights_autograd(bases, gt, valid, to_depth)
    torch.testing.assert_close(_loss(bases, gt, valid, fast), _loss(bases, gt, valid, ref), rtol=1e-5, atol=1e-10)
    # what the data determines (the two equal bases' sum, the other weights) agrees
    merged = lambda w: torch.cat([w[:, :1] + w[:, 1:2], w[:, 2:]], 1)  # noqa: E731
    torch.testing.assert_close(merged(fast), merged(ref), rtol=1e-3, atol=1e-5)


def test_an_image_is_the_same_bits_alone_in_any_batch_and_on_1_or_2_threads(one_thread):
    bases, gt, valid = _problem(3)
    together = fit_oracle_weights(bases, gt, valid, to_depth)
    for b in range(5):
        assert torch.equal(fit_oracle_weights(bases[b:b + 1], gt[b:b + 1], valid[b:b + 1], to_depth), together[b:b + 1])
    doubled = fit_oracle_weights(torch.cat([bases, bases.flip(0)]), torch.cat([gt, gt.flip(0)]),
                                 torch.cat([valid, valid.flip(0)]), to_depth)
    assert torch.equal(doubled[:5], together) and torch.equal(doubled[5:], together.flip(0))
    torch.set_num_threads(2)  # one_thread restores the count
    assert torch.equal(fit_oracle_weights(bases, gt, valid, to_depth), together)


def test_another_map_or_another_size_takes_the_definition(one_thread):
    bases, gt, valid = _problem(4, B=3)

    def squared(sig):  # not an affine disparity
        disp = 0.01 + sig * sig
        return disp, 1.0 / disp

    assert _affine_disparity(to_depth) == pytest.approx((1 / MAX_D, 1 / MIN_D - 1 / MAX_D), rel=1e-12)
    assert _affine_disparity(squared) is None
    assert torch.equal(fit_oracle_weights(bases, gt, valid, squared, steps=10),
                       fit_oracle_weights_autograd(bases, gt, valid, squared, steps=10))
    big_gt = torch.nn.functional.interpolate(gt, scale_factor=2, mode="nearest")
    big_valid = torch.nn.functional.interpolate(valid.float(), scale_factor=2, mode="nearest") > 0.5
    assert torch.equal(fit_oracle_weights(bases, big_gt, big_valid, to_depth, steps=10),
                       fit_oracle_weights_autograd(bases, big_gt, big_valid, to_depth, steps=10))
