"""FSM: Full Surround Monodepth (Guizilini et al., "Full Surround Monodepth from Multiple Cameras",
RA-L 2022), the method ``fsm``: the rig's overlap used in TRAINING only.

Network and inference are Monodepth2's (`FsmDepthModel` is `mcdp.methods.depth_bases.MonoDepthModel` under
its own name): one image in, one depth out, no neighbour at inference, so cutting the neighbours
at inference changes nothing (``study.sweep.probes.Probed(pred, CUT)`` predicts the same depth; tested). What
makes it FSM is its loss, on top of the system's temporal Monodepth2 term (`mcdp.system`: the
per-pixel minimum over frames t-1 / t+1 of the same camera, auto-masked, weight 1):

- **spatial + spatio-temporal photometric term** (`spatial_photometric`): for every directed
  pair of adjacent cameras (target i, source j) the target image is synthesised from three
  contexts of camera j: j at t (through the extrinsics: T_cj_ci = inv(T_ego_cj) T_ego_ci, metric
  by construction) and j at t-1 / t+1 (through the extrinsics and camera j's motion:
  T_cj(t+o)_ci(t) = M_j(o) T_cj_ci, with M_j predicted by the pose network or, with
  ``scale.source=odometry``, the given rig motion). Per pixel the minimum over the contexts that
  see it; self-occlusion (ego-body) masks on both sides of every warp: a target pixel on the
  target's ego body never counts, a context pixel whose sample lands on the source's ego body is
  invalid. Out-of-view or behind-the-camera samples are invalid; a pixel no context sees is left
  out, so a pair without overlap contributes nothing. No auto-masking here (as in the authors'
  released code, vidar ``FSMModel``: ``automask=False`` for the spatial contexts): a neighbour's
  unwarped image is another viewpoint, not a "nothing moved" explanation. The term of a pair is
  the mean over its seen pixels (all scales of the decoder, as the temporal term); the pairs are
  summed and divided by the number of cameras (the temporal term is a mean over cameras), so each
  directed pair weighs ``SPATIAL_WEIGHT`` against a camera's temporal term, as in vidar.
- **pose consistency** (`pose_consistency`, only where a pose network predicts each camera's
  motion: ``scale.source`` velocity or oracle_gt_median; with ``odometry`` the rig motion is
  given and already consistent): every camera's predicted motion, moved into the front camera's
  frame through the extrinsics (T_ref_j M_j T_ref_j^-1), must equal the front camera's own;
  squared translation (m^2) and squared Euler-angle (rad^2) differences, summed over the other
  cameras, mean over the batch and the two temporal directions (the paper's L_pcc).

Weights (`FsmParams`: the run config's ``method_params`` section, e.g.
``method_params.spatial_weight=0.2``; the defaults are the module constants below, and a run that
leaves the section empty keeps its config hash; the reasons for the defaults are here):

- ``SPATIAL_WEIGHT = 0.1``: the authors' released FSM model (TRI-ML/vidar
  ``arch/models/depth/FSMModel.py``, ``stereo_weight = 0.1``): the spatial contexts see the scene
  across a wide baseline, with larger occlusions and viewpoint-dependent appearance than the
  temporal ones, and only in the overlap; they add metric scale and cross-camera constraints to
  the temporal term rather than replace it.
- ``POSE_TRANSLATION_WEIGHT = POSE_ROTATION_WEIGHT = 1.0``: the paper's L_pcc weights alpha_t and
  alpha_r on unit footing; the released vidar FSM model has no pose-consistency term and its
  ``PoseConsistencyLoss`` takes both weights from configs that are not released, so no other value
  could be checked here. Squared errors in metres and radians are small for a nearly consistent rig
  (1 cm -> 1e-4), so the term only bites on clearly inconsistent motions.
- temporal term 1 and smoothness 1e-3 / 2^s: the system's Monodepth2 terms, as for ``mono2``.

Each term a switch (the calibration's ablations, issue 57): the temporal term ``loss.temporal_weight=0``
(`mcdp.config.LossConfig`); the spatial and spatio-temporal terms together ``method_params.spatial_weight=0``;
the spatio-temporal contexts alone ``method_params.spatio_temporal=false`` (the neighbour at t only); pose
consistency ``method_params.pose_translation_weight=0`` and ``pose_rotation_weight=0`` (it exists only with a
pose network). Each default leaves the step bit-identical.

Not taken from vidar: its spatial masks also drop the top 15 % and bottom 25 % of image rows (a
DDAD-specific crop); our renders have exact ego-body masks instead.

Warm start (``model.init_from``): every depth layer (encoder, decoder, the mono head as its
one-channel output) comes from the shared pretraining exactly as for ``mono2``; nothing of the
depth network starts fresh. The pose network starts as for every method (not pretrained there).
"""
from __future__ import annotations

import torch
from pydantic import Field

