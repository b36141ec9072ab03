"""Per-sequence sums of a metric, so a reader can resample a split's sequences (a bootstrap over test
sequences, `study.stats.variance`) and recompute the split's figure exactly as `mcdp.evaluate` computes it.

`mcdp.evaluate` averages a metric over images per camera, then over cameras. A sequence's images share its
scene, so sequences, not images, are the independent units of a split. For each scaling, region and sequence
this keeps, per camera, the sum of the metric over that sequence's images and their count (images with no
valid pixel in the region are left out, as the mean leaves them out). For any multiset S of sequences,

    figure(S) = mean over cameras of ( sum_{s in S} sum[s][c] / sum_{s in S} n[s][c] )

and S = every sequence once gives the split's own figure (`resampled`).

Example::

    ps = metrics["stages"]["final"]["median"]["per_sequence"]["non_overlap"]   # {seq: {"sum": [...], "n": [...]}}
    resampled(ps, list(ps))                                                     # == the split's non_overlap abs_rel
"""
from __future__ import annotations

import math
from collections.abc import Iterable, Mapping, Sequence

import numpy as np

#: the regions and the metric kept per sequence (a small record: 3 regions x cameras x sequences per scaling)
REGIONS = ("all", "overlap", "non_overlap")
METRIC = "abs_rel"


def per_sequence(per_image: Mapping[str, Sequence[Sequence[Mapping[str, float]]]], seqs: Sequence[str]) -> dict:
    """``{region: {seq: {"sum": [per camera], "n": [per camera]}}}`` from one scaling's per-image metrics
    ``per_image[region][camera][k]`` (k = the k-th sample, whose sequence is ``seqs[k]``)."""
    arrays = {}
    for region in REGIONS:
        cams = per_image.get(region)
        if cams is None:
            continue
        for c, values in enumerate(cams):
            if len(values) != len(seqs):
                raise ValueError(f"per_sequence: camera {c} of region {region!r} has {len(values)} images, "
                                 f"expected {len(seqs)}")
        arrays[region] = np.array([[_number(m.get(METRIC, math.nan)) for m in values] for values in cams],
                                  dtype=np.float64).T.reshape(len(seqs), len(cams))
    return per_sequence_arrays(arrays, seqs)


def _number(v) -> float:
    return float(v) if isinstance(v, (int, float)) else math.nan


def per_sequence_arrays(values: Mapping[str, np.ndarray], seqs: Sequence[str]) -> dict:
    """`per_sequence` from ``values[region]``: (images, cameras) float, image k of sequence ``seqs[k]``; a value
    that is not finite is left out. The sums run over a sequence's images in order (as a loop adds them)."""
    out: dict = {}
    for region in REGIONS:
        v = values.get(region)
        if v is None:
            continue
        v = np.asarray(v, dtype=np.float64)
        if v.shape[0] != len(seqs):
            raise ValueError(f"per_sequence: region {region!r} has {v.shape[0]} images, expected {len(seqs)}")
        ok = np.isfinite(v)
        rec: dict = {}
        for seq in dict.fromkeys(seqs):  # first-seen order
            rows = [k for k, s in enumerate(seqs) if s == seq]
            total = np.zeros(v.shape[1])
            for k in rows:  # in image order, as the per-image loop summed them
                total += np.where(ok[k], v[k], 0.0)
            rec[seq] = {"sum": [float(x) for x in total], "n": [int(x) for x in ok[rows].sum(axis=0)]}
        out[region] = rec
    return out


def resampled(rec: Mapping[str, Mapping[str, Sequence[float]]], seqs: Iterable[str]) -> float:
    """The region's figure over the multiset ``seqs`` of sequences (repeats count again): mean over cameras of
    the pooled per-image mean; NaN where no camera has an image."""
    sums: list[float] | None = None
    ns: list[float] | None = None
    for s in seqs:
        r = rec[s]
        if sums is None:
            sums, ns = [0.0] * len(r["sum"]), [0.0] * len(r["n"])
        for c, (a, k) in enumerate(zip(r["sum"], r["n"])):
            sums[c] += a
            ns[c] += k
    if not sums:
        return math.nan
    per_cam = [a / k for a, k in zip(sums, ns) if k > 0]
    return math.fsum(per_cam) / len(per_cam) if per_cam else math.nan
