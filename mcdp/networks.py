"""Network building blocks: ResNet-18 encoder, Monodepth2 depth/pose decoders, MCDP weight network.

The encoder and decoders follow Monodepth2 (Godard et al. 2019) layer for
layer; the depth decoder's last layer outputs ``n_out`` sigmoid channels (1
for Monodepth2, n depth bases for MCDP). Weights are never downloaded:
``pretrained`` is a path to a local torchvision ResNet-18 state dict.

Example::

    enc = ResnetEncoder(pretrained=None)
    dec = DepthDecoder(enc.num_ch_enc, n_out=32)
    feats = enc(rgb)          # rgb (B, 3, H, W) in [0, 1]
    sig = dec(feats)          # {0: (B, 32, H, W), 1: (B, 32, H/2, W/2), ...}
"""
from __future__ import annotations

import math
import re
from pathlib import Path

import torch
import torch.nn as nn
import torch.nn.functional as F
import torchvision


class NetworkError(ValueError):
    """A network could not be built (e.g. unreadable pretrained weights); the message names the file."""


def read_weights_file(path: str | Path, field: str, hint: str, error: type[Exception] = NetworkError):
    """``torch.load(weights_only=True)`` of a user-given file (no code in it can run); ``error`` naming
    the config field and the file when it is missing (``hint`` says what to do) or unreadable."""
    p = Path(path)
    if not p.is_file():
        raise error(f"{field}: weights file {p} does not exist ({hint})")
    from corelib.readfile import open_file

    try:
        with open_file(p, kind="checkpoint", link_ok=True) as f:  # regular, bounded, never a FIFO's blocking read
            return torch.load(f, map_location="cpu", weights_only=True)
    except Exception as exc:  # noqa: BLE001 - any unreadable file is a user error
        raise error(f"{field}: cannot read {p} as a plain weights file: {load_error_line(exc)}") from None


def load_error_line(exc: BaseException) -> str:
    """Why ``torch.load(weights_only=True)`` refused a file, in one line, without torch's advice to load it
    again with ``weights_only=False`` or to allow its globals (that would run the code in a file one was
    handed): what it holds that is not a tensor or plain container, when torch names it."""
    text = str(exc).strip()
    if "weights only load failed" not in text.lower():
        return text.splitlines()[0][:200] if text else type(exc).__name__
    code = re.search(r"GLOBAL [\w.]+|Unsupported global: [^\s]+", text)
    if code:
        return (f"it holds Python objects, not only tensors and plain containers ({code.group(0)[:120]}); refused "
                "unread: loading it could run code")
    other = re.search(r"Unsupported operand [^\s.]+", text)
    return "torch's safe loader cannot read it" + (f" ({other.group(0)[:80]})" if other else "")


def load_resnet18_weights(path: str | Path) -> dict:
    """Read a local torchvision ResNet-18 state dict (``.pth``); raises NetworkError naming the file."""
    p = Path(path)
    sd = read_weights_file(p, "model.pretrained", "weights are never downloaded")
    if isinstance(sd, dict) and "state_dict" in sd:
        sd = sd["state_dict"]
    if not isinstance(sd, dict) or "conv1.weight" not in sd:
        raise NetworkError(f"model.pretrained: {p} is not a torchvision ResNet-18 state dict (no conv1.weight)")
    return sd


#: the encoder depths `ResnetEncoder` builds (Monodepth2's ``resnets``; 50 has bottleneck blocks, 4x the channels)
ENCODER_LAYERS = (18, 34, 50)


def encoder_channels(layers: int = 18) -> tuple[int, ...]:
    """The five feature maps' channels of a ResNet trunk of ``layers`` (Monodepth2: ``num_ch_enc[1:] *= 4`` above 34)."""
    if layers not in ENCODER_LAYERS:
        raise ValueError(f"encoder layers must be one of {ENCODER_LAYERS}, got {layers}")
    return (64, 64, 128, 256, 512) if layers <= 34 else (64, 256, 512, 1024, 2048)


