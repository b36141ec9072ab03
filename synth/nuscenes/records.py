"""The rows of the nuScenes tables that an export writes (`TableRows`), with what they are made of: tokens
(`Tokens`: 32 hex digits of a sha256 of the dataset's config hash and the record's names, so the same dataset
always exports the same tables), timestamps (`timestamp_us`), our camera -> nuScenes channel (`channel_map`)
and the rigid transforms checked (`check_rigid`).

Conventions: calibrated_sensor is sensor -> ego (translation, rotation quaternion [w, x, y, z]), ego_pose is
ego -> global; every frame is a key frame and a sample_data's ego_pose has its token. The files the rows
name are `synth.nuscenes.export`'s.

Example::

    rows = TableRows(Tokens(config_hash))
    rows.add_sensor("CAM_FRONT", "camera", T_ego_cam, K)
    tables = rows.tables()                       # table name -> rows, as the devkit loads them
"""
from __future__ import annotations

import datetime as _dt
import hashlib
import json

import numpy as np

from synth.nuscenes.geometry import rotation_to_quaternion
from synth.nuscenes.layout import NUSCENES_CAMERAS, ExportError

TABLES = ("category", "attribute", "visibility", "instance", "sensor", "calibrated_sensor", "ego_pose", "log",
          "scene", "sample", "sample_data", "sample_annotation", "map")
BASE_TIMESTAMP_US = 1_577_836_800 * 10**6   # 2020-01-01T00:00:00Z
SEQUENCE_SPACING_US = 86_400 * 10**6        # sequence k starts k days later (a sequence lasts < 6 h)
VEHICLE = "mcdp-synth-ego"


def check_rigid(T: np.ndarray, where: str) -> np.ndarray:
    """`T` as a float64 4x4 when it is a finite rigid transform; else ExportError naming `where`."""
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


class Tokens:
    """`tok(kind, *parts)`: the 32-hex-digit token of a record (module docstring)."""

    def __init__(self, namespace: str) -> None:
        self.ns = namespace

    def __call__(self, kind: str, *parts) -> str:
        key = json.dumps([self.ns, kind, *[str(p) for p in parts]])
        return hashlib.sha256(key.encode()).hexdigest()[:32]


def timestamp_us(seq_index: int, frame: int, fps: float) -> int:
    """Microseconds since the epoch of `frame` in the `seq_index`-th sequence (sorted ids)."""
    return BASE_TIMESTAMP_US + seq_index * SEQUENCE_SPACING_US + int(round(frame * 1e6 / fps))


def pose(T: np.ndarray, ts: int | None = None) -> dict:
    """A pose record's translation and rotation of 4x4 `T` (+ its timestamp when `ts` is given)."""
    rec = {"translation": [float(x) for x in T[:3, 3]], "rotation": rotation_to_quaternion(T[:3, :3])}
    return rec if ts is None else {**rec, "timestamp": ts}


class TableRows:
    """The rows of the `TABLES` one export gathers (`rows[table]`), added in the order written: the static rig
    (`add_sensor`), then per sequence its log, every frame's sample and sample_data (each with its ego_pose),
    its scene; `tables` gives them with the map record. Chains (prev / next) and cross-references are tokens
    made from names, so a row never waits for the next."""

    def __init__(self, tok: Tokens) -> None:
        self.tok = tok
        self.rows: dict[str, list[dict]] = {name: [] for name in TABLES}
        self.cs_token: dict[str, str] = {}  # channel -> its calibrated_sensor token
        self.map_token = tok("map", "semantic_prior")
        self.map_file = f"maps/{self.map_token}.png"

    def add_sensor(self, ch: str, modality: str, T: np.ndarray, K=None) -> None:
        """Channel `ch`'s sensor and calibrated_sensor (sensor -> ego `T`, camera_intrinsic `K` or [])."""
        st, ct = self.tok("sensor", ch), self.tok("calibrated_sensor", ch)
        self.rows["sensor"].append({"token": st, "channel": ch, "modality": modality})
        self.rows["calibrated_sensor"].append({"token": ct, "sensor_token": st, **pose(T), "camera_intrinsic":
                                               [] if K is None else [[float(x) for x in row] for row in K]})
        self.cs_token[ch] = ct

    def add_log(self, seq: str, t0: int, family: str) -> None:
        date = _dt.datetime.fromtimestamp(t0 / 1e6, _dt.timezone.utc).strftime("%Y-%m-%d")
        self.rows["log"].append({"token": self.tok("log", seq), "logfile": seq, "vehicle": VEHICLE,
                                 "date_captured": date, "location": f"synth-{family}"})

    def add_sample(self, seq: str, f: int, n: int, ts: int) -> str:
        """Frame `f` (of `n`) of `seq` as a sample; returns its token."""
        tok = self.tok
        token = tok("sample", seq, f)
        self.rows["sample"].append({"token": token, "timestamp": ts, "scene_token": tok("scene", seq),
                                    "prev": tok("sample", seq, f - 1) if f > 0 else "",
                                    "next": tok("sample", seq, f + 1) if f + 1 < n else ""})
        return token

    def sd_token(self, seq: str, ch: str, f: int) -> str:
        """The token of channel `ch`'s sample_data (and ego_pose) of frame `f` of `seq`."""
        return self.tok("sample_data", seq, ch, f)

    def add_sample_data(self, seq: str, ch: str, f: int, n: int, ts: int, filename: str, fileformat: str,
                        size: tuple[int, int], ego_pose: dict) -> str:
        """Channel `ch`'s key frame `f` of `seq` (file `filename`, `size` = (width, height), 0 x 0 for a
        LiDAR) and its ego_pose (`pose` of T_world_ego at `ts`); returns the token they share."""
        tok = self.tok
        token = self.sd_token(seq, ch, f)
        self.rows["sample_data"].append({
            "token": token, "sample_token": tok("sample", seq, f), "ego_pose_token": token,
            "calibrated_sensor_token": self.cs_token[ch], "filename": filename, "fileformat": fileformat,
            "width": int(size[0]), "height": int(size[1]), "timestamp": ts, "is_key_frame": True,
            "next": self.sd_token(seq, ch, f + 1) if f + 1 < n else "",
            "prev": self.sd_token(seq, ch, f - 1) if f > 0 else ""})
        self.rows["ego_pose"].append({"token": token, **ego_pose})
        return token

    def add_scene(self, seq: str, n: int, description: str) -> None:
        self.rows["scene"].append({"token": self.tok("scene", seq), "name": seq, "description": description,
                                   "log_token": self.tok("log", seq), "nbr_samples": n,
                                   "first_sample_token": self.tok("sample", seq, 0),
                                   "last_sample_token": self.tok("sample", seq, n - 1)})

    def tables(self) -> dict[str, list[dict]]:
        """Every table's rows, the map record (one placeholder map for every log) added."""
        self.rows["map"] = [{"token": self.map_token, "log_tokens": [lg["token"] for lg in self.rows["log"]],
                             "category": "semantic_prior", "filename": self.map_file}]
        return dict(self.rows)
