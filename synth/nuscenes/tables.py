"""The tables of a nuScenes dataroot through the official devkit: finding the version folder, loading
it with errors that name the broken record and token, and the train / val / test scene lists.

Without the devkit (an environment with the ``viz`` extra: rerun-sdk needs numpy >= 2, nuscenes-devkit
1.2.0 numpy < 2) `load_tables` reads the tables the reader uses as plain JSON (`PlainTables`: the same
records, with the devkit's ``sample["data"]`` / ``sample_data["channel"]`` reverse index), so
`synth view` can record a dataroot; the official splits still need the devkit. Beside them, nuScenes'
rotation convention both ways: `rotation_matrix` and `pose_matrix` (the reader), `rotation_to_quaternion` (the
export).

Example::

    if is_nuscenes_root(root):
        nusc = load_tables(root, resolve_version(root, None))
"""
from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from synth.files import DatasetError, read_json, regular_file, within


EXPORT_DIR = "mcdp_synth"
INSTALL_HINT = "install the extra: pip install -e '.[nuscenes]'"


def version_dirs(root: Path) -> list[str]:
    """Sub-folders of `root` holding a ``sample.json`` (nuScenes version folders), sorted."""
    try:
        return sorted(d.name for d in root.iterdir() if d.is_dir() and (d / "sample.json").is_file())
    except OSError:
        return []


def is_nuscenes_root(root: str | Path) -> bool:
    """A folder with ``samples/``, a version folder holding ``sample.json`` and no ``manifest.json``."""
    root = Path(root)
    return root.is_dir() and (root / "samples").is_dir() and not (root / "manifest.json").exists() and bool(
        version_dirs(root))


def resolve_version(root: Path, version: str | None) -> str:
    """`version` checked to be a version folder of `root`, or (None) the only one; DatasetError otherwise."""
    if version is not None:
        if not (root / version / "sample.json").is_file():
            raise DatasetError(f"{root / version / 'sample.json'}: missing; {root} has no nuScenes version "
                               f"{version!r} (version folders: {version_dirs(root) or 'none'})")
        return version
    found = version_dirs(root)
    if not found:
        raise DatasetError(f"{root}: no nuScenes version folder (a folder holding sample.json)")
    if len(found) > 1:
        raise DatasetError(f"{root}: several nuScenes versions ({', '.join(found)}); name one (version=...)")
    return found[0]


def _diagnose_key_error(root: Path, version: str, exc: KeyError) -> str:
    """The devkit raised KeyError(token) while indexing: find which record names the missing token."""
    tables = {}
    for name in ("sample", "sample_data", "calibrated_sensor", "sensor", "ego_pose", "instance", "category",
                 "sample_annotation"):
        try:
            tables[name] = read_json(root / version / f"{name}.json", root)
        except DatasetError:
            tables[name] = []
    tokens = {k: {r.get("token") for r in v if isinstance(r, dict)} for k, v in tables.items()}
    refs = [("sample_data", "sample_token", "sample"), ("sample_data", "calibrated_sensor_token", "calibrated_sensor"),
            ("sample_data", "ego_pose_token", "ego_pose"), ("calibrated_sensor", "sensor_token", "sensor"),
            ("sample_annotation", "instance_token", "instance"), ("instance", "category_token", "category")]
    for table, field, target in refs:
        for r in tables[table]:
            if isinstance(r, dict) and r.get(field) not in tokens[target]:
                return (f"{root / version / (table + '.json')}: {table} {r.get('token')} names {field} "
                        f"{r.get(field)!r}, which is not in {target}.json")
    return f"{root / version}: the devkit could not index the tables: no record with token {exc}"


class PlainTables:
    """The part of the devkit's ``NuScenes`` that `synth.nuscenes.read` uses, from the JSON tables alone:
    ``sensor``, ``scene``, ``get(table, token)``, ``dataroot``, ``version``, and the reverse index the
    devkit adds (``sample_data["channel"]``, ``sample["data"][channel]`` = the key-frame sample_data)."""

    TABLES = ("sensor", "calibrated_sensor", "ego_pose", "scene", "sample", "sample_data")

    def __init__(self, root: Path, version: str) -> None:
        self.dataroot, self.version = str(root), version
        self._by_token: dict[str, dict[str, dict]] = {}
        for name in self.TABLES:
            f = root / version / f"{name}.json"
            rows = read_json(f, root, f"the {name} table")
            if not isinstance(rows, list) or not all(isinstance(r, dict) and "token" in r for r in rows):
                raise DatasetError(f"{f}: must be a list of records with a token")
            setattr(self, name, rows)
            self._by_token[name] = {r["token"]: r for r in rows}
        for sd in self.sample_data:
            cs = self.get("calibrated_sensor", sd["calibrated_sensor_token"])
            sd["channel"] = self.get("sensor", cs["sensor_token"])["channel"]
        for s in self.sample:
            s["data"] = {}
        for sd in self.sample_data:
            if sd.get("is_key_frame"):
                self.get("sample", sd["sample_token"])["data"][sd["channel"]] = sd["token"]

    def get(self, table: str, token) -> dict:
        return self._by_token[table][token]  # KeyError for a missing token, as the devkit


