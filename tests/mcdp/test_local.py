"""MCDP-local (`mcdp.methods.local`): per-pixel basis weights, the neighbours' warped depth, and the contract."""
from pathlib import Path

import torch

from corelib.configlib import load_config
from mcdp.config import RunConfig
from mcdp.inputs import DepthInput
from mcdp.methods import METHODS, build_network
from mcdp.methods.base import combine_bases
from mcdp.methods.local import LocalDepthModel, LocalWeightNet
from mcdp.networks import WeightNet

TINY = Path(__file__).resolve().parents[2] / "configs" / "train" / "tiny"


def test_head_on_a_constant_map_equals_the_pooled_head():
    """Per cell, the local head is MCDP's fully connected head: given a spatially constant feature map, every
    cell gets what the pooled network gives the image (the only difference is the pooling)."""
    torch.manual_seed(0)
    pooled = WeightNet([64, 64, 128], 2, 8, c_red=16, c_conv=32, c_fc=64, init_std=0.5)
    local = LocalWeightNet([64, 64, 128], 2, 8, c_red=16, c_conv=32, c_fc=64, init_std=0.5)
    for conv, fc in zip([local.head[0], local.head[2], local.head[4]], [pooled.fc[0], pooled.fc[2], pooled.fc[4]]):
        conv.weight.data.copy_(fc.weight.data[:, :, None, None])
        conv.bias.data.copy_(fc.bias.data)
    v = torch.randn(3, 32)
    fmap = v[:, :, None, None].expand(3, 32, 5, 7)
    out = local.head(fmap)  # (3, 8, 5, 7)
    ref = pooled.fc(torch.nn.functional.adaptive_avg_pool2d(fmap, 1).flatten(1))  # (3, 8)
    assert out.shape == (3, 8, 5, 7)
    assert torch.allclose(out, ref[:, :, None, None].expand_as(out), atol=1e-5)


def test_per_pixel_weights_combine_convexly():
    bases = torch.rand(2, 4, 16, 24)
    w = torch.softmax(torch.randn(2, 4, 4, 6), 1)
    sig = combine_bases(bases, w)
    assert sig.shape == (2, 1, 16, 24)
    assert (sig >= bases.min(1, keepdim=True).values - 1e-6).all() and (sig <= bases.max(1, keepdim=True).values + 1e-6).all()
    flat = torch.full((2, 4), 0.25)  # a constant weight map equals the per-image combination
    assert torch.allclose(combine_bases(bases, flat[:, :, None, None].expand(2, 4, 4, 6)), combine_bases(bases, flat),
                          atol=1e-6)


def _model():
    cfg = load_config(RunConfig, TINY / "mcdp_local.yaml", ["model.weight_init_std=1.0"])
    torch.manual_seed(0)
    return build_network(cfg.model).eval(), cfg


def _inputs(N=6, H=64, W=96):
    import math

    torch.manual_seed(1)
    rgb = torch.rand(1, N, 3, H, W)
    fx = (W / 2) / math.tan(math.radians(35))
    K = torch.tensor([[fx, 0, W / 2], [0, fx, H / 2], [0, 0, 1.0]]).expand(1, N, 3, 3).clone()
    T = torch.eye(4).repeat(1, N, 1, 1)
    for c in range(N):  # a ring at 50 degrees: neighbours overlap by ~30 %
        a = math.radians(-50 * c)
        R_yaw = torch.tensor([[math.cos(a), -math.sin(a), 0], [math.sin(a), math.cos(a), 0], [0, 0, 1.0]])
        R_cv = torch.tensor([[0, 0, 1.0], [-1.0, 0, 0], [0, -1.0, 0]])
        T[0, c, :3, :3] = R_yaw @ R_cv
        T[0, c, :3, 3] = torch.tensor([0.0, 0.0, 1.6])
    mask = torch.ones(1, N, 1, H, W)
    nbr = torch.tensor([[(c - 1) % N, (c + 1) % N] for c in range(N)])
    return rgb, K, T, mask, nbr


def test_local_model_gives_per_pixel_weights_and_reads_its_neighbours():
    model, cfg = _model()
    assert isinstance(model, LocalDepthModel) and model.uses_neighbours and model.has_bases
    assert METHODS["mcdp_local"].defaults["model.method"] == "mcdp_local"
    rgb, K, T, mask, nbr = _inputs()
    with torch.no_grad():
        out = model(DepthInput(rgb, K, T, mask, nbr), scales=1)
        cut = model(DepthInput(rgb, K, T, mask, nbr).cut(), scales=1)
    w = out["weights", "refine2"]
    assert w.dim() == 4 and w.shape[:2] == (6, cfg.model.bases)
    assert torch.allclose(w.sum(1), torch.ones_like(w[:, 0]), atol=1e-5)
    assert float(w.std(dim=(2, 3)).mean()) > 1e-4  # the weights vary over the image
    assert torch.equal(out["depth", "init", 0], cut["depth", "init", 0])  # the bases see no neighbour
    assert not torch.allclose(out["depth", "refine2", 0], cut["depth", "refine2", 0])  # the refinement does


def test_warped_depth_ratio_is_zero_where_the_neighbours_agree():
    """Two cameras looking at the same flat ground with ground-truth depth: the log ratio input is 0 on the
    overlap (up to sampling at the overlap's edge) and 0 where there is no overlap."""
    model, _ = _model()
    rgb, K, T, mask, nbr = _inputs()
    for c in range(6):  # tilt every camera down 20 degrees so that each sees the road plane z = 0
        import math

        a = math.radians(-20)
        R_pitch = torch.tensor([[1, 0, 0], [0, math.cos(a), -math.sin(a)], [0, math.sin(a), math.cos(a)]])
        T[0, c, :3, :3] = T[0, c, :3, :3] @ R_pitch
    B, N, h, w = 1, 6, 32, 48
    from mcdp.geometry import scale_intrinsics

    K_h = scale_intrinsics(K.reshape(N, 3, 3), 0.5, 0.5).reshape(1, N, 3, 3)
    # ground-truth depth of the plane z = 0 for each camera at the feature resolution
    v, u = torch.meshgrid(torch.arange(h) + 0.5, torch.arange(w) + 0.5, indexing="ij")
    pix = torch.stack([u, v, torch.ones_like(u)]).reshape(3, -1)
    depth = []
    for c in range(N):
        d_ego = T[0, c, :3, :3] @ (torch.linalg.inv(K_h[0, c]) @ pix)  # rays with z_cam = 1, in the ego frame
        t = -T[0, c, 2, 3] / d_ego[2]
        depth.append(torch.where(t > 0, t, torch.full_like(t, 1e3)).clamp(max=1e3).reshape(1, h, w))
    depth = torch.stack(depth)  # (N, 1, h, w)
    red = torch.zeros(N, 4, h, w)
    m_h = torch.ones(N, 1, h, w)
    Tf = T.float()
    parts, chans = model._neighbour_features(red, m_h, depth, K_h, Tf, torch.linalg.inv(Tf), nbr, "cpu")
    valids, ratios = chans[:2], chans[2:]
    near = depth < 8  # the road within 8 m: bilinear sampling of a depth map is exact only where it is linear
    for valid, r in zip(valids, ratios):
        assert valid.sum() > 0
        inside = (valid > 0) & near
        assert float(r[inside].abs().median()) < 0.01
        assert float(r[valid == 0].abs().max()) == 0.0
