"""One self-supervised training step, in Monodepth2's order: inputs -> predict poses -> predict
depth -> warp -> losses (`SelfSupervisedSystem.process_batch`). Each term is a tested function of
`mcdp.losses`; this module only decides which pixels, stages and scales they see.

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
- a method's own terms (its network's `mcdp.methods.base.DepthNetwork.loss_terms`, none for MCDP and
  Mono2), added weighted as the method returns them; what they read of the step besides the
  outputs and the batch is a `mcdp.methods.base.LossContext` (the poses, the camera pairs, the step, the
  method's own parameters), never an entry written into ``outputs``.

Example::

    system = SelfSupervisedSystem(cfg, ds.neighbours, len(ds.camera_names))
    outputs, losses = system.process_batch(batch, step=0, train=True)
    losses["loss"].backward()
"""
from __future__ import annotations

import torch
import torch.nn.functional as F

from mcdp.config import RunConfig
from mcdp.data import directed_pairs, neighbour_table
from mcdp.geometry import scale_intrinsics, splat_depth, warp_by_depth
from mcdp.inputs import RigBatch
from mcdp.losses import consistency_loss, photometric_error, reprojection_loss, smoothness_loss
from mcdp.methods import fields_of, method_of, method_params
from mcdp.methods.base import LossContext, is_refined, resize_mask_to
from mcdp.pose import PoseModel
from mcdp.rigid import odometry_camera_motion


