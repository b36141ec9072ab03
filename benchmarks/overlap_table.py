"""Target vs measured pixel overlap for rig.overlap in 0.1 .. 0.6, both overlap modes.

    .venv/bin/python benchmarks/overlap_table.py [--sequences 2 --frames 3 --width 320 --height 192]

Renders a small dataset per (mode, overlap) into a temporary folder and prints, per mode, the
target and the measured fraction of camera pixels seen by the neighbour (mean of both directions,
summed over all frames) for every adjacent pair, from the manifest the renderer writes.
"""
from __future__ import annotations

import argparse
import sys
import tempfile
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))


def main(argv=None) -> int:
    ap = argparse.ArgumentParser()
    ap.add_argument("--sequences", type=int, default=2)
    ap.add_argument("--frames", type=int, default=3)
    ap.add_argument("--width", type=int, default=320)
    ap.add_argument("--height", type=int, default=192)
    ap.add_argument("--modes", default="spacing,fov")
    args = ap.parse_args(argv)
    from synth.config import load_data_config
    from synth.render import render_dataset

    short = {"CAM_FRONT": "F", "CAM_FRONT_RIGHT": "FR", "CAM_BACK_RIGHT": "BR", "CAM_BACK": "B",
             "CAM_BACK_LEFT": "BL", "CAM_FRONT_LEFT": "FL"}
    for mode in args.modes.split(","):
        rows = []
        for o in (0.1, 0.2, 0.3, 0.4, 0.5, 0.6):
            cfg = load_data_config("configs/data/default.yaml", [
                f"rig.overlap={o}", f"rig.overlap_mode={mode}", f"dataset.sequences={args.sequences}",
                f"dataset.frames={args.frames}", f"camera.width={args.width}", f"camera.height={args.height}"])
            with tempfile.TemporaryDirectory() as tmp:
                s = render_dataset(cfg, Path(tmp) / "d", progress=False, log=lambda *a: None)
            rows.append((o, s["overlap"]))
        pairs = list(rows[0][1]["per_pair_measured"])
        names = ["-".join(short[n] for n in p.split("-")) for p in pairs]
        print(f"\nmode={mode}  ({args.sequences} seq x {args.frames} frames, {args.width}x{args.height}); "
              "each cell: geometric target / measured pixel overlap")
        print(f"{'overlap':>7} | {'hfov':>5} | " + " | ".join(f"{n:>13}" for n in names))
        print("-" * (18 + 16 * len(names)))
        for o, ov in rows:
            cells = []
            for p in pairs:
                d = ov["per_pair_measured"][p]
                cells.append(f"{d['target']:+.2f} / {d['measured']:.3f}")
            print(f"{o:7.2f} | {ov['hfov_deg']:5.1f} | " + " | ".join(f"{c:>13}" for c in cells))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
