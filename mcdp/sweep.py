"""The overlap sweep: render + train + evaluate every method at every camera overlap, then report.

For each overlap of a sweep preset (``configs/sweep/*.yaml``) the dataset is
rendered (``spacing`` mode by default: intrinsics fixed, only the yaw spacing
changes, so overlap is the only variable), every method preset is trained for
every seed, evaluated on the test split, and `mcdp.report` writes the tables,
CSV/JSON and plots::

    mcdp sweep configs/sweep/ci.yaml --out SWEEP [key=value ...]
    mcdp sweep configs/sweep/cpu.yaml --out sweeps/cpu "overlaps=[0.2,0.4]" seeds=[0,1]

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
a run whose ``sweep_status.json`` records the same resolved run config as
trained is not retrained (an interrupted one resumes from ``checkpoints/last.pt``
through `mcdp.trainer.Trainer`); an evaluation is reused when its key (run
config, checkpoint step, eval config, dataset hash) is unchanged. A rerun of a
finished sweep only rewrites the report.

Honesty rules kept here: model selection (``best.pt``) uses the val split's
self-supervised loss only; the test split is read once per run, by the
evaluation; no setting is chosen by looking at test numbers.
"""
from __future__ import annotations

import argparse
import json
import math
import sys
import time
from pathlib import Path
from typing import Any, Callable, Literal

import yaml
from pydantic import Field, field_validator, model_validator

from corelib.atomic import atomic_write_json
from mcdp.pretrain import PretrainConfig
from corelib.configlib import ConfigError, StrictModel, config_hash, config_to_dict, load_config

METHODS = ("mono2", "mcdp_m0", "mcdp_m1_nocon", "mcdp_m1", "mcdp_m2")
ROOT = Path(__file__).resolve().parents[1]
STATUS = "sweep_status.json"
SPLIT = "test"


class SweepEvalConfig(StrictModel):
    """Evaluation settings applied to every run (see `mcdp.evaluate.EvalConfig`; depths in metres)."""

    min_depth: float = Field(0.5, gt=0.0)
    max_depth: float = Field(80.0, gt=0.0)
    frame_stride: int = Field(1, ge=1)
    skip_ends: bool = True

    @model_validator(mode="after")
    def _range(self) -> "SweepEvalConfig":
        if self.min_depth >= self.max_depth:
            raise ValueError(f"eval.min_depth ({self.min_depth}) must be < eval.max_depth ({self.max_depth})")
        return self


