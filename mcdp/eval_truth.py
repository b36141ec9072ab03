"""What the evaluation (`mcdp.evaluate`) reads once: of the rig (`EvalRig`) and of each test sample (`SampleTruth`, held
by `TruthCache` and shared by every pass and stage scored on the sample, and by the ORACLE stages that read the same
ground truth, `study.sweep.oracle_stages`).

A sample's regions (all, overlap, non_overlap, the distance bands, and with semantic labels the class groups, motion
and the road by band; `mcdp.evaluate`'s module docstring) are kept as one float 0/1 matrix per camera over its valid
pixels, so that a stage's sums of every metric's per-pixel terms over every region are one matrix product.

Example::

    truths = TruthCache(ds, EvalConfig())
    t = truths.get("seq_00001", 3)      # read once; a second get of the same sample returns it
    t.regions, t.R[0].shape              # ("all", "overlap", ...), (len(regions), valid pixels of camera 0)
"""
from __future__ import annotations

import numpy as np

from mcdp.config import EvalConfig
from synth.overlap import BAND_NAMES, distance_bands, overlap_union
from synth import camera
from synth.protocol import DatasetReader

from . import label_regions as LR
from .metrics import valid_gt_mask
from .truth import camera_poses_at, overlap_cameras

#: band regions: pixels binned by their distance to the nearest overlap pixel of the same image
#: (`synth.overlap.distance_bands`; "band0" is the overlap itself)
BANDS = tuple(f"band{k}" for k in range(len(BAND_NAMES)))
REGIONS = ("all", "overlap", "non_overlap") + BANDS


class EvalRig:
    """What `evaluate` reads of the rig once: camera names, sizes, K, each camera's lens (``cams``: its
    `synth.camera.Intrinsics`; ``kinds``: its depth kind, ``z_depth`` or ``range``; ``lens``: (row names, (N, D)
    float64 parameters padded to the longest row) for the Dep Con splat, None for a pinhole rig), T_ego_cam, scene
    masks, and the ordered neighbour pairs (src j, tgt i) with their relative poses T_ci_cj. The overlap regions
    and Dep Con go through each camera's true lens, whatever a model assumed (``model.lens``)."""

    def __init__(self, ds: DatasetReader) -> None:
        self.names = list(ds.camera_names)
        specs = list(ds.cameras)
        self.shapes = [(int(s.height), int(s.width)) for s in specs]
        self.Ks = [np.asarray(s.K, dtype=np.float64) for s in specs]
        self.cams = [s.intrinsics for s in specs]
        self.kinds = [camera.depth_kind(c) for c in self.cams]
        self.overlap_cams = overlap_cameras(specs)  # what synth.overlap takes of each camera
        self.lens = None
        if any(c.model != "pinhole" for c in self.cams):
            D = max(len(c.dist) for c in self.cams)
            self.lens = (tuple(c.model for c in self.cams),
                         np.array([list(c.dist) + [0.0] * (D - len(c.dist)) for c in self.cams], np.float64))
        self.Ts = [np.asarray(s.T_ego_cam, dtype=np.float64) for s in specs]
        self.masks = [np.asarray(ds.mask(n), dtype=bool) for n in self.names]
        for c, (m, shp) in enumerate(zip(self.masks, self.shapes)):
            if m.shape != shp:
                raise ValueError(f"ds.mask({self.names[c]!r}) has shape {m.shape}, camera is {shp}")
        self.pairs = []  # ordered (src j, tgt i)
        for a, b in ds.neighbours:
            self.pairs += [(int(a), int(b)), (int(b), int(a))]
        self.nbrs = {i: sorted({j for j, t in self.pairs if t == i}) for i in range(len(self.names))}
        self.T_c_c = {(i, j): np.linalg.inv(self.Ts[i]) @ self.Ts[j] for j, i in self.pairs}  # T_ci_cj
        self.pair_key = {(j, i): f"{self.names[j]}->{self.names[i]}" for j, i in self.pairs}
        self.labels = LR.LabelIndex.of(ds)  # None: no semantic labels, no class / motion regions


