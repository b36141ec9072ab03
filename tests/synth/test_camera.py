"""The camera-model table (`synth.camera`): each row against OpenCV on fixed points (to 1e-6 px), round trips
(unproject then project returns the pixel grid), the pinhole row's bytes against today's expressions, resizes,
validity and the JSON round trip."""
from __future__ import annotations

import json

import cv2
import numpy as np
import pytest

from synth import camera as C
from synth.camera import Intrinsics

K = np.array([[310.5, 0.0, 161.2], [0.0, 305.25, 95.7], [0.0, 0.0, 1.0]])
RADTAN = (-0.28, 0.09, 0.001, -0.0015, -0.012)
KB = (0.05, -0.01, 0.002, -0.0003)
#: a 200 degree fisheye: theta = 100 deg at the image's half-width of 400 px
KB_FISH = (0.02, -0.004, 0.0005, -0.0001)
_T = np.radians(100.0)
_F = 400 / (_T * (1 + 0.02 * _T**2 - 0.004 * _T**4 + 0.0005 * _T**6 - 0.0001 * _T**8))
K_FISH = np.array([[_F, 0.0, 400.0], [0.0, _F, 300.0], [0.0, 0.0, 1.0]])
CAMS = {"pinhole": Intrinsics("pinhole", K), "radtan": Intrinsics("radtan", K, RADTAN),
        "kannala_brandt": Intrinsics("kannala_brandt", K_FISH, KB_FISH)}
SIZES = {"pinhole": (192, 320), "radtan": (192, 320), "kannala_brandt": (600, 800)}


def _points(n=60, seed=3):
    rng = np.random.default_rng(seed)
    return np.stack([rng.uniform(-2, 2, n), rng.uniform(-1.5, 1.5, n), rng.uniform(1, 10, n)])


def test_the_table_has_its_rows_in_order_with_their_depth_kinds():
    assert list(C.MODELS) == ["pinhole", "radtan", "kannala_brandt"]
    assert {n: r.depth_kind for n, r in C.MODELS.items()} == {"pinhole": "z_depth", "radtan": "z_depth",
                                                            "kannala_brandt": "range"}
    assert C.MODELS["radtan"].dist_names == ("k1", "k2", "p1", "p2", "k3")
    with pytest.raises(ValueError, match="unknown camera model 'fisheye'; the table has pinhole, radtan, kannala"):
        Intrinsics("fisheye", K)
    with pytest.raises(ValueError, match="registered twice"):
        C.register(C.MODELS["pinhole"])


@pytest.mark.parametrize("dist", [RADTAN, (0.1, -0.05, 0.0, 0.0, 0.0), (-0.05, 0.01, -0.002, 0.003, 0.001)])
def test_radtan_projects_as_cv2_projectPoints(dist):
    P = _points()
    uv, ok = C.project(Intrinsics("radtan", K, dist), P)
    ref, _ = cv2.projectPoints(P.T.copy(), np.zeros(3), np.zeros(3), K, np.array(dist))
    assert ok.all()
    assert np.abs(uv.T - ref[:, 0]).max() < 1e-6


@pytest.mark.parametrize("dist", [KB, KB_FISH, (0.0, 0.0, 0.0, 0.0)])
def test_kannala_brandt_projects_as_cv2_fisheye_projectPoints(dist):
    P = _points()
    uv, ok = C.project(Intrinsics("kannala_brandt", K, dist), P)
    ref, _ = cv2.fisheye.projectPoints(P.T.copy()[:, None], np.zeros(3), np.zeros(3), K, np.array(dist))
    assert ok.all()
    assert np.abs(uv.T - ref[:, 0]).max() < 1e-6