class SweepConfig(StrictModel):
    """One overlap sweep; every default here, a preset lists what differs.

    data: data preset YAML (relative paths: to the working directory, else to the project root).
    data_overrides: dotted overrides for the data config (``rig.overlap``/``rig.overlap_mode`` are set per overlap).
    overlaps: target overlaps (shared fraction of hfov of adjacent cameras), each in [0.10, 0.60].
    overlap_mode: ``spacing`` (fixed intrinsics, yaw spacing solved: the clean experiment) or ``fov``.
    methods: subset of mono2, mcdp_m0, mcdp_m1_nocon, mcdp_m1, mcdp_m2 (``<train_presets_dir>/<method>.yaml``).
    train_overrides: dotted overrides applied to every run (e.g. ``train.steps=200``).
    seeds: training seeds (``train.seed``); the dataset seed comes from the data preset.
    eval: evaluation settings for every run.
    checkpoint: which checkpoint is evaluated: ``auto`` (best val loss, else last), ``best``, ``last``.
    workers: rendering processes.
    jobs: runs (train + eval) at once, each in its own process; on a CPU give each job
        ``train.threads`` cores (jobs x threads <= cores). Progress bars are off when > 1.
    device: training / inference device.
    preview: write a preview sheet of one rig at the smallest and largest overlap.
    pretrain: a shared self-supervised pretraining (`mcdp.pretrain.PretrainConfig`) that every
        run starts from (``model.init_from``), made once into ``SWEEP/pretrain/<hash>/`` and
        reused by its config hash; null = every run from scratch.
    keep_last: keep every run's ``checkpoints/last.pt`` (weights + Adam state: about three
        quarters of a run's disk). ``false`` removes it once the run is trained and its
        ``best.pt`` has been evaluated (only then); the results, ``best.pt`` and rerun skipping
        are unaffected, but such a run can no longer be resumed with more steps (the sweep
        refuses, naming the run folder to delete).
    """

    data: str = "configs/data/tiny.yaml"
    data_overrides: list[str] = Field(default_factory=list)
    overlaps: list[float] = Field(default_factory=lambda: [0.10, 0.20, 0.30, 0.40, 0.50, 0.60])
    overlap_mode: Literal["spacing", "fov"] = "spacing"
    methods: list[Literal["mono2", "mcdp_m0", "mcdp_m1_nocon", "mcdp_m1", "mcdp_m2"]] = Field(
        default_factory=lambda: list(METHODS))
    train_presets_dir: str = "configs/train"
    train_overrides: list[str] = Field(default_factory=list)
    seeds: list[int] = Field(default_factory=lambda: [0])
    eval: SweepEvalConfig = Field(default_factory=SweepEvalConfig)
    checkpoint: Literal["auto", "best", "last"] = "auto"
    workers: int = Field(2, ge=1, le=256)
    jobs: int = Field(1, ge=1, le=64)
    device: Literal["auto", "cpu", "cuda"] = "auto"
    preview: bool = True
    keep_last: bool = True
    pretrain: PretrainConfig | None = None

    @field_validator("overlaps")
    @classmethod
    def _overlaps(cls, v: list[float]) -> list[float]:
        if not v:
            raise ValueError("must list at least one overlap in [0.10, 0.60]")
        bad = [o for o in v if not 0.10 - 1e-9 <= o <= 0.60 + 1e-9]
        if bad:
            raise ValueError(f"overlaps must be in [0.10, 0.60], got {bad}")
        keys = [f"{o:.2f}" for o in v]
        if len(set(keys)) != len(keys):
            raise ValueError(f"overlaps must be distinct at 2 decimals, got {v}")
        return sorted(v)

    @field_validator("methods")
    @classmethod
    def _methods(cls, v: list[str]) -> list[str]:
        if not v:
            raise ValueError(f"must list at least one of {', '.join(METHODS)}")
        if len(set(v)) != len(v):
            raise ValueError(f"methods must be distinct, got {v}")
        return [m for m in METHODS if m in v]  # canonical (table) order

    @field_validator("seeds")
    @classmethod
    def _seeds(cls, v: list[int]) -> list[int]:
        if not v:
            raise ValueError("must list at least one seed")
        if len(set(v)) != len(v) or any(s < 0 for s in v):
            raise ValueError(f"seeds must be distinct and >= 0, got {v}")
        return v

    @field_validator("data_overrides")
    @classmethod
    def _no_overlap_override(cls, v: list[str]) -> list[str]:
        for key in override_keys(v):
            if key in ("rig.overlap", "rig.overlap_mode"):
                raise ValueError(f"{key} is set by the sweep (use overlaps / overlap_mode), not by data_overrides")
        return v

    @field_validator("train_overrides")
    @classmethod
    def _no_seed_override(cls, v: list[str]) -> list[str]:
        for key in override_keys(v):
            if key == "train.seed":
                raise ValueError("train.seed is set by the sweep (use seeds), not by train_overrides")
            if key.startswith("eval."):
                raise ValueError(f"{key}: set evaluation settings in the sweep's eval section")
        return v


def override_keys(items: list[str]) -> list[str]:
    """The dotted keys of key=value override strings."""
    return [item.split("=", 1)[0].strip() for item in items]


def overlap_key(o: float) -> str:
    return f"overlap_{o:.2f}"


def resolve_path(p: str | Path, kind: str) -> Path:
    """A relative path: to the working directory if it exists there, else to the project root."""
    p = Path(p)
    if p.is_absolute() or p.exists():
        return p
    alt = ROOT / p
    if alt.exists():
        return alt
    raise ConfigError(f"{kind} {p} does not exist (looked in {Path.cwd()} and {ROOT})")


def load_sweep_config(path: str | Path | None, overrides=()) -> SweepConfig:
    return load_config(SweepConfig, path, overrides)


# --------------------------------------------------------------------------- small helpers
def _read_json(path: Path) -> dict | None:
    try:
        return json.loads(path.read_text())
    except (OSError, ValueError):
        return None


def _write_json(path: Path, obj) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    atomic_write_json(path, obj, allow_nan=True)


