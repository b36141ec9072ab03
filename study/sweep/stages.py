"""The stages of one sweep: make the shared pretraining, and train + evaluate one (overlap, method, seed)
run; each stage is skipped when its inputs' hashes are unchanged (module docstring of `study.sweep_command`).
The worlds (render, measured overlap, yardsticks) are `study.sweep.worlds`.

A run's files are written, and its checkpoints deleted, only inside the sweep's own folder: every folder from
the sweep's down to the file is reached without following a link (`corelib.nolinks`). A run folder that is, or
lies under, a symbolic link (``runs/``, ``runs/overlap_0.50/`` or the run's own folder linked to another
sweep's, to reuse it) is read only: reused when its records match, with one line saying so, never cleaned up;
one that would be trained or evaluated again is refused in one line naming the link.
"""
from __future__ import annotations

import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from corelib.configlib import ConfigError, config_hash, config_to_dict
from corelib.version import code_version, warn_other_code
from study.sweep.cleanup import remove_best, remove_last, removed_line, trim_pretraining
from study.sweep.config import SPLIT, SweepConfig, eval_config_for, overlap_key, run_config_for
from study.sweep.records import Counters, finite, read_json, write_json  # noqa: F401 (re-exported)
from study.sweep.variants import CUT, ORACLE, ORACLE_OVL, SPREAD, TRAINED, VARIANTS, cut, entries_of, having


STATUS = "sweep_status.json"


def pretrain_stage(cfg: SweepConfig, sweep_dir: Path, progress: bool, log) -> dict | None:
    """Make (or reuse) the sweep's shared pretraining; its record with ``weights`` (the path runs start from)."""
    if cfg.pretrain is None:
        return None
    from study.sweep.pretrain import WEIGHTS, resolved_configs, run_pretrain

    _, _, h = resolved_configs(cfg.pretrain)
    pdir = sweep_dir / "pretrain" / h[:12]
    rec = run_pretrain(cfg.pretrain, pdir, progress=progress, log=log)
    trim_pretraining(cfg, pdir / "run", int(rec["step"]), log, root=sweep_dir)
    return {"weights": str(pdir / WEIGHTS), "config_hash": h, "sha256": rec["sha256"], "step": rec["step"],
            "render_s": rec.get("render_s"), "train_s": rec.get("train_s"), "depth_spread": rec.get("depth_spread"),
            "code_version": rec.get("code_version"), "cpu_capability": rec.get("cpu_capability")}


#: what an evaluation measures; a change re-evaluates every cached run (labels: by class group and motion)
EVAL_PROTOCOL = "as-trained+cut+cut-change+oracle-weights+oracle-overlap+bands+labels+per-sequence"


#: the variants `EVAL_PROTOCOL` evaluates (by name: what the protocol string has always covered, so that cached
#: evaluations keep their key); one registered beyond them (`study.sweep.variants`) is part of the eval key
PROTOCOL_VARIANTS = (TRAINED, CUT, ORACLE, ORACLE_OVL, SPREAD)


def _eval_key(run_hash: str, step: int, eval_cfg: dict, data_hash: str, checkpoint: str, ckpt_name: str) -> str:
    key = {"run": run_hash, "step": step, "eval": eval_cfg, "data": data_hash, "checkpoint": checkpoint,
           "file": ckpt_name, "protocol": EVAL_PROTOCOL}
    more = [v for v in VARIANTS if v not in PROTOCOL_VARIANTS]
    return config_hash({**key, "variants": more} if more else key)


def metrics_path(run_dir: Path, variant: str) -> Path:
    """The metrics file of one pass of a run's evaluation: ``metrics_test.json`` as trained (it names the eval
    key that says every pass is complete), ``metrics_test_<variant>.json`` for another pass."""
    return Path(run_dir) / (f"metrics_{SPLIT}.json" if variant == TRAINED else f"metrics_{SPLIT}_{variant}.json")


