"""The evaluator through the camera (issue 59): on a two-camera room whose depth is ray-cast along the camera
table's rays (`synth.camera`, each camera's depth of its kind: z-depth for radtan, range for kannala_brandt), the
evaluator's overlap region and Dep Con equal a brute-force numpy computation through the table (the definitions
of `synth.overlap` and `mcdp.evaluate`, pixel by pixel), and are wrong when the lens is ignored; a perfect
prediction scores abs_rel 0; ``model.lens=pinhole`` (the "as if pinhole" ablation) drops the lens from the
training batch, keeps every hash, and is refused for a range camera."""
from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pytest

from mcdp import evaluate as E
from mcdp.config import EvalConfig
from mcdp.eval_truth import EvalRig, TruthCache
from mcdp.metrics import dep_con, valid_gt_mask
from synth import camera as C
from synth.overlap import overlap_union
from synth.rig import CameraSpec

sys.path.insert(0, str(Path(__file__).parent))
from test_camera import _T_ego_cam, _render  # noqa: E402  (the ray-cast room of the convention test)

DIST = {"pinhole": (), "radtan": (-0.25, 0.06, 0.001, -0.001, 0.0), "kannala_brandt": (0.01, -0.002, 0.0, 0.0)}
POSES = (_T_ego_cam(0.0, [1.5, 0.0, 1.6]), _T_ego_cam(-60.0, [1.2, -0.7, 1.6]))  # front, front right
EGO_ROWS = 3  # the bottom rows of each image are ego body


def _lens(name):
    fish = name == "kannala_brandt"
    H, W = (64, 64) if fish else (48, 64)
    f = (W / 2) / np.radians(100.0) if fish else 32.0  # the fisheye: 200 degrees across
    return C.Intrinsics(name, np.array([[f, 0.0, W / 2], [0.0, f, H / 2], [0.0, 0.0, 1.0]]), DIST[name]), H, W


@pytest.fixture(scope="module")
def room(fake_dataset):
    """``room(model)``: a dataset reader (tests/conftest.py's FakeDataset, its splits and frames) of two cameras of
    row ``model`` in the closed room of the convention test, depth ray-cast along the table's rays."""
    def make(model):
        cam, H, W = _lens(model)

        class Room(fake_dataset):
            def __init__(self):
                super().__init__(n_frames=3)
                self.cameras = [CameraSpec(n, W, H, np.array(cam.K), T, 100.0, 0.0, 0.0, model, DIST[model])
                                for n, T in zip(self.camera_names, POSES)]
                self._hw = {c.name: (H, W) for c in self.cameras}
                self.depth = {c.name: _render(cam, H, W, T)[0].astype(np.float32) for c, T in zip(self.cameras, POSES)}

            def read_depth(self, seq, cam_name, frame):
                self.depth_reads.append((seq, cam_name, frame))
                return self.depth[cam_name].copy()

            def mask(self, cam_name):
                m = np.ones(self._hw[cam_name], bool)
                m[-EGO_ROWS:] = False
                return m
        return Room()
    return make


# --------------------------------------------------------------------------- brute force, through the table
def _points(depth, cam):
    """(3, H*W) camera-frame points of every pixel (NaN where the row has no ray): depth (of the row's kind) x ray."""
    H, W = depth.shape
    return C.rays(cam, H, W) * depth.astype(np.float64).ravel()


def _depth_of(cam, p):
    return np.linalg.norm(p, axis=0) if C.depth_kind(cam) == "range" else p[2]


def brute_overlap(gi, cam_i, Ti, gj, cam_j, Tj, mi, mj, z_tol=0.05):
    """`synth.overlap`'s definition pixel by pixel: camera i's point seen by j (the table's projection valid, inside
    j's image, on a scene pixel of j) and passing the z-test against j's 3x3 maximum depth, each of its kind."""
    H, W = gi.shape
    Hj, Wj = gj.shape
    T = np.linalg.inv(Tj) @ Ti
    p = T[:3, :3] @ _points(gi, cam_i) + T[:3, 3:]
    uv, ok = C.project(cam_j, p)
    dj = _depth_of(cam_j, p)
    out = np.zeros(H * W, bool)
    for k in np.flatnonzero(((gi > 0) & mi).ravel() & ok):
        col, row = int(np.floor(uv[0, k])), int(np.floor(uv[1, k]))
        if not (0 <= col < Wj and 0 <= row < Hj) or not mj[row, col]:
            continue
        near = gj[max(row - 1, 0):row + 2, max(col - 1, 0):col + 2].max()
        out[k] = near > 0 and dj[k] > C.EPS_Z and dj[k] <= (1 + z_tol) * near
    return out.reshape(H, W)


