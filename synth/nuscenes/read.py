"""Read a nuScenes dataroot (ours from `synth export --format nuscenes`, or the real one) as a `Dataset`.

`open_nuscenes(root)` loads the tables with the official devkit (``nuscenes-devkit``, the ``nuscenes``
extra; where it is not installed, as beside the ``viz`` extra, the same records are read as plain JSON
and the devkit's LiDAR reader, projection and quaternion are replaced by the same numpy) and returns a `NuScenesDataset` with the interface `mcdp` uses (`synth.protocol.DatasetReader`):
cameras, neighbours, splits, sequences, ego poses, RGB, depth, masks. `synth.open.open_dataset`
calls it for a folder that looks like a dataroot (`is_nuscenes_root`). docs/NUSCENES.md, "Reading a
nuScenes dataroot", has the mapping and its limits; in short:

- sequences = scenes (name = scene name), frames = the scene's key-frame samples in prev/next order;
- cameras = the six CAM_* channels in rig order (`RIG_ORDER`, the export's order), ring neighbours;
  K = ``camera_intrinsic`` (+0.5 on cx, cy for a dataroot without our ``mcdp_synth/export.json``:
  nuScenes is taken to use integer pixel centres, ours puts them at +0.5), T_ego_cam =
  ``calibrated_sensor`` (must be the same for every sample: one rig);
- T_world_ego = the ego_pose of each sample's CAM_FRONT sample_data;
- depth = the sample's LIDAR_TOP sweep projected into the camera with the devkit's chain
  (lidar -> ego at lidar time -> global -> ego at camera time -> camera), z at pixel
  (floor(u), floor(v)) in our +0.5-centre K, nearest point per pixel, kept in
  [`LIDAR_MIN_DEPTH`, `LIDAR_MAX_DEPTH`] m, 0 elsewhere;
- masks = ``mcdp_synth/masks/<CHANNEL>.png``, else ``masks=`` folder, else all scene (one warning).

Every problem is a `DatasetError` of one line naming the token, file or channel.

Example::

    ds = open_nuscenes("NS_ROOT")          # or synth.open.open_dataset("NS_ROOT")
    d = ds.read_depth(ds.split("test")[0], "CAM_FRONT", 1)   # sparse LiDAR z-depth, 0 = none
"""
from __future__ import annotations

import warnings
from pathlib import Path

import numpy as np

from synth.files import DatasetError, read_image, read_json, read_png, regular_file, within
from synth.label_reader import NoLabels
from synth.nuscenes.geometry import check_intrinsic, lidar_xyz, pose_matrix, view_points
from synth.nuscenes.layout import EXPORT_DIR
from synth.nuscenes.tables import get_record, load_tables, read_splits, resolve_version
from synth.rig import CameraSpec
from synth.sizes import shared_size, size_keys

RIG_ORDER = ("CAM_FRONT", "CAM_FRONT_RIGHT", "CAM_BACK_RIGHT", "CAM_BACK", "CAM_BACK_LEFT", "CAM_FRONT_LEFT")
LIDAR = "LIDAR_TOP"
RING = tuple((i, (i + 1) % 6) for i in range(6))
# depth range of the projected LiDAR (SurroundDepth configs/nusc.txt: min_depth 0.1, max_depth 80;
# VFDepth configs/nuscenes/*: eval_max_depth 80); the evaluator applies its own range on top
LIDAR_MIN_DEPTH = 0.1
LIDAR_MAX_DEPTH = 80.0
RIG_TOL = 1e-9  # calibrated_sensor values that differ by more are two rigs
NO_MASKS = "no self-occlusion masks: every pixel counts as scene"


def _angles(K: np.ndarray, T: np.ndarray, width: int) -> tuple[float, float, float]:
    """(hfov, yaw, pitch) in degrees of a camera (yaw CCW from ego x, as synth.rig)."""
    axis = T[:3, :3] @ np.array([0.0, 0.0, 1.0])
    hfov = float(np.degrees(2 * np.arctan2(width / 2.0, K[0, 0])))
    return hfov, float(np.degrees(np.arctan2(axis[1], axis[0]))), float(np.degrees(np.arcsin(np.clip(axis[2], -1, 1))))


