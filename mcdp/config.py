"""Configuration of an MCDP / Monodepth2 training run: every default in one place.

A preset (``configs/train/<name>.yaml``) lists only what differs from these
defaults; the command line overrides single keys::

    mcdp train configs/train/mcdp_m1.yaml --data data/tiny --out runs/m1 train.steps=200 loss.consistency_weight=0.05

The resolved `RunConfig` is saved as ``RUN/config.yaml`` and inside every
checkpoint. Sections:

- ``model``: networks (method, bases n, refinement steps m, neighbours, depth range).
- ``loss``: photometric / smoothness / consistency weights.
- ``scale``: where metric scale comes from (no ground truth unless the labelled oracle).
- ``train``: optimisation, resolution, seeding, logging cadence.
- ``eval``: evaluation settings (`EvalConfig`, read by `mcdp.evaluate`).
- ``method_params``: the method's own parameters (e.g. FSM's loss weights): keys of the params class
  its registry row declares (`mcdp.methods.Method.params`), validated there (`mcdp.methods.method_params`:
  an unknown key or a bad value is a ConfigError naming ``method_params.<key>``); unset keys keep the
  model's defaults. Empty by default, and then outside the run's hash (`corelib.configlib.added_key`).
"""
from __future__ import annotations

import re
from typing import Annotated, Any, Literal

from pydantic import BeforeValidator, Field, field_validator, model_validator

from corelib.configlib import StrictModel, added_key

_SCI_FLOAT = re.compile(r"^[-+]?(\d+\.?\d*|\.\d+)[eE][-+]?\d+$")


def _yaml12_float(v: Any) -> Any:
    # PyYAML (YAML 1.1) reads `1e-4` as the *string* "1e-4"; YAML 1.2 and every
    # user read it as a float. Only that exact scientific spelling is accepted,
    # any other string still fails strict validation.
    if isinstance(v, str) and _SCI_FLOAT.match(v.strip()):
        return float(v)
    return v


Float = Annotated[float, BeforeValidator(_yaml12_float)]

# Upper bounds of the numeric keys: each well beyond what a real run uses, so that a typo or a probe
# (train.steps=10**15, model.weight_channels=100000) is refused before anything is allocated or written.
MAX_DEPTH_M = 1000.0
MAX_STEPS = 10_000_000
MAX_WEIGHT = 1000.0  # loss weights, learning-rate multipliers
#: train.batch_size x height x width: pixels of one camera image summed over a step's rig samples
MAX_STEP_PIXELS = 1 << 24
IMAGES_PER_SAMPLE = 18  # 6 cameras x 3 frames (target + 2 sources)


