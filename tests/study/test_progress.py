"""The sweep's overall progress (study.sweep.progress): runs done / total, elapsed, ETA, stage; and that
`run_all` reports every finished run (the CI sweep's own lines are checked in test_sweep.py)."""
from __future__ import annotations

import re

import pytest

from study.sweep.progress import SweepProgress, fmt_duration


class Clock:
    def __init__(self) -> None:
        self.t = 100.0

    def __call__(self) -> float:
        return self.t


def test_fmt_duration():
    assert [fmt_duration(s) for s in (0, 12.4, 75, 3725)] == ["0s", "12s", "1m15s", "1h02m05s"]


def test_lines_count_runs_and_eta_is_time_per_run_times_runs_left():
    clock, lines = Clock(), []
    p = SweepProgress(4, lines.append, clock=clock)
    p.stage("pretraining")
    clock.t += 30
    p.stage("render of overlap 0.20")
    clock.t += 10
    p.stage("runs")
    assert lines[-1] == ("[sweep] progress: 0/4 runs done, elapsed 40s, ETA after the first run, "
                         "stage: runs")
    clock.t += 20
    p.run_done()
    assert p.eta_s() == pytest.approx(60.0)  # 20 s per run x 3 left
    assert lines[-1] == ("[sweep] progress: 1/4 runs done, elapsed 1m00s, ETA 1m00s (20.0 s/run over 1 run(s)), "
                         "stage: runs")
    for _ in range(3):
        clock.t += 10
        p.run_done()
    assert p.eta_s() == 0.0 and p.done == 4
    done = [ln for ln in lines if "runs done" in ln and "stage: runs" in ln]
    assert [int(re.search(r"(\d+)/4 runs", ln).group(1)) for ln in done] == [0, 1, 2, 3, 4]


def test_skipped_runs_count_as_done_but_not_in_the_time_per_run():
    """A resumed sweep: 3 runs skipped at once, then a run that took 100 s: the ETA is 100 s x runs left,
    not 25 s (the rate over every finished run); an all-skipped rerun ends at ETA 0s."""
    clock, lines = Clock(), []
    skipped = {"train_skipped": True, "eval_skipped": True}
    p = SweepProgress(6, lines.append, clock=clock)
    p.stage("runs")
    for _ in range(3):
        p.run_done(skipped)
    assert p.done == 3 and p.eta_s() is None and "ETA after the first run" in lines[-1]
    clock.t += 100
    p.run_done({"train_skipped": False, "eval_skipped": False})
    assert p.eta_s() == pytest.approx(200.0)  # 100 s per run x 2 left
    p.run_done({"train_skipped": True, "eval_skipped": False})  # trained before, evaluated now: work
    assert p._runs_done == 2
    q = SweepProgress(2, lines.append, clock=clock)
    q.stage("runs")
    q.run_done(skipped)
    q.run_done(skipped)
    assert lines[-1].startswith("[sweep] progress: 2/2 runs done") and "ETA 0s" in lines[-1]


def test_min_interval_thins_lines_but_keeps_the_last_run():
    clock, lines = Clock(), []
    p = SweepProgress(10, lines.append, min_interval_s=60, clock=clock)
    p.stage("runs")
    for _ in range(10):
        clock.t += 5
        p.run_done()
    # the stage line, then nothing until 60 s have passed (10 runs x 5 s = 50 s), but the last run always
    assert [ln.split(" runs done")[0][-5:].strip() for ln in lines] == ["0/10", "10/10"]


def test_run_all_reports_every_run_in_process(monkeypatch, tmp_path):
    import study.sweep.engines as engines
    from study.sweep.config import load_sweep_config
    from study.sweep.stages import Counters
    from pathlib import Path

    cfg = load_sweep_config(Path(__file__).resolve().parents[2] / "configs" / "sweep" / "ci.yaml", ["jobs=1"])
    todo = [({"overlap": o}, m, s) for o in cfg.overlaps for m in cfg.methods for s in cfg.seeds]
    monkeypatch.setattr(engines, "run_stage", lambda cfg, o, d, m, s, *a, **k: {"overlap": o, "method": m})
    lines = []
    p = SweepProgress(len(todo), lines.append)
    p.stage("runs")
    rows = engines.run_all(cfg, todo, tmp_path, Counters(), lambda s: None, False, None, on_done=p.run_done)
    assert [(r["overlap"], r["method"]) for r in rows] == [(d["overlap"], m) for d, m, _ in todo]
    assert p.done == len(todo) == 14  # 2 overlaps x 7 methods x 1 seed
    assert lines[-1].startswith("[sweep] progress: 14/14 runs done")