class NuScenesDataset(NoLabels):
    format = "nuscenes"  # `synth.protocol.DatasetReader.format`
    """A nuScenes dataroot as a `synth.protocol.DatasetReader` (module docstring). Holds plain
    records only (the devkit object is dropped after `open_nuscenes`), so it pickles cheaply."""

    def __init__(self, root: Path, version: str, cameras: list[CameraSpec], frames: dict[str, list[dict]],
                 splits: dict[str, list[str]], split_source: str, fps: float, masks: dict[str, np.ndarray],
                 mask_source: str, has_depth: bool, pixel_centre: str) -> None:
        self.root = root
        self.version = version
        self.cameras = cameras
        self.camera_names = [c.name for c in cameras]
        self.neighbours = list(RING)
        self._frames = frames
        self._splits = splits
        self.split_source = split_source
        self._fps = fps
        self._masks = masks
        self.mask_source = mask_source
        self._has_depth = has_depth
        self.pixel_centre = pixel_centre
        self._points_cache: tuple | None = None
        self.manifest = {
            "format": "nuscenes", "version": version, "dataroot": str(root), "fps": fps,
            "cameras": list(self.camera_names),
            **size_keys((cameras[0].width, cameras[0].height), cameras),  # channels may differ in size
            "splits": {k: list(v) for k, v in splits.items()}, "split_source": split_source,
            "sequences": {s: {"frames": len(f), "scene_token": f[0]["scene_token"]} for s, f in frames.items()},
            "has_depth": has_depth, "ground_truth": self.ground_truth, "masks": mask_source,
            "pixel_centre": pixel_centre,
        }

    # --------------------------------------------------------------- the DatasetReader interface
    @property
    def width(self) -> int:
        """The image width every channel shares; channels of several sizes have none (`synth.sizes.shared_size`)."""
        return shared_size(self.root, self.cameras)[0]

    @property
    def height(self) -> int:
        """The image height every channel shares (`width`)."""
        return shared_size(self.root, self.cameras)[1]

    @property
    def fps(self) -> float:
        return self._fps

    @property
    def has_depth(self) -> bool:
        return self._has_depth

    @property
    def ground_truth(self) -> dict:
        """Provenance of `read_depth` (copied into the evaluator's metrics)."""
        return {"kind": "lidar",
                "description": f"{LIDAR} key-frame sweep (one per sample, no sweeps/) projected into each camera "
                               "with the devkit's chain (lidar -> ego at lidar time -> global -> ego at camera "
                               "time -> camera): sparse z-depth at pixel (floor(u), floor(v)), nearest point per "
                               "pixel, 0 = no return",
                "channel": LIDAR, "min_depth": LIDAR_MIN_DEPTH, "max_depth": LIDAR_MAX_DEPTH,
                "pixel_centre": self.pixel_centre, "dataroot": str(self.root), "version": self.version,
                "note": "overlap / non_overlap and Dep Con are computed on LiDAR pixels only; the overlap "
                        "z-test uses the neighbour's sparse depth (3x3 maximum)"}

    @property
    def sequences(self) -> list[str]:
        return sorted(self._frames)

    def split(self, name: str) -> list[str]:
        if name not in self._splits:
            raise DatasetError(f"{self.root}: no split {name!r} (has {sorted(self._splits)})")
        seqs = list(self._splits[name])
        if not seqs and self.split_source.startswith("nuscenes"):
            raise DatasetError(f"{self.root}: split {name!r} is empty: no scene of {self.version} is in the "
                               f"devkit's official {name} split and there is no {EXPORT_DIR}/splits.json "
                               "({train, val, test: [scene names]}); write one")
        return seqs

    def n_frames(self, seq: str) -> int:
        return len(self._seq(seq))

    def _seq(self, seq: str) -> list[dict]:
        if seq not in self._frames:
            raise DatasetError(f"{self.root}: no scene named {seq!r}")
        return self._frames[seq]

    def _rec(self, seq: str, frame: int) -> dict:
        fr = self._seq(seq)
        if not 0 <= frame < len(fr):
            raise DatasetError(f"{self.root}: scene {seq} has {len(fr)} key frames, asked for frame {frame}")
        return fr[frame]

    def ego(self, seq: str) -> list[dict]:
        return [{"timestamp_s": f["timestamp_s"], "T_world_ego": f["T_world_ego"].tolist(),
                 "sample_token": f["sample_token"]} for f in self._seq(seq)]

    def T_world_ego(self, seq: str) -> np.ndarray:
        return np.stack([f["T_world_ego"] for f in self._seq(seq)]).astype(np.float64)

    def rgb_path(self, seq: str, cam: str, frame: int) -> Path:
        return self.root / self._cam(seq, cam, frame)["filename"]

    def depth_path(self, seq: str, cam: str, frame: int) -> Path:
        """The LIDAR_TOP file the camera's depth is projected from."""
        self._cam(seq, cam, frame)
        lid = self._rec(seq, frame).get("lidar")
        if lid is None:
            raise DatasetError(f"{self.root}: sample {self._rec(seq, frame)['sample_token']} has no {LIDAR}")
        return self.root / lid["filename"]

    def _cam(self, seq: str, cam: str, frame: int) -> dict:
        rec = self._rec(seq, frame)
        if cam not in rec["cams"]:
            raise DatasetError(f"{self.root}: no camera {cam!r} (channels {self.camera_names})")
        return rec["cams"][cam]

    def _spec(self, cam: str) -> CameraSpec:
        return self.cameras[self.camera_names.index(cam)]

    def read_rgb(self, seq: str, cam: str, frame: int) -> np.ndarray:
        """(H, W, 3) uint8 RGB; DatasetError naming the file if it is missing, outside the dataroot, not
        of the format its name says (`synth.files.read_image`) or of another size."""
        p = self.rgb_path(seq, cam, frame)
        img = read_image(within(self.root, p, f"sample_data {self._cam(seq, cam, frame)['token']}"))
        c = self._spec(cam)
        if img.shape[:2] != (c.height, c.width):
            raise DatasetError(f"{p}: the image is {img.shape[1]}x{img.shape[0]}, the first {cam} image is "
                               f"{c.width}x{c.height}")
        return img

    def _global_points(self, seq: str, frame: int) -> np.ndarray:
        """(3, N) float64 LiDAR points of a sample in the global frame (cached for the last sample)."""
        key = (seq, frame)
        if self._points_cache is not None and self._points_cache[0] == key:
            return self._points_cache[1]
        p = self.depth_path(seq, frame=frame, cam=self.camera_names[0])
        lid = self._rec(seq, frame)["lidar"]
        regular_file(p, self.root, f"sample_data {lid['token']}")
        try:
            pts = lidar_xyz(p).astype(np.float64)
        except Exception as exc:  # noqa: BLE001 - the devkit raises bare errors for unreadable files
            raise DatasetError(f"{p}: missing or not a readable LiDAR point cloud ({type(exc).__name__}: "
                               f"{str(exc)[:80]})") from None
        T = lid["T_world_ego"] @ lid["T_ego_lidar"]  # lidar -> ego at lidar time -> global
        g = T[:3, :3] @ pts + T[:3, 3:4]
        self._points_cache = (key, g)
        return g

    def lidar_points_world(self, seq: str, frame: int) -> np.ndarray:
        """(N, 3) float64 LiDAR points of a sample in the global frame (`synth.view` records them)."""
        return self._global_points(seq, frame).T

    def read_depth(self, seq: str, cam: str, frame: int) -> np.ndarray:
        """(H, W) float32 sparse z-depth (m) from the sample's LIDAR_TOP, 0 = no return (module docstring)."""
        c, rec = self._spec(cam), self._cam(seq, cam, frame)
        g = self._global_points(seq, frame)
        T = np.linalg.inv(rec["T_world_ego"] @ c.T_ego_cam)  # global -> ego at camera time -> camera
        pc = T[:3, :3] @ g + T[:3, 3:4]
        z = pc[2]
        keep = (z >= LIDAR_MIN_DEPTH) & (z <= LIDAR_MAX_DEPTH)
        uv = view_points(pc[:, keep], c.K)
        u, v, z = np.floor(uv[0]), np.floor(uv[1]), z[keep]
        inside = (u >= 0) & (u < c.width) & (v >= 0) & (v < c.height)
        u, v, z = u[inside].astype(np.int64), v[inside].astype(np.int64), z[inside]
        depth = np.full(c.height * c.width, np.inf)
        np.minimum.at(depth, v * c.width + u, z)  # nearest point wins
        depth[~np.isfinite(depth)] = 0.0
        return depth.reshape(c.height, c.width).astype(np.float32)

    def mask(self, cam: str) -> np.ndarray:
        """(H, W) bool, True = scene, False = ego body."""
        if cam not in self._masks:
            raise DatasetError(f"{self.root}: no camera {cam!r} (channels {self.camera_names})")
        return self._masks[cam]