class SampleTruth:
    """One sample's ground truth, read once and shared by every stage and pass scored on it: depth per camera, its
    valid pixels, those pixels' depth and log depth, the overlap, and per camera the region matrix ``R[c]``
    (len(regions), N_c) float 0/1 over the camera's valid pixels (``regions``: all, overlap, non_overlap, the bands,
    and with labels the class groups, motion and the road by band) with its pixel counts ``counts[c]``: a stage's
    per-region sums of every metric's per-pixel terms are then one matrix product per camera (`_score`)."""

    def __init__(self, ds: DatasetReader, rig: EvalRig, seq: str, f: int, cfg: EvalConfig) -> None:
        self.gts = [np.asarray(ds.read_depth(seq, n, f), dtype=np.float64) for n in rig.names]
        for c, g in enumerate(self.gts):
            if g.shape != rig.shapes[c]:
                raise ValueError(f"ds.read_depth({seq!r}, {rig.names[c]!r}, {f}) has shape {g.shape}, expected "
                                 f"{rig.shapes[c]}")
        self.valids = [valid_gt_mask(g, m, cfg.min_depth, cfg.max_depth) for g, m in zip(self.gts, rig.masks)]
        Ts = camera_poses_at(ds, seq, f)  # each camera's own pose at its trigger time: the static rig when synchronous
        self.T_c_c = {(i, j): np.linalg.inv(Ts[i]) @ Ts[j] for j, i in rig.pairs}  # T_ci_cj of this frame (Dep Con)
        overlaps = [overlap_union(i, self.gts, rig.overlap_cams, Ts, rig.masks, rig.nbrs[i])
                    for i in range(len(rig.names))]  # through each camera's lens, depths of its kind
        self.g_v = [g[v] for g, v in zip(self.gts, self.valids)]  # 1-D, float64
        self.lg_v = [np.log(g) for g in self.g_v]
        ov_v = [o[v] for o, v in zip(overlaps, self.valids)]
        sel = {"all": [np.ones(g.size, bool) for g in self.g_v], "overlap": ov_v, "non_overlap": [~o for o in ov_v]}
        bands_v = [distance_bands(o)[v] for o, v in zip(overlaps, self.valids)]
        for k, name in enumerate(BANDS):
            sel[name] = [b == k for b in bands_v]
        self.overlaps = overlaps  # (H, W) bool per camera: the ORACLE of the overlap reads it
        if rig.labels is not None:  # class groups and motion, on the valid pixels
            sels = [rig.labels.selectors(np.asarray(ds.read_semantic(seq, n, f))[v])
                    for n, v in zip(rig.names, self.valids)]
            for r in rig.labels.regions:
                sel[r] = [s[r] for s in sels]
            for b in BANDS:  # the road alone by distance to the overlap: what the neighbours share most
                sel[f"road_{b}"] = [bd & s["class_road"] for bd, s in zip(sel[b], sels)]
        self.regions = tuple(sel)
        self.R = [np.stack([s[c] for s in sel.values()]).astype(np.float64) for c in range(len(rig.names))]
        self.counts = [r.sum(axis=1) for r in self.R]


class TruthCache:
    """The ground truth of the sample under evaluation (`SampleTruth`), read once and shared by every pass and stage that
    `evaluate_passes` scores on it, and by a stage of a predictor that reads the same ground truth (the ORACLE
    stages, `study.sweep.oracle_stages`, through ``get``). Holds one sample: the passes are scored sample by sample."""

    def __init__(self, ds: DatasetReader, cfg: EvalConfig) -> None:
        self.ds, self.cfg, self.rig = ds, cfg, EvalRig(ds)
        self._key: tuple | None = None
        self._truth: SampleTruth | None = None

    def get(self, seq: str, frame: int) -> SampleTruth:
        """The ground truth of sample (seq, frame), read when it is not the one held."""
        if self._key != (seq, frame):
            self._truth, self._key = SampleTruth(self.ds, self.rig, seq, frame, self.cfg), (seq, frame)
        return self._truth