class ModelConfig(StrictModel):
    """Depth, pose and weight networks.

    method: the depth network: ``mono2`` (Monodepth2: one sigmoid channel -> depth), ``mcdp``
        (n depth bases, initial weights 1/n, ``refine_steps`` weight networks), or the model of
        another method registered in `mcdp.methods`. What a network needs of the other keys is
        checked by the network (`mcdp.methods.check_model`), not here.
    bases: n, number of depth bases (mcdp only; mono2 always uses 1 channel).
    refine_steps: m, refinement steps (0 = bases only, the "M0" row).
    neighbours: which ring neighbours feed the weight network: ``left`` (i-1),
        ``right`` (i+1) or ``both``. L_con always uses every adjacent pair in
        both directions (see `mcdp.methods.depth_bases`).
    pretrained: path to a local torchvision ResNet-18 state dict (never downloaded), or null.
    min_depth, max_depth: metres; the sigmoid output maps to disparity in
        [1/max_depth, 1/min_depth] (`mcdp.methods.base.disp_to_depth`).
    init_depth: metres; the depth head's bias is initialised so that a fresh
        network predicts about this depth everywhere. Metric training (odometry
        or velocity scale, metres per frame of motion) needs a start near the
        scene's scale: Monodepth2's sigmoid(0) start is 0.2 m for the default
        range, from where warps with real camera motion leave the image and
        training collapses to a constant depth. null = Monodepth2's init.
    scales: decoder output scales used by the loss (Monodepth2: 4).
    weight_channels: channels each encoder-feature pyramid is reduced to
        before warping, inside each weight network (keeps refinement cheap).
    weight_conv_channels, weight_fc: widths of the weight network's conv stack and FC layers.
    weight_init_std: std of the normal init of each weight network's last layer (bias 0), so
        a fresh step starts near the previous step's weights (paper: not stated).
    mono_head: pretraining only (`study.sweep.pretrain`): a one-channel Monodepth2 head beside the
        n bases on the same encoder and decoder trunk (stages "mono" and "init").
    init_from: path to a shared pretraining's ``pretrained.pt`` (`study.sweep.pretrain`), or null. A
        fresh run copies the encoder and decoder from it (mono2 takes the mono head, mcdp the
        n basis channels); weight networks start fresh. Refused, naming the layer, when the
        architecture differs. The run records the file's path and sha256.
    sync: cameras that fire at their own times (a dataset rendered with ``rig.trigger``, or nuScenes):
        ``compensate`` (default) puts each camera at its own pose at its own time in every cross-camera warp
        (MCDP's neighbour features, FSM's spatial terms, L_con; `mcdp.data.RigReader.T_ego_cam_at`) and in the
        camera motion the ego odometry gives every method (`mcdp.rigid.odometry_camera_motion`, Mono2's too);
        ``assume`` uses the static rig extrinsics, as if the cameras fired together (the ablation of what
        ignoring the offsets costs). Equal on synchronous data; an added key (unset: the run's hash as before).
    warm_start: false trains from scratch although ``init_from`` names a pretraining (random encoder and
        decoder, the calibration's "from scratch" arm against a sweep's shared pretraining; Monodepth2's and
        PackNet's "without ImageNet pretraining" rows). The run still records the file it did not read in its
        hash. An added key.
    feature_ego_mask: MCDP's weight networks see the ego body's features zeroed and a neighbour's warped
        features invalid where they land on its ego body (default true, today's); false feeds them unmasked
        (the calibration's "no self-occlusion masks" switch for the features; the public MCDP code masks
        them). An added key.
    encoder_layers: the depth encoder's ResNet depth, 18 (default), 34 or 50 (Monodepth2's ``--num_layers``; the
        pose network stays ResNet-18, as Monodepth2's default). A pretraining or ``pretrained`` file of another
        depth is refused naming the layer; train from scratch (``warm_start: false``) against a ResNet-18
        pretraining. An added key.
    lens: ``rig`` (default) warps through each camera's lens (`mcdp.camera`: the batch carries it); ``pinhole``
        drops the distortion and treats each camera's K as a pinhole's, in the run's own warps (training, and the
        network's inference, as ``sync``): the ablation of what ignoring distortion costs. The evaluation's
        overlap regions and Dep Con always go through the true lens. Refused, naming this key, for a camera whose
        depth kind is range (kannala_brandt), where z-depth does not exist. Equal on a pinhole rig; an added key.
    """

    method: str = Field("mcdp", pattern=r"^[a-z][a-z0-9_]{0,39}$")
    bases: int = Field(32, ge=1, le=256)
    refine_steps: int = Field(0, ge=0, le=8)
    neighbours: Literal["left", "right", "both"] = "both"
    pretrained: str | None = None
    min_depth: Float = Field(0.1, gt=0.0, le=MAX_DEPTH_M, allow_inf_nan=False)
    max_depth: Float = Field(100.0, gt=0.0, le=MAX_DEPTH_M, allow_inf_nan=False)
    init_depth: Float | None = Field(10.0, gt=0.0, le=MAX_DEPTH_M, allow_inf_nan=False)
    scales: int = Field(4, ge=1, le=4)
    weight_channels: int = Field(32, ge=1, le=512)
    weight_conv_channels: int = Field(64, ge=1, le=1024)
    weight_fc: int = Field(128, ge=1, le=4096)
    weight_init_std: Float = Field(1e-3, ge=0.0, le=1.0)
    mono_head: bool = False
    init_from: str | None = None
    sync: Literal["compensate", "assume"] = added_key("compensate")
    warm_start: bool = added_key(True)
    encoder_layers: Literal[18, 34, 50] = added_key(18)
    feature_ego_mask: bool = added_key(True)
    lens: Literal["rig", "pinhole"] = added_key("rig")

    @model_validator(mode="after")
    def _check(self) -> "ModelConfig":
        if self.min_depth >= self.max_depth:
            raise ValueError(f"model.min_depth ({self.min_depth}) must be < model.max_depth ({self.max_depth})")
        if self.init_depth is not None and not self.min_depth < self.init_depth < self.max_depth:
            raise ValueError(
                f"model.init_depth ({self.init_depth}) must lie in (min_depth, max_depth) = "
                f"({self.min_depth}, {self.max_depth})"
            )
        if self.mono_head and self.refine_steps > 0:
            raise ValueError("model.mono_head (the shared pretraining's extra head) needs model.refine_steps=0")
        return self


