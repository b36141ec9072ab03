"""Inference with a trained run: depth of every stage at the dataset resolution, plus outputs on disk.

`Predictor(run_dir, ds)` loads a checkpoint and answers ``predict(seq, frame)
-> {stage: (N, H, W) float32 metres}`` (the ``predict_fn`` of
`mcdp.evaluate.evaluate`). The network runs at the training size; depth is
upsampled bilinearly to each camera's dataset size. Only frame t is used (no
temporal neighbours, no pose network). No ground truth is read, except by a
run trained with ``scale.source=oracle_gt_median``, which rescales by the GT
median exactly as in training and is labelled ORACLE (`Predictor.oracle`), and the
``oracle_weights`` yardsticks (`mcdp.oracle`), extra stages "oracle" (weights fitted on every
valid pixel) and "oracle_overlap" (fitted on the overlap pixels only) after "final".

Two switches serve the overlap experiment (`study.stages`):

- ``cut=True`` cuts the neighbours at inference: every camera's neighbour table entry is -1,
  so each weight network sees zeros and valid = 0 for both neighbours, exactly as a camera
  without neighbours. As trained minus cut is what the neighbours contribute.
- `Predictor.refinement` accumulates, over every predicted image, how much the refinement acts:
  mean |w - 1/n| of the last stage's weights and the mean |refined - init| depth (metres, scene
  pixels, training size). Near zero means an inert refinement. A cut predictor given the as-trained
  one as ``reference`` (which then keeps its depths: ``keep=True``) also records ``cut_change_m``, the
  mean |as trained - cut| depth of the same images: what cutting the neighbours changes, in metres.

`write_prediction` writes, per rig sample::

    PRED/<seq>/<frame:06d>_grid.png          row 1 RGB, then one colour-mapped
                                             disparity row per stage; 6 cameras side by side
    PRED/<seq>/<CAM>/<frame:06d>.depth.exr   final-stage z-depth, metres (channel "Z")
    PRED/<seq>/<frame:06d>.ply               optional: coloured point cloud of the rig, ego frame

Example::

    mcdp predict runs/m1 --data data/tiny --out pred --ply
"""
from __future__ import annotations

from pathlib import Path

import numpy as np
import torch
import torch.nn.functional as F

from corelib.atomic import atomic_write_bytes
from corelib.configlib import config_to_dict
from mcdp.data import RigReader, neighbour_table
from mcdp.methods import build_depth_model
from mcdp.runs import RunError, config_from_checkpoint, find_checkpoint, load_checkpoint, resolve_device
from mcdp.visual import depth_grid
from synth.protocol import DatasetReader