def data_config_for(cfg: SweepConfig, overlap: float):
    """The resolved data config of one overlap."""
    from synth.config import load_data_config

    ov = list(cfg.data_overrides) + [f"rig.overlap={overlap:.2f}", f"rig.overlap_mode={cfg.overlap_mode}"]
    return load_data_config(resolve_path(cfg.data, "data preset"), ov)


def run_config_for(cfg: SweepConfig, method: str, seed: int, init_from: str | None = None):
    """The resolved RunConfig of one (method, seed): preset + train_overrides + seed + eval + device
    (+ ``model.init_from``, the sweep's pretraining)."""
    from mcdp.config import RunConfig

    preset = resolve_path(Path(cfg.train_presets_dir) / f"{method}.yaml", "training preset")
    ov = list(cfg.train_overrides) + [f"train.seed={seed}", f"train.device={cfg.device}"]
    if init_from is not None:
        ov.append(f"model.init_from={json.dumps(init_from)}")
    ov += [f"eval.{k}={json.dumps(v)}" for k, v in config_to_dict(cfg.eval).items()]
    return load_config(RunConfig, preset, ov), preset


def eval_config_for(cfg: SweepConfig):
    """The `mcdp.evaluate.EvalConfig` every run and the reference are evaluated with."""
    from mcdp.evaluate import EvalConfig
    from corelib.configlib import build_config

    return build_config(EvalConfig, config_to_dict(cfg.eval), "sweep eval")


def measured_overlap(manifest: dict) -> dict:
    """Target and measured pixel overlap of a dataset (from its manifest).

    ``measured_mean``: mean measured overlap over the adjacent pairs whose geometric
    target equals the sweep's target. In ``spacing`` mode the ring does not close, so
    the two pairs that take up the remaining angle (side cameras) have another target
    (a gap or a small overlap); they are listed per pair but not averaged.
    ``measured_all``: mean over every adjacent pair.
    """
    ov = manifest.get("overlap", {})
    pp = ov.get("per_pair_measured", {})
    target = ov.get("target")
    same = [v["measured"] for v in pp.values()
            if _finite(target) and _finite(v.get("target")) and abs(v["target"] - target) < 1e-3
            and _finite(v.get("measured"))]
    allm = [v["measured"] for v in pp.values() if _finite(v.get("measured"))]
    return {
        "target": target,
        "mode": ov.get("mode"),
        "hfov_deg": ov.get("hfov_deg"),
        "yaw_spacing_deg": ov.get("yaw_spacing_deg"),
        "measured_mean": sum(same) / len(same) if same else float("nan"),
        "measured_all": sum(allm) / len(allm) if allm else float("nan"),
        "pairs_at_target": len(same),
        "pairs": len(pp),
        "per_pair": {k: {"target": v.get("target"), "measured": v.get("measured")} for k, v in pp.items()},
    }


def _finite(x) -> bool:
    return isinstance(x, (int, float)) and math.isfinite(x)


def summarize_metrics(metrics: dict, stage: str = "final") -> dict:
    """The numbers the report uses, from one metrics.json (`mcdp.evaluate` layout)."""
    st = metrics["stages"][stage]
    out: dict[str, Any] = {}
    for sc in ("none", "median", "rig_median"):
        if sc not in st:
            continue
        out[sc] = {
            "mean": dict(st[sc]["mean"]),
            "overlap": dict(st[sc]["overlap"]),
            "non_overlap": dict(st[sc]["non_overlap"]),
            "per_camera_abs_rel": {c: v["abs_rel"] for c, v in st[sc]["per_camera"].items()},
        }
    dc = st["dep_con"]
    out["dep_con"] = {"mean": dc["mean"], "per_camera": dict(dc["per_camera"]), "per_pair": dict(dc["per_pair"])}
    out["spread"] = dict(st.get("spread", {}))
    out["n_samples"] = metrics.get("n_samples")
    out["stages"] = list(metrics["stages"])
    return out


# --------------------------------------------------------------------------- stages
class Counters(dict):
    def bump(self, key: str) -> None:
        self[key] = self.get(key, 0) + 1


