"""Render throughput and memory: rig-frames/s (six cameras, RGB + depth written) and RSS.

Feeds: docs/results/render_throughput.md
Record: ``--record PATH.txt`` also writes the table it prints to PATH, as printed (the text a
docs/results/<doc>/*.txt holds; `scripts/publish_bench.py` puts it in the doc).

    .venv/bin/python benchmarks/render_throughput.py [--sequences 2 --frames 20 --renders 1000 --rounds 3]

Prints a table: resolution, end-to-end rig-frames/s of one process (scene generation,
six renders, PNG + EXR writes, checksums, overlap counts), the render-only rate, their ratio,
the end-to-end rate with the files and overlap counts switched off (what the renders, scene
generation and start-up alone allow: the ceiling of any faster writing on this machine),
peak RSS, and the RSS growth over N single-camera renders after warm-up (a leak check).

Render only = the very render calls of the end-to-end run (the same sequences' scenes with the ego
body, lights, per-camera gains and shadows), read back, with the scenes built and uploaded
beforehand and untimed. With --rounds R the three runs alternate R times in the same process and
each column is the median (the ratios are medians of the R per-round ratios).
"""
from __future__ import annotations

import contextlib
import resource
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from benchmarks._table import tee  # noqa: E402


def rss_mb() -> float:
    for line in Path("/proc/self/status").read_text().splitlines():
        if line.startswith("VmRSS:"):
            return int(line.split()[1]) / 1024
    return float("nan")


def render_only_rate(cfg, rig) -> tuple[float, float]:
    """Rig-frames/s of the end-to-end run's own render calls (module docstring), scenes prepared untimed,
    and the process's CPU milliseconds per rig frame (all threads: llvmpipe rasterises on every core)."""
    import numpy as np

    from synth.lighting import draw_sequence_lighting, frame_gains
    from synth.pipeline import build_sequence_scene
    from synth.render import make_ego_mesh, renderer_for

    r = renderer_for(cfg)
    seconds, cpu, n_rig = 0.0, 0.0, 0
    for index in range(cfg.dataset.sequences):
        _, light_ss, flicker_ss = np.random.SeedSequence([cfg.seed, index]).spawn(3)  # as render_sequence
        scene = build_sequence_scene(cfg, index)
        seq_light = draw_sequence_lighting(cfg.lighting, rig.names, np.random.default_rng(light_ss))
        flicker = np.random.default_rng(flicker_ss)
        r.load_scene(scene, make_ego_mesh(cfg))
        t0, c0 = time.perf_counter(), time.process_time()
        for f in range(cfg.dataset.frames):
            gains = frame_gains(seq_light, flicker)
            for cam in rig.cameras:
                r.render(cam.K, scene.T_world_ego[f] @ cam.T_ego_cam, f, seq_light.light, gains[cam.name])
            n_rig += 1
        seconds += time.perf_counter() - t0
        cpu += time.process_time() - c0
    return n_rig / seconds, 1000 * cpu / n_rig


@contextlib.contextmanager
def files_off():
    """End to end with the frame sink's image (RGB, labels), EXR and overlap tasks switched off (the ablation
    column)."""
    from synth import pipeline

    saved = {k: getattr(pipeline.FrameSink, k) for k in ("png", "rgb", "exr", "overlap")}
    for k in saved:
        setattr(pipeline.FrameSink, k, lambda *a, **kw: None)
    try:
        yield
    finally:
        for k, v in saved.items():
            setattr(pipeline.FrameSink, k, v)


