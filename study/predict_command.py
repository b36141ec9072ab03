"""``mcdp predict``: a run folder's checkpoint run on a split of a dataset -> depth grids, EXR depth, an optional
PLY of the rig and an optional Rerun recording (`mcdp.predict`, `mcdp.recording`); its ``--out`` holds the
predictions of one run and dataset (predict.json says which). Registered in `study.method_commands.COMMANDS`
beside ``train`` (`study.train_command`) and ``eval`` (`study.eval_command`).

Example::

    mcdp predict runs/m1 --data data/tiny --out pred/m1 --max-samples 2 --ply
"""
from __future__ import annotations

import argparse
import sys
from pathlib import Path

from corelib.atomic import atomic_write_json, check_writable
from corelib.readfile import read_json_file
from study.command_common import open_dataset, outside_datasets, require_split


def predict_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("run", help="run folder written by mcdp train")
    p.add_argument("--data", required=True, help="dataset folder")
    p.add_argument("--out", default=None, help="output folder (grids, EXR, PLY); --out, --rrd or both")
    p.add_argument("--rrd", default=None, help="also (or only) a Rerun recording *.rrd: ground truth and every "
                   "stage's depth, points and abs_rel image (mcdp.recording; the viz extra: .venv-viz/bin/mcdp, "
                   "made by scripts/setup.sh --test)")
    p.add_argument("--split", default="test", choices=["train", "val", "test"], help="split to predict (default test)")
    p.add_argument("--max-samples", type=int, default=None, help="at most this many rig samples")
    p.add_argument("--stride", type=int, default=1, help="every k-th frame")
    p.add_argument("--ply", action="store_true", help="also write a coloured PLY point cloud of the rig (ego frame)")
    p.add_argument("--checkpoint", default="auto", help="auto | best | last | path")
    p.add_argument("--device", default="auto", choices=["auto", "cpu", "cuda"],
                   help="where the network runs: auto = CUDA when available, else cpu (default auto)")
    p.add_argument("--no-progress", action="store_true", help="no progress bar (--rrd)")


def predict(args: argparse.Namespace) -> int:
    from mcdp.predict import Predictor, write_prediction
    from mcdp.runs import RunError

    if args.stride < 1 or (args.max_samples is not None and args.max_samples < 1):
        raise RunError("--stride and --max-samples must be >= 1")
    if args.out is None and args.rrd is None:
        raise RunError("give --out PRED (files), --rrd FILE.rrd (a Rerun recording) or both")
    if args.rrd is not None:
        from synth.view import check_rrd_target, import_rerun

        outside_datasets(args.rrd, "--rrd")
        check_rrd_target(args.rrd, "--rrd")
        import_rerun()  # the viz extra missing: one line naming the install command, before any work
    if args.out is not None:
        outside_datasets(args.out)
        check_writable(Path(args.out) / "predict.json")
    ds = open_dataset(args.data)
    require_split(ds, args.data, args.split)
    pred = Predictor(args.run, ds, args.checkpoint, args.device)
    samples = [(s, f) for s in ds.split(args.split) for f in range(0, ds.n_frames(s), args.stride)]
    if args.max_samples is not None:
        samples = samples[: args.max_samples]
    label = " [ORACLE]" if pred.oracle else ""
    print(f"mcdp predict: {pred.ckpt_path} (step {pred.step}), {len(samples)} rig samples -> "
          f"{' + '.join(str(x) for x in (args.out, args.rrd) if x is not None)}{label}", file=sys.stderr)
    from corelib.rundir import claim

    lock = None
    if args.out is not None:  # every output claimed first: a refused --out leaves no recording behind
        lock = claim(args.out, "predict")  # a folder of the user's own files is refused, nothing written
    n = 0
    try:
        if lock is not None:
            _record_source(Path(args.out), args.run, pred, args.data)
        if args.rrd is not None:
            from mcdp.recording import record_predictions
            from synth.gltf_export import rebuilt_world_mesh

            # a dataset rendered without labels.mesh: its world mesh rebuilt from the manifest's config
            r = record_predictions(pred, samples, args.rrd, progress=not args.no_progress and sys.stderr.isatty(),
                                   rebuild=rebuilt_world_mesh)
            print(f"mcdp predict: wrote {args.rrd} ({r['bytes'] / 1e6:.2f} MB, {r['bytes_per_rig_frame'] / 1e6:.3f} "
                  f"MB per rig-frame); open it with `rerun {args.rrd}`", file=sys.stderr)
        if lock is None:
            return 0
        for seq, f in samples:
            n += len(write_prediction(pred, seq, f, args.out, ply=args.ply))
    finally:
        if lock is not None:
            lock.release()
    print(f"mcdp predict: wrote {n} files", file=sys.stderr)
    return 0


def _record_source(out: Path, run: str, pred, data: str) -> None:
    """``predict.json`` names the run, checkpoint and dataset a prediction folder holds; another run's or
    dataset's predictions are refused there (files of two runs would mix without a record)."""
    from corelib.rundir import FolderError

    rec = {"run": str(Path(run).resolve()), "data": str(Path(data).resolve())}
    p = out / "predict.json"
    if p.is_file():
        try:
            old = read_json_file(p, kind="record")
        except (OSError, ValueError, UnicodeDecodeError):
            old = None
        old = {k: old.get(k) for k in rec} if isinstance(old, dict) else old
        if old != rec:
            raise FolderError(f"--out {out} holds predictions of another run or dataset ({p}: {str(old)[:200]}); "
                              "nothing was written: use a new --out")
    atomic_write_json(p, {**rec, "checkpoint": str(pred.ckpt_path), "step": pred.step})
