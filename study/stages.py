"""The stages of one sweep: make the shared pretraining, and train + evaluate one (overlap, method, seed)
run; each stage is skipped when its inputs' hashes are unchanged (module docstring of `study.sweep`).
The worlds (render, measured overlap, yardsticks) are `study.worlds`.
"""
from __future__ import annotations

import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from corelib.configlib import ConfigError, config_hash, config_to_dict
from corelib.version import code_version, warn_other_code
from study.cleanup import remove_best, remove_last, removed_line, trim_pretraining
from study.config import SPLIT, SweepConfig, eval_config_for, overlap_key, run_config_for
from study.records import Counters, finite, read_json, summarize_metrics, write_json  # noqa: F401 (re-exported)


STATUS = "sweep_status.json"


def pretrain_stage(cfg: SweepConfig, sweep_dir: Path, progress: bool, log) -> dict | None:
    """Make (or reuse) the sweep's shared pretraining; its record with ``weights`` (the path runs start from)."""
    if cfg.pretrain is None:
        return None
    from study.pretrain import WEIGHTS, resolved_configs, run_pretrain

    _, _, h = resolved_configs(cfg.pretrain)
    pdir = sweep_dir / "pretrain" / h[:12]
    rec = run_pretrain(cfg.pretrain, pdir, progress=progress, log=log)
    trim_pretraining(cfg, pdir / "run", int(rec["step"]), log)
    return {"weights": str(pdir / WEIGHTS), "config_hash": h, "sha256": rec["sha256"], "step": rec["step"],
            "render_s": rec.get("render_s"), "train_s": rec.get("train_s"), "depth_spread": rec.get("depth_spread")}


#: what an evaluation measures; a change re-evaluates every cached run (labels: by class group and motion)
EVAL_PROTOCOL = "as-trained+cut+cut-change+oracle-weights+oracle-overlap+bands+labels"


def _eval_key(run_hash: str, step: int, eval_cfg: dict, data_hash: str, checkpoint: str, ckpt_name: str) -> str:
    return config_hash({"run": run_hash, "step": step, "eval": eval_cfg, "data": data_hash, "checkpoint": checkpoint,
                        "file": ckpt_name, "protocol": EVAL_PROTOCOL})


def run_dir_for(sweep_dir: Path, overlap: float, method: str, seed: int) -> Path:
    """The folder of one (overlap, method, seed) run: ``SWEEP/runs/overlap_0.30/<method>_s<seed>``."""
    return Path(sweep_dir) / "runs" / overlap_key(overlap) / f"{method}_s{seed}"


def run_stage(cfg: SweepConfig, overlap: float, data: dict, method: str, seed: int, sweep_dir: Path,
              counters: Counters, log, progress: bool, init_from: str | None = None) -> dict:
    """Train (or reuse / resume) and evaluate one (overlap, method, seed); returns its result row."""
    from synth.open import open_dataset

    rcfg, preset = run_config_for(cfg, method, seed, init_from)
    run_dir = run_dir_for(sweep_dir, overlap, method, seed)
    status = read_json(run_dir / STATUS) or {}
    rhash = sweep_run_hash(rcfg, status)
    run = _Run(cfg, overlap, data, method, seed, rcfg, rhash, run_dir, status,
               f"[sweep] overlap {overlap:.2f} {method} seed {seed}", counters, log, progress)
    row: dict[str, Any] = {"overlap": overlap, "method": method, "seed": seed, "run_dir": str(run_dir),
                           "preset": str(preset), "run_config_hash": rhash, "status": "ok"}
    run.ds = open_dataset(data["path"])
    if not _train(run, row):
        return row  # diverged: the row says so
    metrics, metrics_cut, key = _evaluate(run, row)
    removed = []
    if not cfg.keep_last:
        # (its log line of a kept file only when remove_best, which says it too, does not run)
        run.status, removed = remove_last(run_dir, run.status, run.status_path,
                                           log if cfg.keep_best else (lambda _: None), run.tag)
    if not cfg.keep_best:
        run.status, gone = remove_best(run_dir, run.status, run.status_path, key, log, run.tag)
        removed += gone
    if removed:
        log(f"{run.tag}: {removed_line(removed)}; its evaluation is in {run_dir / f'metrics_{SPLIT}.json'}")
    _fill_row(row, run.status, metrics, metrics_cut, key)
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

    @property
    def status_path(self) -> Path:
        return self.run_dir / STATUS


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
                                      "trained": False, "diverged": str(exc)})
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
    write_json(run.status_path, run.status)
    row.update(train_s=train_s, train_skipped=False, steps=summary["steps"])
    return True


