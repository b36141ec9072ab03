"""The lens travels with the batch (issue 59 item 1): `mcdp.camera.Lens` from a reader's cameras, through
`mcdp.inputs.stack` / `RigBatch.to` / `depth_input`, flattened per item as the warps flatten images; a batch that
mixes rows warps each item through its own; `mcdp.geometry.splat_depth` (L_con) through the lenses (camera j's
true depth splatted into camera i is i's true depth, of i's depth kind); and one training step of every method
family through a fisheye lens (finite losses and gradients that differ from the same step as if pinhole)."""
from __future__ import annotations

import dataclasses
import sys
from pathlib import Path

import numpy as np
import pytest
import torch

from mcdp.camera import Lens
from mcdp.geometry import splat_depth, warp_by_depth
from mcdp.inputs import stack
from synth import camera as C
from synth.rig import CameraSpec

sys.path.insert(0, str(Path(__file__).parent))
from test_camera import _T_ego_cam, _render, _t  # noqa: E402  (the ray-cast room of the convention test)

KB = (0.01, -0.002, 0.0, 0.0)
RT = (-0.25, 0.06, 0.001, -0.001, 0.0)


def _spec(name, model="pinhole", dist=()):
    return CameraSpec(name, 8, 6, np.diag([4.0, 4.0, 1.0]), np.eye(4), 90.0, 0.0, 0.0, model, dist)


def test_a_lens_of_cameras_pads_and_flattens_as_the_warps_do():
    assert Lens.of_cameras([_spec("A"), _spec("B")]) is None  # a pinhole rig: no lens, the pinhole path
    lens = Lens.of_cameras([_spec("A"), _spec("B", "radtan", RT), _spec("C", "kannala_brandt", KB)])
    assert lens.models == ("pinhole", "radtan", "kannala_brandt") and lens.dist.dtype == torch.float32
    assert torch.equal(lens.dist, torch.tensor([[0.0] * 5, list(RT), list(KB) + [0.0]], dtype=torch.float32))
    item = {"rgb": torch.zeros(3, 3, 3, 6, 8), "K": torch.eye(3).repeat(3, 1, 1), "T_ego_cam": torch.eye(4).repeat(3, 1, 1),
            "mask": torch.ones(3, 1, 6, 8), "T_world_ego": torch.eye(4).repeat(3, 1, 1), "seq_index": torch.tensor(0),
            "frame": torch.tensor(1), "fields": {}, "lens": lens}
    batch = stack([item, {**item, "lens": lens.map(lambda d: d * 2)}])
    assert batch.lens.dist.shape == (2, 3, 5) and batch.to("cpu").lens.models == lens.models
    models, dist = batch.lens.of(torch.tensor([2, 0]))  # items in (b, p) order, as images reshape (B * P, ...)
    assert models == ("kannala_brandt", "pinhole") * 2
    assert torch.equal(dist[[0, 2], 0], torch.tensor([KB[0], 2 * KB[0]], dtype=torch.float32))
    assert batch.depth_input(torch.full((3, 2), -1)).lens is batch.lens


def _room(name, T, H=48, W=64):
    fish = name == "kannala_brandt"
    f = (W / 2) / np.radians(100.0) if fish else 32.0
    K = np.array([[f, 0.0, W / 2], [0.0, f, H / 2], [0.0, 0.0, 1.0]])
    dist = {"pinhole": (), "radtan": RT, "kannala_brandt": KB}[name]
    depth, tex = _render(C.Intrinsics(name, K, dist), H, W, T)
    return depth, tex, _t(K)[None], (name, _t(dist).view(1, -1))


def test_a_batch_that_mixes_rows_warps_each_item_through_its_own():
    Ti, Tj = _T_ego_cam(0.0, [1.5, 0.0, 1.6]), _T_ego_cam(-60.0, [1.2, -0.7, 1.6])
    T = _t(np.linalg.inv(Tj) @ Ti)[None]
    one = {n: _room(n, Ti) + (_room(n, Tj)[1],) for n in ("radtan", "kannala_brandt")}
    alone = {n: warp_by_depth(_t(ij)[None, None], _t(d)[None, None], K, K, T, lens_tgt=ln, lens_src=ln)[0]
             for n, (d, _, K, ln, ij) in one.items()}
    (d0, _, K0, l0, j0), (d1, _, K1, l1, j1) = one["radtan"], one["kannala_brandt"]
    mixed = (("radtan", "kannala_brandt"), torch.cat([l0[1], torch.cat([l1[1], l1[1].new_zeros(1, 1)], 1)]))
    both, _ = warp_by_depth(_t(np.stack([j0, j1]))[:, None], _t(np.stack([d0, d1]))[:, None], torch.cat([K0, K1]),
                            torch.cat([K0, K1]), T.expand(2, 4, 4), lens_tgt=mixed, lens_src=mixed)
    assert torch.equal(both[0], alone["radtan"][0]) and torch.equal(both[1], alone["kannala_brandt"][0])
    assert not torch.equal(alone["radtan"], alone["kannala_brandt"])


