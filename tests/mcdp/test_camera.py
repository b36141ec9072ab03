"""The torch twins of the camera-model table (`mcdp.camera`): the same rows as `synth.camera`, agreeing with
them, float64 gradcheck through project and unproject (the Newton inverses included), and the pinhole twin's
bytes as `mcdp.geometry` computed them before the table."""
from __future__ import annotations

import numpy as np
import pytest
import torch

from mcdp import camera as TC
from synth import camera as C

K = np.array([[310.5, 0.0, 161.2], [0.0, 305.25, 95.7], [0.0, 0.0, 1.0]])
DIST = {"pinhole": (), "radtan": (-0.28, 0.09, 0.001, -0.0015, -0.012),
        "kannala_brandt": (0.05, -0.01, 0.002, -0.0003)}


def _t(x):
    return torch.tensor(np.asarray(x), dtype=torch.float64)


def _cam(name):
    return C.Intrinsics(name, K, DIST[name]), _t(K)[None], _t(DIST[name]).view(1, -1)


def test_the_twins_are_keyed_by_the_tables_rows():
    assert list(TC.TORCH_MODELS) == list(C.MODELS)
    with pytest.raises(ValueError, match="unknown camera model 'fisheye'"):
        TC.project(torch.zeros(1, 3, 2), torch.eye(3)[None], None, "fisheye")
    with pytest.raises(ValueError, match=r"camera model 'radtan': dist must have shape \(B, 5\), got \(1, 4\)"):
        TC.project(torch.zeros(1, 3, 2), torch.eye(3)[None], torch.zeros(1, 4), "radtan")


@pytest.mark.parametrize("name", list(C.MODELS))
def test_numpy_and_torch_rows_agree(name):
    cam, Kt, dt = _cam(name)
    rng = np.random.default_rng(5)
    P = np.stack([rng.uniform(-2, 2, 80), rng.uniform(-1.5, 1.5, 80), rng.uniform(-1, 10, 80)])
    P[:, 0] = [0.0, 0.0, -1.0]  # straight behind: no row sees it
    uv, ok = C.project(cam, P)
    uv_t, ok_t = TC.project(_t(P)[None], Kt, dt, name)
    assert np.array_equal(ok, ok_t[0].numpy()) and (~ok).any() and ok.sum() > 40
    assert np.abs(uv[:, ok] - uv_t[0].numpy()[:, ok]).max() < 1e-9
    H, W = 24, 40
    r = C.rays(cam, H, W)
    pts = TC.unproject(torch.full((1, 1, H, W), 2.0, dtype=torch.float64), Kt, dt, name)
    assert np.abs(pts[0].reshape(3, -1).numpy() - 2.0 * r).max() < 1e-12


@pytest.mark.parametrize("name", list(C.MODELS))
def test_gradcheck_project_and_unproject(name):
    _, Kt, dt = _cam(name)
    P = _t([[0.3, -0.5, 0.1], [0.2, 0.4, -0.3], [2.0, 3.0, 4.0]])[None].requires_grad_(True)
    Kg = Kt.clone().requires_grad_(True)
    dg = dt.clone().requires_grad_(name != "pinhole")
    assert torch.autograd.gradcheck(lambda p, k, d: TC.project(p, k, d, name)[0], (P, Kg, dg))
    uv = _t([[[20.5, 160.0, 300.25], [10.5, 95.0, 180.75]]]).requires_grad_(True)
    assert torch.autograd.gradcheck(lambda u, k, d: TC.unproject_pixels(u, k, d, name), (uv, Kg, dg))


def test_the_pinhole_twin_keeps_mcdp_geometrys_bytes():
    from mcdp.geometry import depth_to_points, pixel_grid, points_to_pixels

    g = torch.Generator().manual_seed(0)
    depth = torch.rand(2, 1, 6, 10, generator=g) * 20
    Kb = torch.tensor([[[9.5, 0.0, 5.1], [0.0, 9.25, 3.2], [0.0, 0.0, 1.0]]]).repeat(2, 1, 1)
    Kb[1, 0, 0] = 11.0
    old = (torch.linalg.inv(Kb) @ pixel_grid(6, 10).view(1, 3, 60)).view(-1, 3, 6, 10) * depth
    pts = depth_to_points(depth, Kb)
    assert torch.equal(pts, old)
    Kp = Kb @ pts.reshape(2, 3, 60)
    uv, z = points_to_pixels(pts, Kb)
    assert torch.equal(uv, (Kp[:, :2] / Kp[:, 2:3].clamp(min=1e-6)).view(2, 2, 6, 10)) and torch.equal(z, pts[:, 2:3])