from corelib.configlib import StrictModel
from mcdp.config import MAX_WEIGHT, Float
from mcdp.geometry import warp_by_depth
from mcdp.losses import min_reprojection, photometric_error
from mcdp.methods.base import LossContext
from mcdp.methods.depth_bases import MonoDepthModel

SPATIAL_WEIGHT = 0.1
POSE_TRANSLATION_WEIGHT = 1.0
POSE_ROTATION_WEIGHT = 1.0
#: the contexts of a neighbour camera: same time (spatial), then t-1 and t+1 (spatio-temporal)
CONTEXTS = (0, -1, 1)


class FsmParams(StrictModel):
    """FSM's own loss weights (``method_params``; module docstring): the spatial photometric term's and the
    pose consistency's translation (per m^2) and rotation (per rad^2) weights."""

    spatial_weight: Float = Field(SPATIAL_WEIGHT, ge=0, le=MAX_WEIGHT, allow_inf_nan=False)
    #: the neighbours' frames t-1 and t+1 among the spatial term's contexts (``CONTEXTS``); false: the neighbour
    #: at t alone (the spatial term without its spatio-temporal part). vidar's FSM takes both.
    spatio_temporal: bool = True
    pose_translation_weight: Float = Field(POSE_TRANSLATION_WEIGHT, ge=0, le=MAX_WEIGHT, allow_inf_nan=False)
    pose_rotation_weight: Float = Field(POSE_ROTATION_WEIGHT, ge=0, le=MAX_WEIGHT, allow_inf_nan=False)


class FsmDepthModel(MonoDepthModel):
    """FSM's depth network: Monodepth2's, one image in, one depth out (no neighbour at inference); its own
    loss terms are `fsm_loss`."""

    def loss_terms(self, outputs: dict, batch, ctx: LossContext) -> dict:
        return fsm_loss(outputs, batch, ctx)


def spatial_photometric(depth: torch.Tensor, rgb: torch.Tensor, mask: torch.Tensor, K: torch.Tensor,
                        T_ego_cam: torch.Tensor, motions: dict, tgt: torch.Tensor, src: torch.Tensor,
                        alpha: float = 0.85, contexts=CONTEXTS, lens=None) -> dict:
    """FSM's spatial (+ spatio-temporal) photometric error of every directed camera pair (tgt, src).

    Args:
        depth: (B, N, 1, H, W) z-depth of every camera at t, metres.
        rgb: (B, N, 3, 3, H, W) frames t-1, t, t+1 in [0, 1].
        mask: (B, N, 1, H, W) 1 = scene, 0 = ego body.
        K: (B, N, 3, 3) intrinsics at H x W; T_ego_cam: (B, N, 4, 4).
        motions: {o: (B, N, 4, 4)} T_cam(t+o)_cam(t) of every camera, for each o != 0 in ``contexts``.
        tgt, src: (P,) int64 camera indices of the directed pairs.
        alpha: SSIM weight of the photometric error.
        contexts: which times of the source camera are warped: 0 (spatial), -1 / +1 (spatio-temporal).
        lens: the cameras' lenses (`mcdp.camera.Lens`, dist (B, N, D)), None for a pinhole rig; with one, depth
            is of each camera's depth kind and the warps go through the lenses.

    Returns:
        {"pair": (P,) mean over seen pixels of the per-pixel minimum (0 for a pair that sees nothing),
         "per_pixel": (B, P, 1, H, W) that minimum (border-padded error where no context sees the pixel),
         "seen": (B, P, 1, H, W) float 0/1, some context sees the target scene pixel,
         "errors" / "valid": lists, per context, of (B, P, 1, H, W)}.
    """
    B, N, _, H, W = depth.shape
    P = int(tgt.numel())
    BP = B * P
    T = T_ego_cam.float()
    T_src_tgt = torch.linalg.inv(T[:, src]) @ T[:, tgt]  # (B, P, 4, 4) camera i at t -> camera j at t
    K_t = K[:, tgt].reshape(BP, 3, 3).float()
    K_s = K[:, src].reshape(BP, 3, 3).float()
    d = depth[:, tgt].reshape(BP, 1, H, W).float()
    target = rgb[:, tgt, 1].reshape(BP, 3, H, W).float()
    m_tgt = mask[:, tgt].reshape(BP, 1, H, W).float()
    m_src = mask[:, src].reshape(BP, 1, H, W).float()
    errors, valid = [], []
    for o in contexts:
        T_ctx = T_src_tgt if o == 0 else motions[o][:, src].float() @ T_src_tgt
        src_img = torch.cat([rgb[:, src, 1 + o].reshape(BP, 3, H, W).float(), m_src], 1)
        w, v = warp_by_depth(src_img, d, K_t, K_s, T_ctx.reshape(BP, 4, 4), padding_mode="border",
                             lens_tgt=None if lens is None else lens.of(tgt),
                             lens_src=None if lens is None else lens.of(src))
        v = v * (w[:, 3:] > 0.99).to(v.dtype) * m_tgt  # self-occlusion on both sides of the warp
        errors.append(photometric_error(w[:, :3], target, alpha))
        valid.append(v)
    per_pixel, seen = min_reprojection(errors, valid)
    seen = seen.to(per_pixel.dtype)
    pp = per_pixel.view(B, P, 1, H, W)
    sn = seen.view(B, P, 1, H, W)
    total = torch.where(sn > 0, pp, torch.zeros_like(pp)).sum(dim=(0, 2, 3, 4))
    count = sn.sum(dim=(0, 2, 3, 4))
    return {"pair": total / count.clamp(min=1), "per_pixel": pp, "seen": sn,
            "errors": [e.view(B, P, 1, H, W) for e in errors], "valid": [v.view(B, P, 1, H, W) for v in valid]}