class LossConfig(StrictModel):
    """Loss weights.

    ssim_alpha: pe = alpha/2 (1 - SSIM) + (1 - alpha) L1 (paper: 0.85).
    smoothness_weight: edge-aware smoothness on mean-normalised disparity,
        divided by 2^scale as in Monodepth2 (paper: 1e-3).
    consistency_weight: lambda of L_con; 0 disables it. Default 1e-3, the paper's (sec. 4.1).
        L_con here is the masked mean of |D_i - D_hat_i| in metres over the overlap
        (`mcdp.losses.consistency_loss`), the same quantity as the public MCDP code's
        ``depth_consistency_loss`` (``L1Loss()(warp_depth[mask], depth[mask])``), which
        defaults to 1e-4 (``--weight_depth_consistency_loss`` in its ``options_DDAD.py``).
        The earlier default 0.02 (20x the paper) rested on a wrong reading of the paper's L1 as a
        per-pixel sum; measured in docs/results/consistency_weight.md.
    automask: Monodepth2 auto-masking of stationary pixels.
    out_of_view: what a pixel that no source frame sees (warped outside every source image
        or behind it) scores. ``identity`` (default; `mcdp.losses.identity_floored_error`):
        its identity error, and with auto-masking every pixel scores min(reprojection,
        identity), averaged over ALL scene pixels as Monodepth2 does, so no depth can lower
        the loss by sending pixels out of view. ``border``: the earlier rule (the border-padded
        reprojection error, averaged over the auto-mask's pixels only); measured in
        docs/results/learning.md: at lr 1e-3 it left training stuck at a near-constant depth
        (median abs_rel 0.86 vs 0.84 for a constant after 300 steps) where ``identity`` reached 0.41.
    refine_scales: how many decoder scales the photometric loss of each
        *refined* stage uses (the initial stage always uses all
        ``model.scales``). Default 1 = full resolution only: a refined stage
        differs from the initial one only by its n global basis weights, so
        the coarse-scale terms (which in Monodepth2 keep the per-pixel decoder
        out of local minima) would repeat the initial stage's signal at 4x the
        cost of the full-resolution term. Set 4 for the literal paper loss.
    reprojection: how the sources' reprojection errors combine per pixel: ``min`` (default, Monodepth2's
        per-pixel minimum) or ``mean`` (Monodepth2's ``--avg_reprojection`` ablation: the mean over the
        sources that see the pixel, and with auto-masking the identity error is the sources' mean too, as
        its ``trainer.py`` averages ``identity_reprojection_losses``). An added key.
    multiscale: ``full_res`` (default, Monodepth2's: each decoder scale's depth upsampled to the full
        resolution and the photometric loss computed there) or ``per_scale`` (Monodepth2's
        ``--v1_multiscale`` ablation: each scale's depth at its own resolution, the images and K scaled to
        it, as its ``trainer.py`` sets ``source_scale = scale``). An added key.
    photometric_ego_mask: default true (today's): the photometric and smoothness losses skip the ego body's
        pixels, and a source pixel that lands on the source's ego body is invalid; false: the masks are all
        ones for both (the paper's Table 1 row "Mono2 without the self-occlusion masks"). An added key.
    consistency_ego_mask: default true: L_con skips pixels on either camera's ego body; false: it does not
        (its own switch, for MCDP's row of the same ablation). An added key.
    temporal_weight: the weight of the temporal photometric term (each camera's reprojection from its own frames
        t-1 and t+1; default 1, Monodepth2's and vidar FSM's). 0 trains on a method's other terms alone: for FSM,
        its spatial and spatio-temporal terms (the cross-view-only ablation, OccNeRF arXiv 2312.09243 Table VI;
        vidar's FSM has no switch for it, so this one scales the term and keeps everything else, smoothness
        included). For Mono2 and MCDP a weight of 0 leaves only smoothness (and L_con): no depth signal. An added
        key; at 1 the step is bit-identical to before it (the term is not multiplied).
    """

    ssim_alpha: Float = Field(0.85, ge=0.0, le=1.0)
    smoothness_weight: Float = Field(1e-3, ge=0.0, le=MAX_WEIGHT, allow_inf_nan=False)
    consistency_weight: Float = Field(1e-3, ge=0.0, le=MAX_WEIGHT, allow_inf_nan=False)
    automask: bool = True
    out_of_view: Literal["identity", "border"] = "identity"
    refine_scales: int = Field(1, ge=1, le=4)
    reprojection: Literal["min", "mean"] = added_key("min")
    multiscale: Literal["full_res", "per_scale"] = added_key("full_res")
    photometric_ego_mask: bool = added_key(True)
    consistency_ego_mask: bool = added_key(True)
    temporal_weight: Float = added_key(1.0, ge=0.0, le=MAX_WEIGHT, allow_inf_nan=False)

    @model_validator(mode="after")
    def _check(self) -> "LossConfig":
        if self.reprojection == "mean" and self.out_of_view != "identity":
            raise ValueError("loss.reprojection=mean needs loss.out_of_view=identity (the mean over the sources that "
                             "see a pixel; an unseen pixel scores its identity error)")
        return self


