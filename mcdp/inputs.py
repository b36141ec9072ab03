"""What a depth network reads: `DepthInput` for one forward pass, `RigBatch` for one training step, and
the optional `Field`s that only some methods read.

Every network reads the same core of a rig sample at frame t (`DepthInput`: images, intrinsics,
extrinsics, scene mask, neighbour table). What only some methods read is a `Field`: a name, a reader
that makes it for one rig sample, and what it carries. A network declares the fields it reads
(`mcdp.methods.base.DepthNetwork.inputs`); the data reader (`mcdp.data.RigDataset`) and the predictor
(`mcdp.predict.Predictor.inputs`) fill those and no other, and the network finds them in
``DepthInput.fields``. A method that needs an input of its own declares its `Field` in its own module
(`mcdp.methods.oracle_local.OVERLAP_TRUTH`; tests/mcdp/test_toy_method.py adds one in a test): nothing
else changes.

Batch schema (B = rig samples, N = cameras in rig order, frames in the order [-1, 0, +1], H x W =
training size)::

    rgb          (B, N, 3, 3, H, W) float32 in [0, 1]   images of frames t-1, t, t+1
    K            (B, N, 3, 3)       float32             intrinsics scaled to H x W
    T_ego_cam    (B, N, 4, 4)       float32             camera -> ego (rig extrinsics)
    mask         (B, N, 1, H, W)    float32 0/1         1 = scene, 0 = ego body
    T_world_ego  (B, 3, 4, 4)       float32             ego odometry at t-1, t, t+1
    seq_index    (B,)               int64               index into `mcdp.data.RigDataset.seqs`
    frame        (B,)               int64               frame t
    fields       {name: (B, N, ...)}                    the declared `Field`s, nothing else

Ground truth enters a batch only through a field that says so (``Field.truth``: an ORACLE's input, a
yardstick); the rows whose networks read one are labelled ORACLE in every report.

Example::

    batch = collate([train[0], train[1]])         # `RigBatch`
    out = network(batch.depth_input(nbr, fields=network.inputs))
"""
from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field
from typing import Any, Callable, Mapping

import torch


@dataclass(frozen=True)
class Field:
    """An input only some networks read.

    Args:
        name: its key in ``DepthInput.fields`` and ``RigBatch.fields``.
        read: ``read(reader, seq, frame) -> (N, ...)`` array or tensor of one rig sample at the reader's size
            (``reader``: a `mcdp.data.RigReader`: ``ds``, ``mask_full``, ``height``, ``width``).
        shape: its shape in words, for the docs and error messages, e.g. "(N, 1, H, W) metres".
        neighbours: it carries what other cameras see, so cutting the neighbours at inference empties it.
        truth: it reads ground truth: a network that reads it is an ORACLE (a yardstick, never a method).
    """

    name: str
    read: Callable[[Any, str, int], Any]
    shape: str = ""
    neighbours: bool = False
    truth: bool = False

    def of(self, reader, seq: str, frame: int) -> torch.Tensor:
        """This field for rig sample (seq, frame), as a float32 tensor (N, ...)."""
        return torch.as_tensor(self.read(reader, seq, frame), dtype=torch.float32)


@dataclass(frozen=True)
class DepthInput:
    """What a depth network reads in one forward pass: frame t of B rig samples.

    rgb (B, N, 3, H, W) float32 in [0, 1]; K (B, N, 3, 3); T_ego_cam (B, N, 4, 4); mask (B, N, 1, H, W) 1 =
    scene; nbr (N, 2) int64 [left, right] neighbour of each camera, -1 for none (`mcdp.data.neighbour_table`);
    fields: {name: (B, N, ...)} the declared `Field`s (``declared``: what they are), an emptied one absent.
    """

    rgb: torch.Tensor
    K: torch.Tensor
    T_ego_cam: torch.Tensor
    mask: torch.Tensor
    nbr: torch.Tensor
    fields: Mapping[str, torch.Tensor] = field(default_factory=dict)
    declared: tuple[Field, ...] = ()

    def get(self, f: Field | str) -> torch.Tensor | None:
        """The field's value, or None when it was not filled (not declared, or emptied)."""
        return self.fields.get(f if isinstance(f, str) else f.name)

    def cut(self) -> "DepthInput":
        """The same input with the neighbours cut: every neighbour entry -1, as for a camera without
        neighbours, and every field that carries other cameras' content (``Field.neighbours``) emptied."""
        drop = {f.name for f in self.declared if f.neighbours}
        return dataclasses.replace(self, nbr=torch.full_like(self.nbr, -1),
                                   fields={k: v for k, v in self.fields.items() if k not in drop})


@dataclass
class RigBatch:
    """One training step's rig samples (schema in the module docstring); `mcdp.data.collate` makes it."""

    rgb: torch.Tensor
    K: torch.Tensor
    T_ego_cam: torch.Tensor
    mask: torch.Tensor
    T_world_ego: torch.Tensor
    seq_index: torch.Tensor
    frame: torch.Tensor
    fields: dict[str, torch.Tensor] = field(default_factory=dict)

    def _map(self, fn) -> "RigBatch":
        """The same batch with ``fn`` applied to every tensor, the fields' too."""
        core = (fn(getattr(self, f.name)) for f in dataclasses.fields(self) if f.name != "fields")
        return RigBatch(*core, fields={k: fn(v) for k, v in self.fields.items()})

    def to(self, device, non_blocking: bool = False) -> "RigBatch":
        """The same batch on ``device``."""
        return self._map(lambda t: t.to(device, non_blocking=non_blocking))

    def pin_memory(self) -> "RigBatch":
        """The same batch in page-locked memory (the DataLoader calls this with ``pin_memory=True``, on CUDA)."""
        return self._map(lambda t: t.pin_memory())

    def depth_input(self, nbr: torch.Tensor, declared: tuple[Field, ...] = (),
                    rgb: torch.Tensor | None = None) -> DepthInput:
        """Frame t as a network reads it. ``rgb``: (B, N, 3, 3, H, W) images to use instead of ``self.rgb``
        (e.g. colour-augmented); ``declared``: the fields the network was filled with."""
        images = self.rgb if rgb is None else rgb
        return DepthInput(images[:, :, 1], self.K, self.T_ego_cam, self.mask, nbr, dict(self.fields), tuple(declared))


def stack(items: list[Mapping[str, Any]]) -> RigBatch:
    """Rig samples (dicts with the batch schema's keys, ``fields`` a dict) stacked into a `RigBatch`."""
    core = {k: torch.stack([it[k] for it in items]) for k in items[0] if k != "fields"}
    names = items[0].get("fields", {})
    return RigBatch(**core, fields={k: torch.stack([it["fields"][k] for it in items]) for k in names})