# ----------------------------------------------------------------------------- open


def _masks(root: Path, cameras: list[CameraSpec], masks) -> tuple[dict[str, np.ndarray], str]:
    ours = root / EXPORT_DIR / "masks"
    if ours.is_dir():
        folder, source = within(root, ours, "the masks folder"), f"{EXPORT_DIR}/masks"
    elif masks is not None:
        folder, source = Path(masks), str(masks)
        if not folder.is_dir():
            raise DatasetError(f"{folder}: masks folder does not exist")
    else:
        warnings.warn(f"{root}: {ours} is missing and no masks= folder was given: {NO_MASKS}", stacklevel=3)
        return {c.name: np.ones((c.height, c.width), bool) for c in cameras}, "none (all scene)"
    out = {}
    for c in cameras:
        p = folder / f"{c.name}.png"
        m = read_png(within(root, p, "a mask") if folder == ours else p, gray=True)
        if m.shape != (c.height, c.width):
            raise DatasetError(f"{p}: the mask is {m.shape[1]}x{m.shape[0]}, the {c.name} images are "
                               f"{c.width}x{c.height}")
        out[c.name] = m > 127
    return out, source


def open_nuscenes(root: str | Path, version: str | None = None, masks: str | Path | None = None,
                  pixel_centre: str | None = None) -> NuScenesDataset:
    """Open a nuScenes dataroot through the devkit (module docstring).

    Args:
        root: the dataroot (holds ``samples/`` and the version folder).
        version: e.g. ``v1.0-mini``; None = the one folder holding ``sample.json`` (several: refused).
        masks: folder of ``<CHANNEL>.png`` self-occlusion masks (255 = scene), used when the dataroot has
            no ``mcdp_synth/masks``; neither: every pixel is scene (one warning).
        pixel_centre: ``"half"`` (camera_intrinsic puts pixel centres at +0.5, our export) or ``"integer"``
            (OpenCV / nuScenes: K gets +0.5 on cx, cy); None = ``half`` if ``mcdp_synth/export.json``
            exists, else ``integer``.
    """
    root = Path(root)
    if not root.is_dir():
        raise DatasetError(f"{root}: dataset folder does not exist")
    version = resolve_version(root, version)
    export, pixel_centre = _export_record(root, pixel_centre)
    scan = _Scan(root, version, load_tables(root, version))
    frames = scan.frames()
    cameras = scan.cameras(pixel_centre)
    m, mask_source = _masks(root, cameras, masks)
    splits, split_source = read_splits(root, list(frames), version)
    return NuScenesDataset(root, version, cameras, frames, splits, split_source, _fps(export, frames), m, mask_source,
                           scan.n_lidar > 0, pixel_centre)


