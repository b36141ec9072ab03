"""Self-supervised training of MCDP and its Monodepth2 baseline on a synth dataset.

One step follows Monodepth2's stages: ``process_batch -> predict_poses ->
compute_losses`` (the warps of ``generate_images_pred`` are made inside the
loss loop so that no stage keeps all its warped images alive).

Loss (paper eq. 9), with masks excluded from every mean::

    L = sum over stages st in (init, refine1..m) of [ L_p(st) + lambda * L_con(st) ]
        + velocity_weight * L_vel                        (scale.source = velocity)
    L_p(st) = 1/S sum_s [ reprojection(st, s) + smoothness_weight * smooth(st, s) / 2^s ]
    (s over the 4 decoder scales for "init"; over the first loss.refine_scales,
    default full resolution only, for refined stages: see `LossConfig`)

- reprojection: 0.85 SSIM + 0.15 L1, per-pixel minimum over frames t-1/t+1,
  Monodepth2 auto-masking; a source pixel that lands on the ego body of the
  source image is invalid; ego-body target pixels never count. With
  ``loss.out_of_view=identity`` (default) a pixel no source sees scores its
  identity error and the mean is over all scene pixels
  (`mcdp.losses.identity_floored_error`).
- the shared pretraining's stage "mono" (``model.mono_head``) is a stage like
  "init": all decoder scales, no refinement.
- L_con: every adjacent camera pair in both directions; the source camera's
  full-resolution depth is forward-projected into the target camera with a
  z-buffer; L1 in metres on pixels both cameras see (outside both ego masks).
- L_vel (PackNet): | ||t_pred|| - ||t_odom|| | per camera and source frame, with
  the ego odometry motion transformed into each camera.

Guards: a NaN/inf loss or gradient (before the update) or validation loss stops
training with `TrainingDiverged` naming the step (checkpoints stay the last finite
state); the depth's spread (`mcdp.diagnostics`) is logged and a collapse to a
constant or to a bound of the depth range is warned about, naming the step.
A fresh run may start from a shared pretraining (``model.init_from``, `mcdp.warmstart`).

Model selection uses the val split only and no ground truth: every
``train.val_every`` steps the final stage's L_p + lambda L_con on fixed val
samples is measured and the lowest is kept as ``checkpoints/best.pt``.

Run folder::

    RUN/config.yaml            resolved RunConfig
    RUN/run.json               dataset path, cameras, neighbours
    RUN/checkpoints/last.pt    model, optimiser, step, config (atomic: tmp + os.replace)
    RUN/checkpoints/best.pt    lowest val loss: networks, step, config (no optimiser state: a
                               third of the size; resuming always starts from last.pt)
    RUN/tensorboard/           scalars and six-camera image grids

Example::

    mcdp train configs/train/tiny/mcdp_m1.yaml --data data/tiny --out runs/m1
"""
from __future__ import annotations

import io
import math
import sys
import time
from pathlib import Path

import numpy as np
import torch
import torch.nn.functional as F
import yaml

from corelib.atomic import atomic_write_bytes, atomic_write_json, atomic_write_text
from mcdp.config import RunConfig, resume_conflicts
from mcdp.data import RigDataset, StepBatchSampler, collate, directed_pairs, neighbour_table
from mcdp.diagnostics import collapse_reason, depth_spread
from mcdp.geometry import splat_depth, warp_by_depth
from mcdp.losses import (
    consistency_loss,
    identity_floored_error,
    masked_mean,
    min_reprojection,
    photometric_error,
    smoothness_loss,
    used_pixels,
)
from mcdp.model import DepthModel, PoseModel, is_refined, odometry_camera_motion, resize_mask_to
from corelib.rundir import claim
from mcdp.warmstart import warm_start
from corelib.configlib import build_config, config_to_dict