def run_dir_for(sweep_dir: Path, overlap: float, method: str, seed: int) -> Path:
    """The folder of one (overlap, method, seed) run: ``SWEEP/runs/overlap_0.30/<method>_s<seed>``."""
    return Path(sweep_dir) / "runs" / overlap_key(overlap) / f"{method}_s{seed}"


def run_stage(cfg: SweepConfig, overlap: float, data: dict, method: str, seed: int, sweep_dir: Path,
              counters: Counters, log, progress: bool, init_from: str | None = None) -> dict:
    """Train (or reuse / resume) and evaluate one (overlap, method, seed); returns its result row."""
    from corelib.nolinks import linked_part
    from synth.open import open_dataset

    rcfg, preset = run_config_for(cfg, method, seed, init_from)
    run_dir = run_dir_for(sweep_dir, overlap, method, seed)
    status = read_json(run_dir / STATUS) or {}
    rhash = sweep_run_hash(rcfg, status)
    run = _Run(cfg, overlap, data, method, seed, rcfg, rhash, run_dir, status,
               f"[sweep] overlap {overlap:.2f} {method} seed {seed}", counters, log, progress,
               root=Path(sweep_dir), linked=linked_part(sweep_dir, run_dir))
    row: dict[str, Any] = {"overlap": overlap, "method": method, "seed": seed, "world": data.get("data_seed"),
                           "run_dir": str(run_dir),
                           "preset": str(preset), "run_config_hash": rhash, "run_config": config_to_dict(rcfg),
                           "status": "ok"}
    run.ds = open_dataset(data["path"])
    if not _train(run, row):
        return row  # diverged: the row says so
    passes, key = _evaluate(run, row)
    removed = []
    if run.linked is not None:  # another sweep's run, linked in to be reused: never cleaned up from here
        log(f"{run.tag}: {_link_words(run)}: the run is read only, reused as it is; nothing is written or deleted "
            "through the link" + ("" if cfg.keep_last and cfg.keep_best else
                                  " (keep_last / keep_best: false are not applied to it)"))
    else:
        if not cfg.keep_last:
            # (its log line of a kept file only when remove_best, which says it too, does not run)
            run.status, removed = remove_last(run_dir, run.status, run.status_path,
                                               log if cfg.keep_best else (lambda _: None), run.tag, root=run.root)
        if not cfg.keep_best:
            run.status, gone = remove_best(run_dir, run.status, run.status_path, key, log, run.tag, root=run.root)
            removed += gone
    if removed:
        log(f"{run.tag}: {removed_line(removed)}; its evaluation is in {run_dir / f'metrics_{SPLIT}.json'}")
    _fill_row(row, run.status, passes)
    log(_row_line(run.tag, row))
    return row


def sweep_run_hash(rcfg, status: dict) -> str:
    """The run's cache key, `mcdp.runs.run_hash` (free of the sweep folder's path); for a run whose status
    was recorded before that, under the key of its day (`config_hash`, which held ``model.init_from``'s
    path), that one while it still matches: such a run is reused where it lies, not trained again."""
    from mcdp.runs import run_hash

    legacy = config_hash(rcfg)
    return legacy if rcfg.model.init_from is not None and status.get("run_config_hash") == legacy else run_hash(rcfg)


@dataclass
class _Run:
    """One run of `run_stage`: what it is, its resolved config and hash, its folder and status record."""
    cfg: SweepConfig
    overlap: float
    data: dict
    method: str
    seed: int
    rcfg: Any
    rhash: str
    run_dir: Path
    status: dict
    tag: str
    counters: Counters
    log: Any
    progress: bool
    ds: Any = None
    root: Path | None = None    # the sweep's folder: the run's files are written only below it, never through a link
    linked: Path | None = None  # the symbolic link (runs/, runs/overlap_*/ or the run's folder) it is reached through

    @property
    def status_path(self) -> Path:
        return self.run_dir / STATUS


