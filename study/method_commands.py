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

Each command is a module of its own (its arguments and its run, the ``Command`` pair): ``train`` in
`study.train_command`, ``eval`` in `study.eval_command`, ``predict`` in `study.predict_command`; what they
share in `study.command_common`; this module holds the table (`COMMANDS`), ``presets`` and the error rules.
Subcommands are registered in `COMMANDS` as `corelib.cli.Command` (name, help, add_arguments,
run), the one CLI style of `synth` and `mcdp`; a new one is one more entry. The ``mcdp`` console script is `study.cli.main`: these
commands plus the study's ``sweep``.
"""
from __future__ import annotations

import argparse
import sys
from typing import Iterable

from corelib import cli
from corelib.cli import Command
from corelib.exitcodes import DIVERGED as EXIT_DIVERGED, USAGE as EXIT_USAGE
from study.eval_command import eval_arguments, evaluate
from study.predict_command import predict, predict_arguments
from study.train_command import train, train_arguments

#: (module, class) of every error a user can cause, and of a diverged training
USER_ERRORS = [("corelib.configlib", "ConfigError"), ("corelib.rundir", "FolderError"), ("synth.files", "DatasetError"),
               ("synth.files", "OutputFolderError"), ("mcdp.runs", "RunError"), ("mcdp.networks", "NetworkError"),
               ("mcdp.warmstart", "WarmStartError"), ("synth.view", "ViewError"), ("corelib.readfile", "ReadRefused")]
DIVERGED = [("mcdp.trainer", "TrainingDiverged")]


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
    Command("eval", "evaluate a run on a split -> metrics.json and per-camera tables", eval_arguments, evaluate),
    Command("predict", "write depth grids, EXR depth and optional PLY for a split", predict_arguments, predict),
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