def brute_splat(dj, cam_j, shape_i, cam_i, T_i_j, mask_j):
    """`mcdp.geometry.splat_depth`'s definition pixel by pixel: each scene pixel of j with depth lands on the pixel
    of i that contains its projection; the nearest (of i's depth kind) wins, ties to the lowest source pixel."""
    Hi, Wi = shape_i
    p = T_i_j[:3, :3] @ _points(dj, cam_j) + T_i_j[:3, 3:]
    uv, ok = C.project(cam_i, p)
    d = _depth_of(cam_i, p)
    best = np.full(Hi * Wi, np.inf)
    for k in np.flatnonzero(ok & (dj.ravel() > 0) & mask_j.ravel()):
        col, row = int(np.floor(uv[0, k])), int(np.floor(uv[1, k]))
        if 0 <= col < Wi and 0 <= row < Hi and d[k] > 1e-6 and d[k] < best[row * Wi + col]:
            best[row * Wi + col] = d[k]
    hit = np.isfinite(best)
    return np.where(hit, best, 0.0).reshape(Hi, Wi), hit.reshape(Hi, Wi)


def _truth(ds):
    gts = [np.asarray(ds.read_depth("s0", n, 1), np.float64) for n in ds.camera_names]
    masks = [ds.mask(n) for n in ds.camera_names]
    return gts, masks, [c.intrinsics for c in ds.cameras]


# --------------------------------------------------------------------------- the overlap region
@pytest.mark.parametrize("model", ["radtan", "kannala_brandt"])
def test_ignoring_the_lens_gets_the_overlap_wrong(room, model):
    """What the evaluator must not do: the same depth with each K taken as a pinhole's gives another overlap."""
    ds = room(model)
    gts, masks, cams = _truth(ds)
    for i, j in ((0, 1), (1, 0)):
        truth = brute_overlap(gts[i], cams[i], POSES[i], gts[j], cams[j], POSES[j], masks[i], masks[j])
        assert truth.sum() > 0.15 * truth.size  # the pair overlaps
        pinhole = overlap_union(i, gts, [c.K for c in cams], list(POSES), masks, [j])
        assert (pinhole != truth).sum() > 0.05 * truth.sum()


@pytest.mark.parametrize("model", ["pinhole", "radtan", "kannala_brandt"])
def test_the_evaluators_overlap_is_the_brute_force_overlap_through_the_table(room, model):
    ds = room(model)
    gts, masks, cams = _truth(ds)
    t = TruthCache(ds, EvalConfig()).get("s0", 1)
    for i, j in ((0, 1), (1, 0)):
        truth = brute_overlap(gts[i], cams[i], POSES[i], gts[j], cams[j], POSES[j], masks[i], masks[j])
        assert truth.sum() > 0.15 * truth.size
        assert np.array_equal(t.overlaps[i], truth), f"{(t.overlaps[i] != truth).sum()} pixels differ"


# --------------------------------------------------------------------------- Dep Con
@pytest.mark.parametrize("model", ["pinhole", "radtan", "kannala_brandt"])
def test_dep_con_splats_through_the_lens_as_brute_force_does(room, model):
    """The evaluator's splat (`mcdp.evaluate._splat_pairs` with the rig's lens) of a perfect prediction is the
    brute-force splat pixel for pixel, its Dep Con small; as if pinhole it is several times larger."""
    ds = room(model)
    gts, masks, cams = _truth(ds)
    rig = EvalRig(ds)
    assert (rig.lens is None) == (model == "pinhole") and rig.kinds == [C.depth_kind(cams[0])] * 2
    T_c_c = {(i, j): np.linalg.inv(POSES[i]) @ POSES[j] for j, i in rig.pairs}
    d_hats, hits = E._splat_pairs(gts, rig.pairs, rig.Ks, T_c_c, rig.shapes, rig.masks, rig.lens)
    flat, flat_hits = E._splat_pairs(gts, rig.pairs, rig.Ks, T_c_c, rig.shapes, rig.masks, None)
    for (j, i), d_hat, hit, d_flat, hit_flat in zip(rig.pairs, d_hats, hits, flat, flat_hits):
        want, want_hit = brute_splat(gts[j], cams[j], gts[i].shape, cams[i], T_c_c[(i, j)], masks[j])
        assert np.array_equal(hit, want_hit) and hit.sum() > 0.15 * hit.size
        np.testing.assert_allclose(d_hat, want, rtol=1e-12)
        valid = valid_gt_mask(gts[i], masks[i], 0.5, 80.0)
        dc, dc_flat = dep_con(gts[i], d_hat, gts[i], valid & hit), dep_con(gts[i], d_flat, gts[i], valid & hit_flat)
        assert dc < 0.02  # a splat lands within its pixel: the depth of a nearby ray
        if model != "pinhole":
            assert dc_flat > 3 * dc, (dc, dc_flat)


