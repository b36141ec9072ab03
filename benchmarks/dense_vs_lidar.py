"""One trained run evaluated on dense rendered depth and on the LiDAR depth of its nuScenes export.

Feeds: docs/NUSCENES.md

    .venv/bin/python benchmarks/dense_vs_lidar.py [--sequences 40 --frames 10 --steps 300]

Renders a tiny-preset world, trains mono2 from scratch (the recipe of docs/results/learning.md:
lr 5e-4, out_of_view identity, one thread), exports the world with `synth export --format
nuscenes`, and evaluates the run (a) on the source dataset (PNG input, dense exact z-depth) and
(b) on the export read back through the devkit (JPEG q95 input, LIDAR_TOP projected depth), next
to the constant-depth yardstick on each. Needs the `nuscenes` extra. Prints a table.
"""
from __future__ import annotations

import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))


def main(argv=None) -> int:
    from corelib.cli import ArgumentParser  # its errors echo the user's words cut and escaped

    ap = ArgumentParser()
    ap.add_argument("--sequences", type=int, default=40)
    ap.add_argument("--frames", type=int, default=10)
    ap.add_argument("--steps", type=int, default=300)
    ap.add_argument("--keep", default=None, help="folder to keep the data, run and export in (reused if there)")
    ap.add_argument("--supervised", action="store_true",
                    help="train with ground-truth depth instead (benchmarks/learning_curves.py's upper bound): a "
                         "network with depth structure for sure, when the question is only the ground truth's effect")
    args = ap.parse_args(argv)
    import torch

    torch.set_num_threads(1)
    from corelib.configlib import load_config
    from mcdp.config import RunConfig
    from mcdp.evaluate import EvalConfig, evaluate
    from mcdp.priors import constant_depth_predictor, median_gt_depth
    from mcdp.predict import Predictor
    from mcdp.trainer import Trainer
    from synth.config import load_data_config
    from synth.open import open_dataset
    from synth.nuscenes.export import export_nuscenes
    from synth.render import render_dataset

    tmp = Path(args.keep) if args.keep else Path(tempfile.mkdtemp())
    t0 = time.perf_counter()
    dcfg = load_data_config(ROOT / "configs/data/tiny.yaml",
                            [f"dataset.sequences={args.sequences}", f"dataset.frames={args.frames}"])
    if not (tmp / "data" / "manifest.json").is_file():
        render_dataset(dcfg, tmp / "data", progress=False, log=lambda *a: None)
    ds = open_dataset(tmp / "data")
    t_render = time.perf_counter() - t0
    cfg = load_config(RunConfig, ROOT / "configs/train/tiny/mono2.yaml",
                      [f"train.steps={args.steps}", "train.lr=5e-4", "train.threads=1", "train.num_workers=0"])
    t0 = time.perf_counter()
    run = tmp / ("run_supervised" if args.supervised else "run")
    if args.supervised:
        sys.path.insert(0, str(ROOT / "benchmarks"))
        from learning_curves import SupervisedRun

        st = SupervisedRun(cfg, ds)
        st.train(args.steps)
        (run / "checkpoints").mkdir(parents=True, exist_ok=True)
        st.save_checkpoint(run / "checkpoints" / "last.pt")
    else:
        tr = Trainer(cfg, ds, run, progress=False, tensorboard=False)
        try:
            tr.train()
        finally:
            tr.close()
    t_train = time.perf_counter() - t0
    t0 = time.perf_counter()
    if not (tmp / "ns" / "mcdp_synth" / "export.json").is_file():
        export_nuscenes(open_dataset(tmp / "data"), tmp / "ns", progress=False)
    t_export = time.perf_counter() - t0
    ns = open_dataset(tmp / "ns")
    ecfg = EvalConfig()
    rows = []
    for name, d in (("dense (rendered, PNG)", ds), ("LiDAR (export, JPEG)", ns)):
        pred = Predictor(run, d, "last" if args.supervised else "auto")
        m = evaluate(d, pred.predict, "test", ecfg, progress=False)
        c = evaluate(d, constant_depth_predictor(d, median_gt_depth(d, "train", ecfg)), "test", ecfg, progress=False)
        who = "mono2 supervised (GT), median scaling" if args.supervised else "mono2, median scaling"
        rows.append((name, who, m["stages"]["final"]["median"], m["stages"]["final"]["dep_con"]))
        rows.append((name, "constant depth, median scaling", c["stages"]["final"]["median"],
                     c["stages"]["final"]["dep_con"]))
    print(f"\n{args.sequences} sequences x {args.frames} frames (96x64), mono2 {args.steps} steps"
          f"{' supervised with ground truth' if args.supervised else ''}; "
          f"render {t_render:.0f} s, train {t_train:.0f} s, export {t_export:.0f} s; test split, eval "
          f"{ecfg.min_depth}-{ecfg.max_depth} m")
    print("| ground truth | predictor | abs_rel | sq_rel | rmse | a1 | overlap / non-overlap abs_rel | Dep Con (m) |")
    print("|---|---|---|---|---|---|---|---|")
    for gt, who, med, dc in rows:
        a, o, n = med["mean"], med["overlap"], med["non_overlap"]
        print(f"| {gt} | {who} | {a['abs_rel']:.3f} | {a['sq_rel']:.3f} | {a['rmse']:.2f} | {a['a1']:.3f} | "
              f"{o['abs_rel']:.3f} / {n['abs_rel']:.3f} | {dc['mean']:.3f} |")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
