"""The labels of the nuScenes export (`synth.nuscenes.export`): lidarseg for the LiDAR and the image labels beside.

A dataset with semantic labels (`ds.label_kinds`) exports, besides what docs/NUSCENES.md lists::

    lidarseg/<version>/<lidar sample_data token>_lidarseg.bin   uint8 nuScenes-lidarseg class index per point,
                                          in the point order of the .pcd.bin (the devkit's lidarseg format)
    <version>/lidarseg.json               [{token (= the sample_data token), sample_data_token, filename}]
    <version>/category.json               the 32 nuScenes-lidarseg categories with their official ``index``
    mcdp_synth/lidarseg/<token>.classes.bin  uint8 per point, our own class (export.json labels.classes)
    mcdp_synth/labels/<CHANNEL>/<stem>.semantic.png / .instance.png   the dataset's label maps (bytes copied;
                                          the JPEG's stem)
    mcdp_synth/labels/<seq>.instances.json   the sequence's object table (parsed and checked, bytes copied)

A point's class is that of the camera pixel its hit lies nearest to (`synth.lidar.labelled_sweep`). Our classes
map onto nuScenes' by name (`TO_NUSCENES`; a class not named there by its evaluation group), so the devkit's
own colour map draws them: ``nusc.render_sample_data(lidar_token, show_lidarseg=True)``. The map loses what
nuScenes does not tell apart (parked from moving cars, poles and barriers from buildings, lane markings from
road); the ``.classes.bin`` side file keeps our classes. A dataset without labels (or ``labels=False``) exports
exactly as before: an empty category table, no lidarseg.
"""
from __future__ import annotations

import numpy as np

from corelib.atomic import atomic_write_bytes
from synth.files import DatasetError
from synth.label_kinds import INSTANCE, INSTANCES, SEMANTIC
from synth.lidar import LidarConfig, labelled_sweep, simulate_sweep
from synth.nuscenes.layout import EXPORT_DIR, LIDARSEG_DIR

#: nuScenes-lidarseg's categories in the order of their ``index`` (nuscenes.utils.color_map.get_colormap)
NUSCENES_CLASSES = (
    "noise", "animal", "human.pedestrian.adult", "human.pedestrian.child", "human.pedestrian.construction_worker",
    "human.pedestrian.personal_mobility", "human.pedestrian.police_officer", "human.pedestrian.stroller",
    "human.pedestrian.wheelchair", "movable_object.barrier", "movable_object.debris",
    "movable_object.pushable_pullable", "movable_object.trafficcone", "static_object.bicycle_rack", "vehicle.bicycle",
    "vehicle.bus.bendy", "vehicle.bus.rigid", "vehicle.car", "vehicle.construction", "vehicle.emergency.ambulance",
    "vehicle.emergency.police", "vehicle.motorcycle", "vehicle.trailer", "vehicle.truck", "flat.driveable_surface",
    "flat.other", "flat.sidewalk", "flat.terrain", "static.manmade", "static.other", "static.vegetation",
    "vehicle.ego",
)
#: our class (scenes.labels.CLASSES) -> nuScenes-lidarseg category
TO_NUSCENES = {
    "sky": "noise", "road": "flat.driveable_surface", "lane_marking": "flat.driveable_surface",
    "sidewalk": "flat.sidewalk", "building": "static.manmade", "vegetation": "static.vegetation",
    "pole": "static.manmade", "barrier": "static.manmade", "parked_vehicle": "vehicle.car",
    "moving_vehicle": "vehicle.car", "other_ground": "flat.terrain", "ego": "vehicle.ego",
}
#: a class TO_NUSCENES does not name: by its evaluation group
GROUP_TO_NUSCENES = {"sky": "noise", "road": "flat.driveable_surface", "building": "static.manmade",
                     "vehicle": "vehicle.car", "vegetation": "static.vegetation", "other": "static.other",
                     "ego": "vehicle.ego"}


def nuscenes_index(classes: list[dict]) -> np.ndarray:
    """(len(classes),) uint8: the nuScenes-lidarseg index of each of our classes (a dataset's class table)."""
    idx = {n: i for i, n in enumerate(NUSCENES_CLASSES)}
    return np.array([idx[TO_NUSCENES.get(c["name"]) or GROUP_TO_NUSCENES.get(c.get("group"), "static.other")]
                     for c in classes], np.uint8)


def category_table(tok) -> list[dict]:
    """The category.json of nuScenes-lidarseg: token, name, description, index."""
    return [{"token": tok("category", name), "name": name, "description": f"nuScenes-lidarseg class {name}",
             "index": i} for i, name in enumerate(NUSCENES_CLASSES)]