@pytest.mark.parametrize("model", ["radtan", "kannala_brandt"])
def test_a_perfect_prediction_scores_abs_rel_0_and_the_brute_force_dep_con(room, model, one_thread):
    ds = room(model)
    gts, masks, cams = _truth(ds)
    m = E.evaluate(ds, lambda seq, f: {"final": gts}, "test", EvalConfig(), progress=False)
    kind = C.depth_kind(cams[0])
    assert m["lenses"] == {n: {"model": model, "depth_kind": kind} for n in ds.camera_names}
    st = m["stages"]["final"]
    for region in ("mean", "overlap", "non_overlap"):
        assert st["none"][region]["abs_rel"] == 0.0 and st["none"][region]["a1"] == 1.0, region
    for j, i in ((1, 0), (0, 1)):
        T = np.linalg.inv(POSES[i]) @ POSES[j]
        d_hat, hit = brute_splat(gts[j], cams[j], gts[i].shape, cams[i], T, masks[j])
        want = dep_con(gts[i], d_hat, gts[i], valid_gt_mask(gts[i], masks[i], 0.5, 80.0) & hit)
        got = st["dep_con"]["per_pair"][f"{ds.camera_names[j]}->{ds.camera_names[i]}"]
        assert 0 < got < 0.02 and got == pytest.approx(want, rel=1e-9)
    overlap = [brute_overlap(gts[i], cams[i], POSES[i], gts[1 - i], cams[1 - i], POSES[1 - i], masks[i], masks[1 - i])
               for i in (0, 1)]
    assert m["stages"]["final"]["none"]["overlap_per_camera"][ds.camera_names[0]]["abs_rel"] == 0.0
    assert all(o.any() for o in overlap)


def test_the_flat_road_prior_is_of_the_cameras_depth_kind():
    """`mcdp.priors.flat_road_depth` through the lens: its depth, unprojected through the table, lies on the road."""
    from mcdp.priors import flat_road_depth

    for model in ("radtan", "kannala_brandt"):
        cam, H, W = _lens(model)
        T = POSES[0]
        d = flat_road_depth(cam, T, H, W, far=50.0).astype(np.float64)
        road = d < 50.0
        assert road.sum() > 0.2 * road.size
        p = T[:3, :3] @ _points(d, cam) + T[:3, 3:]
        np.testing.assert_allclose(p[2][road.ravel()], 0.0, atol=1e-4)  # z_ego = 0 (float32 depth)


# --------------------------------------------------------------------------- model.lens: as if pinhole
def test_the_as_if_pinhole_switch_keeps_every_hash():
    from corelib.configlib import build_config, config_hash
    from mcdp.config import RunConfig

    plain = build_config(RunConfig, {})
    assert config_hash(build_config(RunConfig, {"model": {"lens": "rig"}})) == config_hash(plain)
    assert config_hash(build_config(RunConfig, {"model": {"lens": "pinhole"}})) != config_hash(plain)
    with pytest.raises(Exception, match="lens"):
        build_config(RunConfig, {"model": {"lens": "fisheye"}})


def test_as_if_pinhole_the_training_batch_has_no_lens(room):
    from mcdp.data import RigDataset, collate

    ds = room("radtan")
    rig = collate([RigDataset(ds, "train", 32, 64, lens="rig")[0]])
    flat = collate([RigDataset(ds, "train", 32, 64, lens="pinhole")[0]])
    assert rig.lens is not None and rig.lens.models == ("radtan", "radtan")
    assert np.allclose(rig.lens.dist[0, 0].numpy(), DIST["radtan"])
    assert flat.lens is None
    assert np.array_equal(rig.K.numpy(), flat.K.numpy()) and np.array_equal(rig.rgb.numpy(), flat.rgb.numpy())
    assert RigDataset(room("pinhole"), "train", 32, 64, lens="pinhole")[0].get("lens") is None


def test_as_if_pinhole_is_refused_for_a_range_camera(room):
    from mcdp.data import RigDataset

    ds = room("kannala_brandt")
    assert RigDataset(ds, "train", 32, 64)[0]["lens"].models == ("kannala_brandt",) * 2
    with pytest.raises(ValueError, match=r"^model\.lens=pinhole needs z-depth cameras; CAM_FRONT \(kannala_brandt\), "
                                         r"CAM_FRONT_RIGHT \(kannala_brandt\) store range depth") as e:
        RigDataset(ds, "train", 32, 64, lens="pinhole")
    assert "\n" not in str(e.value)


@pytest.mark.parametrize("lens", ["rig", "pinhole"])
def test_the_trainer_and_its_predictor_read_model_lens(room, tmp_path, lens, one_thread):
    """The trainer's batches and its predictor's input (the network's warps, as trained) carry the lens under
    ``rig`` and none under ``pinhole``; the evaluator's rig keeps the true lens either way."""
    from corelib.configlib import load_config
    from mcdp.config import RunConfig
    from mcdp.trainer import Trainer

    from .conftest import TINY, _untrained

    ds = room("radtan")
    over = [f"model.lens={lens}"]
    tr = Trainer(load_config(RunConfig, TINY / "mono2.yaml", over), ds, tmp_path / "run", progress=False,
                 tensorboard=False)
    try:
        assert ("lens" in tr.train_set[0]) == (lens == "rig")
        assert (tr.train_set.reader.lens is None) == (tr.val_set.reader.lens is None) == (lens == "pinhole")
    finally:
        tr.close()
    pred = _untrained(ds, tmp_path / "net.pt", "mcdp_m2", *over)
    assert (pred.inputs("s0", 1).network_input.lens is None) == (lens == "pinhole")
    assert EvalRig(ds).lens[0] == ("radtan", "radtan")
