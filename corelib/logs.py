"""Python `logging` for the commands and the trainer: one stderr handler and a log file per run folder.

Every logger of the project hangs under ``mcdp`` (``mcdp.train``, ...). `logger` installs, once, a
handler that writes the bare message to the *current* ``sys.stderr`` (so the lines read as the
``print`` they replaced, and pytest's capture sees them), at INFO unless `set_verbosity` changed it
(``-q``: warnings only, ``-v``: debug lines too). `run_log` adds a file handler (``RUN/train.log``,
timestamped, DEBUG: it also holds the per-step lines the terminal does not show) for as long as a
run is open.

Example::

    log = logger("mcdp.train")
    handler = run_log(run_dir / "train.log")   # ... log.info("...") ...
    close_run_log(handler)
"""
from __future__ import annotations

import logging
import sys
from pathlib import Path

ROOT = "mcdp"
_STDERR_NAME = "mcdp-stderr"


class _CurrentStderr(logging.StreamHandler):
    """A StreamHandler bound to whatever ``sys.stderr`` is when a record is written."""

    def __init__(self) -> None:
        super().__init__(sys.stderr)
        self.set_name(_STDERR_NAME)

    @property
    def stream(self):  # noqa: D401
        return sys.stderr

    @stream.setter
    def stream(self, value) -> None:  # StreamHandler.__init__ assigns it; the property ignores it
        pass


class _Printable(logging.Formatter):
    """The bare message, its control characters escaped (`corelib.text.printable`): a line that echoes a path
    or key of the user's writes nothing but text to the terminal."""

    def format(self, record: logging.LogRecord) -> str:
        from corelib.text import printable

        return printable(super().format(record))


def _root() -> logging.Logger:
    root = logging.getLogger(ROOT)
    if not any(h.get_name() == _STDERR_NAME for h in root.handlers):
        h = _CurrentStderr()
        h.setFormatter(_Printable("%(message)s"))
        h.setLevel(logging.INFO)
        root.addHandler(h)
        root.setLevel(logging.DEBUG)  # the handlers choose what they show
    return root


def logger(name: str = ROOT) -> logging.Logger:
    """The logger ``name`` (under ``mcdp``), its stderr handler installed."""
    _root()
    return logging.getLogger(name if name == ROOT or name.startswith(ROOT + ".") else f"{ROOT}.{name}")


def set_verbosity(quiet: int = 0, verbose: int = 0) -> None:
    """The stderr handler's level: WARNING with ``quiet``, DEBUG with ``verbose``, else INFO."""
    level = logging.WARNING if quiet else logging.DEBUG if verbose else logging.INFO
    for h in _root().handlers:
        if h.get_name() == _STDERR_NAME:
            h.setLevel(level)


def run_log(path: str | Path) -> logging.Handler:
    """Append every ``mcdp`` record (DEBUG and up, timestamped) to ``path`` until `close_run_log`."""
    h = logging.FileHandler(path, mode="a", encoding="utf-8")
    h.setFormatter(logging.Formatter("%(asctime)s %(levelname)s %(name)s: %(message)s"))
    h.setLevel(logging.DEBUG)
    _root().addHandler(h)
    return h


def close_run_log(handler: logging.Handler | None) -> None:
    if handler is not None:
        _root().removeHandler(handler)
        handler.close()