def euler_angles(R: torch.Tensor) -> torch.Tensor:
    """(..., 3, 3) rotation -> (..., 3) angles (x, y, z) in radians of R = Rz Ry Rx."""
    rx = torch.atan2(R[..., 2, 1], R[..., 2, 2])
    ry = torch.asin((-R[..., 2, 0]).clamp(-1 + 1e-6, 1 - 1e-6))
    rz = torch.atan2(R[..., 1, 0], R[..., 0, 0])
    return torch.stack([rx, ry, rz], -1)


def pose_consistency(motions: dict, T_ego_cam: torch.Tensor, ref: int = 0) -> tuple[torch.Tensor, torch.Tensor]:
    """FSM's pose consistency: every camera's motion seen from the reference (front) camera.

    Args:
        motions: {o: (B, N, 4, 4)} T_cam(t+o)_cam(t) per camera (predicted).
        T_ego_cam: (B, N, 4, 4) extrinsics.
        ref: the reference camera (rig order: 0 = CAM_FRONT).

    Returns:
        (translation, rotation): squared differences to the reference's motion, summed over the
        cameras, mean over the batch and the directions o; (m^2, rad^2). 0 for a rigid rig motion.
    """
    X = T_ego_cam.float()
    A = torch.linalg.inv(X[:, ref:ref + 1]) @ X  # (B, N, 4, 4) camera j -> reference camera, rigid
    A_inv = torch.linalg.inv(A)
    t_err, r_err = [], []
    for o in sorted(motions):
        M = A @ motions[o].float() @ A_inv  # camera j's motion in the reference camera's frame
        t_err.append((M[..., :3, 3] - M[:, ref:ref + 1, :3, 3]).pow(2).sum(-1).sum(1).mean())
        ang = euler_angles(M[..., :3, :3])
        r_err.append((ang - ang[:, ref:ref + 1]).pow(2).sum(-1).sum(1).mean())
    return torch.stack(t_err).mean(), torch.stack(r_err).mean()


def fsm_loss(outputs: dict, batch, ctx: LossContext) -> dict:
    """FSM's own terms for `mcdp.system.SelfSupervisedSystem` (weighted; module docstring).

    Reads from ``batch`` (the step's `mcdp.inputs.RigBatch`) the images and the rig, from ``outputs`` the depths of every stage and scale, and from the step's `LossContext` its
    ``poses`` ({-1, +1}: (B*N, 4, 4) T_src_tgt, the camera motions of the temporal warps) and ``pairs``.
    """
    cfg, w = ctx.cfg, ctx.params or FsmParams()
    rgb = batch.rgb.float()
    B, N = rgb.shape[:2]
    H, W = rgb.shape[-2:]
    tgt, src = ctx.pairs
    motions = {o: p.reshape(B, N, 4, 4) for o, p in ctx.poses.items()}
    out: dict = {}
    # loss.photometric_ego_mask false (the no-masks ablation) reaches the spatial terms too
    mask = batch.mask if cfg.loss.photometric_ego_mask else torch.ones_like(batch.mask)
    if tgt.numel() > 0 and w.spatial_weight > 0:
        total = 0.0
        for stage in outputs["stages"]:
            scales = [s for s in range(8) if ("depth", stage, s) in outputs]
            st = 0.0
            for s in scales:
                depth = outputs["depth", stage, s].reshape(B, N, 1, H, W)
                r = spatial_photometric(depth, rgb, mask, batch.K, batch.T_ego_cam, motions,
                                        tgt, src, cfg.loss.ssim_alpha,
                                        contexts=CONTEXTS if w.spatio_temporal else (0,), lens=batch.lens)
                st = st + r["pair"].sum() / N
            total = total + st / len(scales)
        out["fsm/spatial"] = w.spatial_weight * total
    if cfg.scale.source != "odometry":  # a pose network predicts each camera's motion
        t, r = pose_consistency(motions, batch.T_ego_cam)
        out["fsm/pose_consistency"] = w.pose_translation_weight * t + w.pose_rotation_weight * r
    return out
