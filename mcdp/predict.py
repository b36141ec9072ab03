"""Inference with a trained run: depth of every stage at the dataset resolution, plus outputs on disk.

`Predictor(run_dir, ds)` loads a checkpoint and answers ``predict(seq, frame)
-> {stage: (N, H, W) float32 metres}`` (the ``predict_fn`` of
`mcdp.evaluate.evaluate`). The network runs at the training size; depth is
upsampled bilinearly to each camera's dataset size. Only frame t is used (no
temporal neighbours, no pose network). No ground truth is read, except what the network itself
declares as an input field (`mcdp.inputs.InputField`): a run trained with ``scale.source=oracle_gt_median``
rescales by the GT median exactly as in training and is labelled ORACLE (`Predictor.oracle`), and
ORACLE-local is given the overlap's ground-truth depth (its field reads it).

Inference only predicts. Its steps are public so that an experiment can change an input or
observe the outputs without the predictor knowing the experiment (the overlap experiment's cut,
ORACLE weights and refinement statistics: `study.sweep.probes`)::

    inp = pred.inputs(seq, frame)      # `Inputs`: what the network reads of one rig sample
    out = pred.forward(inp.cut())      # the network's outputs, here with the neighbours cut
    small = pred.stages_of(out)        # {stage: (N, 1, h, w) metres at training size}
    depth = pred.upsample(small)       # {stage: (N, H, W) float32 metres at the dataset size}

`write_prediction` writes, per rig sample::

    PRED/<seq>/<frame:06d>_grid.png          row 1 RGB, then one colour-mapped
                                             disparity row per stage; 6 cameras side by side
    PRED/<seq>/<CAM>/<frame:06d>.depth.exr   final-stage z-depth, metres (channel "Z")
    PRED/<seq>/<frame:06d>.ply               optional: coloured point cloud of the rig, ego frame

Example::

    mcdp predict runs/m1 --data data/tiny --out pred --ply
"""
from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch
import torch.nn.functional as F

from corelib.atomic import atomic_write_bytes
from corelib.configlib import config_to_dict
from mcdp.config import EVAL_MAX_DEPTH
from mcdp.data import RigReader, neighbour_table
from mcdp.inputs import DepthInput, read_fields
from mcdp.methods import build_network, fields_of, method_params
from mcdp.runs import RunError, config_from_checkpoint, find_checkpoint, load_checkpoint, resolve_device
from mcdp.visual import depth_grid
from synth.protocol import DatasetReader, pixel_rays_at


@dataclass(frozen=True)
class Inputs:
    """One rig sample at inference: which it is, its images at training size ``rgb_np`` (N, 3, h, w) float32
    in [0, 1], and ``network_input``, the `mcdp.inputs.DepthInput` (a batch of one rig) the network reads,
    with the input fields it declares and no other."""

    seq: str
    frame: int
    rgb_np: np.ndarray
    network_input: DepthInput

    def cut(self) -> "Inputs":
        """The same sample with the neighbours cut (`mcdp.inputs.DepthInput.cut`)."""
        return dataclasses.replace(self, network_input=self.network_input.cut())


