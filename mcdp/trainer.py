"""Self-supervised training of MCDP and its Monodepth2 baseline on a synth dataset.

One step follows Monodepth2's stages: ``process_batch -> predict_poses ->
compute_losses`` (the warps of ``generate_images_pred`` are made inside the
loss loop so that no stage keeps all its warped images alive).

The loss (paper eq. 9) is specified in `mcdp.system`'s module docstring, beside the step that
computes it.

Guards: a NaN/inf loss or gradient (before the update) or validation loss stops
training with `TrainingDiverged` naming the step (checkpoints stay the last finite
state); the depth's spread (`mcdp.diagnostics`) is logged and a collapse to a
constant or to a bound of the depth range is warned about, naming the step.
A fresh run may start from a shared pretraining (``model.init_from``, `mcdp.warmstart`).

Model selection uses the val split only and no ground truth: every
``train.val_every`` steps the final stage's L_p + lambda L_con on fixed val
samples is measured and the lowest is kept as ``checkpoints/best.pt``.

The run folder it writes (config.yaml, run.json, checkpoints/, tensorboard/, train.log) is described once, in
`mcdp.runs`; a checkpoint's writer and reader sit side by side there and in `mcdp.checkpoint_files`, the guards
(collapse, divergence, fp16 skips) in `mcdp.diagnostics`.

Example::

    mcdp train configs/train/tiny/mcdp_m1.yaml --data data/tiny --out runs/m1
"""
from __future__ import annotations

import math
import time
from pathlib import Path

import torch
import yaml

from corelib.atomic import atomic_write_text
from corelib.configlib import config_to_dict
from corelib.logs import close_run_log, logger, run_log
from corelib.rundir import FolderError, claim
from corelib.version import warn_other_code
from mcdp.config import RunConfig
from mcdp.data import RigDataset, step_loader
from mcdp.diagnostics import (CollapseGuard, SkipGuard, TrainingDiverged,  # noqa: F401 (imported from here too)
                              gradient_divergence, loss_divergence)
from mcdp.distributed import Dist
from mcdp.inputs import RigBatch
from mcdp.logger import TrainLogger
from mcdp.checkpoint_files import write_checkpoint
from mcdp.methods import check_run
from mcdp.runs import (RunError, check_resume, checkpoint_record, non_finite, resolve_device, resolve_precision,
                       restore_checkpoint, write_run_record)
from mcdp.system import SelfSupervisedSystem
from mcdp.validation import val_indices, validation_loss
from mcdp.warmstart import warm_start

log = logger("mcdp.train")


