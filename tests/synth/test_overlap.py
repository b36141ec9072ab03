"""The one overlap definition (synth.overlap): frustum, ego mask on both sides, z-test."""
from __future__ import annotations

import numpy as np
import pytest

from synth.overlap import overlap_mask


def two_camera_rig(shift_px=3, H=12, W=16, f=20.0, Z=10.0):
    """Two forward-looking cameras, j to the right of i by b = shift_px * Z / f; a wall at depth Z."""
    K = np.array([[f, 0, W / 2], [0, f, H / 2], [0, 0, 1.0]])
    b = shift_px * Z / f
    R = np.array([[0.0, 0, 1], [-1, 0, 0], [0, -1, 0]])  # OpenCV camera axes in ego (x fwd, y left, z up)
    T_i = np.eye(4)
    T_i[:3, :3] = R
    T_i[:3, 3] = [0, 0, 1.5]
    T_j = T_i.copy()
    T_j[:3, 3] = [0, -b, 1.5]  # to the right = -y in ego
    return K, T_i, T_j, np.full((H, W), Z)


def test_frustum_hand_computed_both_directions():
    K, T_i, T_j, gt = two_camera_rig(shift_px=3)
    ov = overlap_mask(gt, K, T_i, gt, K, T_j)
    # u_j = u_i - 3: columns 0..2 of camera i fall left of camera j's image
    assert ov[:, :3].sum() == 0 and ov[:, 3:].all()
    ov_j = overlap_mask(gt, K, T_j, gt, K, T_i)
    assert ov_j[:, 13:].sum() == 0 and ov_j[:, :13].all()


def test_ego_masks_of_both_cameras_and_missing_depth_exclude_pixels():
    K, T_i, T_j, gt = two_camera_rig(shift_px=3)
    gt0 = gt.copy()
    gt0[0, 5] = 0                       # no surface in i: never overlap
    mask_j = np.ones((12, 16), bool)
    mask_j[-2:, :] = False              # j's ego body on its two bottom rows
    mask_i = np.ones((12, 16), bool)
    mask_i[5, 7] = False                # i's own ego body
    ov = overlap_mask(gt0, K, T_i, gt, K, T_j, mask_i=mask_i, mask_j=mask_j)
    assert not ov[0, 5] and not ov[5, 7] and not ov[-2:].any()
    assert ov[:-2, 3:].sum() == 10 * 13 - 2


def test_a_point_hidden_behind_a_nearer_object_in_j_is_not_overlap():
    K, T_i, T_j, gt = two_camera_rig(shift_px=3)
    gt_j = gt.copy()
    gt_j[:, 4:9] = 4.0                  # j sees a pole at 4 m in front of the wall (10 m) on columns 4..8
    ov = overlap_mask(gt, K, T_i, gt_j, K, T_j)
    # i's columns u_i = u_j + 3: 3 + 4 .. 3 + 8 land on the pole in j, and the 3x3 maximum keeps the
    # pole's edge columns (j's 4 and 8, i's 7 and 11) overlapping: only i's columns 8..10 are hidden
    hidden = ~ov[:, 3:]
    assert hidden[:, 8 - 3:11 - 3].all() and hidden.sum() == 3 * 12
    # sky in j (no surface) hides nothing behind it: it fails the z-test
    gt_sky = gt.copy()
    gt_sky[:, :] = 0
    assert not overlap_mask(gt, K, T_i, gt_sky, K, T_j).any()


@pytest.mark.parametrize("tol, expect", [(0.0, False), (0.05, True)])
def test_the_z_test_tolerance_is_relative(tol, expect):
    K, T_i, T_j, gt = two_camera_rig(shift_px=0)
    gt_j = gt / 1.03                    # j's surface 3 % nearer than i's point
    assert overlap_mask(gt, K, T_i, gt_j, K, T_j, z_tol=tol).all() == expect


def test_shapes_are_checked_naming_the_argument():
    K, T_i, T_j, gt = two_camera_rig()
    with pytest.raises(ValueError, match="mask_j"):
        overlap_mask(gt, K, T_i, gt, K, T_j, mask_j=np.ones((3, 3), bool))
    with pytest.raises(ValueError, match="K_j"):
        overlap_mask(gt, K, T_i, gt, np.eye(4), T_j)