CHECKPOINT_VERSION = 1
#: steps a fresh network may stay a constant map before the collapse guard warns
COLLAPSE_GRACE_STEPS = 100
#: logged checks in a row that must show a collapse before the guard warns
COLLAPSE_STREAK = 5


class RunError(ValueError):
    """A run folder or checkpoint cannot be used as asked; the message says why and what to do."""


class TrainingDiverged(RuntimeError):
    """The loss became NaN/inf; training stopped (the last checkpoint is intact)."""


# --------------------------------------------------------------------------- checkpoints
def atomic_torch_save(obj, path: Path) -> None:
    """torch.save to ``path.tmp`` then os.replace: a crash never leaves a half-written checkpoint."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    buf = io.BytesIO()  # serialised in memory: a full disk then fails in one plain write, not inside torch
    torch.save(obj, buf)
    atomic_write_bytes(path, buf.getbuffer())


def load_checkpoint(path: Path) -> dict:
    """Read a checkpoint written by `Trainer.save_checkpoint`; RunError naming the file otherwise."""
    path = Path(path)
    if not path.is_file():
        raise RunError(f"checkpoint {path} does not exist")
    try:
        # weights_only: tensors and plain containers only; a pickle that would run code is refused
        ckpt = torch.load(path, map_location="cpu", weights_only=True)
    except Exception as exc:  # noqa: BLE001
        first = str(exc).strip().splitlines()[0][:200] if str(exc).strip() else type(exc).__name__
        raise RunError(f"checkpoint {path} is unreadable or not a plain weights file: {first}") from None
    if not isinstance(ckpt, dict) or ckpt.get("version") != CHECKPOINT_VERSION or "config" not in ckpt:
        raise RunError(f"checkpoint {path} is not an mcdp checkpoint of version {CHECKPOINT_VERSION}")
    return ckpt


def config_from_checkpoint(ckpt: dict, source: str = "checkpoint") -> RunConfig:
    return build_config(RunConfig, ckpt["config"], source=source)


def check_resume(run_dir: Path, cfg: RunConfig) -> dict | None:
    """The checkpoint to resume from (or None for a fresh run); RunError naming conflicting keys."""
    last = Path(run_dir) / "checkpoints" / "last.pt"
    if not last.exists():
        return None
    ckpt = load_checkpoint(last)
    saved = ckpt["config"]
    requested = config_to_dict(cfg)
    bad = resume_conflicts(saved, requested)
    if bad:

        def get(d, k):
            for p in k.split("."):
                d = d.get(p) if isinstance(d, dict) else None
            return d

        lines = [f"  {k}: checkpoint has {get(saved, k)!r}, requested {get(requested, k)!r}" for k in bad]
        raise RunError(
            f"{last} was trained with a different config; these keys conflict:\n"
            + "\n".join(lines)
            + f"\nuse the run's own settings (see {Path(run_dir) / 'config.yaml'}) or a new --out folder"
        )
    return ckpt


def resolve_device(name: str) -> torch.device:
    if name == "auto":
        return torch.device("cuda" if torch.cuda.is_available() else "cpu")
    if name == "cuda" and not torch.cuda.is_available():
        raise RunError("train.device=cuda but no CUDA device is available (use train.device=cpu or auto)")
    return torch.device(name)


# --------------------------------------------------------------------------- augmentation
def color_augment(rgb: torch.Tensor, seed: int, step: int) -> torch.Tensor:
    """Monodepth2-style colour jitter (p = 0.5 per camera; brightness, contrast, saturation +-0.2).

    One draw per (rig sample, camera), shared by its three frames; drawn from a
    generator seeded by (seed, step), so resumed runs see the same jitter.
    Network input only; losses use the original images.

    Args:
        rgb: (B, N, F, 3, H, W) in [0, 1].
    """
    B, N = rgb.shape[:2]
    g = torch.Generator().manual_seed(int(seed) * 7_919 + int(step) * 104_729 + 17)
    u = torch.rand(B, N, 4, generator=g)
    apply = (u[..., 0] < 0.5).float()
    bri = 1 + apply * (u[..., 1] * 0.4 - 0.2)
    con = 1 + apply * (u[..., 2] * 0.4 - 0.2)
    sat = 1 + apply * (u[..., 3] * 0.4 - 0.2)
    shp = (B, N, 1, 1, 1, 1)
    x = rgb * bri.view(shp).to(rgb)
    gray = (0.299 * x[:, :, :, 0:1] + 0.587 * x[:, :, :, 1:2] + 0.114 * x[:, :, :, 2:3])
    mean = gray.mean(dim=(-3, -2, -1), keepdim=True)
    x = (x - mean) * con.view(shp).to(rgb) + mean
    gray = (0.299 * x[:, :, :, 0:1] + 0.587 * x[:, :, :, 1:2] + 0.114 * x[:, :, :, 2:3])
    x = (x - gray) * sat.view(shp).to(rgb) + gray
    return x.clamp(0, 1)


# --------------------------------------------------------------------------- one step
class SelfSupervisedSystem(torch.nn.Module):
    """Depth model + pose source + losses of one training step; knows the rig, not the dataset.

    Args:
        cfg: RunConfig.
        neighbours: the dataset's adjacent camera pairs (i, i+1), rig order.
        n_cams: number of cameras.

    ``process_batch(batch, step, train)`` -> (outputs, losses) for a batch of
    the `mcdp.data` schema on this module's device; ``losses["loss"]`` is the
    scalar to minimise, other entries are detached statistics.
    """

    def __init__(self, cfg: RunConfig, neighbours, n_cams: int):
        super().__init__()
        self.cfg = cfg
        self.depth = DepthModel(cfg.model)
        self.pose = PoseModel(cfg.model.pretrained) if cfg.scale.source != "odometry" else None
        self.register_buffer("nbr", neighbour_table(neighbours, n_cams), persistent=False)
        tgt, src = directed_pairs(neighbours)
        self.register_buffer("pair_tgt", tgt, persistent=False)
        self.register_buffer("pair_src", src, persistent=False)
        self.use_amp = False
        self.amp_dtype = torch.float16

    @property
    def device(self) -> torch.device:
        return self.nbr.device

    def predict_poses(self, batch: dict, net_rgb: torch.Tensor) -> tuple[dict, dict]:
        """T_src_tgt per source offset, (B*N, 4, 4), and pose statistics/velocity loss terms."""
        B, N = batch["rgb"].shape[:2]
        odom = {o: odometry_camera_motion(batch["T_world_ego"], batch["T_ego_cam"], o) for o in (-1, 1)}
        stats = {}
        if self.pose is None:
            poses = odom
        else:
            with torch.autocast(self.device.type, dtype=self.amp_dtype, enabled=self.use_amp):
                poses = self.pose(net_rgb)
            t_pred = torch.stack([poses[o][..., :3, 3].norm(dim=-1) for o in (-1, 1)])  # (2, B, N)
            t_odom = torch.stack([odom[o][..., :3, 3].norm(dim=-1) for o in (-1, 1)])
            stats["velocity"] = (t_pred - t_odom).abs().mean()
            stats["t_norm_pred"] = t_pred.detach().mean()
            stats["t_norm_odom"] = t_odom.mean()
        return {o: p.reshape(B * N, 4, 4).float() for o, p in poses.items()}, stats

    def process_batch(self, batch: dict, step: int = 0, train: bool = True, need_con: bool | None = None) -> tuple[dict, dict]:
        """Forward + losses for one batch (schema in `mcdp.data`). Returns (outputs, losses)."""
        cfg = self.cfg
        rgb = batch["rgb"]
        net_rgb = color_augment(rgb, cfg.train.seed, step) if (train and cfg.train.color_aug) else rgb
        oracle = batch.get("gt_median") if cfg.scale.oracle else None
        with torch.autocast(self.device.type, dtype=self.amp_dtype, enabled=self.use_amp):
            outputs = self.depth(
                net_rgb[:, :, 1], batch["K"], batch["T_ego_cam"], batch["mask"], self.nbr, oracle,
                scales=cfg.model.scales, refine_scales=cfg.loss.refine_scales,
            )
        poses, pose_stats = self.predict_poses(batch, net_rgb)
        losses = self.compute_losses(batch, outputs, poses, need_con=need_con)
        for k, v in pose_stats.items():
            losses[f"pose/{k}"] = v
        if "velocity" in pose_stats and cfg.scale.source == "velocity":
            losses["loss"] = losses["loss"] + cfg.scale.velocity_weight * pose_stats["velocity"]
        return outputs, losses

    def compute_losses(self, batch: dict, outputs: dict, poses: dict, need_con: bool | None = None) -> dict:
        """Photometric + smoothness per stage and scale, L_con per stage (module docstring)."""
        cfg = self.cfg
        rgb = batch["rgb"].float()
        B, N, _, C, H, W = rgb.shape
        BN = B * N
        target = rgb[:, :, 1].reshape(BN, C, H, W)
        sources = [rgb[:, :, 1 + o].reshape(BN, C, H, W) for o in (-1, 1)]
        mask = batch["mask"].reshape(BN, 1, H, W).float()
        K = batch["K"].reshape(BN, 3, 3).float()
        src_and_mask = [torch.cat([s, mask], 1) for s in sources]  # the ego body is static in each camera
        scales = list(range(cfg.model.scales))
        img_s = {s: target if s == 0 else F.avg_pool2d(target, 2**s) for s in scales}
        mask_s = {s: mask if s == 0 else resize_mask_to(mask, H // 2**s, W // 2**s) for s in scales}
        lam = cfg.loss.consistency_weight
        need_con = lam > 0 if need_con is None else need_con

        ident = None
        mono2_mask = cfg.loss.out_of_view == "identity"
        if cfg.loss.automask or mono2_mask:
            with torch.no_grad():
                ident = torch.cat([photometric_error(sc, target, cfg.loss.ssim_alpha) for sc in sources], 1)
                ident = ident.min(1, keepdim=True).values  # (BN, 1, H, W)
        losses: dict = {}
        total = 0.0
        for stage in outputs["stages"]:
            lp_sum = 0.0
            st_scales = scales[: cfg.loss.refine_scales] if is_refined(stage) else scales
            for s in st_scales:
                depth = outputs["depth", stage, s].float()
                errors, valid = [], []
                for o, sm in zip((-1, 1), src_and_mask):
                    w, v = warp_by_depth(sm, depth, K, K, poses[o], padding_mode="border")
                    errors.append(photometric_error(w[:, :C], target, cfg.loss.ssim_alpha))
                    valid.append(v * (w[:, C:] > 0.99).to(v.dtype))
                # == reprojection_loss(..., automask=True), with the identity error computed
                # once per batch instead of once per stage and scale (it does not depend on depth);
                if mono2_mask:
                    per_pixel, used = identity_floored_error(errors, valid, ident, cfg.loss.automask)
                    rep = masked_mean(per_pixel, mask)
                    used = used * mask
                else:
                    per_pixel, seen = min_reprojection(errors, valid)
                    used = used_pixels(per_pixel, seen, ident, mask)
                    rep = masked_mean(per_pixel, used)
                smooth = smoothness_loss(outputs["disp", stage, s].float(), img_s[s], mask_s[s])
                lp_sum = lp_sum + rep + cfg.loss.smoothness_weight * smooth / (2**s)
                if s == 0:
                    losses[f"reprojection/{stage}"] = rep.detach()
                    losses[f"smoothness/{stage}"] = smooth.detach()
                    if stage == outputs["stages"][-1]:
                        losses["_used"] = used.detach()
            lp = lp_sum / len(st_scales)
            losses[f"photometric/{stage}"] = lp.detach()
            stage_loss = lp
            if need_con and self.pair_tgt.numel() > 0:
                lcon = self.consistency(outputs["depth", stage, 0].float(), batch)
                losses[f"consistency/{stage}"] = lcon.detach()
                if lam > 0:
                    stage_loss = stage_loss + lam * lcon
            losses[f"stage/{stage}"] = stage_loss.detach()
            total = total + stage_loss
        losses["loss"] = total
        return losses

    def consistency(self, depth: torch.Tensor, batch: dict) -> torch.Tensor:
        """L_con over every directed adjacent pair: (B*N, 1, H, W) depth -> scalar (metres)."""
        B, N = batch["rgb"].shape[:2]
        H, W = depth.shape[-2:]
        tgt, src = self.pair_tgt, self.pair_src
        P = tgt.numel()
        d = depth.view(B, N, 1, H, W)
        m = batch["mask"].float()
        K = batch["K"].float()
        T = batch["T_ego_cam"].float()
        T_tgt_src = torch.linalg.inv(T[:, tgt]) @ T[:, src]  # (B, P, 4, 4)
        d_hat, hit = splat_depth(
            d[:, src].reshape(B * P, 1, H, W),
            K[:, src].reshape(B * P, 3, 3),
            K[:, tgt].reshape(B * P, 3, 3),
            T_tgt_src.reshape(B * P, 4, 4),
            H,
            W,
            valid_src=m[:, src].reshape(B * P, 1, H, W),
        )
        return consistency_loss(d[:, tgt].reshape(B * P, 1, H, W), d_hat, hit, m[:, tgt].reshape(B * P, 1, H, W))


# --------------------------------------------------------------------------- trainer
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
        self.writer = None
        # the run folder is ours (marker) and ours alone (flock) before anything is read or written
        self._lock = claim(self.run_dir, "run", legacy=("run.json", "checkpoints"))
        try:
            self._setup(cfg, ds, tensorboard)
        except BaseException:
            self._lock.release()
            raise

    def _setup(self, cfg: RunConfig, ds, tensorboard: bool) -> None:
        self.device = resolve_device(cfg.train.device)
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
        self.optimizer = torch.optim.Adam(self.system.parameters(), lr=tc.lr, betas=(0.9, 0.999))

        oracle = cfg.scale.oracle
        self.train_set = RigDataset(ds, "train", tc.height, tc.width, oracle=oracle)
        if len(self.train_set) == 0:
            raise RunError(f"dataset {ds.root}: the train split has no rig sample (sequences need >= 3 frames)")
        self.val_set = RigDataset(ds, "val", tc.height, tc.width, oracle=oracle)

        self.use_amp = tc.amp and self.device.type == "cuda"
        self.amp_dtype = (
            torch.bfloat16 if self.use_amp and torch.cuda.is_bf16_supported() else torch.float16
        )
        self.scaler = torch.amp.GradScaler("cuda", enabled=self.use_amp and self.amp_dtype == torch.float16)
        self.system.use_amp, self.system.amp_dtype = self.use_amp, self.amp_dtype

        self.init_from: dict | None = None
        if ckpt is None and cfg.model.init_from is not None:
            self.init_from = warm_start(self.depth, cfg.model.init_from)
        self.step = 0
        self.spread: dict = {}
        self.spread_armed = False
        self.collapse_streak = 0
        self.best_val = math.inf
        self.val_history: list[tuple[int, float]] = []
        if ckpt is not None:
            self._restore(ckpt)
        self.run_dir.mkdir(parents=True, exist_ok=True)
        (self.run_dir / "checkpoints").mkdir(exist_ok=True)
        atomic_write_text(self.run_dir / "config.yaml", yaml.safe_dump(config_to_dict(cfg), sort_keys=False))
        atomic_write_json(self.run_dir / "run.json", {
            "data": str(Path(ds.root).resolve()),
            "cameras": list(ds.camera_names),
            "neighbours": [list(p) for p in ds.neighbours],
            "oracle": oracle,
            "init_from": self.init_from,
        })
        self.writer = None
        if tensorboard:
            from torch.utils.tensorboard import SummaryWriter

            self.writer = SummaryWriter(str(self.run_dir / "tensorboard"))

    # ------------------------------------------------------------------ state
    def state(self) -> dict:
        return {
            "version": CHECKPOINT_VERSION,
            "step": self.step,
            "config": config_to_dict(self.cfg),
            "depth_model": self.depth.state_dict(),
            "pose_model": self.pose.state_dict() if self.pose is not None else None,
            "optimizer": self.optimizer.state_dict(),
            "scaler": self.scaler.state_dict(),
            "best_val": self.best_val,
            "val_history": self.val_history,
            "cameras": list(self.ds.camera_names),
            "neighbours": [list(p) for p in self.ds.neighbours],
            "torch_rng": torch.get_rng_state(),
            "depth_spread": dict(self.spread),
            "init_from": self.init_from,
        }

    def save_checkpoint(self, name: str = "last.pt", weights_only: bool = False) -> Path:
        """Atomically write ``checkpoints/<name>``; `weights_only` drops optimiser/scaler/RNG state."""
        path = self.run_dir / "checkpoints" / name
        state = self.state()
        if weights_only:
            for k in ("optimizer", "scaler", "torch_rng"):
                state.pop(k)
        atomic_torch_save(state, path)
        return path

    def _restore(self, ckpt: dict) -> None:
        self.depth.load_state_dict(ckpt["depth_model"])
        if self.pose is not None:
            self.pose.load_state_dict(ckpt["pose_model"])
        self.optimizer.load_state_dict(ckpt["optimizer"])
        if ckpt.get("scaler"):
            self.scaler.load_state_dict(ckpt["scaler"])
        self.step = int(ckpt["step"])
        self.best_val = float(ckpt.get("best_val", math.inf))
        self.val_history = [tuple(x) for x in ckpt.get("val_history", [])]
        self.spread = dict(ckpt.get("depth_spread") or {})
        self.init_from = ckpt.get("init_from")
        torch.set_rng_state(ckpt["torch_rng"])

    # ------------------------------------------------------------------ schedule
    def lr_at(self, step: int) -> float:
        tc = self.cfg.train
        return tc.lr * (tc.lr_decay_factor if step >= int(tc.lr_decay_at * tc.steps) else 1.0)

    def to_device(self, batch: dict) -> dict:
        return {k: v.to(self.device, non_blocking=True) for k, v in batch.items()}

    # ------------------------------------------------------------------ validation
    def val_indices(self) -> list[int]:
        n = len(self.val_set)
        k = min(n, self.cfg.train.val_samples)
        return sorted({int(round(i * (n - 1) / max(k - 1, 1))) for i in range(k)}) if n else []

    @torch.no_grad()
    def validate(self) -> float | None:
        """Final-stage L_p + lambda L_con on fixed val samples (no ground truth); None without a val split."""
        idx = self.val_indices()
        if not idx:
            return None
        self.depth.eval()
        if self.pose is not None:
            self.pose.eval()
        vals = []
        final = self.depth.stages[-1]
        lam = self.cfg.loss.consistency_weight
        for i in idx:
            batch = self.to_device(collate([self.val_set[i]]))
            _, losses = self.system.process_batch(batch, self.step, train=False)
            v = losses[f"photometric/{final}"]
            if lam > 0 and f"consistency/{final}" in losses:
                v = v + lam * losses[f"consistency/{final}"]
            vals.append(float(v))
        self.depth.train()
        if self.pose is not None:
            self.pose.train()
        return float(np.mean(vals))

    # ------------------------------------------------------------------ logging
    def log_scalars(self, losses: dict, extra: dict) -> None:
        if self.writer is None:
            return
        for k, v in losses.items():
            if k.startswith("_"):
                continue
            self.writer.add_scalar(f"train/{k}", float(v.detach()), self.step)
        for k, v in extra.items():
            self.writer.add_scalar(k, v, self.step)

    def log_images(self, batch: dict, outputs: dict, losses: dict) -> None:
        if self.writer is None:
            return
        from mcdp.predict import colorize_disparity

        N = batch["rgb"].shape[1]
        rows = [batch["rgb"][0, :, 1].float().cpu()]  # (N, 3, H, W)
        for stage in outputs["stages"]:
            disp = outputs["disp", stage, 0][:N].detach().float().cpu()
            rows.append(torch.from_numpy(colorize_disparity(disp[:, 0].numpy())).permute(0, 3, 1, 2).float() / 255)
        m = batch["mask"][0].float().cpu()
        used = losses["_used"][:N].float().cpu()
        rows.append(torch.cat([m, used, m * 0], 1))  # red: scene mask, green: pixels used by L_p
        import torchvision

        grid = torchvision.utils.make_grid(torch.cat(rows, 0), nrow=N, padding=2)
        self.writer.add_image("rig/rgb_depth_per_stage_masks", grid, self.step)

    def check_spread(self, outputs: dict, batch: dict) -> dict:
        """Spread of the final stage's depth on this batch (`mcdp.diagnostics`); warns once per collapse."""
        m = self.cfg.model
        final = self.depth.stages[-1]
        depth = outputs["depth", final, 0]
        mask = batch["mask"].reshape(depth.shape)
        spread = depth_spread(depth, mask, m.min_depth, m.max_depth)
        reason = collapse_reason(spread)
        if reason is None:
            self.spread_armed = True
            self.collapse_streak = 0
        else:
            self.collapse_streak += 1
        # a fresh network starts as a constant (model.init_depth): warn only once the depth has
        # spread out, or after COLLAPSE_GRACE_STEPS steps that never left the constant start; and
        # only when COLLAPSE_STREAK logged checks in a row agree (one odd batch is not a collapse)
        armed = self.spread_armed or self.step >= COLLAPSE_GRACE_STEPS
        if reason is not None and armed and self.collapse_streak == COLLAPSE_STREAK:
            print(f"mcdp train: WARNING step {self.step}: depth collapsed: {reason}", file=sys.stderr)
        self.spread = dict(spread, collapsed=reason)
        if self.writer is not None:
            for k in ("ratio", "at_min", "at_max"):
                self.writer.add_scalar(f"depth_spread/{k}", spread[k], self.step)
        return spread

    def _last_good(self) -> str:
        last = self.run_dir / "checkpoints" / "last.pt"
        return f"; the last good checkpoint is {last}" if last.exists() else ""

    def _check_gradients(self) -> None:
        """TrainingDiverged naming the step and the first parameter whose gradient is NaN/inf."""
        grads = [p.grad for p in self.system.parameters() if p.grad is not None]
        if not grads or torch.isfinite(torch.nn.utils.get_total_norm(grads)):
            return
        name = next((n for n, p in self.system.named_parameters()
                     if p.grad is not None and not torch.isfinite(p.grad).all()), "?")
        raise TrainingDiverged(f"the gradient of {name} is not finite at step {self.step} (loss was finite); "
                               "the weights were not updated" + self._last_good()
                               + "; try a lower train.lr or train.grad_clip=1.0")

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
        sampler = StepBatchSampler(len(self.train_set), tc.batch_size, tc.seed, start, end)
        loader = torch.utils.data.DataLoader(
            self.train_set,
            batch_sampler=sampler,
            collate_fn=collate,
            num_workers=tc.num_workers,
            pin_memory=self.device.type == "cuda",
            persistent_workers=False,
        )
        self.depth.train()
        if self.pose is not None:
            self.pose.train()
        bar = None
        if self.progress:
            from tqdm import tqdm

            bar = tqdm(total=tc.steps, initial=start, desc="train", unit="step", dynamic_ncols=True)
        history = []
        t_last, n_last = time.perf_counter(), 0
        ema = None
        for batch in loader:
            batch = self.to_device(batch)
            lr = self.lr_at(self.step)
            for g in self.optimizer.param_groups:
                g["lr"] = lr
            t0 = time.perf_counter()
            outputs, losses = self.system.process_batch(batch, self.step, train=True)
            loss = losses["loss"]
            if not torch.isfinite(loss):
                bad = {k: float(v.detach()) for k, v in losses.items() if not k.startswith("_") and v.numel() == 1}
                last = self.run_dir / "checkpoints" / "last.pt"
                raise TrainingDiverged(
                    f"loss is {float(loss.detach())} at step {self.step}; terms: "
                    + ", ".join(f"{k}={v:.4g}" for k, v in bad.items())
                    + (f"; the last good checkpoint is {last}" if last.exists() else "")
                    + "; try a lower train.lr or train.grad_clip=1.0"
                )
            self.optimizer.zero_grad(set_to_none=True)
            self.scaler.scale(loss).backward()
            if not self.scaler.is_enabled():  # (fp16's GradScaler skips non-finite steps itself)
                self._check_gradients()
            if tc.grad_clip is not None:
                self.scaler.unscale_(self.optimizer)
                torch.nn.utils.clip_grad_norm_(
                    [p for g in self.optimizer.param_groups for p in g["params"]], tc.grad_clip
                )
            self.scaler.step(self.optimizer)
            self.scaler.update()
            self.step += 1
            lv = float(loss.detach())
            history.append(lv)
            ema = lv if ema is None else 0.9 * ema + 0.1 * lv
            n_last += batch["rgb"].shape[0]
            dt_step = time.perf_counter() - t0

            if self.step % tc.log_every == 0 or self.step == tc.steps:
                self.check_spread(outputs, batch)
                now = time.perf_counter()
                rate = n_last / max(now - t_last, 1e-9)
                t_last, n_last = now, 0
                self.log_scalars(losses, {"train/lr": lr, "perf/rig_samples_per_s": rate, "perf/step_s": dt_step})
            if self.writer is not None and (self.step % tc.image_every == 0 or self.step == 1):
                self.log_images(batch, outputs, losses)
            if bar is not None:
                bar.set_postfix(loss=f"{ema:.4f}", rig_s=f"{1.0 / max(dt_step, 1e-9):.2f}/s", lr=f"{lr:.1e}")
                bar.update(1)
            if self.step % tc.val_every == 0 or self.step == tc.steps:
                v = self.validate()
                if v is not None and not math.isfinite(v):
                    raise TrainingDiverged(
                        f"validation loss is {v} at step {self.step}; nothing of this step was saved"
                        + self._last_good() + "; try a lower train.lr or train.grad_clip=1.0")
                if v is not None:
                    self.val_history.append((self.step, v))
                    if self.writer is not None:
                        self.writer.add_scalar("val/loss", v, self.step)
                    if v < self.best_val:
                        self.best_val = v
                        self.save_checkpoint("best.pt", weights_only=True)
            if self.step % tc.ckpt_every == 0 or self.step == end:
                self.save_checkpoint("last.pt")
        if bar is not None:
            bar.close()
        if self.writer is not None:
            self.writer.flush()
        return {
            "steps": self.step,
            "trained": self.step - start,
            "loss_first": history[0] if history else None,
            "loss_last": history[-1] if history else None,
            "losses": history,
            "best_val": self.best_val,
            "depth_spread": dict(self.spread),
        }

    def close(self) -> None:
        if self.writer is not None:
            self.writer.close()
        if hasattr(self, "_threads_before"):
            torch.set_num_threads(self._threads_before)
        self._lock.release()
