"""What motion blur costs the renderer (issue 48, item 4): the render time of one image made of K sub-frames
(`sensor.exposure_ms`, `sensor.subframes`; `synth.shutter`) against one render of it (K = 1), on the tiny
preset's first scene, 6 frames x 6 cameras at its size, labels read back as a dataset render does.

Rounds alternate the order (1, 3, 5 then 5, 3, 1) and each ratio pairs a K's time with the K = 1 time of the same
round; the table gives the median, min and max over rounds of the process's CPU time ratio and the wall ratio.
The CPU ratio is the one to quote on a shared machine.

    .venv/bin/python benchmarks/shutter_costs.py --rounds 6 [--record docs/results/render_throughput/shutter_<date>.txt]

Feeds: docs/results/render_throughput.md
"""
from __future__ import annotations

import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))


def main(argv=None) -> int:
    from corelib.cli import ArgumentParser

    ap = ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--rounds", type=int, default=6, help="paired rounds (1..50)")
    ap.add_argument("--record", type=Path, default=None, help="also write the table to this file")
    args = ap.parse_args(argv)
    if not 1 <= args.rounds <= 50:
        ap.error(f"--rounds {args.rounds} is not in 1..50")
    from benchmarks._table import tee
    from synth.config import load_data_config
    from synth.gl_backend import LightState
    from synth.pipeline import build_sequence_scene
    from synth.render import make_ego_mesh, make_rig, renderer_for
    from synth.shutter import Shutter

    cfg = load_data_config(ROOT / "configs" / "data" / "tiny.yaml")
    rig, scene = make_rig(cfg), build_sequence_scene(cfg, 0)
    r = renderer_for(cfg)
    r.load_scene(scene, make_ego_mesh(cfg))
    light = LightState((0.3, 0.2, 0.9), (1, 1, 1), (0.3, 0.3, 0.3), (0.5, 0.6, 0.8), (0.7, 0.7, 0.8), shadows=True)

    def image(sh, cam, x):
        def at(xs):
            return r.render(cam.K, scene.ego_pose_at(xs) @ cam.T_ego_cam, xs, light, size=(cam.width, cam.height),
                            labels=True)
        return at(x) if sh is None else sh.render(at, x, cam.height)

    arms = {1: None, 3: Shutter(10, 3, 0, 8, 10), 5: Shutter(10, 5, 0, 8, 10)}
    res: dict[int, list] = {k: [] for k in arms}
    for rnd in range(args.rounds):
        for k in ([1, 3, 5] if rnd % 2 == 0 else [5, 3, 1]):
            c0, w0 = time.process_time(), time.perf_counter()
            for f in range(6):
                for cam in rig.cameras:
                    image(arms[k], cam, f)
            res[k].append((time.process_time() - c0, time.perf_counter() - w0))
    with tee(args.record):
        print(f"{'K':>3} | {'CPU ratio median (min-max)':>27} | {'wall ratio median (min-max)':>28} | rounds")
        print("-" * 76)
        for k in (3, 5):
            cpu = [a[0] / b[0] for a, b in zip(res[k], res[1])]
            wall = [a[1] / b[1] for a, b in zip(res[k], res[1])]
            print(f"{k:>3} | {np.median(cpu):>8.2f} ({min(cpu):.2f}-{max(cpu):.2f}){'':>9} | "
                  f"{np.median(wall):>8.2f} ({min(wall):.2f}-{max(wall):.2f}){'':>10} | {len(cpu)}")
        print(f"K = 1: {np.median([a for a, _ in res[1]]) / 6 * 1000:.1f} ms of CPU, "
              f"{np.median([b for _, b in res[1]]) / 6 * 1000:.1f} ms of wall time a rig-frame (median)")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
