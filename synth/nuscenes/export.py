"""Export a finished synth dataset as a nuScenes dataroot (docs/NUSCENES.md).

The official devkit loads the result: ``NuScenes(version="v1.0-synth", dataroot=NS_ROOT)``.
Layout written (and nothing outside ``NS_ROOT``)::

    NS_ROOT/
      <version>/*.json                  the 13 tables the devkit loads, written LAST (into
                                        <version>.partial/, each file tmp + rename, then the folder
                                        is renamed); annotation tables are empty lists
      samples/<CHANNEL>/<seq>__<CHANNEL>__<timestamp_us>.jpg      every frame is a key frame
      samples/LIDAR_TOP/<seq>__LIDAR_TOP__<timestamp_us>.pcd.bin  float32 (x, y, z, intensity, ring)
      maps/<token>.png                  placeholder semantic-prior mask (all background): the devkit
                                        needs one map record with an existing file
      mcdp_synth/export.json            what was exported from what: source dataset, channel map,
                                        LiDAR config, pixel-centre convention, per sample_data the
                                        sequence / frame / camera and the exact depth file
      mcdp_synth/splits.json            {train, val, test: [scene names]} (our sequence ids)
      mcdp_synth/masks/<CHANNEL>.png    self-occlusion masks (255 = scene, 0 = ego body)
      mcdp_synth/depth/<CHANNEL>/<seq>__<CHANNEL>__<timestamp_us>.depth.exr   exact z-depth (copied bytes)
      lidarseg/<version>/*.bin, mcdp_synth/labels/...  a dataset's labels (`synth.nuscenes.lidarseg`)

Conventions: calibrated_sensor is sensor -> ego (translation, rotation quaternion [w, x, y, z]),
ego_pose is ego -> global; our camera frame is OpenCV like nuScenes'. ``camera_intrinsic`` is the
rig's ``K`` unchanged, so its pixel centres are at +0.5: a point that ``view_points`` projects to
(u, v) falls in pixel (floor(u), floor(v)). Tokens are 32 hex digits from a sha256 of the dataset's
config hash and the record's names, so the same dataset always exports the same tables.

Example::

    export_nuscenes("data/tiny", "data/tiny_ns")      # synth export data/tiny --format nuscenes --out data/tiny_ns
"""
from __future__ import annotations

import datetime as _dt
import hashlib
import json
import os
import shutil
from pathlib import Path

import cv2
import numpy as np

from corelib.atomic import atomic_write_bytes
from corelib.rundir import lock_folder
from synth.dataset import is_plain_name
from synth.open import open_dataset
from synth.files import DatasetError, read_json, read_png, write_json, write_png
from synth.lidar import LidarConfig, luma
from synth.nuscenes.lidarseg import LIDARSEG_DIR, ExportLabels
from synth.nuscenes.geometry import rotation_to_quaternion

FORMAT = "mcdp-synth-nuscenes-export"
FORMAT_VERSION = 1
DEFAULT_VERSION = "v1.0-synth"
EXPORT_DIR = "mcdp_synth"
MARKER = f"{EXPORT_DIR}/export.json"
SPLITS_FILE = f"{EXPORT_DIR}/splits.json"
# nuScenes' camera channels, clockwise from the front as in nuScenes
NUSCENES_CAMERAS = ("CAM_FRONT", "CAM_FRONT_RIGHT", "CAM_BACK_RIGHT", "CAM_BACK", "CAM_BACK_LEFT", "CAM_FRONT_LEFT")
LIDAR_CHANNEL = "LIDAR_TOP"
TABLES = ("category", "attribute", "visibility", "instance", "sensor", "calibrated_sensor", "ego_pose", "log",
          "scene", "sample", "sample_data", "sample_annotation", "map")
