"""What a depth network reads: `DepthInput` for one forward pass, `RigBatch` for one training step, and
the optional `InputField`s that only some methods read.

Every network reads the same core of a rig sample at frame t (`DepthInput`: images, intrinsics,
extrinsics, scene mask, neighbour table). What only some methods read is an `InputField`: a name, a reader
that makes it for one rig sample, and what it carries. A network declares the fields it reads
(`mcdp.methods.base.DepthNetwork.inputs`); the data reader (`mcdp.data.RigDataset`) and the predictor
(`mcdp.predict.Predictor.inputs`) fill those and no other (both read them with `read_fields` and make the
network's input with the one constructor `DepthInput.filled`), and the network finds them in ``DepthInput.fields``.
A network runs with any declared field absent (``inp.get(FIELD)`` is None): the cut empties the fields that carry
other cameras' content, and a caller may fill none (tests/mcdp/test_methods.py runs every registered network
with each declared field absent). A method that needs an input of its own declares its `InputField` in its own module
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
    fields       {name: (B, N, ...)}                    the declared `InputField`s, nothing else
    lens         `mcdp.camera.Lens` or None             the cameras' lens models, dist (B, N, D) (issue 59);
                                                        None: every camera pinhole (depth then z-depth)

With a lens, each camera's depth is of its row's depth kind (range for kannala_brandt) and every warp of the
step goes through the lens (`mcdp.camera.Lens.of`); a pinhole rig has no lens and its step is unchanged.

Ground truth enters a batch only through a field that says so (``InputField.truth``: an ORACLE's input, a
yardstick); the rows whose networks read one are labelled ORACLE in every report.

Example (run as a doctest in the fast tier, tests/test_doctests.py): a field of one value per camera, two rig
samples of two cameras stacked into a batch (`mcdp.data.collate` does this for `mcdp.data.RigDataset`'s samples),
frame t as the network reads it, and its cut::

    >>> import torch
    >>> SPEED = InputField("speed", lambda reader, seq, frame: [2.0, 2.0], "(N,) metres per frame")
    >>> sample = {"rgb": torch.zeros(2, 3, 3, 4, 6), "K": torch.eye(3).repeat(2, 1, 1),
    ...           "T_ego_cam": torch.eye(4).repeat(2, 1, 1), "mask": torch.ones(2, 1, 4, 6),
    ...           "T_world_ego": torch.eye(4).repeat(3, 1, 1), "seq_index": torch.tensor(0), "frame": torch.tensor(1),
    ...           "fields": read_fields((SPEED,), None, "seq", 1)}
    >>> batch = stack([sample, sample])
    >>> nbr = torch.tensor([[1, 1], [0, 0]])                # each camera's left and right neighbour
    >>> inp = batch.depth_input(nbr, declared=(SPEED,))
    >>> tuple(inp.rgb.shape), inp.get(SPEED).tolist()
    ((2, 2, 3, 4, 6), [[2.0, 2.0], [2.0, 2.0]])
    >>> cut = inp.cut()                                     # SPEED carries no other camera's content: it stays
    >>> cut.nbr.tolist(), cut.get(SPEED) is not None
    ([[-1, -1], [-1, -1]], True)
"""
from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field
from typing import Any, Callable, Mapping

import torch

from mcdp.camera import Lens


@dataclass(frozen=True)
class InputField:
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


def read_fields(declared: tuple[InputField, ...], reader, seq: str, frame: int) -> dict[str, torch.Tensor]:
    """{name: (N, ...) float32} of every declared field for rig sample (seq, frame): what the data reader puts in
    a sample and the predictor in its input (``reader``: a `mcdp.data.RigReader`)."""
    return {f.name: f.of(reader, seq, frame) for f in declared}