class ScaleConfig(StrictModel):
    """Where metric scale comes from (depth must be in metres for cross-camera warping).

    source:
      ``velocity``: pose network per camera; its translation norm is supervised
        with the ego-odometry displacement transformed into the camera (PackNet).
      ``odometry``: no pose network; camera motion from the ego odometry directly.
      ``oracle_gt_median``: what the public reference code does: every depth is
        rescaled by median(GT)/median(pred) per image, in training AND inference.
        Reads ground truth; labelled ORACLE in every output.
    velocity_weight: weight of |‖t_pred‖ - ‖t_odom‖| (PackNet: 0.05).
    """

    source: Literal["velocity", "odometry", "oracle_gt_median"] = "velocity"
    velocity_weight: Float = Field(0.05, ge=0.0, le=MAX_WEIGHT, allow_inf_nan=False)

    @property
    def oracle(self) -> bool:
        return self.source == "oracle_gt_median"


def _upgrade_train(train: dict[str, Any]) -> dict[str, Any]:
    """The train section of an older version in today's keys: ``amp`` true -> precision auto, false -> fp32."""
    if "amp" not in train:
        return train
    train = dict(train)
    amp = train.pop("amp")
    train.setdefault("precision", "auto" if amp else "fp32")
    return train


class TrainConfig(StrictModel):
    """Optimisation and bookkeeping.

    steps: optimiser steps; batch_size: rig samples per step (each = 6 cameras x 3 frames); under
        torchrun the GLOBAL batch, split evenly over the ranks (`mcdp.distributed`).
    lr: Adam learning rate; decayed by lr_decay_factor after lr_decay_at * steps
        (paper: 1e-4, x0.1 after 15 of 20 epochs).
    height, width: training resolution (multiples of 32, ResNet skips).
    color_aug: Monodepth2 colour jitter (p=0.5) on the network input only.
    val_every: steps between val-split evaluations of the self-supervised loss
        (no ground truth); the lowest val loss is kept as checkpoints/best.pt.
    val_samples: val rig samples used each time (evenly spaced, fixed).
    ckpt_every: steps between checkpoints/last.pt writes (also written at the end).
    log_every, image_every: TensorBoard scalar / image cadence.
    precision: ``auto`` (bf16 autocast on a CUDA device that has it, else fp16 with a GradScaler;
        fp32 on CPU), ``fp32``, ``bf16`` (autocast; CPU too) or ``fp16`` (autocast + GradScaler;
        CUDA only). Geometry (warps, splatting) always runs in float32.
    device: ``auto`` (CUDA if available), ``cpu`` or ``cuda``.
    num_workers: DataLoader processes (0 = in the main process).
    threads: torch intra-op CPU threads (0 = torch's default). On a shared
        machine 1 avoids the heavy slow-down of oversubscribed OpenMP threads.
    grad_clip: max global grad norm (> 0, finite), or null.
    weight_lr_mult: the learning rate of the depth network's fresh layers (MCDP's weight networks,
        `mcdp.methods.surround`'s cross-view attention: ``DepthModel.fresh_parameters``) is ``lr *
        weight_lr_mult`` (1 = one rate for every parameter). They start fresh while the encoder and decoder come from a
        pretraining, and at one small rate they did not move in a 100-step fine-tuning
        (docs/results/refinement.md).
    """

    steps: int = Field(20000, ge=1, le=MAX_STEPS)
    batch_size: int = Field(1, ge=1, le=256)
    lr: Float = Field(1e-4, gt=0.0, le=1.0, allow_inf_nan=False)
    lr_decay_at: Float = Field(0.75, gt=0.0, le=1.0)
    lr_decay_factor: Float = Field(0.1, gt=0.0, le=1.0)
    height: int = Field(192, ge=32, le=2048)
    width: int = Field(320, ge=32, le=4096)
    seed: int = Field(0, ge=0, le=2**32 - 1)
    color_aug: bool = True
    val_every: int = Field(1000, ge=1, le=MAX_STEPS)
    val_samples: int = Field(16, ge=1, le=100_000)
    ckpt_every: int = Field(1000, ge=1, le=MAX_STEPS)
    log_every: int = Field(50, ge=1, le=MAX_STEPS)
    image_every: int = Field(500, ge=1, le=MAX_STEPS)
    precision: Literal["auto", "fp32", "bf16", "fp16"] = "auto"
    device: Literal["auto", "cpu", "cuda"] = "auto"
    num_workers: int = Field(2, ge=0, le=64)
    threads: int = Field(0, ge=0, le=1024)
    grad_clip: Float | None = Field(None, gt=0.0, le=1e6, allow_inf_nan=False)
    weight_lr_mult: Float = Field(1.0, gt=0.0, le=MAX_WEIGHT, allow_inf_nan=False)

    @model_validator(mode="before")
    @classmethod
    def _old_amp_key(cls, data: Any) -> Any:
        """``train.amp`` (before precision existed): true -> auto, false -> fp32."""
        return _upgrade_train(data) if isinstance(data, dict) else data

    @model_validator(mode="after")
    def _check(self) -> "TrainConfig":
        for key in ("height", "width"):
            v = getattr(self, key)
            if v % 32:
                raise ValueError(f"train.{key}={v} must be a multiple of 32 (ResNet skip connections)")
        px = self.batch_size * self.height * self.width
        if px > MAX_STEP_PIXELS:
            gb = px * IMAGES_PER_SAMPLE * 3 * 4 / 1e9
            raise ValueError(f"train.batch_size x height x width = {self.batch_size} x {self.height} x {self.width} "
                             f"= {px} pixels per camera image and step, above the limit {MAX_STEP_PIXELS}: the "
                             f"float32 input alone would be {gb:.1f} GB ({IMAGES_PER_SAMPLE} images a rig sample), "
                             "the activations many times that")
        return self