def test_the_inverses_match_cv2_undistortPoints():
    rng = np.random.default_rng(4)
    pts = np.stack([rng.uniform(0, 320, 40), rng.uniform(0, 192, 40)])
    crit = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 100, 1e-15)
    ref = cv2.undistortPointsIter(pts.T[:, None].copy(), K, np.array(RADTAN), None, None, crit)[:, 0]
    r = C.unproject(Intrinsics("radtan", K, RADTAN), pts)
    assert np.array_equal(r[2], np.ones(40)) and np.abs(r[:2].T - ref).max() * K[0, 0] < 1e-6
    ref = cv2.fisheye.undistortPoints(pts.T[:, None].copy(), K, np.array(KB), criteria=crit)[:, 0]
    r = C.unproject(Intrinsics("kannala_brandt", K, KB), pts)
    assert np.allclose(np.linalg.norm(r, axis=0), 1.0, rtol=0, atol=1e-15)
    assert np.abs((r[:2] / r[2]).T - ref).max() * K[0, 0] < 1e-6


@pytest.mark.parametrize("name", list(CAMS))
def test_unproject_then_project_returns_the_pixel_grid(name):
    cam, (H, W) = CAMS[name], SIZES[name]
    r = C.rays(cam, H, W)
    assert not np.isnan(r).any()
    d = np.linspace(0.5, 80.0, H * W)  # any depth (z or range) along the ray lands on its pixel
    uv, ok = C.project(cam, r * d)
    v, u = np.divmod(np.arange(H * W), W)
    assert ok.all()
    assert np.abs(uv - np.stack([u + 0.5, v + 0.5])).max() < 1e-8
    if C.depth_kind(cam) == "range":
        assert np.abs(np.linalg.norm(r, axis=0) - 1).max() < 1e-15
    else:
        assert np.array_equal(r[2], np.ones(H * W))