@dataclass(frozen=True)
class DepthInput:
    """What a depth network reads in one forward pass: frame t of B rig samples.

    rgb (B, N, 3, H, W) float32 in [0, 1]; K (B, N, 3, 3); T_ego_cam (B, N, 4, 4); mask (B, N, 1, H, W) 1 =
    scene; nbr (N, 2) int64 [left, right] neighbour of each camera, -1 for none (`mcdp.data.neighbour_table`);
    fields: {name: (B, N, ...)} the declared `InputField`s (``declared``: what they are), an emptied one absent;
    lens: the cameras' lenses (`mcdp.camera.Lens`, dist (B, N, D)), None for a pinhole rig.
    """

    rgb: torch.Tensor
    K: torch.Tensor
    T_ego_cam: torch.Tensor
    mask: torch.Tensor
    nbr: torch.Tensor
    fields: Mapping[str, torch.Tensor] = field(default_factory=dict)
    declared: tuple[InputField, ...] = ()
    lens: Lens | None = None

    @classmethod
    def filled(cls, rgb: torch.Tensor, K: torch.Tensor, T_ego_cam: torch.Tensor, mask: torch.Tensor, nbr: torch.Tensor,
               values: Mapping[str, torch.Tensor], declared: tuple[InputField, ...],
               lens: Lens | None = None) -> "DepthInput":
        """The one constructor of a network's input from read data, used by the data reader's batches
        (`RigBatch.depth_input`) and the predictor (`mcdp.predict.Predictor.inputs`): frame t of the rig and the
        values of the declared fields. A declared field may be absent (the network runs without it); a value that
        no declared field names is a ValueError (a network is filled with what it declares, nothing else)."""
        known = {f.name for f in declared}
        extra = sorted(set(values) - known)
        if extra:
            raise ValueError(f"input field {extra[0]!r} is not declared (declared: {', '.join(sorted(known)) or 'none'})")
        return cls(rgb, K, T_ego_cam, mask, nbr, dict(values), tuple(declared), lens)

    def get(self, f: InputField | str) -> torch.Tensor | None:
        """The field's value, or None when it was not filled (not declared, or emptied)."""
        return self.fields.get(f if isinstance(f, str) else f.name)

    def cut(self) -> "DepthInput":
        """The same input with the neighbours cut: every neighbour entry -1, as for a camera without
        neighbours, and every field that carries other cameras' content (``InputField.neighbours``) emptied."""
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
    lens: Lens | None = None

    def _map(self, fn) -> "RigBatch":
        """The same batch with ``fn`` applied to every tensor, the fields' and the lens's too."""
        core = (fn(getattr(self, f.name)) for f in dataclasses.fields(self) if f.name not in ("fields", "lens"))
        return RigBatch(*core, fields={k: fn(v) for k, v in self.fields.items()},
                        lens=None if self.lens is None else self.lens.map(fn))

    def to(self, device, non_blocking: bool = False) -> "RigBatch":
        """The same batch on ``device``."""
        return self._map(lambda t: t.to(device, non_blocking=non_blocking))

    def pin_memory(self) -> "RigBatch":
        """The same batch in page-locked memory (the DataLoader calls this with ``pin_memory=True``, on CUDA)."""
        return self._map(lambda t: t.pin_memory())

    def depth_input(self, nbr: torch.Tensor, declared: tuple[InputField, ...] = (),
                    rgb: torch.Tensor | None = None) -> DepthInput:
        """Frame t as a network reads it. ``rgb``: (B, N, 3, 3, H, W) images to use instead of ``self.rgb``
        (e.g. colour-augmented); ``declared``: the fields the network was filled with."""
        images = self.rgb if rgb is None else rgb
        return DepthInput.filled(images[:, :, 1], self.K, self.T_ego_cam, self.mask, nbr, self.fields, tuple(declared),
                                 self.lens)


def stack(items: list[Mapping[str, Any]]) -> RigBatch:
    """Rig samples (dicts with the batch schema's keys, ``fields`` a dict, ``lens`` a `Lens` of (N, D) or absent)
    stacked into a `RigBatch`."""
    core = {k: torch.stack([it[k] for it in items]) for k in items[0] if k not in ("fields", "lens")}
    names = items[0].get("fields", {})
    lens = items[0].get("lens")
    lens = None if lens is None else Lens(lens.models, torch.stack([it["lens"].dist for it in items]))
    return RigBatch(**core, fields={k: torch.stack([it["fields"][k] for it in items]) for k in names}, lens=lens)
