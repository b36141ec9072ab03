"""Ground-truth readers: what a yardstick reads of a dataset's depth, at the dataset or a network's size.

Data, not the ORACLE: every reader here reads ground truth, so whatever uses one is a yardstick and says
so (an ORACLE-scaled run, `mcdp.methods.oracle_local`'s input field, the ORACLE weights and propagator of
`mcdp.oracle` and `study.sweep.probes`). Nothing in training or inference reads them unless a `mcdp.inputs.InputField`
with ``truth=True`` is declared.
"""
from __future__ import annotations

import numpy as np
import torch
import torch.nn.functional as F

from synth.overlap import neighbours_of, overlap_union


def gt_median(ds, masks, seq: str, frame: int) -> np.ndarray:
    """(N,) float32: each camera's median ground-truth depth over its scene pixels at the dataset resolution
    (1.0 for a camera without one): the ORACLE scale mode's input (``scale.source=oracle_gt_median``)."""
    med = np.ones(len(ds.camera_names), dtype=np.float32)
    for c, name in enumerate(ds.camera_names):
        d = ds.read_depth(seq, name, frame)
        v = d[(d > 0) & masks[c]]
        if v.size:
            med[c] = float(np.median(v))
    return med


def ground_truth_at(ds, masks, seq: str, frame: int, size: tuple[int, int],
                    depth_range: tuple[float, float]) -> tuple[torch.Tensor, torch.Tensor]:
    """ORACLE input: every camera's ground truth at ``size`` (nearest) and its valid pixels.

    Args:
        ds: a dataset (``camera_names``, ``read_depth``); masks: per camera (H, W) bool scene masks.
        depth_range: (min, max) metres that count, as in the evaluation.
    Returns:
        gt (N, 1, h, w) metres, valid (N, 1, h, w) bool.
    """
    lo, hi = depth_range
    gts, valids = [], []
    for c, name in enumerate(ds.camera_names):
        g = torch.from_numpy(ds.read_depth(seq, name, frame).astype("float32"))[None, None]
        v = (g >= lo) & (g <= hi) & torch.as_tensor(masks[c], dtype=torch.bool)[None, None]
        gts.append(F.interpolate(g, size=size, mode="nearest"))
        valids.append(F.interpolate(v.float(), size=size, mode="nearest") > 0.5)
    return torch.cat(gts), torch.cat(valids)


def camera_poses_at(ds, seq: str, frame: int) -> list[np.ndarray]:
    """Per camera, (4, 4) float64: its true pose at its own trigger time in the ego frame of the frame's time
    (`synth.dataset.Dataset.camera_poses`), the static ``T_ego_cam`` for a reader without per-camera times.
    What the truth of the overlap and Dep Con warp through, whatever a model assumes (``model.sync``)."""
    get = getattr(ds, "camera_poses", None)
    if get is None:
        return [np.asarray(c.T_ego_cam, np.float64) for c in ds.cameras]
    return list(np.asarray(get(seq)[1][frame], np.float64))


def overlap_cameras(cameras) -> list:
    """What `synth.overlap`'s region functions take of each camera (`synth.protocol.Camera`): its lens, an
    `synth.camera.Intrinsics` (the depths compared are of each camera's depth kind), or for a pinhole camera its
    bare K (the table's pinhole row: the arithmetic, and the bytes, of before)."""
    return [np.asarray(c.K, np.float64) if c.intrinsics.model == "pinhole" else c.intrinsics for c in cameras]


def overlap_truth(ds, masks, seq: str, frame: int) -> list:
    """Per camera, (H, W) float32 at the dataset resolution: the ground-truth depth (of the camera's depth kind) of
    its overlap pixels (`synth.overlap.overlap_mask` with every neighbour through each camera's true lens, as the
    evaluation splits its regions), 0 elsewhere (a camera without neighbours: 0 everywhere). ORACLE input: it
    reads ground truth."""
    names = list(ds.camera_names)
    gts = [np.asarray(ds.read_depth(seq, n, frame), np.float64) for n in names]
    cams, Ts = overlap_cameras(ds.cameras), camera_poses_at(ds, seq, frame)
    nbrs = neighbours_of(ds.neighbours, len(names))
    return [np.where(overlap_union(i, gts, cams, Ts, masks, nbrs[i]), gts[i], 0.0).astype(np.float32)
            for i in range(len(names))]


def overlap_truth_at(ds, masks, seq: str, frame: int, size: tuple[int, int]) -> torch.Tensor:
    """(N, 1, h, w) float32: `overlap_truth` at ``size`` (nearest: a depth, never a blend of two)."""
    maps = overlap_truth(ds, masks, seq, frame)
    return torch.cat([F.interpolate(torch.from_numpy(m)[None, None], size=size, mode="nearest") for m in maps])


def overlap_at(ds, masks, seq: str, frame: int, size: tuple[int, int]) -> torch.Tensor:
    """(N, 1, h, w) bool: each camera's overlap pixels at ``size`` (nearest). ORACLE input."""
    return overlap_truth_at(ds, masks, seq, frame, size) > 0
