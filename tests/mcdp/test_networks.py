"""Network blocks: shapes, output ranges, local pretrained weights, weight-network init."""
from __future__ import annotations

import pytest
import torch
import torch.nn.functional as F
import torchvision

from mcdp.networks import DepthDecoder, NetworkError, PoseNet, PyramidReduce, ResnetEncoder, WeightNet

pytestmark = pytest.mark.usefixtures("one_thread")


def test_encoder_feature_pyramid_shapes():
    enc = ResnetEncoder()
    feats = enc(torch.rand(2, 3, 64, 96))
    assert [tuple(f.shape) for f in feats] == [
        (2, 64, 32, 48), (2, 64, 16, 24), (2, 128, 8, 12), (2, 256, 4, 6), (2, 512, 2, 3)
    ]


@pytest.mark.parametrize("n_out", [1, 8])
def test_depth_decoder_outputs_n_channels_per_scale_in_unit_interval(n_out):
    enc = ResnetEncoder()
    dec = DepthDecoder(enc.num_ch_enc, n_out=n_out, scales=4)
    with torch.no_grad():
        out = dec(enc(torch.rand(1, 3, 64, 96)))
    assert sorted(out) == [0, 1, 2, 3]
    for s, x in out.items():
        assert x.shape == (1, n_out, 64 // 2**s, 96 // 2**s)
        assert float(x.min()) > 0 and float(x.max()) < 1


def test_depth_decoder_init_sigmoid_sets_the_starting_output():
    torch.manual_seed(0)
    enc = ResnetEncoder()
    dec = DepthDecoder(enc.num_ch_enc, n_out=4, init_sigmoid=0.02)
    with torch.no_grad():
        out = dec(enc(torch.rand(1, 3, 64, 96)))
    assert abs(float(out[0].median()) - 0.02) < 0.01


def test_pretrained_weights_come_from_a_local_file_and_are_repeated_for_pose(tmp_path):
    torch.manual_seed(1)
    ref = torchvision.models.resnet18(weights=None)
    path = tmp_path / "resnet18.pth"
    torch.save(ref.state_dict(), path)
    enc = ResnetEncoder(pretrained=str(path))
    assert torch.equal(enc.net.conv1.weight, ref.conv1.weight)
    assert torch.equal(enc.net.layer4[1].conv2.weight, ref.layer4[1].conv2.weight)
    pose = PoseNet(pretrained=str(path))
    w = pose.encoder.net.conv1.weight
    assert w.shape == (64, 6, 7, 7)
    # Monodepth2: two stacked images; conv1 repeated and halved so the response to identical images is unchanged
    assert torch.allclose(w[:, :3] + w[:, 3:], ref.conv1.weight)


def test_missing_or_wrong_pretrained_file_names_the_file(tmp_path):
    with pytest.raises(NetworkError, match="nope.pth does not exist"):
        ResnetEncoder(pretrained=str(tmp_path / "nope.pth"))
    bad = tmp_path / "bad.pth"
    torch.save({"foo": torch.zeros(1)}, bad)
    with pytest.raises(NetworkError, match="bad.pth is not a torchvision ResNet-18"):
        ResnetEncoder(pretrained=str(bad))


def test_pose_net_starts_with_small_motions():
    torch.manual_seed(0)
    net = PoseNet()
    with torch.no_grad():
        aa, t = net(torch.rand(3, 3, 64, 96), torch.rand(3, 3, 64, 96))
    assert aa.shape == (3, 3) and t.shape == (3, 3)
    assert float(t.abs().max()) < 0.1  # Monodepth2's 0.01 output scaling


def test_weight_net_output_shape_and_near_zero_start():
    torch.manual_seed(0)
    wn = WeightNet(c_levels=(64, 64, 128), n_slots=2, n_bases=8, c_red=16, c_conv=32, c_fc=64)
    feats = [torch.rand(4, 64, 32, 48), torch.rand(4, 64, 16, 24), torch.rand(4, 128, 8, 12)]
    red = wn.reduce(feats)
    assert red.shape == (4, 16, 32, 48)
    x = torch.cat([red, red, red, torch.ones(4, 2, 32, 48)], 1)
    with torch.no_grad():
        out = wn(x)
    assert out.shape == (4, 8)
    assert float(out.abs().max()) < 0.05  # a fresh refinement step starts close to the previous weights


def test_pyramid_reduce_equals_a_1x1_conv_over_the_upsampled_concatenation():
    """Reducing each level at its own size, then upsampling, is the paper's resize-concat-conv exactly."""
    torch.manual_seed(0)
    red = PyramidReduce((4, 6, 8), 5).eval()
    feats = [torch.rand(2, 4, 16, 24), torch.rand(2, 6, 8, 12), torch.rand(2, 8, 4, 6)]
    up = torch.cat([feats[0]] + [F.interpolate(f, size=(16, 24), mode="bilinear", align_corners=False)
                                 for f in feats[1:]], 1)  # (2, 18, 16, 24)
    W = torch.cat([c.weight for c in red.convs], 1)  # (5, 18, 1, 1)
    ref = F.relu(red.bn(F.conv2d(up, W)))
    with torch.no_grad():
        assert torch.allclose(red(feats), ref, atol=1e-5)