class ResnetEncoder(nn.Module):
    """torchvision ResNet-18 (or 34 / 50) trunk returning 5 feature maps (Monodepth2 ``ResnetEncoder``).

    Args:
        num_input_images: images stacked along channels (2 for the pose network;
            pretrained conv1 weights are repeated and divided as in Monodepth2).
        pretrained: local state dict path or None (random init); ResNet-18 weights only.
        layers: 18 (default), 34 or 50 (`model.encoder_layers`; 50's features have 4x the channels from the
            second map on: ``self.num_ch_enc``, as Monodepth2's encoder sets them).

    forward(x): x (B, 3*num_input_images, H, W) in [0, 1] ->
        [ (B, 64, H/2, W/2), (B, 64, H/4, W/4), (B, 128, H/8, W/8),
          (B, 256, H/16, W/16), (B, 512, H/32, W/32) ]
    """

    num_ch_enc = (64, 64, 128, 256, 512)

    def __init__(self, num_input_images: int = 1, pretrained: str | None = None, layers: int = 18):
        super().__init__()
        self.num_ch_enc = encoder_channels(layers)
        net = {18: torchvision.models.resnet18, 34: torchvision.models.resnet34,
               50: torchvision.models.resnet50}[layers](weights=None)
        if num_input_images > 1:
            net.conv1 = nn.Conv2d(3 * num_input_images, 64, kernel_size=7, stride=2, padding=3, bias=False)
        if pretrained is not None and layers != 18:
            raise NetworkError(f"model.pretrained: ResNet-18 weights only, the encoder has {layers} layers")
        if pretrained is not None:
            sd = load_resnet18_weights(pretrained)
            if num_input_images > 1:
                sd = dict(sd)
                sd["conv1.weight"] = torch.cat([sd["conv1.weight"]] * num_input_images, 1) / num_input_images
            net.load_state_dict(sd)
        del net.fc, net.avgpool  # unused; keeps state dicts small
        self.net = net

    def forward(self, x: torch.Tensor, extra: torch.Tensor | None = None) -> list[torch.Tensor]:
        """``extra`` (B, 64, H/2, W/2): added to the first convolution's output before its batch norm (an
        extra input's own first layer, `mcdp.methods.oracle_local`)."""
        x = (x - 0.45) / 0.225
        n = self.net
        y = n.conv1(x)
        f0 = n.relu(n.bn1(y if extra is None else y + extra))
        f1 = n.layer1(n.maxpool(f0))
        f2 = n.layer2(f1)
        f3 = n.layer3(f2)
        f4 = n.layer4(f3)
        return [f0, f1, f2, f3, f4]


class ConvBlock(nn.Module):
    """3x3 reflection-padded conv + ELU (Monodepth2)."""

    def __init__(self, c_in: int, c_out: int):
        super().__init__()
        self.conv = nn.Conv2d(c_in, c_out, 3, padding=1, padding_mode="reflect")
        self.nonlin = nn.ELU(inplace=True)

    def forward(self, x):
        return self.nonlin(self.conv(x))


class DepthDecoder(nn.Module):
    """Monodepth2 multi-scale decoder with ``n_out`` sigmoid outputs per scale.

    forward(features) -> {s: (B, n_out, H/2^s, W/2^s) in (0, 1)} for s in range(scales).
    ``init_sigmoid``: initial output value (bias init), or None for PyTorch's default init.
    The sigmoid values are mapped to depth only by `mcdp.methods.base.disp_to_depth`.
    """

    def __init__(self, num_ch_enc=ResnetEncoder.num_ch_enc, n_out: int = 1, scales: int = 4, init_sigmoid: float | None = None):
        super().__init__()
        self.num_ch_enc = tuple(num_ch_enc)
        self.num_ch_dec = (16, 32, 64, 128, 256)
        self.scales = scales
        self.upconv0 = nn.ModuleList()
        self.upconv1 = nn.ModuleList()
        for i in range(5):
            c_in = self.num_ch_enc[-1] if i == 4 else self.num_ch_dec[i + 1]
            self.upconv0.append(ConvBlock(c_in, self.num_ch_dec[i]))
            c_in = self.num_ch_dec[i] + (self.num_ch_enc[i - 1] if i > 0 else 0)
            self.upconv1.append(ConvBlock(c_in, self.num_ch_dec[i]))
        self.dispconv = nn.ModuleList(
            [nn.Conv2d(self.num_ch_dec[s], n_out, 3, padding=1, padding_mode="reflect") for s in range(scales)]
        )
        if init_sigmoid is not None:  # start every output near this sigmoid value (see ModelConfig.init_depth)
            for conv in self.dispconv:
                nn.init.constant_(conv.bias, math.log(init_sigmoid / (1.0 - init_sigmoid)))

    def forward(self, feats: list[torch.Tensor]) -> dict[int, torch.Tensor]:
        out = {}
        x = feats[-1]
        for i in range(4, -1, -1):
            x = self.upconv0[i](x)
            x = F.interpolate(x, scale_factor=2, mode="nearest")
            if i > 0:
                x = torch.cat([x, feats[i - 1]], 1)
            x = self.upconv1[i](x)
            if i < self.scales:
                out[i] = torch.sigmoid(self.dispconv[i](x))
        return out


