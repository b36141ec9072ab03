"""`NuScenesDataset`: a nuScenes dataroot as a `synth.protocol.DatasetReader`, from the plain records that
`synth.nuscenes.read.open_nuscenes` scans out of its tables (docs/NUSCENES.md, "Reading a nuScenes dataroot").

Its depth is the sample's LIDAR_TOP sweep projected into the camera with the devkit's chain (lidar -> ego at
lidar time -> global -> ego at camera time -> camera), z at pixel (floor(u), floor(v)) in our +0.5-centre K,
nearest point per pixel, kept in [`LIDAR_MIN_DEPTH`, `LIDAR_MAX_DEPTH`] m, 0 elsewhere. Every problem is a
`DatasetError` of one line naming the token, file or channel.

Example::

    ds = open_nuscenes("NS_ROOT")
    d = ds.read_depth(ds.split("test")[0], "CAM_FRONT", 1)   # sparse LiDAR z-depth, 0 = none
"""
from __future__ import annotations

from pathlib import Path

import numpy as np

from synth.files import DatasetError, read_image, regular_file, within
from synth.label_reader import NoLabels
from synth.nuscenes.geometry import lidar_xyz, view_points
from synth.nuscenes.layout import LIDAR_CHANNEL, SPLITS_FILE
from synth.rig import CameraSpec
from synth.sizes import SharedSize, size_keys

RING = tuple((i, (i + 1) % 6) for i in range(6))
# depth range of the projected LiDAR (SurroundDepth configs/nusc.txt: min_depth 0.1, max_depth 80;
# VFDepth configs/nuscenes/*: eval_max_depth 80); the evaluator applies its own range on top
LIDAR_MIN_DEPTH = 0.1
LIDAR_MAX_DEPTH = 80.0


class NuScenesDataset(NoLabels, SharedSize):
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
    def fps(self) -> float:
        return self._fps

    @property
    def has_depth(self) -> bool:
        return self._has_depth

    @property
    def ground_truth(self) -> dict:
        """Provenance of `read_depth` (copied into the evaluator's metrics)."""
        return {"kind": "lidar",
                "description": f"{LIDAR_CHANNEL} key-frame sweep (one per sample, no sweeps/) projected into each "
                               "camera with the devkit's chain (lidar -> ego at lidar time -> global -> ego at camera "
                               "time -> camera): sparse z-depth at pixel (floor(u), floor(v)), nearest point per "
                               "pixel, 0 = no return",
                "channel": LIDAR_CHANNEL, "min_depth": LIDAR_MIN_DEPTH, "max_depth": LIDAR_MAX_DEPTH,
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
                               f"devkit's official {name} split and there is no {SPLITS_FILE} "
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

    def camera_poses(self, seq: str) -> tuple[np.ndarray, np.ndarray]:
        """(F, N) each camera's timestamp_s and (F, N, 4, 4) its pose in the ego frame of its frame's time, from its
        own ``sample_data``: ``T_world_ego(f)^-1 @ ego_pose(camera) @ T_ego_cam`` (the frame's time and pose are
        CAM_FRONT's, `T_world_ego`), the contract of `synth.dataset.Dataset.camera_poses`. A camera whose ego_pose
        is the frame's (a synchronous export) gets the static ``T_ego_cam`` itself."""
        frames = self._seq(seq)
        ts = np.empty((len(frames), len(self.cameras)), np.float64)
        T = np.empty((len(frames), len(self.cameras), 4, 4), np.float64)
        for f, fr in enumerate(frames):
            T_ego_world, t_front = None, fr["cams"]["CAM_FRONT"]["timestamp"]
            for c, spec in enumerate(self.cameras):
                rec = fr["cams"][spec.name]
                ts[f, c] = fr["timestamp_s"] + (rec["timestamp"] - t_front) / 1e6
                if np.array_equal(rec["T_world_ego"], fr["T_world_ego"]):
                    T[f, c] = spec.T_ego_cam
                    continue
                if T_ego_world is None:
                    T_ego_world = np.linalg.inv(fr["T_world_ego"])
                T[f, c] = T_ego_world @ rec["T_world_ego"] @ spec.T_ego_cam
        return ts, T

    def rgb_path(self, seq: str, cam: str, frame: int) -> Path:
        return self.root / self._cam(seq, cam, frame)["filename"]

    def depth_path(self, seq: str, cam: str, frame: int) -> Path:
        """The LIDAR_TOP file the camera's depth is projected from."""
        self._cam(seq, cam, frame)
        lid = self._rec(seq, frame).get("lidar")
        if lid is None:
            raise DatasetError(f"{self.root}: sample {self._rec(seq, frame)['sample_token']} has no {LIDAR_CHANNEL}")
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
