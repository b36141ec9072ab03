"""The overlap sweep: render + train + evaluate every method at every camera overlap, then report.

For each overlap of a sweep preset (``configs/sweep/*.yaml``) the dataset is
rendered (``spacing`` mode by default: intrinsics fixed, only the yaw spacing
changes, so overlap is the only variable), every method preset is trained for
every seed, evaluated on the test split, and `study.report.compose` writes the tables,
CSV/JSON and plots::

    mcdp sweep configs/sweep/ci.yaml --out SWEEP [key=value ...]
    mcdp sweep configs/sweep/cpu.yaml --out sweeps/cpu "overlaps=[0.2,0.4]" seeds=[0,1]
    mcdp sweep configs/sweep/cpu.yaml --out /shared/sweeps/cpu --engine ray   # Ray tasks (docs/SCALING.md)

Engines (`study.sweep.engines`): ``local`` runs the renders in ``workers`` processes and the runs
``jobs`` at a time in processes; ``ray`` makes every rendered sequence and every run a Ray task
on a local Ray or the cluster at ``RAY_ADDRESS``; a run that fails twice there is a row with
status ``failed`` and the other runs go on. Rows, counters, resumption and skipping are the same.

Layout of SWEEP::

    sweep_config.yaml                          resolved SweepConfig (+ its hash)
    data/overlap_0.10/                         dataset (synth contract v1)
    data/overlap_0.10.reference.json           constant-depth reference evaluated on its test split
    runs/overlap_0.10/<method>_s<seed>/        training run (config.yaml, checkpoints/, tensorboard/)
        metrics_test.json                      mcdp.evaluate layout + "run" + "sweep" keys
        sweep_status.json                      what this sweep finished for the run, with stage timings
    report.md, results.csv, results.json, plots/*.png, preview_overlap_*.png

Resumption: a dataset whose manifest's ``config_hash`` equals the resolved data
config's hash is reused (an incomplete one is resumed by `synth.render.render_dataset`);
a run whose ``sweep_status.json`` records the same run hash (`mcdp.runs.run_hash`:
the resolved run config, its warm start named by the weights' sha256) as
trained is not retrained (an interrupted one resumes from ``checkpoints/last.pt``
through `mcdp.trainer.Trainer`); an evaluation is reused when its key (run
hash, checkpoint step, eval config, dataset hash) is unchanged. A rerun of a
finished sweep only rewrites the report. No key holds a path: a sweep folder
copied or moved elsewhere resumes there with nothing redone.

Honesty rules kept here: model selection (``best.pt``) uses the val split's
self-supervised loss only; the test split is read once per run, by the
evaluation; no setting is chosen by looking at test numbers.
"""
from __future__ import annotations

import sys
import time
from pathlib import Path
from typing import Callable

import yaml

from corelib.atomic import atomic_write_text
from corelib.logs import logger
from corelib.configlib import ConfigError, config_hash, config_to_dict, read_yaml
from study.sweep.config import SPLIT, SweepConfig, check_nested_configs, overlap_key, world_of_seed, worlds_of
from study.report.outputs import write_all
from study.results.summary import build_results
from study.sweep.engines import run_all
from study.sweep.progress import SweepProgress, fmt_duration
from study.sweep.stages import Counters, pretrain_stage
from study.sweep.worlds import combine_worlds, reference_stage, render_stage


def run_sweep(cfg: SweepConfig, out: str | Path, progress: bool = True, log: Callable[[str], None] | None = None,
              config_source: str | None = None, yes: bool = False, checked: bool = False) -> dict:
    """Run (or resume) a whole sweep into `out`; writes the report; returns the results dict.

    The returned dict (also ``out/results.json``) holds ``counters`` (rendered,
    render_skipped, trained, train_skipped, train_resumed, evaluated, eval_skipped,
    diverged, failed), ``data`` (per overlap), ``rows`` (per overlap x method x seed),
    ``aggregate`` (mean/std over seeds) and ``timing``. Its renders together above
    `synth.config.MAX_RENDER_BYTES`, or renders and checkpoints together above the space free under `out`
    (`study.sweep.disk.check_disk`), are refused (ConfigError) unless `yes`. ``checked``: the caller has resolved and
    size-checked every nested config and the disk already (`study.sweep.config.check_nested_configs`, as the command
    line does before it says the sizes), so they are not resolved a second time.
    """
    from corelib.rundir import claim

    log = log or logger("sweep").info  # stderr (-q hides it) and, during a run, its train.log
    out = Path(out)
    if not checked:  # a typo in an override, a huge render, a disk too small: refused before anything is written
        from study.sweep.disk import check_disk

        log(f"[sweep] its checkpoints: {check_disk(cfg, out, check_nested_configs(cfg, yes)['max_bytes'], yes)}")
    if cfg.engine == "ray":
        from corelib.cluster import import_ray
        import_ray()  # Ray missing: one line, before anything is written
    lock = claim(out, "sweep", legacy=("sweep_config.yaml",))
    try:
        if cfg.engine != "ray":
            return _run_sweep(cfg, out, progress, log, config_source)
        from corelib.cluster import ray_session

        with ray_session(cfg.ray_cpus, log):
            return _run_sweep(cfg, out, progress, log, config_source)
    finally:
        lock.release()