class PoseDecoder(nn.Module):
    """Monodepth2 pose decoder for one image pair.

    forward(f4 (B, 512, h, w)) -> axisangle (B, 3), translation (B, 3); the
    0.01 output scaling of Monodepth2 keeps initial motions small.
    """

    def __init__(self, c_enc: int = 512):
        super().__init__()
        self.squeeze = nn.Conv2d(c_enc, 256, 1)
        self.pose0 = nn.Conv2d(256, 256, 3, padding=1)
        self.pose1 = nn.Conv2d(256, 256, 3, padding=1)
        self.pose2 = nn.Conv2d(256, 6, 1)

    def forward(self, f4: torch.Tensor):
        x = F.relu(self.squeeze(f4))
        x = F.relu(self.pose0(x))
        x = F.relu(self.pose1(x))
        x = self.pose2(x).mean((2, 3)) * 0.01  # (B, 6)
        return x[:, :3], x[:, 3:]


class PoseNet(nn.Module):
    """Monodepth2 "separate_resnet" pose network: 2-image ResNet-18 + PoseDecoder.

    forward(img_a, img_b): (B, 3, H, W) each, in temporal order -> (axisangle, translation),
    the motion from a to b as used by `mcdp.rigid.pose_from_axisangle`.
    """

    def __init__(self, pretrained: str | None = None):
        super().__init__()
        self.encoder = ResnetEncoder(num_input_images=2, pretrained=pretrained)
        self.decoder = PoseDecoder(ResnetEncoder.num_ch_enc[-1])

    def forward(self, img_a: torch.Tensor, img_b: torch.Tensor):
        return self.decoder(self.encoder(torch.cat([img_a, img_b], 1))[-1])


def conv_bn_relu(c_in: int, c_out: int, k: int = 3, stride: int = 1) -> nn.Sequential:
    return nn.Sequential(
        nn.Conv2d(c_in, c_out, k, stride=stride, padding=k // 2, bias=False),
        nn.BatchNorm2d(c_out),
        nn.ReLU(inplace=True),
    )


class PyramidReduce(nn.Module):
    """1x1 conv/BN/ReLU over encoder features resized to the finest level and concatenated.

    Computed as one bias-free 1x1 conv per level *at its own resolution*,
    bilinearly upsampled and summed, then BN + ReLU: exactly a 1x1 conv over
    the concatenation of the upsampled features (both maps are linear and
    commute), without upsampling 256 channels.

    forward([f0 (B, c0, h, w), f1 (B, c1, h/2, w/2), f2 (B, c2, h/4, w/4)]) -> (B, c_red, h, w)
    """

    def __init__(self, c_levels, c_red: int):
        super().__init__()
        self.convs = nn.ModuleList([nn.Conv2d(c, c_red, 1, bias=False) for c in c_levels])
        self.bn = nn.BatchNorm2d(c_red)

    def forward(self, feats: list[torch.Tensor]) -> torch.Tensor:
        h, w = feats[0].shape[-2:]
        x = self.convs[0](feats[0])
        for conv, f in zip(self.convs[1:], feats[1:]):
            x = x + F.interpolate(conv(f), size=(h, w), mode="bilinear", align_corners=False)
        return F.relu(self.bn(x))


class WeightNet(nn.Module):
    """MCDP weight network of one refinement step (shared across cameras).

    Two parts, so that neighbour features are reduced *before* they are warped
    (warping 256 channels per neighbour would cost more than the refinement):

    - ``reduce([f0, f1, f2])``: the encoder features at 1/2, 1/4, 1/8 ->
      (B, c_red, H/2, W/2), a 1x1 conv/BN/ReLU over their concatenation after
      resizing to 1/2 (`PyramidReduce`).
    - ``forward(x)``: x (B, c_red * (1 + S) + S, H/2, W/2), the target's reduced
      features, S warped neighbour features (zeros outside the overlap) and the
      S overlap masks -> (B, n) change of the basis-weight logits. Conv/BN/ReLU
      stack (3 stride-2 convs), global average pooling, three FC layers; the
      last FC starts near zero (std 1e-3) so a fresh step starts from the
      previous weights while every layer already receives gradients.
    """

    def __init__(self, c_levels, n_slots: int, n_bases: int, c_red: int = 32, c_conv: int = 64, c_fc: int = 128,
                 init_std: float = 1e-3):
        super().__init__()
        self.reduce = PyramidReduce(c_levels, c_red)
        c_in = c_red * (1 + n_slots) + n_slots
        self.convs = nn.Sequential(
            conv_bn_relu(c_in, c_conv, 3, stride=2),
            conv_bn_relu(c_conv, c_conv, 3, stride=2),
            conv_bn_relu(c_conv, c_conv, 3, stride=2),
        )
        self.fc = nn.Sequential(
            nn.Linear(c_conv, c_fc),
            nn.ReLU(inplace=True),
            nn.Linear(c_fc, c_fc),
            nn.ReLU(inplace=True),
            nn.Linear(c_fc, n_bases),
        )
        nn.init.normal_(self.fc[-1].weight, std=init_std)
        nn.init.zeros_(self.fc[-1].bias)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        x = self.convs(x)
        x = F.adaptive_avg_pool2d(x, 1).flatten(1)  # (B, c_conv)
        return self.fc(x)
