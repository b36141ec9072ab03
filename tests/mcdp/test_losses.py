"""Tests for mcdp.losses: identities, hand-computed masked means, auto-masking, smoothness, L_con."""
import pytest
import torch

from mcdp import losses as L


def rand(*shape, seed=0, dtype=torch.float32):
    return torch.rand(*shape, generator=torch.Generator().manual_seed(seed), dtype=dtype)


def test_ssim_identity_is_zero_and_range():
    x = rand(2, 3, 8, 9)
    assert torch.allclose(L.ssim_dissimilarity(x, x), torch.zeros_like(x), atol=1e-6)
    d = L.ssim_dissimilarity(x, rand(2, 3, 8, 9, seed=1))
    assert d.shape == (2, 3, 8, 9)
    assert d.min() >= 0 and d.max() <= 1 and d.mean() > 0.1


def test_ssim_hand_value_constant_images():
    # constant images a, b: sigma = 0, SSIM = (2ab + C1) / (a^2 + b^2 + C1)
    a, b, C1 = 0.2, 0.6, 0.01 ** 2
    x = torch.full((1, 1, 4, 4), a, dtype=torch.float64)
    y = torch.full((1, 1, 4, 4), b, dtype=torch.float64)
    ssim = (2 * a * b + C1) / (a * a + b * b + C1)
    assert torch.allclose(L.ssim_dissimilarity(x, y), torch.full_like(x, (1 - ssim) / 2))


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_ssim_box_filter_equals_avg_pool_values_and_gradients(seed):
    # the separable 3x3 sum (_box3, the fast CPU path) is Monodepth2's avg_pool2d(3, 1), values and
    # gradients, including non-contiguous inputs (a channel slice) and a grid of odd size
    g = torch.Generator().manual_seed(seed)
    t = torch.rand(2, 4, 11, 14, generator=g, dtype=torch.float64)[:, 1:].requires_grad_(True)
    a = L._box3(t)
    b = torch.nn.functional.avg_pool2d(t, 3, 1)
    assert torch.allclose(a, b, atol=1e-12)
    w = torch.rand(a.shape, generator=g, dtype=torch.float64)
    ga, = torch.autograd.grad((a * w).sum(), t)
    gb, = torch.autograd.grad((b * w).sum(), t)
    assert torch.allclose(ga, gb, atol=1e-12)


def test_photometric_error_identity_and_hand_value():
    x = rand(1, 3, 6, 6)
    assert torch.allclose(L.photometric_error(x, x), torch.zeros(1, 1, 6, 6), atol=1e-6)
    a, b, C1 = 0.2, 0.6, 0.01 ** 2
    x = torch.full((1, 3, 4, 4), a, dtype=torch.float64)
    y = torch.full((1, 3, 4, 4), b, dtype=torch.float64)
    ssim_d = (1 - (2 * a * b + C1) / (a * a + b * b + C1)) / 2
    expected = 0.85 * ssim_d + 0.15 * 0.4
    assert torch.allclose(L.photometric_error(x, y), torch.full((1, 1, 4, 4), expected, dtype=torch.float64))


def test_masked_mean_excludes_masked_pixels():
    x = torch.tensor([[[[1.0, 2.0], [3.0, 100.0]]]], requires_grad=True)
    m = torch.tensor([[[[1.0, 1.0], [1.0, 0.0]]]])
    v = L.masked_mean(x, m)
    assert v.item() == pytest.approx(2.0)  # (1 + 2 + 3) / 3, not (1+2+3+0)/4
    v.backward()
    assert torch.allclose(x.grad, torch.tensor([[[[1 / 3, 1 / 3], [1 / 3, 0.0]]]]))


def test_masked_mean_ignores_nan_under_mask_and_empty_mask_is_zero_with_grad():
    x = torch.tensor([[[[1.0, float("nan")]]]], requires_grad=True)
    assert L.masked_mean(x, torch.tensor([[[[1.0, 0.0]]]])).item() == 1.0
    v = L.masked_mean(x, torch.zeros(1, 1, 1, 2))
    assert v.item() == 0.0 and v.requires_grad
    v.backward()
    assert torch.all(x.grad == 0)


