"""Tests for mcdp.geometry: hand-computed projections, round trips, warps, z-buffered splats, gradchecks."""
import math

import pytest
import torch

from mcdp import geometry as G


def make_K(fx=20.0, fy=20.0, cx=16.0, cy=12.0, dtype=torch.float32, batch=1):
    K = torch.tensor([[fx, 0.0, cx], [0.0, fy, cy], [0.0, 0.0, 1.0]], dtype=dtype)
    return K.expand(batch, 3, 3).clone()


def make_T(R=None, t=(0.0, 0.0, 0.0), dtype=torch.float32):
    T = torch.eye(4, dtype=dtype)
    if R is not None:
        T[:3, :3] = torch.as_tensor(R, dtype=dtype)
    T[:3, 3] = torch.tensor(t, dtype=dtype)
    return T[None]


def rot_y(a):
    c, s = math.cos(a), math.sin(a)
    return [[c, 0.0, s], [0.0, 1.0, 0.0], [-s, 0.0, c]]


# --------------------------------------------------------------------------- basics
def test_pixel_grid_centres():
    g = G.pixel_grid(2, 3)
    assert g.shape == (1, 3, 2, 3)
    assert torch.equal(g[0, 0], torch.tensor([[0.5, 1.5, 2.5], [0.5, 1.5, 2.5]]))
    assert torch.equal(g[0, 1], torch.tensor([[0.5, 0.5, 0.5], [1.5, 1.5, 1.5]]))
    assert torch.equal(g[0, 2], torch.ones(2, 3))


def test_scale_intrinsics_values():
    K = make_K()
    Ks = G.scale_intrinsics(K, 0.5, 0.25)
    expected = torch.tensor([[[10.0, 0.0, 8.0], [0.0, 5.0, 3.0], [0.0, 0.0, 1.0]]])
    assert torch.allclose(Ks, expected)


def test_scale_intrinsics_consistent_with_downsampled_grid():
    # a 3D point seen through K at 24x32 lands on (u, v); at 12x16 (K scaled by 1/2) on (u/2, v/2),
    # and the centre of the 2x2 block of full-res pixels is the centre of the low-res pixel.
    K = make_K(dtype=torch.float64)
    K2 = G.scale_intrinsics(K, 0.5, 0.5)
    d = torch.full((1, 1, 24, 32), 7.0, dtype=torch.float64)
    pts = G.depth_to_points(d, K)  # points through full-res pixel centres
    uv2, _ = G.points_to_pixels(pts, K2)
    assert torch.allclose(uv2, G.pixel_grid(24, 32, dtype=torch.float64)[:, :2] / 2)
    # low-res pixel (c, r) centre (c+0.5, r+0.5) == mean of the full-res centres 2c+0.5, 2c+1.5 halved
    low = G.pixel_grid(12, 16, dtype=torch.float64)[:, :2]
    block_mean = torch.nn.functional.avg_pool2d(uv2, 2)
    assert torch.allclose(block_mean, low)


def test_point_lands_on_hand_computed_pixel():
    K = make_K()  # fx=fy=20, cx=16, cy=12
    pts = torch.tensor([1.0, -0.5, 4.0]).view(1, 3, 1, 1)
    uv, z = G.points_to_pixels(pts, K)
    # u = 20 * 1/4 + 16 = 21, v = 20 * -0.5/4 + 12 = 9.5
    assert torch.allclose(uv.flatten(), torch.tensor([21.0, 9.5]))
    assert z.item() == 4.0


def test_depth_to_points_hand_value():
    K = make_K()
    d = torch.zeros(1, 1, 24, 32)
    d[0, 0, 2, 5] = 10.0
    p = G.depth_to_points(d, K)
    # pixel (c=5, r=2): centre (5.5, 2.5) -> x = (5.5-16)/20*10 = -5.25, y = (2.5-12)/20*10 = -4.75
    assert torch.allclose(p[0, :, 2, 5], torch.tensor([-5.25, -4.75, 10.0]))


def test_unproject_project_round_trip():
    gen = torch.Generator().manual_seed(0)
    B, H, W = 2, 6, 8
    K = make_K(fx=9.0, fy=8.0, cx=4.2, cy=2.9, batch=B, dtype=torch.float64)
    d = 1.0 + 10.0 * torch.rand(B, 1, H, W, generator=gen, dtype=torch.float64)
    uv, z = G.points_to_pixels(G.depth_to_points(d, K), K)
    assert torch.allclose(uv, G.pixel_grid(H, W, dtype=torch.float64)[:, :2].expand(B, -1, -1, -1))
    assert torch.allclose(z, d)


