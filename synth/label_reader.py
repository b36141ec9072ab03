"""Reading a rendered dataset's labels (`synth.labels` writes them; layout: docs/DATASET.md): semantic class
maps, object ids, forward flow with its validity, the moving-object mask and each sequence's object table.

A dataset rendered before the labels existed (or with ``labels.<kind>=false``) has none of that kind; asking
for it raises a `DatasetError` that says what the dataset lacks and how to get it. `NoLabels` is the same
answer for readers of formats without labels (a nuScenes dataroot).

Example::

    if "semantic" in ds.label_kinds:
        sem = ds.read_semantic(seq, "CAM_FRONT", 0)       # (H, W) uint8, ds.classes[i]["name"]
"""
from __future__ import annotations

from pathlib import Path

import numpy as np

from synth.files import DatasetError, frame_stem, read_flow_exr, read_json, read_png


def lacks(root, kind: str) -> DatasetError:
    return DatasetError(f"{root}: has no {kind} labels (rendered before labels existed, or with "
                        f"labels.{kind}=false); render it again with labels.{kind}=true to get them")


class NoLabels:
    """The label members of `synth.protocol.DatasetReader` for a dataset that has none."""

    @property
    def label_kinds(self) -> tuple[str, ...]:
        return ()

    @property
    def classes(self) -> list[dict]:
        return []

    def read_semantic(self, seq: str, cam: str, frame: int) -> np.ndarray:
        raise lacks(self.root, "semantic")

    def read_instance(self, seq: str, cam: str, frame: int) -> np.ndarray:
        raise lacks(self.root, "instance")

    def read_movers(self, seq: str, cam: str, frame: int) -> np.ndarray:
        raise lacks(self.root, "flow")

    def read_flow(self, seq: str, cam: str, frame: int) -> tuple[np.ndarray, np.ndarray]:
        raise lacks(self.root, "flow")

    def instances(self, seq: str) -> list[dict]:
        raise lacks(self.root, "instance")


class LabelReader:
    """The label members of `synth.dataset.Dataset` (it supplies root, manifest, inside, _size, _sized)."""

    @property
    def label_kinds(self) -> tuple[str, ...]:
        """The labels every sequence holds: some of ("semantic", "instance", "flow"); () before labels."""
        rec = self.manifest.get("labels")
        kinds = rec.get("kinds") if isinstance(rec, dict) else None
        return tuple(k for k in ("semantic", "instance", "flow") if isinstance(kinds, list) and k in kinds)

    @property
    def classes(self) -> list[dict]:
        """The class table (index, name, color, group) of the semantic maps ([] without them)."""
        if "semantic" not in self.label_kinds:
            return []
        table = self.manifest["labels"].get("classes")
        if not isinstance(table, list) or not all(isinstance(c, dict) and isinstance(c.get("name"), str)
                                                 and c.get("index") == i for i, c in enumerate(table)):
            raise DatasetError(f"{self.root / 'manifest.json'}: labels.classes must list index (0, 1, ...), name, "
                               "color, group")
        return table

    def _label(self, kind: str, seq: str, cam: str, frame: int, suffix: str) -> Path:
        if kind not in self.label_kinds:
            raise lacks(self.root, kind)
        return self.inside(self.root / seq / cam / f"{frame_stem(frame)}.{suffix}")

    def read_semantic(self, seq: str, cam: str, frame: int) -> np.ndarray:
        """(H, W) uint8 class index (`classes`) at the camera's size."""
        p = self._label("semantic", seq, cam, frame, "semantic.png")
        sem = self._sized(read_png(p, gray=True), p, "the semantic map", cam)
        if int(sem.max(initial=0)) >= len(self.classes):
            raise DatasetError(f"{p}: class index {int(sem.max())} is not in labels.classes")
        return sem

    def read_instance(self, seq: str, cam: str, frame: int) -> np.ndarray:
        """(H, W) uint16 object id (0 = none; `instances`) at the camera's size."""
        p = self._label("instance", seq, cam, frame, "instance.png")
        return self._sized(read_png(p, depth16=True), p, "the instance map", cam)

    def read_movers(self, seq: str, cam: str, frame: int) -> np.ndarray:
        """(H, W) bool, True on the pixels of moving objects."""
        p = self._label("flow", seq, cam, frame, "movers.png")
        return self._sized(read_png(p, gray=True), p, "the mover mask", cam) > 127

    def read_flow(self, seq: str, cam: str, frame: int) -> tuple[np.ndarray, np.ndarray]:
        """((H, W, 2) float32 forward flow frame -> frame + 1 in pixels, (H, W) bool valid); frames
        0 .. n_frames - 2."""
        if not 0 <= frame < self.n_frames(seq) - 1:
            raise DatasetError(f"{self.root / seq}: forward flow exists for frames 0..{self.n_frames(seq) - 2}, "
                               f"not {frame}")
        p = self._label("flow", seq, cam, frame, "flow.exr")
        flow = self._sized(read_flow_exr(p, self._size(cam)), p, "the flow map", cam)
        if not np.isfinite(flow).all():
            raise DatasetError(f"{p}: flow holds non-finite values")
        pv = self._label("flow", seq, cam, frame, "flow_valid.png")
        return flow, self._sized(read_png(pv, gray=True), pv, "the flow validity", cam) > 127

    def instances(self, seq: str) -> list[dict]:
        """The objects of sequence `seq`: id, class, moving (a mover's name and T_world_obj per frame)."""
        if "instance" not in self.label_kinds:
            raise lacks(self.root, "instance")
        rows = read_json(self.inside(self.root / seq / "instances.json")).get("instances")
        if not isinstance(rows, list):
            raise DatasetError(f"{self.root / seq / 'instances.json'}: 'instances' must be a list")
        return rows
