"""Target vs measured pixel overlap for rig.overlap in 0.1 .. 0.6, both overlap modes.

Feeds: docs/results/overlap.md
Record: ``--record PATH.txt`` also writes the tables it prints to PATH, as printed (the text a
docs/results/<doc>/*.txt holds; `scripts/publish_bench.py` puts it in the doc).

    .venv/bin/python benchmarks/overlap_table.py [--sequences 2 --frames 3 --width 320 --height 192]

Renders a small dataset per (mode, overlap) into a temporary folder and prints, per mode, the
geometric target and the measured overlap (`synth.overlap`: the neighbour sees the pixel's point,
ego masks and z-test included; mean of both directions, summed over all frames) for every adjacent
pair, from the manifest the renderer writes; in brackets the frustum-only fraction (no ego mask in
the neighbour, no z-test: the definition before issue #11) from the same depth files.
"""
from __future__ import annotations

import sys
import tempfile
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from benchmarks._table import tee  # noqa: E402


def frustum_only(path: Path) -> dict[str, float]:
    """Per pair, mean of both directions: valid pixels of i whose point is in front of j and inside its
    image (no ego mask in j, no z-test), as the manifest measured it before the one definition."""
    import numpy as np

    from synth.open import open_dataset
    from synth.overlap import overlap_mask, pair_overlaps

    ds = open_dataset(path)
    cams, tot = ds.cameras, {}
    for seq in ds.sequences:
        for f in range(ds.n_frames(seq)):
            depth = {c.name: ds.read_depth(seq, c.name, f) for c in cams}
            for a, b in ds.neighbours:
                for i, j in ((a, b), (b, a)):
                    ci, cj = cams[i], cams[j]
                    far = np.full_like(depth[cj.name], 1e12)  # nothing in j is nearer: no z-test
                    ov = overlap_mask(depth[ci.name], ci.K, ci.T_ego_cam, far, cj.K, cj.T_ego_cam,
                                      mask_i=ds.mask(ci.name))
                    t = tot.setdefault(f"{ci.name}->{cj.name}", [0, 0])
                    t[0] += int(((depth[ci.name] > 0) & ds.mask(ci.name)).sum())
                    t[1] += int(ov.sum())
    return {k: v["measured"] for k, v in pair_overlaps(tot, ds.camera_names, ds.neighbours).items()}


def main(argv=None) -> int:
    from corelib.cli import ArgumentParser  # its errors echo the user's words cut and escaped

    ap = ArgumentParser()
    ap.add_argument("--sequences", type=int, default=2)
    ap.add_argument("--frames", type=int, default=3)
    ap.add_argument("--width", type=int, default=320)
    ap.add_argument("--height", type=int, default=192)
    ap.add_argument("--modes", default="spacing,fov")
    ap.add_argument("--presets", default="", help="real-rig data presets instead of the sweep of the knob, e.g. "
                    "nuscenes_like,ddad_like (configs/data/<name>.yaml)")
    ap.add_argument("--knob", choices=["angle", "pixels"], default="angle",
                    help="pixels: the calibrated knob (synth.calibrate): target / solved angle / measured, and its cost")
    ap.add_argument("--record", metavar="PATH", help="also write what it prints to PATH (text)")
    args = ap.parse_args(argv)
    with tee(args.record):
        if args.presets:
            return preset_table(args)
        if args.knob == "pixels":
            return calibrated_table(args)
        return angle_table(args)


def angle_table(args) -> int:
    """Per mode, target / measured / frustum-only overlap of every pair at rig.overlap 0.1 .. 0.6."""
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
                frustum = frustum_only(Path(tmp) / "d")
            rows.append((o, s["overlap"], frustum))
        pairs = list(rows[0][1]["per_pair_measured"])
        names = ["-".join(short[n] for n in p.split("-")) for p in pairs]
        print(f"\nmode={mode}  ({args.sequences} seq x {args.frames} frames, {args.width}x{args.height}); "
              "each cell: geometric target / measured pixel overlap")
        print(f"{'overlap':>7} | {'hfov':>5} | " + " | ".join(f"{n:>21}" for n in names))
        print("-" * (18 + 24 * len(names)))
        for o, ov, fr in rows:
            cells = []
            for p in pairs:
                d = ov["per_pair_measured"][p]
                cells.append(f"{d['target']:+.2f} / {d['measured']:.3f} ({fr[p]:.3f})")
            print(f"{o:7.2f} | {ov['hfov_deg']:5.1f} | " + " | ".join(f"{c:>21}" for c in cells))
    return 0


def calibrated_table(args) -> int:
    """rig.overlap_target=pixels for 0.10-0.60 in each mode: the solved geometric overlap, the calibration
    sample's measured overlap, the rendered dataset's (mean of the pairs at the target) and the calibration's
    wall time (docs/results/overlap.md, 'The calibrated knob')."""
    import time

    from synth import calibrate
    from synth.config import load_data_config
    from synth.render import render_dataset

    for mode in args.modes.split(","):
        print(f"\nmode={mode}, rig.overlap_target=pixels ({args.sequences} seq x {args.frames} frames, "
              f"{args.width}x{args.height}; calibration sample: frame 0 of {calibrate.SAMPLES} sequences)")
        print(f"{'target':>6} | {'solved angle overlap':>20} | {'calibration':>11} | {'dataset':>7} | {'calib. s':>8}")
        for o in (0.1, 0.2, 0.3, 0.4, 0.5, 0.6):
            cfg = load_data_config("configs/data/default.yaml", [
                f"rig.overlap={o}", f"rig.overlap_mode={mode}", "rig.overlap_target=pixels",
                f"dataset.sequences={args.sequences}", f"dataset.frames={args.frames}",
                f"camera.width={args.width}", f"camera.height={args.height}"])
            t0 = time.perf_counter()
            try:
                cal = calibrate.calibration(cfg)
            except ValueError as exc:
                print(f"{o:6.2f} | {str(exc)[:90]}")
                continue
            dt = time.perf_counter() - t0
            with tempfile.TemporaryDirectory() as tmp:
                s = render_dataset(cfg, Path(tmp) / "d", progress=False, log=lambda *a: None)
            ov = s["overlap"]
            at = [v["measured"] for v in ov["per_pair_measured"].values() if abs(v["target"] - ov["geometric"]) < 1e-3]
            print(f"{o:6.2f} | {cal['geometric']:20.3f} | {cal['measured']:11.3f} | {sum(at) / len(at):7.3f} | {dt:8.1f}")
    return 0


def preset_table(args) -> int:
    """The measured pixel overlap per pair of each real-rig preset (docs/results/overlap.md, 'Real rigs')."""
    from synth.config import load_data_config
    from synth.render import render_dataset

    for name in args.presets.split(","):
        cfg = load_data_config(f"configs/data/{name}.yaml", [
            f"dataset.sequences={args.sequences}", f"dataset.frames={args.frames}", f"camera.width={args.width}",
            f"camera.height={args.height}"])
        with tempfile.TemporaryDirectory() as tmp:
            s = render_dataset(cfg, Path(tmp) / "d", progress=False, log=lambda *a: None)
        pp = s["overlap"]["per_pair_measured"]
        print(f"\n{name} ({args.sequences} seq x {args.frames} frames, {args.width}x{args.height}): "
              "pair | geometric target | measured pixel overlap")
        for p, d in pp.items():
            print(f"  {p:<32} {d['target']:+.3f}   {d['measured']:.3f}")
        m = [d["measured"] for d in pp.values()]
        print(f"  {'mean over the pairs':<32} {'':>6}   {sum(m) / len(m):.3f}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
