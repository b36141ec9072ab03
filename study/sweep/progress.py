"""Overall progress of a sweep: runs done / total, elapsed, an ETA from the runs finished so far, and the
current stage (pretraining, render of overlap x, yardsticks, runs, report).

`SweepProgress` is fed by `study.sweep_command` (stages) and `study.sweep.engines.run_all` (one call per finished run,
whichever engine ran it: in process, a local process pool, or Ray). On a terminal it is a tqdm bar;
with ``--no-progress`` (or no terminal) it writes log lines instead: one at every stage change and one
per finished run (at most one every `min_interval_s` seconds, the last run always)::

    [sweep] progress: 4/10 runs done, elapsed 1m12s, ETA 1m48s (27.0 s/run over 4 runs), stage: runs

The ETA is (time spent in the runs stage / runs that did work in it) x runs left: with ``jobs > 1``
that is the wall time per run at the achieved parallelism. Runs a rerun skips (trained and evaluated
before) count as done but not in the rate, so a resumed sweep's ETA is that of the work left, assuming
the runs still to come are not skipped.

tqdm draws the bar, but the ETA is computed here, not by tqdm: tqdm's rate is of bar updates over the
time since the bar began (smoothed), so the pretraining and renders before the first run and the runs a
rerun skips at once would enter it (a resumed sweep's ETA near zero); and the ``--no-progress`` lines
(a sweep's log) keep their ``1m15s`` format where tqdm's `format_interval` writes ``01:15``.

Example::

    p = SweepProgress(total=90, log=print, bar=False)
    p.stage("render of overlap 0.10"); p.stage("runs"); p.run_done(); p.close()
"""
from __future__ import annotations

import time
from typing import Callable


def fmt_duration(s: float) -> str:
    """12 s -> '12s', 75 s -> '1m15s', 3725 s -> '1h02m05s'."""
    s = int(round(max(s, 0.0)))
    h, m, sec = s // 3600, s % 3600 // 60, s % 60
    return f"{h}h{m:02d}m{sec:02d}s" if h else f"{m}m{sec:02d}s" if m else f"{sec}s"


class SweepProgress:
    """Runs done / total, elapsed, ETA, stage (module docstring). `clock` is injectable for tests."""

    def __init__(self, total: int, log: Callable[[str], None], bar: bool = False, min_interval_s: float = 0.0,
                 clock: Callable[[], float] = time.monotonic) -> None:
        if total < 0:
            raise ValueError(f"total runs must be >= 0, got {total}")
        self.total, self.log, self.clock = int(total), log, clock
        self.min_interval_s = float(min_interval_s)
        self.t0 = clock()
        self.done = 0
        self.current = "starting"
        self._runs_t0: float | None = None
        self._runs_done = 0
        self._last_line = float("-inf")
        self._bar = None
        if bar:
            from corelib.progress import progress_bar
            self._bar = progress_bar(total=self.total, desc="sweep", unit="run")

    # ------------------------------------------------------------------ state
    def eta_s(self) -> float | None:
        """Seconds left, from the runs that did work in the runs stage so far; None before the first."""
        if self._runs_t0 is None or self._runs_done == 0:
            return None
        per_run = (self.clock() - self._runs_t0) / self._runs_done
        return per_run * (self.total - self.done)

    def line(self) -> str:
        eta = self.eta_s()
        if eta is None:
            eta_text = "ETA after the first run" if self.done < self.total else "ETA 0s"
        else:
            per = (self.clock() - self._runs_t0) / self._runs_done
            eta_text = f"ETA {fmt_duration(eta)} ({per:.1f} s/run over {self._runs_done} run(s))"
        return (f"[sweep] progress: {self.done}/{self.total} runs done, elapsed "
                f"{fmt_duration(self.clock() - self.t0)}, {eta_text}, stage: {self.current}")

    # ------------------------------------------------------------------ events
    def stage(self, name: str) -> None:
        """The sweep entered stage `name` ("pretraining", "render of overlap 0.10", "runs", ...)."""
        self.current = name
        if name == "runs" and self._runs_t0 is None:
            self._runs_t0 = self.clock()
        self._emit(force=True)

    def run_done(self, row: dict | None = None, n: int = 1) -> None:
        """`n` more runs finished (trained and evaluated, skipped, diverged or failed); ``row``: the run's
        result row (`study.sweep.stages.run_stage`), whose ``train_skipped`` and ``eval_skipped`` both true mean it
        was skipped: done, but not counted in the time per run."""
        self.done = min(self.done + int(n), self.total)
        skipped = bool(row) and bool(row.get("train_skipped")) and bool(row.get("eval_skipped"))
        if self._runs_t0 is not None and not skipped:
            self._runs_done += int(n)
        if self._bar is not None:
            self._bar.update(int(n))
        self._emit(force=self.done == self.total)

    def _emit(self, force: bool) -> None:
        if self._bar is not None:
            eta = self.eta_s()
            self._bar.set_postfix_str(f"{self.current}" + ("" if eta is None else f", ETA {fmt_duration(eta)}"))
            return
        now = self.clock()
        if force or now - self._last_line >= self.min_interval_s:
            self._last_line = now
            self.log(self.line())

    def close(self) -> None:
        if self._bar is not None:
            self._bar.close()
            self._bar = None
