"""Render throughput and memory: rig-frames/s (six cameras, RGB + depth written) and RSS.

    .venv/bin/python benchmarks/render_throughput.py [--sequences 2 --frames 20 --renders 1000 --rounds 3]

Prints a table: resolution, end-to-end rig-frames/s of one process (scene generation,
six renders, PNG + EXR writes, checksums, overlap counts), the render-only rate, their ratio,
peak RSS, and the RSS growth over N single-camera renders after warm-up (a leak check).
With --rounds R the end-to-end and render-only runs alternate R times in the same process and
each column is the median (the ratio is the median of the R per-round ratios).
"""
from __future__ import annotations

import argparse
import resource
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))


def rss_mb() -> float:
    for line in Path("/proc/self/status").read_text().splitlines():
        if line.startswith("VmRSS:"):
            return int(line.split()[1]) / 1024
    return float("nan")


def main(argv=None) -> int:
    ap = argparse.ArgumentParser()
    ap.add_argument("--sequences", type=int, default=2)
    ap.add_argument("--frames", type=int, default=20)
    ap.add_argument("--renders", type=int, default=1000)
    ap.add_argument("--sizes", default="320x192,640x384")
    ap.add_argument("--rounds", type=int, default=3)
    args = ap.parse_args(argv)
    import numpy as np

    from synth.config import load_data_config
    from synth.render import renderer_for, make_rig, render_dataset

    rows = []
    for size in args.sizes.split(","):
        w, h = (int(x) for x in size.split("x"))
        cfg = load_data_config("configs/data/default.yaml", [f"camera.width={w}", f"camera.height={h}",
                                                             f"dataset.sequences={args.sequences}",
                                                             f"dataset.frames={args.frames}"])
        # end to end and render-only (one scene, no files) in turn, `rounds` times
        from scenes import build_scene
        from synth.lighting import draw_sequence_lighting
        rig = make_rig(cfg)
        e2es, ros = [], []
        for _ in range(args.rounds):
            with tempfile.TemporaryDirectory() as tmp:
                s = render_dataset(cfg, Path(tmp) / "d", workers=1, progress=False, log=lambda *a: None)
            e2es.append(s["rig_frames_per_s"])
            r = renderer_for(cfg)
            scene = build_scene(cfg.scene, args.frames, cfg.dataset.fps, np.random.default_rng(1))
            r.load_scene(scene, None)
            light = draw_sequence_lighting(cfg.lighting, rig.names, np.random.default_rng(2)).light
            t0 = time.perf_counter()
            n_rig = 0
            for f in range(args.frames):
                for cam in rig.cameras:
                    r.render(cam.K, scene.T_world_ego[f] @ cam.T_ego_cam, f, light)
                n_rig += 1
            ros.append(n_rig / (time.perf_counter() - t0))
        e2e, render_only = float(np.median(e2es)), float(np.median(ros))
        ratio = float(np.median(np.asarray(e2es) / np.asarray(ros)))
        # leak check on one scene
        for i in range(50):
            cam = rig.cameras[i % 6]
            r.render(cam.K, scene.T_world_ego[i % args.frames] @ cam.T_ego_cam, i % args.frames, light)
        rss0 = rss_mb()
        for i in range(args.renders):
            cam = rig.cameras[i % 6]
            r.render(cam.K, scene.T_world_ego[i % args.frames] @ cam.T_ego_cam, i % args.frames, light)
        growth = rss_mb() - rss0
        peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
        rows.append((size, e2e, render_only, ratio, peak, growth, s["backend"]))
        print(f"{size}: end to end per round {', '.join(f'{x:.2f}' for x in e2es)} rig-frames/s (the first "
              f"includes the process's GL start-up), render only {', '.join(f'{x:.2f}' for x in ros)}", flush=True)
    print(f"{'size':>9} | {'rig-frames/s (end to end)':>25} | {'rig-frames/s (render only)':>26} | "
          f"{'end to end / render only':>24} | {'peak RSS MB':>11} | "
          f"{'RSS growth over ' + str(args.renders) + ' renders MB':>32} | backend")
    print("-" * 157)
    for size, e2e, ro, ratio, peak, growth, be in rows:
        print(f"{size:>9} | {e2e:25.2f} | {ro:26.2f} | {ratio:23.2f}x | {peak:11.0f} | {growth:32.1f} | {be}")
    print(f"({args.rounds} round(s) of {args.sequences} sequences x {args.frames} frames end to end, then "
          f"{args.frames} rig frames render-only; medians)")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
