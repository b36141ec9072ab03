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


#: the label kinds a manifest's ``labels.kinds`` may list
KINDS = ("semantic", "instance", "flow")
#: the most classes a class table may hold: a semantic map is uint8
MAX_CLASSES = 256
#: the longest class or group name (characters)
MAX_CLASS_NAME = 64
#: the largest object id: an instance map is uint16
MAX_INSTANCE_ID = 2**16 - 1


def _short_name(v) -> bool:
    return isinstance(v, str) and 0 < len(v) <= MAX_CLASS_NAME and v.isprintable()


def check_labels_record(rec, mpath: Path) -> None:
    """The manifest's ``labels`` (`synth.manifest.labels_record`): an object with ``kinds`` (a list of `KINDS`),
    and with semantic labels a class table of at most `MAX_CLASSES` rows (a semantic map is uint8), each
    {index (0, 1, ...), name and group (printable strings of at most `MAX_CLASS_NAME` characters), color ([r, g, b]
    in 0..255)}; DatasetError naming the field otherwise."""
    if not isinstance(rec, dict):
        raise DatasetError(f"{mpath}: labels must be an object {{kinds, classes, ...}}, not a "
                           f"{type(rec).__name__}")
    extra = sorted(str(k)[:40] for k in rec if k not in ("kinds", "classes", *KINDS))
    if extra:
        raise DatasetError(f"{mpath}: labels has unknown key(s) {', '.join(map(repr, extra[:4]))} (it knows kinds, "
                           f"classes, {', '.join(KINDS)})")
    kinds = rec.get("kinds")
    if not isinstance(kinds, list) or len(kinds) > len(KINDS) or not all(k in KINDS for k in kinds):
        raise DatasetError(f"{mpath}: labels.kinds must be a list of {', '.join(KINDS)}, got {str(kinds)[:60]}")
    if "semantic" not in kinds and "classes" not in rec:
        return
    table = rec.get("classes")
    if not isinstance(table, list) or not 0 < len(table) <= MAX_CLASSES:
        n = len(table) if isinstance(table, list) else type(table).__name__
        raise DatasetError(f"{mpath}: labels.classes must list 1 to {MAX_CLASSES} classes (a semantic map is "
                           f"uint8), got {n}")
    for i, c in enumerate(table):
        color = c.get("color") if isinstance(c, dict) else None
        if not (isinstance(c, dict) and c.get("index") == i and not isinstance(c.get("index"), bool)
                and _short_name(c.get("name")) and ("group" not in c or _short_name(c["group"]))
                and isinstance(color, list) and len(color) == 3
                and all(isinstance(v, int) and not isinstance(v, bool) and 0 <= v <= 255 for v in color)):
            raise DatasetError(f"{mpath}: labels.classes[{i}] must be {{index: {i}, name, group (printable strings of "
                               f"at most {MAX_CLASS_NAME} characters), color: [r, g, b] in 0..255}}, got "
                               f"{str(c)[:80]}")


def instance_ids(doc, path: Path) -> set[int]:
    """The object ids of a sequence's instances.json (`synth.render`: {sequence, instances: [{id, class, moving,
    ...}]}): each an integer in 1..`MAX_INSTANCE_ID` (an instance map is uint16, 0 = none), none twice;
    DatasetError naming the file otherwise."""
    rows = doc.get("instances") if isinstance(doc, dict) else None
    if not isinstance(rows, list):
        raise DatasetError(f"{path}: 'instances' must be a list")
    ids: set[int] = set()
    for k, r in enumerate(rows):
        i = r.get("id") if isinstance(r, dict) else None
        if not isinstance(i, int) or isinstance(i, bool) or not 0 < i <= MAX_INSTANCE_ID or i in ids:
            raise DatasetError(f"{path}: instances[{k}].id must be an integer in 1..{MAX_INSTANCE_ID}, each once; got "
                               f"{str(i)[:40]}")
        ids.add(i)
    return ids


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
        check_labels_record(self.manifest["labels"], self.root / "manifest.json")
        return self.manifest["labels"]["classes"]

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
        p = self.inside(self.root / seq / "instances.json")
        doc = read_json(p)
        instance_ids(doc, p)
        return doc["instances"]
