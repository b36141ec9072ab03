"""Export a finished synth dataset as a nuScenes dataroot (docs/NUSCENES.md): `export_nuscenes`.

The official devkit loads the result: ``NuScenes(version="v1.0-synth", dataroot=NS_ROOT)``. This module
writes the files (what and where: `synth.nuscenes.layout`), in order: the marker, the static rig (masks,
map), every frame's JPEG, depth copy and simulated LIDAR_TOP sweep (`synth.lidar`; labelled, with its
lidarseg, by `synth.nuscenes.lidarseg`), then the tables, whose rows `synth.nuscenes.records` makes, last.

Conventions: our camera frame is OpenCV like nuScenes'. ``camera_intrinsic`` is the rig's ``K`` unchanged,
so its pixel centres are at +0.5: a point that ``view_points`` projects to (u, v) falls in pixel
(floor(u), floor(v)). The same dataset always exports the same bytes. Cameras that fire at their own times
(``rig.trigger``): each camera's sample_data has its own timestamp and ego_pose, the LiDAR meshes each
camera's depth at its own pose; a synchronous dataset exports as before.

Example::

    export_nuscenes(open_dataset("data/tiny"), "data/tiny_ns")   # synth export data/tiny --format nuscenes --out ...

It takes an opened reader (`synth.open.open_dataset`): the writer sits above the reader factory and imports
neither it nor `synth.dataset` (tests/test_layers.py).
"""
from __future__ import annotations

import dataclasses
import os
import shutil
from pathlib import Path

import numpy as np

from corelib.atomic import atomic_write_bytes
from corelib.rundir import lock_folder
from synth.camera import pinhole_only
from synth.files import DatasetError, encode_jpeg, is_plain_name, read_png, write_json, write_png
from synth.lidar import LidarConfig, luma
from synth.nuscenes.layout import (EXPORT_DIR, FORMAT, LIDAR_CHANNEL, LOCK, MARKER, MASKS_DIR, OWNED, SPLITS_FILE,
                                   ExportError, prepare_output)
from synth.nuscenes.lidarseg import ExportLabels
from synth.nuscenes.records import (BASE_TIMESTAMP_US, SEQUENCE_SPACING_US, TableRows, Tokens, channel_map,
                                    check_rigid, pose, timestamp_us)

FORMAT_VERSION = 1
DEFAULT_VERSION = "v1.0-synth"


DEFAULT_JPEG_QUALITY = 95  # a PNG dataset's images are encoded at this quality unless told


def _write_jpeg(path: Path, rgb: np.ndarray, quality: int) -> None:
    try:
        data = encode_jpeg(rgb, quality)
    except ValueError:
        raise ExportError(f"{path}: could not encode JPEG") from None
    atomic_write_bytes(path, data, fsync=False)  # whole or absent; the tables, written last, seal


# ----------------------------------------------------------------------------- export

def export_nuscenes(ds, out: str | Path, version: str = DEFAULT_VERSION,
                    lidar: LidarConfig | None = LidarConfig(), jpeg_quality: int | None = None,
                    progress: bool = False, labels: bool = True) -> dict:
    """Write the nuScenes dataroot `out` from `ds`, a rendered dataset opened by `synth.open.open_dataset`;
    returns a summary dict. `lidar=None` exports cameras only (no LIDAR_TOP); `labels=False` leaves a dataset's
    labels out. `jpeg_quality` None: a JPEG dataset's images (``sensor.jpeg_quality``) are copied byte for byte,
    a PNG dataset's encoded at `DEFAULT_JPEG_QUALITY`; a number: every image is encoded at it (a JPEG one again)."""
    ex = _Export(ds, Path(out), version, lidar, jpeg_quality, labels)  # the source checked
    prepare_output(ex.out, ex.cfg_hash, version, clean=False)  # refuse a foreign folder before writing a byte
    ex.out.mkdir(parents=True, exist_ok=True)
    lock = lock_folder(ex.out, LOCK)  # a second export into `out` is refused, naming this pid
    try:
        prepare_output(ex.out, ex.cfg_hash, version)  # under the lock: remove what a previous export wrote
        return ex.run(progress)
    finally:
        lock.release()


