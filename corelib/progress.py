"""Progress of a long loop: a tqdm bar on a terminal, one plain line per interval anywhere else.

tqdm redraws its bar with carriage returns, many times a second; written to a file or a pipe (a log, CI) that
is a flood of frames on one "line". `progress_bar` gives tqdm only a stream that is a terminal; otherwise a
`LineProgress` with the same methods (iteration, ``update``, ``set_postfix``, ``set_postfix_str``, ``close``)
writes ``desc: n/total unit (p %), elapsed[, postfix]`` at most once per `INTERVAL_S` seconds, and once when
closed. Every progress bar of the project comes from here.

Example::

    for item in progress_bar(items, total=len(items), desc="verify", unit="file"):
        ...
    bar = progress_bar(total=steps, desc="train", unit="step")
    bar.update(1); bar.set_postfix(loss="0.1234"); bar.close()
"""
from __future__ import annotations

import sys
import time
from typing import Any, Iterable, Iterator, TextIO

#: seconds between two lines of a progress written to a stream that is not a terminal
INTERVAL_S = 30.0


def _is_terminal(stream: TextIO) -> bool:
    try:
        return bool(stream.isatty())
    except (AttributeError, ValueError, OSError):
        return False


def progress_bar(iterable: Iterable | None = None, *, total: int | None = None, desc: str = "", unit: str = "it",
                 initial: int = 0, file: TextIO | None = None):
    """A tqdm bar when ``file`` (stderr by default) is a terminal, else a `LineProgress` (module docstring)."""
    stream = sys.stderr if file is None else file
    if total is None and iterable is not None and hasattr(iterable, "__len__"):
        total = len(iterable)  # type: ignore[arg-type]
    if _is_terminal(stream):
        from tqdm import tqdm

        return tqdm(iterable, total=total, initial=initial, desc=desc, unit=unit, file=stream, dynamic_ncols=True)
    return LineProgress(iterable, total=total, desc=desc, unit=unit, initial=initial, file=stream)


class LineProgress:
    """tqdm's few methods used here, as one plain line per `INTERVAL_S` seconds (and one at `close`)."""

    def __init__(self, iterable: Iterable | None = None, *, total: int | None, desc: str, unit: str,
                 initial: int = 0, file: TextIO):
        self.iterable, self.total, self.desc, self.unit, self.n, self.file = iterable, total, desc, unit, initial, file
        self.postfix = ""
        self._t0 = self._last = time.monotonic()
        self._closed = False

    def __iter__(self) -> Iterator[Any]:
        try:
            for item in self.iterable or ():
                yield item
                self.update(1)
        finally:
            self.close()

    def __len__(self) -> int:
        return self.total or 0

    def update(self, n: int = 1) -> None:
        self.n += n
        now = time.monotonic()
        if now - self._last >= INTERVAL_S:
            self._last = now
            self._line()

    def set_postfix(self, **kw: Any) -> None:
        self.postfix = ", ".join(f"{k}={v}" for k, v in kw.items())

    def set_postfix_str(self, s: str) -> None:
        self.postfix = str(s)

    def close(self) -> None:
        if not self._closed:
            self._closed = True
            self._line()

    def _line(self) -> None:
        of = f"/{self.total}" if self.total else ""
        pct = f" ({100.0 * self.n / self.total:.0f} %)" if self.total else ""
        line = (f"{self.desc + ': ' if self.desc else ''}{self.n}{of} {self.unit}{pct}, "
                f"{time.monotonic() - self._t0:.0f} s" + (f", {self.postfix}" if self.postfix else ""))
        try:
            print(line, file=self.file, flush=True)
        except (OSError, ValueError):
            pass