class Predictor:
    """Depth of every stage for rig samples of a dataset, from a run's checkpoint.

    Args:
        run_dir: run folder (or None when ``checkpoint`` is a path).
        ds: the dataset (`synth.protocol.DatasetReader`) with the same cameras as in training.
        checkpoint: ``auto`` | ``best`` | ``last`` | path.
        device: ``auto`` | ``cpu`` | ``cuda``.
    """

    def __init__(self, run_dir, ds: DatasetReader, checkpoint: str = "auto", device: str = "auto"):
        self.ckpt_path = find_checkpoint(run_dir, checkpoint) if run_dir is not None else Path(checkpoint)
        ckpt = load_checkpoint(self.ckpt_path)
        self.cfg = config_from_checkpoint(ckpt, source=str(self.ckpt_path))
        self.step = int(ckpt["step"])
        trained_cams = ckpt.get("cameras")
        if trained_cams is not None and list(trained_cams) != list(ds.camera_names):
            raise RunError(
                f"dataset {ds.root} has cameras {list(ds.camera_names)}, the run was trained on {list(trained_cams)}"
            )
        self.ds = ds
        self.device = resolve_device(device)
        self.network = build_network(self.cfg.model, method_params(self.cfg)).to(self.device)
        self.network.load_state_dict(ckpt["depth_model"])
        self.network.eval()
        for name in ("encoder", "decoder"):  # a second forward of the same images reuses their features (`SameInputs`)
            module = getattr(self.network, name, None)
            if isinstance(module, torch.nn.Module):
                module.forward = SameInputs(module.forward)
        self.fields = fields_of(self.cfg)  # the input fields the network reads (as in training)
        self.reader = RigReader(ds, self.cfg.train.height, self.cfg.train.width, sync=self.cfg.model.sync,
                                lens=self.cfg.model.lens)  # the network's warps as trained (model.lens)
        self.nbr = neighbour_table(ds.neighbours, len(ds.camera_names)).to(self.device)
        self.K = torch.from_numpy(self.reader.K).to(self.device)[None]
        self.T_ego_cam = torch.from_numpy(self.reader.T_ego_cam).to(self.device)[None]
        self.mask = torch.from_numpy(self.reader.mask).to(self.device)[None]
        self.lens = None if self.reader.lens is None else self.reader.lens.map(lambda d: d.to(self.device)[None])
        self.oracle = self.cfg.scale.oracle
        self.stages = list(self.network.stages)
        self.n_out = self.network.n_out  # depth bases of the network (1: nothing to weight)
        self._last_inputs: Inputs | None = None

    def inputs(self, seq: str, frame: int) -> Inputs:
        """What the network reads of rig sample (seq, frame), as trained; asked again for the sample it last
        answered (each pass of an evaluation asks in turn), the same `Inputs`, not read again."""
        last = self._last_inputs
        if last is not None and (last.seq, last.frame) == (seq, frame):
            return last
        rgb = self.reader.rgb(seq, frame)
        values = {k: v.to(self.device)[None] for k, v in read_fields(self.fields, self.reader, seq, frame).items()}
        T = torch.from_numpy(self.reader.T_ego_cam_at(seq, frame)).to(self.device)[None]  # model.sync, as trained
        net = DepthInput.filled(torch.from_numpy(rgb).to(self.device)[None], self.K, T, self.mask, self.nbr,
                                values, self.fields, self.lens)
        self._last_inputs = Inputs(seq, frame, rgb, net)
        return self._last_inputs

    @torch.no_grad()
    def forward(self, inp: Inputs) -> dict:
        """The network's outputs for ``inp`` at training size (`mcdp.methods.depth_bases.DepthModel.forward`, scale 0 only)."""
        return self.network(inp.network_input, scales=1)

    def stages_of(self, out: dict) -> dict[str, torch.Tensor]:
        """{stage: (N, 1, h, w) float32 metres at training size}, stages in order."""
        return {st: out["depth", st, 0].float() for st in self.stages}

    def upsample(self, small: dict[str, torch.Tensor]) -> dict[str, np.ndarray]:
        """{stage: (N, 1, h, w) tensor} -> {stage: (N, H, W) float32 numpy at each camera's dataset size}
        (a list of (H_c, W_c) arrays when the cameras' sizes differ)."""
        res = {}
        for st, d in small.items():
            cams = []
            for c, spec in enumerate(self.ds.cameras):
                up = F.interpolate(d[c : c + 1], size=(spec.height, spec.width), mode="bilinear", align_corners=False)
                cams.append(up[0, 0].cpu().numpy().astype(np.float32))
            shapes = {a.shape for a in cams}
            res[st] = np.stack(cams) if len(shapes) == 1 else cams
        return res

    def predict_train_size(self, seq: str, frame: int) -> tuple[dict, np.ndarray]:
        """({stage: (N, 1, h, w) tensor metres at training size}, rgb (N, 3, h, w))."""
        inp = self.inputs(seq, frame)
        return self.stages_of(self.forward(inp)), inp.rgb_np

    def predict(self, seq: str, frame: int) -> dict[str, np.ndarray]:
        """{stage: (N, H, W) float32 metres at the dataset resolution}, stages in order."""
        return self.upsample(self.predict_train_size(seq, frame)[0])

    __call__ = predict


