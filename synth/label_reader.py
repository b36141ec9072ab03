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

from synth.files import DatasetError, read_json
from synth.label_kinds import INSTANCES, MOVERS, LabelFile, instance_ids, kind_names, label_kind

#: the most classes a class table may hold: a semantic map is uint8
MAX_CLASSES = 256
#: the longest class or group name (characters)
MAX_CLASS_NAME = 64


def _short_name(v) -> bool:
    return isinstance(v, str) and 0 < len(v) <= MAX_CLASS_NAME and v.isprintable()


def check_labels_record(rec, mpath: Path) -> None:
    """The manifest's ``labels`` (`synth.manifest.labels_record`): an object with ``kinds`` (a list of the kinds of
    `synth.label_kinds`),
    and with semantic labels a class table of at most `MAX_CLASSES` rows (a semantic map is uint8), each
    {index (0, 1, ...), name and group (printable strings of at most `MAX_CLASS_NAME` characters), color ([r, g, b]
    in 0..255)}; DatasetError naming the field otherwise."""
    if not isinstance(rec, dict):
        raise DatasetError(f"{mpath}: labels must be an object {{kinds, classes, ...}}, not a "
                           f"{type(rec).__name__}")
    known = kind_names()
    extra = sorted(str(k)[:40] for k in rec if k not in ("kinds", "classes", *known))
    if extra:
        raise DatasetError(f"{mpath}: labels has unknown key(s) {', '.join(map(repr, extra[:4]))} (it knows kinds, "
                           f"classes, {', '.join(known)})")
    kinds = rec.get("kinds")
    if not isinstance(kinds, list) or len(kinds) > len(known) or not all(k in known for k in kinds):
        raise DatasetError(f"{mpath}: labels.kinds must be a list of {', '.join(known)}, got {str(kinds)[:60]}")
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


def lacks(root, kind: str) -> DatasetError:
    return DatasetError(f"{root}: has no {kind} labels (rendered before labels existed, or with "
                        f"labels.{kind}=false); render it again with labels.{kind}=true to get them")


class NoLabels:
    """The label members of `synth.protocol.DatasetReader` for a dataset that has none."""

    def read_label(self, kind: str, seq: str, cam: str | None = None, frame: int | None = None):
        raise lacks(self.root, kind)

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
        """The labels every sequence holds: some of the kinds of `synth.label_kinds` (table order); () before
        labels."""
        rec = self.manifest.get("labels")
        kinds = rec.get("kinds") if isinstance(rec, dict) else None
        return tuple(k for k in kind_names() if isinstance(kinds, list) and k in kinds)

    @property
    def classes(self) -> list[dict]:
        """The class table (index, name, color, group) of the semantic maps ([] without them)."""
        if "semantic" not in self.label_kinds:
            return []
        check_labels_record(self.manifest["labels"], self.root / "manifest.json")
        return self.manifest["labels"]["classes"]

    def label_path(self, kind: str, lf: LabelFile, seq: str, cam: str | None = None, frame: int | None = None) -> Path:
        """The path of label file `lf` of `kind` (`synth.label_kinds`), inside the root; DatasetError saying what
        the dataset lacks when it does not hold `kind`."""
        if kind not in self.label_kinds:
            raise lacks(self.root, kind)
        return self.inside(self.root / lf.rel(seq, cam, frame))

    def read_label_file(self, kind: str, lf: LabelFile, seq: str, cam: str, frame: int) -> np.ndarray:
        """Image file `lf` of `kind` of one camera-frame, decoded, at the camera's size."""
        p = self.label_path(kind, lf, seq, cam, frame)
        return self._sized(lf.decode(p, self._size(cam)), p, lf.what, cam)

    def read_label(self, kind: str, seq: str, cam: str | None = None, frame: int | None = None):
        """The value of label `kind` (its row's ``read``: `synth.label_kinds`) of one camera-frame."""
        if kind not in self.label_kinds:
            raise lacks(self.root, kind)
        return label_kind(kind).read(self, seq, cam, frame)

    def read_semantic(self, seq: str, cam: str, frame: int) -> np.ndarray:
        """(H, W) uint8 class index (`classes`) at the camera's size."""
        return self.read_label("semantic", seq, cam, frame)

    def read_instance(self, seq: str, cam: str, frame: int) -> np.ndarray:
        """(H, W) uint16 object id (0 = none; `instances`) at the camera's size."""
        return self.read_label("instance", seq, cam, frame)

    def read_movers(self, seq: str, cam: str, frame: int) -> np.ndarray:
        """(H, W) bool, True on the pixels of moving objects."""
        return self.read_label_file("flow", MOVERS, seq, cam, frame) > 127

    def read_flow(self, seq: str, cam: str, frame: int) -> tuple[np.ndarray, np.ndarray]:
        """((H, W, 2) float32 forward flow frame -> frame + 1 in pixels, (H, W) bool valid); frames
        0 .. n_frames - 2."""
        return self.read_label("flow", seq, cam, frame)

    def instances(self, seq: str) -> list[dict]:
        """The objects of sequence `seq`: id, class, moving (a mover's name and T_world_obj per frame)."""
        p = self.label_path("instance", INSTANCES, seq)
        doc = read_json(p)
        instance_ids(doc, p)
        return doc["instances"]