#: the evaluation's depth range in metres (Monodepth2's and the paper's: ground truth outside it is not scored,
#: predictions are clamped to it); the one source of `EvalConfig`'s and the sweep's defaults and `mcdp.metrics`'
EVAL_MIN_DEPTH, EVAL_MAX_DEPTH = 0.5, 80.0


class EvalConfig(StrictModel):
    """Evaluation settings (depths in metres; `mcdp.evaluate` reads them)."""

    min_depth: float = Field(EVAL_MIN_DEPTH, le=1000.0, allow_inf_nan=False)
    max_depth: float = Field(EVAL_MAX_DEPTH, le=1000.0, allow_inf_nan=False)
    frame_stride: int = Field(1, le=10_000)  # evaluate every k-th frame
    skip_ends: bool = True  # skip first and last frame of each sequence (no temporal neighbours)

    @field_validator("min_depth")
    @classmethod
    def _min_pos(cls, v: float) -> float:
        if not v > 0:
            raise ValueError(f"must be > 0, got {v}")
        return v

    @field_validator("frame_stride")
    @classmethod
    def _stride_pos(cls, v: int) -> int:
        if v < 1:
            raise ValueError(f"must be >= 1, got {v}")
        return v

    @model_validator(mode="after")
    def _range(self):
        if not self.max_depth > self.min_depth:
            raise ValueError(f"max_depth ({self.max_depth}) must be > min_depth ({self.min_depth})")
        return self


