"""The recipe's switches for the calibration against real-data ablations (issue 57, item 1): each default leaves
the run's hash and the training step as they were; each switch, when on, changes what it should and nothing else."""
from __future__ import annotations

import pytest
import torch

from corelib.configlib import build_config, config_hash
from mcdp.config import RunConfig
from mcdp.losses import identity_floored_error, reprojection_loss
from mcdp.methods.depth_bases import DepthModel
from mcdp.system import SelfSupervisedSystem

from .test_model import H, RING, W, N, rig_batch, run_cfg, small_model_cfg

pytestmark = pytest.mark.usefixtures("one_thread")

SWITCHES = {"loss": {"reprojection": "min", "multiscale": "full_res", "photometric_ego_mask": True,
                     "consistency_ego_mask": True, "temporal_weight": 1.0},
            "model": {"warm_start": True, "feature_ego_mask": True}}


def test_every_switch_at_its_default_leaves_the_run_hash():
    plain = build_config(RunConfig, {})
    explicit = build_config(RunConfig, SWITCHES)
    assert config_hash(plain) == config_hash(explicit)
    off = build_config(RunConfig, {"loss": {"reprojection": "mean"}})
    assert config_hash(off) != config_hash(plain)


def test_mean_reprojection_needs_identity_out_of_view():
    with pytest.raises(Exception, match="loss.reprojection=mean needs loss.out_of_view=identity"):
        build_config(RunConfig, {"loss": {"reprojection": "mean", "out_of_view": "border"}})


def test_mean_reprojection_is_the_mean_of_the_seeing_sources_on_a_hand_built_case():
    e1 = torch.tensor([[[[0.2, 0.4, 0.9]]]])
    e2 = torch.tensor([[[[0.6, 0.1, 0.3]]]])
    v1 = torch.tensor([[[[1.0, 1.0, 0.0]]]])  # pixel 2: only source 2 sees it
    v2 = torch.tensor([[[[1.0, 1.0, 1.0]]]])
    ident = torch.full((1, 1, 1, 3), 10.0)  # larger than every error: auto-masking keeps every seen pixel
    mean, used = identity_floored_error([e1, e2], [v1, v2], ident, automask=True, reduce="mean")
    assert torch.allclose(mean, torch.tensor([[[[0.4, 0.25, 0.3]]]]))
    mn, _ = identity_floored_error([e1, e2], [v1, v2], ident, automask=True, reduce="min")
    assert torch.allclose(mn, torch.tensor([[[[0.2, 0.1, 0.3]]]]))
    # a pixel no source sees scores its identity error under both rules
    none = torch.zeros_like(v1)
    m0, u0 = identity_floored_error([e1, e2], [none, none], ident, reduce="mean")
    assert torch.equal(m0, ident) and float(u0.sum()) == 0.0


def test_mean_reprojection_loss_averages_the_identity_errors_too():
    g = torch.Generator().manual_seed(0)
    tgt = torch.rand(1, 3, 8, 8, generator=g)
    srcs = [torch.rand(1, 3, 8, 8, generator=g) for _ in range(2)]
    ones = torch.ones(1, 1, 8, 8)
    # the warped images ARE the sources: every reprojection error equals its identity error, so with auto-masking
    # each pixel scores min(mean reprojection, mean identity) = the mean of the two sources' errors
    loss_mean, per_pixel, _ = reprojection_loss(tgt, srcs, [ones, ones], srcs, ones, True, 0.85, "identity",
                                                reduce="mean")
    from mcdp.losses import photometric_error

    expect = (photometric_error(srcs[0], tgt) + photometric_error(srcs[1], tgt)) / 2
    assert torch.allclose(per_pixel, expect, atol=1e-6)
    loss_min, _, _ = reprojection_loss(tgt, srcs, [ones, ones], srcs, ones, True, 0.85, "identity")
    assert float(loss_min) < float(loss_mean)


def _step_losses(cfg: RunConfig, batch, seed: int = 0) -> dict:
    torch.manual_seed(seed)
    system = SelfSupervisedSystem(cfg, RING, N)
    system.eval()
    with torch.no_grad():
        _, losses = system.process_batch(batch, step=0, train=False)
    return {k: float(v) for k, v in losses.items() if torch.is_tensor(v) and v.dim() == 0}


