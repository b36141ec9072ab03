"""Where a sweep's (overlap, method, seed) runs execute: in this process, a local process pool, or Ray.

One signature, ``run_all(cfg, todo, out, counters, log, progress, init_from, on_done) -> rows``: the
rows come back in the order of `todo` (the table order) whatever finishes first, and the
per-run counters (trained, train_skipped, evaluated, ...) are summed into `counters`, so the
results, resumption and skipping are the same whichever engine ran them. ``on_done(row)`` is called
in this process once per finished run with its row, as it finishes (the sweep's progress, `study.sweep.progress`).

- ``engine: local``, ``jobs: 1``: one run after the other in this process.
- ``engine: local``, ``jobs: N``: N spawned processes (`concurrent.futures`); the first failure
  (other than a diverged run, which is a row) stops the sweep after the running jobs end.
- ``engine: ray``: every run is one Ray task on the Ray of `corelib.cluster.ray_session` (the
  sweep opens it), with ``num_cpus`` = the run's ``train.threads`` (at least 1) and
  ``num_gpus`` = 1 when the run trains on CUDA (``device: cuda``, or ``auto`` on a cluster
  that has GPUs), else 0; Ray schedules them. A task that fails is rerun once
  (``max_retries=1``: a crashed worker or a lost node; ``retry_exceptions=True``: an exception
  raised by the run); one that fails again becomes a row with ``status: failed``, ``error``
  (the error's first line) and ``failed_attempts`` (how many attempts raised), the other runs go on, and the sweep exits
  `EXIT_RUN_FAILED`. Every failed attempt that raised is appended, with its traceback, to
  ``SWEEP/runs/overlap_*/<method>_s<seed>.errors.jsonl`` (beside the run folder, which the
  trainer owns). A rerun of the sweep retries failed runs from their last checkpoint.
"""
from __future__ import annotations

import json
import os
import socket
import time
import traceback
from pathlib import Path

from corelib import exitcodes
from corelib.cluster import error_line
from corelib.configlib import ConfigError
from corelib.logs import logger
from corelib.readfile import read_file
from study.sweep.config import SweepConfig, run_config_for
from study.sweep.stages import Counters, run_dir_for, run_stage


EXIT_RUN_FAILED = exitcodes.RUN_FAILED  # `mcdp sweep`: some run failed (engine ray; the report lists it)


def run_all(cfg: SweepConfig, todo: list, out: Path, counters: Counters, log, progress: bool,
            init_from: str | None = None, on_done=None) -> list[dict]:
    """Run every (data record, method, seed) of `todo` with the sweep's engine; the rows in `todo`'s order."""
    on_done = on_done or (lambda row: None)
    if cfg.engine == "ray":
        return _run_ray(cfg, todo, out, counters, log, init_from, on_done)
    if cfg.jobs == 1 or len(todo) == 1:
        rows = []
        for d, method, seed in todo:
            rows.append(run_stage(cfg, d["overlap"], d, method, seed, out, counters, log, progress, init_from))
            on_done(rows[-1])
        return rows
    return _run_parallel(cfg, todo, out, counters, log, init_from, on_done)


def _stage_job(cfg: SweepConfig, d: dict, method: str, seed: int, out: Path, init_from: str | None) -> tuple[dict, dict]:
    """One run in a worker process: no progress bars, log lines to stderr; the row and its counters."""
    counters = Counters()
    row = run_stage(cfg, d["overlap"], d, method, seed, out, counters,
                    logger("sweep").info, False, init_from)
    return row, dict(counters)


def _merge(counters: Counters, c: dict) -> None:
    for k, v in c.items():
        counters[k] = counters.get(k, 0) + v


def _run_parallel(cfg: SweepConfig, todo: list, out: Path, counters: Counters, log,
                  init_from: str | None = None, on_done=lambda row: None) -> list[dict]:
    """The runs ``cfg.jobs`` at a time in spawned processes (see the module docstring). Ctrl-C (or SystemExit)
    at any moment, even while a run is being submitted, ends the workers and returns at once
    (`corelib.procs.stop_pool`); the workers never see the Ctrl-C themselves (`corelib.procs.sigint_held`)."""
    import multiprocessing as mp
    from concurrent.futures import ProcessPoolExecutor, as_completed
    from concurrent.futures.process import BrokenProcessPool

    from corelib.procs import die_with_parent, lost_workers, sigint_held, stop_pool

    log(f"[sweep] {len(todo)} run(s), {cfg.jobs} at a time (one process each; progress bars off)")
    rows: list[dict | None] = [None] * len(todo)
    # workers die with the sweep: SIGTERM, SIGHUP or kill -9 of this process leaves no run training
    pool = ProcessPoolExecutor(max_workers=cfg.jobs, mp_context=mp.get_context("spawn"), initializer=die_with_parent,
                               initargs=(os.getpid(),))
    try:
        index = {}
        for i, (d, method, seed) in enumerate(todo):
            with sigint_held():  # a worker started here inherits SIGINT blocked: this process ends it
                index[pool.submit(_stage_job, cfg, d, method, seed, out, init_from)] = i
        for fut in as_completed(index):  # as they finish, for the progress; rows keep todo's order
            row, c = fut.result()
            rows[index[fut]] = row
            _merge(counters, c)
            on_done(row)
    except (KeyboardInterrupt, SystemExit, BrokenProcessPool) as exc:
        # nothing waited for (a run trains for minutes); the pool's own thread cancels what was queued
        stop_pool(pool)
        if isinstance(exc, BrokenProcessPool):  # a run's process died (kill -9, the OOM killer)
            unfinished = [run_dir_for(out, d["overlap"], m, s).name for (d, m, s), r in zip(todo, rows) if r is None]
            raise lost_workers("mcdp sweep", unfinished, "run(s)") from None
        raise
    except BaseException:  # a run failed: the sweep stops once the running runs end, the queued ones never start
        try:
            pool.shutdown(wait=True, cancel_futures=True)
        except BaseException:  # Ctrl-C while waiting for them
            stop_pool(pool)
            raise
        raise
    pool.shutdown(wait=True)
    return rows  # type: ignore[return-value]


