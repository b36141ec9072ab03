"""Generator-trainer convention test: the renderer's depth, K, extrinsics and odometry agree with mcdp.geometry.

Warp one rendered camera into its neighbour (and one frame into the next)
with ground-truth depth and the stored transforms: the photometric error on
the overlap must be small, and clearly larger once the transform is perturbed.
If a sign, an axis or the +0.5 pixel-centre convention differed between
`synth` and `mcdp`, the unperturbed error would be as large as the perturbed one.
"""
from __future__ import annotations

import math

import numpy as np
import pytest
import torch

from mcdp.geometry import warp_by_depth
from mcdp.losses import photometric_error
from mcdp.rigid import odometry_camera_motion


def _yaw(T: np.ndarray, deg: float) -> np.ndarray:
    """T with an extra rotation of `deg` about the camera's y axis (a yaw error of the mounting)."""
    a = math.radians(deg)
    R = np.array([[math.cos(a), 0, math.sin(a)], [0, 1, 0], [-math.sin(a), 0, math.cos(a)]])
    out = T.copy()
    out[:3, :3] = T[:3, :3] @ R
    return out


def _t(x) -> torch.Tensor:
    return torch.as_tensor(np.asarray(x), dtype=torch.float64)


def _warp_error(ds, seq, frame_tgt, cam_tgt, frame_src, cam_src, T_src_tgt):
    """Mean L1 colour error (after per-channel gain matching) and pixel count on target pixels seeing the source.

    The renderer gives every camera its own exposure and white balance (as real
    rigs do), so colours are compared after matching the per-channel mean gain
    over the overlap; geometry errors cannot be compensated that way.
    """
    names = ds.camera_names
    ci, cj = ds.cameras[names.index(cam_tgt)], ds.cameras[names.index(cam_src)]
    tgt = _t(ds.read_rgb(seq, cam_tgt, frame_tgt)).permute(2, 0, 1)[None] / 255
    src = _t(ds.read_rgb(seq, cam_src, frame_src)).permute(2, 0, 1)[None] / 255
    depth = _t(ds.read_depth(seq, cam_tgt, frame_tgt))[None, None]
    m_src = _t(ds.mask(cam_src).astype(np.float64))[None, None]
    warped, valid = warp_by_depth(torch.cat([src, m_src], 1), depth, _t(ci.K)[None], _t(cj.K)[None], _t(T_src_tgt)[None])
    use = (valid > 0) & (depth > 0) & (warped[:, 3:] > 0.999) & torch.from_numpy(ds.mask(cam_tgt))[None, None]
    use = use[0, 0]
    n = int(use.sum())
    if n == 0:
        return float("nan"), 0
    t, w = tgt[0][:, use], warped[0, :3][:, use]  # (3, n)
    gain = t.mean(1, keepdim=True) / w.mean(1, keepdim=True).clamp(min=1e-6)
    return float((t - w * gain).abs().mean()), n


def _best_pair(ds, seq):
    """The adjacent pair with the most overlap pixels (spacing-mode rings may not close)."""
    best = None
    names = ds.camera_names
    for i, j in ds.neighbours:
        Ti, Tj = np.asarray(ds.cameras[i].T_ego_cam), np.asarray(ds.cameras[j].T_ego_cam)
        _, n = _warp_error(ds, seq, 1, names[i], 1, names[j], np.linalg.inv(Tj) @ Ti)
        if best is None or n > best[2]:
            best = (i, j, n)
    return best


def test_cross_camera_warp_with_gt_depth_matches_on_the_overlap(tiny_dataset):
    from synth.open import open_dataset

    ds = open_dataset(tiny_dataset)
    seq = ds.split("train")[0]
    i, j, n = _best_pair(ds, seq)
    assert n > 50, "the tiny rig must have an overlap between some neighbours"
    names = ds.camera_names
    Ti, Tj = np.asarray(ds.cameras[i].T_ego_cam), np.asarray(ds.cameras[j].T_ego_cam)
    good, n_good = _warp_error(ds, seq, 1, names[i], 1, names[j], np.linalg.inv(Tj) @ Ti)
    bad, _ = _warp_error(ds, seq, 1, names[i], 1, names[j], np.linalg.inv(_yaw(Tj, 2.0)) @ Ti)
    assert good < 0.06, f"{names[j]} -> {names[i]}: error {good:.3f} on {n_good} overlap pixels"
    assert bad > 1.5 * good, f"a 2 deg extrinsic error should be clearly worse: {bad:.3f} vs {good:.3f}"


@pytest.mark.parametrize("offset", [-1, 1])
def test_temporal_warp_with_gt_depth_and_odometry(tiny_dataset, offset):
    """Same camera, frame t+offset -> t, with the odometry motion mcdp uses for scale.source=odometry."""
    from synth.open import open_dataset

    ds = open_dataset(tiny_dataset)
    seq = ds.split("train")[0]
    Tw = torch.from_numpy(ds.T_world_ego(seq)[[0, 1, 2]])[None]  # frames t-1, t, t+1 with t = 1
    c = 1  # a side camera: forward motion gives lateral parallax (the front camera sees little)
    name = ds.camera_names[c]
    Tc = torch.from_numpy(np.asarray(ds.cameras[c].T_ego_cam))[None, None]
    T = odometry_camera_motion(Tw, Tc, offset)[0, 0].numpy()
    good, n = _warp_error(ds, seq, 1, name, 1 + offset, name, T)
    still, _ = _warp_error(ds, seq, 1, name, 1 + offset, name, np.eye(4))  # pretend the car did not move
    backwards, _ = _warp_error(ds, seq, 1, name, 1 + offset, name, np.linalg.inv(T))  # wrong direction
    assert n > 500
    assert good < 0.06, f"temporal warp error {good:.3f}"
    assert still > 1.5 * good, f"ignoring the ego motion should be clearly worse: {still:.3f} vs {good:.3f}"
    assert backwards > 1.5 * good, f"the inverse motion should be clearly worse: {backwards:.3f} vs {good:.3f}"
