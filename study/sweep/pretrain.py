"""Shared self-supervised pretraining: this project's stand-in for the paper's ImageNet initialisation.

It renders a world of its own (`synth.render`) and trains on it (`mcdp.trainer`): orchestration, so it
lives here in the top layer, beside the sweep that uses it; the method library only reads its file
(`mcdp.warmstart`).

One monocular, self-supervised training (no ground truth, no cross-camera term) on
a world of its own (its data config has its own seed, so no street of it is in a
sweep's test split) trains an encoder and decoder trunk with two heads: n depth
bases (read at weights 1/n) and a one-channel Monodepth2 head (``model.mono_head``).
Every run of a sweep then starts from it (``model.init_from``, `mcdp.warmstart`):
mono2 from the mono head, every MCDP variant from the bases, so both methods start
from the same encoder and trunk trained for the same steps.

::

    mcdp pretrain configs/pretrain/tiny.yaml --out pretrain/tiny [key=value ...]

Layout of DIR::

    pretrain.json      resolved config, its hash, sha256 of pretrained.pt, code version (written last)
    pretrained.pt      {"format": "mcdp-pretrain", "version", "config_hash", "model", "depth_model", "step"}
    data/              the rendered pretraining world (synth contract v1)
    run/               the training run (checkpoints, tensorboard)

It is cached by its resolved config hash: a rerun with the same config returns at
once; a folder that holds another pretraining, or anything else, is refused. An
interrupted pretraining resumes (render and training both resume).
"""
from __future__ import annotations

import time
from pathlib import Path
from typing import Callable

from pydantic import Field

from corelib.atomic import atomic_write_json
from corelib.logs import logger
from corelib.readfile import read_json_file
from corelib.configlib import ConfigError, StrictModel, config_hash, config_to_dict, hashed_dict, load_config, resolve_path
from corelib.version import code_version, warn_other_code

MARKER = "pretrain.json"
WEIGHTS = "pretrained.pt"


class PretrainConfig(StrictModel):
    """A shared pretraining: its world (data preset + overrides) and its training (preset + overrides).

    data: data preset YAML; data_overrides: dotted overrides (give it its own ``seed``).
    train_preset: training preset with ``model.mono_head: true``; train_overrides: dotted overrides.
    workers: rendering processes.
    """

    data: str = "configs/data/tiny.yaml"
    data_overrides: list[str] = Field(default_factory=lambda: ["seed=1000"])
    train_preset: str = "configs/train/tiny/pretrain.yaml"
    train_overrides: list[str] = Field(default_factory=list)
    workers: int = Field(2, ge=1, le=256)


def resolved_configs(cfg: PretrainConfig, check_network: bool = True):
    """(DataConfig, RunConfig, hash) of a pretraining; the hash names what it learns from and how.
    ``check_network=False``: the configs only, not what the network needs of them (imports torch)."""
    from mcdp.config import RunConfig
    from mcdp.methods import check_model
    from synth.config import load_data_config

    dcfg = load_data_config(resolve_path(cfg.data, "data preset"), cfg.data_overrides)
    rcfg = load_config(RunConfig, resolve_path(cfg.train_preset, "training preset"), cfg.train_overrides)
    if check_network:
        check_model(rcfg.model)
    if not rcfg.model.mono_head:
        raise ConfigError(f"{cfg.train_preset}: a pretraining needs model.mono_head: true (both heads)")
    if rcfg.model.init_from is not None:
        raise ConfigError("model.init_from: a pretraining starts from scratch")
    if rcfg.scale.oracle:
        raise ConfigError("scale.source=oracle_gt_median reads ground truth; a pretraining must not")
    h = config_hash({"data": hashed_dict(dcfg), "run": hashed_dict(rcfg)})
    return dcfg, rcfg, h


def cached(out: Path, h: str) -> dict | None:
    """The record of a finished pretraining in ``out`` with hash ``h``, or None if there is none yet."""
    from corelib.hashing import sha256_file

    marker = out / MARKER
    if not marker.is_file():
        return None
    try:
        rec = read_json_file(marker, kind="record")
    except (OSError, ValueError):  # ValueError: corelib.readfile.ReadRefused (a link, a FIFO, not JSON)
        raise ConfigError(f"{marker} is unreadable; delete {out} to pretrain again") from None
    if rec.get("config_hash") != h:
        raise ConfigError(f"{out} holds another pretraining (config hash {str(rec.get('config_hash'))[:12]}, "
                          f"requested {h[:12]}); use a new --out or delete {out}")
    w = out / WEIGHTS
    if not w.is_file() or sha256_file(w) != rec.get("sha256"):
        raise ConfigError(f"{w} is missing or does not match its sha256 in {marker}; delete {out} to pretrain again")
    return rec


def run_pretrain(cfg: PretrainConfig, out: str | Path, progress: bool = True,
                 log: Callable[[str], None] | None = None) -> dict:
    """Render + train + export a pretraining into ``out`` (or return the cached one). Returns its record."""
    from corelib.rundir import claim

    log = log or logger("pretrain").info  # stderr (-q hides it) and, during a run, its train.log
    out = Path(out)
    dcfg, rcfg, h = resolved_configs(cfg)
    rec = cached(out, h)
    if rec is not None:
        log(f"[pretrain] {out}: pretraining {h[:12]} is complete (step {rec['step']}), reused")
        warn_other_code(f"pretraining {out}", rec.get("code_version"), lambda line: log(f"[pretrain] {line}"))
        return rec
    lock = claim(out, "pretrain", legacy=("pretrain.config.json",))
    try:
        return _pretrain(cfg, out, dcfg, rcfg, h, progress, log)
    finally:
        lock.release()