class Predictor:
    """Depth of every stage for rig samples of a dataset, from a run's checkpoint.

    Args:
        run_dir: run folder (or None when ``checkpoint`` is a path).
        ds: the dataset (`synth.protocol.DatasetReader`) with the same cameras as in training.
        checkpoint: ``auto`` | ``best`` | ``last`` | path.
        device: ``auto`` | ``cpu`` | ``cuda``.
    """

    #: at most this many bytes of depth maps kept for a cut predictor's comparison (``keep=True``)
    KEEP_BYTES = 64 << 20

    def __init__(self, run_dir, ds: DatasetReader, checkpoint: str = "auto", device: str = "auto", cut: bool = False,
                 oracle_weights: bool = False, oracle_range: tuple[float, float] = (0.5, 80.0), keep: bool = False,
                 reference: "Predictor | None" = None):
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
        self.model = build_depth_model(self.cfg.model).to(self.device)
        self.model.load_state_dict(ckpt["depth_model"])
        self.model.eval()
        self.reader = RigReader(ds, self.cfg.train.height, self.cfg.train.width)
        self.nbr = neighbour_table(ds.neighbours, len(ds.camera_names)).to(self.device)
        self.cut = bool(cut)
        if self.cut:  # neighbours cut at inference: as for a camera without neighbours
            self.nbr = torch.full_like(self.nbr, -1)
        self.K = torch.from_numpy(self.reader.K).to(self.device)[None]
        self.T_ego_cam = torch.from_numpy(self.reader.T_ego_cam).to(self.device)[None]
        self.mask = torch.from_numpy(self.reader.mask).to(self.device)[None]
        self.oracle = self.cfg.scale.oracle
        self.stages = list(self.model.stages)
        self.n_out = self.model.n_out  # depth bases of the network (1: nothing to weight)
        self.oracle_weights = bool(oracle_weights) and self.n_out > 1
        self.oracle_range = (float(oracle_range[0]), float(oracle_range[1]))
        self._acc = {"images": 0, "weight_move": 0.0, "depth_change_m": 0.0, "oracle_weight_move": 0.0,
                     "cut_images": 0, "cut_change_m": 0.0}
        self.kept: dict | None = {} if keep else None  # (seq, frame) -> last stage's depth at training size
        self._kept_bytes = 0
        self.reference = reference

    @property
    def refinement(self) -> dict:
        """How much the refinement acted on the images predicted so far (module docstring)."""
        a = self._acc
        k = max(a["images"], 1)
        out = {"images": a["images"], "cut": self.cut,
               "weight_move": a["weight_move"] / k if len(self.stages) > 1 else float("nan"),
               "depth_change_m": a["depth_change_m"] / k if len(self.stages) > 1 else float("nan")}
        if self.oracle_weights:
            out["oracle_weight_move"] = a["oracle_weight_move"] / k
        if self.reference is not None:
            out["cut_change_m"] = a["cut_change_m"] / a["cut_images"] if a["cut_images"] else float("nan")
        return out

    def _compare(self, seq: str, frame: int, depth: torch.Tensor) -> None:
        """Keep this depth (``keep``) and/or add its mean |difference| to the reference's (``reference``)."""
        if self.kept is not None and self._kept_bytes + depth.numel() * 4 <= self.KEEP_BYTES:
            self.kept[seq, frame] = depth.float().cpu()
            self._kept_bytes += depth.numel() * 4
        ref = None if self.reference is None or self.reference.kept is None else self.reference.kept.get((seq, frame))
        if ref is not None:
            m = self.mask.reshape(-1, 1, *self.mask.shape[-2:]).float()
            diff = (depth.float() - ref.to(depth.device)).abs() * m
            self._acc["cut_change_m"] += float((diff.flatten(1).sum(1) / m.flatten(1).sum(1).clamp(min=1)).sum())
            self._acc["cut_images"] += int(depth.shape[0])

    def _record(self, out: dict) -> None:
        last = self.stages[-1]
        w = out.get(("weights", last))  # None for a method without basis weights
        self._acc["images"] += int(out["depth", last, 0].shape[0])
        if w is None or last == "init" or "init" not in self.stages:
            return
        n = w.shape[1]  # (B*N, n) or per pixel (B*N, n, h, w) (`mcdp.local`): the mean over all of them
        self._acc["weight_move"] += float((w.float() - 1.0 / n).abs().flatten(1).mean(1).sum())
        m = self.mask.reshape(-1, 1, *self.mask.shape[-2:]).float()
        diff = (out["depth", last, 0].float() - out["depth", "init", 0].float()).abs() * m
        self._acc["depth_change_m"] += float((diff.flatten(1).sum(1) / m.flatten(1).sum(1).clamp(min=1)).sum())

    def _oracle_depth(self, seq: str, frame: int, out: dict) -> tuple[torch.Tensor, torch.Tensor]:
        """ORACLE: depth of this run's bases at weights fitted to the ground truth (`mcdp.oracle`): on every
        valid pixel ("oracle"), and on the overlap pixels only ("oracle_overlap": what MCDP's one global
        weight vector per image could carry from a perfectly known overlap to the rest of the image)."""
        from mcdp.model import combine_bases
        from mcdp.oracle import fit_oracle_weights, ground_truth_at, overlap_at

        bases = out["bases"][0]  # (N, n, h, w)
        size = tuple(bases.shape[-2:])
        gt, valid = ground_truth_at(self.ds, self.reader.mask_full, seq, frame, size, self.oracle_range)
        gt, valid = gt.to(self.device), valid.to(self.device)
        wts = fit_oracle_weights(bases, gt, valid, self.model.to_depth)
        n = wts.shape[1]
        self._acc["oracle_weight_move"] += float((wts - 1.0 / n).abs().mean(1).sum())
        ov = overlap_at(self.ds, self.reader.mask_full, seq, frame, size).to(self.device)
        w_ov = fit_oracle_weights(bases, gt, valid & ov, self.model.to_depth)  # no overlap pixel: 1/n
        return (self.model.to_depth(combine_bases(bases.float(), wts))[1],
                self.model.to_depth(combine_bases(bases.float(), w_ov))[1])

    @torch.no_grad()
    def predict_train_size(self, seq: str, frame: int) -> tuple[dict, np.ndarray]:
        """({stage: (N, 1, h, w) tensor metres at training size}, rgb (N, 3, h, w))."""
        rgb = self.reader.rgb(seq, frame)
        x = torch.from_numpy(rgb).to(self.device)[None]
        gtm = None
        if self.oracle:  # ORACLE: the reference code's ground-truth median scaling
            gtm = torch.from_numpy(self.reader.gt_median(seq, frame)).to(self.device)[None]
        hint = None
        if self.model.reads_overlap_truth and not self.cut:  # ORACLE-local, filled (cut: emptied)
            from mcdp.oracle import overlap_truth_at

            hint = overlap_truth_at(self.ds, self.reader.mask_full, seq, frame, tuple(self.mask.shape[-2:]))
            hint = hint.to(self.device)[None]
        out = self.model(x, self.K, self.T_ego_cam, self.mask, self.nbr, gtm, scales=1, overlap_truth=hint)
        self._record(out)
        if self.kept is not None or self.reference is not None:
            self._compare(seq, frame, out["depth", self.stages[-1], 0])
        res = {st: out["depth", st, 0].float() for st in self.stages}
        if self.oracle_weights:  # "final" is named explicitly so that the yardstick stays apart from it
            res["final"] = res[self.stages[-1]]
            d_all, d_ov = self._oracle_depth(seq, frame, out)
            res["oracle"] = d_all * out["scale"].view(-1, 1, 1, 1)
            res["oracle_overlap"] = d_ov * out["scale"].view(-1, 1, 1, 1)
        return res, rgb

    def predict(self, seq: str, frame: int) -> dict[str, np.ndarray]:
        """{stage: (N, H, W) float32 metres at the dataset resolution}, stages in order."""
        small, _ = self.predict_train_size(seq, frame)
        res = {}
        for st, d in small.items():
            cams = []
            for c, spec in enumerate(self.ds.cameras):
                up = F.interpolate(d[c : c + 1], size=(spec.height, spec.width), mode="bilinear", align_corners=False)
                cams.append(up[0, 0].cpu().numpy().astype(np.float32))
            shapes = {a.shape for a in cams}
            res[st] = np.stack(cams) if len(shapes) == 1 else cams
        return res

    __call__ = predict


