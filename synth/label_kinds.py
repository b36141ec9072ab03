"""The label kinds a render writes besides RGB and depth, as a table: one `LabelKind` row each, its files (suffix,
dtype, encoding, every frame / frames 0..F-2 / once per sequence), whether it is on by default, its cost and the
hooks that write, read, verify and show it. The writer (`synth.pipeline.LabelFrames`), the reader
(`synth.label_reader`), `synth verify`, the manifest (`synth.manifest.labels_record`), the render's size estimate
(`synth.config.render_size`), the preview sheet and the Rerun recording all read this table; a new kind is a row
(and its hooks beside it, writer and reader side by side), with no other edit. A kind without a ``labels.<name>``
config key is written when it is on by default.

The label values themselves are computed in `synth.labels`; the class table is `scenes.labels`.

Example::

    >>> import numpy as np
    >>> from synth.label_kinds import LabelFile, LabelKind, label_kind
    >>> [f.rel("seq_00000", "CAM_FRONT", 3) for f in label_kind("flow").files][:2]
    ['seq_00000/CAM_FRONT/000003.movers.png', 'seq_00000/CAM_FRONT/000003.flow.exr']
    >>> SKY = LabelFile("sky.png", "uint8", "png8", "the sky mask")
    >>> sky = LabelKind("sky", (SKY,), default_on=True, bytes_per_pixel=1, about="<frame>.sky.png: 255 = no surface",
    ...                 write=lambda w, f: w.png(SKY, f, np.where(f.res["depth"] > 0, 0, 255).astype(np.uint8)),
    ...                 read=lambda ds, seq, cam, frame: ds.read_label_file("sky", SKY, seq, cam, frame) > 127)
    >>> sky.files[0].rel("seq_00000", "CAM_BACK", 0), sky.bytes_per_pixel
    ('seq_00000/CAM_BACK/000000.sky.png', 1)

(tests/synth/test_label_kinds.py renders, verifies, reads and shows such a row.)
"""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Callable, Literal

import numpy as np

from synth.files import DatasetError, frame_stem, read_flow_exr, read_json, read_png, short_list, within

#: every frame; frames 0..F-2 (a pair t -> t+1); once per sequence (``<seq>/<suffix>``)
Scope = Literal["frame", "pair", "sequence"]
#: the largest object id: an instance map is uint16
MAX_INSTANCE_ID = 2**16 - 1


@dataclass(frozen=True)
class LabelFile:
    """One file of a label kind: ``<seq>/<CAM>/<frame>.<suffix>`` (scope frame / pair) or ``<seq>/<suffix>``."""

    suffix: str
    dtype: str
    encoding: str  # png8 (8-bit gray PNG), png16 (16-bit PNG), exr_uv (float32 EXR, channels U, V), json
    what: str  # its name in an error message ("the semantic map")
    scope: Scope = "frame"

    def rel(self, seq: str, cam: str | None = None, frame: int | None = None) -> str:
        """Its path relative to the dataset root."""
        if self.scope == "sequence":
            return f"{seq}/{self.suffix}"
        return f"{seq}/{cam}/{frame_stem(frame)}.{self.suffix}"

    def decode(self, path: Path, size: tuple[int, int] | None = None):
        """The file's value: an array (images) or the parsed JSON."""
        if self.encoding == "png8":
            return read_png(path, gray=True)
        if self.encoding == "png16":
            return read_png(path, depth16=True)
        if self.encoding == "exr_uv":
            return read_flow_exr(path, size)
        return read_json(path)


@dataclass(frozen=True)
class LabelKind:
    """A row of the table. Hooks: ``write(w, f)`` submits rendered frame `f`'s files (`synth.pipeline.LabelFrames`
    `w`; `f`: a `synth.pipeline.RenderedFrame`); ``read(ds, seq, cam, frame)`` returns the kind's value
    (`Dataset.read_label`); ``finish(w)`` writes the per-sequence files ({relative path: sha256}); ``verify(root,
    manifest)`` returns the problems `synth verify` adds; ``show(ds, seq, cam, frame)`` the preview sheet's
    tiles [(RGB image, caption)]; ``log(rr, rec, path, ds, seq, cam, frame, shown)`` logs the Rerun entity
    ``<path>/<name>`` (``shown``: the values logged so far this camera-frame, by kind) and returns its value;
    ``record()`` the manifest's extra ``labels`` keys. Cost: `bytes_per_pixel`, before compression."""

    name: str
    files: tuple[LabelFile, ...]
    default_on: bool
    bytes_per_pixel: int
    about: str  # the manifest's ``labels.<name>``: the file conventions
    write: Callable
    read: Callable
    finish: Callable | None = None
    verify: Callable | None = None
    show: Callable | None = None
    log: Callable | None = None
    record: Callable | None = None