def _export_record(root: Path, pixel_centre: str | None) -> tuple[dict | None, str]:
    """Our export's ``mcdp_synth/export.json`` (None: not our export) and the pixel-centre convention."""
    marker = root / EXPORT_DIR / "export.json"
    export = None
    if marker.exists() or marker.is_symlink():
        export = read_json(marker, root, "the export record")
    if pixel_centre is None:
        pixel_centre = "half" if export is not None else "integer"
    if pixel_centre not in ("half", "integer"):
        raise DatasetError(f"pixel_centre must be 'half' or 'integer', got {pixel_centre!r}")
    return export, pixel_centre


def _fps(export: dict | None, frames: dict[str, list[dict]]) -> float:
    """Our export's fps, else 1 / the median time between key frames (NaN without two frames)."""
    if export is not None and isinstance(export.get("fps"), (int, float)):
        return float(export["fps"])
    dts = [b["timestamp_s"] - a["timestamp_s"] for fs in frames.values() for a, b in zip(fs, fs[1:])]
    return float(1.0 / np.median(dts)) if dts and np.median(dts) > 0 else float("nan")


class _Scan:
    """The tables read into the reader's records: the scenes' key frames (`frames`), then the rig (`cameras`)."""

    def __init__(self, root: Path, version: str, nusc) -> None:
        self.root, self.nusc, self.tab = root, nusc, root / version
        channels = {s["channel"] for s in nusc.sensor}
        for ch in RIG_ORDER:
            if ch not in channels:
                raise DatasetError(f"{self.tab / 'sensor.json'}: no camera channel {ch} (has {sorted(channels)}); "
                                   f"the rig needs {', '.join(RIG_ORDER)}")
        self.calib: dict[str, tuple] = {}  # channel -> (values, token) of the first sample's calibrated_sensor
        self.first_file: dict[str, Path] = {}  # channel -> its first image, and the sizes its sample_data give
        self.sizes: dict[str, set] = {}
        self.n_lidar = self.n_samples = 0

    def frames(self) -> dict[str, list[dict]]:
        """Scene name -> its key frames in prev/next order (``timestamp_s`` from the scene's first)."""
        tab, frames = self.tab, {}
        for scene in sorted(self.nusc.scene, key=lambda s: s["name"]):
            name = scene["name"]
            if name in frames:
                raise DatasetError(f"{tab / 'scene.json'}: two scenes named {name!r}")
            out = [self._frame(s, scene) for s in self._samples(scene)]
            t0 = out[0]["timestamp_s"]
            for fr in out:
                fr["timestamp_s"] -= t0
            frames[name] = out
        if not frames:
            raise DatasetError(f"{tab / 'scene.json'}: no scene")
        if 0 < self.n_lidar < self.n_samples:
            missing = next(f["sample_token"] for fs in frames.values() for f in fs if "lidar" not in f)
            raise DatasetError(f"{tab / 'sample_data.json'}: sample {missing} has no key-frame {LIDAR} (others have)")
        return frames

    def _samples(self, scene: dict) -> list[dict]:
        """The scene's samples along the next chain."""
        name, tab = scene["name"], self.tab
        recs, tok, seen = [], scene.get("first_sample_token"), set()
        while tok:
            if tok in seen:
                raise DatasetError(f"{tab / 'sample.json'}: scene {name}: the next chain loops at sample {tok}")
            seen.add(tok)
            s = get_record(self.nusc, "sample", tok, f"scene {name} ({scene['token']})")
            recs.append(s)
            tok = s.get("next")
        if not recs:
            raise DatasetError(f"{tab / 'scene.json'}: scene {name} has no sample")
        return recs

    def _frame(self, s: dict, scene: dict) -> dict:
        """One sample: its six cameras, the ego pose of CAM_FRONT, its LiDAR sweep if any."""
        self.n_samples += 1
        fr = {"sample_token": s["token"], "scene_token": scene["token"], "cams": {}}
        for ch in RIG_ORDER:
            if ch not in s["data"]:
                raise DatasetError(f"{self.tab / 'sample_data.json'}: sample {s['token']} (scene {scene['name']}) "
                                   f"has no key-frame {ch} sample_data")
            fr["cams"][ch] = self._camera(ch, s, scene["name"])
        front = fr["cams"]["CAM_FRONT"]
        fr["T_world_ego"] = front["T_world_ego"]
        fr["timestamp_s"] = front["timestamp"] / 1e6
        if LIDAR in s["data"]:
            fr["lidar"] = self._lidar(s)
            self.n_lidar += 1
        return fr

    def _camera(self, ch: str, s: dict, name: str) -> dict:
        """Camera `ch` of sample `s`: its file, time and ego pose; its calibration is the rig's (checked)."""
        nusc, tab, calib = self.nusc, self.tab, self.calib
        sd = get_record(nusc, "sample_data", s["data"][ch], f"sample {s['token']}")
        who = f"sample_data {sd['token']} ({ch})"
        cs = get_record(nusc, "calibrated_sensor", sd["calibrated_sensor_token"], who)
        pose = get_record(nusc, "ego_pose", sd["ego_pose_token"], who)
        vals = (np.asarray(cs.get("camera_intrinsic"), np.float64), np.asarray(cs["rotation"], np.float64),
                np.asarray(cs["translation"], np.float64))
        if ch not in calib:
            check_intrinsic(vals[0], f"{tab / 'calibrated_sensor.json'}: calibrated_sensor {cs['token']} ({ch})")
            pose_matrix(vals[1], vals[2], f"{tab / 'calibrated_sensor.json'}: calibrated_sensor {cs['token']} ({ch})")
            calib[ch] = (vals, cs["token"])
        elif cs["token"] != calib[ch][1] and not all(
                a.shape == b.shape and np.allclose(a, b, rtol=0, atol=RIG_TOL) for a, b in zip(vals, calib[ch][0])):
            raise DatasetError(f"{tab / 'calibrated_sensor.json'}: {ch} calibration {cs['token']} (sample "
                               f"{s['token']}, scene {name}) differs from {calib[ch][1]}; one rig is "
                               "modelled: open a dataroot of one vehicle / calibration")
        path = self.root / sd["filename"]
        if not path.is_file():
            raise DatasetError(f"{path}: image file is missing ({who})")
        self.first_file.setdefault(ch, path)
        if sd.get("width") and sd.get("height"):
            self.sizes.setdefault(ch, set()).add((int(sd["width"]), int(sd["height"])))
        return {"token": sd["token"], "filename": sd["filename"], "timestamp": sd["timestamp"],
                "T_world_ego": pose_matrix(pose["rotation"], pose["translation"], f"ego_pose {pose['token']}")}

    def _lidar(self, s: dict) -> dict:
        """Sample `s`'s LIDAR_TOP sweep: its file, the LiDAR's calibration and the ego pose at its time."""
        sd = get_record(self.nusc, "sample_data", s["data"][LIDAR], f"sample {s['token']}")
        who = f"sample_data {sd['token']} ({LIDAR})"
        cs = get_record(self.nusc, "calibrated_sensor", sd["calibrated_sensor_token"], who)
        pose = get_record(self.nusc, "ego_pose", sd["ego_pose_token"], who)
        path = self.root / sd["filename"]
        if not path.is_file() and not path.exists():
            raise DatasetError(f"{path}: LiDAR file is missing ({who})")
        regular_file(path, self.root, who)
        return {"token": sd["token"], "filename": sd["filename"],
                "T_ego_lidar": pose_matrix(cs["rotation"], cs["translation"], f"calibrated_sensor {cs['token']}"),
                "T_world_ego": pose_matrix(pose["rotation"], pose["translation"], f"ego_pose {pose['token']}")}

    def cameras(self, pixel_centre: str) -> list[CameraSpec]:
        """The rig in `RIG_ORDER`: the first image's size (every sample_data must agree), the calibration."""
        cameras = []
        for ch in RIG_ORDER:
            first = self.first_file[ch]
            h, w = read_image(within(self.root, first, ch)).shape[:2]
            other = sorted(self.sizes.get(ch, set()) - {(w, h)})
            if other:
                raise DatasetError(f"{self.tab / 'sample_data.json'}: {ch} sample_data give size "
                                   f"{other[0][0]}x{other[0][1]}, the first image {first} is {w}x{h}")
            (K, rot, trans), cs_token = self.calib[ch]
            K = K.copy()
            if pixel_centre == "integer":
                K[0, 2] += 0.5
                K[1, 2] += 0.5
            T = pose_matrix(rot, trans, f"calibrated_sensor {cs_token}")
            cameras.append(CameraSpec(ch, int(w), int(h), K, T, *_angles(K, T, w)))
        return cameras
