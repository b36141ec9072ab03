"""Six-camera surround rig: intrinsics, extrinsics, the overlap solver and the ego body.

Conventions: ego frame x forward, y left, z up (origin on the road below the rear
axle); camera frame OpenCV (x right, y down, z forward); `T_ego_cam` maps camera
points into the ego frame; yaw is measured in the ego frame, counter-clockwise
(to the left) from x; pitch is positive looking up. `K` is in pixels for the
stored image size of each camera with pixel centres at +0.5.

Overlap of adjacent cameras is the shared fraction of the horizontal field of
view, ``o = (hfov - yaw_spacing) / hfov`` (DESIGN.md). Two ways to reach a target:

* ``spacing``: fixed intrinsics (``camera.hfov_deg``); the yaw spacing of the four
  front/back pairs is solved, ``s = hfov (1 - o)``. FRONT and BACK look along the
  axis, so the two side pairs (FRONT_RIGHT-BACK_RIGHT, BACK_LEFT-FRONT_LEFT) get
  what is left (``180 - 2 s``): the ring may not close. The clean experiment:
  overlap is the only variable.
* ``fov``: a closed 360 degree ring at 60 degree spacing, hfov solved,
  ``hfov = 60 / (1 - o)``; all six pairs reach the target.

Example::

    rig = build_rig(RigConfig(overlap=0.3), CameraConfig(width=320, height=192))
    rig.cameras[0].K, rig.pair_target_overlap()
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Literal

import numpy as np
from pydantic import Field, field_validator, model_validator

from corelib.configlib import StrictModel, added_key
from synth import camera as camera_table

CAMERA_NAMES = ("CAM_FRONT", "CAM_FRONT_RIGHT", "CAM_BACK_RIGHT", "CAM_BACK", "CAM_BACK_LEFT", "CAM_FRONT_LEFT")
# adjacent pairs in ring order: (0,1) (1,2) ... (5,0)
RING_PAIRS = tuple((i, (i + 1) % 6) for i in range(6))

# OpenCV camera axes expressed in a "look along +x" body frame (x fwd, y left, z up):
# camera x (right) = -y, camera y (down) = -z, camera z (forward) = +x.
_R_BODY_CV = np.array([[0.0, 0.0, 1.0], [-1.0, 0.0, 0.0], [0.0, -1.0, 0.0]])

#: the largest image side of a camera (pixels): the config's bound, and what a manifest may claim and a reader
#: decodes (`synth.dataset.check_manifest_keys`, `synth.files.read_png`)
MAX_CAMERA_PX = 4096
#: the widest horizontal field of view of a z-depth (pinhole-like) camera, and of a range (fisheye) one (degrees)
MAX_PINHOLE_HFOV, MAX_FISHEYE_HFOV = 150.0, 220.0
#: the largest trigger offset of a camera from its frame's time (ms, either way): `RigConfig.trigger_offsets_ms`
MAX_TRIGGER_MS = 500.0


class CameraConfig(StrictModel):
    """Image size and lens. ``hfov_deg`` is used in ``spacing`` mode (solved in ``fov`` mode); above
    `MAX_PINHOLE_HFOV` only for a rig whose cameras have a range-depth (fisheye) lens (`build_rig` refuses
    another, naming the camera)."""

    width: int = Field(320, ge=16, le=MAX_CAMERA_PX)
    height: int = Field(192, ge=16, le=MAX_CAMERA_PX)
    hfov_deg: float = Field(70.0, gt=20.0, le=MAX_FISHEYE_HFOV)


class CameraOverride(StrictModel):
    """One camera's own settings over the rig's (``rig.cameras.<CAM>.<key>``; null = the rig's).

    hfov_deg: its horizontal field of view (its K: square pixels, centred principal point; the focal length
        that maps the half-angle to the half-width through its lens model, `intrinsics_for`).
    model / dist: its lens (issue 59), a row of `synth.camera.MODELS` and that row's distortion parameters in
        order (radtan: k1 k2 p1 p2 k3; kannala_brandt: k1 k2 k3 k4); null = pinhole.
    width / height: its image size in pixels (bounded like ``camera.width`` / ``camera.height``), instead of
        the dataset's ``camera.width`` x ``camera.height``; its K is made from its own size and hfov, and its
        images, depth maps and mask are written at that size (the manifest's ``camera_sizes``).
    yaw_deg: its yaw in the ego frame (counter-clockwise from x, degrees), instead of the solved layout's.
    pitch_deg: its pitch (positive looks up).
    mount_m: its optical centre in the ego frame (x forward, y left, z up; metres above the road), instead
        of the roof mount at ``camera_height_m``.
    """

    hfov_deg: float | None = Field(None, gt=20.0, le=MAX_FISHEYE_HFOV)  # above 150: a fisheye `model` only
    width: int | None = added_key(None, ge=16, le=MAX_CAMERA_PX)  # added_key: a rig.cameras entry keeps its hash
    height: int | None = added_key(None, ge=16, le=MAX_CAMERA_PX)
    yaw_deg: float | None = Field(None, ge=-180.0, le=180.0)
    pitch_deg: float | None = Field(None, ge=-45.0, le=45.0)
    mount_m: list[float] | None = None  # [x, y, z]
    # issue 59: the lens, a row of the camera-model table (`synth.camera.MODELS`) and its distortion parameters in
    # the row's order; null = pinhole (added keys: a pinhole camera's entry keeps its hash, its rig.json its bytes)
    model: str | None = added_key(None)
    dist: list[float] | None = added_key(None)

    @field_validator("model")
    @classmethod
    def _model(cls, v):
        if v is not None and v not in camera_table.MODELS:
            raise ValueError(f"unknown camera model {str(v)[:40]!r}; the table has {', '.join(camera_table.MODELS)}")
        return v

    @model_validator(mode="after")
    def _lens(self) -> "CameraOverride":
        names = camera_table.model(self.model or "pinhole").dist_names
        if len(self.dist or ()) != len(names) or not all(math.isfinite(d) and abs(d) <= 10.0 for d in self.dist or ()):
            raise ValueError(f"dist must be {len(names)} finite numbers within 10 ({', '.join(names) or 'none'}) for "
                             f"camera model {self.model or 'pinhole'}, got {str(self.dist)[:200]}")
        if self.hfov_deg is not None and self.hfov_deg > MAX_PINHOLE_HFOV and camera_table.depth_kind(self.model or "pinhole") == "z_depth":
            raise ValueError(f"hfov_deg {self.hfov_deg:g} needs a range-depth (fisheye) camera model; "
                             f"camera model {self.model or 'pinhole'} allows up to {MAX_PINHOLE_HFOV:g}")
        return self

    @field_validator("mount_m")
    @classmethod
    def _mount(cls, v):
        if v is not None and not (len(v) == 3 and all(math.isfinite(c) and abs(c) <= 10.0 for c in v)
                                  and 0.2 <= v[2] <= 5.0):
            raise ValueError(f"mount_m must be finite (x, y, z) metres within 10 m of the rear axle, z in [0.2, 5], "
                             f"got {v}")
        return v


class RigConfig(StrictModel):
    """Rig geometry. ``overlap`` is the target shared fraction of hfov of adjacent cameras.

    ``znear_m`` / ``zfar_m``: the clipping planes of every camera, as camera-frame z in metres.
    Nothing nearer than ``znear_m`` or farther than ``zfar_m`` is rendered (depth 0 there, as
    for the sky). ``znear_m`` must stay below the nearest part of the ego body a camera sees
    (the roof, about 5 cm in z from a rear-side camera in the widest ``fov`` rig), or the
    road shows through the car and the self-occlusion mask misses it; the default 1 cm
    costs no depth resolution (the renderer tests linear depth, `synth.gl_backend`).
    ``zfar_m`` bounds the depth maps (scenes end well before 400 m; fog hides the horizon).
    ``overlap_target``: what ``overlap`` means: ``angle`` (the shared fraction of hfov, below) or
    ``pixels`` (the mean measured pixel overlap of the pairs at the target: the layout's angle is
    solved on a sample of the world's own scenes, `synth.calibrate`).
    ``cameras``: per-camera overrides of hfov, yaw, pitch, mount and image size (`CameraOverride`), applied
    over the solved layout, e.g. ``rig.cameras.CAM_BACK.hfov_deg=110`` or ``rig.cameras.CAM_BACK.width=480``
    (real rigs: configs/data/nuscenes_like.yaml).
    ``trigger``: when each camera fires within a frame (`synth.trigger`): ``synchronous`` (all at the frame
    time), ``offsets`` (``trigger_offsets_ms``, one per camera in rig order, each within +-`MAX_TRIGGER_MS`)
    or ``lidar_sweep`` (as the LiDAR rotating at ``lidar_hz`` passes each camera's yaw, as in nuScenes).
    """

    overlap: float = Field(0.25, ge=0.10, le=0.60)
    overlap_mode: Literal["spacing", "fov"] = "spacing"
    overlap_target: Literal["angle", "pixels"] = added_key("angle")
    camera_height_m: float = Field(1.6, ge=0.5, le=3.0)
    side_pitch_deg: float = Field(-12.0, ge=-30.0, le=10.0)
    znear_m: float = Field(0.01, ge=0.001, le=2.0)
    zfar_m: float = Field(400.0, ge=50.0, le=5000.0)
    cameras: dict[str, CameraOverride] = added_key(default_factory=dict)
    # added keys (issue 48): synchronous, the frame's bytes are those rendered without them
    trigger: Literal["synchronous", "offsets", "lidar_sweep"] = added_key("synchronous")
    trigger_offsets_ms: list[float] | None = added_key(None)
    lidar_hz: float = added_key(20.0, ge=2.0, le=100.0)
    # issue 59: the cameras the rig has, a subset of CAMERA_NAMES (null = all six; e.g. four fisheyes); the ring's
    # pairs join consecutive ones in rig order. Per-camera lists (trigger_offsets_ms, sensor) stay one per name.
    active_cameras: list[str] | None = added_key(None)

    @field_validator("active_cameras")
    @classmethod
    def _active(cls, v):
        if v is not None and not (len(v) >= 2 and len(set(v)) == len(v) and all(n in CAMERA_NAMES for n in v)):
            raise ValueError(f"rig.active_cameras must name at least 2 distinct cameras of {', '.join(CAMERA_NAMES)}, "
                             f"got {str(v)[:200]}")
        return v

    @field_validator("trigger_offsets_ms")
    @classmethod
    def _offsets(cls, v):
        if v is not None and not (len(v) == len(CAMERA_NAMES)
                                  and all(math.isfinite(x) and abs(x) <= MAX_TRIGGER_MS for x in v)):
            raise ValueError(f"rig.trigger_offsets_ms must be {len(CAMERA_NAMES)} numbers (ms, one per camera: "
                             f"{', '.join(CAMERA_NAMES)}) within +-{MAX_TRIGGER_MS:g}, got {str(v)[:200]}")
        return v

    @model_validator(mode="after")
    def _trigger(self) -> "RigConfig":
        if (self.trigger == "offsets") != (self.trigger_offsets_ms is not None):
            raise ValueError("rig.trigger_offsets_ms is set exactly when rig.trigger=offsets (got rig.trigger="
                             f"{self.trigger}, rig.trigger_offsets_ms={self.trigger_offsets_ms})")
        return self

    @field_validator("cameras")
    @classmethod
    def _camera_names(cls, v: dict) -> dict:
        bad = [k for k in v if k not in CAMERA_NAMES]
        if bad:
            raise ValueError(f"unknown camera(s) {', '.join(map(str, bad))[:200]}; the rig's: {', '.join(CAMERA_NAMES)}")
        return v

    @model_validator(mode="after")
    def _cameras_active(self) -> "RigConfig":
        off = [k for k in self.cameras if self.active_cameras is not None and k not in self.active_cameras]
        if off:
            raise ValueError(f"rig.cameras sets {', '.join(off)[:200]}, not in rig.active_cameras "
                             f"({', '.join(self.active_cameras)})")
        return self


@dataclass(frozen=True)
class CameraSpec:
    """One camera: image size, `K` (pixels), `T_ego_cam` (camera -> ego), angles in degrees, and its lens:
    `model` (a row of `synth.camera.MODELS`) and `dist` (that row's parameters in order). JSON (rig.json): a
    pinhole camera has no ``model`` / ``dist`` keys (every dataset rendered before lenses reads as it was, its
    bytes unchanged); another has ``"model"`` and ``"dist": {name: value}``."""

    name: str
    width: int
    height: int
    K: np.ndarray
    T_ego_cam: np.ndarray
    hfov_deg: float
    yaw_deg: float
    pitch_deg: float
    model: str = "pinhole"
    dist: tuple[float, ...] = ()

    @property
    def intrinsics(self) -> camera_table.Intrinsics:
        """The camera-table camera (model, K, dist): what every projection of this camera goes through."""
        return camera_table.Intrinsics(self.model, self.K, self.dist)

    def to_json(self) -> dict:
        out = {
            "name": self.name, "width": self.width, "height": self.height,
            "K": self.K.tolist(), "T_ego_cam": self.T_ego_cam.tolist(),
            "hfov_deg": self.hfov_deg, "yaw_deg": self.yaw_deg, "pitch_deg": self.pitch_deg,
        }
        if self.model != "pinhole":
            out.update(self.intrinsics.to_json(), K=out["K"])  # model, dist {name: value}; K in its place
        return out

    @staticmethod
    def from_json(d: dict) -> "CameraSpec":
        lens = camera_table.Intrinsics.from_json({"model": d["model"], "K": d["K"], "dist": d["dist"]}) \
            if "model" in d else None
        return CameraSpec(d["name"], int(d["width"]), int(d["height"]), np.asarray(d["K"], np.float64),
                          np.asarray(d["T_ego_cam"], np.float64), float(d["hfov_deg"]), float(d["yaw_deg"]),
                          float(d.get("pitch_deg", 0.0)), *((lens.model, lens.dist) if lens else ()))


@dataclass(frozen=True)
class Rig:
    cameras: tuple[CameraSpec, ...]
    neighbours: tuple[tuple[int, int], ...]
    overlap_target: float
    overlap_mode: str
    yaw_spacing_deg: float

    @property
    def names(self) -> list[str]:
        return [c.name for c in self.cameras]

    def pair_target_overlap(self) -> dict[str, float]:
        """Geometric overlap (hfov fraction, may be negative = gap) of each adjacent pair."""
        out = {}
        for i, j in self.neighbours:
            a, b = self.cameras[i], self.cameras[j]
            d = abs((a.yaw_deg - b.yaw_deg + 180.0) % 360.0 - 180.0)
            out[f"{a.name}-{b.name}"] = ((a.hfov_deg + b.hfov_deg) / 2 - d) / ((a.hfov_deg + b.hfov_deg) / 2)
        return out

    def size_text(self) -> str:
        """The cameras' image size, ``WxH``; where they differ, the most common one and the others by camera
        (``320x192, CAM_BACK 480x192``)."""
        return sizes_text({c.name: (c.width, c.height) for c in self.cameras})

    def to_json(self) -> dict:
        return {"cameras": [c.to_json() for c in self.cameras], "neighbours": [list(p) for p in self.neighbours]}


def sizes_text(sizes: dict[str, tuple[int, int]]) -> str:
    """`Rig.size_text` of {camera: (width, height)}."""
    counts: dict[tuple[int, int], int] = {}
    for wh in sizes.values():
        counts[wh] = counts.get(wh, 0) + 1
    common = max(counts, key=counts.get)
    return ", ".join([f"{common[0]}x{common[1]}"] + [f"{n} {w}x{h}" for n, (w, h) in sizes.items() if (w, h) != common])


def intrinsics_for(width: int, height: int, hfov_deg: float, model: str = "pinhole", dist=()) -> np.ndarray:
    """K with square pixels and the principal point at the image centre whose lens maps the half hfov to the
    half width (`synth.camera.unit_focal_radius`); a pinhole camera's is `intrinsics_from_hfov`, as ever."""
    if model == "pinhole":
        return intrinsics_from_hfov(width, height, hfov_deg)
    fx = (width / 2.0) / camera_table.unit_focal_radius(model, dist, math.radians(hfov_deg) / 2.0)
    return np.array([[fx, 0.0, width / 2.0], [0.0, fx, height / 2.0], [0.0, 0.0, 1.0]])


def intrinsics_from_hfov(width: int, height: int, hfov_deg: float) -> np.ndarray:
    """Pinhole K with square pixels and the principal point at the image centre (pixel centres at +0.5)."""
    fx = (width / 2.0) / math.tan(math.radians(hfov_deg) / 2.0)
    return np.array([[fx, 0.0, width / 2.0], [0.0, fx, height / 2.0], [0.0, 0.0, 1.0]])


def rotation_ego_cam(yaw_rad: float, pitch_rad: float) -> np.ndarray:
    """R_ego_cam for a camera looking along yaw (CCW from x) and pitch (up positive)."""
    cy, sy, cp, sp = math.cos(yaw_rad), math.sin(yaw_rad), math.cos(pitch_rad), math.sin(pitch_rad)
    R_yaw = np.array([[cy, -sy, 0.0], [sy, cy, 0.0], [0.0, 0.0, 1.0]])
    # pitch about the body's y axis; positive pitch tilts the optical axis (+x) up (+z)
    R_pitch = np.array([[cp, 0.0, -sp], [0.0, 1.0, 0.0], [sp, 0.0, cp]])
    return R_yaw @ R_pitch @ _R_BODY_CV


def solve_layout(overlap: float, mode: str, hfov_deg: float) -> tuple[float, float]:
    """(hfov_deg, yaw_spacing_deg) that reach `overlap` in `mode` (see module docstring)."""
    if not 0.0 < overlap < 1.0:
        raise ValueError(f"overlap must be in (0, 1), got {overlap}")
    if mode == "spacing":
        return hfov_deg, hfov_deg * (1.0 - overlap)
    if mode == "fov":
        return 60.0 / (1.0 - overlap), 60.0
    raise ValueError(f"overlap_mode must be 'spacing' or 'fov', got {mode!r}")


# Mount points in the ego frame (x, y, z offset from camera_height_m) per camera, on the roof.
# FRONT sits at the top of the windscreen (the hood stays out of view); the rear-side cameras sit
# inboard on the roof and look slightly down, so the roof and body shoulders are in their lower
# image, as the rear cameras of DDAD see the car.
_MOUNTS = {
    "CAM_FRONT": (2.15, 0.0, 0.0),
    "CAM_FRONT_RIGHT": (1.95, -0.55, 0.0),
    "CAM_BACK_RIGHT": (0.2, -0.45, 0.0),
    "CAM_BACK": (-0.45, 0.0, 0.0),
    "CAM_BACK_LEFT": (0.2, 0.45, 0.0),
    "CAM_FRONT_LEFT": (1.95, 0.55, 0.0),
}


def active_names(rig: RigConfig) -> tuple[str, ...]:
    """The rig's cameras in rig order: `CAMERA_NAMES`, or those of ``rig.active_cameras``."""
    return tuple(n for n in CAMERA_NAMES if rig.active_cameras is None or n in rig.active_cameras)


def ring_pairs(n: int) -> tuple[tuple[int, int], ...]:
    """Adjacent pairs of a ring of `n` cameras in rig order: (0, 1) (1, 2) ... (n - 1, 0); one pair for two."""
    return RING_PAIRS if n == len(CAMERA_NAMES) else ((0, 1),) if n == 2 else tuple((i, (i + 1) % n) for i in range(n))


def camera_sizes_of(rig: RigConfig, camera: CameraConfig) -> dict[str, tuple[int, int]]:
    """{camera: (width, height)} in rig order: ``camera.width`` x ``camera.height``, or the camera's own
    ``rig.cameras.<CAM>.width`` / ``.height``."""
    out = {}
    for name in active_names(rig):
        o = rig.cameras.get(name) or CameraOverride()
        out[name] = (camera.width if o.width is None else o.width, camera.height if o.height is None else o.height)
    return out


def build_rig(rig: RigConfig, camera: CameraConfig) -> Rig:
    """The six cameras for a rig config (see module docstring for the layout; ``rig.active_cameras``: those)."""
    hfov, s = solve_layout(rig.overlap, rig.overlap_mode, camera.hfov_deg)
    if rig.overlap_mode == "fov" and hfov >= 179.0:
        raise ValueError(f"rig.overlap={rig.overlap} in fov mode needs hfov {hfov:.1f} deg (max 179)")
    if rig.overlap_mode == "spacing":
        yaws = {"CAM_FRONT": 0.0, "CAM_FRONT_RIGHT": -s, "CAM_BACK_RIGHT": -(180.0 - s), "CAM_BACK": 180.0,
                "CAM_BACK_LEFT": 180.0 - s, "CAM_FRONT_LEFT": s}
    else:
        yaws = {"CAM_FRONT": 0.0, "CAM_FRONT_RIGHT": -60.0, "CAM_BACK_RIGHT": -120.0, "CAM_BACK": 180.0,
                "CAM_BACK_LEFT": 120.0, "CAM_FRONT_LEFT": 60.0}
    pitches = {n: 0.0 for n in CAMERA_NAMES}
    pitches["CAM_BACK_RIGHT"] = pitches["CAM_BACK_LEFT"] = rig.side_pitch_deg
    cams, sizes = [], camera_sizes_of(rig, camera)
    for name in active_names(rig):
        o = rig.cameras.get(name) or CameraOverride()
        yaw = yaws[name] if o.yaw_deg is None else o.yaw_deg
        pitch = pitches[name] if o.pitch_deg is None else o.pitch_deg
        h = hfov if o.hfov_deg is None else o.hfov_deg
        if h > MAX_PINHOLE_HFOV and camera_table.depth_kind(o.model or "pinhole") == "z_depth":
            raise ValueError(f"camera.hfov_deg {h:g} needs a range-depth (fisheye) camera model; rig.cameras.{name}"
                             f".model is {o.model or 'pinhole'} (up to {MAX_PINHOLE_HFOV:g} degrees)")
        T = np.eye(4)
        T[:3, :3] = rotation_ego_cam(math.radians(yaw), math.radians(pitch))
        mx, my, mz = _MOUNTS[name]
        T[:3, 3] = (mx, my, rig.camera_height_m + mz) if o.mount_m is None else o.mount_m
        w, ht = sizes[name]
        lens = (o.model or "pinhole", tuple(o.dist or ()))
        cams.append(CameraSpec(name, w, ht, intrinsics_for(w, ht, h, *lens), T, h, yaw, pitch, *lens))
    return Rig(tuple(cams), ring_pairs(len(cams)), rig.overlap, rig.overlap_mode, s)