def _evaluate(run: _Run, row: dict) -> tuple[dict, dict | None, str]:
    """Evaluate the run's checkpoint (or reuse the metrics of the same eval key); (metrics, metrics_cut, key)."""
    from mcdp.predict import run_record
    from mcdp.runs import find_checkpoint, rig_differences

    cfg, run_dir, status = run.cfg, run.run_dir, run.status
    metrics_path = run_dir / f"metrics_{SPLIT}.json"
    cut_path = run_dir / f"metrics_{SPLIT}_cut.json"
    ecfg = eval_config_for(cfg)
    # keep_best: false removed the evaluated checkpoint: its name is the recorded one (by name, as in remove_last)
    removed = bool(status.get("best_removed"))
    ckpt_name = Path(status.get("checkpoint") or "").name if removed else find_checkpoint(run_dir, cfg.checkpoint).name
    key = _eval_key(run.rhash, int(status.get("steps", -1)), config_to_dict(cfg.eval), run.data["config_hash"],
                    cfg.checkpoint, ckpt_name)
    metrics = read_json(metrics_path)
    metrics_cut = read_json(cut_path)
    if metrics is not None and metrics.get("sweep", {}).get("eval_key") == key and status.get("eval_key") == key:
        run.counters.bump("eval_skipped")
        row.update(eval_s=status.get("eval_s", float("nan")), eval_skipped=True)
        run.log(f"{run.tag}: evaluated already, skipped")
        return metrics, metrics_cut, key
    if removed:
        raise ConfigError(f"{run_dir}: its evaluation is out of date (the sweep's eval settings, checkpoint or this "
                          f"code's evaluation changed) and its checkpoint checkpoints/{ckpt_name} was removed after "
                          f"it was evaluated (keep_best: false), so it cannot be evaluated again; delete {run_dir} "
                          "to retrain it, or use a new --out")
    t0 = time.perf_counter()
    metrics, metrics_cut, pred = evaluate_run(cfg, run_dir, run.ds, ecfg, run.progress, run.log, run.tag)
    metrics["run"] = run_record(pred, run_dir, run.data["path"], rig_differences(run_dir, run.ds))
    metrics["sweep"] = {"eval_key": key, "overlap": run.overlap, "method": run.method, "seed": run.seed}
    if metrics_cut is not None:
        metrics_cut["sweep"] = {**metrics["sweep"], "cut": True}
        write_json(cut_path, metrics_cut)
    write_json(metrics_path, metrics)  # last: it names the eval key that says both are complete
    eval_s = time.perf_counter() - t0
    run.status = {**status, "eval_key": key, "eval_s": eval_s, "checkpoint": metrics["run"]["checkpoint"],
                  "checkpoint_step": metrics["run"]["step"]}
    write_json(run.status_path, run.status)
    run.counters.bump("evaluated")
    row.update(eval_s=eval_s, eval_skipped=False)
    return metrics, metrics_cut, key


def _fill_row(row: dict, status: dict, metrics: dict, metrics_cut: dict | None, key: str) -> None:
    """The row's checkpoint and the numbers the report reads: every stage's, the cut's (of this eval key)."""
    row["checkpoint"] = status.get("checkpoint")
    row["checkpoint_step"] = status.get("checkpoint_step")
    row["oracle"] = bool(metrics.get("run", {}).get("oracle", False))
    row["metrics"] = summarize_metrics(metrics)
    row["refinement"] = metrics.get("refinement")
    if "init" in metrics["stages"] and len(metrics["stages"]) > 2:
        row["metrics_init"] = summarize_metrics(metrics, "init")
    if "oracle" in metrics["stages"]:
        row["metrics_oracle"] = summarize_metrics(metrics, "oracle")
    if "oracle_overlap" in metrics["stages"]:
        row["metrics_oracle_overlap"] = summarize_metrics(metrics, "oracle_overlap")
    if "oracle_spread" in metrics["stages"]:
        row["metrics_oracle_spread"] = summarize_metrics(metrics, "oracle_spread")
    if metrics_cut is not None and metrics_cut.get("sweep", {}).get("eval_key") == key:
        row["metrics_cut"] = summarize_metrics(metrics_cut)
        row["refinement_cut"] = metrics_cut.get("refinement")


