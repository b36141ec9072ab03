"""Per-camera trigger times (issue 48, item 1): when each camera of a rig frame fires, and its pose then.

Camera c of frame f fires at ``t = f / fps + dt_c``; its image, depth, masks, labels and flow are rendered
with the ego and every mover at that time (`scenes.timeline`: the screw motion between the frames around it,
exact on a route's lines and arcs). ``rig.trigger`` (`synth.rig.RigConfig`) sets the offsets ``dt_c``:

* ``synchronous`` (the default): every ``dt_c = 0``; nothing of this module is written, the dataset's bytes and
  config hash are those of a render made before it.
* ``offsets``: ``rig.trigger_offsets_ms``, one per camera in rig order (``synth.rig.CAMERA_NAMES``).
* ``lidar_sweep``: each camera fires when a LiDAR spinning at ``rig.lidar_hz`` points along the camera's yaw,
  as nuScenes triggers its cameras. Convention: the LiDAR turns clockwise seen from above (as the HDL-32E of
  nuScenes' LIDAR_TOP: yaw, counter-clockwise in the ego frame, decreases) and points forward (+x, yaw 0) at
  the frame time, so ``dt_c = ((0 - yaw_c) mod 360) / (360 * lidar_hz)``: CAM_FRONT fires at the frame time,
  then CAM_FRONT_RIGHT, CAM_BACK_RIGHT, CAM_BACK, CAM_BACK_LEFT, and CAM_FRONT_LEFT almost a sweep later (at
  20 Hz the six span about 41 ms of the 50 ms sweep, as nuScenes' do).

Recorded only when the trigger is not synchronous: the manifest's ``trigger`` (the mode and each camera's
offset in ms) and, per frame of ``<seq>/ego.json``, ``cameras.<CAM>``: its ``timestamp_s``, ``T_world_ego``
(the ego at that time) and ``T_world_cam``. The frame's own ``timestamp_s`` / ``T_world_ego`` stay the frame
time's. A camera's pose relative to the frame's ego pose, ``T_ego_cam_at = T_world_ego(f)^-1 T_world_cam``,
is what every cross-camera warp of that frame uses in place of the static ``T_ego_cam``: it carries the ego's
motion between the frame time and the camera's (the relative pose of cameras i and j then goes through the
world). The overlap counts of the manifest use it too, so a static surface is counted as seen by both cameras
exactly as in a synchronous rig; a mover has moved between the two times, and counts only where it still
passes the z-test.

Example::

    times = CameraTimes.for_sequence(cfg, rig, scene)     # None when rig.trigger is synchronous
    x = times.frame_index(c, f)                           # the renderer's continuous frame index
"""
from __future__ import annotations

import dataclasses

import numpy as np

from scenes.model import Scene
from synth.rig import Rig, RigConfig


def lidar_sweep_offset_s(yaw_deg: float, lidar_hz: float) -> float:
    """Seconds after the frame time at which a clockwise LiDAR that points forward then points along `yaw_deg`."""
    return float(((0.0 - yaw_deg) % 360.0) / (360.0 * lidar_hz))


def trigger_offsets_s(cfg: RigConfig, rig: Rig) -> np.ndarray | None:
    """(cameras,) offsets in seconds of each camera from its frame's time, rig order; None when synchronous."""
    if cfg.trigger == "synchronous":
        return None
    if cfg.trigger == "offsets":
        from synth.rig import CAMERA_NAMES  # one offset per name: the rig's cameras pick theirs

        return np.asarray(cfg.trigger_offsets_ms, np.float64)[[CAMERA_NAMES.index(c.name) for c in rig.cameras]] / 1000.0
    return np.array([lidar_sweep_offset_s(c.yaw_deg, cfg.lidar_hz) for c in rig.cameras])


def trigger_record(cfg: RigConfig, rig: Rig) -> dict | None:
    """The manifest's ``trigger``: mode, each camera's offset in ms (and the LiDAR's rate); None when synchronous."""
    off = trigger_offsets_s(cfg, rig)
    if off is None:
        return None
    rec = {"mode": cfg.trigger, "offsets_ms": {c.name: float(o * 1000.0) for c, o in zip(rig.cameras, off)}}
    if cfg.trigger == "lidar_sweep":
        rec["lidar_hz"] = cfg.lidar_hz
        rec["convention"] = "clockwise seen from above, pointing forward (+x) at the frame time"
    return rec


