"""One command-line style for `synth` and `mcdp`: a table of subcommands and one error rule.

A CLI is a list of `Command` (name, help, add_arguments, run) handed to `main`. Why a table of
plain argparse subcommands rather than a CLI library (click, typer): argparse is in the standard
library (nothing to pin), the commands take dotted ``key=value`` overrides anywhere after the
subcommand, which argparse collects as unknown words, and a new command is one more table entry.

The one error rule (`corelib.exitcodes`): every error a user can cause ends in ONE line on stderr,
``PROG COMMAND: error: ...`` naming the file or key, with its exit code, and no traceback.
"""
from __future__ import annotations

import argparse
import sys
from typing import Callable, Iterable, NamedTuple, Sequence

from corelib.atomic import disk_full_message, file_error_message, is_disk_full, is_user_file_error
from corelib.exitcodes import DISK_FULL, INTERRUPTED, USAGE
from corelib.text import bounded, safe_streams


class Command(NamedTuple):
    """One subcommand: ``add_arguments(parser)`` declares its options (a command that takes dotted
    overrides sets an ``overrides`` default); ``run(args) -> exit code``."""
    name: str
    help: str
    add_arguments: Callable[[argparse.ArgumentParser], None]
    run: Callable[[argparse.Namespace], int]


#: an error mapping: (exception classes, or (module, class) names looked up only in modules already
#: imported, exit code, what the line says before the message)
ErrorRule = tuple[Sequence, int, str]


#: the longest part of an argparse error (characters): it may echo a value of any length
MAX_USAGE_ERROR = 300


class ArgumentParser(argparse.ArgumentParser):
    """argparse's parser whose own errors (an invalid value, an unknown choice) echo the user's words cut to
    `MAX_USAGE_ERROR` characters and escaped (`corelib.text.bounded`); its subcommands' parsers are of this
    class too (argparse makes them with the parent's class). Every CLI's parser: `build_parser`."""

    def error(self, message: str):
        self.print_usage(sys.stderr)
        self.exit(USAGE, f"{self.prog}: error: {bounded(message, MAX_USAGE_ERROR)}\n")


def build_parser(prog: str, description: str, commands: Iterable[Command]) -> argparse.ArgumentParser:
    parser = ArgumentParser(prog=prog, description=description)
    from corelib.version import package_version

    parser.add_argument("--version", action="version", version=f"{prog} {package_version()}")
    parser.add_argument("--print-completion", action=_PrintCompletion)
    _verbosity(parser, "top_")
    common = ArgumentParser(add_help=False)
    _verbosity(common, "")
    sub = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")
    for c in commands:
        p = sub.add_parser(c.name, help=c.help, description=c.help, parents=[common])
        c.add_arguments(p)
        p.set_defaults(_run=c.run)
    return parser


#: the shells ``--print-completion`` writes a script for
COMPLETION_SHELLS = ("bash", "zsh")

#: the line when shtab is missing (it is a dependency: pyproject.toml)
NO_SHTAB = "--print-completion needs shtab: bash scripts/setup.sh (or .venv/bin/pip install 'shtab>=1.10')"


class _PrintCompletion(argparse.Action):
    """``--print-completion SHELL``: print the shell's completion script for this parser, made by shtab (a
    static script from the parser: subcommands, options, choices, preset names; nothing of ours runs when
    the shell completes) and exit 0. Enable it with, e.g., ``eval "$(mcdp --print-completion bash)"``."""

    def __init__(self, option_strings, dest, **kw):
        kw.update(choices=COMPLETION_SHELLS, default=argparse.SUPPRESS, metavar="SHELL",
                  help=f"print the {' / '.join(COMPLETION_SHELLS)} completion script and exit "
                       '(e.g. eval "$(%(prog)s --print-completion bash)" in ~/.bashrc)')
        super().__init__(option_strings, dest, **kw)

    def __call__(self, parser, namespace, values, option_string=None):
        try:
            import shtab
        except ImportError:
            parser.exit(USAGE, f"{parser.prog}: error: {NO_SHTAB}\n")
        from corelib.presets import completion_preamble

        sys.stdout.write(shtab.complete(parser, values, preamble=completion_preamble()))
        parser.exit(0)


