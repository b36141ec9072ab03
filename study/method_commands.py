"""The ``mcdp`` command line: train, evaluate and run MCDP / Monodepth2 models on synth datasets.

These commands use the method library (`mcdp`) and live here, in the top layer, so that `mcdp` is a pure
library with no command line of its own.

::

    mcdp train configs/train/<preset>.yaml --data DATA --out RUN [key=value ...]   # resumes if RUN has a checkpoint
    mcdp train configs/train/<preset>.yaml --print-config [key=value ...]         # the resolved config; nothing run
    mcdp presets [train|sweep|pretrain|data]                                      # the presets in configs/
    mcdp eval RUN --data DATA [--split test] [--out metrics.json] [--checkpoint auto|best|last|PATH] [eval.key=value ...]
    mcdp predict RUN --data DATA --out PRED [--split test] [--max-samples N] [--ply] [--rrd pred.rrd]
    mcdp pretrain configs/pretrain/tiny.yaml --out DIR [key=value ...]           # added by study.cli
    mcdp sweep configs/sweep/cpu.yaml --out SWEEP [key=value ...]          # added by study.cli

Exit codes (`corelib.exitcodes`, the same in every command; the README's table): 0 success, 2 bad
input (config, dataset, run folder, or a file the operating system refuses: permission denied,
read-only file system, a name too long; one line on stderr naming it, no traceback), 3 training
diverged (NaN/inf loss), 4 disk full, 5 a sweep's run failed twice (engine ray), 6 no OpenGL back end
(pretrain, sweep: they render), 130 interrupted.

A config is checked before torch is imported (seconds): a wrong key fails at once.

``train`` lives in `study.train_command`, what the commands share in `study.command_common`.
Subcommands are registered in `COMMANDS` as `corelib.cli.Command` (name, help, add_arguments,
run), the one CLI style of `synth` and `mcdp`; a new one is one more entry. The ``mcdp`` console script is `study.cli.main`: these
commands plus the study's ``sweep``.
"""
from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path
from typing import Iterable

from corelib import cli
from corelib.atomic import atomic_write_json, check_writable
from corelib.cli import Command
from corelib.exitcodes import DIVERGED as EXIT_DIVERGED, USAGE as EXIT_USAGE
from study.command_common import open_dataset, outside_datasets, require_split
from study.train_command import train, train_arguments

#: (module, class) of every error a user can cause, and of a diverged training
USER_ERRORS = [("corelib.configlib", "ConfigError"), ("corelib.rundir", "FolderError"), ("synth.files", "DatasetError"),
               ("synth.files", "OutputFolderError"), ("mcdp.runs", "RunError"), ("mcdp.networks", "NetworkError"),
               ("mcdp.warmstart", "WarmStartError"), ("synth.view", "ViewError")]
DIVERGED = [("mcdp.trainer", "TrainingDiverged")]


def _is_metrics(path: Path) -> bool:
    try:
        return isinstance(json.loads(path.read_text()[:1 << 26]).get("run", {}).get("checkpoint"), str)
    except (OSError, ValueError, UnicodeDecodeError, AttributeError):
        return False


def _check_metrics_target(out: Path) -> None:
    """`eval --out` names a file: new, or a metrics file an earlier `mcdp eval` wrote; anything else (a
    file of the user's, a folder, a device, a symlink) is refused before the evaluation starts."""
    from corelib.rundir import check_output_file

    check_output_file(out, _is_metrics, "metrics file written by mcdp eval")


# --------------------------------------------------------------------------- eval
def _eval_args(p: argparse.ArgumentParser) -> None:
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


def _eval(args: argparse.Namespace) -> int:
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


# --------------------------------------------------------------------------- predict
def _predict_args(p: argparse.ArgumentParser) -> None:
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


def _predict(args: argparse.Namespace) -> int:
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

            r = record_predictions(pred, samples, args.rrd, progress=not args.no_progress and sys.stderr.isatty())
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
            old = json.loads(p.read_text()[:1 << 20])
        except (OSError, ValueError, UnicodeDecodeError):
            old = None
        old = {k: old.get(k) for k in rec} if isinstance(old, dict) else old
        if old != rec:
            raise FolderError(f"--out {out} holds predictions of another run or dataset ({p}: {str(old)[:200]}); "
                              "nothing was written: use a new --out")
    atomic_write_json(p, {**rec, "checkpoint": str(pred.ckpt_path), "step": pred.step})


# --------------------------------------------------------------------------- presets
def _presets_args(p: argparse.ArgumentParser) -> None:
    from corelib.presets import KINDS

    p.add_argument("kind", nargs="?", choices=["methods", *KINDS], help="one kind (default: all); methods: the "
                   "registered methods, each a value of --method and the model.method it trains")


def format_methods() -> str:
    """The registered methods (`mcdp.methods.METHODS`, table order): each row's name (``--method``), the
    ``model.method`` it trains, its label and its role; the README points here rather than listing them."""
    from mcdp.methods import METHODS

    w = max(len(n) for n in METHODS)
    out = ["methods (mcdp/methods/__init__.py; mcdp train configs/train/tiny/base.yaml --method NAME):"]
    out += [f"  {n:<{w}}  model.method={m.defaults['model.method']:<{w}}  {m.label} ({m.role})" for n, m in METHODS.items()]
    return "\n".join(out)


def _presets(args: argparse.Namespace) -> int:
    from corelib.presets import KINDS, format_presets

    if args.kind in (None, "methods"):
        print(format_methods())
    if args.kind != "methods":
        print(format_presets([args.kind] if args.kind else list(KINDS)))
    return 0


# --------------------------------------------------------------------------- main
COMMANDS: list[Command] = [
    Command("train", "train a model (resumes if RUN has a checkpoint)", train_arguments, train),
    Command("eval", "evaluate a run on a split -> metrics.json and per-camera tables", _eval_args, _eval),
    Command("predict", "write depth grids, EXR depth and optional PLY for a split", _predict_args, _predict),
    Command("presets", "list the registered methods and the presets in configs/ (train, sweep, pretrain, data)",
            _presets_args, _presets),
]

#: errors -> exit codes (`corelib.cli`: first match wins; then a full disk, a refused file, Ctrl-C)
RULES = [(USER_ERRORS, EXIT_USAGE, "error"), (DIVERGED, EXIT_DIVERGED, "training diverged")]


def main(argv: list[str] | None = None, extra_commands: Iterable[Command] = (),
         extra_rules: Iterable[cli.ErrorRule] = ()) -> int:
    """The method's commands; `extra_commands` add more (the study's ``pretrain`` and ``sweep``, assembled
    by `study.cli`), `extra_rules` their errors."""
    return cli.main("mcdp", __doc__.split("\n")[0], [*COMMANDS, *extra_commands], argv, [*extra_rules, *RULES])


if __name__ == "__main__":
    sys.exit(main())
