"""Where an end-to-end rig frame's CPU goes: each writer task alone, the compression its bytes require,

Feeds: docs/results/render_throughput.md
scene generation, and the process's CPU by thread in end-to-end, render-only and files-off runs.

    .venv/bin/python benchmarks/render_costs.py [--size 320x192 --frames 10 --scenes 6]

Prints three tables (docs/results/render_throughput.md, "Why 0.85x cannot be reached"):
1. CPU ms per rig frame of each task on one thread, over `--frames` rig frames of sequence 0: PNG encode
   (cv2, as the writer does), the deflate alone (``zlib.compress(filtered rows, level)``, and how many of
   cv2's IDAT streams it reproduces byte for byte), EXR write, overlap counts;
2. CPU seconds to build each of the first `--scenes` sequences' scenes (family named);
3. CPU ms per rig frame by thread (from /proc/self/task) for `benchmarks/render_throughput.py`'s end to
   end, render only and files off, 2 sequences x 20 frames.
"""
from __future__ import annotations

import collections
import contextlib
import os
import struct
import sys
import tempfile
import time
import zlib
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
sys.path.insert(0, str(Path(__file__).resolve().parent))


def idat(png: bytes) -> bytes:
    """The concatenated IDAT payload (the zlib stream) of a PNG file."""
    i, out = 8, b""
    while i < len(png):
        n, = struct.unpack(">I", png[i:i + 4])
        if png[i + 4:i + 8] == b"IDAT":
            out += png[i + 8:i + 8 + n]
        i += 12 + n
    return out


def thread_cpu() -> collections.Counter:
    """CPU seconds so far of each live thread of this process, by thread name (digits stripped)."""
    out: collections.Counter = collections.Counter()
    tck = os.sysconf("SC_CLK_TCK")
    for t in os.listdir("/proc/self/task"):
        try:
            stat = Path(f"/proc/self/task/{t}/stat").read_text().rsplit(")", 1)[1].split()
            name = Path(f"/proc/self/task/{t}/comm").read_text().strip().rstrip("0123456789_-")
        except OSError:
            continue
        out[(t, name)] += (int(stat[11]) + int(stat[12])) / tck
    return out


def main(argv=None) -> int:
    from corelib.cli import ArgumentParser  # its errors echo the user's words cut and escaped

    ap = ArgumentParser()
    ap.add_argument("--size", default="320x192")
    ap.add_argument("--frames", type=int, default=10)
    ap.add_argument("--scenes", type=int, default=6)
    args = ap.parse_args(argv)
    import numpy as np

    from render_throughput import files_off, render_only_rate
    from synth.config import load_data_config
    from synth.files import encode_png, write_depth_exr
    from synth.lighting import draw_sequence_lighting
    from synth.overlap import overlap_fraction_counts
    from synth.pipeline import build_sequence_scene
    from synth.render import make_ego_mesh, make_rig, render_dataset, render_masks, renderer_for

    w, h = (int(x) for x in args.size.split("x"))
    cfg = load_data_config("configs/data/default.yaml", [f"camera.width={w}", f"camera.height={h}",
                                                         "dataset.sequences=2", "dataset.frames=20"])
    rig = make_rig(cfg)
    level = cfg.render.png_compression
    r = renderer_for(cfg)
    scene = build_sequence_scene(cfg, 0)
    r.load_scene(scene, make_ego_mesh(cfg))
    light = draw_sequence_lighting(cfg.lighting, rig.names, np.random.default_rng(2)).light
    frames = [{c.name: r.render(c.K, scene.T_world_ego[f] @ c.T_ego_cam, f, light) for c in rig.cameras}
              for f in range(args.frames)]
    masks = render_masks(cfg, rig)

    def per_frame(fn) -> float:
        fn(frames[0])  # warm-up: the overlap's per-rig rays and candidates, encoders' first calls
        c0 = time.thread_time()
        for fr in frames:
            fn(fr)
        return 1000 * (time.thread_time() - c0) / len(frames)

    pngs = [encode_png(x["rgb"], level) for fr in frames for x in fr.values()]
    streams = [idat(p) for p in pngs]
    rows = [zlib.decompress(s) for s in streams]
    same = sum(zlib.compress(raw, level) == s for raw, s in zip(rows, streams))
    c0 = time.thread_time()
    for raw in rows:
        zlib.compress(raw, level)
    deflate = 1000 * (time.thread_time() - c0) / len(frames)
    def png(fr):
        for x in fr.values():
            encode_png(x["rgb"], level)

    def overlap(fr):
        overlap_fraction_counts({k: x["depth"] for k, x in fr.items()}, masks, rig.cameras, rig.neighbours)

    with tempfile.TemporaryDirectory() as tmp:
        def exr(fr):
            for k, x in fr.items():
                write_depth_exr(Path(tmp) / f"{k}.exr", x["depth"], fsync=False)

        costs = [("PNG encode (cv2, as written)", per_frame(png)),
                 (f"  of which the deflate alone (zlib level {level}; {same}/{len(streams)} IDAT streams identical)",
                  deflate),
                 ("EXR write (OpenEXR, ZIP)", per_frame(exr)),
                 ("overlap counts", per_frame(overlap))]
    print(f"{args.size}, {len(frames)} rig frames of sequence 0, one thread")
    print(f"{'task':<74} | CPU ms / rig frame")
    for name, ms in costs:
        print(f"{name:<74} | {ms:18.1f}")

    print(f"\nscene generation, default config ({cfg.dataset.frames} frames a sequence)")
    print(f"{'sequence':>8} | {'family':<12} | CPU s | CPU ms / rig frame")
    for i in range(args.scenes):
        c0 = time.thread_time()
        sc = build_sequence_scene(cfg, i)
        s = time.thread_time() - c0
        print(f"{i:>8} | {str(sc.info.get('family')):<12} | {s:5.2f} | {1000 * s / cfg.dataset.frames:18.0f}")

    print(f"\nCPU ms per rig frame by thread, 2 sequences x 20 frames at {args.size}")
    n_rig = cfg.dataset.sequences * cfg.dataset.frames
    for mode in ("end to end", "render only", "files off"):
        before, p0 = thread_cpu(), time.process_time()
        if mode == "render only":
            render_only_rate(cfg, rig)  # includes its untimed scene builds on the main thread
        else:
            with files_off() if mode == "files off" else contextlib.nullcontext(), \
                    tempfile.TemporaryDirectory() as tmp:
                render_dataset(cfg, Path(tmp) / "d", workers=1, progress=False, log=lambda *a: None)
        after, total = thread_cpu(), time.process_time() - p0
        by: collections.Counter = collections.Counter()
        for key, v in after.items():
            by[key[1]] += v - before.get(key, 0.0)
        gone = total - sum(by.values())  # threads that ended during the run: the writers and the scene builder
        cols = ", ".join(f"{k} {1000 * v / n_rig:.0f}" for k, v in sorted(by.items()) if v > 0)
        print(f"{mode:>12}: {cols}, ended threads (writers, scene builder) {1000 * gone / n_rig:.0f}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