def _row_line(tag: str, row: dict) -> str:
    """The run's log line: abs_rel, Dep Con, how much the refinement acted, the cut, the ORACLE weights."""
    m = row["metrics"]
    r = row["refinement"] or {}
    return (f"{tag}: abs_rel metric {m['none']['mean']['abs_rel']:.4f}, median {m['median']['mean']['abs_rel']:.4f}, "
            f"dep_con {m['dep_con']['mean']:.4f}"
            + (f"; refinement |w - 1/n| {r['weight_move']:.4f}, |refined - init| {r['depth_change_m']:.3f} m"
               if r.get("weight_move") == r.get("weight_move") and "weight_move" in r else "")
            + (f"; cut median {row['metrics_cut']['median']['mean']['abs_rel']:.4f}, |trained - cut| "
               f"{(row.get('refinement_cut') or {}).get('cut_change_m', float('nan')):.4f} m"
               if "metrics_cut" in row else "")
            + (f"; ORACLE weights median {row['metrics_oracle']['median']['mean']['abs_rel']:.4f}"
               if "metrics_oracle" in row else ""))


def evaluate_run(cfg: SweepConfig, run_dir: Path, ds, ecfg, progress: bool, log, tag: str):
    """Evaluate one run's checkpoint: as trained (+ the ORACLE-weights stages of a run with bases),
    and, for a network whose depth uses the neighbours at inference (``uses_neighbours``: MCDP's refinement,
    the cross-view attention of `mcdp.methods.surround`, ORACLE-local's input), a second time with its neighbours
    cut at inference (`study.probes`).

    Returns (metrics, metrics_cut or None, the run's `mcdp.predict.Predictor`); ``metrics["refinement"]`` /
    ``metrics_cut["refinement"]`` record how much the refinement acted.
    """
    import torch

    from mcdp.predict import Predictor

    pred = Predictor(run_dir, ds, cfg.checkpoint, cfg.device)
    threads_before = torch.get_num_threads()
    if pred.cfg.train.threads > 0 and pred.device.type == "cpu":
        # the run's thread count, as in training: a rerun that only evaluates would otherwise use torch's
        # default in each of `jobs` processes at once (oversubscribed: an evaluate-only rerun of the CPU sweep,
        # 2 jobs on 2 cores, took a median 147 s per MCDP (m = 2) evaluation against 46 s right after training)
        torch.set_num_threads(pred.cfg.train.threads)
    try:
        metrics, metrics_cut = _evaluate_both(ds, ecfg, progress, log, tag, pred)
        return metrics, metrics_cut, pred
    finally:
        torch.set_num_threads(threads_before)


def _evaluate_both(ds, ecfg, progress: bool, log, tag: str, pred):
    """`evaluate_run` once the predictor and the thread count are set."""
    from mcdp.evaluate import evaluate
    from study.probes import CUT, Probed

    # keep=True: its depths (<= 64 MiB) are what the cut evaluation of a network that reads its neighbours
    # is compared with
    trained = Probed(pred, oracle_range=(ecfg.min_depth, ecfg.max_depth), keep=True)
    log(f"{tag}: evaluating {pred.ckpt_path.name} (step {pred.step}) on the {SPLIT} split"
        + (" (+ ORACLE weights of its bases)" if trained.oracle_weights else ""))
    metrics = evaluate(ds, trained.predict, SPLIT, ecfg, progress=progress)
    metrics["refinement"] = trained.refinement
    metrics_cut = None
    if pred.network.uses_neighbours:
        cut = Probed(pred, CUT, reference=trained)
        log(f"{tag}: evaluating it again with the neighbours cut at inference")
        metrics_cut = evaluate(ds, cut.predict, SPLIT, ecfg, progress=progress)
        metrics_cut["refinement"] = cut.refinement
    return metrics, metrics_cut


#: why a checkpoint was removed (`mcdp.checkpoint_files.record_removed`; `mcdp eval` on the run prints it)
