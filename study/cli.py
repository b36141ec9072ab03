"""The `mcdp` command: the method's commands (`study.method_commands`: train, eval, predict) and the study's
`pretrain` and `sweep` (they render worlds), assembled here at the top of the house so that `mcdp`
never imports `study`. ``python -m mcdp`` runs this too (`mcdp.__main__`).

Example::

    mcdp pretrain configs/pretrain/tiny.yaml --out pretrain/tiny [key=value ...]   # cached by its config hash
    mcdp sweep configs/sweep/ci.yaml --out SWEEP [key=value ...]
    mcdp sweep configs/sweep/ci.yaml --print-config [key=value ...]   # the resolved config; nothing run (pretrain too)
"""
from __future__ import annotations

import argparse
import sys

from corelib import exitcodes
from corelib.cli import Command
from study import calibrate_command, command_common, method_commands
from corelib.presets import complete_presets, preset_path

# the study's modules (and torch, which they import) are imported by the command that runs, once its
# config is checked: a wrong key fails in well under a second


def _pretrain_args(p: argparse.ArgumentParser) -> None:
    complete_presets(p.add_argument("config", help="pretraining config YAML, e.g. configs/pretrain/tiny.yaml (list: "
                                    "mcdp presets pretrain)"), "pretrain")
    p.add_argument("--out", help="pretraining folder (reused when its config hash matches); required unless "
                   "--print-config")
    command_common.add_print_config(p)
    p.add_argument("--no-progress", action="store_true", help="no progress bars (log lines only)")
    p.add_argument("--yes", action="store_true", help="start a pretraining whose render is larger than "
                   "synth.config.MAX_RENDER_BYTES (500 GB uncompressed) without refusing")
    p.add_argument("overrides", nargs="*", help="overrides of the pretraining config, e.g. 'train_overrides=[train.steps=50]'")


def run_pretrain_command(args: argparse.Namespace) -> int:
    """Run the ``pretrain`` subcommand (a cached pretraining returns at once); 0 on success."""
    from study.sweep.pretrain import load_pretrain_config, resolved_configs, run_pretrain
    from synth.config import check_render_size, render_size, size_statement

    cfg = load_pretrain_config(preset_path(args.config, "pretrain"), args.overrides)
    if args.print_config:
        return command_common.print_config(cfg)
    command_common.require(args, "--out")
    command_common.outside_datasets(args.out)  # before anything is written
    size = render_size(resolved_configs(cfg, check_network=False)[0])
    print(f"mcdp pretrain: its world: {size_statement(size)}", file=sys.stderr)
    check_render_size(size, args.yes, f"{args.config} data_overrides")
    run_pretrain(cfg, args.out, progress=not args.no_progress)
    return 0


def _sweep_args(p: argparse.ArgumentParser) -> None:
    complete_presets(p.add_argument("preset", help="sweep preset YAML, e.g. configs/sweep/ci.yaml (list: mcdp presets "
                                    "sweep)"), "sweep")
    p.add_argument("--out", help="sweep folder; a rerun resumes and skips finished work; required unless "
                   "--print-config")
    command_common.add_print_config(p)
    p.add_argument("--no-progress", action="store_true", help="no progress bars (log lines only)")
    p.add_argument("--engine", choices=["local", "ray"], default=None,
                   help="where renders and runs execute (overrides the config's engine): local processes, or Ray "
                        "tasks on a local Ray / the cluster at RAY_ADDRESS (pip install -e '.[cluster]'; "
                        "docs/SCALING.md)")
    p.add_argument("--yes", action="store_true", help="start a sweep whose renders together are larger than "
                   "synth.config.MAX_RENDER_BYTES (500 GB uncompressed), or whose renders and checkpoints are more "
                   "than the disk has free (study.sweep.disk), without refusing")
    p.add_argument("overrides", nargs="*",
                   help="sweep config overrides key=value, e.g. 'overlaps=[0.2,0.5]' seeds=[0,1] "
                        "'train_overrides=[train.steps=100]'")


def run_sweep_command(args: argparse.Namespace) -> int:
    """Run the ``sweep`` subcommand; 0 on success, 5 if some run failed (engine ray: retried once, then a
    ``failed`` row), else 3 if some run diverged (the report says which); 2 for a usage / config error."""
    from study.sweep.config import check_nested_configs, load_sweep_config
    from synth.config import check_render_size, size_statement

    preset = preset_path(args.preset, "sweep")
    engine = getattr(args, "engine", None)
    cfg = load_sweep_config(preset, args.overrides, {"engine": engine} if engine else None)
    if args.print_config:
        return command_common.print_config(cfg)
    command_common.require(args, "--out")
    command_common.outside_datasets(args.out)  # before anything is written
    size = check_nested_configs(cfg, yes=True)  # its overrides' configs too, before the sweep's modules are imported
    if cfg.engine == "ray":  # refused before anything is said or written
        from corelib.cluster import import_ray

        import_ray()
    print(f"mcdp sweep: its renders: {size_statement(size)}", file=sys.stderr)
    check_render_size(size, args.yes, f"sweep {args.preset}: its renders together",
                      "dataset.sequences / dataset.frames / camera.* in data_overrides (and pretrain.data_overrides)")
    from study.sweep.disk import check_disk

    print(f"mcdp sweep: its checkpoints: {check_disk(cfg, args.out, size['max_bytes'], args.yes)}", file=sys.stderr)
    from study.sweep.engines import EXIT_RUN_FAILED
    from study.sweep_command import run_sweep

    source = str(preset) + (" + " + " ".join(args.overrides) if args.overrides else "")
    results = run_sweep(cfg, args.out, progress=not args.no_progress,  # checked above: resolved once
                        config_source=source + (f" + --engine {engine}" if engine else ""), yes=args.yes,
                        checked=True)
    if results["counters"].get("failed"):
        return EXIT_RUN_FAILED
    return exitcodes.DIVERGED if results["counters"].get("diverged") else exitcodes.OK


#: the study's commands, added to the method's (`study.method_commands.COMMANDS`) in the one CLI style (`corelib.cli`)
COMMANDS = [
    Command("pretrain", "shared self-supervised pretraining: render its world, train both heads (cached by its "
            "config hash)", _pretrain_args, run_pretrain_command),
    Command("sweep", "render + train + eval every method over camera overlaps -> report.md, results.csv/json, "
            "plots", _sweep_args, run_sweep_command),
    Command("calibrate", "train every arm of a calibration anchors file at a sweep recipe, one sweep folder per arm "
            "(configs/calibration/anchors.yaml; the page: scripts/publish_calibration.py)",
            calibrate_command.calibrate_args, calibrate_command.run_calibrate),
]


#: the study's commands render: no OpenGL back end is exit 6, as in `synth render` (`corelib.exitcodes`)
RULES = [([("synth.gl_context", "RenderBackendError")], exitcodes.NO_BACKEND, "error"),
         ([("corelib.procs", "WorkerLost")], exitcodes.FAILED, "error")]  # a render or run worker died


def main(argv: list[str] | None = None) -> int:
    """The `mcdp` console script: `study.method_commands.main` with the `pretrain` and `sweep` subcommands added."""
    return method_commands.main(argv, extra_commands=COMMANDS, extra_rules=RULES)


if __name__ == "__main__":
    sys.exit(main())
