"""Start a run's depth network from a shared pretraining (``model.init_from``).

The pretraining (`study.sweep.pretrain`) trains one encoder + decoder trunk with two heads:
n basis channels and, as the decoder's last channel, a one-channel Monodepth2 head.
`warm_start` copies the encoder and the decoder trunk into a fresh `DepthModel`; the
output convolutions (``decoder.dispconv.*``) come from the head the method uses
(mono2: the mono head; mcdp: the n basis channels). The MCDP weight networks are not
pretrained and keep their initialisation.

Refused with `WarmStartError` naming the layer when the architectures differ (another
number of bases, scales or a different encoder). The file is read with
``torch.load(weights_only=True)``: no code in it can run.

Example::

    record = warm_start(network, "pretrain/pretrained.pt")   # {"path", "sha256", "config_hash", "step"}
"""
from __future__ import annotations

from pathlib import Path

from corelib.hashing import sha256_file
from mcdp.networks import read_weights_file

FORMAT = "mcdp-pretrain"
VERSION = 1


class WarmStartError(ValueError):
    """The pretraining file cannot initialise this network; the message names the file and the layer."""



def read_pretraining(path: str | Path) -> dict:
    """The pretraining file's dict (format checked); WarmStartError naming the file otherwise."""
    p = Path(path)
    obj = read_weights_file(p, "model.init_from", "make it with: mcdp pretrain CONFIG --out DIR", WarmStartError)
    if not isinstance(obj, dict) or obj.get("format") != FORMAT or obj.get("version") != VERSION:
        raise WarmStartError(f"model.init_from: {p} is not an {FORMAT} v{VERSION} file (written by mcdp pretrain)")
    if not isinstance(obj.get("depth_model"), dict) or not isinstance(obj.get("model"), dict):
        raise WarmStartError(f"model.init_from: {p} has no depth_model / model entries")
    return obj


def warm_start(network, path: str | Path) -> dict:
    """Copy a pretraining's encoder, decoder trunk and matching head into ``network`` (a `mcdp.methods.base.DepthNetwork`).

    Returns the record a run keeps: {"path", "sha256", "config_hash", "step"}.
    """
    p = Path(path).resolve()
    obj = read_pretraining(p)
    src = obj["depth_model"]
    n_src = int(obj["model"].get("bases", -1))
    if not obj["model"].get("mono_head"):
        raise WarmStartError(f"model.init_from: {p} was not trained with the mono head (model.mono_head=true)")
    mono = not network.has_bases  # Monodepth2's one channel takes the pretraining's mono head
    n_dst = network.n_out
    if not mono and n_dst != n_src:
        raise WarmStartError(
            f"model.init_from: layer decoder.dispconv: the pretraining {p} has {n_src} bases, this run "
            f"model.bases={n_dst}; use model.bases={n_src} or another pretraining")
    dst = network.state_dict()
    new = {}
    for key, t in dst.items():
        if not (key.startswith("encoder.") or key.startswith("decoder.")):
            continue  # weight networks: not pretrained
        if key not in src:
            raise WarmStartError(f"model.init_from: layer {key} of this network is not in the pretraining {p}")
        s = src[key]
        if key.startswith("decoder.dispconv."):
            s = s[n_src:n_src + 1] if mono else s[:n_src]
        if tuple(s.shape) != tuple(t.shape):
            raise WarmStartError(
                f"model.init_from: layer {key} has shape {tuple(t.shape)} here, {tuple(s.shape)} in the pretraining "
                f"{p}; the architectures differ")
        new[key] = s.to(t.dtype)
    network.load_state_dict({**dst, **new})
    return {"path": str(p), "sha256": sha256_file(p), "config_hash": obj.get("config_hash"),
            "step": int(obj.get("step", -1))}
