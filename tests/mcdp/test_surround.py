"""The SurroundDepth-style network (mcdp/methods/surround.py): its warm start is Monodepth2 exactly, it is
equivariant to a permutation of the cameras (with their embeddings), one camera's image changes
another camera's depth (not for mono2, not with the neighbours cut), and the tiny preset trains two
steps and evaluates, as trained and cut; its sizes are its ``method_params`` (checked, and rebuilt from a
checkpoint)."""
from __future__ import annotations

from pathlib import Path

import pytest
import torch

from mcdp.inputs import DepthInput

from corelib.configlib import load_config
from mcdp.config import RunConfig
from mcdp.methods.depth_bases import MonoDepthModel
from mcdp.methods.surround import CrossViewBlock, SurroundDepthModel, SurroundParams

ROOT = Path(__file__).resolve().parents[2]
TINY = ROOT / "configs" / "train" / "tiny"
N = 6


def build(seed: int, active: bool = True) -> SurroundDepthModel:
    """The tiny preset's network; ``active``: the cross-view outputs get random weights (they start at 0)."""
    torch.manual_seed(seed)
    model = SurroundDepthModel(load_config(RunConfig, TINY / "surround.yaml").model).eval()
    if active:
        for block in model.cross_view.values():
            torch.nn.init.normal_(block.out.weight, std=0.2)
    return model


def inputs(seed: int):
    g = torch.Generator().manual_seed(seed)
    rgb = torch.rand(1, N, 3, 64, 96, generator=g)
    K = torch.tensor([[60.0, 0, 48], [0, 60.0, 32], [0, 0, 1]]).expand(1, N, 3, 3)
    T = torch.eye(4).expand(1, N, 4, 4)
    mask = torch.ones(1, N, 1, 64, 96)
    nbr = torch.tensor([[(i - 1) % N, (i + 1) % N] for i in range(N)])
    return rgb, K, T, mask, nbr


def depth(model, rgb, nbr, K, T, mask) -> torch.Tensor:
    with torch.no_grad():
        return model(DepthInput(rgb, K, T, mask, nbr))["depth", "init", 0]


@pytest.mark.parametrize("seed", [0, 1])
def test_at_its_warm_start_it_is_monodepth2_exactly(seed, one_thread):
    """The cross-view blocks add through a zero convolution: with the same encoder and decoder, the
    depth equals Monodepth2's, bit for bit."""
    model = build(seed, active=False)
    mono = MonoDepthModel(load_config(RunConfig, TINY / "mono2.yaml").model).eval()
    mono.load_state_dict({k: v for k, v in model.state_dict().items() if not k.startswith("cross_view.")})
    rgb, K, T, mask, nbr = inputs(seed)
    assert torch.equal(depth(model, rgb, nbr, K, T, mask), depth(mono, rgb, nbr, K, T, mask))
    assert {n.split(".")[0] for n, _ in model.named_parameters() if "cross_view" in n} == {"cross_view"}
    assert all(n.startswith("cross_view.") for n, _ in
               ((n, p) for n, p in model.named_parameters() if any(p is q for q in model.fresh_parameters())))


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_equivariant_to_a_permutation_of_the_cameras_with_their_embeddings(seed, one_thread):
    model = build(seed)
    for block in model.cross_view.values():  # embeddings as after training (they start at std 0.02)
        torch.nn.init.normal_(block.camera, std=1.0)
    rgb, K, T, mask, nbr = inputs(seed)
    perm = torch.randperm(N, generator=torch.Generator().manual_seed(seed + 10))
    out = depth(model, rgb, nbr, K, T, mask)
    for block in model.cross_view.values():
        block.camera.data[:N] = block.camera.data[perm].clone()
    out_p = depth(model, rgb[:, perm], nbr, K, T, mask)
    err = float((out_p - out[perm]).abs().max())
    assert err < 1e-4, err  # float rounding of a different summation order
    # the embeddings are what tells the cameras apart: without permuting them back the result differs
    for block in model.cross_view.values():
        block.camera.data[:N] = block.camera.data[torch.argsort(perm)].clone()
    off = float((depth(model, rgb[:, perm], nbr, K, T, mask) - out[perm]).abs().max())
    assert off > max(100 * err, 1e-3), (off, err)