def test_transform_points_hand_value():
    T = make_T(R=[[0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]], t=(1.0, 2.0, 3.0))
    p = torch.tensor([1.0, 0.0, 0.0]).view(1, 3, 1, 1)
    assert torch.allclose(G.transform_points(T, p).flatten(), torch.tensor([1.0, 3.0, 3.0]))


def test_pixels_to_grid_edges():
    uv = torch.tensor([[0.0, 0.0], [32.0, 24.0], [16.0, 12.0]]).T.reshape(1, 2, 1, 3)
    grid = G.pixels_to_grid(uv, 24, 32)
    assert torch.allclose(grid[0, 0], torch.tensor([[-1.0, -1.0], [1.0, 1.0], [0.0, 0.0]]))


def test_shape_errors_name_the_argument():
    with pytest.raises(ValueError, match=r"depth must have shape \(B, 1, H, W\)"):
        G.depth_to_points(torch.ones(1, 2, 3, 3), make_K())
    with pytest.raises(ValueError, match=r"K must have shape \(B, 3, 3\)"):
        G.depth_to_points(torch.ones(1, 1, 3, 3), torch.eye(3))
    with pytest.raises(ValueError, match="T_src_tgt"):
        G.warp_by_depth(torch.ones(1, 3, 4, 4), torch.ones(1, 1, 4, 4), make_K(), make_K(), torch.eye(4))
    with pytest.raises(ValueError, match="valid_src"):
        G.splat_depth(torch.ones(1, 1, 4, 4), make_K(), make_K(), make_T(), 4, 4, valid_src=torch.ones(1, 1, 3, 4))
    with pytest.raises(ValueError, match="K has batch size 2, expected 1 or 3"):
        G.depth_to_points(torch.ones(3, 1, 4, 4), make_K(batch=2))


# --------------------------------------------------------------------------- warp
def test_warp_identity_returns_source():
    gen = torch.Generator().manual_seed(1)
    src = torch.rand(2, 3, 12, 16, generator=gen)
    depth = 1.0 + 5.0 * torch.rand(2, 1, 12, 16, generator=gen)
    K = make_K(fx=10.0, fy=10.0, cx=8.0, cy=6.0, batch=2)
    warped, valid = G.warp_by_depth(src, depth, K, K, make_T().expand(2, 4, 4))
    assert torch.allclose(warped, src, atol=1e-5)
    assert torch.all(valid == 1)


def test_warp_known_translation_shifts_by_hand_computed_pixels():
    # fronto-parallel plane at Z = 10, source camera 1 m to the right of the target (x_src = x_tgt - 1):
    # u_src = u_tgt - fx * 1 / 10 = u_tgt - 2 pixels.
    gen = torch.Generator().manual_seed(2)
    H, W = 12, 16
    src = torch.rand(1, 3, H, W, generator=gen, dtype=torch.float64)
    depth = torch.full((1, 1, H, W), 10.0, dtype=torch.float64)
    K = make_K(fx=20.0, fy=20.0, cx=8.0, cy=6.0, dtype=torch.float64)
    T_src_tgt = make_T(t=(-1.0, 0.0, 0.0), dtype=torch.float64)
    warped, valid = G.warp_by_depth(src, depth, K, K, T_src_tgt)
    assert torch.allclose(warped[..., 2:], src[..., :-2], atol=1e-12)
    # u_src of column c is c - 1.5: inside the image for c >= 2 only
    assert torch.all(valid[..., 2:] == 1) and torch.all(valid[..., :2] == 0)


def test_warp_to_different_resolution():
    # identity pose, source at 2x resolution with K scaled by 2; a source image linear in u_src is
    # reproduced exactly by bilinear sampling: value(target col c) = alpha * 2 * (c + 0.5)
    H, W, alpha = 6, 8, 0.05
    K_t = make_K(fx=8.0, fy=8.0, cx=4.0, cy=3.0, dtype=torch.float64)
    K_s = G.scale_intrinsics(K_t, 2.0, 2.0)
    u_src = torch.arange(2 * W, dtype=torch.float64) + 0.5
    src = (alpha * u_src).expand(1, 1, 2 * H, 2 * W).clone()
    depth = torch.full((1, 1, H, W), 3.0, dtype=torch.float64)
    warped, valid = G.warp_by_depth(src, depth, K_t, K_s, make_T(dtype=torch.float64))
    expected = (alpha * 2 * (torch.arange(W, dtype=torch.float64) + 0.5)).expand(1, 1, H, W)
    assert warped.shape == (1, 1, H, W)
    assert torch.allclose(warped, expected, atol=1e-12)
    assert torch.all(valid == 1)