# what an export owns at the top of NS_ROOT (anything else there makes a re-export refuse)
_OWNED = ("samples", "sweeps", "maps", EXPORT_DIR, LIDARSEG_DIR)
LOCK = ".lock"  # held while an export writes the folder (a second writer is refused, naming the pid)
BASE_TIMESTAMP_US = 1_577_836_800 * 10**6   # 2020-01-01T00:00:00Z
SEQUENCE_SPACING_US = 86_400 * 10**6        # sequence k starts k days later (a sequence lasts < 6 h)
VEHICLE = "mcdp-synth-ego"


class ExportError(RuntimeError):
    """The export cannot be written (refused output folder, bad source); the message names the file."""


# ----------------------------------------------------------------------------- conventions

def _check_rigid(T: np.ndarray, where: str) -> np.ndarray:
    T = np.asarray(T, np.float64)
    if T.shape != (4, 4) or not np.all(np.isfinite(T)):
        raise ExportError(f"{where}: expected a finite 4x4 transform, got shape {T.shape}")
    R = T[:3, :3]
    if not np.allclose(R @ R.T, np.eye(3), atol=1e-5) or np.linalg.det(R) < 0.999 or \
            not np.allclose(T[3], [0, 0, 0, 1], atol=1e-9):
        raise ExportError(f"{where}: not a rigid transform (rotation not orthonormal or last row not 0 0 0 1)")
    return T


def channel_map(cameras) -> dict[str, str]:
    """Our camera name -> nuScenes channel. Names that already are nuScenes channels are kept (their yaw
    must agree: FRONT near 0, *_LEFT positive = to the left, *_RIGHT negative, BACK near 180); otherwise
    channels are assigned by yaw, clockwise from the camera nearest the front."""
    names = [c.name for c in cameras]
    if len(cameras) != 6:
        raise ExportError(f"rig has {len(cameras)} cameras ({names}); a nuScenes export needs the six of a "
                          "surround rig")
    if sorted(names) == sorted(NUSCENES_CAMERAS):
        mapping = {n: n for n in names}
    else:
        yaw = {c.name: (c.yaw_deg + 180.0) % 360.0 - 180.0 for c in cameras}
        front = min(names, key=lambda n: abs(yaw[n]))
        # clockwise = decreasing yaw, starting at the front camera
        order = sorted(names, key=lambda n: (yaw[front] - yaw[n]) % 360.0)
        mapping = dict(zip(order, NUSCENES_CAMERAS))
    for c in cameras:
        ch, y = mapping[c.name], (c.yaw_deg + 180.0) % 360.0 - 180.0
        ok = {"CAM_FRONT": abs(y) < 45, "CAM_BACK": abs(y) > 135,
              "CAM_FRONT_LEFT": 0 < y < 135, "CAM_BACK_LEFT": 45 < y < 180,
              "CAM_FRONT_RIGHT": -135 < y < 0, "CAM_BACK_RIGHT": -180 < y < -45}[ch]
        if not ok:
            raise ExportError(f"rig.json: camera {c.name} (yaw {c.yaw_deg:+.1f} deg, positive = left) cannot be "
                              f"nuScenes channel {ch}")
    return mapping


class _Tokens:
    def __init__(self, namespace: str) -> None:
        self.ns = namespace

    def __call__(self, kind: str, *parts) -> str:
        key = json.dumps([self.ns, kind, *[str(p) for p in parts]])
        return hashlib.sha256(key.encode()).hexdigest()[:32]


def timestamp_us(seq_index: int, frame: int, fps: float) -> int:
    """Microseconds since the epoch of `frame` in the `seq_index`-th sequence (sorted ids)."""
    return BASE_TIMESTAMP_US + seq_index * SEQUENCE_SPACING_US + int(round(frame * 1e6 / fps))


# ----------------------------------------------------------------------------- output folder

