"""`synth info DATA`: what a dataset holds, read from its manifest (nothing decoded): sequences and frames,
splits, scene families, cameras and their image sizes, depth, the rig's measured overlap per camera pair, and
its size on disk. Works for a rendered dataset and, through the same reader (`synth.open.open_dataset`),
a nuScenes dataroot (no families or overlap record there).

Example::

    info = dataset_info("data/tiny")
    print(format_info(info))
"""
from __future__ import annotations

import os
from pathlib import Path

SPLITS = ("train", "val", "test")


def disk_bytes(root: str | Path) -> tuple[int, int]:
    """(bytes, files) of the regular files under ``root``; links are not followed (nor counted)."""
    total = n = 0
    for folder, dirs, files in os.walk(root, followlinks=False):
        for f in files:
            p = os.path.join(folder, f)
            if not os.path.islink(p):
                total += os.stat(p).st_size
                n += 1
    return total, n


def dataset_info(path: str | Path) -> dict:
    """A JSON-able summary of the dataset at ``path`` (`synth.files.DatasetError` naming the file if it is
    not one)."""
    from synth.open import open_dataset

    ds = open_dataset(path)
    m = (ds.manifest if ds.format in ("synth", "nuscenes") else {}) or {}
    frames = {s: ds.n_frames(s) for s in ds.sequences}
    splits = {k: list(m.get("splits", {}).get(k, [])) for k in SPLITS}
    overlap = m.get("overlap") or {}
    size, n_files = disk_bytes(ds.root)
    default = m.get("image_size") or {"width": ds.cameras[0].width, "height": ds.cameras[0].height}
    return {
        "path": str(ds.root), "format": ds.format, "version": m.get("version"),
        "sequences": frames, "frames": sum(frames.values()),
        "splits": {k: {"sequences": v, "frames": sum(frames.get(s, 0) for s in v)} for k, v in splits.items()},
        "families": dict(m.get("families") or {}),
        "cameras": list(ds.camera_names), "image_size": [default["width"], default["height"]],  # the manifest's
        "camera_sizes": {c.name: [c.width, c.height] for c in ds.cameras}, "fps": ds.fps,
        "has_depth": bool(ds.has_depth),
        "overlap": {"target": overlap.get("target"), "mode": overlap.get("mode"),
                    "per_pair": {p: {"target": d.get("target"), "measured": d.get("measured")}
                                 for p, d in (overlap.get("per_pair_measured") or {}).items()}},
        "bytes": size, "files": n_files, "config_hash": m.get("config_hash"),
    }


def _size(n: int) -> str:
    for unit, f in (("GB", 1e9), ("MB", 1e6), ("kB", 1e3)):
        if n >= f:
            return f"{n / f:.2f} {unit}"
    return f"{n} B"


def format_info(info: dict) -> str:
    """The summary as text, one fact a line."""
    from synth.rig import sizes_text

    seqs = info["sequences"]
    lines = [f"{info['path']} ({info['format']}{' ' + info['version'] if info['version'] else ''})",
             f"sequences   {len(seqs)}, {info['frames']} rig-frames at {info['fps']:g} fps",
             f"cameras     {len(info['cameras'])} ({', '.join(info['cameras'])}), "
             + sizes_text({c: tuple(wh) for c, wh in info["camera_sizes"].items()}),
             f"depth       {'yes' if info['has_depth'] else 'no'}",
             f"disk        {_size(info['bytes'])} in {info['files']} files"]
    for k, v in info["splits"].items():
        lines.append(f"split {k:<5} {len(v['sequences'])} sequences, {v['frames']} frames: "
                     + (", ".join(v["sequences"]) if v["sequences"] else "-"))
    if info["families"]:
        lines.append("families    " + ", ".join(f"{f} {n}" for f, n in sorted(info["families"].items())))
    ov = info["overlap"]
    if ov["per_pair"]:
        lines.append(f"overlap     target {ov['target']:.2f} ({ov['mode']}); measured pixel overlap per pair:")
        for pair, d in ov["per_pair"].items():
            tgt = "" if d["target"] is None else f"geometric {d['target']:+.3f}  "
            lines.append(f"  {pair:32s} {tgt}measured {d['measured']:.3f}")
    lines.append("frames per sequence: " + ", ".join(f"{s} {n}" for s, n in seqs.items()))
    return "\n".join(lines)