def render_stage(cfg: SweepConfig, overlap: float, sweep_dir: Path, counters: Counters, log, progress: bool) -> dict:
    """Render (or reuse / resume) the dataset of one overlap; returns its record."""
    from synth.render import render_dataset

    dcfg = data_config_for(cfg, overlap)
    h = config_hash(dcfg)
    out = sweep_dir / "data" / overlap_key(overlap)
    manifest = _read_json(out / "manifest.json")
    status = _read_json(out.parent / f"{overlap_key(overlap)}.status.json") or {}
    if manifest is not None and manifest.get("config_hash") == h:
        counters.bump("render_skipped")
        log(f"[sweep] overlap {overlap:.2f}: dataset {out} is complete (config hash {h[:12]}), reused")
        render_s, skipped = status.get("render_s", float("nan")), True
    else:
        if manifest is not None:
            raise ConfigError(
                f"{out} holds a dataset with another config (hash {str(manifest.get('config_hash'))[:12]}, "
                f"requested {h[:12]}); the sweep's data settings changed: use a new --out or delete {out}")
        log(f"[sweep] overlap {overlap:.2f}: rendering {dcfg.dataset.sequences} sequences x {dcfg.dataset.frames} "
            f"frames at {dcfg.camera.width}x{dcfg.camera.height} into {out}")
        t0 = time.perf_counter()
        summary = render_dataset(dcfg, out, workers=cfg.workers, progress=progress,
                                 log=lambda *a: log("[sweep]   " + " ".join(str(x) for x in a)))
        if not summary["complete"]:
            raise RuntimeError(f"render of {out} did not complete: {summary}")
        render_s = time.perf_counter() - t0  # this invocation only (an interrupted earlier part is not counted)
        skipped = False
        counters.bump("rendered")
        if summary.get("skipped_sequences"):
            counters.bump("render_resumed")
        manifest = _read_json(out / "manifest.json")
        _write_json(out.parent / f"{overlap_key(overlap)}.status.json", {"config_hash": h, "render_s": render_s})
    ov = measured_overlap(manifest)
    log(f"[sweep] overlap {overlap:.2f}: target {ov['target']:.2f}, measured pixel overlap {ov['measured_mean']:.3f} "
        f"(mean of the {ov['pairs_at_target']}/{ov['pairs']} pairs at the target)")
    return {"overlap": overlap, "path": str(out), "config_hash": h, "render_s": render_s, "render_skipped": skipped,
            "measured": ov, "splits": {k: len(v) for k, v in manifest["splits"].items()}}


def reference_stage(cfg: SweepConfig, d: dict, sweep_dir: Path, counters: Counters, log) -> dict:
    """Evaluate the constant-depth reference on one overlap's test split (cached beside the dataset).

    The constant is the median ground-truth depth of the train split
    (`mcdp.evaluate.median_gt_depth`): a depth map with no structure at all. With median
    scaling its value does not matter (every image is scaled to its ground-truth median).
    A method worse than this reference has learnt no usable depth structure.
    """
    from mcdp.evaluate import constant_depth_predictor, evaluate, median_gt_depth
    from synth.dataset import open_dataset

    from mcdp.priors import flat_road_predictor

    o = d["overlap"]
    path = sweep_dir / "data" / f"{overlap_key(o)}.reference.json"
    key = config_hash({"data": d["config_hash"], "eval": config_to_dict(cfg.eval),
                       "reference": "constant_train_median+flat_road"})
    cached = _read_json(path)
    if cached is not None and cached.get("key") == key:
        counters.bump("reference_skipped")
        return cached["reference"], cached["prior"]
    ds = open_dataset(d["path"])
    ecfg = eval_config_for(cfg)
    t0 = time.perf_counter()
    depth = median_gt_depth(ds, "train", ecfg)
    metrics = evaluate(ds, constant_depth_predictor(ds, depth), SPLIT, ecfg, progress=False)
    ref = {"kind": "constant depth = median ground-truth depth of the train split", "depth_m": depth,
           "metrics": summarize_metrics(metrics), "eval_s": time.perf_counter() - t0}
    t0 = time.perf_counter()
    metrics = evaluate(ds, flat_road_predictor(ds, depth), SPLIT, ecfg, progress=False)
    prior = {"kind": "flat-road prior: road-plane depth from the rig geometry, capped at the constant", "far_m": depth,
             "metrics": summarize_metrics(metrics), "eval_s": time.perf_counter() - t0}
    _write_json(path, {"key": key, "reference": ref, "prior": prior})
    counters.bump("reference_evaluated")
    for name, r in (("constant-depth reference", ref), ("flat-road prior", prior)):
        log(f"[sweep] overlap {o:.2f}: {name} ({depth:.2f} m): abs_rel metric "
            f"{r['metrics']['none']['mean']['abs_rel']:.4f}, median {r['metrics']['median']['mean']['abs_rel']:.4f}, "
            f"dep_con {r['metrics']['dep_con']['mean']:.4f}")
    return ref, prior


