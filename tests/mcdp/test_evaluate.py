"""Tests for mcdp.evaluate on a fake two-camera dataset with an analytic wall (no rendering)."""
import json
import math

import numpy as np
import pytest

from mcdp import evaluate as E
from mcdp import priors as P
from mcdp import tables as T
from mcdp.metrics import metric_names
from synth.label_reader import NoLabels

#: the geometry of the fake dataset (tests/conftest.py's FakeDataset, the `fake_dataset` fixture; checked below)
H, W, Z_WALL, SHIFT_PX = 12, 16, 10.0, 3


def perfect(seq, frame):
    d = np.full((2, H, W), Z_WALL, np.float32)
    return {"init": d * 1.5, "refine1": d}


def run(ds, fn, **cfg):
    return E.evaluate(ds, fn, "test", E.EvalConfig(**cfg), progress=False)


def test_layout_and_perfect_prediction(fake_dataset):
    ds = fake_dataset()
    assert (ds.H, ds.W, ds.Z_WALL, ds.SHIFT_PX) == (H, W, Z_WALL, SHIFT_PX)  # the sizes this module's tests use
    m = run(ds, perfect)
    assert m["split"] == "test" and m["n_samples"] == 4  # 2 sequences x frames 1, 2 (ends skipped)
    assert m["cameras"] == ["CAM_FRONT", "CAM_FRONT_RIGHT"]
    assert m["min_depth"] == 0.5 and m["max_depth"] == 80.0
    assert list(m["stages"]) == ["init", "refine1", "final"]
    assert {f for _, _, f in ds.depth_reads} == {1, 2}
    for stage in m["stages"].values():
        assert set(stage) == {"none", "median", "rig_median", "dep_con", "spread"}
        assert stage["spread"]["ratio"] == pytest.approx(1.0)  # a flat wall predicted flat: p90/p10 = 1
        for sc in E.SCALINGS:
            s = stage[sc]
            assert {"mean", "per_camera", "overlap", "non_overlap"} <= set(s)
            assert set(s["mean"]) == set(metric_names())
            assert set(s["per_camera"]) == set(m["cameras"])
        assert set(stage["dep_con"]["per_pair"]) == {"CAM_FRONT->CAM_FRONT_RIGHT", "CAM_FRONT_RIGHT->CAM_FRONT"}
        assert set(stage["dep_con"]["per_camera"]) == set(m["cameras"])
    fin = m["stages"]["final"]
    for sc in E.SCALINGS:
        for region in ("mean", "overlap", "non_overlap"):
            assert fin[sc][region]["abs_rel"] == pytest.approx(0.0, abs=1e-7)
            assert fin[sc][region]["a1"] == 1.0
    assert fin["dep_con"]["mean"] < 1e-6
    # NaN-aware: a distance band without a pixel holds NaN metrics in both
    assert json.dumps(fin, sort_keys=True) == json.dumps(m["stages"]["refine1"], sort_keys=True)
    # init is 1.5x too far: metric abs_rel 0.5, median-scaled 0; Dep Con stays 0 on a wall (both scaled)
    assert m["stages"]["init"]["none"]["mean"]["abs_rel"] == pytest.approx(0.5)
    assert m["stages"]["init"]["median"]["mean"]["abs_rel"] == pytest.approx(0.0, abs=1e-7)
    json.dumps(m)  # serialisable


def test_double_depth_none_vs_median(fake_dataset):
    m = run(fake_dataset(), lambda s, f: {"init": np.full((2, H, W), 2 * Z_WALL, np.float32)})
    fin = m["stages"]["final"]
    assert fin["none"]["mean"]["abs_rel"] == pytest.approx(1.0)
    assert fin["none"]["mean"]["a3"] == 0.0
    assert fin["median"]["mean"]["abs_rel"] == pytest.approx(0.0, abs=1e-7)
    assert fin["rig_median"]["mean"]["abs_rel"] == pytest.approx(0.0, abs=1e-7)