@pytest.mark.parametrize("seed", [0, 1])
def test_one_cameras_image_changes_another_cameras_depth_unless_cut(seed, one_thread):
    rgb, K, T, mask, nbr = inputs(seed)
    rgb2 = rgb.clone()
    rgb2[:, 0] = torch.rand(rgb2[:, 0].shape, generator=torch.Generator().manual_seed(99))
    model = build(seed)
    d, d2 = depth(model, rgb, nbr, K, T, mask), depth(model, rgb2, nbr, K, T, mask)
    assert (d[1:] - d2[1:]).abs().max() > 1e-6  # measured 3e-5 .. 1e-4 (seeds 0-3); cameras 1..5 see camera 0's change (exactly 0 when cut)
    cut = torch.full_like(nbr, -1)
    d, d2 = depth(model, rgb, cut, K, T, mask), depth(model, rgb2, cut, K, T, mask)
    assert torch.equal(d[1:], d2[1:]) and (d[0] - d2[0]).abs().max() > 1e-3
    mono = MonoDepthModel(load_config(RunConfig, TINY / "mono2.yaml").model).eval()
    assert torch.equal(depth(mono, rgb, nbr, K, T, mask)[1:], depth(mono, rgb2, nbr, K, T, mask)[1:])


def test_the_cut_mask_is_block_diagonal():
    """Cut: a token attends to the tokens of its own camera only (queried through the attention itself)."""
    torch.manual_seed(0)
    block = CrossViewBlock(8, SurroundParams())
    torch.nn.init.normal_(block.out.weight, std=0.1)
    f = torch.randn(3 * 4, 8, 2, 3)
    f2 = f.clone()
    f2[5] += 1.0  # rig 1, camera 1
    with torch.no_grad():
        a, b = block(f, 3, 4, cut=True), block(f2, 3, 4, cut=True)
        full_a, full_b = block(f, 3, 4, cut=False), block(f2, 3, 4, cut=False)
    changed = (a - b).flatten(1).abs().amax(1) > 0
    assert changed.tolist() == [i == 5 for i in range(12)]
    changed = (full_a - full_b).flatten(1).abs().amax(1) > 0
    assert changed.tolist() == [4 <= i < 8 for i in range(12)]  # the whole rig 1, no other rig


def test_the_tiny_surround_preset_trains_two_steps_and_evaluates_as_trained_and_cut(tiny_dataset, ds, tmp_path):
    from study.method_commands import main
    from mcdp.evaluate import EvalConfig, evaluate
    from mcdp.predict import Predictor

    run = tmp_path / "surround"
    rc = main(["train", str(TINY / "surround.yaml"), "--data", str(tiny_dataset), "--out", str(run), "--no-progress",
               "train.steps=2", "scale.source=odometry", "method_params.d_model=64", "method_params.levels=[4]"])
    assert rc == 0 and (run / "checkpoints" / "last.pt").is_file()
    from study.sweep.probes import CUT, Probed

    net = Predictor(run, ds, "last")
    pred = Probed(net, keep=True)
    cut = Probed(net, CUT, reference=pred)
    assert isinstance(net.network, SurroundDepthModel) and net.network.uses_neighbours
    # the checkpoint's method_params rebuilt the network it trained (sizes not at their defaults)
    assert list(net.network.cross_view) == ["4"] and net.network.cross_view["4"].camera.shape == (16, 64)
    # two steps moved the zero convolutions off zero: the fresh layers learn
    assert all(float(b.out.weight.detach().abs().max()) > 0 for b in net.network.cross_view.values())
    a = evaluate(ds, pred.predict, "test", EvalConfig(), progress=False)
    c = evaluate(ds, cut.predict, "test", EvalConfig(), progress=False)
    fa, fc = a["stages"]["final"]["median"]["mean"]["abs_rel"], c["stages"]["final"]["median"]["mean"]["abs_rel"]
    assert 0 < fa < 1 and 0 < fc < 1 and fa != fc
    # what cutting changes, in metres, on the same images (the sweep's "acting" number)
    ch = cut.refinement["cut_change_m"]
    assert cut.refinement["images"] == pred.refinement["images"] > 0 and 0 < ch < 1, cut.refinement