def load_tables(root: Path, version: str):
    """The devkit's ``NuScenes`` object of `root`'s `version` (`PlainTables` without the devkit);
    DatasetError naming the broken record."""
    try:
        from nuscenes.nuscenes import NuScenes
    except ImportError:
        NuScenes = None
    check_tables(root, version)
    try:
        if NuScenes is None:
            return PlainTables(root, version)
        return NuScenes(version=version, dataroot=str(root), verbose=False)
    except KeyError as exc:
        raise DatasetError(_diagnose_key_error(root, version, exc)) from None
    except (OSError, ValueError, AssertionError, TypeError) as exc:
        raise DatasetError(f"{root / version}: the devkit could not load the tables ({type(exc).__name__}: "
                           f"{str(exc)[:120]})") from None


def check_tables(root: Path, version: str) -> None:
    """Every ``<version>/*.json`` table (what the devkit opens by name) inside the dataroot and a regular
    file (`synth.files.regular_file`), checked before the devkit or `PlainTables` reads one."""
    within(root, root / version, "the version folder")
    for f in sorted((root / version).iterdir()):
        if f.suffix == ".json":
            regular_file(f, root, "a table")


def get_record(nusc, table: str, token, who: str) -> dict:
    """``nusc.get(table, token)``; DatasetError naming `who` refers to the missing token."""
    try:
        return nusc.get(table, token)
    except KeyError:
        raise DatasetError(f"{nusc.dataroot}/{nusc.version}: {who}: {table}_token {token!r} is not in "
                           f"{table}.json") from None


def read_splits(root: Path, scenes: list[str], version: str) -> tuple[dict[str, list[str]], str]:
    """(train / val / test scene names, their source): ``mcdp_synth/splits.json`` if the dataroot has one,
    else the devkit's official splits of the scenes present (test = val where there is no test scene)."""
    f = root / EXPORT_DIR / "splits.json"
    if f.exists() or f.is_symlink():
        sp = read_json(f, root, "the splits")
        if not isinstance(sp, dict) or not all(isinstance(v, list) for v in sp.values()):
            raise DatasetError(f"{f}: must map split names to lists of scene names")
        for name, seqs in sp.items():
            for s in seqs:
                if s not in scenes:
                    raise DatasetError(f"{f}: splits.{name} names scene {str(s)[:60]!r}, which is not in "
                                       f"{version}/scene.json")
        return {k: list(v) for k, v in sp.items()}, f"{EXPORT_DIR}/splits.json"
    try:
        from nuscenes.utils.splits import create_splits_scenes
    except ImportError:
        raise DatasetError(f"{root}: no {EXPORT_DIR}/splits.json, and the official splits come from the devkit; "
                           f"{INSTALL_HINT}") from None

    official = create_splits_scenes()
    mini = version.endswith("mini")
    present = set(scenes)
    pick = {s: [n for n in official["mini_" + s if mini else s] if n in present] for s in ("train", "val")}
    test = [] if mini else [n for n in official["test"] if n in present]
    source = "nuscenes-devkit create_splits_scenes: " + ("mini_train / mini_val" if mini else "train / val / test")
    if not test:  # v1.0-mini, v1.0-trainval: no test scenes; depth papers report on the official val split
        test = list(pick["val"])
        source += " (test = val: this dataroot has no test scene)"
    return {"train": pick["train"], "val": pick["val"], "test": test}, source


# ---------------------------------------------------------------- the devkit's arithmetic, with or without it
def rotation_matrix(q: np.ndarray) -> np.ndarray:
    """3x3 rotation of a quaternion [w, x, y, z] (normalised first): pyquaternion's ``rotation_matrix``,
    or the same formula where pyquaternion (a devkit dependency) is not installed."""
    try:
        from pyquaternion import Quaternion
    except ImportError:  # pyquaternion's arithmetic step by step, so both give the same bits
        q = np.array(q, dtype=float)
        ss = np.dot(q, q)
        if not abs(1.0 - ss) < 1e-14 and ss > 0:
            q = q / np.sqrt(ss)
        w, x, y, z = q
        qm = np.array([[w, -x, -y, -z], [x, w, -z, y], [y, z, w, -x], [z, -y, x, w]])
        qb = np.array([[w, -x, -y, -z], [x, w, z, -y], [y, -z, w, x], [z, y, -x, w]])
        return np.dot(qm, qb.conj().transpose())[1:][:, 1:]
    return Quaternion(q).rotation_matrix