# ----------------------------------------------------------------------------- semantic

SEMANTIC = LabelFile("semantic.png", "uint8", "png8", "the semantic map")


def _write_semantic(w, f) -> None:
    from synth.labels import semantic_map

    res = f.res
    w.png(SEMANTIC, f, semantic_map(res["layer"], res["instance"], res["ego"], res["depth"], w.classes))


def _read_semantic(ds, seq: str, cam: str, frame: int) -> np.ndarray:
    sem = ds.read_label_file("semantic", SEMANTIC, seq, cam, frame)
    if int(sem.max(initial=0)) >= len(ds.classes):
        raise DatasetError(f"{ds.root / SEMANTIC.rel(seq, cam, frame)}: class index {int(sem.max())} is not in "
                           "labels.classes")
    return sem


def _show_semantic(ds, seq: str, cam: str, frame: int) -> list:
    from synth.preview_labels import colorize_classes

    return [(colorize_classes(ds.read_semantic(seq, cam, frame), ds.classes), "classes")]


def _log_semantic(rr, rec, path: str, ds, seq: str, cam: str, frame: int, shown: dict):
    sem = ds.read_semantic(seq, cam, frame)
    rec.log(f"{path}/semantic", rr.SegmentationImage(sem))
    return sem


def _class_record() -> dict:
    from scenes.labels import class_table

    return {"classes": class_table()}


# ----------------------------------------------------------------------------- instance

INSTANCE = LabelFile("instance.png", "uint16", "png16", "the instance map")
INSTANCES = LabelFile("instances.json", "json", "json", "the object table", "sequence")


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


def _write_instance(w, f) -> None:
    w.png(INSTANCE, f, f.inst)


def _read_instance(ds, seq: str, cam: str, frame: int) -> np.ndarray:
    return ds.read_label_file("instance", INSTANCE, seq, cam, frame)


def _finish_instance(w) -> dict[str, str]:
    from scenes.labels import instance_table

    return w.json(INSTANCES, {"sequence": w.seq, "instances": instance_table(w.scene)})


def _verify_instance(root: Path, manifest: dict) -> list[str]:
    """Every listed instance map holding an object id its sequence's instances.json lacks (a problem naming the
    map and up to 6 ids); an instances.json that is unreadable or whose ids are not 1..65535, each once (a problem
    naming it). A map or table already reported (missing, altered) is read as it is, or skipped when unreadable."""
    files, problems = manifest.get("files", {}), []
    for seq in manifest.get("sequences", {}):
        table = root / INSTANCES.rel(seq)
        if not table.is_file():
            continue  # reported by `synth verify`: missing, not a regular file, or not listed
        try:
            ids = instance_ids(read_json(within(root, table, "", "dataset root", "is a link to")), table)
        except DatasetError as exc:
            problems.append(str(exc))
            continue
        for rel in sorted(r for r in files if r.startswith(f"{seq}/") and r.endswith(f".{INSTANCE.suffix}")):
            p = root / rel
            try:
                found = np.unique(INSTANCE.decode(within(root, p, "", "dataset root", "is a link to")))
            except DatasetError:
                continue  # reported above (missing, a link out, altered) or by its checksum
            unknown = [int(i) for i in found if i and int(i) not in ids]
            if unknown:
                problems.append(f"{p}: object id(s) {short_list([str(i) for i in unknown])} not in {table}")
    return problems


# ----------------------------------------------------------------------------- flow

MOVERS = LabelFile("movers.png", "bool", "png8", "the mover mask")
FLOW = LabelFile("flow.exr", "float32", "exr_uv", "the flow map", "pair")
FLOW_VALID = LabelFile("flow_valid.png", "bool", "png8", "the flow validity", "pair")


def _write_flow(w, f) -> None:
    w.png(MOVERS, f, np.where(np.isin(f.inst, w.mover_ids), 255, 0).astype(np.uint8))
    w.flow_pair(f, FLOW, FLOW_VALID)


def _read_flow(ds, seq: str, cam: str, frame: int) -> tuple[np.ndarray, np.ndarray]:
    if not 0 <= frame < ds.n_frames(seq) - 1:
        raise DatasetError(f"{ds.root / seq}: forward flow exists for frames 0..{ds.n_frames(seq) - 2}, not {frame}")
    flow = ds.read_label_file("flow", FLOW, seq, cam, frame)
    if not np.isfinite(flow).all():
        raise DatasetError(f"{ds.root / FLOW.rel(seq, cam, frame)}: flow holds non-finite values")
    return flow, ds.read_label_file("flow", FLOW_VALID, seq, cam, frame) > 127