def test_masked_mean_shape_error():
    with pytest.raises(ValueError, match="mask must have shape"):
        L.masked_mean(torch.ones(1, 1, 2, 2), torch.ones(1, 1, 3, 2))


def test_reprojection_min_over_sources_and_invalid_source_loses():
    tgt = rand(1, 3, 8, 8, seed=0)
    good = tgt.clone()
    bad = rand(1, 3, 8, 8, seed=1)
    ones = torch.ones(1, 1, 8, 8)
    mask = torch.ones(1, 1, 8, 8)
    # source 0 is perfect but invalid on the left half: there source 1 must win
    v0 = ones.clone()
    v0[..., :4] = 0
    loss, per_pixel, used = L.reprojection_loss(tgt, [good, bad], [v0, ones], None, mask, automask=False)
    e_bad = L.photometric_error(bad, tgt)
    assert torch.allclose(per_pixel[..., 4:], torch.zeros(1, 1, 8, 4), atol=1e-6)
    assert torch.allclose(per_pixel[..., :4], e_bad[..., :4])
    assert torch.all(used == 1)
    assert loss.item() == pytest.approx(e_bad[..., :4].sum().item() / 64, rel=1e-5)


def test_reprojection_no_valid_source_is_counted_with_its_border_error():
    """Monodepth2: a pixel that no source sees keeps its (border-padded) error and is counted."""
    tgt = rand(1, 3, 4, 4)
    w = rand(1, 3, 4, 4, seed=5)
    valid = torch.ones(1, 1, 4, 4)
    valid[0, 0, 0, 0] = 0
    loss, per_pixel, used = L.reprojection_loss(tgt, [w], [valid], None, torch.ones(1, 1, 4, 4), automask=False)
    e = L.photometric_error(w, tgt)
    assert used.sum() == 16
    assert torch.allclose(per_pixel, e)
    assert loss.item() == pytest.approx(e.mean().item(), rel=1e-6)


def test_sending_every_pixel_out_of_view_is_not_rewarded():
    """Regression: pixels no source saw were dropped, so a depth that warps everything out of
    view scored 0 and CPU training collapsed to a constant depth. They count now, automask or not."""
    tgt = rand(1, 3, 8, 8, seed=0)
    src = rand(1, 3, 8, 8, seed=1)
    ones = torch.ones(1, 1, 8, 8)
    nowhere = torch.zeros(1, 1, 8, 8)
    border = src[..., :1].expand_as(src).contiguous()  # what a warp far out of view samples
    loss_out, per_pixel, used = L.reprojection_loss(tgt, [border], [nowhere], [src], ones)
    assert torch.all(used == 1)
    assert loss_out.item() == pytest.approx(L.photometric_error(border, tgt).mean().item(), rel=1e-6)
    # a correct warp (target reproduced) scores far lower than the collapse
    loss_good, _, _ = L.reprojection_loss(tgt, [tgt.clone()], [ones], [src], ones)
    assert loss_good.item() < 0.01 * loss_out.item()


def test_automask_drops_static_pixels():
    # a static scene region: source == target there, so identity error (0) is not beaten by the warp
    tgt = rand(1, 3, 8, 8, seed=0)
    src = rand(1, 3, 8, 8, seed=1)
    src[..., :, :4] = tgt[..., :, :4]  # left half static (identical in source and target)
    warped = tgt.clone()  # the warp reproduces the target everywhere (error 0)
    warped[..., :, 4:] += 0.05 * rand(1, 3, 8, 4, seed=2)  # small residual on the moving half
    ones = torch.ones(1, 1, 8, 8)
    loss, per_pixel, used = L.reprojection_loss(tgt, [warped], [ones], [src], ones)
    # columns 0-2 are fully static (their 3x3 SSIM window stays in the static half): dropped
    assert torch.all(used[..., :3] == 0)
    # moving half: warp error (small) < identity error (large): used
    assert torch.all(used[..., 5:] == 1)
    assert loss.item() == pytest.approx(L.masked_mean(per_pixel, used).item())
    # without automask every pixel is used
    _, _, used_all = L.reprojection_loss(tgt, [warped], [ones], [src], ones, automask=False)
    assert torch.all(used_all == 1)