@pytest.mark.parametrize("seed", [0, 1])
def test_joint_pose_is_one_rigid_rig_motion_and_keeps_one_that_already_is(seed, ds):
    """rig_motion: from any per-camera predictions, every camera's motion is the same ego motion (FSM's
    pose-consistency error ~0); from predictions that already are one rig motion, it returns them."""
    from mcdp.data import RigDataset, collate
    from mcdp.methods.fsm import pose_consistency
    from mcdp.rigid import odometry_camera_motion, pose_from_axisangle, rig_motion

    b = collate([RigDataset(ds, "train", 64, 96)[seed]])
    T = b.T_ego_cam.float()
    n = T.shape[1]
    g = torch.Generator().manual_seed(seed)
    aa, t = torch.randn(n, 3, generator=g) * 0.05, torch.randn(n, 3, generator=g)
    raw = {1: pose_from_axisangle(aa, t).view(1, n, 4, 4), -1: torch.linalg.inv(pose_from_axisangle(aa, t)).view(1, n, 4, 4)}
    assert float(sum(pose_consistency(raw, T))) > 1e-2  # six unrelated motions
    joint = {1: rig_motion(aa, t, T), -1: rig_motion(aa, t, T, invert=True)}
    tr, rot = pose_consistency(joint, T)
    assert float(tr) < 1e-9 and float(rot) < 1e-9
    # odometry motions are one rig motion already: decompose them and average: the same motions back
    mot = odometry_camera_motion(b.T_world_ego, T, 1)[0]  # (N, 4, 4)
    R, tt = mot[:, :3, :3].double(), mot[:, :3, 3]
    ang = torch.arccos(((R.diagonal(dim1=-2, dim2=-1).sum(-1) - 1) / 2).clamp(-1, 1))
    axis = torch.stack([R[:, 2, 1] - R[:, 1, 2], R[:, 0, 2] - R[:, 2, 0], R[:, 1, 0] - R[:, 0, 1]], -1)
    aa_o = (axis / (2 * torch.sin(ang).clamp(min=1e-12))[:, None] * ang[:, None]).float()
    back = rig_motion(aa_o, tt, T)[0]
    assert torch.allclose(back, mot, atol=1e-4), float((back - mot).abs().max())


def test_the_system_feeds_the_extrinsics_to_the_pose_network_for_surround_only(ds):
    from mcdp.data import RigDataset, collate
    from mcdp.methods.fsm import pose_consistency
    from mcdp.system import SelfSupervisedSystem

    b = collate([RigDataset(ds, "train", 64, 96)[0]])
    for name, rigid in (("surround", True), ("mono2", False)):
        cfg = load_config(RunConfig, TINY / f"{name}.yaml", ["scale.source=velocity"])
        torch.manual_seed(0)
        system = SelfSupervisedSystem(cfg, ds.neighbours, len(ds.camera_names))
        with torch.no_grad():
            poses, _ = system.predict_poses(b, b.rgb)
        n = len(ds.camera_names)
        tr, rot = pose_consistency({o: p.view(1, n, 4, 4) for o, p in poses.items()}, b.T_ego_cam)
        assert (float(tr) + float(rot) < 1e-8) == rigid, (name, float(tr), float(rot))


def test_its_sizes_are_its_method_params_checked_and_default_to_the_sizes_it_had():
    """SurroundParams: unset, the sizes the network always had (the same state-dict shapes, and the run's hash
    is untouched: tests/mcdp/test_methods.py); set, they size the blocks; a bad one is one ConfigError naming it."""
    from corelib.configlib import ConfigError, config_hash
    from mcdp import methods

    cfg = load_config(RunConfig, TINY / "surround.yaml")
    p = methods.method_params(cfg)
    assert p == SurroundParams() and (p.d_model, p.heads, p.mlp_ratio, p.max_cameras, p.levels) == (128, 4, 2, 16, [3, 4])
    net = methods.build_network(cfg.model, p)
    shapes = {k: tuple(v.shape) for k, v in net.state_dict().items() if k.startswith("cross_view.")}
    assert shapes["cross_view.3.camera"] == (16, 128) and shapes["cross_view.4.qkv.weight"] == (384, 128)
    assert shapes["cross_view.4.mlp.0.weight"] == (256, 128) and len({k.split(".")[1] for k in shapes}) == 2
    assert {k: tuple(v.shape) for k, v in SurroundDepthModel(cfg.model).state_dict().items()} == {
        k: tuple(v.shape) for k, v in net.state_dict().items()}  # params=None: the defaults
    small = load_config(RunConfig, TINY / "surround.yaml", ["method_params.d_model=32", "method_params.heads=2",
                                                             "method_params.levels=[2, 4]", "method_params.mlp_ratio=1"])
    assert config_hash(small) != config_hash(cfg)
    net = methods.build_network(small.model, methods.method_params(small))
    assert sorted(net.cross_view) == ["2", "4"] and net.cross_view["2"].camera.shape == (16, 32)
    assert net.cross_view["2"].heads == 2 and net.cross_view["2"].mlp[0].weight.shape == (32, 32)
    for override, msg in [("method_params.d_model=30", r"^method_params: .*d_model=30 must be a multiple of 4"),
                          ("method_params.levels=[4, 3]", r"^method_params: .*levels=\[4, 3\] must be increasing"),
                          ("method_params.levels=[5]", r"^method_params: .*among 0-4"),
                          ("method_params.heads=0", r"^method_params\.heads: .*greater than or equal to 1"),
                          ("method_params.d_model=100000", r"^method_params\.d_model: .*less than or equal to 1024"),
                          ("method_params.width=3", r"^method_params\.width: unknown key for method 'surround'")]:
        with pytest.raises(ConfigError, match=msg):
            methods.check_run(load_config(RunConfig, TINY / "surround.yaml", [override]))