def pretrain_stage(cfg: SweepConfig, sweep_dir: Path, progress: bool, log) -> dict | None:
    """Make (or reuse) the sweep's shared pretraining; its record with ``weights`` (the path runs start from)."""
    if cfg.pretrain is None:
        return None
    from mcdp.pretrain import WEIGHTS, resolved_configs, run_pretrain

    _, _, h = resolved_configs(cfg.pretrain)
    pdir = sweep_dir / "pretrain" / h[:12]
    rec = run_pretrain(cfg.pretrain, pdir, progress=progress, log=log)
    return {"weights": str(pdir / WEIGHTS), "config_hash": h, "sha256": rec["sha256"], "step": rec["step"],
            "render_s": rec.get("render_s"), "train_s": rec.get("train_s"), "depth_spread": rec.get("depth_spread")}


def _eval_key(run_hash: str, step: int, eval_cfg: dict, data_hash: str, checkpoint: str, ckpt_name: str) -> str:
    return config_hash({"run": run_hash, "step": step, "eval": eval_cfg, "data": data_hash, "checkpoint": checkpoint,
                        "file": ckpt_name})


def run_stage(cfg: SweepConfig, overlap: float, data: dict, method: str, seed: int, sweep_dir: Path,
              counters: Counters, log, progress: bool, init_from: str | None = None) -> dict:
    """Train (or reuse / resume) and evaluate one (overlap, method, seed); returns its result row."""
    from mcdp.evaluate import evaluate
    from mcdp.predict import Predictor
    from mcdp.runs import RunError
    from mcdp.trainer import Trainer, TrainingDiverged
    from synth.dataset import open_dataset

    rcfg, preset = run_config_for(cfg, method, seed, init_from)
    rhash = config_hash(rcfg)
    run_dir = sweep_dir / "runs" / overlap_key(overlap) / f"{method}_s{seed}"
    status_path = run_dir / STATUS
    status = _read_json(status_path) or {}
    tag = f"[sweep] overlap {overlap:.2f} {method} seed {seed}"
    row: dict[str, Any] = {"overlap": overlap, "method": method, "seed": seed, "run_dir": str(run_dir),
                           "preset": str(preset), "run_config_hash": rhash, "status": "ok"}
    ds = open_dataset(data["path"])

    # ---- train
    if status.get("trained") and status.get("run_config_hash") == rhash and status.get("data_hash") == data["config_hash"]:
        counters.bump("train_skipped")
        row.update(train_s=status.get("train_s", float("nan")), train_skipped=True, steps=status.get("steps"))
        log(f"{tag}: trained already ({status.get('steps')} steps), skipped")
    else:
        if status.get("data_hash") not in (None, data["config_hash"]):
            raise ConfigError(f"{run_dir} was trained on another dataset; delete it or use a new --out")
        if status.get("last_removed") and not (run_dir / "checkpoints" / "last.pt").exists():
            raise ConfigError(f"{run_dir}: the resolved config of {method} changed since this run was trained, and "
                              "its checkpoints/last.pt was removed after evaluation (keep_last: false), so it "
                              f"cannot resume; delete {run_dir} to retrain it, or use a new --out")
        t0 = time.perf_counter()
        try:
            trainer = Trainer(rcfg, ds, run_dir, progress=progress)
        except RunError as exc:
            raise RunError(f"{exc}\n(sweep: the resolved config of {method} changed since this run was trained, "
                           f"through the sweep preset, its overrides or new code defaults; delete {run_dir} "
                           "to retrain it, or use a new --out)") from None
        resumed_at = trainer.step
        log(f"{tag}: training {rcfg.train.steps} steps"
            + (f" (resuming at step {resumed_at})" if resumed_at else "") + f" -> {run_dir}")
        try:
            summary = trainer.train()
        except TrainingDiverged as exc:
            log(f"{tag}: TRAINING DIVERGED: {exc}")
            counters.bump("diverged")
            _write_json(status_path, {**status, "run_config_hash": rhash, "data_hash": data["config_hash"],
                                      "trained": False, "diverged": str(exc)})
            row.update(status="diverged", error=str(exc), train_s=time.perf_counter() - t0, train_skipped=False)
            return row
        finally:
            trainer.close()
        train_s = time.perf_counter() - t0  # this invocation only (an interrupted earlier part is not counted)
        counters.bump("trained")
        if resumed_at:
            counters.bump("train_resumed")
        status = {"run_config_hash": rhash, "data_hash": data["config_hash"], "trained": True,
                  "steps": summary["steps"], "train_s": train_s, "best_val": summary["best_val"]}
        _write_json(status_path, status)
        row.update(train_s=train_s, train_skipped=False, steps=summary["steps"])

    # ---- eval
    metrics_path = run_dir / f"metrics_{SPLIT}.json"
    ecfg = eval_config_for(cfg)
    pred = None
    from mcdp.runs import find_checkpoint

    ckpt_path = find_checkpoint(run_dir, cfg.checkpoint)
    key = _eval_key(rhash, int(status.get("steps", -1)), config_to_dict(cfg.eval), data["config_hash"],
                    cfg.checkpoint, ckpt_path.name)
    metrics = _read_json(metrics_path)
    if metrics is not None and metrics.get("sweep", {}).get("eval_key") == key and status.get("eval_key") == key:
        counters.bump("eval_skipped")
        row.update(eval_s=status.get("eval_s", float("nan")), eval_skipped=True)
        log(f"{tag}: evaluated already, skipped")
    else:
        t0 = time.perf_counter()
        pred = Predictor(run_dir, ds, cfg.checkpoint, cfg.device)
        log(f"{tag}: evaluating {pred.ckpt_path.name} (step {pred.step}) on the {SPLIT} split")
        metrics = evaluate(ds, pred.predict, SPLIT, ecfg, progress=progress)
        metrics["run"] = {"run_dir": str(run_dir), "checkpoint": str(pred.ckpt_path), "step": pred.step,
                          "method": pred.cfg.model.method, "refine_steps": pred.cfg.model.refine_steps,
                          "bases": pred.cfg.model.n_out, "consistency_weight": pred.cfg.loss.consistency_weight,
                          "scale_source": pred.cfg.scale.source, "oracle": pred.oracle, "data": data["path"],
                          "config": config_to_dict(pred.cfg)}
        metrics["sweep"] = {"eval_key": key, "overlap": overlap, "method": method, "seed": seed}
        _write_json(metrics_path, metrics)
        eval_s = time.perf_counter() - t0
        status = {**status, "eval_key": key, "eval_s": eval_s, "checkpoint": str(pred.ckpt_path),
                  "checkpoint_step": pred.step}
        _write_json(status_path, status)
        counters.bump("evaluated")
        row.update(eval_s=eval_s, eval_skipped=False)
    if not cfg.keep_last:
        status = _remove_last(run_dir, status, status_path)
    row["checkpoint"] = status.get("checkpoint")
    row["checkpoint_step"] = status.get("checkpoint_step")
    row["oracle"] = bool(metrics.get("run", {}).get("oracle", False))
    row["metrics"] = summarize_metrics(metrics)
    m = row["metrics"]
    log(f"{tag}: abs_rel metric {m['none']['mean']['abs_rel']:.4f}, median {m['median']['mean']['abs_rel']:.4f}, "
        f"dep_con {m['dep_con']['mean']:.4f}")
    return row