def _link_words(run: _Run) -> str:
    """``SWEEP/runs/overlap_0.50 is a symbolic link (to /elsewhere)``: the link a read-only run is reached through."""
    import os

    try:
        target = os.readlink(run.linked)
    except OSError:
        target = "?"
    return f"{run.linked} is a symbolic link (to {target})"


def _refuse_linked(run: _Run, what: str) -> None:
    """A read-only run (reached through a link) that would be trained or evaluated again: one line naming the link."""
    if run.linked is not None:
        raise ConfigError(f"{run.run_dir}: {_link_words(run)}, and the run would be {what} again; the sweep writes "
                          f"and deletes only inside its own folder {run.root}: copy the run into it instead of "
                          "linking it, or remove the link")


def _train(run: _Run, row: dict) -> bool:
    """Train the run (or skip a trained one, or resume); False if it diverged (the row and status say so)."""
    from mcdp.runs import RunError
    from mcdp.trainer import Trainer, TrainingDiverged

    status, data, rhash, run_dir, tag = run.status, run.data, run.rhash, run.run_dir, run.tag
    if status.get("trained") and status.get("run_config_hash") == rhash and status.get("data_hash") == data["config_hash"]:
        run.counters.bump("train_skipped")
        row.update(train_s=status.get("train_s", float("nan")), train_skipped=True, steps=status.get("steps"))
        run.log(f"{tag}: trained already ({status.get('steps')} steps), skipped")
        warn_other_code(f"run {run_dir}", status.get("code_version"), lambda line: run.log(f"{tag}: {line}"))
        return True
    _refuse_linked(run, "trained")
    if status.get("data_hash") not in (None, data["config_hash"]):
        raise ConfigError(f"{run_dir} was trained on another dataset; delete it or use a new --out")
    if status.get("last_removed") and not (run_dir / "checkpoints" / "last.pt").exists():
        raise ConfigError(f"{run_dir}: the resolved config of {run.method} changed since this run was trained, and "
                          "its checkpoints/last.pt was removed after evaluation (keep_last: false"
                          + (", and best.pt by keep_best: false" if status.get("best_removed") else "")
                          + f"), so it cannot resume; delete {run_dir} to retrain it, or use a new --out")
    t0 = time.perf_counter()
    try:
        trainer = Trainer(run.rcfg, run.ds, run_dir, progress=run.progress)
    except RunError as exc:
        raise RunError(f"{exc}\n(sweep: the resolved config of {run.method} changed since this run was trained, "
                       f"through the sweep preset, its overrides or new code defaults; delete {run_dir} "
                       "to retrain it, or use a new --out)") from None
    resumed_at = trainer.step
    run.log(f"{tag}: training {run.rcfg.train.steps} steps"
            + (f" (resuming at step {resumed_at})" if resumed_at else "") + f" -> {run_dir}")
    try:
        summary = trainer.train()
    except TrainingDiverged as exc:
        run.log(f"{tag}: TRAINING DIVERGED: {exc}")
        run.counters.bump("diverged")
        write_json(run.status_path, {**status, "run_config_hash": rhash, "data_hash": data["config_hash"],
                                      "trained": False, "diverged": str(exc)}, root=run.root)
        row.update(status="diverged", error=str(exc), train_s=time.perf_counter() - t0, train_skipped=False)
        return False
    finally:
        trainer.close()
    train_s = time.perf_counter() - t0  # this invocation only (an interrupted earlier part is not counted)
    run.counters.bump("trained")
    if resumed_at:
        run.counters.bump("train_resumed")
    run.status = {"run_config_hash": rhash, "data_hash": data["config_hash"], "trained": True,
                  "steps": summary["steps"], "train_s": train_s, "best_val": summary["best_val"],
                  "code_version": code_version()}
    write_json(run.status_path, run.status, root=run.root)
    row.update(train_s=train_s, train_skipped=False, steps=summary["steps"])
    return True