# --------------------------------------------------------------------------- augmentation
def color_augment(rgb: torch.Tensor, seed: int, step: int, offset: int = 0, global_batch: int | None = None
                  ) -> torch.Tensor:
    """Monodepth2-style colour jitter (p = 0.5 per camera; brightness, contrast, saturation +-0.2).

    One draw per (rig sample, camera), shared by its three frames; drawn from a
    generator seeded by (seed, step), so resumed runs see the same jitter.
    Network input only; losses use the original images.

    Args:
        rgb: (B, N, F, 3, H, W) in [0, 1].
        offset, global_batch: this batch is samples ``offset .. offset + B - 1`` of a global batch
            (a torchrun rank's share): each sample gets the draw it gets in one process.
    """
    B, N = rgb.shape[:2]
    g = torch.Generator().manual_seed(int(seed) * 7_919 + int(step) * 104_729 + 17)
    u = torch.rand(global_batch or B, N, 4, generator=g)[offset:offset + B]
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
    scalar to minimise, other entries are detached scalar statistics (every
    value a 0-d tensor). ``outputs`` are the depth network's, plus the step's
    one entry ``"used"``: (B*N, 1, H, W) the pixels L_p counted at the final
    stage, full resolution (the image log's green mask).
    """

    def __init__(self, cfg: RunConfig, neighbours, n_cams: int):
        super().__init__()
        self.cfg = cfg
        method = method_of(cfg.model)
        self.params = method_params(cfg)  # the method's own parameters (LossContext.params), or None
        self.depth = method.builder(cfg.model, self.params)
        self.fields = fields_of(cfg)  # the optional inputs its batches carry (`mcdp.inputs.InputField`)
        self.pose = PoseModel(cfg.model.pretrained) if cfg.scale.source != "odometry" else None
        self.register_buffer("nbr", neighbour_table(neighbours, n_cams), persistent=False)
        tgt, src = directed_pairs(neighbours)
        self.register_buffer("pair_tgt", tgt, persistent=False)
        self.register_buffer("pair_src", src, persistent=False)
        self.use_amp = False
        self.amp_dtype = torch.float16
        self.shard = (0, 1)  # (rank, world) under torchrun: which part of the global batch this is

    @property
    def device(self) -> torch.device:
        return self.nbr.device

    def param_groups(self, weight_lr_mult: float) -> list[dict]:
        """The optimiser's parameter groups: the depth network's fresh layers (``fresh_parameters``: MCDP's
        weight networks, SurroundDepth's attention, ...) at ``weight_lr_mult`` x the rate (``lr_mult``), every
        other parameter (the pose network's too) at the rate."""
        fresh = list(self.depth.fresh_parameters())
        fresh_ids = {id(p) for p in fresh}
        groups = [{"params": [p for p in self.parameters() if id(p) not in fresh_ids], "lr_mult": 1.0}]
        return groups + ([{"params": fresh, "lr_mult": weight_lr_mult}] if fresh else [])

    def predict_poses(self, batch: RigBatch, net_rgb: torch.Tensor) -> tuple[dict, dict]:
        """T_src_tgt per source offset, (B*N, 4, 4), and pose statistics/velocity loss terms."""
        B, N = batch.rgb.shape[:2]
        odom = {o: odometry_camera_motion(batch.T_world_ego, batch.T_ego_cam, o) for o in (-1, 1)}
        stats = {}
        if self.pose is None:
            poses = odom
        else:
            with torch.autocast(self.device.type, dtype=self.amp_dtype, enabled=self.use_amp):
                # a network that moves the rig as one (`joint_pose`: mcdp.methods.surround) gets the extrinsics
                joint = batch.T_ego_cam if self.depth.joint_pose else None
                poses = self.pose(net_rgb, joint)
            t_pred = torch.stack([poses[o][..., :3, 3].norm(dim=-1) for o in (-1, 1)])  # (2, B, N)
            t_odom = torch.stack([odom[o][..., :3, 3].norm(dim=-1) for o in (-1, 1)])
            stats["velocity"] = (t_pred - t_odom).abs().mean()
            stats["t_norm_pred"] = t_pred.detach().mean()
            stats["t_norm_odom"] = t_odom.mean()
        return {o: p.reshape(B * N, 4, 4).float() for o, p in poses.items()}, stats

    def process_batch(self, batch: RigBatch, step: int = 0, train: bool = True, need_con: bool | None = None) -> tuple[dict, dict]:
        """Forward + losses for one batch (schema in `mcdp.data`). Returns (outputs, losses)."""
        cfg = self.cfg
        rgb = batch.rgb
        B = rgb.shape[0]
        rank, world = self.shard
        net_rgb = (color_augment(rgb, cfg.train.seed, step, rank * B, world * B)
                   if (train and cfg.train.color_aug) else rgb)
        with torch.autocast(self.device.type, dtype=self.amp_dtype, enabled=self.use_amp):
            outputs = self.depth(batch.depth_input(self.nbr, self.fields, net_rgb),
                                 scales=cfg.model.scales, refine_scales=cfg.loss.refine_scales)
        poses, pose_stats = self.predict_poses(batch, net_rgb)
        losses = self.compute_losses(batch, outputs, poses, need_con=need_con, step=step)
        for k, v in pose_stats.items():
            losses[f"pose/{k}"] = v
        if "velocity" in pose_stats and cfg.scale.source == "velocity":
            losses["loss"] = losses["loss"] + cfg.scale.velocity_weight * pose_stats["velocity"]
        return outputs, losses

    forward = process_batch  # DistributedDataParallel calls forward: its gradient hooks need it

    def compute_losses(self, batch: RigBatch, outputs: dict, poses: dict, need_con: bool | None = None,
                       step: int = 0) -> dict:
        """Photometric + smoothness per stage and scale, L_con per stage, the method's own terms (module
        docstring); writes ``outputs["used"]``."""
        cfg = self.cfg
        rgb = batch.rgb.float()
        B, N, _, C, H, W = rgb.shape
        BN = B * N
        target = rgb[:, :, 1].reshape(BN, C, H, W)
        sources = [rgb[:, :, 1 + o].reshape(BN, C, H, W) for o in (-1, 1)]
        mask = batch.mask.reshape(BN, 1, H, W).float()
        if not cfg.loss.photometric_ego_mask:  # the ablation without self-occlusion masks (LossConfig)
            mask = torch.ones_like(mask)
        K = batch.K.reshape(BN, 3, 3).float()
        lens = None if batch.lens is None else batch.lens.of()  # each item's lens (None: pinhole, the path of before)
        scales = list(range(cfg.model.scales))
        img_s = {s: target if s == 0 else F.avg_pool2d(target, 2**s) for s in scales}
        mask_s = {s: mask if s == 0 else resize_mask_to(mask, H // 2**s, W // 2**s) for s in scales}
        lam = cfg.loss.consistency_weight
        need_con = lam > 0 if need_con is None else need_con
        need_ident = cfg.loss.automask or cfg.loss.out_of_view == "identity"

        def level(s: int) -> tuple:
            """(target, [source (3 ch) + its ego mask (1 ch)] per source, K, mask, identity error) at scale s:
            full resolution, or scale s's own (``loss.multiscale=per_scale``, Monodepth2's v1_multiscale)."""
            tgt, srcs, K_s = target, sources, K
            if s > 0:
                tgt, srcs = img_s[s], [F.avg_pool2d(x, 2**s) for x in sources]
                K_s = scale_intrinsics(K, tgt.shape[-1] / W, tgt.shape[-2] / H)
            ident = None  # the identity error does not depend on depth: once per batch, not per stage and scale
            if need_ident:
                with torch.no_grad():
                    ident = torch.cat([photometric_error(sc, tgt, cfg.loss.ssim_alpha) for sc in srcs], 1)
                    ident = (ident.min(1, keepdim=True).values if cfg.loss.reprojection == "min"
                             else ident.mean(1, keepdim=True))  # (BN, 1, h, w)
            m = mask_s[s]
            return tgt, [torch.cat([x, m], 1) for x in srcs], K_s, m, ident  # the ego body is static in each camera

        per_scale = cfg.loss.multiscale == "per_scale"
        levels = {0: level(0)}
        losses: dict = {}
        total = 0.0
        for stage in outputs["stages"]:
            lp_sum = 0.0
            st_scales = scales[: cfg.loss.refine_scales] if is_refined(stage) else scales
            for s in st_scales:
                if per_scale and s > 0:  # scale s's depth at its own resolution (disp = 1 / depth there)
                    if s not in levels:
                        levels[s] = level(s)
                    tgt, src_and_mask, K_s, m_s, ident = levels[s]
                    depth = 1.0 / outputs["disp", stage, s].float()
                    if outputs.get("scale") is not None:  # the ORACLE scale mode's factor (1 otherwise)
                        depth = depth * outputs["scale"].float().view(BN, 1, 1, 1)
                else:
                    tgt, src_and_mask, K_s, m_s, ident = levels[0]
                    depth = outputs["depth", stage, s].float()
                warped, valid = [], []
                for o, sm in zip((-1, 1), src_and_mask):
                    w, v = warp_by_depth(sm, depth, K_s, K_s, poses[o], padding_mode="border", lens_tgt=lens,
                                         lens_src=lens)
                    warped.append(w[:, :C])
                    valid.append(v * (w[:, C:] > 0.99).to(v.dtype))  # not onto the source's ego body
                rep, _, used = reprojection_loss(tgt, warped, valid, None, m_s, cfg.loss.automask,
                                                 cfg.loss.ssim_alpha, cfg.loss.out_of_view, ident=ident,
                                                 reduce=cfg.loss.reprojection)
                smooth = smoothness_loss(outputs["disp", stage, s].float(), img_s[s], mask_s[s])
                rep_w = rep if cfg.loss.temporal_weight == 1.0 else cfg.loss.temporal_weight * rep  # 1: not multiplied
                lp_sum = lp_sum + rep_w + cfg.loss.smoothness_weight * smooth / (2**s)
                if s == 0:
                    losses[f"reprojection/{stage}"] = rep.detach()
                    losses[f"smoothness/{stage}"] = smooth.detach()
                    if stage == outputs["stages"][-1]:
                        outputs["used"] = used.detach()
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
        ctx = LossContext(cfg=cfg, params=self.params, poses=poses, pairs=(self.pair_tgt, self.pair_src), step=step)
        for name, term in self.depth.loss_terms(outputs, batch, ctx).items():
            losses[name] = term.detach()
            total = total + term
        losses["loss"] = total
        return losses

    def consistency(self, depth: torch.Tensor, batch: RigBatch) -> torch.Tensor:
        """L_con over every directed adjacent pair: (B*N, 1, H, W) depth -> scalar (metres)."""
        B, N = batch.rgb.shape[:2]
        H, W = depth.shape[-2:]
        tgt, src = self.pair_tgt, self.pair_src
        P = tgt.numel()
        d = depth.view(B, N, 1, H, W)
        m = batch.mask.float()
        if not self.cfg.loss.consistency_ego_mask:  # L_con's own switch of the no-masks ablation (LossConfig)
            m = torch.ones_like(m)
        K = batch.K.float()
        T = batch.T_ego_cam.float()
        T_tgt_src = torch.linalg.inv(T[:, tgt]) @ T[:, src]  # (B, P, 4, 4)
        d_hat, hit = splat_depth(
            d[:, src].reshape(B * P, 1, H, W),
            K[:, src].reshape(B * P, 3, 3),
            K[:, tgt].reshape(B * P, 3, 3),
            T_tgt_src.reshape(B * P, 4, 4),
            H,
            W,
            valid_src=m[:, src].reshape(B * P, 1, H, W),
            lens_src=None if batch.lens is None else batch.lens.of(src),
            lens_tgt=None if batch.lens is None else batch.lens.of(tgt),
        )
        return consistency_loss(d[:, tgt].reshape(B * P, 1, H, W), d_hat, hit, m[:, tgt].reshape(B * P, 1, H, W))
