"""``mcdp train``: a preset (optionally under a registered method's row: ``--method``), overrides, then a run
folder trained (resumed when it holds a checkpoint); the command line of `mcdp.trainer.Trainer`."""
from __future__ import annotations

import argparse
from pathlib import Path

from corelib.atomic import check_writable
from study.command_common import add_print_config, open_dataset, outside_datasets, print_config, require


def train_arguments(p: argparse.ArgumentParser) -> None:
    from corelib.presets import complete_presets

    complete_presets(p.add_argument("preset", help="training preset YAML, e.g. configs/train/mcdp_m1.yaml (list: mcdp "
                                    "presets train)"), "train")
    p.add_argument("--method", help="a registered method (mcdp/methods/__init__.py) whose row's config values go "
                   "under the preset, e.g. configs/train/tiny/base.yaml --method mcdp_m2 (a method needs no preset "
                   "of its own)")
    p.add_argument("--data", help="dataset folder (synth render output); required unless --print-config")
    p.add_argument("--out", help="run folder; training resumes if it holds checkpoints/last.pt; required unless "
                   "--print-config")
    p.add_argument("--no-progress", action="store_true", help="no progress bar")
    add_print_config(p)
    p.add_argument("overrides", nargs="*", help="config overrides key=value, e.g. train.steps=100 model.bases=16")


#: what `mcdp train` says when a method with bases starts without a pretraining (README, "Training on a CPU")
NO_INIT_WARNING = ("mcdp train: warning: model.method={method} (a network with bases) starts from scratch: without "
                   "model.init_from it tends to collapse to a constant depth; pretrain first (mcdp pretrain "
                   "configs/pretrain/tiny.yaml --out pretrain/tiny) and pass model.init_from=pretrain/tiny/pretrained.pt")


#: what `mcdp train` says when the dataset's val split holds no rig sample (`synth render` warned of it)
NO_VAL_WARNING = ("mcdp train: warning: {data} has no val rig sample (an empty val split): no validation loss and no "
                  "checkpoints/best.pt; checkpoints/last.pt is the result (render 3 or more dataset.sequences)")


def method_row_defaults(name: str | None) -> dict | None:
    """The config values of registered method ``name`` (its row's defaults), None for no name; a ConfigError
    naming ``--method`` and the registered names for another."""
    from corelib.configlib import ConfigError
    from corelib.text import bounded
    from mcdp.methods import METHODS

    if name is None:
        return None
    if name not in METHODS:
        raise ConfigError(f"--method {bounded(name, 80)}: not a registered method (registered: {', '.join(METHODS)})")
    return dict(METHODS[name].defaults)


def train(args: argparse.Namespace) -> int:
    from mcdp.config import RunConfig
    from corelib.configlib import load_config
    from corelib.logs import logger
    from corelib.presets import preset_path

    row = method_row_defaults(args.method)
    cfg = load_config(RunConfig, preset_path(args.preset, "train"), args.overrides, base=row)  # before torch
    if row is not None and cfg.model.method != row["model.method"]:
        from corelib.configlib import ConfigError

        raise ConfigError(f"--method {args.method}: the preset sets model.method={cfg.model.method}, not this "
                          "method's; give a preset that names no method (configs/train/base.yaml, "
                          "configs/train/tiny/base.yaml)")
    if args.print_config:
        return print_config(cfg)
    require(args, "--data", "--out")
    outside_datasets(args.out)
    check_writable(Path(args.out) / "run.json")
    from mcdp.trainer import Trainer

    ds = open_dataset(args.data)
    trainer = Trainer(cfg, ds, args.out, progress=not args.no_progress)
    m, tc = cfg.model, cfg.train
    n_params = sum(p.numel() for p in trainer.depth.parameters())
    log = logger("mcdp.train")  # stderr and RUN/train.log (corelib.logs)
    say = log.info if trainer.dist.is_main else (lambda *a, **k: None)  # torchrun: rank 0 speaks
    ranks = f", {trainer.dist.world} ranks (torchrun; global batch)" if trainer.dist.enabled else ""
    say(
        f"mcdp train: method={m.method} bases={trainer.depth.n_out} refine_steps={m.refine_steps} "
        f"neighbours={m.neighbours} "
        f"lambda={cfg.loss.consistency_weight} scale={cfg.scale.source}"
        + (" [ORACLE: uses ground-truth median scale]" if cfg.scale.oracle else ""))
    say(
        f"  {len(ds.camera_names)} cameras, {len(trainer.train_set)} train / {len(trainer.val_set)} val rig samples, "
        f"{tc.height}x{tc.width}, batch {tc.batch_size}{ranks}, depth net {n_params / 1e6:.2f} M params, "
        f"device {trainer.device}, precision {tc.precision}"
        + (f", resuming at step {trainer.step}" if trainer.step else ""))
    if trainer.dist.is_main and trainer.step == 0 and m.init_from is None and trainer.depth.has_bases:
        log.warning(NO_INIT_WARNING.format(method=m.method))
    no_val = len(trainer.val_set) == 0
    if no_val and trainer.dist.is_main:
        log.warning(NO_VAL_WARNING.format(data=args.data))
    try:
        summary = trainer.train()
        val = "no val split, no best.pt" if no_val else f"best val loss {summary['best_val']:.4f}"
        say(f"mcdp train: step {summary['steps']} ({summary['trained']} this run), {val}, checkpoints in "
            f"{Path(args.out) / 'checkpoints'}")
    finally:
        trainer.close()
    return 0
