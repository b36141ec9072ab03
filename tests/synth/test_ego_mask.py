"""The rendered self-occlusion mask is the ego mesh's own projection, in every camera of every rig.

A ray cast of `synth.ego_body.ego_body_mesh` (Moller-Trumbore in float64, one ray per pixel centre) is
the reference: the renderer's ego mask must equal the pixels whose ray hits the body, up to a few
pixels on the silhouette, and its z-depth there must be the ray's. Before the near plane moved
to 1 cm, the roof that the rear-side cameras look down on was clipped (15 % of their pixels).
"""
import numpy as np
import pytest

from scenes.model import Scene
from scenes.primitives import quad
from synth.gl_backend import LightState, Renderer
from synth.render import make_ego_mesh
from synth.config import DataConfig
from synth.rig import build_rig

W, H = 128, 80
LIGHT = LightState((0.3, 0.2, 0.9), (1.0, 1.0, 1.0), (0.5, 0.5, 0.5), (0.3, 0.5, 0.9), (0.8, 0.8, 0.9),
                   shadows=False)
TEX = np.full((1, 8, 8, 3), 120, np.uint8)
RIGS = [("spacing", 0.10), ("spacing", 0.60), ("fov", 0.10), ("fov", 0.60), ("preset", "nuscenes_like"),
        ("preset", "ddad_like")]


def ray_cast_z(positions, tris, K, T_ego_cam, width, height):
    """(H, W) z-depth of the first hit of each pixel-centre ray with the triangles (inf: no hit)."""
    u, v = np.meshgrid(np.arange(width) + 0.5, np.arange(height) + 0.5)
    d_cam = np.linalg.inv(K) @ np.stack([u.ravel(), v.ravel(), np.ones(u.size)])  # z = 1: t is z-depth
    d = (T_ego_cam[:3, :3] @ d_cam).T  # (N, 3) in the ego frame
    o = T_ego_cam[:3, 3]
    v0, v1, v2 = (positions[tris[:, k]] for k in range(3))  # (T, 3)
    e1, e2 = v1 - v0, v2 - v0
    best = np.full(d.shape[0], np.inf)
    for s in range(0, d.shape[0], 2048):
        dd = d[s:s + 2048, None, :]  # (n, 1, 3)
        p = np.cross(dd, e2[None])  # (n, T, 3)
        det = np.einsum("ntk,tk->nt", p, e1)
        ok = np.abs(det) > 1e-12
        inv = np.where(ok, 1.0 / np.where(ok, det, 1.0), 0.0)
        tv = o - v0  # (T, 3)
        bu = np.einsum("ntk,tk->nt", p, tv) * inv
        q = np.cross(tv, e1)  # (T, 3)
        bv = np.einsum("nk,tk->nt", dd[:, 0], q) * inv
        t = np.einsum("tk,tk->t", e2, q)[None] * inv
        hit = ok & (bu >= 0) & (bv >= 0) & (bu + bv <= 1) & (t > 0)
        best[s:s + 2048] = np.where(hit, t, np.inf).min(axis=1)
    return best.reshape(height, width)


@pytest.fixture(scope="module")
def renderer():
    cfg = DataConfig()
    r = Renderer(W, H, znear=cfg.rig.znear_m, zfar=cfg.rig.zfar_m)
    yield r
    r.close()


@pytest.mark.parametrize("mode,overlap", RIGS)
def test_ego_mask_is_the_mesh_projection(renderer, mode, overlap):
    if mode == "preset":  # a real-rig preset (configs/data/<name>.yaml) at the test's image size
        from pathlib import Path

        from corelib.configlib import load_config

        path = Path(__file__).resolve().parents[2] / "configs" / "data" / f"{overlap}.yaml"
        cfg = load_config(DataConfig, path, [f"camera.width={W}", f"camera.height={H}"])
    else:
        cfg = DataConfig.model_validate({"camera": {"width": W, "height": H},
                                         "rig": {"overlap": overlap, "overlap_mode": mode}})
    rig = build_rig(cfg.rig, cfg.camera)
    ego = make_ego_mesh(cfg)
    road = quad(np.array([(-200, -200, 0.0), (200, -200, 0.0), (200, 200, 0.0), (-200, 200, 0.0)]), 0)
    renderer.load_scene(Scene(road, [], TEX, ["flat"], np.eye(4)[None], "test"), ego)
    tris = ego.indices.reshape(-1, 3)
    seen_any = 0
    for cam in rig.cameras:
        out = renderer.render(cam.K, cam.T_ego_cam, frame=0, light=LIGHT)
        z_ref = ray_cast_z(ego.positions.astype(np.float64), tris, cam.K, cam.T_ego_cam, W, H)
        ref = np.isfinite(z_ref)
        mask = out["ego"]
        differ = mask != ref
        # pixels that differ lie on the silhouette: a 3x3 neighbourhood holds both body and scene
        pad = np.pad(ref, 1, mode="edge")
        win = np.stack([pad[i:i + H, j:j + W] for i in range(3) for j in range(3)])
        edge = win.any(0) & ~win.all(0)
        assert not (differ & ~edge).any(), f"{mode} {overlap} {cam.name}: {int((differ & ~edge).sum())} " \
                                           f"pixels off the silhouette disagree with the ego mesh"
        assert differ.sum() <= 2 * W, f"{cam.name}: {int(differ.sum())} silhouette pixels disagree"
        both = mask & ref
        np.testing.assert_allclose(out["depth"][both], z_ref[both], rtol=1e-4, atol=1e-5)
        seen_any += int(ref.sum())
        if cam.name in ("CAM_BACK_LEFT", "CAM_BACK_RIGHT") and cam.pitch_deg < 0:
            assert ref.mean() > 0.05, f"{cam.name} should look down on the roof"
            assert mask.mean() > 0.05
    assert seen_any > 0