def _checkpoint_of(run_dir: Path, which: str) -> str:
    """The name of the run's checkpoint the sweep evaluates (`mcdp.runs.find_checkpoint`); a checkpoint deleted
    by other means than the sweep's clean-up (which records it) is a ConfigError that says what to do."""
    from mcdp.runs import RunError, find_checkpoint

    try:
        return find_checkpoint(run_dir, which).name
    except RunError as exc:
        raise ConfigError(f"{exc}; the sweep reads it to evaluate the run or to skip it, and a checkpoint removed "
                          "by hand is not recorded as removed: restore it, or delete the run folder to retrain "
                          "it (keep_last / keep_best: false remove checkpoints with a record, and a rerun then "
                          "skips the run)") from None


def _evaluate(run: _Run, row: dict) -> tuple[dict[str, dict], str]:
    """Evaluate the run's checkpoint (or reuse the metrics of the same eval key); ({variant: metrics of its pass}
    (`study.sweep.probes.run_probes`), key)."""
    from mcdp.predict import run_record
    from mcdp.runs import rig_differences

    cfg, run_dir, status = run.cfg, run.run_dir, run.status
    ecfg = eval_config_for(cfg)
    # keep_best: false removed the evaluated checkpoint: its name is the recorded one (by name, as in remove_last)
    removed = bool(status.get("best_removed"))
    ckpt_name = Path(status.get("checkpoint") or "").name if removed else _checkpoint_of(run_dir, cfg.checkpoint)
    key = _eval_key(run.rhash, int(status.get("steps", -1)), config_to_dict(cfg.eval), run.data["config_hash"],
                    cfg.checkpoint, ckpt_name)
    metrics = read_json(metrics_path(run_dir, TRAINED))
    if metrics is not None and metrics.get("sweep", {}).get("eval_key") == key and status.get("eval_key") == key:
        run.counters.bump("eval_skipped")
        row.update(eval_s=status.get("eval_s", float("nan")), eval_skipped=True)
        run.log(f"{run.tag}: evaluated already, skipped")
        passes = {TRAINED: metrics}
        for v in VARIANTS.values():
            m = read_json(metrics_path(run_dir, v.name)) if v.probe is not None and v.name != TRAINED else None
            if m is not None and m.get("sweep", {}).get("eval_key") == key:  # a pass of this eval key
                passes[v.name] = m
        return passes, key
    _refuse_linked(run, "evaluated")
    if removed:
        raise ConfigError(f"{run_dir}: its evaluation is out of date (the sweep's eval settings, checkpoint or this "
                          f"code's evaluation changed) and its checkpoint checkpoints/{ckpt_name} was removed after "
                          f"it was evaluated (keep_best: false), so it cannot be evaluated again; delete {run_dir} "
                          "to retrain it, or use a new --out")
    t0 = time.perf_counter()
    passes, pred = evaluate_run(cfg, run_dir, run.ds, ecfg, run.progress, run.log, run.tag)
    metrics = passes[TRAINED]
    metrics["run"] = run_record(pred, run_dir, run.data["path"], rig_differences(run_dir, run.ds))
    metrics["sweep"] = {"eval_key": key, "overlap": run.overlap, "method": run.method, "seed": run.seed}
    for name, m in passes.items():
        if name != TRAINED:
            m["sweep"] = {**metrics["sweep"], "variant": name}
            write_json(metrics_path(run_dir, name), m, root=run.root)
    write_json(metrics_path(run_dir, TRAINED), metrics, root=run.root)  # last: its eval key says all are complete
    eval_s = time.perf_counter() - t0
    run.status = {**status, "eval_key": key, "eval_s": eval_s, "checkpoint": metrics["run"]["checkpoint"],
                  "checkpoint_step": metrics["run"]["step"]}
    write_json(run.status_path, run.status, root=run.root)
    run.counters.bump("evaluated")
    row.update(eval_s=eval_s, eval_skipped=False)
    return passes, key