def _remove_last(run_dir: Path, status: dict, status_path: Path) -> dict:
    """keep_last=false: delete last.pt of a trained run whose evaluated checkpoint is best.pt."""
    last, best = run_dir / "checkpoints" / "last.pt", run_dir / "checkpoints" / "best.pt"
    evaluated = Path(status.get("checkpoint") or "")
    if status.get("trained") and last.is_file() and best.is_file() and evaluated.resolve() == best.resolve():
        status = {**status, "last_removed": True}
        _write_json(status_path, status)  # first: an interruption between the two leaves a last.pt, not a lie
        last.unlink()
    return status


# --------------------------------------------------------------------------- driver
def run_sweep(cfg: SweepConfig, out: str | Path, progress: bool = True, log: Callable[[str], None] | None = None,
              config_source: str | None = None) -> dict:
    """Run (or resume) a whole sweep into `out`; writes the report; returns the results dict.

    The returned dict (also ``out/results.json``) holds ``counters`` (rendered,
    render_skipped, trained, train_skipped, train_resumed, evaluated, eval_skipped,
    diverged), ``data`` (per overlap), ``rows`` (per overlap x method x seed),
    ``aggregate`` (mean/std over seeds) and ``timing``.
    """
    from corelib.rundir import claim

    log = log or (lambda s: print(s, file=sys.stderr, flush=True))
    out = Path(out)
    lock = claim(out, "sweep", legacy=("sweep_config.yaml",))
    try:
        return _run_sweep(cfg, out, progress, log, config_source)
    finally:
        lock.release()