@pytest.mark.parametrize("name", list(C.MODELS))
def test_a_neighbours_true_depth_splatted_through_the_lens_is_the_true_depth(name):
    """L_con's convention for every row: camera j's true depth (of its kind) forward-projected into camera i
    lands on i's true depth (of i's kind) wherever it hits; as if pinhole it does not (distorted rows)."""
    Ti, Tj = _T_ego_cam(0.0, [1.5, 0.0, 1.6]), _T_ego_cam(-50.0, [1.2, -0.7, 1.6])
    di, _, K, lens = _room(name, Ti)
    dj = _room(name, Tj)[0]
    T_i_j = _t(np.linalg.inv(Ti) @ Tj)[None]

    def rel_err(ls, lt):
        d_hat, hit = splat_depth(_t(dj)[None, None], K, K, T_i_j, 48, 64, lens_src=ls, lens_tgt=lt)
        ok = hit[0, 0].bool()
        return float(((d_hat[0, 0] - _t(di)).abs() / _t(di))[ok].median()), int(ok.sum())

    e, n = rel_err(lens, lens)
    assert n > 0.15 * 48 * 64 and e < 0.01  # a splat lands within its pixel: the depth of a nearby ray
    if name != "pinhole":
        assert rel_err(None, None)[0] > 3 * e


@pytest.mark.parametrize("method", ["mono2", "mcdp", "mcdp_local", "fsm"])
def test_one_training_step_through_a_fisheye_lens(method):
    from test_model import RING, N, rig_batch, run_cfg

    from mcdp.system import SelfSupervisedSystem

    model = {"method": method}
    if method == "mono2":
        model.update(bases=1, refine_steps=0)
    elif method == "fsm":
        model.update(bases=1, refine_steps=0)
    cfg = run_cfg(model, scale={"source": "odometry"})
    batch = rig_batch()
    fish = dataclasses.replace(batch, lens=Lens(("kannala_brandt",) * N, torch.tensor([KB] * N).float()[None]))

    def step(b):
        torch.manual_seed(0)
        s = SelfSupervisedSystem(cfg, RING, N)
        _, losses = s.process_batch(b, step=0, train=True)
        losses["loss"].backward()
        return losses, {n: p.grad.clone() for n, p in s.named_parameters() if p.grad is not None}

    lp, gp = step(batch)
    lf, gf = step(fish)
    assert torch.isfinite(lf["loss"]) and all(torch.isfinite(g).all() for g in gf.values())
    assert float(lf["loss"]) != float(lp["loss"])
    moved = [k for k in lp if k.startswith(("reprojection/", "consistency/", "fsm/")) and float(lp[k]) != float(lf[k])]
    assert moved, "no warped term changed with the lens"


@pytest.mark.parametrize("name", ["radtan", "kannala_brandt"])
def test_the_convention_holds_in_float32_with_finite_gradients(name):
    """Training runs in float32: the Newton inverses' tolerance is float32's there (`mcdp.camera._tol`), so the
    pixels keep their rays, and a pixel without one (beyond the row's range) gives a finite gradient."""
    Ti, Tj = _T_ego_cam(0.0, [1.5, 0.0, 1.6]), _T_ego_cam(-60.0, [1.2, -0.7, 1.6])
    di, ii, K, (n, dist) = _room(name, Ti)
    ij = _room(name, Tj)[1]
    f32 = (lambda x: _t(x).float()[None, None])
    depth = f32(di).requires_grad_(True)
    T = _t(np.linalg.inv(Tj) @ Ti)[None].float()
    lens = (n, dist.float())
    w, ok = warp_by_depth(f32(ij), depth, K.float(), K.float(), T, lens_tgt=lens, lens_src=lens)
    w.sum().backward()
    okb = ok[0, 0].bool()
    assert okb.sum() > 0.05 * 48 * 64 and float((w[0, 0] - f32(ii)[0, 0]).abs()[okb].mean()) < 0.02
    assert torch.isfinite(depth.grad).all()