def _prepare_output(out: Path, config_hash: str, version: str, clean: bool = True) -> None:
    """Refuse anything but a new/empty folder or a previous export of the same dataset (then remove what
    that export wrote, version tables first, so a half-written re-export is never loadable)."""
    if out.exists() and not out.is_dir():
        raise ExportError(f"{out}: exists and is not a folder")
    if out.is_symlink():
        raise ExportError(f"{out}: is a symlink; give the real folder")
    if not out.is_dir() or not any(p.name != LOCK for p in out.iterdir()):
        return
    marker = out / MARKER
    if not marker.is_file():
        raise ExportError(f"{out}: folder is not empty and holds no nuScenes export of a synth dataset "
                          f"(no {MARKER}); choose an empty or new folder")
    try:
        prev = read_json(marker)
    except DatasetError as exc:
        raise ExportError(str(exc)) from None
    if not isinstance(prev, dict) or prev.get("format") != FORMAT:
        raise ExportError(f"{marker}: not an export marker of {FORMAT}; refusing to overwrite {out}")
    prev_hash = (prev.get("source") or {}).get("config_hash")
    if prev_hash != config_hash:
        raise ExportError(f"{out}: holds the export of another dataset (config_hash {str(prev_hash)[:12]}..., "
                          f"this one {config_hash[:12]}...); choose another --out")
    versions = {str(v) for v in [prev.get("version"), version] if v}
    owned = set(_OWNED) | versions | {f"{v}.partial" for v in versions} | {LOCK}
    for p in sorted(out.iterdir()):
        if p.name not in owned:
            raise ExportError(f"{p}: not part of the previous export in {out}; refusing to overwrite it")
        if p.is_symlink():
            raise ExportError(f"{p}: is a symlink; an export writes inside {out} only")
    if not clean:
        return
    for name in sorted(versions) + sorted(f"{v}.partial" for v in versions) + list(_OWNED):
        p = out / name
        if p.is_dir():
            shutil.rmtree(p)
        elif p.exists():
            p.unlink()


def _write_jpeg(path: Path, rgb: np.ndarray, quality: int) -> None:
    ok, buf = cv2.imencode(".jpg", np.ascontiguousarray(rgb[:, :, ::-1]), [cv2.IMWRITE_JPEG_QUALITY, int(quality)])
    if not ok:
        raise ExportError(f"{path}: could not encode JPEG")
    atomic_write_bytes(path, buf.tobytes(), fsync=False)  # whole or absent; the tables, written last, seal


# ----------------------------------------------------------------------------- export

def export_nuscenes(dataset: str | Path, out: str | Path, version: str = DEFAULT_VERSION,
                    lidar: LidarConfig | None = LidarConfig(), jpeg_quality: int = 95,
                    progress: bool = False, labels: bool = True) -> dict:
    """Write the nuScenes dataroot `out` from the synth dataset `dataset`; returns a summary dict.
    `lidar=None` exports cameras only (no LIDAR_TOP); `labels=False` leaves a dataset's labels out."""
    ex = _Export(Path(dataset), Path(out), version, lidar, jpeg_quality, labels)  # the source checked
    _prepare_output(ex.out, ex.cfg_hash, version, clean=False)  # refuse a foreign folder before writing a byte
    ex.out.mkdir(parents=True, exist_ok=True)
    lock = lock_folder(ex.out, LOCK)  # a second export into `out` is refused, naming this pid
    try:
        _prepare_output(ex.out, ex.cfg_hash, version)  # under the lock: remove what a previous export wrote
        return ex.run(progress)
    finally:
        lock.release()


