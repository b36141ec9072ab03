"""Evaluation regions that come from a dataset's semantic labels (`synth.protocol.DatasetReader.read_semantic`):
the class groups, static against moving pixels, and the "infinite depth" hole on moving objects.

Groups are those of the dataset's own class table (``classes[].group``, in the table's order; a rendered
dataset's: road, other, building, vegetation, vehicle; `NOT_EVALUATED`: sky has no depth and the ego body is
masked), so the evaluation knows no generator's class list; road and vehicle must be there. Vehicles are also split
into parked and moving (classes ``parked_vehicle`` / ``moving_vehicle``). Motion: ``moving`` = the pixels
of moving objects (class ``moving_vehicle``, exactly the movers' pixels), ``static`` = every other valid
pixel.

The hole: self-supervised depth pushes objects that move with the camera towards infinite depth (their
photometric loss is lowest there). `HOLE_RATIO`: the share of a class's valid pixels predicted farther than
twice their true depth (after the scaling); moving vehicles against parked ones, the same object kind
standing still, as the yardstick.

Example::

    index = LabelIndex(ds.classes)            # None-safe: LabelIndex.of(ds) is None without semantic labels
    sel = index.selectors(sem_on_valid_pixels)   # {"class_road": bool (N,), ..., "moving": ..., "static": ...}
"""
from __future__ import annotations

import numpy as np

#: groups of a class table that are never evaluated (docs/DATASET.md): sky has no depth, the ego body is masked
NOT_EVALUATED = ("sky", "ego")
MOTIONS = ("static", "moving")
HOLE_RATIO = 2.0
HOLE_KINDS = ("moving", "parked")
#: the region of each hole kind (`HOLE_KINDS` order)
HOLE_REGIONS = ("class_vehicle_moving", "class_vehicle_parked")


class LabelIndex:
    """Which class indices make each region, read from a class table (index, name, group)."""

    def __init__(self, classes: list[dict]) -> None:
        n = len(classes)
        group = np.array([str(c.get("group", "")) for c in classes], dtype=object)
        names = [str(c.get("name", "")) for c in classes]

        def of(pred) -> np.ndarray:
            return np.array([bool(pred(i)) for i in range(n)] + [False], bool)  # +1: an index beyond the table

        table_groups = [g for g in dict.fromkeys(group) if g and g not in NOT_EVALUATED]  # its order, each once
        #: the table's evaluation groups, the vehicles also split parked / moving
        self.groups = tuple(g for t in table_groups
                            for g in (t, *(("vehicle_parked", "vehicle_moving") if t == "vehicle" else ())))
        missing = [g for g in ("road", "vehicle") if g not in self.groups]
        if missing:
            raise ValueError(f"the dataset's class table has no {' or '.join(map(repr, missing))} group: the "
                             "evaluation's road bands and vehicle holes read them (its groups: "
                             f"{', '.join(map(str, dict.fromkeys(group)))[:200]})")
        #: the regions this table gives: a class group's pixels, then the motions
        self.regions = tuple(f"class_{g}" for g in self.groups) + MOTIONS
        self.lut = {f"class_{g}": of(lambda i, g=g: group[i] == g) for g in table_groups}
        self.lut["class_vehicle_parked"] = of(lambda i: names[i] == "parked_vehicle")
        self.lut["class_vehicle_moving"] = of(lambda i: names[i] == "moving_vehicle")
        self.lut["moving"] = self.lut["class_vehicle_moving"]
        self.n = n

    @staticmethod
    def of(ds) -> "LabelIndex | None":
        """The index of `ds`'s class table, None when it has no semantic labels."""
        return LabelIndex(ds.classes) if "semantic" in ds.label_kinds else None

    def selectors(self, sem: np.ndarray) -> dict[str, np.ndarray]:
        """{region: bool array like `sem`} for class indices `sem` (any shape)."""
        idx = np.minimum(sem.astype(np.int64), self.n)
        out = {r: self.lut[r][idx] for r in self.regions if r != "static"}
        out["static"] = ~out["moving"]
        return out


def hole_counts(pred: np.ndarray, gt: np.ndarray, sel: dict[str, np.ndarray]) -> dict[str, tuple[int, int]]:
    """{kind: (pixels predicted beyond HOLE_RATIO x their depth, pixels)} for moving and parked vehicles."""
    far = pred > HOLE_RATIO * gt
    out = {}
    for kind, region in zip(HOLE_KINDS, HOLE_REGIONS):
        s = sel[region]
        out[kind] = (int(np.count_nonzero(far & s)), int(np.count_nonzero(s)))
    return out


def hole_summary(counts: dict[str, list[int]]) -> dict:
    """The hole record of one scaling: fractions (NaN without pixels of the kind) and pixel counts."""
    out: dict = {"ratio": HOLE_RATIO}
    for kind in HOLE_KINDS:
        n_far, n = counts.get(kind, (0, 0))
        out[kind] = float(n_far / n) if n else float("nan")
        out[f"{kind}_pixels"] = int(n)
    return out