class _Export:
    """One export: the source's checks (constructor), then `run`: the marker, the static rig (sensors,
    calibration, masks, map), every sequence's frames (JPEG, depth copy, LiDAR sweep, table rows), and the
    tables last."""

    def __init__(self, ds, out: Path, version: str, lidar: LidarConfig | None, jpeg_quality: int | None,
                 labels: bool = True) -> None:
        if not is_plain_name(version) or version in OWNED or version.endswith(".partial"):
            raise ExportError(f"--version {version!r} is not a plain folder name (letters, digits, . _ -)")
        if jpeg_quality is not None and not 1 <= int(jpeg_quality) <= 100:
            raise ExportError(f"jpeg quality {jpeg_quality} is not in 1..100")
        src = Path(ds.root)
        if ds.format != "synth":
            raise ExportError(f"{src}: a {ds.format} dataset, not one mcdp-synth rendered; only a rendered dataset "
                              "exports")
        pinhole_only(ds.cameras, f"{src}: a nuScenes export (camera_intrinsic: a pinhole K)", ExportError)
        if src.resolve() == out.resolve() or out.resolve().is_relative_to(src.resolve()):
            raise ExportError(f"{out}: inside the source dataset {src}; choose a folder outside it")
        if not ds.has_depth and lidar is not None:
            raise ExportError(f"{src / 'manifest.json'}: dataset has no depth; export with --no-lidar")
        self.chmap = channel_map(ds.cameras)
        self.cfg_hash = str(ds.manifest.get("config_hash") or "")
        if not self.cfg_hash:
            raise ExportError(f"{src / 'manifest.json'}: no config_hash")
        rgb = ds.manifest.get("rgb") if ds.format == "synth" else None  # checked on open (`synth.dataset.rgb_suffix`)
        self.copy_jpeg = jpeg_quality is None and rgb is not None  # already JPEG, as nuScenes ships: copied
        self.src, self.out, self.ds, self.version, self.lidar = src, out, ds, version, lidar
        self.jpeg_quality = rgb["quality"] if self.copy_jpeg else jpeg_quality or DEFAULT_JPEG_QUALITY
        self.fps = ds.fps
        self.seqs = ds.sequences
        self.splits = {s: ds.split(s) for s in ("train", "val", "test") if s in ds.manifest.get("splits", {})}
        self.split_of = {q: s for s, qs in self.splits.items() for q in qs}
        self.rows = TableRows(Tokens(self.cfg_hash))
        self.sd_index: dict[str, dict] = {}
        self.n_points: list[int] = []
        self.labels = ExportLabels(ds, out, version, self.rows.tok, labels, ExportError)

    def run(self, progress: bool) -> dict:
        ds, out, rows = self.ds, self.out, self.rows
        (out / EXPORT_DIR).mkdir(exist_ok=True)
        marker = {"format": FORMAT, "format_version": FORMAT_VERSION, "complete": False, "version": self.version,
                  "source": {"path": str(self.src.resolve()), "config_hash": self.cfg_hash,
                             "generator_version": ds.manifest.get("generator_version"), "seed": ds.manifest.get("seed")}}
        write_json(out / MARKER, marker)
        self._calibration()
        mask_files = self._masks()
        (out / "maps").mkdir(exist_ok=True)
        write_png(out / rows.map_file, np.zeros((8, 8), np.uint8))  # the placeholder map
        for ch in self.channels:
            (out / "samples" / ch).mkdir(parents=True, exist_ok=True)
            if ch != LIDAR_CHANNEL:
                (out / EXPORT_DIR / "depth" / ch).mkdir(parents=True, exist_ok=True)
        frames_total, bar = sum(ds.n_frames(q) for q in self.seqs), None
        if progress:
            from corelib.progress import progress_bar
            bar = progress_bar(total=frames_total, desc="export", unit="frame")
        for si, seq in enumerate(self.seqs):
            self._sequence(si, seq, bar)
        if bar is not None:
            bar.close()
        # a dataset with labels: category (with index) and lidarseg
        self._finish(marker, mask_files, {**rows.tables(), **self.labels.tables()})
        return {"out": str(out), "version": self.version, "scenes": len(rows.rows["scene"]),
                "samples": len(rows.rows["sample"]), "sample_data": len(rows.rows["sample_data"]),
                "channels": self.channels, "lidarseg": len(self.labels.records),
                "lidar_points_per_sweep": None if self.lidar is None else float(np.mean(self.n_points))}

    def _calibration(self) -> None:
        """The sensor and calibrated_sensor rows of the static rig (+ LIDAR_TOP); sets `channels` (the
        cameras' in rig order, then LIDAR_TOP)."""
        for cam in self.ds.cameras:
            T = check_rigid(cam.T_ego_cam, f"{self.src / 'rig.json'} camera {cam.name} T_ego_cam")
            self.rows.add_sensor(self.chmap[cam.name], "camera", T, cam.K)
        self.channels = [self.chmap[c.name] for c in self.ds.cameras]
        if self.lidar is not None:
            self.rows.add_sensor(LIDAR_CHANNEL, "lidar", self.lidar.T_ego_lidar())
            self.channels.append(LIDAR_CHANNEL)

    def _masks(self) -> dict[str, str]:
        """Copy the self-occlusion masks (checked against the rig); sets `masks` (scene = True, for the LiDAR);
        returns the channel -> file map of the marker."""
        ds, out = self.ds, self.out
        (out / MASKS_DIR).mkdir(parents=True, exist_ok=True)
        self.masks: dict[str, np.ndarray] = {}
        mask_files = {}
        for cam in ds.cameras:
            ch = self.chmap[cam.name]
            try:
                m = read_png(ds.inside(ds.root / "masks" / f"{cam.name}.png"), gray=True)
            except DatasetError as exc:
                raise ExportError(str(exc)) from None
            if m.shape != (cam.height, cam.width):
                raise ExportError(f"{ds.root / 'masks' / (cam.name + '.png')}: {m.shape[1]}x{m.shape[0]}, "
                                  f"rig.json says {cam.width}x{cam.height}")
            self.masks[cam.name] = m > 127
            mask_files[ch] = f"{MASKS_DIR}/{ch}.png"
            write_png(out / mask_files[ch], m)
        return mask_files

    def _sequence(self, si: int, seq: str, bar) -> None:
        """The `si`-th sequence: its log, samples, every frame's files and records, its scene."""
        ds, fps = self.ds, self.fps
        info = ds.manifest["sequences"][seq]
        family = str((info.get("scene") or {}).get("family", "synth"))
        n = ds.n_frames(seq)
        ego_path = ds.root / seq / "ego.json"
        try:
            ego = ds.ego(seq)
        except DatasetError as exc:
            raise ExportError(str(exc)) from None
        if len(ego) != n:
            raise ExportError(f"{ego_path}: {len(ego)} frames, the manifest says {n}")
        self.rows.add_log(seq, timestamp_us(si, 0, fps), family)
        own = self._camera_poses(seq, ego) if any("cameras" in fr for fr in ego) else None
        for f in range(n):
            fr = ego[f]
            ts = timestamp_us(si, f, fps)
            if abs(float(fr.get("timestamp_s", f / fps)) - f / fps) > 1e-6:
                raise ExportError(f"{ego_path}: frame {f} timestamp_s {fr.get('timestamp_s')} is not frame / fps "
                                  f"= {f / fps}")
            T_we = check_rigid(fr.get("T_world_ego"), f"{ego_path} frame {f} T_world_ego")
            self.rows.add_sample(seq, f, n, ts)
            self._frame(seq, f, n, ts, pose(T_we, ts), None if own is None else self._own_times(seq, own, fr, f, ts))
            if bar is not None:
                bar.update(1)
        desc = f"mcdp-synth {family}, {info.get('time_of_day', '?')}, split {self.split_of.get(seq, '-')}"
        self.rows.add_scene(seq, n, desc)

    def _camera_poses(self, seq: str, ego: list[dict]) -> tuple[np.ndarray, np.ndarray]:
        """A sequence whose cameras fire at their own times (rig.trigger, docs/DATASET.md): the reader's checked
        (F, N) timestamps and (F, N, 4, 4) poses in the frame's ego frame (`Dataset.camera_poses`)."""
        try:
            ts, T = self.ds.camera_poses(seq)
        except DatasetError as exc:
            raise ExportError(str(exc)) from None
        if ts.shape[0] != len(ego):
            raise ExportError(f"{self.ds.root / seq / 'ego.json'}: camera poses for {ts.shape[0]} frames, "
                              f"ego.json has {len(ego)}")
        return ts, T

    def _own_times(self, seq: str, own: tuple, fr: dict, f: int, ts: int) -> dict | None:
        """Frame `f`'s cameras at their own trigger times: {camera: (timestamp in us, its ego_pose row, its pose
        in the frame's ego frame)}; the timestamp is the frame's plus the camera's offset (rounded to 1 us), the
        ego_pose that of ego.json's ``cameras.<CAM>.T_world_ego``. A frame without ``cameras``: None."""
        if "cameras" not in fr:
            return None
        path = self.ds.root / seq / "ego.json"
        out = {}
        for c, cam in enumerate(self.ds.cameras):
            t = ts + int(round((float(own[0][f, c]) - f / self.fps) * 1e6))
            T = check_rigid(fr["cameras"][cam.name].get("T_world_ego"),
                            f"{path} frame {f} cameras.{cam.name}.T_world_ego")
            out[cam.name] = (t, pose(T, t), np.asarray(own[1][f, c], np.float64))
        return out

    def _frame(self, seq: str, f: int, n: int, ts: int, ego_pose: dict, own: dict | None = None) -> None:
        """Frame `f` of `seq`: every camera's JPEG (+ depth copy), then the LiDAR sweep simulated from them. With
        `own` (cameras that fire at their own times, `_own_times`) each camera's sample_data has its own timestamp
        and ego_pose, and the LiDAR meshes each camera's depth at its own pose in the frame's ego frame."""
        ds, out, lidar, rows = self.ds, self.out, self.lidar, self.rows
        depths, grays = {}, {}
        for cam in ds.cameras:
            ch = self.chmap[cam.name]
            cam_ts, cam_pose = (ts, ego_pose) if own is None else own[cam.name][:2]
            stem = f"{seq}__{ch}__{cam_ts}"
            try:
                rgb = ds.read_rgb(seq, cam.name, f)
            except DatasetError as exc:
                raise ExportError(str(exc)) from None
            if rgb.shape[:2] != (cam.height, cam.width):
                raise ExportError(f"{ds.rgb_path(seq, cam.name, f)}: {rgb.shape[1]}x{rgb.shape[0]}, rig.json "
                                  f"says {cam.width}x{cam.height}")
            rel = f"samples/{ch}/{stem}.jpg"
            if self.copy_jpeg:  # the dataset's JPEG as it is (read and checked above): no second compression
                atomic_write_bytes(out / rel, ds.read_bytes(ds.rgb_path(seq, cam.name, f)), fsync=False)
            else:
                _write_jpeg(out / rel, rgb, self.jpeg_quality)
            entry = {"sequence": seq, "frame": f, "camera": cam.name, "channel": ch,
                     **self.labels.camera(seq, cam.name, f, ch, stem)}
            if ds.has_depth:
                entry["depth"] = self._depth(seq, cam, f, stem, ch, depths)
                if lidar is not None:
                    grays[cam.name] = luma(rgb)
            token = rows.add_sample_data(seq, ch, f, n, cam_ts, rel, "jpg", (cam.width, cam.height), cam_pose)
            self.sd_index[token] = entry
        if lidar is not None:
            token = rows.sd_token(seq, LIDAR_CHANNEL, f)
            rel = f"samples/{LIDAR_CHANNEL}/{seq}__{LIDAR_CHANNEL}__{ts}.pcd.bin"
            cameras = list(ds.cameras) if own is None else \
                [dataclasses.replace(c, T_ego_cam=own[c.name][2]) for c in ds.cameras]  # each at its own pose
            pts = self.labels.sweep(token, lidar, cameras, depths, self.masks, grays)
            atomic_write_bytes(out / rel, pts.astype("<f4").tobytes(), fsync=False)
            self.n_points.append(len(pts))
            self.sd_index[token] = {"sequence": seq, "frame": f, "channel": LIDAR_CHANNEL, "points": int(len(pts)),
                                    **self.labels.entry(token)}
            rows.add_sample_data(seq, LIDAR_CHANNEL, f, n, ts, rel, "pcd", (0, 0), ego_pose)

    def _depth(self, seq: str, cam, f: int, stem: str, ch: str, depths: dict) -> str:
        """Copy one depth map's bytes (a file inside the dataset only, written whole); with a LiDAR, read it
        into `depths` (checked against the rig). Returns its path in the export."""
        ds = self.ds
        dsrc = ds.depth_path(seq, cam.name, f)
        drel = f"{EXPORT_DIR}/depth/{ch}/{stem}.depth.exr"
        try:
            atomic_write_bytes(self.out / drel, ds.read_bytes(dsrc), fsync=False)
        except DatasetError as exc:
            raise ExportError(str(exc)) from None
        if self.lidar is not None:
            try:
                depths[cam.name] = ds.read_depth(seq, cam.name, f)
            except DatasetError as exc:
                raise ExportError(str(exc)) from None
            if depths[cam.name].shape != (cam.height, cam.width):
                raise ExportError(f"{dsrc}: depth is {depths[cam.name].shape[::-1]}, rig.json says "
                                  f"{cam.width}x{cam.height}")
        return drel

    def _finish(self, marker: dict, mask_files: dict, tables: dict) -> None:
        """splits.json, the completed marker, then the tables: into <version>.partial/, then one rename."""
        out, lidar, n_points, chmap = self.out, self.lidar, self.n_points, self.chmap
        write_json(out / SPLITS_FILE, self.splits)
        marker.update({
            "complete": True,
            "channels": {c.name: chmap[c.name] for c in self.ds.cameras},
            "lidar": None if lidar is None else {
                "channel": LIDAR_CHANNEL, "config": lidar.model_dump(mode="json"),
                "points_per_sweep": {"min": int(min(n_points)), "max": int(max(n_points)),
                                     "mean": float(np.mean(n_points))}},
            "fps": self.fps, "timestamp_base_us": BASE_TIMESTAMP_US, "sequence_spacing_us": SEQUENCE_SPACING_US,
            "jpeg_quality": int(self.jpeg_quality), "jpeg": "copied" if self.copy_jpeg else "encoded",
            "pixel_centre": "camera_intrinsic is rig.json K: pixel (c, r) has its centre at (c + 0.5, r + 0.5); "
                            "a projected (u, v) lies in pixel (floor(u), floor(v)). For the integer-centre "
                            "convention subtract 0.5 from K[0][2] and K[1][2].",
            "splits": SPLITS_FILE, "masks": mask_files, "sample_data": self.sd_index, **self.labels.marker(),
        })
        if "trigger" in self.ds.manifest:  # cameras that fire at their own times; a synchronous rig: as before
            marker["trigger"] = self.ds.manifest["trigger"]
        write_json(out / MARKER, marker)
        tmp_dir, final_dir = out / f"{self.version}.partial", out / self.version
        if tmp_dir.exists():
            shutil.rmtree(tmp_dir)
        tmp_dir.mkdir()
        for name in tables:
            write_json(tmp_dir / f"{name}.json", tables[name])
        if final_dir.exists():
            shutil.rmtree(final_dir)
        os.replace(tmp_dir, final_dir)
