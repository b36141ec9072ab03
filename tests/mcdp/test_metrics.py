"""Tests for mcdp.metrics: hand-computed metrics, scalings, Dep Con and overlap masks."""
import math

import numpy as np
import pytest
import torch

from mcdp import geometry as G
from mcdp import metrics as M


def test_depth_metrics_hand_computed_2x2():
    gt = np.array([[2.0, 4.0], [8.0, 10.0]])
    pred = np.array([[1.0, 4.0], [10.0, 5.0]])
    valid = np.array([[True, True], [True, False]])
    m = M.depth_metrics(gt, pred, valid)
    assert set(m) == set(M.metric_names())
    assert m["abs_rel"] == pytest.approx((0.5 + 0.0 + 0.25) / 3)
    assert m["sq_rel"] == pytest.approx((0.5 + 0.0 + 0.5) / 3)
    assert m["rmse"] == pytest.approx(math.sqrt(5 / 3))
    assert m["rmse_log"] == pytest.approx(math.sqrt((math.log(2) ** 2 + math.log(0.8) ** 2) / 3))
    # ratios 2, 1, 1.25: 1.25 is not < 1.25
    assert m["a1"] == pytest.approx(1 / 3)
    assert m["a2"] == pytest.approx(2 / 3)
    assert m["a3"] == pytest.approx(2 / 3)


def test_depth_metrics_accepts_torch_float32():
    gt = torch.tensor([[2.0, 4.0], [8.0, 10.0]])
    m = M.depth_metrics(gt, gt * 1.1, torch.ones(2, 2, dtype=torch.bool))
    assert m["abs_rel"] == pytest.approx(0.1, rel=1e-6)


def test_perfect_prediction_and_empty_mask():
    rng = np.random.default_rng(0)
    gt = rng.uniform(1, 50, size=(5, 6))
    m = M.depth_metrics(gt, gt.copy(), np.ones_like(gt, dtype=bool))
    assert m["abs_rel"] == 0 and m["rmse"] == 0 and m["a1"] == 1 and m["a3"] == 1
    e = M.depth_metrics(gt, gt, np.zeros_like(gt, dtype=bool))
    assert all(math.isnan(v) for v in e.values())


def test_depth_metrics_rejects_bad_input():
    gt = np.ones((2, 2))
    with pytest.raises(ValueError, match="pred must have the shape of gt"):
        M.depth_metrics(gt, np.ones((2, 3)), np.ones((2, 2), bool))
    with pytest.raises(ValueError, match="pred must be positive"):
        M.depth_metrics(gt, np.zeros((2, 2)), np.ones((2, 2), bool))


def test_valid_gt_mask_range_and_scene_mask():
    gt = np.array([[0.0, 0.4, 0.5], [80.0, 80.5, 10.0]])
    scene = np.array([[True, True, True], [True, True, False]])
    v = M.valid_gt_mask(gt, scene, 0.5, 80.0)
    assert v.tolist() == [[False, False, True], [True, False, False]]


def test_median_scaling_recovers_factor_two():
    rng = np.random.default_rng(1)
    gt = rng.uniform(2, 40, size=(8, 9))
    valid = np.ones_like(gt, dtype=bool)
    pred = gt / 2.0
    s = M.median_scale(gt, pred, valid)
    assert s == pytest.approx(2.0)
    m = M.depth_metrics(gt, M.clamp_depth(pred * s), valid)
    assert m["abs_rel"] == pytest.approx(0.0, abs=1e-12)
    assert math.isnan(M.median_scale(gt, pred, np.zeros_like(valid)))


def test_rig_median_uses_one_scale_for_all_cameras():
    gts = [np.full((2, 2), 10.0), np.full((1, 5), 10.0)]
    preds = [np.full((2, 2), 5.0), np.full((1, 5), 20.0)]
    valids = [np.ones((2, 2), bool), np.ones((1, 5), bool)]
    # pooled preds: four 5s and five 20s -> median 20 -> scale 0.5 for both cameras
    assert M.rig_median_scale(gts, preds, valids) == pytest.approx(0.5)
    # per-image medians would be 2 and 0.5
    assert M.median_scale(gts[0], preds[0], valids[0]) == pytest.approx(2.0)
    m0 = M.depth_metrics(gts[0], M.clamp_depth(preds[0] * 0.5), valids[0])
    assert m0["abs_rel"] == pytest.approx(0.75)


def test_clamp_after_scaling():
    p = M.clamp_depth(np.array([0.1, 5.0, 100.0, np.nan]), 0.5, 80.0)
    assert p.tolist() == [0.5, 5.0, 80.0, 80.0]