def test_rig_median_differs_from_median_and_dep_con_hand_value(fake_dataset):
    def fn(seq, frame):
        d = np.full((2, H, W), Z_WALL, np.float32)
        d[0] *= 2.0
        d[1] *= 4.0
        return {"init": d}

    fin = run(fake_dataset(), fn)["stages"]["final"]
    assert fin["none"]["per_camera"]["CAM_FRONT"]["abs_rel"] == pytest.approx(1.0)
    assert fin["none"]["per_camera"]["CAM_FRONT_RIGHT"]["abs_rel"] == pytest.approx(3.0)
    assert fin["none"]["mean"]["abs_rel"] == pytest.approx(2.0)  # mean of the per-camera values
    assert fin["median"]["mean"]["abs_rel"] == pytest.approx(0.0, abs=1e-7)
    # rig median: pooled preds are half 20 m, half 40 m -> median 30 -> scale 1/3: 6.67 m and 13.3 m
    rm = fin["rig_median"]["per_camera"]
    assert rm["CAM_FRONT"]["abs_rel"] == pytest.approx(1 / 3, rel=1e-5)
    assert rm["CAM_FRONT_RIGHT"]["abs_rel"] == pytest.approx(1 / 3, rel=1e-5)
    # Dep Con on unscaled predictions: |20 - 40| / 10 = 2 in both directions
    assert fin["dep_con"]["per_pair"]["CAM_FRONT_RIGHT->CAM_FRONT"] == pytest.approx(2.0)
    assert fin["dep_con"]["per_pair"]["CAM_FRONT->CAM_FRONT_RIGHT"] == pytest.approx(2.0)
    assert fin["dep_con"]["mean"] == pytest.approx(2.0)


def test_overlap_split_separates_regions(fake_dataset):
    # error only in the columns of CAM_FRONT that CAM_FRONT_RIGHT cannot see (0..2)
    def fn(seq, frame):
        d = np.full((2, H, W), Z_WALL, np.float32)
        d[0, :, :SHIFT_PX] = 2 * Z_WALL
        return {"init": d}

    r = run(fake_dataset(), fn)["stages"]["final"]["none"]
    assert r["overlap_per_camera"]["CAM_FRONT"]["abs_rel"] == pytest.approx(0.0, abs=1e-7)
    assert r["non_overlap_per_camera"]["CAM_FRONT"]["abs_rel"] == pytest.approx(1.0)
    assert r["per_camera"]["CAM_FRONT"]["abs_rel"] == pytest.approx(3 / 16)
    assert r["per_camera"]["CAM_FRONT_RIGHT"]["abs_rel"] == pytest.approx(0.0, abs=1e-7)


def test_frame_stride_and_skip_ends(fake_dataset):
    ds = fake_dataset(n_frames=6)
    assert run(ds, perfect, frame_stride=2)["n_samples"] == 4  # frames 1, 3 of 0..5
    assert run(ds, perfect, skip_ends=False)["n_samples"] == 12