def _show_flow(ds, seq: str, cam: str, frame: int) -> list:
    from synth.preview_labels import colorize_flow

    if frame < ds.n_frames(seq) - 1:
        rgb, scale = colorize_flow(*ds.read_flow(seq, cam, frame))
        return [(rgb, f"flow ({scale:.1f} px)")]
    movers = ds.read_movers(seq, cam, frame)
    return [(np.repeat(movers[..., None].astype(np.uint8) * 255, 3, axis=2), "movers")]


def _log_flow(rr, rec, path: str, ds, seq: str, cam: str, frame: int, shown: dict):
    from synth.view_labels import flow_arrows

    if frame < ds.n_frames(seq) - 1:
        rec.log(f"{path}/flow", flow_arrows(rr, *ds.read_flow(seq, cam, frame), shown.get("semantic")))
    else:
        rec.log(f"{path}/flow", rr.Clear(recursive=False))  # no forward flow at the last frame


# ----------------------------------------------------------------------------- the table

LABEL_KINDS: tuple[LabelKind, ...] = (
    LabelKind("semantic", (SEMANTIC,), True, 1,
              "<seq>/<CAM>/<frame>.semantic.png: uint8 class index (classes[].index)",
              _write_semantic, _read_semantic, show=_show_semantic, log=_log_semantic, record=_class_record),
    LabelKind("instance", (INSTANCE, INSTANCES), True, 2,
              "<seq>/<CAM>/<frame>.instance.png: uint16 object id, 0 = none; <seq>/instances.json: id, class, "
              "moving, a mover's T_world_obj per frame",
              _write_instance, _read_instance, finish=_finish_instance, verify=_verify_instance),
    LabelKind("flow", (MOVERS, FLOW, FLOW_VALID), False, 10,  # 2 x float32 + validity and mover masks
              "<seq>/<CAM>/<frame>.flow.exr: forward flow t -> t+1 in pixels (channels U, V; frames 0..F-2), "
              "<frame>.flow_valid.png: 255 = valid; <frame>.movers.png: 255 = a moving object (every frame)",
              _write_flow, _read_flow, show=_show_flow, log=_log_flow),
)


def label_kinds() -> tuple[LabelKind, ...]:
    """The table, in its order (the order of the manifest's ``labels.kinds``)."""
    return LABEL_KINDS


def label_kind(name: str) -> LabelKind:
    """The row called `name`; KeyError naming the kinds otherwise."""
    for k in label_kinds():
        if k.name == name:
            return k
    raise KeyError(f"no label kind {name!r} (kinds {', '.join(k.name for k in label_kinds())})")


def kind_names() -> tuple[str, ...]:
    return tuple(k.name for k in label_kinds())


def enabled_kinds(labels_cfg) -> list[str]:
    """The kinds a render writes: each row's ``labels.<name>`` (its default when the config has no such key)."""
    return [k.name for k in label_kinds() if getattr(labels_cfg, k.name, k.default_on)]


def expected_files(kinds, seq: str, cam: str | None, frame: int | None, n_frames: int) -> list[str]:
    """The label files of `kinds` a dataset lists for camera `cam`'s `frame` (frame and pair scopes, the frame's
    files first), or with ``cam=None`` the sequence's own files."""
    rows = [k for k in label_kinds() if k.name in kinds]
    if cam is None:
        return [f.rel(seq) for k in rows for f in k.files if f.scope == "sequence"]
    scopes = ("frame", "pair") if frame < n_frames - 1 else ("frame",)
    return [f.rel(seq, cam, frame) for s in scopes for k in rows for f in k.files if f.scope == s]


def label_bytes_per_pixel(labels_cfg) -> int:
    """Uncompressed label bytes a render writes per pixel (the rows' `bytes_per_pixel` of `enabled_kinds`)."""
    return sum(label_kind(k).bytes_per_pixel for k in enabled_kinds(labels_cfg))


def preview_tiles(ds, seq: str, cam: str, frame: int) -> list[tuple[np.ndarray, str]]:
    """The label tiles of one camera-frame on the preview sheet: each held kind's ``show`` tiles, in table
    order; [] for a dataset without labels."""
    return [t for k in label_kinds() if k.show is not None and k.name in ds.label_kinds
            for t in k.show(ds, seq, cam, frame)]


def write_sequence_files(w, kinds) -> dict[str, str]:
    """Each of `kinds`' per-sequence files (``finish``): {relative path: sha256}."""
    out: dict[str, str] = {}
    for k in label_kinds():
        if k.name in kinds and k.finish is not None:
            out.update(k.finish(w))
    return out