# --------------------------------------------------------------------------- outputs
def rig_point_cloud(
    ds, depths: list[np.ndarray], rgbs: list[np.ndarray], stride: int = 2, max_depth: float = 80.0
) -> tuple[np.ndarray, np.ndarray]:
    """Points of every camera in the ego frame: (M, 3) float32 metres, (M, 3) uint8 colours.

    Ego-body pixels (mask) and depths beyond max_depth are dropped; every
    ``stride``-th pixel in each direction is used.
    """
    pts, cols = [], []
    for c, spec in enumerate(ds.cameras):
        d = depths[c]
        H, W = d.shape
        v, u = np.mgrid[0:H:stride, 0:W:stride]
        z = d[v, u]
        keep = (z > 0) & (z <= max_depth) & np.asarray(ds.mask(spec.name), bool)[v, u]
        uv1 = np.stack([u[keep] + 0.5, v[keep] + 0.5, np.ones(keep.sum())], 0)  # pixel centres at +0.5
        X = np.linalg.inv(np.asarray(spec.K, float)) @ uv1 * z[keep]
        T = np.asarray(spec.T_ego_cam, float)
        pts.append((T[:3, :3] @ X + T[:3, 3:4]).T)
        cols.append(rgbs[c][v[keep], u[keep]])
    return np.concatenate(pts).astype(np.float32), np.concatenate(cols).astype(np.uint8)


def write_ply(path: str | Path, points: np.ndarray, colors: np.ndarray) -> None:
    """Binary little-endian PLY with float xyz and uchar rgb."""
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
        pts, cols = rig_point_cloud(pred.ds, list(final), rgbs)
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