def _mono(**sections) -> RunConfig:
    return run_cfg({"method": "mono2", "bases": 1, "refine_steps": 0},
                   scale={"source": "odometry"}, **sections)


def test_defaults_give_the_same_step_as_explicit_defaults():
    batch = rig_batch()
    a = _step_losses(_mono(), batch)
    b = _step_losses(_mono(loss=SWITCHES["loss"]), batch)
    assert a == b


def _fixed_depth_losses(cfg: RunConfig, batch, poked) -> tuple[dict, dict]:
    """One step's losses on ``batch`` and on ``poked`` from the SAME depth and poses (those of ``batch``)."""
    torch.manual_seed(0)
    system = SelfSupervisedSystem(cfg, RING, N).eval()
    with torch.no_grad():
        outputs = system.depth(batch.depth_input(system.nbr, system.fields, batch.rgb), scales=cfg.model.scales,
                               refine_scales=cfg.loss.refine_scales)
        poses, _ = system.predict_poses(batch, batch.rgb)
        out = []
        for b in (batch, poked):
            losses = system.compute_losses(b, dict(outputs), poses)
            out.append({k: float(v) for k, v in losses.items() if torch.is_tensor(v) and v.dim() == 0})
    return out[0], out[1]


def test_photometric_masks_off_lets_the_loss_see_the_ego_pixels():
    batch = rig_batch()
    poked = rig_batch()
    # the ego rows (rig_batch's mask: the last 6) away from the mask's border, which SSIM's 3x3 window and the
    # bilinear warp may read one row into: the last 3 rows of every image
    poked.rgb[..., -3:, :] = torch.rand_like(poked.rgb[..., -3:, :])
    on = _fixed_depth_losses(_mono(), batch, poked)
    off = _fixed_depth_losses(_mono(loss={"photometric_ego_mask": False}), batch, poked)
    assert on[0]["reprojection/init"] == pytest.approx(on[1]["reprojection/init"], rel=1e-6)
    assert on[0]["smoothness/init"] == pytest.approx(on[1]["smoothness/init"], rel=1e-6)
    assert abs(off[0]["reprojection/init"] - off[1]["reprojection/init"]) > 1e-4
    assert abs(off[0]["smoothness/init"] - off[1]["smoothness/init"]) > 0


def test_consistency_masks_off_counts_the_ego_pixels():
    cfg_on = run_cfg({"refine_steps": 0})
    cfg_off = run_cfg({"refine_steps": 0}, loss={"consistency_ego_mask": False})
    batch = rig_batch()
    torch.manual_seed(0)
    depth = 5 + 20 * torch.rand(N, 1, H, W)
    poked = depth.clone()
    poked[..., -6:, :] = 0.6  # near depths on the ego rows only
    sys_on = SelfSupervisedSystem(cfg_on, RING, N)
    sys_off = SelfSupervisedSystem(cfg_off, RING, N)
    assert float(sys_on.consistency(depth, batch)) == pytest.approx(float(sys_on.consistency(poked, batch)), rel=1e-6)
    assert abs(float(sys_off.consistency(depth, batch)) - float(sys_off.consistency(poked, batch))) > 1e-3


def test_feature_masks_off_changes_the_refined_weights_only():
    batch = rig_batch()
    inp = batch.depth_input(torch.tensor([[(i - 1) % N, (i + 1) % N] for i in range(N)]), {}, batch.rgb)
    outs = []
    for on in (True, False):
        torch.manual_seed(0)
        net = DepthModel(small_model_cfg(feature_ego_mask=on, weight_init_std=0.5)).eval()
        with torch.no_grad():
            outs.append(net(inp, scales=1, refine_scales=1))
    a, b = outs
    assert torch.equal(a["depth", "init", 0], b["depth", "init", 0])  # the bases do not read the mask
    assert not torch.allclose(a["weights", "refine1"], b["weights", "refine1"], atol=1e-7)


def test_per_scale_loss_differs_from_full_resolution_only_at_the_coarse_scales():
    batch = rig_batch()
    full = _step_losses(_mono(), batch)
    per = _step_losses(_mono(loss={"multiscale": "per_scale"}), batch)
    assert full["reprojection/init"] == pytest.approx(per["reprojection/init"], rel=1e-6)  # scale 0: the same
    assert abs(full["photometric/init"] - per["photometric/init"]) > 1e-5
    one = run_cfg({"method": "mono2", "bases": 1, "refine_steps": 0, "scales": 1}, scale={"source": "odometry"})
    one_per = run_cfg({"method": "mono2", "bases": 1, "refine_steps": 0, "scales": 1}, scale={"source": "odometry"},
                      loss={"multiscale": "per_scale"})
    assert _step_losses(one, batch) == _step_losses(one_per, batch)