# ----------------------------------------------------------------------------- Ray


def errors_path(out: Path, overlap: float, method: str, seed: int) -> Path:
    """The failed attempts of one run (JSON lines), beside its run folder."""
    run_dir = run_dir_for(out, overlap, method, seed)
    return run_dir.parent / f"{run_dir.name}.errors.jsonl"


def _ray_job(cfg: SweepConfig, d: dict, method: str, seed: int, out: Path, init_from: str | None) -> tuple[dict, dict]:
    """`_stage_job` as a Ray task; an exception is recorded in `errors_path` and raised again (Ray retries it)."""
    try:
        return _stage_job(cfg, d, method, seed, out, init_from)
    except BaseException as exc:
        rec = {"time": time.strftime("%Y-%m-%d %H:%M:%S"), "host": socket.gethostname(), "pid": os.getpid(),
               "error": error_line(exc), "traceback": traceback.format_exc()}
        p = errors_path(out, d["overlap"], method, seed)
        p.parent.mkdir(parents=True, exist_ok=True)
        with open(p, "a") as fh:  # one short line per attempt: appends, not a whole-file rewrite
            fh.write(json.dumps(rec) + "\n")
        raise


def _count_lines(p: Path) -> int:
    try:
        return len(read_file(p, kind="record").decode(errors="replace").splitlines())
    except (OSError, ValueError):  # ValueError: corelib.readfile.ReadRefused
        return 0


def _resources(cfg: SweepConfig, method: str, seed: int, init_from: str | None, gpus_in_cluster: float) -> dict:
    rcfg, _ = run_config_for(cfg, method, seed, init_from)
    device = rcfg.train.device
    cuda = device == "cuda" or (device == "auto" and gpus_in_cluster >= 1)
    return {"num_cpus": max(1, rcfg.train.threads), "num_gpus": 1 if cuda else 0}


def _run_ray(cfg: SweepConfig, todo: list, out: Path, counters: Counters, log, init_from: str | None,
             on_done=lambda row: None) -> list[dict]:
    """Every run as one Ray task (see the module docstring); failed runs become rows."""
    from corelib.cluster import import_ray

    ray = import_ray()
    task = ray.remote(max_retries=1, retry_exceptions=True)(_ray_job)
    gpus = ray.cluster_resources().get("GPU", 0)
    refs, before, shapes = [], [], set()
    for d, method, seed in todo:
        res = _resources(cfg, method, seed, init_from, gpus)
        if res["num_gpus"] > gpus:  # Ray would keep such a task pending forever
            raise ConfigError(f"the sweep trains on CUDA (device: {cfg.device}) but the Ray cluster has no GPU; "
                              "use device: cpu or a cluster with GPUs")
        shapes.add(f"{res['num_cpus']} CPU + {res['num_gpus']} GPU")
        name = f"{run_dir_for(out, d['overlap'], method, seed).parent.name}/{method}_s{seed}"
        before.append(_count_lines(errors_path(out, d["overlap"], method, seed)))
        refs.append(task.options(name=name, **res).remote(cfg, d, method, seed, out, init_from))
    log(f"[sweep] {len(todo)} run(s) submitted to Ray as tasks of {' / '.join(sorted(shapes))} each; "
        "Ray schedules them, a failed task is rerun once")
    index = {ref: i for i, ref in enumerate(refs)}
    rows: list[dict | None] = [None] * len(todo)
    pending = list(refs)
    try:
        while pending:
            ready, pending = ray.wait(pending, num_returns=1)
            for ref in ready:
                i = index[ref]
                d, method, seed = todo[i]
                try:
                    row, c = ray.get(ref)
                except ray.exceptions.RayError as exc:
                    rows[i] = _failed_row(cfg, out, d, method, seed, exc, before[i], init_from)
                    counters.bump("failed")
                    log(f"[sweep] overlap {d['overlap']:.2f} {method} seed {seed}: FAILED (rerun once; "
                        f"{rows[i]['failed_attempts']} attempt(s) raised): {rows[i]['error']} (tracebacks: "
                        f"{errors_path(out, d['overlap'], method, seed)})")
                    on_done(rows[i])
                    continue
                rows[i] = row
                _merge(counters, c)
                on_done(row)
    except BaseException:  # interrupted: nothing more runs for this sweep; a rerun resumes
        for ref in pending:
            ray.cancel(ref, force=True)
        raise
    return rows  # type: ignore[return-value]


def _failed_row(cfg: SweepConfig, out: Path, d: dict, method: str, seed: int, exc: BaseException, before: int,
                init_from: str | None) -> dict:
    from mcdp.runs import run_hash

    rcfg, preset = run_config_for(cfg, method, seed, init_from)
    # the attempts that raised, as the task recorded them (a crashed worker records nothing)
    raised = _count_lines(errors_path(out, d["overlap"], method, seed)) - before
    return {"overlap": d["overlap"], "method": method, "seed": seed,
            "run_dir": str(run_dir_for(out, d["overlap"], method, seed)), "preset": str(preset),
            "run_config_hash": run_hash(rcfg), "status": "failed", "error": error_line(exc),
            "failed_attempts": raised}