class Trainer:
    """Builds networks, data and optimiser for one run; `train()` runs to ``cfg.train.steps``.

    Args:
        cfg: resolved RunConfig.
        ds: opened `synth.dataset` dataset.
        run_dir: output folder (created); resumes from ``run_dir/checkpoints/last.pt``
            if present (``check_resume`` first, so conflicting configs are refused).
        progress: tqdm progress bar.
        tensorboard: write TensorBoard logs.
    """

    def __init__(self, cfg: RunConfig, ds, run_dir: str | Path, progress: bool = True, tensorboard: bool = True):
        self.cfg = cfg
        self.ds = ds
        self.run_dir = Path(run_dir)
        self.progress = progress
        self.log = TrainLogger(None)
        check_run(cfg, len(ds.camera_names))  # a rig the network cannot take: refused before the folder is made
        self.dist = Dist.from_env()  # torchrun's ranks, or one process
        self._lock = self._log_file = None
        try:
            self.device = self.dist.start(resolve_device(cfg.train.device))
            # the run folder is ours (marker) and ours alone (flock) before anything is read or written;
            # under torchrun rank 0 holds it and alone writes it, and every rank learns if it could not
            refused = None
            if self.dist.is_main:
                try:
                    self._lock = claim(self.run_dir, "run", legacy=("run.json", "checkpoints"))
                except (FolderError, OSError) as exc:  # OSError: a folder that cannot be written
                    refused = exc
            if self.dist.any_true(refused is not None, self.device):
                raise refused or FolderError(f"{self.run_dir}: rank 0 could not claim the run folder (its message "
                                             "says why)")
            self._setup(cfg, ds, tensorboard)
        except BaseException:
            self.close()
            raise

    def _setup(self, cfg: RunConfig, ds, tensorboard: bool) -> None:
        tc = cfg.train
        ckpt = check_resume(self.run_dir, cfg)
        if ckpt is not None and list(ckpt.get("cameras", ds.camera_names)) != list(ds.camera_names):
            raise RunError(
                f"{self.run_dir} was trained on cameras {ckpt['cameras']}, dataset {ds.root} has "
                f"{list(ds.camera_names)}; use a new --out folder"
            )
        self._threads_before = torch.get_num_threads()
        if tc.threads > 0 and self.device.type == "cpu":
            torch.set_num_threads(tc.threads)

        torch.manual_seed(tc.seed)
        self.system = SelfSupervisedSystem(cfg, ds.neighbours, len(ds.camera_names)).to(self.device)
        self.depth, self.pose = self.system.depth, self.system.pose
        groups = self.system.param_groups(tc.weight_lr_mult)  # the fresh layers learn at a rate of their own
        # fused: one kernel for all parameters (CPU and CUDA); ~7x faster than the per-tensor loop on
        # a CPU, the same update to float rounding (docs/results/train_step.md)
        fused = self.device.type in ("cpu", "cuda")
        self.optimizer = torch.optim.Adam(groups, lr=tc.lr, betas=(0.9, 0.999), fused=fused)

        fields = self.system.fields  # the optional inputs its network reads (e.g. ORACLE-local's ground truth)
        self.train_set = RigDataset(ds, "train", tc.height, tc.width, fields, sync=cfg.model.sync,
                                    lens=cfg.model.lens)
        if len(self.train_set) == 0:
            raise RunError(f"dataset {ds.root}: the train split has no rig sample (sequences need >= 3 frames)")
        self.val_set = RigDataset(ds, "val", tc.height, tc.width, fields, sync=cfg.model.sync,
                                  lens=cfg.model.lens)

        self.use_amp, self.amp_dtype = resolve_precision(tc.precision, self.device)
        self.scaler = torch.amp.GradScaler("cuda", enabled=self.use_amp and self.amp_dtype == torch.float16)
        self.system.use_amp, self.system.amp_dtype = self.use_amp, self.amp_dtype
        self.system.shard = (self.dist.rank, self.dist.world)
        if tc.batch_size % self.dist.world:
            raise RunError(f"train.batch_size={tc.batch_size} is the global batch and must be a multiple of the "
                           f"{self.dist.world} torchrun ranks")
        self.ddp = None
        if self.dist.enabled:
            from torch.nn.parallel import DistributedDataParallel

            # every parameter reaches the loss (the pose network exists only when it is used)
            self.ddp = DistributedDataParallel(self.system, device_ids=[self.device] if self.device.type == "cuda"
                                               else None)

        self.init_from: dict | None = None
        if ckpt is None and cfg.model.init_from is not None and cfg.model.warm_start:  # warm_start false: scratch
            self.init_from = warm_start(self.depth, cfg.model.init_from)
        self.step = 0
        self.skip_guard = SkipGuard()
        self.spread: dict = {}
        self.collapse_guard = CollapseGuard()
        self.best_val = math.inf
        self.val_history: list[tuple[int, float]] = []
        if ckpt is not None:
            self._restore(ckpt)
        if not self.dist.is_main:
            return  # rank 0 writes the run folder and the logs
        self.run_dir.mkdir(parents=True, exist_ok=True)
        (self.run_dir / "checkpoints").mkdir(exist_ok=True)
        self._log_file = run_log(self.run_dir / "train.log")
        config_text = yaml.safe_dump(config_to_dict(cfg), sort_keys=False)
        atomic_write_text(self.run_dir / "config.yaml", config_text)
        write_run_record(self.run_dir, ds, self.step, cfg.scale.oracle, self.init_from, log.warning)  # another dataset: said
        self.log = TrainLogger(self.run_dir / "tensorboard" if tensorboard else None)
        self.log.text("config", config_text, self.step)

    # ------------------------------------------------------------------ state
    def state(self) -> dict:
        """What checkpoints/last.pt holds (`mcdp.runs.checkpoint_record`, beside the reader of the format)."""
        return checkpoint_record(self.step, self.cfg, self.depth, self.pose, self.optimizer, self.scaler, self.ds,
                                 best_val=self.best_val, val_history=self.val_history, spread=self.spread,
                                 init_from=self.init_from, world_size=self.dist.world)

    def save_checkpoint(self, name: str = "last.pt", weights_only: bool = False) -> Path:
        """Atomically write ``checkpoints/<name>``, its sha256 recorded (`mcdp.checkpoint_files.write_checkpoint`);
        `weights_only` drops optimiser/scaler/RNG state. Under torchrun only rank 0 writes (every rank holds the
        same weights)."""
        if not self.dist.is_main:
            return self.run_dir / "checkpoints" / name
        for key, net in (("depth_model", self.depth), ("pose_model", self.pose)):
            bad = non_finite(net.state_dict()) if net is not None else None
            if bad is not None:  # a checkpoint is written with finite weights only: `_last_good` says so
                raise TrainingDiverged(f"{key}.{bad[0]} holds {bad[1]} non-finite value(s) at step {self.step}; "
                                       f"{name} not written" + self._last_good()
                                       + "; try a lower train.lr or train.grad_clip=1.0")
        return write_checkpoint(self.run_dir, name, self.state(), self.step, weights_only)

    def _restore(self, ckpt: dict) -> None:
        """Resume from last.pt (`mcdp.runs.restore_checkpoint`, beside its writer and reader)."""
        if self.dist.is_main:  # a run resumed by other code: one warning line (corelib.version)
            warn_other_code(f"checkpoint {self.run_dir / 'checkpoints' / 'last.pt'}",
                            ckpt.get("code_version"), log.warning)
        rest = restore_checkpoint(ckpt, self.depth, self.pose, self.optimizer, self.scaler,
                                  source=str(self.run_dir / "checkpoints" / "last.pt"))
        self.step, self.best_val, self.val_history = rest["step"], rest["best_val"], rest["val_history"]
        self.spread, self.init_from = rest["spread"], rest["init_from"]
        if rest["world_size"] != self.dist.world and self.dist.is_main:
            # exact in what is trained: batches and augmentation are functions of the step, and the
            # global batch is the same; only the split of each batch over processes changes
            log.info(f"mcdp train: resuming a run trained on {rest['world_size']} process(es) with {self.dist.world}: "
                     "the same global batches; numbers differ as an N-rank run differs from a 1-process one "
                     "(per-rank BatchNorm statistics)")

    # ------------------------------------------------------------------ schedule
    def lr_at(self, step: int) -> float:
        tc = self.cfg.train
        return tc.lr * (tc.lr_decay_factor if step >= int(tc.lr_decay_at * tc.steps) else 1.0)

    def to_device(self, batch: RigBatch) -> RigBatch:
        return batch.to(self.device, non_blocking=True)

    # ------------------------------------------------------------------ validation
    def val_indices(self) -> list[int]:
        return val_indices(len(self.val_set), self.cfg.train.val_samples)

    @torch.no_grad()
    def validate(self) -> float | None:
        """Final-stage L_p + lambda L_con on fixed val samples (no ground truth); None without a val split.
        With ground truth in the dataset, the same samples' depth metrics go to TensorBoard (`mcdp.validation`)."""
        idx = self.val_indices()
        if not idx:
            return None
        scored = self.ds.has_depth and self.dist.is_main and self.log.enabled  # ground truth for TensorBoard only
        loss, depth = validation_loss(self.system, self.val_set, idx, self.step, self.dist, self.device,
                                      (self.ds, self.cfg.eval) if scored else None)
        if depth:
            self.log.scalars({f"val/depth_{k}": v for k, v in depth.items()}, self.step)
        return loss

    # ------------------------------------------------------------------ logging
    def check_spread(self, outputs: dict, mask: torch.Tensor) -> dict:
        """Spread of the final stage's depth on this batch (`mcdp.diagnostics.CollapseGuard`); warns once per collapse."""
        m = self.cfg.model
        depth = outputs["depth", self.depth.stages[-1], 0]
        self.spread, warn = self.collapse_guard.check(depth, mask, m.min_depth, m.max_depth, self.step)
        if warn is not None and self.dist.is_main:
            log.warning(f"mcdp train: WARNING step {self.step}: depth collapsed: {warn}")
        self.log.scalars({f"depth_spread/{k}": self.spread[k] for k in ("ratio", "at_min", "at_max")}, self.step)
        return self.spread

    def _last_good(self) -> str:
        last = self.run_dir / "checkpoints" / "last.pt"
        # "good" only as far as it was checked: every checkpoint is written with finite weights (`save_checkpoint`)
        return f"; the last checkpoint written (its weights finite when written) is {last}" if last.exists() else ""

    # ------------------------------------------------------------------ loop
    def train(self, until: int | None = None) -> dict:
        """Train from the current step to ``train.steps`` (or stop early at step ``until``).

        Stopping at ``until`` writes checkpoints/last.pt exactly as an interrupted
        run would have; a later `train()` continues bit-identically (the learning
        rate schedule depends on ``train.steps``, so extending ``train.steps``
        continues a run but is not identical to having asked for more steps).
        Returns a summary dict.
        """
        tc = self.cfg.train
        start = self.step
        end = tc.steps if until is None else min(int(until), tc.steps)
        if start >= end:
            return {"steps": self.step, "trained": 0, "best_val": self.best_val, "losses": []}
        loader = step_loader(self.train_set, self.cfg.train, start, end, self.dist.rank, self.dist.world,
                             pin=self.device.type == "cuda")
        self.depth.train()
        if self.pose is not None:
            self.pose.train()
        bar = None
        if self.progress and self.dist.is_main:
            from corelib.progress import progress_bar

            bar = progress_bar(total=tc.steps, initial=start, desc="train", unit="step")
        history = []
        t_last, n_last = time.perf_counter(), 0
        ema = None
        for batch in loader:
            batch = self.to_device(batch)
            lr = self.lr_at(self.step)
            for g in self.optimizer.param_groups:
                g["lr"] = lr * g.get("lr_mult", 1.0)
            t0 = time.perf_counter()
            outputs, losses = self._step(batch)
            loss = losses["loss"]
            self.step += 1
            lv = self.dist.sum_([float(loss.detach())], self.device)[0] / self.dist.world  # mean over ranks
            history.append(lv)
            ema = lv if ema is None else 0.9 * ema + 0.1 * lv
            n_last += batch.rgb.shape[0] * self.dist.world
            dt_step = time.perf_counter() - t0

            if self.step % tc.log_every == 0 or self.step == tc.steps:
                self.check_spread(outputs, batch.mask)
                now = time.perf_counter()
                rate = n_last / max(now - t_last, 1e-9)
                t_last, n_last = now, 0
                self.log.scalars({**{f"train/{k}": v for k, v in losses.items() if not k.startswith("_")},
                                  "train/lr": lr, "perf/rig_samples_per_s": rate, "perf/step_s": dt_step}, self.step)
                log.debug(f"step {self.step}/{tc.steps} loss {lv:.5f} lr {lr:.2e} {rate:.2f} rig samples/s")
            if self.log.enabled and (self.step % tc.image_every == 0 or self.step == 1):
                self.log.images(batch, outputs, self.step)
            if bar is not None:
                bar.set_postfix(loss=f"{ema:.4f}", rig_s=f"{1.0 / max(dt_step, 1e-9):.2f}/s", lr=f"{lr:.1e}")
                bar.update(1)
            if self.step % tc.val_every == 0 or self.step == tc.steps:
                self._validate_and_keep_best()
            if self.step % tc.ckpt_every == 0 or self.step == end:
                self.save_checkpoint("last.pt")
        if bar is not None:
            bar.close()
        self.log.flush()
        return {
            "steps": self.step,
            "trained": self.step - start,
            "loss_first": history[0] if history else None,
            "loss_last": history[-1] if history else None,
            "losses": history,
            "best_val": self.best_val,
            "depth_spread": dict(self.spread),
        }

    def _step(self, batch: RigBatch) -> tuple[dict, dict]:
        """One optimiser step on `batch` at `self.step`: (outputs, losses). TrainingDiverged on a non-finite loss
        (on any rank) or gradient, or fp16 steps skipped too often in a row (`mcdp.diagnostics.SkipGuard`)."""
        tc = self.cfg.train
        outputs, losses = (self.ddp or self.system)(batch, self.step, True)
        loss = losses["loss"]
        if self.dist.any_true(not bool(torch.isfinite(loss)), self.device):  # every rank stops together
            raise TrainingDiverged(loss_divergence(losses, self.step) + self._last_good()
                                   + "; try a lower train.lr or train.grad_clip=1.0")
        self.optimizer.zero_grad(set_to_none=True)
        self.scaler.scale(loss).backward()
        if not self.scaler.is_enabled():  # (fp16's GradScaler skips non-finite steps itself)
            bad_grad = gradient_divergence(self.system.named_parameters(), self.step)  # names the first parameter
            if bad_grad is not None:
                raise TrainingDiverged(bad_grad + self._last_good() + "; try a lower train.lr or train.grad_clip=1.0")
        if tc.grad_clip is not None:
            self.scaler.unscale_(self.optimizer)
            torch.nn.utils.clip_grad_norm_([p for g in self.optimizer.param_groups for p in g["params"]], tc.grad_clip)
        scale = self.scaler.get_scale() if self.scaler.is_enabled() else None
        self.scaler.step(self.optimizer)
        self.scaler.update()
        if scale is not None:  # fp16: the scaler skips a step with non-finite gradients and lowers the scale
            skipped = self.skip_guard.record(scale, self.scaler.get_scale(), self.step)
            if skipped is not None:
                raise TrainingDiverged(skipped + self._last_good() + "; try train.precision=bf16 or fp32")
        return outputs, losses

    def _validate_and_keep_best(self) -> None:
        """Validate at `self.step`; a lower val loss than any before is saved as best.pt. TrainingDiverged on a
        non-finite one (nothing of this step saved)."""
        v = self.validate()
        if v is not None and not math.isfinite(v):
            raise TrainingDiverged(
                f"validation loss is {v} at step {self.step}; nothing of this step was saved"
                + self._last_good() + "; try a lower train.lr or train.grad_clip=1.0")
        if v is not None:
            self.val_history.append((self.step, v))
            self.log.scalars({"val/loss": v}, self.step)
            if v < self.best_val:
                self.best_val = v
                self.save_checkpoint("best.pt", weights_only=True)

    def close(self) -> None:
        self.log.close()
        close_run_log(self._log_file)
        self._log_file = None
        if hasattr(self, "_threads_before"):
            torch.set_num_threads(self._threads_before)
        self.dist.stop()
        if self._lock is not None:
            self._lock.release()