def _run_sweep(cfg: SweepConfig, out: Path, progress: bool, log, config_source: str | None) -> dict:
    resolved = config_to_dict(cfg)
    prev = out / "sweep_config.yaml"
    _note_config_change(prev, resolved, log)
    atomic_write_text(prev, yaml.safe_dump({"config": resolved, "config_hash": config_hash(cfg),
                                            "source": config_source}, sort_keys=False))
    n_runs = len(cfg.overlaps) * len(cfg.methods) * len(cfg.seeds)
    log(f"[sweep] {len(cfg.overlaps)} overlap(s) {', '.join(f'{o:.2f}' for o in cfg.overlaps)} ({cfg.overlap_mode}), "
        f"methods {', '.join(cfg.methods)}, seeds {cfg.seeds}: {n_runs} run(s) -> {out}")
    counters = Counters(rendered=0, render_skipped=0, render_resumed=0, trained=0, train_skipped=0, train_resumed=0,
                        evaluated=0, eval_skipped=0, diverged=0, failed=0, reference_evaluated=0, reference_skipped=0)
    t_start = time.perf_counter()
    # overall progress: a bar on a terminal, else log lines (study.sweep.progress)
    prog = SweepProgress(n_runs, log, bar=progress and sys.stderr.isatty())
    try:
        prog.stage("pretraining")
        pre = pretrain_stage(cfg, out, progress, log)
        init_from = pre["weights"] if pre else None
        per_overlap = {}  # overlap -> its worlds' records (one: shared; one per seed: per_seed)
        for o in cfg.overlaps:
            per_overlap[o] = []
            for w in worlds_of(cfg):
                prog.stage(f"render of overlap {o:.2f}" + ("" if w is None else f", world {w}"))
                per_overlap[o].append(render_stage(cfg, o, out, counters, log, progress, world=w))
        prog.stage("yardsticks")
        data, worlds = [], {}  # worlds[(overlap, seed)]: the dataset that seed trains on
        for o, recs in per_overlap.items():
            for r in recs:
                r["reference"], r["prior"] = reference_stage(cfg, r, out, counters, log)
            data.append(recs[0] if len(recs) == 1 else combine_worlds(recs))
            ids = worlds_of(cfg)
            for seed in cfg.seeds:
                worlds[o, seed] = recs[0] if len(recs) == 1 else recs[ids.index(world_of_seed(cfg, seed))]
        todo = [(worlds[d["overlap"], seed], method, seed) for d in data for method in cfg.methods
                for seed in cfg.seeds]
        prog.stage("runs")
        rows = run_all(cfg, todo, out, counters, log, progress, init_from, on_done=prog.run_done)
        prog.stage("report")
    finally:
        prog.close()
    previews = []
    if cfg.preview:
        previews = _previews(data, out, log)
    total_s = time.perf_counter() - t_start
    results = build_results(cfg, data, rows, dict(counters), total_s, previews)
    results["pretrain"] = pre
    write_all(results, out)
    log(f"[sweep] done in {total_s:.1f} s: " + ", ".join(f"{k}={v}" for k, v in counters.items()))
    log(f"[sweep] finished: {prog.done}/{n_runs} runs in {fmt_duration(total_s)} wall time; report: {out / 'report.md'}")
    return results


def _note_config_change(prev: Path, resolved: dict, log) -> None:
    """Log which keys of the resolved config differ from those saved in ``prev`` (an earlier run of the sweep);
    the file is read with the project's loader (`corelib.configlib.read_yaml`: bounded in size, depth and
    keys, no aliases), and one that is not read is a note, not an error (only the note is lost)."""
    if not prev.is_file():
        return
    try:
        old = read_yaml(prev).get("config")
    except ConfigError as exc:
        log(f"[sweep] note: the saved sweep config is not read ({exc}); it is rewritten")
        return
    if isinstance(old, dict) and old != resolved:
        from corelib.configlib import diff_configs

        log(f"[sweep] note: the sweep config differs from the saved one in: {', '.join(diff_configs(old, resolved))}; "
            "datasets/runs are reused only where their own resolved config is unchanged")


def _previews(data: list[dict], out: Path, log) -> list[str]:
    from synth.open import open_dataset
    from synth.preview import make_preview

    paths = []
    picks = [data[0]] if len(data) == 1 else [data[0], data[-1]]
    for d in picks:
        p = out / f"preview_{overlap_key(d['overlap'])}.png"
        if not p.is_file():
            try:
                ds = open_dataset(d["path"])
                seq = ds.split(SPLIT)[0] if ds.split(SPLIT) else None
                make_preview(ds, p, seq=seq, frame=0)
            except Exception as exc:  # a preview is a nicety: never lose the sweep over it
                log(f"[sweep] preview of {d['path']} failed: {exc}")
                continue
        paths.append(p.name)
    return paths