def test_a_range_row_unprojects_range_not_z_depth():
    _, Kt, dt = _cam("kannala_brandt")
    pts = TC.unproject(torch.full((1, 1, 4, 5), 3.0, dtype=torch.float64), Kt, dt, "kannala_brandt")
    assert torch.allclose(pts.norm(dim=1), torch.full((1, 4, 5), 3.0, dtype=torch.float64), rtol=0, atol=1e-12)


# --------------------------------------------------------------------------- the generator-trainer convention
BOX = np.array([[-6.0, -6.0, 0.0], [8.0, 6.0, 4.0]])  # a closed room, ego frame: every ray hits a wall


def _T_ego_cam(yaw_deg, mount):
    c, s = np.cos(np.radians(yaw_deg)), np.sin(np.radians(yaw_deg))
    T = np.eye(4)
    T[:3, :3] = np.column_stack([[s, -c, 0.0], [0.0, 0.0, -1.0], [c, s, 0.0]])  # x right, y down, z forward
    T[:3, 3] = mount
    return T


def _render(cam, H, W, T):
    """Depth (the row's kind) and a smooth texture of the room seen along the table's rays (a ray cast)."""
    r = C.rays(cam, H, W)                       # (3, H*W) camera frame
    d = T[:3, :3] @ r                           # ego frame
    o = T[:3, 3][:, None]
    with np.errstate(divide="ignore", invalid="ignore"):
        t = np.where(d > 0, (BOX[1][:, None] - o) / d, np.where(d < 0, (BOX[0][:, None] - o) / d, np.inf))
    depth = t.min(0)                            # the ray parameter: z-depth (z = 1 rays) or range (unit rays)
    p = o + depth * d
    tex = 0.5 + 0.2 * np.sin(0.7 * p[0] + 0.5 * p[2]) + 0.2 * np.cos(0.6 * p[1] - 0.7 * p[2])
    return depth.reshape(H, W), tex.reshape(H, W)


@pytest.mark.parametrize("name", list(C.MODELS))
def test_a_true_image_warped_with_true_depth_matches_its_neighbour(name):
    """Generator (numpy rays) and trainer (torch twins, `warp_by_depth`) agree for every row: camera j's image
    warped into camera i with i's true depth matches i's image on the overlap; a wrong depth, or (for a
    distorted row) warping as if the camera were pinhole, does not."""
    from mcdp.geometry import warp_by_depth

    fish = name == "kannala_brandt"
    H, W = (64, 64) if fish else (48, 64)
    f = (W / 2) / np.radians(100.0) if fish else 32.0
    K_ = np.array([[f, 0.0, W / 2], [0.0, f, H / 2], [0.0, 0.0, 1.0]])
    dist = {"pinhole": (), "radtan": (-0.25, 0.06, 0.001, -0.001, 0.0), "kannala_brandt": (0.01, -0.002, 0.0, 0.0)}
    cam = C.Intrinsics(name, K_, dist[name])
    Ti, Tj = _T_ego_cam(0.0, [1.5, 0.0, 1.6]), _T_ego_cam(-60.0, [1.2, -0.7, 1.6])
    di, ii = _render(cam, H, W, Ti)
    _, ij = _render(cam, H, W, Tj)
    Kt, lens = _t(K_)[None], (name, _t(dist[name]).view(1, -1))
    T_j_i = _t(np.linalg.inv(Tj) @ Ti)[None]

    def err(depth, lens_):
        w, ok = warp_by_depth(_t(ij)[None, None], _t(depth)[None, None], Kt, Kt, T_j_i, lens_tgt=lens_, lens_src=lens_)
        ok = ok[0, 0].bool()
        return float((w[0, 0] - _t(ii)).abs()[ok].mean()), int(ok.sum())

    e, n = err(di, lens)
    assert n > 0.15 * H * W and e < 0.01
    assert err(di * 1.3, lens)[0] > 2 * e
    if name != "pinhole":
        assert err(di, None)[0] > 2 * e   # the distorted images warped as if pinhole