class ExportLabels:
    """The export's labels of dataset `ds` into `out` (module docstring); inert when the dataset has no semantic
    labels or `enabled` is False. `camera` copies a camera-frame's maps, `sweep` simulates a labelled sweep and
    writes its lidarseg, `tables` and `marker` give what the tables and export.json gain. A bad source file
    raises `error` (the export's ExportError) naming it."""

    def __init__(self, ds, out, version: str, tok, enabled: bool = True, error: type = DatasetError) -> None:
        self.ds, self.out, self.version, self.tok, self.error = ds, out, version, tok, error
        self.on = bool(enabled) and "semantic" in ds.label_kinds
        self.instance = self.on and "instance" in ds.label_kinds
        self.to_ns = nuscenes_index(ds.classes) if self.on else None
        self.records: list[dict] = []
        self.sem: dict[str, np.ndarray] = {}  # the current frame's semantic maps, per camera
        self.counts = np.zeros(len(NUSCENES_CLASSES), np.int64)
        self._seqs: set[str] = set()

    def _copy(self, src, rel: str) -> str:
        p = self.out / rel
        p.parent.mkdir(parents=True, exist_ok=True)
        try:
            atomic_write_bytes(p, self.ds.read_bytes(src), fsync=False)
        except DatasetError as exc:
            raise self.error(str(exc)) from None
        return rel

    def camera(self, seq: str, cam: str, f: int, ch: str, stem: str) -> dict:
        """Copy camera `cam`'s label maps of frame `f` (read and checked first; the semantic map kept for the
        sweep); returns the export.json entries {semantic, instance: path} ({} without labels)."""
        if not self.on:
            return {}
        ds = self.ds
        if seq not in self._seqs and self.instance:
            self._seqs.add(seq)
            try:  # parsed and checked first (the manifest's bounds: `synth.files.read_json`), then copied
                ds.instances(seq)
            except DatasetError as exc:
                raise self.error(str(exc)) from None
            self._copy(ds.root / INSTANCES.rel(seq), f"{EXPORT_DIR}/labels/{seq}.{INSTANCES.suffix}")
        try:
            self.sem[cam] = ds.read_semantic(seq, cam, f)
            if self.instance:
                ds.read_instance(seq, cam, f)
        except DatasetError as exc:
            raise self.error(str(exc)) from None
        entry = {"semantic": self._copy(ds.root / SEMANTIC.rel(seq, cam, f),
                                        f"{EXPORT_DIR}/labels/{ch}/{stem}.{SEMANTIC.suffix}")}
        if self.instance:
            entry["instance"] = self._copy(ds.root / INSTANCE.rel(seq, cam, f),
                                           f"{EXPORT_DIR}/labels/{ch}/{stem}.{INSTANCE.suffix}")
        return entry

    def sweep(self, token: str, lidar: LidarConfig, cameras: list, depths: dict, masks: dict,
              grays: dict) -> np.ndarray:
        """The frame's LiDAR points (`synth.lidar.simulate_sweep`); with labels, their lidarseg file and record
        written, each point's class that of the pixel its hit lies nearest to."""
        if not self.on:
            return simulate_sweep(lidar, cameras, depths, masks, grays)
        pts, ours = labelled_sweep(lidar, cameras, depths, masks, grays, {c.name: self.sem[c.name] for c in cameras})
        ns = self.to_ns[ours]
        files = self.entry(token)
        for rel, labels in ((files["lidarseg"], ns), (files["classes"], ours)):
            (self.out / rel).parent.mkdir(parents=True, exist_ok=True)
            atomic_write_bytes(self.out / rel, labels.astype(np.uint8).tobytes(), fsync=False)
        self.records.append({"token": token, "sample_data_token": token, "filename": files["lidarseg"]})
        self.counts += np.bincount(ns, minlength=len(NUSCENES_CLASSES))
        return pts

    def entry(self, token: str) -> dict:
        """The LiDAR sample_data's export.json entries: {lidarseg, classes: path} ({} without labels)."""
        if not self.on:
            return {}
        return {"lidarseg": f"{LIDARSEG_DIR}/{self.version}/{token}_lidarseg.bin",
                "classes": f"{EXPORT_DIR}/{LIDARSEG_DIR}/{token}.classes.bin"}

    def tables(self) -> dict:
        """The tables the labels change: category (with index) and lidarseg, when a sweep was labelled."""
        if not self.records:
            return {}
        return {"category": category_table(self.tok), "lidarseg": self.records}

    def marker(self) -> dict:
        """What export.json gains: labels {classes, nuscenes_category (of each class), lidarseg points per
        category}; {} without labels."""
        if not self.on:
            return {}
        rec = {"kinds": [k for k in ("semantic", "instance") if k in self.ds.label_kinds],
               "classes": self.ds.classes, "nuscenes_category": [NUSCENES_CLASSES[i] for i in self.to_ns]}
        if self.records:
            rec["lidarseg_points"] = {NUSCENES_CLASSES[i]: int(n) for i, n in enumerate(self.counts) if n}
        return {"labels": rec}