def _run_sweep(cfg: SweepConfig, out: Path, progress: bool, log, config_source: str | None) -> dict:
    from mcdp import report

    resolved = config_to_dict(cfg)
    prev = out / "sweep_config.yaml"
    if prev.is_file():
        old = (yaml.safe_load(prev.read_text()) or {}).get("config")
        if old is not None and old != resolved:
            from corelib.configlib import diff_configs

            log(f"[sweep] note: the sweep config differs from the saved one in: {', '.join(diff_configs(old, resolved))}; "
                "datasets/runs are reused only where their own resolved config is unchanged")
    prev.write_text(yaml.safe_dump({"config": resolved, "config_hash": config_hash(cfg), "source": config_source},
                                   sort_keys=False))
    n_runs = len(cfg.overlaps) * len(cfg.methods) * len(cfg.seeds)
    log(f"[sweep] {len(cfg.overlaps)} overlap(s) {', '.join(f'{o:.2f}' for o in cfg.overlaps)} ({cfg.overlap_mode}), "
        f"methods {', '.join(cfg.methods)}, seeds {cfg.seeds}: {n_runs} run(s) -> {out}")
    counters = Counters(rendered=0, render_skipped=0, render_resumed=0, trained=0, train_skipped=0, train_resumed=0,
                        evaluated=0, eval_skipped=0, diverged=0, reference_evaluated=0, reference_skipped=0)
    t_start = time.perf_counter()
    pre = pretrain_stage(cfg, out, progress, log)
    init_from = pre["weights"] if pre else None
    data = [render_stage(cfg, o, out, counters, log, progress) for o in cfg.overlaps]
    for d in data:
        d["reference"], d["prior"] = reference_stage(cfg, d, out, counters, log)
    todo = [(d, method, seed) for d in data for method in cfg.methods for seed in cfg.seeds]
    if cfg.jobs == 1 or len(todo) == 1:
        rows = [run_stage(cfg, d["overlap"], d, method, seed, out, counters, log, progress, init_from)
                for d, method, seed in todo]
    else:
        rows = _run_parallel(cfg, todo, out, counters, log, init_from)
    previews = []
    if cfg.preview:
        previews = _previews(data, out, log)
    total_s = time.perf_counter() - t_start
    results = report.build_results(cfg, data, rows, dict(counters), total_s, previews)
    results["pretrain"] = pre
    report.write_all(results, out)
    log(f"[sweep] done in {total_s:.1f} s: " + ", ".join(f"{k}={v}" for k, v in counters.items()))
    log(f"[sweep] report: {out / 'report.md'}")
    return results


def _stage_job(cfg: SweepConfig, d: dict, method: str, seed: int, out: Path, init_from: str | None) -> tuple[dict, dict]:
    """One run in a worker process (``jobs`` > 1): no progress bars, log lines to stderr."""
    counters = Counters()
    row = run_stage(cfg, d["overlap"], d, method, seed, out, counters,
                    lambda s: print(s, file=sys.stderr, flush=True), False, init_from)
    return row, dict(counters)


