"""Renderer against analytic geometry: z-depth at pixel centres, K alignment, back end choice."""
import math

import numpy as np
import pytest

from scenes.model import Mesh, Scene
from scenes.primitives import box, quad
from synth.gl_backend import LightState, Renderer, projection_from_K, select_backend
from synth.rig import intrinsics_from_hfov, rotation_ego_cam

W, H = 160, 96
LIGHT = LightState((0.3, 0.2, 0.9), (1.0, 1.0, 1.0), (0.5, 0.5, 0.5), (0.3, 0.5, 0.9), (0.8, 0.8, 0.9),
                   shadows=False)
TEX = np.full((1, 8, 8, 3), 200, np.uint8)


@pytest.fixture(scope="module")
def renderer():
    r = Renderer(W, H)
    yield r
    r.close()


def _scene(mesh: Mesh) -> Scene:
    return Scene(mesh, [], TEX, ["flat"], np.eye(4)[None], "test")


def _cam(yaw_deg, pitch_deg, pos):
    T = np.eye(4)
    T[:3, :3] = rotation_ego_cam(math.radians(yaw_deg), math.radians(pitch_deg))
    T[:3, 3] = pos
    return T


def _analytic_plane_depth(K, T_world_cam, n, c):
    """z-depth of the plane n.p = c seen through each pixel centre (inf where not hit in front)."""
    u, v = np.meshgrid(np.arange(W) + 0.5, np.arange(H) + 0.5)
    d_cam = np.linalg.inv(K) @ np.stack([u.ravel(), v.ravel(), np.ones(u.size)])  # z = 1
    d_w = T_world_cam[:3, :3] @ d_cam
    o = T_world_cam[:3, 3]
    t = (c - n @ o) / (n @ d_w)
    t = np.where(t > 0, t, np.inf)
    return t.reshape(H, W)  # t is the z-depth because d_cam has z = 1


def test_projection_matrix_maps_K():
    K = intrinsics_from_hfov(W, H, 70.0)
    P = projection_from_K(K, W, H, 0.5, 100.0)
    p = np.array([1.3, -0.4, 7.0, 1.0])
    clip = P @ p
    ndc = clip[:3] / clip[3]
    u_expect = K[0, 0] * p[0] / p[2] + K[0, 2]
    v_expect = K[1, 1] * p[1] / p[2] + K[1, 2]
    assert (ndc[0] + 1) / 2 * W == pytest.approx(u_expect)
    assert H - (ndc[1] + 1) / 2 * H == pytest.approx(v_expect)  # GL window y is bottom-up
    assert ndc[2] == pytest.approx(-1 + 2 * (1 / 0.5 - 1 / 7.0) / (1 / 0.5 - 1 / 100.0))


def test_ground_plane_depth_exact(renderer):
    ground = quad(np.array([[-400, -400, 0], [400, -400, 0], [400, 400, 0], [-400, 400, 0]], float), 0)
    renderer.load_scene(_scene(ground), None)
    K = intrinsics_from_hfov(W, H, 80.0)
    T = _cam(20.0, -12.0, (0.3, 0.2, 1.6))
    d = renderer.render(K, T, 0, LIGHT)["depth"]
    expect = _analytic_plane_depth(K, T, np.array([0, 0, 1.0]), 0.0)
    sel = (expect >= 1.0) & (expect <= 150.0)
    assert sel.mean() > 0.4
    assert np.all(d[sel] > 0)
    rel = np.abs(d[sel] - expect[sel]) / expect[sel]
    assert np.median(rel) <= 1e-4
    assert rel.max() <= 1e-3
    assert np.all(d[np.isinf(expect)] == 0)   # sky: no surface


@pytest.mark.parametrize("dist", [1.5, 10.0, 60.0, 150.0])
def test_tilted_wall_depth_exact(renderer, dist):
    # a wall rotated 30 deg about z whose centre is `dist` ahead of the camera
    a = math.radians(30.0)
    n = np.array([-math.cos(a), -math.sin(a), 0.0])
    centre = np.array([dist, 0.0, 1.5])
    tdir = np.array([-math.sin(a), math.cos(a), 0.0])
    s = 3 * dist
    corners = np.array([centre - s * tdir - [0, 0, s], centre + s * tdir - [0, 0, s],
                        centre + s * tdir + [0, 0, s], centre - s * tdir + [0, 0, s]])
    renderer.load_scene(_scene(quad(corners, 0)), None)
    K = intrinsics_from_hfov(W, H, 70.0)
    T = _cam(0.0, 0.0, (0.0, 0.0, 1.5))
    d = renderer.render(K, T, 0, LIGHT)["depth"]
    expect = _analytic_plane_depth(K, T, n, n @ centre)
    sel = np.isfinite(expect) & (expect >= 1.0) & (expect <= 400.0)
    assert sel.mean() > 0.9
    rel = np.abs(d[sel] - expect[sel]) / expect[sel]
    assert np.median(rel) <= 1e-4 and rel.max() <= 1e-3