def _fill_row(row: dict, status: dict, passes: dict[str, dict]) -> None:
    """The row's checkpoint and the numbers the report reads: its evaluations, {variant: entry}
    (`study.sweep.variants.entries_of`)."""
    row["checkpoint"] = status.get("checkpoint")
    row["checkpoint_step"] = status.get("checkpoint_step")
    row["oracle"] = bool(passes[TRAINED].get("run", {}).get("oracle", False))
    row["evaluations"] = entries_of(passes)


def _row_line(tag: str, row: dict) -> str:
    """The run's log line: abs_rel, Dep Con, how much the refinement acted, the cut, the ORACLE weights."""
    ev = row["evaluations"]
    c, ceiling = cut(), next((v for v in having("ceiling") if v.name in ev), None)
    m = ev[TRAINED]["metrics"]
    r = ev[TRAINED].get("refinement") or {}
    return (f"{tag}: abs_rel metric {m['none']['mean']['abs_rel']:.4f}, median {m['median']['mean']['abs_rel']:.4f}, "
            f"dep_con {m['dep_con']['mean']:.4f}"
            + (f"; refinement |w - 1/n| {r['weight_move']:.4f}, |refined - init| {r['depth_change_m']:.3f} m"
               if r.get("weight_move") == r.get("weight_move") and "weight_move" in r else "")
            + (f"; {c} median {ev[c]['metrics']['median']['mean']['abs_rel']:.4f}, |trained - {c}| "
               f"{(ev[c].get('refinement') or {}).get('cut_change_m', float('nan')):.4f} m" if c in ev else "")
            + (f"; {ceiling.label} median {ev[ceiling.name]['metrics']['median']['mean']['abs_rel']:.4f}"
               if ceiling is not None else ""))


def evaluate_run(cfg: SweepConfig, run_dir: Path, ds, ecfg, progress: bool, log, tag: str):
    """Evaluate one run's checkpoint as every variant that applies to it (`study.sweep.variants`: as trained with the
    ORACLE stages of a run with bases, with its neighbours cut for a network that reads them, ...;
    `study.sweep.probes.run_probes`), every pass at once, sample by sample (`mcdp.evaluate.evaluate_passes`): each test
    sample's ground truth, overlap, labels and regions are read once and shared by every pass and stage, the
    ORACLE stages' included.

    Returns ({variant: metrics of its pass, with ``refinement``}, the run's `mcdp.predict.Predictor`).
    """
    import torch

    from mcdp.evaluate import TruthCache, evaluate_passes
    from mcdp.predict import Predictor
    from study.sweep.probes import run_probes

    pred = Predictor(run_dir, ds, cfg.checkpoint, cfg.device)
    threads_before = torch.get_num_threads()
    if pred.cfg.train.threads > 0 and pred.device.type == "cpu":
        # the run's thread count, as in training: a rerun that only evaluates would otherwise use torch's
        # default in each of `jobs` processes at once (oversubscribed: an evaluate-only rerun of the CPU sweep,
        # 2 jobs on 2 cores, took a median 147 s per MCDP (m = 2) evaluation against 46 s right after training)
        torch.set_num_threads(pred.cfg.train.threads)
    log(f"{tag}: evaluating {pred.ckpt_path.name} (step {pred.step}) on the {SPLIT} split")
    try:
        truths = TruthCache(ds, ecfg)  # each test sample's ground truth, read once for every pass and stage
        passes = run_probes(VARIANTS.values(), pred, (ecfg.min_depth, ecfg.max_depth),
                            lambda predicts: evaluate_passes(ds, predicts, SPLIT, ecfg, progress, truths),
                            lambda line: log(f"{tag}: evaluating {line}"), truths)
        return passes, pred
    finally:
        torch.set_num_threads(threads_before)


#: why a checkpoint was removed (`mcdp.checkpoint_files.record_removed`; `mcdp eval` on the run prints it)