class CameraTimes:
    """A sequence's per-camera times and poses (module docstring)."""

    def __init__(self, scene: Scene, rig: Rig, offsets_s: np.ndarray, fps: float) -> None:
        self.scene, self.rig, self.offsets_s, self.fps = scene, rig, np.asarray(offsets_s, np.float64), float(fps)

    @staticmethod
    def for_sequence(cfg, rig: Rig, scene: Scene) -> "CameraTimes | None":
        """The times of `cfg` (a `synth.config.DataConfig`); None when the trigger is synchronous."""
        off = trigger_offsets_s(cfg.rig, rig)
        return None if off is None else CameraTimes(scene, rig, off, cfg.dataset.fps)

    def frame_index(self, c: int, f: int) -> float:
        """Camera c's continuous frame index at frame f (``f`` itself when its offset is 0)."""
        return f + self.offsets_s[c] * self.fps

    def T_world_ego(self, c: int, f: int) -> np.ndarray:
        """The ego's pose when camera c of frame f fires."""
        return self.scene.ego_pose_at(self.frame_index(c, f))

    def cameras_at(self, f: int) -> list:
        """The rig's cameras with ``T_ego_cam`` their pose at their own time in the ego frame of frame f's time."""
        T_ego_world = np.linalg.inv(self.scene.T_world_ego[f])
        return [dataclasses.replace(cam, T_ego_cam=T_ego_world @ self.T_world_ego(c, f) @ cam.T_ego_cam)
                for c, cam in enumerate(self.rig.cameras)]

    def frame_record(self, f: int) -> dict:
        """ego.json's ``cameras`` of frame f: each camera's timestamp_s, T_world_ego and T_world_cam."""
        out = {}
        for c, cam in enumerate(self.rig.cameras):
            T = self.T_world_ego(c, f)
            out[cam.name] = {"timestamp_s": f / self.fps + float(self.offsets_s[c]), "T_world_ego": T.tolist(),
                             "T_world_cam": (T @ cam.T_ego_cam).tolist()}
        return {"cameras": out}


# ----------------------------------------------------------------------------- reading it back

def check_trigger_record(rec, cameras: list, mpath) -> None:
    """The manifest's ``trigger``: a mode and an offset (ms, within +-`MAX_TRIGGER_MS` + one LiDAR sweep) for
    exactly the manifest's cameras; `synth.files.DatasetError` naming the key otherwise."""
    import math

    from synth.files import DatasetError
    from synth.rig import MAX_TRIGGER_MS

    off = rec.get("offsets_ms") if isinstance(rec, dict) else None
    if not isinstance(off, dict) or rec.get("mode") not in ("offsets", "lidar_sweep") \
            or sorted(map(str, off)) != sorted(map(str, cameras)):
        raise DatasetError(f"{mpath}: trigger must be {{mode: offsets | lidar_sweep, offsets_ms: {{camera: ms}}}} "
                           "for every camera of 'cameras'")
    for cam, v in off.items():
        if not (isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v)
                and abs(v) <= MAX_TRIGGER_MS + 500.0):
            raise DatasetError(f"{mpath}: trigger.offsets_ms.{str(cam)[:40]} must be a finite number of ms within "
                               f"+-{MAX_TRIGGER_MS + 500.0:g}, got {str(v)[:40]}")


def camera_poses(frames: list[dict], cameras: list, path, trigger: str | None = None) -> tuple[np.ndarray, np.ndarray]:
    """(F, N) timestamps in seconds and (F, N, 4, 4) T_ego_cam_at of every camera of every frame of a sequence
    (ego.json's ``frames``; module docstring): each camera's own pose at its own time in the ego frame of its
    frame's time. Without ``cameras`` in a frame (a synchronous rig, a dataset made before triggers): the
    frame's timestamp and the static ``T_ego_cam`` itself; a dataset whose manifest records a ``trigger`` (its
    mode, ``trigger``) gives every frame's ``cameras``, and a frame without them is refused (read as synchronous it
    would be silently wrong). DatasetError naming the file, the frame and the key for a bad entry."""
    import math

    from synth.files import DatasetError

    F, N = len(frames), len(cameras)
    ts = np.empty((F, N), np.float64)
    T = np.empty((F, N, 4, 4), np.float64)
    static = np.stack([np.asarray(c.T_ego_cam, np.float64) for c in cameras])
    for f, fr in enumerate(frames):
        per = fr.get("cameras") if isinstance(fr, dict) else None
        if per is None:
            if trigger is not None:
                raise DatasetError(f"{path}: frame {f} has no 'cameras' (each camera's timestamp_s and T_world_cam); "
                                   f"the manifest's trigger is {str(trigger)[:40]}, so every frame gives them")
            t = fr.get("timestamp_s") if isinstance(fr, dict) else None
            if not (isinstance(t, (int, float)) and not isinstance(t, bool) and math.isfinite(t)):
                raise DatasetError(f"{path}: frame {f}: timestamp_s must be a finite number of seconds, got "
                                   f"{str(t)[:40] if t is not None else 'none'}")
            ts[f], T[f] = float(t), static
            continue
        try:
            T_ego_world = np.linalg.inv(np.asarray(fr["T_world_ego"], np.float64))
            for c, cam in enumerate(cameras):
                e = per[cam.name]
                ts[f, c] = float(e["timestamp_s"])
                Twc = np.asarray(e["T_world_cam"], np.float64)
                if Twc.shape != (4, 4):
                    raise ValueError("T_world_cam is not 4x4")
                T[f, c] = T_ego_world @ Twc
        except (KeyError, TypeError, ValueError, np.linalg.LinAlgError) as exc:
            raise DatasetError(f"{path}: frame {f}: cameras must give every camera's timestamp_s and 4x4 "
                               f"T_world_cam ({str(exc)[:80]})") from None
    if not (np.isfinite(ts).all() and np.isfinite(T).all()):
        raise DatasetError(f"{path}: a camera's timestamp_s or T_world_cam is not finite")
    return ts, T