def test_the_fisheye_row_sees_195_degrees():
    cam, (H, W) = CAMS["kannala_brandt"], SIZES["kannala_brandt"]
    r = C.rays(cam, H, W).T.reshape(H, W, 3)
    theta = np.degrees(np.arccos(r[..., 2]))
    assert 2 * theta[H // 2].max() > 195.0  # the middle row's edge pixels look 97.5 degrees off the axis
    assert (r[..., 2] < 0).any()  # beyond the camera's own plane: z-depth is not defined there
    behind = np.array([[1.0, 0.0], [0.0, 1.0], [-0.05, -0.1]])  # 92.9 and 95.7 degrees off the axis
    uv, ok = C.project(cam, behind)
    assert ok.all() and np.allclose(C.unproject(cam, uv), behind / np.linalg.norm(behind, axis=0), atol=1e-12)


def test_points_outside_a_row_are_not_valid():
    uv, ok = C.project(K, np.array([[0.0, 1.0, 0.0], [0.0, 0.0, 0.0], [1.0, -1.0, 1e-7]]))
    assert ok.tolist() == [True, False, False] and np.isfinite(uv).all()
    r_max = C.radtan_max_r(RADTAN)  # k1 < 0: the radial map turns back at r_max
    assert 1.0 < r_max < 2.0
    uv, ok = C.project(Intrinsics("radtan", K, RADTAN), np.array([[0.9 * r_max, 1.1 * r_max], [0, 0], [1, 1]]))
    assert ok.tolist() == [True, False]
    t_max = C.kb_max_theta((0.0, -0.1, 0.0, 0.0))  # 1 - 0.5 t^4 = 0: t = 2^0.25
    assert abs(t_max - 2 ** 0.25) < 1e-3
    p = np.array([[np.sin(t_max - 0.01), np.sin(t_max + 0.01)], [0, 0], [np.cos(t_max - 0.01), np.cos(t_max + 0.01)]])
    assert C.project(Intrinsics("kannala_brandt", K, (0.0, -0.1, 0.0, 0.0)), p)[1].tolist() == [True, False]
    far = C.unproject(Intrinsics("kannala_brandt", K, (0.0, -0.1, 0.0, 0.0)), np.array([[5000.0], [95.7]]))
    assert np.isnan(far).all()  # beyond the largest theta_d: no ray


def _old_pixel_rays(K, W, H):  # synth/protocol.py before the table
    u, v = np.meshgrid(np.arange(W) + 0.5, np.arange(H) + 0.5)
    return np.stack([u, v, np.ones_like(u)], -1) @ np.linalg.inv(K).T


@pytest.mark.parametrize("Kp", [K, np.array([[96.0, 0.0, 48.0], [0.0, 96.0, 32.0], [0.0, 0.0, 1.0]]),
                                np.array([[1266.417, 0.0, 816.267], [0.0, 1266.417, 491.507], [0.0, 0.0, 1.0]])])
def test_the_pinhole_row_gives_todays_bytes(Kp):
    H, W = 64, 96
    r = C.rays(Kp, H, W)
    assert np.array_equal(r.T.reshape(H, W, 3), _old_pixel_rays(Kp, W, H))
    v, u = np.divmod(np.arange(H * W), W)
    assert np.array_equal(C.rays_at(Kp, u, v), np.linalg.inv(Kp) @ np.stack([u + 0.5, v + 0.5, np.ones(u.size)]))
    P = _points(500)
    P[2, :5] = [-1.0, 0.0, 1e-6, 2e-6, 5.0]
    uv, ok = C.project(Kp, P)
    uvw = Kp[:, 0:1] * P[0] + Kp[:, 1:2] * P[1]  # synth/overlap.py's _apply3, then its division
    uvw += Kp[:, 2:3] * P[2]
    zs = np.where(P[2] > 1e-6, P[2], 1.0)
    assert np.array_equal(uv, np.stack([uvw[0] / zs, uvw[1] / zs])) and np.array_equal(ok, P[2] > 1e-6)


@pytest.mark.parametrize("name", list(CAMS))
def test_resized_moves_every_projection_by_the_factors(name):
    cam = CAMS[name]
    small = C.resized(cam, 0.5, 0.25)
    assert C.model(small).name == name and small.dist == cam.dist
    P = _points()
    (uv, ok), (uv2, ok2) = C.project(cam, P), C.project(small, P)
    assert np.array_equal(ok, ok2) and np.abs(uv2 - uv * np.array([[0.5], [0.25]])).max() < 1e-9
    assert isinstance(C.resized(K, 2, 2), np.ndarray) and np.array_equal(C.resized(K, 2, 2), np.diag([2, 2, 1.0]) @ K)


@pytest.mark.parametrize("name", list(CAMS))
def test_json_round_trip_is_exact(name):
    cam = CAMS[name]
    back = Intrinsics.from_json(json.loads(json.dumps(cam.to_json())))
    assert back == cam and np.array_equal(back.K, cam.K) and back.dist == cam.dist
    assert list(cam.to_json()["dist"]) == list(C.MODELS[name].dist_names)


def test_bad_intrinsics_are_errors_that_say_what_is_allowed():
    with pytest.raises(ValueError, match=r"dist must be 5 finite numbers \(k1, k2, p1, p2, k3\)"):
        Intrinsics("radtan", K, (0.1,))
    with pytest.raises(ValueError, match="K must be a finite 3x3 matrix"):
        Intrinsics("pinhole", np.eye(2))
    with pytest.raises(ValueError, match=r"dist must have the keys \['k1', 'k2', 'k3', 'k4'\]"):
        Intrinsics.from_json({"model": "kannala_brandt", "K": K.tolist(), "dist": {"k1": 0.0}})
    with pytest.raises(ValueError, match="keys model, K, dist"):
        Intrinsics.from_json({"model": "pinhole", "K": K.tolist()})
    with pytest.raises(ValueError, match="a pinhole camera is needed here, got camera model 'radtan'"):
        C.pinhole_K(CAMS["radtan"])
    with pytest.raises(ValueError, match=r"points must have shape \(3, N\)"):
        C.project(K, np.zeros((4, 3)))