@pytest.mark.parametrize("layers, deepest", [(34, 512), (50, 2048)])
def test_encoder_depth_switch_builds_monodepth2s_trunks(layers, deepest):
    batch = rig_batch()
    inp = batch.depth_input(torch.tensor([[(i - 1) % N, (i + 1) % N] for i in range(N)]), {}, batch.rgb)
    torch.manual_seed(0)
    net = DepthModel(small_model_cfg(encoder_layers=layers, refine_steps=1)).eval()
    assert net.encoder.num_ch_enc[-1] == deepest
    with torch.no_grad():
        out = net(inp, scales=1, refine_scales=1)
    assert out["depth", "refine1", 0].shape == (N, 1, H, W)
    n18 = sum(p.numel() for p in DepthModel(small_model_cfg()).encoder.parameters())
    assert sum(p.numel() for p in net.encoder.parameters()) > 1.9 * n18  # 21.3 M / 23.5 M against 11.2 M


def test_encoder_depth_refuses_resnet18_weights_in_another_trunk(tmp_path):
    from mcdp.networks import NetworkError, ResnetEncoder

    with pytest.raises(NetworkError, match="ResNet-18 weights only, the encoder has 50 layers"):
        ResnetEncoder(1, str(tmp_path / "r18.pth"), 50)


def test_temporal_weight_scales_the_temporal_term_and_nothing_else():
    """loss.temporal_weight: the step's photometric loss is w * reprojection + smoothness (smoothness and the
    logged reprojection unchanged), so 0 leaves smoothness alone; the default is not multiplied (bit-identical)."""
    batch = rig_batch()
    by_w = {w: _step_losses(_mono(loss={"temporal_weight": w}), batch) for w in (0.0, 1.0, 2.5)}
    rep, smooth = by_w[1.0]["reprojection/init"], by_w[1.0]["smoothness/init"]
    assert rep > 1e-3
    for w, losses in by_w.items():
        assert losses["reprojection/init"] == pytest.approx(rep, rel=1e-6)  # logged unweighted
        assert losses["smoothness/init"] == pytest.approx(smooth, rel=1e-6)
    # photometric = mean over scales of (w rep_s + smooth terms): linear in w, with the smoothness part at w = 0
    p0, p1, p25 = (by_w[w]["photometric/init"] for w in (0.0, 1.0, 2.5))
    assert p1 - p0 > 1e-3
    assert p25 - p0 == pytest.approx(2.5 * (p1 - p0), rel=1e-4)
    assert _step_losses(_mono(), batch) == by_w[1.0]


def _fsm(**params) -> RunConfig:
    return run_cfg({"method": "fsm", "bases": 1, "refine_steps": 0}, scale={"source": "odometry"},
                   method_params=params)


def test_fsm_spatio_temporal_switch_keeps_the_neighbour_at_t_only(monkeypatch):
    """method_params.spatio_temporal=false: FSM's spatial term warps the neighbour at t alone (contexts (0,)),
    its default the three contexts; the temporal terms are untouched."""
    import mcdp.methods.fsm as fsm

    assert fsm.FsmParams().spatio_temporal is True  # an unset key: a run without it keeps its config and hash
    seen = []
    real = fsm.spatial_photometric

    def spy(*a, **kw):
        seen.append(tuple(kw["contexts"]))
        return real(*a, **kw)

    monkeypatch.setattr(fsm, "spatial_photometric", spy)
    batch = rig_batch()
    on = _step_losses(_fsm(), batch)
    assert set(seen) == {fsm.CONTEXTS}
    seen.clear()
    off = _step_losses(_fsm(spatio_temporal=False), batch)
    assert set(seen) == {(0,)}
    assert on["reprojection/init"] == pytest.approx(off["reprojection/init"], rel=1e-6)
    assert off["fsm/spatial"] > 0 and abs(on["fsm/spatial"] - off["fsm/spatial"]) > 1e-6
    assert "fsm/spatial" not in _step_losses(_fsm(spatial_weight=0.0), batch)