class RunConfig(StrictModel):
    """Everything that defines a run; saved with it."""

    model: ModelConfig = ModelConfig()
    loss: LossConfig = LossConfig()
    scale: ScaleConfig = ScaleConfig()
    train: TrainConfig = TrainConfig()
    eval: EvalConfig = EvalConfig()
    #: the method's own parameters, checked against its registry row's params class (module docstring)
    method_params: dict[str, Any] = added_key(default_factory=dict)


# Keys that may change when a run is resumed (they do not change what is learned
# up to the current step, or only extend it). ``model.init_from`` is read by a fresh run only (a resumed one
# starts from its checkpoint): its path changes when a sweep folder is moved.
RESUMABLE_KEYS = (
    "model.init_from",
    "train.steps",
    "train.val_every",
    "train.val_samples",
    "train.ckpt_every",
    "train.log_every",
    "train.image_every",
    "train.num_workers",
    "train.threads",
    "train.device",
    "train.precision",
    "eval.",
)


def upgrade_config_dict(d: dict[str, Any]) -> dict[str, Any]:
    """A saved run config of an older version in today's keys (`_upgrade_train`)."""
    train = d.get("train")
    d = {**d, "train": _upgrade_train(train)} if isinstance(train, dict) else d
    return d if "method_params" in d else {**d, "method_params": {}}  # saved before the section existed


def resume_conflicts(saved: dict[str, Any], requested: dict[str, Any]) -> list[str]:
    """Dotted keys where a saved run config and a requested one differ in a way resume cannot honour."""
    from corelib.configlib import diff_configs

    return [k for k in diff_configs(saved, requested) if not any(k == p or (p.endswith(".") and k.startswith(p)) for p in RESUMABLE_KEYS)]