def main(argv=None) -> int:
    from corelib.cli import ArgumentParser  # its errors echo the user's words cut and escaped

    ap = ArgumentParser()
    ap.add_argument("--sequences", type=int, default=2)
    ap.add_argument("--frames", type=int, default=20)
    ap.add_argument("--renders", type=int, default=1000)
    ap.add_argument("--sizes", default="320x192,640x384")
    ap.add_argument("--rounds", type=int, default=3)
    ap.add_argument("--record", metavar="PATH", help="also write what it prints to PATH (text)")
    args = ap.parse_args(argv)
    import numpy as np

    from synth.config import load_data_config
    from synth.render import make_ego_mesh, make_rig, render_dataset, renderer_for

    def e2e_rate(cfg) -> tuple[float, float, str]:
        """rig-frames/s, process CPU ms per rig frame, backend of one end-to-end render."""
        with tempfile.TemporaryDirectory() as tmp:
            c0 = time.process_time()
            s = render_dataset(cfg, Path(tmp) / "d", workers=1, progress=False, log=lambda *a: None)
            cpu = 1000 * (time.process_time() - c0) / s["rig_frames"]
        return s["rig_frames_per_s"], cpu, s["backend"]

    with tee(args.record):
        rows = []
        for size in args.sizes.split(","):
            w, h = (int(x) for x in size.split("x"))
            cfg = load_data_config("configs/data/default.yaml", [f"camera.width={w}", f"camera.height={h}",
                                                                 f"dataset.sequences={args.sequences}",
                                                                 f"dataset.frames={args.frames}"])
            rig = make_rig(cfg)
            e2es, ros, offs, cpus = [], [], [], []
            for _ in range(args.rounds):  # end to end, render only and files off in turn
                e2e, cpu_e2e, backend = e2e_rate(cfg)
                ro, cpu_ro = render_only_rate(cfg, rig)
                with files_off():
                    off, cpu_off, _ = e2e_rate(cfg)
                e2es.append(e2e)
                ros.append(ro)
                offs.append(off)
                cpus.append((cpu_e2e, cpu_ro, cpu_off))
            e2es, ros, offs = np.asarray(e2es), np.asarray(ros), np.asarray(offs)
            cpu_e2e, cpu_ro, cpu_off = np.median(np.asarray(cpus), axis=0)
            # leak check on one scene
            from synth.pipeline import build_sequence_scene
            from synth.lighting import draw_sequence_lighting

            r = renderer_for(cfg)
            scene = build_sequence_scene(cfg, 0)
            r.load_scene(scene, make_ego_mesh(cfg))
            light = draw_sequence_lighting(cfg.lighting, rig.names, np.random.default_rng(2)).light

            def one(i):
                cam = rig.cameras[i % 6]
                r.render(cam.K, scene.T_world_ego[i % args.frames] @ cam.T_ego_cam, i % args.frames, light)

            for i in range(50):
                one(i)
            rss0 = rss_mb()
            for i in range(args.renders):
                one(i)
            growth = rss_mb() - rss0
            peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
            rows.append((size, np.median(e2es), np.median(ros), np.median(e2es / ros), np.median(offs),
                         np.median(offs / ros), cpu_e2e, cpu_ro, cpu_off, peak, growth, backend))
            print(f"{size}: per round end to end {', '.join(f'{x:.2f}' for x in e2es)} rig-frames/s (the first "
                  f"includes the process's GL start-up), render only {', '.join(f'{x:.2f}' for x in ros)}, "
                  f"files off {', '.join(f'{x:.2f}' for x in offs)}", flush=True)
        head = (f"{'size':>9} | {'end to end':>10} | {'render only':>11} | {'ratio':>6} | {'files off':>9} | "
                f"{'ratio':>6} | {'CPU ms: e2e':>11} | {'render only':>11} | {'files off':>9} | {'peak RSS MB':>11} | "
                f"{'RSS growth, ' + str(args.renders) + ' renders, MB':>30} | backend")
        print("rig-frames/s; ratio = the column before / render only (medians of per-round ratios); CPU ms = the "
              "process's CPU time (all threads) per rig frame")
        print(head)
        print("-" * len(head))
        for size, e2e, ro, ratio, off, ratio_off, c_e2e, c_ro, c_off, peak, growth, be in rows:
            print(f"{size:>9} | {e2e:10.2f} | {ro:11.2f} | {ratio:5.2f}x | {off:9.2f} | {ratio_off:5.2f}x | "
                  f"{c_e2e:11.0f} | {c_ro:11.0f} | {c_off:9.0f} | {peak:11.0f} | {growth:30.1f} | {be}")
        print(f"({args.rounds} round(s) of {args.sequences} sequences x {args.frames} frames each; medians)")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