class SameInputs:
    """A module's ``forward`` that remembers its last call: called again without gradients on inputs equal to the
    last ones (same tensors' shapes, dtypes and values, `torch.equal`; a list of tensors element by element), it
    returns the outputs it gave (a new list or dict of the same tensors) without running again. The evaluation's
    passes of one sample (as trained, then with the neighbours cut) feed the encoder the same images: the cut pass
    reuses the encoder's and decoder's outputs, bit for bit what running them again gives (eval mode: a pure
    function of the inputs). It keeps a copy of the inputs and checks that its outputs were not changed in place
    (their version counters); with gradients enabled or in training mode it always runs."""

    def __init__(self, forward) -> None:
        self.forward = forward
        self.module = getattr(forward, "__self__", None)
        self.hits = self.calls = 0
        self._last: tuple | None = None  # (copy of the inputs, outputs, their versions)

    @staticmethod
    def _tensors(x) -> list | None:
        """The tensors of an output (a tensor, a list / tuple of them, a dict of them); None if anything else."""
        items = x.values() if isinstance(x, dict) else x if isinstance(x, (list, tuple)) else [x]
        items = list(items)
        return items if all(isinstance(t, torch.Tensor) for t in items) else None

    @staticmethod
    def _same(a, b) -> bool:
        if isinstance(a, torch.Tensor) or isinstance(b, torch.Tensor):
            return (isinstance(a, torch.Tensor) and isinstance(b, torch.Tensor) and a.shape == b.shape
                    and a.dtype == b.dtype and a.device == b.device and bool(torch.equal(a, b)))
        if isinstance(a, (list, tuple)) and isinstance(b, (list, tuple)):
            return len(a) == len(b) and all(SameInputs._same(x, y) for x, y in zip(a, b))
        if isinstance(a, dict) and isinstance(b, dict):
            return a.keys() == b.keys() and all(SameInputs._same(a[k], b[k]) for k in a)
        return type(a) is type(b) and a == b

    def _weights(self) -> list[int]:
        """The version of every parameter and buffer: weights changed in place (a load, an optimiser step under
        no_grad) make the kept output stale."""
        if self.module is None:
            return []
        return [t._version for t in (*self.module.parameters(), *self.module.buffers())]

    @staticmethod
    def _copy(x):
        if isinstance(x, torch.Tensor):
            return x.detach().clone()
        if isinstance(x, (list, tuple)):
            return [SameInputs._copy(v) for v in x]
        if isinstance(x, dict):
            return {k: SameInputs._copy(v) for k, v in x.items()}
        return x

    def __call__(self, *args, **kwargs):
        self.calls += 1
        if (torch.is_grad_enabled() or torch.is_inference_mode_enabled()  # inference tensors keep no version
                or (self.module is not None and self.module.training)):
            self._last = None
            return self.forward(*args, **kwargs)
        last = self._last
        if last is not None and self._same(last[0], (args, kwargs)):
            out, versions = last[1], last[2]
            if [t._version for t in self._tensors(out)] + self._weights() == versions:
                self.hits += 1
                return dict(out) if isinstance(out, dict) else list(out) if isinstance(out, list) else out
        out = self.forward(*args, **kwargs)
        tensors = self._tensors(out)
        self._last = None if tensors is None else (self._copy((args, kwargs)), out,
                                                   [t._version for t in tensors] + self._weights())
        return dict(out) if isinstance(out, dict) else list(out) if isinstance(out, list) else out