def rotation_to_quaternion(R: np.ndarray) -> list[float]:
    """Unit quaternion [w, x, y, z] (nuScenes / pyquaternion order) of a 3x3 rotation, w >= 0: the inverse of
    `rotation_matrix` (`synth.nuscenes.export` writes calibrated_sensor and ego_pose with it)."""
    R = np.asarray(R, np.float64)
    tr = R[0, 0] + R[1, 1] + R[2, 2]
    if tr > 0:
        s = 2.0 * math.sqrt(tr + 1.0)
        q = [0.25 * s, (R[2, 1] - R[1, 2]) / s, (R[0, 2] - R[2, 0]) / s, (R[1, 0] - R[0, 1]) / s]
    elif R[0, 0] > R[1, 1] and R[0, 0] > R[2, 2]:
        s = 2.0 * math.sqrt(1.0 + R[0, 0] - R[1, 1] - R[2, 2])
        q = [(R[2, 1] - R[1, 2]) / s, 0.25 * s, (R[0, 1] + R[1, 0]) / s, (R[0, 2] + R[2, 0]) / s]
    elif R[1, 1] > R[2, 2]:
        s = 2.0 * math.sqrt(1.0 + R[1, 1] - R[0, 0] - R[2, 2])
        q = [(R[0, 2] - R[2, 0]) / s, (R[0, 1] + R[1, 0]) / s, 0.25 * s, (R[1, 2] + R[2, 1]) / s]
    else:
        s = 2.0 * math.sqrt(1.0 + R[2, 2] - R[0, 0] - R[1, 1])
        q = [(R[1, 0] - R[0, 1]) / s, (R[0, 2] + R[2, 0]) / s, (R[1, 2] + R[2, 1]) / s, 0.25 * s]
    q = np.asarray(q)
    q = q / np.linalg.norm(q)
    if q[0] < 0:
        q = -q
    return [float(x) for x in q]


MAX_FOCAL_PX = 1e5  # a focal length above this (a 0.06 deg field of view at 100 px) is an error in the table


def check_intrinsic(K: np.ndarray, where: str) -> np.ndarray:
    """`K` when it is a pinhole camera_intrinsic: 3x3, finite, fx and fy in (0, `MAX_FOCAL_PX`], last row
    [0, 0, 1]; else DatasetError naming `where` (the table and token) and the value."""
    if K.shape != (3, 3):
        raise DatasetError(f"{where}: camera_intrinsic must be 3x3, got shape {K.shape}")
    if not np.isfinite(K).all():
        raise DatasetError(f"{where}: camera_intrinsic holds a non-finite value (NaN or inf)")
    for name, f in (("fx", K[0, 0]), ("fy", K[1, 1])):
        if not 0 < f <= MAX_FOCAL_PX:
            raise DatasetError(f"{where}: camera_intrinsic {name} = {float(f):.6g} px; a focal length must be in "
                               f"(0, {MAX_FOCAL_PX:.0e}] px")
    if not np.allclose(K[2], [0.0, 0.0, 1.0], rtol=0, atol=1e-9):
        raise DatasetError(f"{where}: camera_intrinsic's last row must be [0, 0, 1]")
    return K


def pose_matrix(rotation, translation, where: str) -> np.ndarray:
    """4x4 of a nuScenes pose record (rotation [w, x, y, z], translation); DatasetError naming `where`."""
    try:
        q = np.asarray(rotation, np.float64)
        t = np.asarray(translation, np.float64)
        if q.shape != (4,) or t.shape != (3,) or not (np.isfinite(q).all() and np.isfinite(t).all()) or \
                not abs(np.linalg.norm(q) - 1.0) < 1e-3:
            raise ValueError
    except (TypeError, ValueError):
        raise DatasetError(f"{where}: rotation must be a unit quaternion [w, x, y, z] and translation 3 finite "
                           "numbers") from None
    T = np.eye(4)
    T[:3, :3] = rotation_matrix(q)
    T[:3, 3] = t
    return T


def lidar_xyz(path: Path) -> np.ndarray:
    """(3, N) float32 x, y, z of a LIDAR_TOP ``.bin`` (5 float32 per point): the devkit's
    ``LidarPointCloud.from_file``, or the same read without the devkit."""
    regular_file(path)
    try:
        from nuscenes.utils.data_classes import LidarPointCloud
    except ImportError:
        if not str(path).endswith(".bin"):
            raise AssertionError(f"Unsupported filetype {path}") from None
        return np.fromfile(str(path), dtype=np.float32).reshape((-1, 5))[:, :3].T
    return LidarPointCloud.from_file(str(path)).points[:3]


def view_points(pc: np.ndarray, K: np.ndarray) -> np.ndarray:
    """(2, N) pixel coordinates of camera-frame points (3, N): the devkit's ``view_points(..., normalize=True)``
    or the same product without the devkit."""
    try:
        from nuscenes.utils.geometry_utils import view_points
    except ImportError:  # the devkit's arithmetic step by step, so both give the same bits
        pad = np.eye(4)
        pad[:3, :3] = K
        uvw = np.dot(pad, np.concatenate((pc, np.ones((1, pc.shape[1])))))[:3, :]
        return (uvw / uvw[2:3, :].repeat(3, 0).reshape(3, pc.shape[1]))[:2]
    return view_points(pc, K, normalize=True)[:2]