def test_warp_behind_camera_is_invalid():
    src = torch.ones(1, 1, 4, 4)
    depth = torch.full((1, 1, 4, 4), 2.0)
    K = make_K(fx=4.0, fy=4.0, cx=2.0, cy=2.0)
    # source camera 5 m in front of the target looking the same way: the plane at 2 m is behind it
    warped, valid = G.warp_by_depth(src, depth, K, K, make_T(t=(0.0, 0.0, -5.0)))
    assert torch.all(valid == 0)


def test_gradcheck_warp_by_depth():
    gen = torch.Generator().manual_seed(3)
    H, W = 5, 6
    src = torch.rand(1, 2, H, W, generator=gen, dtype=torch.float64)
    depth = (4.0 + torch.rand(1, 1, H, W, generator=gen, dtype=torch.float64)).requires_grad_(True)
    K = make_K(fx=6.0, fy=6.0, cx=3.0, cy=2.5, dtype=torch.float64)
    T = make_T(R=rot_y(0.05), t=(0.37, -0.11, 0.2), dtype=torch.float64)
    assert torch.autograd.gradcheck(lambda d: G.warp_by_depth(src, d, K, K, T, padding_mode="border")[0], (depth,))


# --------------------------------------------------------------------------- splat
def test_splat_identity_returns_depth():
    gen = torch.Generator().manual_seed(4)
    d = 1.0 + 20.0 * torch.rand(2, 1, 12, 16, generator=gen)
    K = make_K(fx=10.0, fy=10.0, cx=8.0, cy=6.0, batch=2)
    out, hit = G.splat_depth(d, K, K, make_T().expand(2, 4, 4), 12, 16)
    assert torch.allclose(out, d)
    assert torch.all(hit == 1)


def test_splat_keeps_nearest_point():
    # pixels (c=1, r=1) and (c=2, r=1) both land on target pixel (1, 1) by construction via a
    # target K with half the focal length and resolution; the nearer one (3 m) must win over 7 m.
    K_s = make_K(fx=4.0, fy=4.0, cx=2.0, cy=2.0)  # 4x4 source
    K_t = G.scale_intrinsics(K_s, 0.5, 0.5)  # 2x2 target: source pixels (2c', 2c'+1) -> target c'
    d = torch.full((1, 1, 4, 4), 10.0)
    d[0, 0, 2, 2] = 3.0  # block of target pixel (1, 1): source rows 2-3, cols 2-3
    d[0, 0, 2, 3] = 7.0
    d[0, 0, 0, 0] = 9.0
    out, hit = G.splat_depth(d, K_s, K_t, make_T(), 2, 2)
    assert torch.all(hit == 1)
    assert out[0, 0, 1, 1].item() == pytest.approx(3.0)
    assert out[0, 0, 0, 0].item() == pytest.approx(9.0)
    assert out[0, 0, 0, 1].item() == pytest.approx(10.0)


def test_splat_z_buffer_under_translation_and_empty_pixels():
    # source at 2 pixels; target camera moved back 1 m: z_tgt = z_src + 1.
    K = make_K(fx=2.0, fy=2.0, cx=1.0, cy=0.5)
    d = torch.tensor([[[[2.0, 0.0]]]])  # second pixel has no surface: must not splat
    out, hit = G.splat_depth(d, K, K, make_T(t=(0.0, 0.0, 1.0)), 1, 2)
    # pixel (0,0): x = (0.5-1)/2*2 = -0.5, z=3 -> u = 2*(-0.5)/3 + 1 = 0.667 -> col 0
    assert hit.flatten().tolist() == [1.0, 0.0]
    assert out.flatten().tolist() == pytest.approx([3.0, 0.0])


def test_splat_valid_src_excludes_points():
    d = torch.full((1, 1, 3, 3), 5.0)
    K = make_K(fx=3.0, fy=3.0, cx=1.5, cy=1.5)
    valid = torch.ones(1, 1, 3, 3)
    valid[0, 0, 1, 1] = 0
    out, hit = G.splat_depth(d, K, K, make_T(), 3, 3, valid_src=valid)
    assert hit[0, 0, 1, 1] == 0 and out[0, 0, 1, 1] == 0
    assert hit.sum() == 8


def test_splat_grad_flows_to_winner_only():
    K_s = make_K(fx=4.0, fy=4.0, cx=2.0, cy=2.0, dtype=torch.float64)
    K_t = G.scale_intrinsics(K_s, 0.5, 0.5)
    d = torch.full((1, 1, 4, 4), 10.0, dtype=torch.float64)
    d[0, 0, 2, 2] = 3.0
    d.requires_grad_(True)
    out, _ = G.splat_depth(d, K_s, K_t, make_T(dtype=torch.float64), 2, 2)
    out[0, 0, 1, 1].backward()
    g = d.grad[0, 0]
    assert g[2, 2].item() == pytest.approx(1.0)
    assert g.abs().sum().item() == pytest.approx(1.0)