def _reference_overlap_mask(gi, Ki, Ti, gj, Kj, Tj, mi, mj, z_tol=0.05):
    """The definition as first written (one 3x3 gather per point), kept to pin the faster code to it."""
    (H, W), (Hj, Wj) = gi.shape, gj.shape
    valid = (gi > 0) & mi
    v, u = np.nonzero(valid)
    z = gi[v, u]
    pts = (np.linalg.inv(Ki) @ np.stack([u + 0.5, v + 0.5, np.ones_like(z)])) * z
    T_j_i = np.linalg.inv(Tj) @ Ti
    pj = T_j_i[:3, :3] @ pts + T_j_i[:3, 3:4]
    zj = pj[2]
    front = zj > 1e-6
    uvw = Kj @ pj
    zs = np.where(front, zj, 1.0)
    uj, vj = uvw[0] / zs, uvw[1] / zs
    ok = front & (uj >= 0) & (uj < Wj) & (vj >= 0) & (vj < Hj)
    col = np.clip(np.floor(np.where(ok, uj, 0)).astype(np.int64), 0, Wj - 1)
    row = np.clip(np.floor(np.where(ok, vj, 0)).astype(np.int64), 0, Hj - 1)
    ok &= mj[row, col]
    pad = np.pad(gj, 1, mode="constant")
    near = np.max(np.stack([pad[row + dr, col + dc] for dr in range(3) for dc in range(3)]), axis=0)
    ok &= (near > 0) & (zj <= (1.0 + z_tol) * near)
    out = np.zeros((H, W), bool)
    out[v[ok], u[ok]] = True
    return out


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_rig_counts_equal_the_pairwise_masks_and_the_first_definition(seed):
    """`overlap_fraction_counts` (points and 3x3 maxima once per camera) gives exactly the counts of
    `overlap_mask` pair by pair and of the per-point gather it replaced, on a real rig with sky, ego
    body, walls at random depths and pixels on the image border."""
    from synth.config import load_data_config
    from synth.overlap import overlap_fraction_counts
    from synth.render import make_rig

    rig = make_rig(load_data_config("configs/data/tiny.yaml"))
    rng = np.random.default_rng(seed)
    H, W = rig.cameras[0].height, rig.cameras[0].width
    depths, masks = {}, {}
    for cam in rig.cameras:
        d = np.repeat(rng.uniform(2.0, 60.0, (H // 4, W // 8)), 4, 0).repeat(8, 1).astype(np.float32)
        d *= rng.uniform(0.97, 1.03, d.shape).astype(np.float32)     # near the z-test's 5 % edge
        d[: int(rng.integers(0, H // 2))] = 0                           # sky
        depths[cam.name] = d
        m = np.full((H, W), 255, np.uint8)
        m[H - int(rng.integers(0, 8)):, :] = 0                          # ego body
        masks[cam.name] = m
    counts = overlap_fraction_counts(depths, masks, rig.cameras, rig.neighbours)
    assert len(counts) == 2 * len(rig.neighbours)
    for a, b in rig.neighbours:
        for i, j in ((a, b), (b, a)):
            ci, cj = rig.cameras[i], rig.cameras[j]
            gi, gj = depths[ci.name].astype(np.float64), depths[cj.name].astype(np.float64)
            mi, mj = masks[ci.name] > 127, masks[cj.name] > 127
            ov = overlap_mask(gi, ci.K, ci.T_ego_cam, gj, cj.K, cj.T_ego_cam, mask_i=mi, mask_j=mj)
            ref = _reference_overlap_mask(gi, ci.K, ci.T_ego_cam, gj, cj.K, cj.T_ego_cam, mi, mj)
            assert np.array_equal(ov, ref)
            assert counts[f"{ci.name}->{cj.name}"] == [int(((gi > 0) & mi).sum()), int(ref.sum())]
    assert sum(n for _, n in counts.values()) > 0


@pytest.mark.parametrize("overlap", [0.10, 0.30, 0.60])
def test_pixels_left_out_as_never_candidates_land_outside_the_other_camera_at_200_depths(overlap):
    """`overlap_fraction_counts` only projects the pixels `_candidates` keeps: every other pixel's ray, at
    200 log-spaced depths from 1 cm to 10 km, lands behind camera j or outside its image, while the
    candidates are a strict subset on the rig (the saving is real)."""
    from synth.config import load_data_config
    from synth.overlap import EPS_Z, _candidates, _rays
    from synth.render import make_rig

    rig = make_rig(load_data_config("configs/data/tiny.yaml", [f"rig.overlap={overlap}"]))
    t = np.logspace(-2, 4, 200)
    kept = []
    for a, b in rig.neighbours:
        for i, j in ((a, b), (b, a)):
            ci, cj = rig.cameras[i], rig.cameras[j]
            cand = _candidates(ci, cj)
            out = np.setdiff1d(np.arange(ci.width * ci.height), cand)
            T = np.linalg.inv(cj.T_ego_cam) @ ci.T_ego_cam
            p = T[:3, :3] @ _rays(ci.K, ci.height, ci.width)[:, out]            # (3, P) direction, at depth 1
            pts = p[:, :, None] * t + T[:3, 3][:, None, None]                  # (3, P, D)
            z = pts[2]
            uvw = np.einsum("rc,cpd->rpd", cj.K, pts)
            with np.errstate(divide="ignore", invalid="ignore"):
                u, v = uvw[0] / z, uvw[1] / z
            inside = (z > EPS_Z) & (u >= 0) & (u < cj.width) & (v >= 0) & (v < cj.height)
            assert not inside.any(), f"{ci.name}->{cj.name}: a left-out pixel lands inside"
            kept.append(cand.size / (ci.width * ci.height))
    assert max(kept) < 0.9 and sum(k > 0 for k in kept) >= 4


def _random_camera(rng, name: str, centre=None):
    import types

    W, H = int(rng.integers(8, 48)), int(rng.integers(8, 48))
    fx = rng.uniform(3, 80)
    K = np.array([[fx, rng.uniform(-5, 5) if rng.random() < 0.3 else 0.0, rng.uniform(-0.5, 1.5) * W],
                  [0.0, fx * rng.uniform(0.5, 2), rng.uniform(-0.5, 1.5) * H], [0.0, 0.0, 1.0]])
    if rng.random() < 0.25:  # not a pinhole's last row: depth stays z = p_2 (`_seen_by_j`), not (K p)_2
        K[2] = [0.0, 0.0, rng.choice([0.3, 0.5, 2.0])]
    q = rng.standard_normal(4)
    w, x, y, z = q / np.linalg.norm(q)
    T = np.eye(4)
    T[:3, :3] = [[1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
                 [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
                 [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)]]
    T[:3, 3] = rng.standard_normal(3) * rng.choice([0.01, 1.0, 10.0]) if centre is None else centre
    return types.SimpleNamespace(name=name, width=W, height=H, K=K, T_ego_cam=T)


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_rig_counts_equal_the_pairwise_masks_for_random_cameras(seed):
    """The exact property behind the candidate pruning: for random pinhole cameras (any sizes, fx != fy,
    skew, principal points off the image, shared centres, a few with another last row of K) and depths from 1 mm to 100 km, the counts of
    `overlap_fraction_counts` equal those of `overlap_mask` pair by pair. Half the cases give camera j a
    depth of 1e9 m, so only the view-cone geometry decides."""
    from synth.overlap import overlap_fraction_counts

    rng = np.random.default_rng(seed)
    hits = 0
    for _ in range(40):
        ci = _random_camera(rng, "a")
        cj = _random_camera(rng, "b", centre=ci.T_ego_cam[:3, 3] if rng.random() < 0.2 else None)
        depths, masks = {}, {}
        for c in (ci, cj):
            d = np.exp(rng.uniform(np.log(1e-3), np.log(1e5), (c.height, c.width)))
            d[rng.random(d.shape) < 0.1] = 0
            depths[c.name] = d.astype(np.float32) if rng.random() < 0.5 else d
            masks[c.name] = np.where(rng.random(d.shape) < 0.9, 255, 0).astype(np.uint8)
        if rng.random() < 0.5:
            depths["b"] = np.full((cj.height, cj.width), 1e9, depths["b"].dtype)
        counts = overlap_fraction_counts(depths, masks, [ci, cj], [(0, 1)])
        for x, y in ((ci, cj), (cj, ci)):
            ov = overlap_mask(np.asarray(depths[x.name], np.float64), x.K, x.T_ego_cam,
                              np.asarray(depths[y.name], np.float64), y.K, y.T_ego_cam,
                              mask_i=masks[x.name] > 127, mask_j=masks[y.name] > 127)
            assert counts[f"{x.name}->{y.name}"][1] == int(ov.sum())
            hits += int(ov.sum()) > 0
    assert hits >= 3  # the cases are not all empty


def test_distance_bands_partition_the_image_and_the_overlap_is_band_zero():
    from synth.overlap import BAND_EDGES, BAND_NAMES, distance_bands, distance_to_overlap

    rng = np.random.default_rng(3)
    for W in (96, 320):
        H = W * 2 // 3
        ov = np.zeros((H, W), bool)
        ov[:, : W // 8] = True  # a left overlap strip
        ov[rng.integers(0, H), rng.integers(W // 2, W)] = True  # and one lone pixel
        d = distance_to_overlap(ov)
        b = distance_bands(ov)
        assert (d[ov] == 0).all() and (d[~ov] > 0).all()
        assert (b[ov] == 0).all() and (b[~ov] > 0).all()
        assert set(np.unique(b)) <= set(range(len(BAND_NAMES)))  # every pixel in exactly one band
        # a pixel on row 0 at column c of the strip's right: distance c - (W//8 - 1), its band by that / W
        for c in (W // 8, W // 8 + int(0.15 * W), W - 1):
            dist = c - (W // 8 - 1)
            assert d[0, c] == pytest.approx(dist, abs=0.01) or d[0, c] < dist  # the lone pixel may be nearer
        frac = d / W
        for k, hi in enumerate(BAND_EDGES, start=1):
            lo = 0.0 if k == 1 else BAND_EDGES[k - 2]
            sel = b == k
            assert ((frac[sel] > lo) & (frac[sel] <= hi)).all()
        assert (frac[b == len(BAND_EDGES) + 1] > BAND_EDGES[-1]).all()
    none = distance_bands(np.zeros((8, 12), bool))
    assert (none == len(BAND_NAMES) - 1).all()  # an image without overlap: all in the last band


def test_the_summaries_neighbours_union_and_pair_means():
    """The summaries every caller shares (synth.overlap): who neighbours whom, the union over them, per-pair
    and target-pair means; hand-computed."""
    from synth.overlap import neighbours_of, overlap_union, overlaps_by_neighbour, pair_overlaps, target_pair_mean

    ring = [(0, 1), (1, 2), (2, 3), (3, 4), (4, 5), (5, 0)]
    nb = neighbours_of(ring, 6)
    assert nb[0] == [1, 5] and nb[3] == [2, 4] and all(len(n) == 2 for n in nb)
    assert neighbours_of([(0, 1), (1, 0)], 3) == [[1], [0], []]  # a pair listed twice counts once; 2 has none
    # camera 0 between a neighbour 3 px to its right (1) and one 3 px to its left (2)
    K, T0, T1, gt = two_camera_rig(shift_px=3)
    T2 = T0.copy()
    T2[:3, 3] = 2 * T0[:3, 3] - T1[:3, 3]
    depths, Ks, Ts = [gt, gt, gt], [K, K, K], [T0, T1, T2]
    by = overlaps_by_neighbour(0, depths, Ks, Ts, None, [1, 2])
    assert by[0][:, :3].sum() == 0 and by[0][:, 3:].all() and by[1][:, 13:].sum() == 0 and by[1][:, :13].all()
    union = overlap_union(0, depths, Ks, Ts, None, [1, 2])
    assert union.all() and (union == (by[0] | by[1])).all()
    assert not overlap_union(0, depths, Ks, Ts, None, []).any()  # no neighbour: no overlap
    pp = pair_overlaps({"A->B": [100, 30], "B->A": [50, 10], "B->C": [0, 0]}, ["A", "B", "C"], [(0, 1), (1, 2)])
    assert pp["A-B"] == pytest.approx({"measured": 0.25, "A->B": 0.3, "B->A": 0.2})
    assert np.isnan(pp["B-C"]["B->C"]) and np.isnan(pp["B-C"]["measured"])  # no valid pixels: no number
    per_pair = {"A-B": {"target": 0.3, "measured": 0.2}, "B-C": {"target": 0.3, "measured": 0.4},
                "C-D": {"target": -0.1, "measured": 0.0}, "D-E": {"target": 0.3, "measured": float("nan")}}
    assert target_pair_mean(per_pair, 0.3) == (pytest.approx(0.3), 2)  # the gap pair and NaN are left out
    m, n = target_pair_mean(per_pair, 0.5)
    assert np.isnan(m) and n == 0


def test_the_overlap_knob_is_a_typed_record_with_the_pairs_target():
    """`OverlapKnob.of` reads a manifest's overlap record: an angle knob's pairs sit at the target, a pixel knob's
    at the calibrated layout's geometric overlap; a record from before the knob reads as angle; another knob is
    one line naming it."""
    from synth.overlap import OverlapKnob

    assert OverlapKnob.of({"target": 0.3, "knob": "angle", "geometric": 0.3}).pair_target == 0.3
    px = OverlapKnob.of({"target": 0.2, "knob": "pixels", "geometric": 0.27})
    assert px.knob == "pixels" and px.pair_target == 0.27 and px.target == 0.2
    old = OverlapKnob.of({"target": 0.25})
    assert old.knob == "angle" and old.pair_target == 0.25 and old.geometric == 0.25
    with pytest.raises(ValueError, match="knob must be angle or pixels, got 'degrees'"):
        OverlapKnob.of({"target": 0.25, "knob": "degrees"})