def test_errors(fake_dataset):
    with pytest.raises(ValueError, match="upsample"):
        run(fake_dataset(), lambda s, f: {"init": np.ones((2, H, W // 2), np.float32)})
    with pytest.raises(ValueError, match="Ncam=2"):
        run(fake_dataset(), lambda s, f: {"init": np.ones((3, H, W), np.float32)})
    with pytest.raises(ValueError, match="max_depth"):
        E.EvalConfig(min_depth=10.0, max_depth=5.0)
    with pytest.raises(ValueError, match="frame_stride"):
        E.EvalConfig(frame_stride=0)
    with pytest.raises(ValueError, match="no frame"):
        E.evaluate(fake_dataset(), perfect, "val", progress=False)


def test_format_tables(fake_dataset):
    m = run(fake_dataset(), perfect)
    txt = T.format_tables(m)
    for s in ("scaling: none", "scaling: median", "scaling: rig_median", "CAM_FRONT_RIGHT", "abs_rel",
              "non_overlap", "Dep Con", "CAM_FRONT->CAM_FRONT_RIGHT"):
        assert s in txt
    with pytest.raises(ValueError, match="stage 'nope'"):
        T.format_tables(m, "nope")


@pytest.fixture
def ramp_dataset(fake_dataset):
    """The fake whose depth rises with the row (5 m at the top ... 16 m at the bottom), all sequences alike."""

    class RampDataset(fake_dataset):
        def read_depth(self, seq, cam_name, frame):
            return np.repeat(np.linspace(5.0, 16.0, H, dtype=np.float32)[:, None], W, axis=1)

    return RampDataset()


def test_constant_depth_reference_hand_values(ramp_dataset):
    ds = ramp_dataset
    g = np.linspace(5.0, 16.0, H)[:-1]  # the bottom row is ego body: never counted
    g = np.repeat(g[:, None], W, axis=1).ravel()
    c = P.median_gt_depth(ds, "train")
    assert c == pytest.approx(np.median(g))
    m = run(ds, P.constant_depth_predictor(ds, c))
    fin = m["stages"]["final"]
    assert list(m["stages"]) == ["constant", "final"]
    assert fin["none"]["mean"]["abs_rel"] == pytest.approx(np.mean(np.abs(c - g) / g))
    # median scaling: the constant becomes each image's gt median, whatever its value
    m2 = run(ds, P.constant_depth_predictor(ds, 3.0 * c))
    assert m2["stages"]["final"]["median"]["mean"]["abs_rel"] == pytest.approx(fin["median"]["mean"]["abs_rel"])
    assert m2["stages"]["final"]["none"]["mean"]["abs_rel"] == pytest.approx(np.mean(np.abs(3 * c - g) / g))


def test_constant_depth_reference_errors(ramp_dataset):
    with pytest.raises(ValueError, match="depth_m"):
        P.constant_depth_predictor(ramp_dataset, 0.0)
    with pytest.raises(ValueError, match="no ground-truth pixel"):
        P.median_gt_depth(ramp_dataset, "train", E.EvalConfig(min_depth=50.0, max_depth=80.0))


def test_cameras_of_different_sizes_are_scored_each_at_its_own_size(fake_dataset):
    """rig.cameras.<CAM>.width: CAM_FRONT_RIGHT at twice CAM_FRONT's size (the same field of view); the
    prediction is a list of one depth map per camera, each at its camera's size."""
    ds = fake_dataset(scale=(1, 2))
    assert [(c.width, c.height) for c in ds.cameras] == [(W, H), (2 * W, 2 * H)]

    def fn(seq, frame):
        d = [np.full((c.height, c.width), Z_WALL, np.float32) for c in ds.cameras]
        return {"init": [d[0], 2 * d[1]], "refine1": d}

    m = run(ds, fn)
    fin, init = m["stages"]["final"], m["stages"]["init"]
    for sc in E.SCALINGS:
        assert fin[sc]["mean"]["abs_rel"] == pytest.approx(0.0, abs=1e-7)
    assert fin["dep_con"]["mean"] == pytest.approx(0.0, abs=1e-7)  # the splat between the two sizes is exact
    assert init["none"]["per_camera"]["CAM_FRONT"]["abs_rel"] == pytest.approx(0.0, abs=1e-7)
    assert init["none"]["per_camera"]["CAM_FRONT_RIGHT"]["abs_rel"] == pytest.approx(1.0)
    assert init["none"]["overlap_per_camera"]["CAM_FRONT_RIGHT"]["abs_rel"] == pytest.approx(1.0)
    for pair in ("CAM_FRONT->CAM_FRONT_RIGHT", "CAM_FRONT_RIGHT->CAM_FRONT"):  # |20 - 10| / 10 both ways
        assert init["dep_con"]["per_pair"][pair] == pytest.approx(1.0)
    with pytest.raises(ValueError, match=r"camera CAM_FRONT_RIGHT: depth must have the dataset resolution "
                                         rf"\({2 * H}, {2 * W}\)"):
        run(ds, lambda s, f: {"init": np.ones((2, H, W), np.float32)})  # one size for both: refused, named


def test_a_toy_metric_is_one_entry_in_the_metrics_table(monkeypatch, fake_dataset):
    """A metric is one `mcdp.metrics.Metric` row: with a toy one added to `METRICS` (and nothing else), the
    evaluation scores it in every scaling and region, the printed tables give it a column, and the trainer's
    validation pools it; its value is the one its term defines (here mean |log10 g - log10 p|)."""
    from mcdp import metrics as M
    from mcdp.validation import DepthAccumulator

    toy = M.Metric("log10", lambda x: np.abs(np.log10(x.g) - np.log10(x.p)))
    monkeypatch.setattr(M, "METRICS", M.METRICS + (toy,))
    assert M.metric_names()[-1] == "log10"
    ds = fake_dataset()

    def double(seq, frame):  # twice the wall's depth everywhere: log10 error log10(2) on every valid pixel
        return {"init": np.full((2, H, W), 2 * Z_WALL, np.float32)}

    m = run(ds, double)
    none = m["stages"]["final"]["none"]
    for region in ("mean", "overlap", "non_overlap"):
        assert none[region]["log10"] == pytest.approx(math.log10(2), rel=1e-6), region
    assert m["stages"]["final"]["median"]["mean"]["log10"] == pytest.approx(0.0, abs=1e-6)  # scaled back
    header = next(line for line in T.format_tables(m).splitlines() if line.startswith("camera"))
    assert header.split()[-1] == "log10"  # the last column of the printed tables
    acc = DepthAccumulator()
    assert acc.sums.shape == (len(M.METRICS) + 1,)
    acc.add(ds, ds.split("test")[0], 1, np.full((2, H, W), 2 * Z_WALL, np.float32), E.EvalConfig())
    assert acc.metrics(acc.sums)["log10"] == pytest.approx(math.log10(2), rel=1e-6)