def _run_parallel(cfg: SweepConfig, todo: list, out: Path, counters: Counters, log,
                  init_from: str | None = None) -> list[dict]:
    """Run the (overlap, method, seed) stages ``cfg.jobs`` at a time in spawned processes.

    Rows come back in the order of `todo` (the table order) whatever finishes first; the
    first failure (other than a diverged run, which is a row) stops the sweep after the
    running jobs end, and a rerun resumes from what finished.
    """
    import multiprocessing as mp
    from concurrent.futures import ProcessPoolExecutor

    log(f"[sweep] {len(todo)} run(s), {cfg.jobs} at a time (one process each; progress bars off)")
    rows: list[dict | None] = [None] * len(todo)
    with ProcessPoolExecutor(max_workers=cfg.jobs, mp_context=mp.get_context("spawn")) as pool:
        futures = [pool.submit(_stage_job, cfg, d, method, seed, out, init_from) for d, method, seed in todo]
        try:
            for i, fut in enumerate(futures):
                row, c = fut.result()
                rows[i] = row
                for k, v in c.items():
                    counters[k] = counters.get(k, 0) + v
        except BaseException:
            for f in futures:
                f.cancel()
            raise
    return rows  # type: ignore[return-value]


def _previews(data: list[dict], out: Path, log) -> list[str]:
    from synth.dataset import open_dataset
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


# --------------------------------------------------------------------------- CLI
def add_sweep_parser(subparsers) -> argparse.ArgumentParser:
    """Add the ``sweep`` subcommand to an argparse subparsers object; returns its parser."""
    p = subparsers.add_parser(
        "sweep", help="render + train + eval every method over camera overlaps -> report",
        description="render + train + eval every method over camera overlaps -> report.md, results.csv/json, plots")
    p.add_argument("preset", help="sweep preset YAML, e.g. configs/sweep/ci.yaml")
    p.add_argument("--out", required=True, help="sweep folder; a rerun resumes and skips finished work")
    p.add_argument("--no-progress", action="store_true", help="no progress bars (log lines only)")
    p.add_argument("overrides", nargs="*",
                   help="sweep config overrides key=value, e.g. 'overlaps=[0.2,0.5]' seeds=[0,1] "
                        "'train_overrides=[train.steps=100]'")
    p.set_defaults(_run=run_sweep_command)
    _allow_intermixed(p)
    return p


def _allow_intermixed(p: argparse.ArgumentParser) -> None:
    """Let ``key=value`` overrides come after ``--out`` (``PRESET --out DIR a=b``).

    Plain argparse binds the optional ``overrides`` positional (nargs='*') to an empty
    list together with PRESET and then rejects later positionals as unrecognised;
    ``parse_known_intermixed_args`` does not, but refuses parsers with subcommands, so it
    is switched on for this (leaf) subparser only, which its parent calls through
    ``parse_known_args``. The guard sends the intermixed parser's own inner calls to the
    original method.
    """
    orig = p.parse_known_args
    state = {"inner": False}

    def parse_known_args(args=None, namespace=None):
        if state["inner"]:
            return orig(args, namespace)
        state["inner"] = True
        try:
            return p.parse_known_intermixed_args(args, namespace)
        finally:
            state["inner"] = False

    p.parse_known_args = parse_known_args


def run_sweep_command(args: argparse.Namespace) -> int:
    """Run the ``sweep`` subcommand; 0 on success, 3 if some run diverged (the report says which)."""
    preset = resolve_path(args.preset, "sweep preset")
    cfg = load_sweep_config(preset, args.overrides)
    results = run_sweep(cfg, args.out, progress=not args.no_progress,
                        config_source=str(preset) + (" + " + " ".join(args.overrides) if args.overrides else ""))
    return 3 if results["counters"].get("diverged") else 0


def main(argv: list[str] | None = None) -> int:
    """Stand-alone entry (``python -m mcdp.sweep PRESET --out SWEEP``), same as ``mcdp sweep``."""
    parser = argparse.ArgumentParser(prog="mcdp")
    sub = parser.add_subparsers(dest="command", required=True)
    add_sweep_parser(sub)
    try:
        args = parser.parse_args(["sweep"] + list(sys.argv[1:] if argv is None else argv))
    except SystemExit as exc:
        return int(exc.code or 0)
    from mcdp.networks import NetworkError
    from mcdp.runs import RunError
    from synth.dataset import DatasetError
    from synth.render import OutputFolderError

    try:
        return run_sweep_command(args)
    except (ConfigError, DatasetError, RunError, NetworkError, OutputFolderError) as exc:
        print(f"mcdp sweep: error: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print("mcdp sweep: interrupted (rerun the same command to resume)", file=sys.stderr)
        return 130


if __name__ == "__main__":
    sys.exit(main())