def _pretrain(cfg: PretrainConfig, out: Path, dcfg, rcfg, h: str, progress: bool, log) -> dict:
    import torch

    from mcdp.runs import atomic_torch_save
    from mcdp.trainer import Trainer
    from corelib.hashing import sha256_file
    from mcdp.warmstart import FORMAT, VERSION
    from synth.open import open_dataset
    from synth.render import render_dataset

    started = out / "pretrain.config.json"
    if started.is_file() and read_json_file(started, kind="record").get("config_hash") != h:
        raise ConfigError(f"{out} holds an unfinished pretraining with another config; use a new --out "
                          f"or delete {out}")
    resolved = {"pretrain": config_to_dict(cfg), "data": config_to_dict(dcfg), "run": config_to_dict(rcfg)}
    atomic_write_json(out / "pretrain.config.json", {"config_hash": h, "config": resolved})
    t0 = time.perf_counter()
    log(f"[pretrain] rendering {dcfg.dataset.sequences} sequences x {dcfg.dataset.frames} frames "
        f"(seed {dcfg.seed}) into {out / 'data'}")
    summary = render_dataset(dcfg, out / "data", workers=cfg.workers, progress=progress,
                             log=lambda *a: log("[pretrain]   " + " ".join(str(x) for x in a)))
    if not summary["complete"]:
        raise RuntimeError(f"render of {out / 'data'} did not complete: {summary}")
    render_s = time.perf_counter() - t0
    ds = open_dataset(str(out / "data"))
    t1 = time.perf_counter()
    log(f"[pretrain] training {rcfg.train.steps} steps ({rcfg.model.bases} bases + mono head) -> {out / 'run'}")
    trainer = Trainer(rcfg, ds, out / "run", progress=progress)
    try:
        trainer.train()
    finally:
        trainer.close()
    train_s = time.perf_counter() - t1
    # the last state, not best.pt: the val loss of a monocular run says little about which
    # step transfers best, and the last state is what "pretrained for N steps" means
    state = {"format": FORMAT, "version": VERSION, "config_hash": h, "model": config_to_dict(rcfg.model),
             "depth_model": trainer.depth.state_dict(), "step": trainer.step}
    atomic_torch_save(state, out / WEIGHTS)
    rec = {"config_hash": h, "sha256": sha256_file(out / WEIGHTS), "path": str((out / WEIGHTS).resolve()),
           "step": trainer.step, "render_s": render_s, "train_s": train_s,
           "depth_spread": trainer.spread, "config": resolved, "code_version": code_version(),
           # the kernels torch dispatched to (AVX2 / AVX512 / ...): the same config and code give other weights
           # on a CPU of another kind, so two pretrainings with one config hash can differ (issue 47)
           "cpu_capability": torch.backends.cpu.get_cpu_capability()}
    atomic_write_json(out / MARKER, rec)
    log(f"[pretrain] done: {out / WEIGHTS} (step {trainer.step}, render {render_s:.0f} s, train {train_s:.0f} s)")
    return rec


def load_pretrain_config(path: str | Path | None, overrides=()) -> PretrainConfig:
    return load_config(PretrainConfig, path, overrides)


def _join(names: list[str]) -> str:
    return names[0] if len(names) == 1 else ", ".join(names[:-1]) + " and " + names[-1]


def weights_in_sweep(path: str) -> str:
    """A pretraining's weights file as a path inside its sweep folder (``pretrain/<hash>/pretrained.pt``): a report
    names no machine's absolute path (results.json of older sweeps records the absolute one)."""
    parts = Path(path).parts
    return "/".join(parts[len(parts) - 1 - parts[::-1].index("pretrain"):]) if "pretrain" in parts else path


def warm_start_line(methods: list[str], configs: dict | None = None) -> str:
    """Which part of the shared pretraining each of the sweep's methods starts from (`mcdp.warmstart`: a
    network with bases takes the n basis channels, one without them the mono head) and which of their
    layers start fresh (the pretraining has neither MCDP's weight networks nor SurroundDepth's cross-view
    blocks), naming only the sweep's own methods (all registered). Read from each network's declared members
    (``has_bases``, ``fresh_layers``), never from its name, at each method's run config (``configs``:
    `study.results.recorded.run_configs`; by default the registry's defaults). The report's setup line (`study.report.compose`)."""
    from mcdp.methods import METHODS, label, model_config, network_class

    mono, bases, fresh = [], [], []
    for m in methods:
        net = network_class(METHODS[m])  # the network's class: what it is made of, not what it is called
        (bases if net.has_bases else mono).append(label(m))
        layers = net.fresh_layers((configs or {}).get(m) or model_config(METHODS[m]))
        if layers:
            fresh.append(f"{label(m)}'s {layers}")
    parts = []
    if mono:
        parts.append(f"{_join(mono)} start{'s' if len(mono) == 1 else ''} from its mono head")
    if bases:
        verb = "" if mono else ("starts " if len(bases) == 1 else "start ")  # after the mono clause, implied
        parts.append(f"{_join(bases)} {verb}from its basis channels")
    if fresh:
        parts.append(f"{_join(fresh)} start fresh")
    return "; ".join(parts)
