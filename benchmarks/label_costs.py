"""What the labels cost a render: seconds per rig-frame and bytes per rig-frame on disk, per label kind.

Feeds: docs/results/render_throughput.md
Record: ``--record PATH.txt`` also writes the table it prints to PATH (`scripts/publish_bench.py`).

    .venv/bin/python benchmarks/label_costs.py [--size 320x192 --sequences 2 --frames 10 --rounds 3]

Renders the same small dataset (``configs/data/default.yaml`` at ``--size``, one worker) with no labels, with
each kind alone (``labels.semantic``, ``labels.instance``, ``labels.flow``), with the defaults (semantic and
instance) and with all three,
the settings in turn round after round (A B C ... A B C ...), and prints per setting the median wall seconds
per rig-frame, its ratio to no labels (the median of the per-round ratios, so a machine whose speed drifts
between rounds still gives a fair ratio), and the bytes per rig-frame the label files add (exact: the files'
sizes on disk, by kind).
"""
from __future__ import annotations

import statistics
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from benchmarks._table import tee  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
SETTINGS = {
    "none": ["labels.semantic=false", "labels.instance=false", "labels.flow=false"],
    "semantic": ["labels.semantic=true", "labels.instance=false", "labels.flow=false"],
    "instance": ["labels.semantic=false", "labels.instance=true", "labels.flow=false"],
    "flow": ["labels.semantic=false", "labels.instance=false", "labels.flow=true"],
    "default": [],  # semantic + instance
    "all three": ["labels.flow=true"],
}
KINDS = {"semantic": (".semantic.png",), "instance": (".instance.png", "instances.json"),
         "flow": (".flow.exr", ".flow_valid.png", ".movers.png")}


def render_once(overrides: list[str], out: Path) -> float:
    from synth.config import load_data_config
    from synth.render import render_dataset

    cfg = load_data_config(ROOT / "configs" / "data" / "default.yaml", overrides)
    t0 = time.perf_counter()
    render_dataset(cfg, out, workers=1, progress=False, log=lambda *a: None)
    return time.perf_counter() - t0


def label_bytes(out: Path) -> dict[str, int]:
    """Bytes on disk by label kind, and of the RGB images and depth maps (``"rgb+depth"``, the yardstick)."""
    sizes = {k: 0 for k in KINDS}
    sizes["rgb+depth"] = 0
    for p in out.rglob("*"):
        if not p.is_file():
            continue
        kind = next((k for k, suffixes in KINDS.items() if p.name.endswith(suffixes)), None)
        if kind is None and p.parent.parent.name.startswith("seq_") and p.name.endswith((".depth.exr", ".png", ".jpg")):
            kind = "rgb+depth"
        if kind is not None:
            sizes[kind] += p.stat().st_size
    return sizes


def main(argv=None) -> int:
    from corelib.cli import ArgumentParser  # its errors echo the user's words cut and escaped

    ap = ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--size", default="320x192")
    ap.add_argument("--sequences", type=int, default=2)
    ap.add_argument("--frames", type=int, default=10)
    ap.add_argument("--rounds", type=int, default=3)
    ap.add_argument("--record", type=Path, default=None)
    a = ap.parse_args(argv)
    w, h = (int(x) for x in a.size.split("x"))
    base = [f"camera.width={w}", f"camera.height={h}", f"dataset.sequences={a.sequences}",
            f"dataset.frames={a.frames}", "dataset.val_fraction=0", "dataset.test_fraction=0"]
    rig_frames = a.sequences * a.frames
    secs: dict[str, list[float]] = {k: [] for k in SETTINGS}
    ratios: dict[str, list[float]] = {k: [] for k in SETTINGS}
    sizes: dict[str, dict[str, int]] = {}
    with tempfile.TemporaryDirectory() as tmp:
        render_once(base + SETTINGS["none"], Path(tmp) / "warmup")  # GL, shaders, caches
        for r in range(a.rounds):
            for name, ov in SETTINGS.items():
                out = Path(tmp) / f"{r}_{name.split()[0]}"
                secs[name].append(render_once(base + ov, out) / rig_frames)
                if r == 0:
                    sizes[name] = label_bytes(out)
            for name in SETTINGS:
                ratios[name].append(secs[name][-1] / secs["none"][-1])
    with tee(a.record):
        print(f"{a.size}, {a.sequences} sequences x {a.frames} frames, one worker, {a.rounds} rounds in turn "
              "(median s per rig-frame; ratio: median of the per-round ratios to no labels)")
        rgbd = sizes["none"]["rgb+depth"] / rig_frames / 1024
        print(f"(RGB images and depth maps alone: {rgbd:.1f} KB a rig-frame on disk)")
        print(f"{'labels':>14} | {'s / rig-frame':>13} | {'x no labels':>11} | {'label KB / rig-frame':>20} | "
              f"{'x RGB + depth bytes':>19}")
        print("-" * 90)
        for name in SETTINGS:
            kb = sum(v for k, v in sizes[name].items() if k != "rgb+depth") / rig_frames / 1024
            print(f"{name:>14} | {statistics.median(secs[name]):13.3f} | {statistics.median(ratios[name]):11.2f} | "
                  f"{kb:20.1f} | {kb / rgbd:19.2f}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