def test_point_lands_on_K_pixel(renderer):
    # a 4 cm cube: the centroid of its depth footprint must be where K projects its centre
    K = intrinsics_from_hfov(W, H, 70.0)
    T = _cam(0.0, 0.0, (0.0, 0.0, 1.5))
    p_cam = np.array([0.9, -0.35, 8.0])     # camera frame (x right, y down)
    p_world = T[:3, :3] @ p_cam + T[:3, 3]
    Tb = np.eye(4)
    Tb[:3, 3] = p_world
    renderer.load_scene(_scene(box((0.3, 0.3, 0.3), 0, T=Tb)), None)
    d = renderer.render(K, T, 0, LIGHT)["depth"]
    v, u = np.nonzero(d > 0)
    assert len(u) > 10
    u_expect = K[0, 0] * p_cam[0] / p_cam[2] + K[0, 2]
    v_expect = K[1, 1] * p_cam[1] / p_cam[2] + K[1, 2]
    assert (u + 0.5).mean() == pytest.approx(u_expect, abs=0.35)
    assert (v + 0.5).mean() == pytest.approx(v_expect, abs=0.35)


def test_ego_flag_and_rgb_alignment(renderer):
    K = intrinsics_from_hfov(W, H, 70.0)
    T = _cam(0.0, 0.0, (0.0, 0.0, 1.5))
    Tb = np.eye(4)
    Tb[:3, 3] = (5.0, 0.0, 1.5)
    renderer.load_scene(_scene(Mesh.empty()), box((1.0, 1.0, 1.0), 0, T=Tb))
    out = renderer.render(K, T, 0, LIGHT)
    assert out["ego"].sum() > 100
    assert np.array_equal(out["ego"], out["depth"] > 0)
    # RGB of the (grey, lit) box differs from the sky exactly on the depth footprint's rows
    rows = np.nonzero(out["ego"].any(axis=1))[0]
    col = W // 2
    gray_box = out["rgb"][rows, col].astype(int)
    assert np.ptp(gray_box, axis=0).max() < 40


def test_backend_selection_errors(monkeypatch):
    with pytest.raises(ValueError, match="render.backend"):
        select_backend("vulkan")
    monkeypatch.setenv("PYOPENGL_PLATFORM", "glx")
    from synth.gl_backend import RenderBackendError
    with pytest.raises(RenderBackendError, match="PYOPENGL_PLATFORM"):
        select_backend("auto")


def test_osmesa_fallback_renders_exact_depth():
    """The OSMesa back end (PyOpenGL fixes its platform at import, hence a subprocess)."""
    import os
    import subprocess
    import sys

    snippet = r'''
import math, sys
import numpy as np
sys.path.insert(0, sys.argv[1])
from scenes.model import Scene
from scenes.primitives import quad
from synth.gl_backend import LightState, Renderer
from synth.rig import intrinsics_from_hfov, rotation_ego_cam
W, H = 64, 48
r = Renderer(W, H, backend="osmesa")
g = quad(np.array([[-400, -400, 0], [400, -400, 0], [400, 400, 0], [-400, 400, 0]], float), 0)
r.load_scene(Scene(g, [], np.full((1, 8, 8, 3), 200, np.uint8), ["f"], np.eye(4)[None], "t"), None)
K = intrinsics_from_hfov(W, H, 70.0)
T = np.eye(4); T[:3, :3] = rotation_ego_cam(0.0, math.radians(-10)); T[2, 3] = 1.5
d = r.render(K, T, 0, LightState((0, 0, 1), (1, 1, 1), (1, 1, 1), (1, 1, 1), (1, 1, 1), shadows=False))["depth"]
u, v = np.meshgrid(np.arange(W) + 0.5, np.arange(H) + 0.5)
ray = T[:3, :3] @ (np.linalg.inv(K) @ np.stack([u.ravel(), v.ravel(), np.ones(u.size)]))
t = (-1.5 / ray[2]).reshape(H, W)
sel = (ray[2].reshape(H, W) < 0) & (t < 150)
print(r.platform, float(np.max(np.abs(d[sel] - t[sel]) / t[sel])), int(sel.sum()))
'''
    root = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
    env = dict(os.environ, PYOPENGL_PLATFORM="osmesa")
    proc = subprocess.run([sys.executable, "-c", snippet, root], env=env, capture_output=True, text=True, timeout=120)
    assert proc.returncode == 0, proc.stderr[-2000:]
    platform, err, n = proc.stdout.split()
    assert platform == "osmesa" and int(n) > 500 and float(err) <= 1e-3