def _verbosity(p: argparse.ArgumentParser, prefix: str) -> None:
    """``-q`` / ``-v`` before or after the subcommand (`corelib.logs.set_verbosity`; a run's train.log keeps
    everything either way)."""
    g = p.add_mutually_exclusive_group()
    g.add_argument("-q", "--quiet", dest=prefix + "quiet", action="count", default=0,
                   help="warnings and errors only on stderr")
    g.add_argument("-v", "--verbose", dest=prefix + "verbose", action="count", default=0,
                   help="debug lines too on stderr (e.g. every logged training step)")


def _classes(errors: Sequence) -> tuple[type[BaseException], ...]:
    """The classes of ``errors``; a (module, class) pair counts only if its module is imported: a module
    not imported cannot have raised its error, and importing it to catch one could import torch (seconds)
    just to report a wrong config key."""
    out = []
    for e in errors:
        if isinstance(e, tuple):
            m, c = e
            if m in sys.modules:
                out.append(getattr(sys.modules[m], c))
        else:
            out.append(e)
    return tuple(out)


def parse_command_line(parser: argparse.ArgumentParser, argv: list[str] | None) -> argparse.Namespace:
    """Parse ``argv`` with a `build_parser` parser. ``key=value`` overrides may come before or after the
    options (``PRESET a=1 --out DIR b=2``): argparse takes positionals in one run only, so the words it
    leaves are collected here into ``overrides``; anything else unknown is a usage error (exit 2)."""
    args, extra = parser.parse_known_args(argv)
    stray = [e for e in extra if e.startswith("-") or "=" not in e]
    if stray or (extra and not hasattr(args, "overrides")):
        parser.error(f"unrecognized arguments: {' '.join(stray or extra)}")
    if extra:
        args.overrides = list(args.overrides) + extra
    return args


def _run(args: argparse.Namespace, own_process: bool) -> int:
    """Run the parsed command. In a process of its own (the console script: no ``argv`` given), the heap it leaves
    is frozen (`gc.freeze`) once the command has returned or raised: the process is about to exit, and the garbage
    collections of the interpreter's shutdown would otherwise walk every object torch, OpenGL and the command made
    (a few hundred thousand after `mcdp pretrain`; on a loaded machine its "done" line came about 2 minutes before
    the exit, issue 49). A caller in the same process (a test) passes ``argv`` and keeps its collector as it was."""
    try:
        return int(args._run(args) or 0)
    finally:
        if own_process:
            import gc

            gc.freeze()


def main(prog: str, description: str, commands: Iterable[Command], argv: list[str] | None,
         rules: Sequence[ErrorRule]) -> int:
    """Parse ``argv``, run its command, and turn the errors of ``rules`` (first match wins), a full disk
    (exit 4), a file the operating system refuses (exit 2) and Ctrl-C (130) into one line each."""
    safe_streams()  # a path the terminal's encoding lacks is written escaped, never a failure after the work
    parser = build_parser(prog, description, commands)
    try:
        args = parse_command_line(parser, argv)
    except SystemExit as exc:  # argparse already printed usage + error
        return int(exc.code or 0)
    from corelib.logs import set_verbosity

    set_verbosity(args.quiet + args.top_quiet, args.verbose + args.top_verbose)
    where = f"{prog} {args.command}"
    try:
        return _run(args, own_process=argv is None)
    except KeyboardInterrupt:
        print(f"{where}: interrupted", file=sys.stderr)
        return INTERRUPTED
    except Exception as exc:  # noqa: BLE001 (matched against the rules below; anything else is re-raised)
        for errors, code, label in rules:
            if isinstance(exc, _classes(errors)):
                print(f"{where}: {label}: {bounded(str(exc))}", file=sys.stderr)
                return code
        if isinstance(exc, OSError) and is_disk_full(exc):
            if exc.filename is None and getattr(args, "out", None) is not None:  # a writer that named no file
                exc = OSError(exc.errno, exc.strerror, f"a file under {args.out}")
            print(f"{where}: error: {bounded(disk_full_message(exc))}", file=sys.stderr)
            return DISK_FULL
        if isinstance(exc, OSError) and is_user_file_error(exc):  # permission denied, read-only fs, a name too long
            print(f"{where}: error: {bounded(file_error_message(exc))}", file=sys.stderr)
            return USAGE
        raise


