"""Yardsticks that need no training: a constant depth and a flat-road prior.

A number without a yardstick says nothing: every learning table and the sweep
report print these next to the trained methods.

- constant: `constant_depth_predictor` with the train split's median
  ground-truth depth (what a depth map without any structure scores).
- flat road: `flat_road_depth` knows the rig (intrinsics, extrinsics, so camera
  height and pitch) and that the road is the plane z = 0 of the ego frame, nothing
  else: a pixel whose ray meets the road gets the road's z-depth, capped at
  ``far``; every other pixel gets ``far``. With ``far`` = the train median depth it
  is "the constant, plus a flat road": what a network must beat to have learned
  more than the ground plane.

Example::

    const = median_gt_depth(ds, "train", cfg)
    metrics = evaluate(ds, flat_road_predictor(ds, const), "test", cfg)
"""
from __future__ import annotations

from typing import TYPE_CHECKING, Callable, Mapping

import numpy as np

from mcdp.config import EvalConfig
from mcdp.metrics import valid_gt_mask
from synth.protocol import pixel_rays_at

if TYPE_CHECKING:
    from synth.protocol import DatasetReader


def flat_road_depth(cam, T_ego_cam: np.ndarray, height: int, width: int, far: float) -> np.ndarray:
    """(height, width) float32 depth of the road plane z_ego = 0 seen by one camera, capped at ``far``: z-depth, or
    range for a camera whose depth kind is range (`synth.camera`).

    Args:
        cam: its lens, a `synth.camera.Intrinsics` at (height, width), or a (3, 3) pinhole K; pixel centres at +0.5.
        T_ego_cam: (4, 4) camera -> ego; ego frame z up, the road at z = 0.
        far: metres, depth of every pixel whose ray does not meet the road nearer than it.
    """
    if not (np.isfinite(far) and far > 0):
        raise ValueError(f"far must be a positive finite depth in metres, got {far}")
    v, u = np.mgrid[0:height, 0:width]
    rays = pixel_rays_at(cam, u.ravel(), v.ravel())  # (3, H*W): z = 1, unit for a range row, NaN: no ray
    T = np.asarray(T_ego_cam, np.float64)
    d = T[:3, :3] @ rays  # ego-frame direction per unit of the camera's depth
    c_z = T[2, 3]
    with np.errstate(divide="ignore", invalid="ignore"):
        t = np.where(d[2] < -1e-9, -c_z / d[2], np.inf)  # the depth where the ray meets z_ego = 0 (no ray: far)
    return np.minimum(t, far).reshape(height, width).astype(np.float32)


def flat_road_predictor(ds, far: float) -> Callable[[str, int], Mapping[str, list]]:
    """A `predict_fn` for `mcdp.evaluate.evaluate`: the flat-road depth of every camera, every frame."""
    maps = [flat_road_depth(c.intrinsics, c.T_ego_cam, int(c.height), int(c.width), far) for c in ds.cameras]
    return lambda seq, frame: {"flat_road": maps}


def median_gt_depth(ds: DatasetReader, split: str = "train", cfg: EvalConfig | None = None) -> float:
    """Median ground-truth depth over a split's evaluable pixels (the constant of the reference predictor).

    Uses the same pixels as `evaluate` (depth range, self-occlusion masks, frame stride,
    skip_ends). It reads ground truth, so the constant-depth predictor built on it is a
    *reference* for reading tables (what a depth map without any structure scores), never a
    method; `study.sweep.stages` takes it from the train split and evaluates it on the test split.

    Raises:
        ValueError: the split has no evaluable pixel.
    """
    from mcdp.evaluate import eval_frames

    cfg = cfg if cfg is not None else EvalConfig()
    names = list(ds.camera_names)
    masks = [np.asarray(ds.mask(n), dtype=bool) for n in names]
    vals = []
    for seq in ds.split(split):
        for f in eval_frames(ds.n_frames(seq), cfg):
            for n, m in zip(names, masks):
                g = np.asarray(ds.read_depth(seq, n, f), dtype=np.float64)
                vals.append(g[valid_gt_mask(g, m, cfg.min_depth, cfg.max_depth)])
    v = np.concatenate(vals) if vals else np.zeros(0)
    if v.size == 0:
        raise ValueError(f"split {split!r} has no ground-truth pixel in [{cfg.min_depth}, {cfg.max_depth}] m")
    return float(np.median(v))


def constant_depth_predictor(ds: DatasetReader, depth_m: float) -> Callable[[str, int], Mapping[str, np.ndarray]]:
    """A `predict_fn` for `evaluate` that predicts `depth_m` metres at every pixel of every camera."""
    if not (np.isfinite(depth_m) and depth_m > 0):
        raise ValueError(f"depth_m must be a positive finite depth in metres, got {depth_m}")
    maps = [np.full((int(c.height), int(c.width)), depth_m, dtype=np.float32) for c in ds.cameras]
    return lambda seq, frame: {"constant": maps}
