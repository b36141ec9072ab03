"""Render throughput and memory: rig-frames/s (six cameras, RGB + depth written) and RSS.

    .venv/bin/python benchmarks/render_throughput.py [--sequences 2 --frames 10 --renders 1000]

Prints a table: resolution, end-to-end rig-frames/s of one process (scene generation,
six renders, PNG + EXR writes, checksums), the render-only rate, peak RSS, and the RSS
growth over N single-camera renders after warm-up (a leak check).
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
        with tempfile.TemporaryDirectory() as tmp:
            s = render_dataset(cfg, Path(tmp) / "d", workers=1, progress=False, log=lambda *a: None)
        # render-only rate and leak check on one scene
        from scenes import build_scene
        from synth.lighting import draw_sequence_lighting
        rig = make_rig(cfg)
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
        render_only = n_rig / (time.perf_counter() - t0)
        for i in range(50):
            cam = rig.cameras[i % 6]
            r.render(cam.K, scene.T_world_ego[i % args.frames] @ cam.T_ego_cam, i % args.frames, light)
        rss0 = rss_mb()
        for i in range(args.renders):
            cam = rig.cameras[i % 6]
            r.render(cam.K, scene.T_world_ego[i % args.frames] @ cam.T_ego_cam, i % args.frames, light)
        growth = rss_mb() - rss0
        peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
        rows.append((size, s["rig_frames_per_s"], render_only, peak, growth, s["backend"]))
    print(f"{'size':>9} | {'rig-frames/s (end to end)':>25} | {'rig-frames/s (render only)':>26} | "
          f"{'peak RSS MB':>11} | {'RSS growth over ' + str(args.renders) + ' renders MB':>32} | backend")
    print("-" * 130)
    for size, e2e, ro, peak, growth, be in rows:
        print(f"{size:>9} | {e2e:25.2f} | {ro:26.2f} | {peak:11.0f} | {growth:32.1f} | {be}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