def test_reprojection_respects_scene_mask():
    tgt = rand(1, 3, 4, 4)
    w = rand(1, 3, 4, 4, seed=3)
    mask = torch.zeros(1, 1, 4, 4)
    mask[..., 0, :] = 1
    loss, per_pixel, used = L.reprojection_loss(tgt, [w], [torch.ones(1, 1, 4, 4)], None, mask, automask=False)
    assert used.sum() == 4
    assert loss.item() == pytest.approx(per_pixel[..., 0, :].mean().item(), rel=1e-6)


def test_reprojection_argument_errors():
    t = torch.ones(1, 3, 4, 4)
    v = torch.ones(1, 1, 4, 4)
    with pytest.raises(ValueError, match="sources_list"):
        L.reprojection_loss(t, [t], [v], None, v, automask=True)
    with pytest.raises(ValueError, match=r"valid_list\[0\]"):
        L.reprojection_loss(t, [t], [torch.ones(1, 1, 4, 3)], [t], v)


def test_smoothness_constant_disparity_is_zero_and_scale_invariant():
    img = rand(2, 3, 6, 7)
    assert L.smoothness_loss(torch.full((2, 1, 6, 7), 0.3), img).item() == pytest.approx(0.0, abs=1e-7)
    disp = 0.1 + rand(2, 1, 6, 7, seed=5)
    a = L.smoothness_loss(disp, img)
    b = L.smoothness_loss(3.0 * disp, img)
    assert a.item() > 0
    assert a.item() == pytest.approx(b.item(), rel=1e-4)  # mean-normalised


def test_smoothness_hand_value_and_mask():
    # disparity ramp 1,2 in x on a flat image; mean 1.5 -> normalised step 2/3, exp(0) = 1
    disp = torch.tensor([[[[1.0, 2.0], [1.0, 2.0]]]], dtype=torch.float64)
    img = torch.zeros(1, 3, 2, 2, dtype=torch.float64)
    assert L.smoothness_loss(disp, img).item() == pytest.approx(1 / 1.5, rel=1e-6)
    # a mask that leaves only the left column: no x-pair inside the mask, y-step 0 -> 0
    mask = torch.tensor([[[[1.0, 0.0], [1.0, 0.0]]]], dtype=torch.float64)
    assert L.smoothness_loss(disp, img, mask).item() == pytest.approx(0.0, abs=1e-12)


def test_consistency_loss_hand_value():
    d = torch.tensor([[[[1.0, 2.0], [3.0, 4.0]]]], requires_grad=True)
    s = torch.tensor([[[[1.5, 0.0], [1.0, 9.0]]]])
    hit = torch.tensor([[[[1.0, 0.0], [1.0, 1.0]]]])
    mask = torch.tensor([[[[1.0, 1.0], [1.0, 0.0]]]])
    loss = L.consistency_loss(d, s, hit, mask)
    assert loss.item() == pytest.approx((0.5 + 2.0) / 2)
    loss.backward()
    assert torch.allclose(d.grad, torch.tensor([[[[-0.5, 0.0], [0.5, 0.0]]]]))
    assert L.consistency_loss(d, s, torch.zeros_like(hit), mask).item() == 0.0


@pytest.mark.parametrize("out_of_view", ["identity", "border"])
def test_reprojection_with_a_given_identity_error_equals_the_computed_one(out_of_view):
    """The training step passes the identity error it computed once per batch (`ident=`)."""
    tgt, src, w = rand(2, 3, 8, 8, seed=0), rand(2, 3, 8, 8, seed=1), rand(2, 3, 8, 8, seed=2)
    valid = (rand(2, 1, 8, 8, seed=3) > 0.3).float()
    mask = torch.ones(2, 1, 8, 8)
    ref = L.reprojection_loss(tgt, [w], [valid], [src], mask, out_of_view=out_of_view)
    ident = L.photometric_error(src, tgt)
    got = L.reprojection_loss(tgt, [w], [valid], None, mask, out_of_view=out_of_view, ident=ident)
    for a, b in zip(ref, got):
        assert torch.equal(a, b)
    with pytest.raises(ValueError, match="ident must have shape"):
        L.reprojection_loss(tgt, [w], [valid], None, mask, ident=ident[:, :, :4])
