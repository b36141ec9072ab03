"""The dataset's record of itself, written last: which sequences are complete, how they are split, and
`manifest.json` (schema: `synth.dataset`; layout: docs/DATASET.md), with the labels every sequence holds.

Example::

    manifest = finalize(cfg, Path("data/tiny"), make_rig(cfg))   # None while a sequence is missing
"""
from __future__ import annotations

from pathlib import Path

import numpy as np

from corelib.configlib import config_hash, config_to_dict
from corelib.hashing import sha256_file
from synth import __version__
from synth.config import DataConfig
from synth.dataset import GENERATOR, INTEGRITY, MANIFEST, SCHEMA_VERSION
from synth.verify import integrity_record
from synth.files import RGB_SUFFIXES, read_json, write_json
from synth.label_kinds import enabled_kinds, kind_names
from synth.label_kinds import label_kinds as label_kinds_table
from synth.rig import Rig
from synth.sizes import size_keys
from synth.shutter import Shutter
from synth.trigger import trigger_record

MARKER_DIR = ".synth"
RECORD = "record.json"


def sequence_id(index: int) -> str:
    return f"seq_{index:05d}"


def label_kinds(cfg: DataConfig) -> list[str]:
    """The labels a render of `cfg` writes (`labels.*`), in the order of the table (`synth.label_kinds`)."""
    return enabled_kinds(cfg.labels)


def labels_record(kinds: list[str]) -> dict:
    """The manifest's ``labels``: the kinds every sequence holds and each held row's record (the class table)
    and file conventions (`synth.label_kinds`)."""
    rec: dict = {"kinds": kinds}
    for k in label_kinds_table():
        if k.name in kinds:
            rec.update(k.record() if k.record is not None else {})
            rec[k.name] = k.about
    return rec


def rgb_record(cfg: DataConfig) -> dict:
    """The manifest's ``rgb`` (only with ``sensor.jpeg_quality``; absent, every image is a PNG): the images'
    format, its JPEG quality and their file name."""
    q = cfg.sensor.jpeg_quality
    if q is None:
        return {}
    return {"rgb": {"format": "jpeg", "quality": int(q), "file": f"<seq>/<CAM>/<frame>{RGB_SUFFIXES['jpeg']}"}}


def assign_splits(cfg: DataConfig) -> dict[str, list[str]]:
    """Deterministic split of sequence ids: a permutation drawn from the seed."""
    n = cfg.dataset.sequences
    rng = np.random.default_rng(np.random.SeedSequence([cfg.seed, 0x5EED]))
    perm = rng.permutation(n)
    n_test = int(round(n * cfg.dataset.test_fraction))
    n_val = int(round(n * cfg.dataset.val_fraction))
    if n >= 3:
        n_test = max(n_test, 1 if cfg.dataset.test_fraction > 0 else 0)
        n_val = max(n_val, 1 if cfg.dataset.val_fraction > 0 else 0)
    n_test, n_val = min(n_test, max(n - 1, 0)), min(n_val, max(n - 1 - n_test, 0))
    test = sorted(sequence_id(int(i)) for i in perm[:n_test])
    val = sorted(sequence_id(int(i)) for i in perm[n_test:n_test + n_val])
    train = sorted(sequence_id(int(i)) for i in perm[n_test + n_val:])
    return {"train": train, "val": val, "test": test}


def began_with(out: Path) -> str | None:
    """The code version that began the render into `out` (`corelib.version.code_version`, in its marker),
    None when the marker does not record one."""
    marker = out / MARKER_DIR / "config.json"
    v = read_json(marker).get("code_version") if marker.is_file() else None
    return v if isinstance(v, str) else None


def complete_sequences(out: Path, n: int) -> list[int]:
    return [i for i in range(n) if (out / sequence_id(i) / RECORD).is_file()]


def finalize(cfg: DataConfig, out: Path, rig: Rig) -> dict | None:
    """Write manifest.json if every sequence is complete; returns the manifest (or None)."""
    from synth.calibrate import overlap_record

    n = cfg.dataset.sequences
    if len(complete_sequences(out, n)) != n:
        return None
    files: dict[str, str] = {"rig.json": sha256_file(out / "rig.json")}
    for name in rig.names:
        files[f"masks/{name}.png"] = sha256_file(out / "masks" / f"{name}.png")
    totals: dict[str, list[int]] = {}
    sequences = {}
    families: dict[str, int] = {}
    kinds = list(kind_names())
    for i in range(n):
        rec = read_json(out / sequence_id(i) / RECORD)
        kinds = [k for k in kinds if k in rec.get("labels", [])]  # a render resumed by older code: the common kinds
        files.update(rec["files"])
        sequences[rec["sequence"]] = {"frames": rec["frames"], "scene": rec["scene"],
                                      "time_of_day": rec["time_of_day"],
                                      **{k: rec[k] for k in ("sensor", "weather") if k in rec}}  # drawn values
        fam = rec["scene"].get("family", "?")
        families[fam] = families.get(fam, 0) + 1
        for k, (a, b) in rec["overlap_counts"].items():
            t = totals.setdefault(k, [0, 0])
            t[0] += a
            t[1] += b
    manifest = {
        "schema_version": SCHEMA_VERSION, "generator": GENERATOR, "generator_version": __version__,
        "code_version": began_with(out),
        "config": config_to_dict(cfg), "config_hash": config_hash(cfg), "seed": cfg.seed,
        "cameras": rig.names, **size_keys((cfg.camera.width, cfg.camera.height), rig.cameras),
        "fps": cfg.dataset.fps, "has_depth": True,
        "splits": assign_splits(cfg), "sequences": sequences, "families": families,
        "overlap": overlap_record(cfg, rig, totals),
        "labels": labels_record(kinds), **rgb_record(cfg),
        "files": files,
    }
    trigger = trigger_record(cfg.rig, rig)
    if trigger is not None:  # a synchronous rig's manifest is as it was
        manifest["trigger"] = trigger
    shutter = Shutter.for_config(cfg)
    if shutter is not None:  # a global, instantaneous shutter's manifest is as it was
        manifest["shutter"] = shutter.record()
    manifest[INTEGRITY] = integrity_record(manifest, read_json(out / "rig.json"))
    write_json(out / MANIFEST, manifest)
    return manifest