# --------------------------------------------------------------------------- outputs
def rig_point_cloud(
    ds, depths: list[np.ndarray], rgbs: list[np.ndarray], stride: int = 2, max_depth: float = EVAL_MAX_DEPTH,
    poses: np.ndarray | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """Points of every camera in the ego frame: (M, 3) float32 metres, (M, 3) uint8 colours.

    Ego-body pixels (mask) and depths beyond max_depth are dropped; every
    ``stride``-th pixel in each direction is used. ``poses``: (N, 4, 4) each camera's pose in the ego frame
    (cameras that fire at their own times: the reader's ``camera_poses`` of the frame); None: the static
    extrinsics.
    """
    pts, cols = [], []
    for c, spec in enumerate(ds.cameras):
        d = depths[c]
        H, W = d.shape
        v, u = np.mgrid[0:H:stride, 0:W:stride]
        z = d[v, u]
        keep = (z > 0) & (z <= max_depth) & np.asarray(ds.mask(spec.name), bool)[v, u]
        X = pixel_rays_at(spec.intrinsics, u[keep], v[keep]) * z[keep]  # through its lens: z-depth or range
        T = np.asarray(spec.T_ego_cam if poses is None else poses[c], float)
        pts.append((T[:3, :3] @ X + T[:3, 3:4]).T)
        cols.append(rgbs[c][v[keep], u[keep]])
    return np.concatenate(pts).astype(np.float32), np.concatenate(cols).astype(np.uint8)


def write_ply(path: str | Path, points: np.ndarray, colors: np.ndarray) -> None:
    """Binary little-endian PLY with float xyz and uchar rgb.

    Hand-written (a 10-line header and one numpy record array) on purpose: trimesh, which writes PLY, is
    only in the optional ``viz`` extra, which lives in its own environment (``.venv-viz``: rerun-sdk needs
    numpy >= 2), while ``mcdp predict --ply`` runs in ``.venv``; plyfile would be a new dependency for
    the same ten lines. tests/mcdp/test_cli.py reads the file back."""
    n = len(points)
    header = (
        "ply\nformat binary_little_endian 1.0\n"
        f"element vertex {n}\nproperty float x\nproperty float y\nproperty float z\n"
        "property uchar red\nproperty uchar green\nproperty uchar blue\nend_header\n"
    )
    rec = np.empty(n, dtype=[("x", "<f4"), ("y", "<f4"), ("z", "<f4"), ("r", "u1"), ("g", "u1"), ("b", "u1")])
    rec["x"], rec["y"], rec["z"] = points[:, 0], points[:, 1], points[:, 2]
    rec["r"], rec["g"], rec["b"] = colors[:, 0], colors[:, 1], colors[:, 2]
    atomic_write_bytes(path, header.encode("ascii") + rec.tobytes())


def write_prediction(pred: Predictor, seq: str, frame: int, out_dir: str | Path, ply: bool = False) -> list[Path]:
    """Write the grid PNG, final-stage EXR depth per camera and (optionally) the PLY of one rig sample."""
    from synth.files import frame_stem, write_depth_exr, write_png

    out = Path(out_dir) / seq
    out.mkdir(parents=True, exist_ok=True)
    depths = pred.predict(seq, frame)
    rgbs = [pred.ds.read_rgb(seq, n, frame) for n in pred.ds.camera_names]
    final = depths[pred.stages[-1]]
    written = []
    grid = depth_grid(rgbs, {st: list(d) for st, d in depths.items()})
    p = out / f"{frame_stem(frame)}_grid.png"
    write_png(p, grid)
    written.append(p)
    for c, name in enumerate(pred.ds.camera_names):
        (out / name).mkdir(exist_ok=True)
        p = out / name / f"{frame_stem(frame)}.depth.exr"
        write_depth_exr(p, np.ascontiguousarray(final[c], dtype=np.float32))
        written.append(p)
    if ply:
        poses = pred.reader.camera_poses(seq)[1][frame]  # each camera where it was when it fired (static if together)
        pts, cols = rig_point_cloud(pred.ds, list(final), rgbs, poses=poses)
        p = out / f"{frame_stem(frame)}.ply"
        write_ply(p, pts, cols)
        written.append(p)
    return written


def run_record(pred: Predictor, run_dir: Path, data_path: str, rig_diff: list[str] | None) -> dict:
    """The ``metrics["run"]`` record of an evaluated checkpoint (``mcdp eval`` and the sweep write it).

    ``rig_diff``: `mcdp.runs.rig_differences` of the evaluated dataset (None: the run did not record its rig).
    """
    return {"run_dir": str(run_dir), "checkpoint": str(pred.ckpt_path), "step": pred.step,
            "method": pred.cfg.model.method, "refine_steps": pred.cfg.model.refine_steps,
            "bases": pred.n_out, "consistency_weight": pred.cfg.loss.consistency_weight,
            "scale_source": pred.cfg.scale.source, "oracle": pred.oracle, "config": config_to_dict(pred.cfg),
            "data": data_path, "rig_as_trained": None if rig_diff is None else not rig_diff,
            "rig_differences": rig_diff}