# --------------------------------------------------------------------------- two-camera analytic rig
def two_camera_rig(shift_px=3, H=12, W=16, f=20.0, Z=10.0):
    """Two forward-looking cameras, j to the right of i by b = shift_px * Z / f; wall at depth Z."""
    K = np.array([[f, 0, W / 2], [0, f, H / 2], [0, 0, 1.0]])
    b = shift_px * Z / f
    # OpenCV camera axes in ego (x fwd, y left, z up): x_cam = -y_ego, y_cam = -z_ego, z_cam = x_ego
    R = np.array([[0.0, 0, 1], [-1, 0, 0], [0, -1, 0]])
    T_i = np.eye(4)
    T_i[:3, :3] = R
    T_i[:3, 3] = [0, 0, 1.5]
    T_j = T_i.copy()
    T_j[:3, 3] = [0, -b, 1.5]  # to the right = -y in ego
    gt = np.full((H, W), Z)
    return K, T_i, T_j, gt


def test_dep_con_ground_truth_against_itself_is_zero():
    K, T_i, T_j, gt = two_camera_rig(shift_px=3)
    T_ci_cj = np.linalg.inv(T_i) @ T_j
    t = lambda a: torch.as_tensor(a, dtype=torch.float64)  # noqa: E731
    d_hat, hit = G.splat_depth(t(gt)[None, None], t(K)[None], t(K)[None], t(T_ci_cj)[None], 12, 16)
    d_hat, hit = d_hat[0, 0].numpy(), hit[0, 0].numpy() > 0
    assert hit[:, 3:].all() and not hit[:, :3].any()
    valid = M.valid_gt_mask(gt, None) & hit
    assert M.dep_con(gt, d_hat, gt, valid) < 1e-6
    # a prediction 10% too far in camera i only: Dep Con = |1.1 Z - Z| / Z = 0.1
    assert M.dep_con(gt * 1.1, d_hat, gt, valid) == pytest.approx(0.1)
    assert math.isnan(M.dep_con(gt, d_hat, gt, np.zeros_like(valid)))


def test_dep_con_hand_value():
    d = np.array([[2.0, 4.0]])
    dh = np.array([[3.0, 0.0]])
    g = np.array([[4.0, 4.0]])
    assert M.dep_con(d, dh, g, np.array([[True, False]])) == pytest.approx(0.25)


def test_one_metric_table_serves_the_evaluator_and_the_validation():
    """`METRICS` is the one definition: the per-image reduction (`reduce_terms`) and the pooled sums of the
    trainer's validation (`DepthAccumulator.metrics`) give the same numbers from it, roots included."""
    from mcdp.validation import DepthAccumulator

    rng = np.random.default_rng(0)
    g, p = rng.uniform(1, 80, 500), rng.uniform(1, 80, 500)
    terms = M.metric_terms(g, p)
    assert terms.shape == (len(M.METRICS), 500) and M.metric_names() == tuple(m.name for m in M.METRICS)
    a = M.reduce_terms(terms, None)
    b = DepthAccumulator.metrics(np.append(terms.sum(axis=1), 500))
    assert a == pytest.approx(b, rel=1e-12)
    assert a["rmse"] == pytest.approx(np.sqrt(np.mean((g - p) ** 2)))
    assert [m.name for m in M.METRICS if m.root_after_mean] == ["rmse", "rmse_log"]


def test_a_metric_has_a_direction_and_one_identity(monkeypatch):
    """Each `Metric` says which way is better (a1-a3 higher, the errors lower); a name given twice fails clearly,
    at import (`check_metrics` wraps the table) and when the table is read (`metric_names`), e.g. a toy appended
    twice."""
    assert {m.name: m.better for m in M.METRICS} == {"abs_rel": "lower", "sq_rel": "lower", "rmse": "lower",
                                                     "rmse_log": "lower", "a1": "higher", "a2": "higher", "a3": "higher"}
    assert M.better("median.non_overlap.a2") == "higher" and M.better("dep_con.pair.0-1") == "lower"
    assert M.better_words("none.mean.rmse") == "lower is better"
    with pytest.raises(KeyError, match="'spread.ratio' names no metric"):
        M.better("spread.ratio")
    with pytest.raises(ValueError, match="better='up', must be 'lower' or 'higher'"):
        M.Metric("toy", lambda x: x.d, better="up")
    with pytest.raises(ValueError, match="holds no '.'"):
        M.Metric("toy.acc", lambda x: x.d)
    toy = M.Metric("log10", lambda x: np.abs(np.log10(x.g) - np.log10(x.p)))
    with pytest.raises(ValueError, match="metric 'a1' is given twice"):
        M.check_metrics(M.METRICS + (M.Metric("a1", lambda x: x.thresh < 1.25, better="higher"),))
    monkeypatch.setattr(M, "METRICS", M.METRICS + (toy, toy))
    with pytest.raises(ValueError, match="metric 'log10' is given twice"):
        M.metric_names()
