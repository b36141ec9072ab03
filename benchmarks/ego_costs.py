"""What the live ego body costs and what it changes (issue 57, item 6; ``ego.appearance=live``,
`synth.config.EgoConfig`).

1. Render time of a rig-frame (6 cameras, labels read back as a dataset render does) with the body live against
   static, on the preset's first scene, 6 frames. Rounds alternate the order (static, live, then live, static);
   each ratio pairs the two arms of one round; the table gives median, min and max over rounds of the process's
   CPU ratio (the one to quote on a shared machine) and the wall ratio.
2. Frame-to-frame photometric change of the body: the preset rendered both ways (same seed) and, per camera that
   sees the body, the mean |RGB(f+1) - RGB(f)| (8-bit levels) over its ego pixels (the mask's 0), frames and
   sequences; the same over the scene pixels for scale.

    .venv/bin/python benchmarks/ego_costs.py [--preset configs/data/tiny.yaml] [--rounds 6]

Feeds: docs/DATASET.md
"""
from __future__ import annotations

import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))


def frame_change(root: Path) -> dict[str, tuple[float, float, list[float]]]:
    """Camera -> (ego, scene, ego per sequence) mean |RGB(f+1) - RGB(f)| of a finished dataset `root`."""
    from synth.files import read_png

    out = {}
    for mpath in sorted((root / "masks").glob("*.png")):
        ego = read_png(mpath, gray=True) == 0
        if not ego.any():
            continue
        e, s, per_seq = [], [], []
        for seq in sorted(p for p in root.glob("seq_*") if p.is_dir()):
            ims = [read_png(p).astype(np.float64) for p in sorted((seq / mpath.stem).glob("??????.png"))]
            for a, b in zip(ims, ims[1:]):
                d = np.abs(b - a)
                e.append(d[ego].mean())
                s.append(d[~ego].mean())
            per_seq.append(float(np.mean(e[-(len(ims) - 1):])))
        out[mpath.stem] = (float(np.mean(e)), float(np.mean(s)), per_seq)
    return out


def main(argv=None) -> int:
    from corelib.cli import ArgumentParser

    ap = ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--preset", default=str(ROOT / "configs" / "data" / "tiny.yaml"))
    ap.add_argument("--rounds", type=int, default=6, help="paired rounds (1..50)")
    args = ap.parse_args(argv)
    if not 1 <= args.rounds <= 50:
        ap.error(f"--rounds {args.rounds} is not in 1..50")
    from scenes.textures import LAYER
    from synth.config import load_data_config
    from synth.lighting import draw_sequence_lighting
    from synth.pipeline import build_sequence_scene
    from synth.render import make_ego_mesh, make_rig, render_dataset, renderer_for

    cfg = load_data_config(args.preset)
    rig, scene = make_rig(cfg), build_sequence_scene(cfg, 0)
    r = renderer_for(cfg)
    light = draw_sequence_lighting(cfg.lighting, rig.names, np.random.default_rng(2)).light
    body = make_ego_mesh(cfg).positions

    def arm(live: bool) -> tuple[float, float]:
        r.load_scene(scene, make_ego_mesh(cfg))
        if live:
            r.set_ego_appearance(True, LAYER["tyre"], (0.8, 0.0, cfg.rig.camera_height_m), cfg.ego.reflection_px,
                                 (body.min(0), body.max(0)))
        c0, w0 = time.process_time(), time.perf_counter()
        for f in range(6):
            for cam in rig.cameras:
                r.render(cam.K, scene.T_world_ego[f] @ cam.T_ego_cam, f, light, size=(cam.width, cam.height),
                         labels=True)
        return time.process_time() - c0, time.perf_counter() - w0

    res: dict[bool, list] = {False: [], True: []}
    arm(False)  # warm-up
    for rnd in range(args.rounds):
        for live in ((False, True) if rnd % 2 == 0 else (True, False)):
            res[live].append(arm(live))
    cpu = [a[0] / b[0] for a, b in zip(res[True], res[False])]
    wall = [a[1] / b[1] for a, b in zip(res[True], res[False])]
    size = f"{cfg.camera.width}x{cfg.camera.height}"
    print(f"{Path(args.preset).name} ({size}, cube faces {cfg.ego.reflection_px} px), 6 rig-frames of sequence 0, "
          f"{args.rounds} rounds")
    print(f"live / static CPU ratio {np.median(cpu):.2f} ({min(cpu):.2f}-{max(cpu):.2f}), wall ratio "
          f"{np.median(wall):.2f} ({min(wall):.2f}-{max(wall):.2f})")
    for live in (False, True):
        print(f"  {'live' if live else 'static':>6}: {np.median([a for a, _ in res[live]]) / 6 * 1000:.1f} ms of CPU, "
              f"{np.median([b for _, b in res[live]]) / 6 * 1000:.1f} ms of wall time a rig-frame (median)")
    with tempfile.TemporaryDirectory() as tmp:
        change = {}
        for mode in ("static", "live"):
            out = Path(tmp) / mode
            render_dataset(load_data_config(args.preset, [f"ego.appearance={mode}"]), out, progress=False,
                           log=lambda *a: None)
            change[mode] = frame_change(out)
    print(f"\nmean |RGB(f+1) - RGB(f)| (8-bit levels), {cfg.dataset.sequences} sequences x {cfg.dataset.frames} frames")
    print(f"{'camera':<16} | {'ego static':>10} | {'ego live':>8} | {'scene':>6} | ego static -> live, by sequence")
    for cam in change["static"]:
        (es, ss, ps), (el, _, pl) = change["static"][cam], change["live"][cam]
        by = ", ".join(f"{a:.2f} -> {b:.2f}" for a, b in zip(ps, pl))
        print(f"{cam:<16} | {es:>10.2f} | {el:>8.2f} | {ss:>6.2f} | {by}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