def test_gradcheck_splat_depth():
    gen = torch.Generator().manual_seed(5)
    Hs, Ws, Ht, Wt = 6, 7, 5, 6
    depth = (4.0 + 2.0 * torch.rand(1, 1, Hs, Ws, generator=gen, dtype=torch.float64))
    K_s = make_K(fx=6.0, fy=6.0, cx=3.5, cy=3.0, dtype=torch.float64)
    K_t = make_K(fx=5.0, fy=5.0, cx=3.0, cy=2.5, dtype=torch.float64)
    T = make_T(R=rot_y(0.1), t=(0.3, 0.05, -0.2), dtype=torch.float64)
    # the test is only meaningful away from pixel borders (piecewise-constant assignment)
    uv, _ = G.points_to_pixels(G.transform_points(T, G.depth_to_points(depth, K_s)), K_t)
    frac = uv - uv.floor()
    assert torch.minimum(frac, 1 - frac).min() > 1e-4
    out, hit = G.splat_depth(depth, K_s, K_t, T, Ht, Wt)
    assert hit.sum() >= 10  # enough pixels are hit for the check to mean something
    depth.requires_grad_(True)
    assert torch.autograd.gradcheck(lambda d: G.splat_depth(d, K_s, K_t, T, Ht, Wt)[0], (depth,))


def test_splat_matches_warp_on_plane():
    # splat(source depth -> target) and backward warp agree on a plane seen by both cameras
    H, W = 24, 32
    K = make_K(dtype=torch.float64)
    T_t_s = make_T(R=rot_y(0.2), t=(0.5, 0.0, 0.1), dtype=torch.float64)
    # plane z_s = 10 in the source frame
    d_s = torch.full((1, 1, H, W), 10.0, dtype=torch.float64)
    out, hit = G.splat_depth(d_s, K, K, T_t_s, H, W)
    # each hit target pixel: its own ray meets the source plane at roughly the splatted z (< 1 px off)
    assert hit.sum() > 100
    # exact check for the winners: transform the winner's z back -> lies on the plane within tolerance
    pts_t = G.depth_to_points(out, K)
    pts_s = G.transform_points(torch.linalg.inv(T_t_s), pts_t)
    z_s = pts_s[:, 2:3][hit > 0]
    # the splatted depth is that of a point up to one pixel away: plane depth varies < 5% per pixel
    assert torch.allclose(z_s, torch.full_like(z_s, 10.0), rtol=0.05)


def test_splat_matches_brute_force_z_buffer():
    gen = torch.Generator().manual_seed(6)
    B, Hs, Ws, Ht, Wt = 2, 9, 11, 5, 6  # many-to-one: collisions on most target pixels
    depth = 2.0 + 8.0 * torch.rand(B, 1, Hs, Ws, generator=gen, dtype=torch.float64)
    depth[0, 0, 0, :4] = 0.0  # no surface
    valid = (torch.rand(B, 1, Hs, Ws, generator=gen) > 0.2).double()
    K_s = make_K(fx=8.0, fy=8.0, cx=5.5, cy=4.5, dtype=torch.float64)
    K_t = make_K(fx=4.0, fy=4.0, cx=3.0, cy=2.5, dtype=torch.float64)
    T = torch.cat([make_T(R=rot_y(0.3), t=(0.4, 0.1, -0.3), dtype=torch.float64),
                   make_T(R=rot_y(-0.2), t=(-0.2, 0.0, 0.5), dtype=torch.float64)])
    out, hit = G.splat_depth(depth, K_s, K_t, T, Ht, Wt, valid_src=valid)

    ref = torch.zeros(B, 1, Ht, Wt, dtype=torch.float64)
    ref_hit = torch.zeros_like(ref)
    pts = G.transform_points(T, G.depth_to_points(depth, K_s))
    uv, z = G.points_to_pixels(pts, K_t)
    for b in range(B):
        for r in range(Hs):
            for c in range(Ws):
                u, v, zz = uv[b, 0, r, c].item(), uv[b, 1, r, c].item(), z[b, 0, r, c].item()
                if depth[b, 0, r, c] <= 0 or valid[b, 0, r, c] <= 0 or zz <= 1e-6:
                    continue
                if not (0 <= u < Wt and 0 <= v < Ht):
                    continue
                cc, rr = int(math.floor(u)), int(math.floor(v))
                if ref_hit[b, 0, rr, cc] == 0 or zz < ref[b, 0, rr, cc]:
                    ref[b, 0, rr, cc] = zz
                    ref_hit[b, 0, rr, cc] = 1
    assert ref_hit.sum() >= 20
    assert torch.equal(hit, ref_hit)
    assert torch.allclose(out, ref, atol=1e-12)
