"""``mcdp eval``: a run folder's checkpoint evaluated on a split of a dataset -> metrics.json and per-camera tables
(`mcdp.evaluate`); its ``--out`` is new or a metrics file an earlier ``mcdp eval`` wrote. Registered in
`study.method_commands.COMMANDS` beside ``train`` (`study.train_command`) and ``predict`` (`study.predict_command`).

Example::

    mcdp eval runs/m1 --data data/tiny --split test --checkpoint best eval.max_depth=60
"""
from __future__ import annotations

import argparse
import sys
from pathlib import Path

from corelib.atomic import atomic_write_json
from corelib.readfile import read_json_file
from study.command_common import open_dataset, outside_datasets, require_split


def _is_metrics(path: Path) -> bool:
    try:
        return isinstance(read_json_file(path, kind="record").get("run", {}).get("checkpoint"), str)
    except (OSError, ValueError, UnicodeDecodeError, AttributeError):
        return False


def _check_metrics_target(out: Path) -> None:
    """`eval --out` names a file: new, or a metrics file an earlier `mcdp eval` wrote; anything else (a
    file of the user's, a folder, a device, a symlink) is refused before the evaluation starts."""
    from corelib.rundir import check_output_file

    check_output_file(out, _is_metrics, "metrics file written by mcdp eval")


def eval_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("run", help="run folder written by mcdp train")
    p.add_argument("--data", required=True, help="dataset folder with ground-truth depth")
    p.add_argument("--split", default="test", choices=["train", "val", "test"], help="split to evaluate (default test)")
    p.add_argument("--out", default=None, help="metrics.json path (default RUN/metrics_<split>.json)")
    p.add_argument(
        "--checkpoint", default="auto", help="auto (best.pt by val loss, else last.pt) | best | last | path"
    )
    p.add_argument("--stage", default="final", help="stage whose tables are printed (all stages are saved)")
    p.add_argument("--device", default="auto", choices=["auto", "cpu", "cuda"],
                   help="where the network runs: auto = CUDA when available, else cpu (default auto)")
    p.add_argument("--no-progress", action="store_true", help="no progress bar")
    p.add_argument("overrides", nargs="*", help="evaluation overrides eval.key=value, e.g. eval.max_depth=60")


def _eval_overrides(overrides: list[str]) -> dict:
    """The ``eval.*`` overrides, their keys checked (before torch is imported; values once the run's
    eval config is read)."""
    from mcdp.config import EvalConfig
    from corelib.configlib import ConfigError, parse_overrides

    ov = parse_overrides(overrides)
    bad = [k for k in ov if k != "eval"]
    if bad:
        raise ConfigError(f"eval accepts only eval.* overrides, got {', '.join(bad)}")
    ev = ov.get("eval", {})
    unknown = [k for k in ev if k not in EvalConfig.model_fields] if isinstance(ev, dict) else []
    if unknown:
        raise ConfigError(f"eval overrides {' '.join(overrides)}: unknown key eval.{unknown[0]} (known: "
                          f"{', '.join(EvalConfig.model_fields)})")
    return ov


def _eval_config(cfg, overrides: list[str]):
    from mcdp.config import EvalConfig
    from corelib.configlib import build_config, config_to_dict, deep_merge

    ov = _eval_overrides(overrides)
    data = deep_merge(config_to_dict(cfg.eval), ov.get("eval", {}))
    return build_config(EvalConfig, data, source="eval overrides " + " ".join(overrides))


def evaluate(args: argparse.Namespace) -> int:
    _eval_overrides(args.overrides)  # a wrong key fails before torch is imported
    out = Path(args.out) if args.out else Path(args.run) / f"metrics_{args.split}.json"
    _check_metrics_target(out)  # before the (long) evaluation: ours or new, in a folder that can be written
    outside_datasets(out)
    from mcdp.evaluate import evaluate
    from mcdp.tables import format_tables
    from mcdp.predict import Predictor, run_record
    from mcdp.runs import RunError, rig_differences

    ds = open_dataset(args.data)
    if not ds.has_depth:
        raise RunError(f"dataset {args.data} has no ground-truth depth (manifest has_depth=false); eval needs it")
    seqs = require_split(ds, args.data, args.split)
    pred = Predictor(args.run, ds, args.checkpoint, args.device)
    stages = pred.stages + ["final"]
    if args.stage not in stages:  # a choice checked before the (long) evaluation
        raise RunError(f"--stage {args.stage[:40]!r} is not a stage of {args.run} (its stages: {', '.join(stages)})")
    ecfg = _eval_config(pred.cfg, args.overrides)
    probe = ds.depth_path(seqs[0], ds.camera_names[0], 0)  # fail early, with the file name, without depth
    if not probe.is_file():
        raise RunError(f"dataset {args.data} has no ground-truth depth ({probe} is missing); eval needs it")
    rig_diff = rig_differences(Path(args.run), ds)
    if rig_diff:
        print(f"mcdp eval: warning: {args.data}'s rig differs from the one {args.run} was trained on: "
              f"{'; '.join(rig_diff[:6])}" + (f" (+{len(rig_diff) - 6} more)" if len(rig_diff) > 6 else ""),
              file=sys.stderr)
    label = " [ORACLE: ground-truth median scale at inference]" if pred.oracle else ""
    print(f"mcdp eval: {pred.ckpt_path} (step {pred.step}) on {args.data} split {args.split}{label}", file=sys.stderr)
    metrics = evaluate(ds, pred.predict, args.split, ecfg, progress=not args.no_progress)
    metrics["run"] = run_record(pred, Path(args.run), str(Path(args.data)), rig_diff)
    out.parent.mkdir(parents=True, exist_ok=True)
    atomic_write_json(out, metrics, allow_nan=True)
    if pred.oracle:
        print("ORACLE RUN: depth scaled by the ground-truth median (scale.source=oracle_gt_median)")
    print(format_tables(metrics, args.stage))
    print(f"\nmetrics written to {out}", file=sys.stderr)
    return 0
