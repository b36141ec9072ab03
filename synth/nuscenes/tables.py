"""The tables of a nuScenes dataroot: recognising one (`is_nuscenes_root`), finding its version folder,
loading it through the official devkit with errors that name the broken record and token, and the
train / val / test scene lists.

Without the devkit (an environment with the ``viz`` extra: rerun-sdk needs numpy >= 2, nuscenes-devkit
1.2.0 numpy < 2) `load_tables` reads the tables the reader uses as plain JSON
(`synth.nuscenes.plain.PlainTables`: the same records, with the devkit's ``sample["data"]`` /
``sample_data["channel"]`` reverse index), so `synth view` can record a dataroot; the official splits
still need the devkit.

Example::

    if is_nuscenes_root(root):
        nusc = load_tables(root, resolve_version(root, None))
"""
from __future__ import annotations

from pathlib import Path

from synth.files import DatasetError, read_json, regular_file, within
from synth.nuscenes.layout import SPLITS_FILE
from synth.nuscenes.plain import PlainTables

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
    f = root / SPLITS_FILE
    if f.exists() or f.is_symlink():
        sp = read_json(f, root, "the splits")
        if not isinstance(sp, dict) or not all(isinstance(v, list) for v in sp.values()):
            raise DatasetError(f"{f}: must map split names to lists of scene names")
        for name, seqs in sp.items():
            for s in seqs:
                if s not in scenes:
                    raise DatasetError(f"{f}: splits.{name} names scene {str(s)[:60]!r}, which is not in "
                                       f"{version}/scene.json")
        return {k: list(v) for k, v in sp.items()}, SPLITS_FILE
    try:
        from nuscenes.utils.splits import create_splits_scenes
    except ImportError:
        raise DatasetError(f"{root}: no {SPLITS_FILE}, and the official splits come from the devkit; "
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