class _Export:
    """One export: the source's checks (constructor), then `run`: the marker, the static rig (sensors,
    calibration, masks, map), every sequence's frames (JPEG, depth copy, LiDAR sweep, table rows), and the
    tables last."""

    def __init__(self, src: Path, out: Path, version: str, lidar: LidarConfig | None, jpeg_quality: int,
                 labels: bool = True) -> None:
        if not is_plain_name(version) or version in _OWNED or version.endswith(".partial"):
            raise ExportError(f"--version {version!r} is not a plain folder name (letters, digits, . _ -)")
        if not 1 <= int(jpeg_quality) <= 100:
            raise ExportError(f"jpeg quality {jpeg_quality} is not in 1..100")
        try:
            ds = open_dataset(src)
        except DatasetError as exc:
            raise ExportError(str(exc)) from None
        if src.resolve() == out.resolve() or out.resolve().is_relative_to(src.resolve()):
            raise ExportError(f"{out}: inside the source dataset {src}; choose a folder outside it")
        if not ds.has_depth and lidar is not None:
            raise ExportError(f"{src / 'manifest.json'}: dataset has no depth; export with --no-lidar")
        self.chmap = channel_map(ds.cameras)
        self.cfg_hash = str(ds.manifest.get("config_hash") or "")
        if not self.cfg_hash:
            raise ExportError(f"{src / 'manifest.json'}: no config_hash")
        self.src, self.out, self.ds, self.version, self.lidar, self.jpeg_quality = \
            src, out, ds, version, lidar, jpeg_quality
        self.fps = ds.fps
        self.seqs = ds.sequences
        self.splits = {s: ds.split(s) for s in ("train", "val", "test") if s in ds.manifest.get("splits", {})}
        self.split_of = {q: s for s, qs in self.splits.items() for q in qs}
        self.tok = _Tokens(self.cfg_hash)
        self.logs, self.scenes, self.samples, self.sample_data, self.ego_poses = [], [], [], [], []
        self.sd_index: dict[str, dict] = {}
        self.n_points: list[int] = []
        self.labels = ExportLabels(ds, out, version, self.tok, labels, ExportError)

    def run(self, progress: bool) -> dict:
        ds, out, tok = self.ds, self.out, self.tok
        (out / EXPORT_DIR).mkdir(exist_ok=True)
        marker = {"format": FORMAT, "format_version": FORMAT_VERSION, "complete": False, "version": self.version,
                  "source": {"path": str(self.src.resolve()), "config_hash": self.cfg_hash,
                             "generator_version": ds.manifest.get("generator_version"), "seed": ds.manifest.get("seed")}}
        write_json(out / MARKER, marker)
        sensors, calibrated = self._calibration()
        mask_files = self._masks()
        # placeholder map
        map_token = tok("map", "semantic_prior")
        (out / "maps").mkdir(exist_ok=True)
        write_png(out / "maps" / f"{map_token}.png", np.zeros((8, 8), np.uint8))
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
        tables = {
            "category": [], "attribute": [], "visibility": [], "instance": [], "sample_annotation": [],
            "sensor": sensors, "calibrated_sensor": calibrated, "ego_pose": self.ego_poses, "log": self.logs,
            "scene": self.scenes, "sample": self.samples, "sample_data": self.sample_data,
            "map": [{"token": map_token, "log_tokens": [lg["token"] for lg in self.logs], "category": "semantic_prior",
                     "filename": f"maps/{map_token}.png"}],
            **self.labels.tables(),  # a dataset with labels: category (with index) and lidarseg
        }
        self._finish(marker, mask_files, tables)
        return {"out": str(out), "version": self.version, "scenes": len(self.scenes), "samples": len(self.samples),
                "sample_data": len(self.sample_data), "channels": self.channels, "lidarseg": len(self.labels.records),
                "lidar_points_per_sweep": None if self.lidar is None else float(np.mean(self.n_points))}

    def _calibration(self) -> tuple[list[dict], list[dict]]:
        """The sensor and calibrated_sensor records of the static rig (+ LIDAR_TOP); sets `cs_token` and
        `channels` (the cameras' in rig order, then LIDAR_TOP)."""
        sensors, calibrated = [], []
        self.cs_token: dict[str, str] = {}
        tok, lidar = self.tok, self.lidar
        for cam in self.ds.cameras:
            ch = self.chmap[cam.name]
            T = _check_rigid(cam.T_ego_cam, f"{self.src / 'rig.json'} camera {cam.name} T_ego_cam")
            st, ct = tok("sensor", ch), tok("calibrated_sensor", ch)
            sensors.append({"token": st, "channel": ch, "modality": "camera"})
            calibrated.append({"token": ct, "sensor_token": st, "translation": [float(x) for x in T[:3, 3]],
                               "rotation": rotation_to_quaternion(T[:3, :3]),
                               "camera_intrinsic": [[float(x) for x in row] for row in cam.K]})
            self.cs_token[ch] = ct
        self.channels = [self.chmap[c.name] for c in self.ds.cameras]
        if lidar is not None:
            T = lidar.T_ego_lidar()
            st, ct = tok("sensor", LIDAR_CHANNEL), tok("calibrated_sensor", LIDAR_CHANNEL)
            sensors.append({"token": st, "channel": LIDAR_CHANNEL, "modality": "lidar"})
            calibrated.append({"token": ct, "sensor_token": st, "translation": [float(x) for x in T[:3, 3]],
                               "rotation": rotation_to_quaternion(T[:3, :3]), "camera_intrinsic": []})
            self.cs_token[LIDAR_CHANNEL] = ct
            self.channels.append(LIDAR_CHANNEL)
        return sensors, calibrated

    def _masks(self) -> dict[str, str]:
        """Copy the self-occlusion masks (checked against the rig); sets `masks` (scene = True, for the LiDAR);
        returns the channel -> file map of the marker."""
        ds, out = self.ds, self.out
        (out / EXPORT_DIR / "masks").mkdir(parents=True, exist_ok=True)
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
            write_png(out / EXPORT_DIR / "masks" / f"{ch}.png", m)
            mask_files[ch] = f"{EXPORT_DIR}/masks/{ch}.png"
        return mask_files

    def _sequence(self, si: int, seq: str, bar) -> None:
        """The `si`-th sequence: its log, samples, every frame's files and records, its scene."""
        ds, tok, fps = self.ds, self.tok, self.fps
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
        log_token, scene_token = tok("log", seq), tok("scene", seq)
        t0 = timestamp_us(si, 0, fps)
        date = _dt.datetime.fromtimestamp(t0 / 1e6, _dt.timezone.utc).strftime("%Y-%m-%d")
        self.logs.append({"token": log_token, "logfile": seq, "vehicle": VEHICLE, "date_captured": date,
                          "location": f"synth-{family}"})
        sample_tokens = [tok("sample", seq, f) for f in range(n)]
        sd_tokens = {ch: [tok("sample_data", seq, ch, f) for f in range(n)] for ch in self.channels}
        for f in range(n):
            fr = ego[f]
            ts = timestamp_us(si, f, fps)
            if abs(float(fr.get("timestamp_s", f / fps)) - f / fps) > 1e-6:
                raise ExportError(f"{ego_path}: frame {f} timestamp_s {fr.get('timestamp_s')} is not frame / fps "
                                  f"= {f / fps}")
            T_we = _check_rigid(fr.get("T_world_ego"), f"{ego_path} frame {f} T_world_ego")
            self.samples.append({"token": sample_tokens[f], "timestamp": ts, "scene_token": scene_token,
                                 "prev": sample_tokens[f - 1] if f > 0 else "",
                                 "next": sample_tokens[f + 1] if f + 1 < n else ""})
            pose = {"translation": [float(x) for x in T_we[:3, 3]], "rotation": rotation_to_quaternion(T_we[:3, :3]),
                    "timestamp": ts}
            self._frame(seq, f, n, ts, sample_tokens[f], sd_tokens, pose)
            if bar is not None:
                bar.update(1)
        desc = f"mcdp-synth {family}, {info.get('time_of_day', '?')}, split {self.split_of.get(seq, '-')}"
        self.scenes.append({"token": scene_token, "name": seq, "description": desc, "log_token": log_token,
                            "nbr_samples": n, "first_sample_token": sample_tokens[0],
                            "last_sample_token": sample_tokens[-1]})

    def _frame(self, seq: str, f: int, n: int, ts: int, sample_token: str, sd_tokens: dict, pose: dict) -> None:
        """Frame `f` of `seq`: every camera's JPEG (+ depth copy), then the LiDAR sweep simulated from them."""
        ds, out, lidar = self.ds, self.out, self.lidar
        depths, grays = {}, {}
        for cam in ds.cameras:
            ch = self.chmap[cam.name]
            token = sd_tokens[ch][f]
            stem = f"{seq}__{ch}__{ts}"
            try:
                rgb = ds.read_rgb(seq, cam.name, f)
            except DatasetError as exc:
                raise ExportError(str(exc)) from None
            if rgb.shape[:2] != (cam.height, cam.width):
                raise ExportError(f"{ds.rgb_path(seq, cam.name, f)}: {rgb.shape[1]}x{rgb.shape[0]}, rig.json "
                                  f"says {cam.width}x{cam.height}")
            rel = f"samples/{ch}/{stem}.jpg"
            _write_jpeg(out / rel, rgb, self.jpeg_quality)
            entry = {"sequence": seq, "frame": f, "camera": cam.name, "channel": ch,
                     **self.labels.camera(seq, cam.name, f, ch, stem)}
            if ds.has_depth:
                entry["depth"] = self._depth(seq, cam, f, stem, ch, depths)
                if lidar is not None:
                    grays[cam.name] = luma(rgb)
            self.sd_index[token] = entry
            self.sample_data.append(_sd_record(token, sample_token, self.cs_token[ch], rel, "jpg", cam.width,
                                               cam.height, ts, sd_tokens[ch], f, n))
            self.ego_poses.append({"token": token, **pose})
        if lidar is not None:
            token = sd_tokens[LIDAR_CHANNEL][f]
            rel = f"samples/{LIDAR_CHANNEL}/{seq}__{LIDAR_CHANNEL}__{ts}.pcd.bin"
            pts = self.labels.sweep(token, lidar, list(ds.cameras), depths, self.masks, grays)
            atomic_write_bytes(out / rel, pts.astype("<f4").tobytes(), fsync=False)
            self.n_points.append(len(pts))
            self.sd_index[token] = {"sequence": seq, "frame": f, "channel": LIDAR_CHANNEL, "points": int(len(pts)),
                                    **self.labels.entry(token)}
            self.sample_data.append(_sd_record(token, sample_token, self.cs_token[LIDAR_CHANNEL], rel, "pcd", 0, 0,
                                               ts, sd_tokens[LIDAR_CHANNEL], f, n))
            self.ego_poses.append({"token": token, **pose})

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
            "lidar": None if lidar is None else {"channel": LIDAR_CHANNEL, "config": lidar.model_dump(mode="json"),
                                                 "points_per_sweep": {"min": int(min(n_points)), "max": int(max(n_points)),
                                                                      "mean": float(np.mean(n_points))}},
            "fps": self.fps, "timestamp_base_us": BASE_TIMESTAMP_US, "sequence_spacing_us": SEQUENCE_SPACING_US,
            "jpeg_quality": int(self.jpeg_quality),
            "pixel_centre": "camera_intrinsic is rig.json K: pixel (c, r) has its centre at (c + 0.5, r + 0.5); "
                            "a projected (u, v) lies in pixel (floor(u), floor(v)). For the integer-centre "
                            "convention subtract 0.5 from K[0][2] and K[1][2].",
            "splits": SPLITS_FILE, "masks": mask_files, "sample_data": self.sd_index, **self.labels.marker(),
        })
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


def _sd_record(token, sample_token, cs_token, filename, fileformat, width, height, ts, chain, f, n) -> dict:
    return {"token": token, "sample_token": sample_token, "ego_pose_token": token,
            "calibrated_sensor_token": cs_token, "filename": filename, "fileformat": fileformat,
            "width": int(width), "height": int(height), "timestamp": ts, "is_key_frame": True,
            "next": chain[f + 1] if f + 1 < n else "", "prev": chain[f - 1] if f > 0 else ""}
