"""The overlap experiment's probes over a run's predictions: the cut, the ORACLE weights, what the
refinement does. Inference (`mcdp.predict.Predictor`) only predicts; this module changes its inputs and
observes its outputs, so that the predictor knows nothing of the experiment.

- **variant** ``trained`` or ``cut``. ``cut`` cuts the neighbours at inference: every camera's neighbour
  table entry is -1, so each weight network sees zeros and valid = 0 for both neighbours, exactly as a
  camera without neighbours, and an ORACLE-local input is emptied. As trained minus cut is what the
  neighbours contribute.
- **refinement** (`Probed.refinement`): accumulated over every predicted image, how much the refinement
  acts: mean |w - 1/n| of the last stage's weights and the mean |refined - init| depth (metres, scene
  pixels, training size). Near zero means an inert refinement. A cut probe given the as-trained one as
  ``reference`` (which then keeps its depths: ``keep=True``) also records ``cut_change_m``, the mean
  |as trained - cut| depth of the same images: what cutting the neighbours changes, in metres.
- **ORACLE weights** (``oracle_range``, a network with bases only): the extra stages "oracle" (this run's
  bases at weights fitted to the ground truth on every valid pixel, `mcdp.oracle`) and "oracle_overlap"
  (fitted on the overlap pixels only: what one global weight vector per image could carry from a perfectly
  known overlap to the rest), after "final". They read ground truth: yardsticks, not methods.
- **hand-built propagator** (``oracle_range``, a network that reads no other camera only): the extra stage
  "oracle_spread", the last stage's depth corrected from the overlap's ground truth alone
  (`mcdp.oracle.spread_from_overlap`): how much the overlap could tell the rest of the image through a
  simple propagator that needs no training, whatever the budget. A yardstick too.

Example::

    pred = Predictor(run_dir, ds)
    trained = Probed(pred, oracle_range=(0.5, 80.0), keep=True)
    cut = Probed(pred, CUT, reference=trained)
    metrics = evaluate(ds, trained.predict, "test", ecfg); metrics["refinement"] = trained.refinement
"""
from __future__ import annotations


import numpy as np
import torch

from study.variants import CUT, TRAINED, VARIANTS

#: the variants a `Probed` runs (the ORACLE ones are extra stages of the as-trained probe)
PROBED = (TRAINED, CUT)


def trained_probe(pred, oracle_range, earlier: dict) -> "Probed":
    """The probe of variant ``trained``: as trained, with the ORACLE stages; it keeps its depths (<= 64 MiB),
    which the cut evaluation of a network that reads its neighbours is compared with."""
    return Probed(pred, oracle_range=oracle_range, keep=True)


def cut_probe(pred, oracle_range, earlier: dict) -> "Probed | None":
    """The probe of variant ``cut``: only for a network whose depth reads its neighbours at inference
    (``uses_neighbours``: MCDP's refinement, the cross-view attention of `mcdp.methods.surround`,
    ORACLE-local's input), compared with the as-trained probe."""
    return Probed(pred, CUT, reference=earlier.get(TRAINED)) if pred.network.uses_neighbours else None


def run_probes(pred, oracle_range: tuple[float, float], evaluate, log=lambda line: None) -> dict[str, dict]:
    """The probe loop: every variant with a probe of its own (`study.variants.VARIANTS` order) that applies to
    the run, each a pass ``evaluate(probe.predict)`` -> its metrics with ``refinement``; {variant: metrics}
    (`study.variants.entries_of` makes the run's {variant: entry} of them)."""
    probes: dict = {}
    out: dict[str, dict] = {}
    for v in VARIANTS.values():
        if v.probe is None:
            continue
        probe = v.resolved("probe")(pred, oracle_range, dict(probes))
        if probe is None:
            continue
        # the ORACLE variants ride on the as-trained pass as its extra stages (a `Probed`'s)
        extra = [s for s in probe.stages if s in VARIANTS and s != v.name] if isinstance(probe, Probed) else []
        log(f"{v.name}: {v.doc}" + (f" (+ {', '.join(extra)})" if extra else ""))
        probes[v.name] = probe
        out[v.name] = evaluate(probe.predict)
        out[v.name]["refinement"] = probe.refinement
    return out


def cut_inputs(inp):
    """`mcdp.predict.Inputs` with the neighbours cut: neighbour table all -1, every input field that carries
    other cameras' content (an ORACLE-local input) emptied (`mcdp.inputs.DepthInput.cut`)."""
    return inp.cut()


class Probed:
    """A `mcdp.predict.Predictor` evaluated as one variant of the overlap experiment (module docstring).

    Args:
        pred: the run's predictor (shared by the variants: one network in memory).
        variant: ``trained`` | ``cut``.
        oracle_range: (min, max) depth in metres of the ground truth the ORACLE weights are fitted to; None:
            no ORACLE stages (nor for a network without bases).
        keep: keep the last stage's depth of each image (at most ``KEEP_BYTES``) for a cut probe's comparison.
        reference: the as-trained probe whose kept depths ``cut_change_m`` is measured against.
    """

    #: at most this many bytes of depth maps kept for a cut probe's comparison (``keep=True``)
    KEEP_BYTES = 64 << 20

    def __init__(self, pred, variant: str = TRAINED, oracle_range: tuple[float, float] | None = None,
                 keep: bool = False, reference: "Probed | None" = None):
        if variant not in PROBED:
            raise ValueError(f"variant {variant!r} is not one of {', '.join(PROBED)}")
        self.pred = pred
        self.variant = variant
        self.oracle_weights = oracle_range is not None and pred.n_out > 1
        self.oracle_spread = oracle_range is not None and variant == TRAINED and not pred.network.uses_neighbours
        self.oracle_range = None if oracle_range is None else (float(oracle_range[0]), float(oracle_range[1]))
        self.kept: dict | None = {} if keep else None  # (seq, frame) -> last stage's depth at training size
        self._kept_bytes = 0
        self.reference = reference
        self._acc = {"images": 0, "weight_move": 0.0, "depth_change_m": 0.0, "oracle_weight_move": 0.0,
                     "cut_images": 0, "cut_change_m": 0.0}

    @property
    def stages(self) -> list[str]:
        """The stages `predict` answers: the network's, then "final", "oracle", "oracle_overlap" if ORACLE
        weights, "oracle_spread" if the hand-built propagator."""
        return (self.pred.stages + (["final"] if self.oracle_weights or self.oracle_spread else [])
                + (["oracle", "oracle_overlap"] if self.oracle_weights else [])
                + (["oracle_spread"] if self.oracle_spread else []))

    @property
    def refinement(self) -> dict:
        """How much the refinement acted on the images predicted so far (module docstring)."""
        a, refined = self._acc, len(self.pred.stages) > 1
        k = max(a["images"], 1)
        out = {"images": a["images"], "cut": self.variant == CUT,
               "weight_move": a["weight_move"] / k if refined else float("nan"),
               "depth_change_m": a["depth_change_m"] / k if refined else float("nan")}
        if self.oracle_weights:
            out["oracle_weight_move"] = a["oracle_weight_move"] / k
        if self.reference is not None:
            out["cut_change_m"] = a["cut_change_m"] / a["cut_images"] if a["cut_images"] else float("nan")
        return out

    @torch.no_grad()
    def predict(self, seq: str, frame: int) -> dict[str, np.ndarray]:
        """{stage: (N, H, W) float32 metres at the dataset resolution} of this variant, stages in order."""
        inp = self.pred.inputs(seq, frame)
        out = self.pred.forward(cut_inputs(inp) if self.variant == CUT else inp)
        small = self.pred.stages_of(out)
        self._record(out)
        self._compare(seq, frame, small[self.pred.stages[-1]])
        if self.oracle_weights or self.oracle_spread:  # "final" named explicitly: the yardsticks stay apart from it
            small["final"] = small[self.pred.stages[-1]]
        if self.oracle_weights:
            d_all, d_ov = self._oracle_depth(seq, frame, out)
            small["oracle"] = d_all * out["scale"].view(-1, 1, 1, 1)
            small["oracle_overlap"] = d_ov * out["scale"].view(-1, 1, 1, 1)
        if self.oracle_spread:
            small["oracle_spread"] = self._spread_depth(seq, frame, small[self.pred.stages[-1]])
        return self.pred.upsample(small)

    __call__ = predict

    def _masked_mean_abs(self, a: torch.Tensor, b: torch.Tensor) -> float:
        """Sum over images of the mean |a - b| on each image's scene pixels (training size)."""
        m = self.pred.mask.reshape(-1, 1, *self.pred.mask.shape[-2:]).float()
        diff = (a.float() - b.to(a.device).float()).abs() * m
        return float((diff.flatten(1).sum(1) / m.flatten(1).sum(1).clamp(min=1)).sum())

    def _record(self, out: dict) -> None:
        stages = self.pred.stages
        last = stages[-1]
        w = out.get(("weights", last))  # None for a method without basis weights
        self._acc["images"] += int(out["depth", last, 0].shape[0])
        if w is None or last == "init" or "init" not in stages:
            return
        n = w.shape[1]  # (B*N, n) or per pixel (B*N, n, h, w) (`mcdp.methods.local`): the mean over all of them
        self._acc["weight_move"] += float((w.float() - 1.0 / n).abs().flatten(1).mean(1).sum())
        self._acc["depth_change_m"] += self._masked_mean_abs(out["depth", last, 0], out["depth", "init", 0])

    def _compare(self, seq: str, frame: int, depth: torch.Tensor) -> None:
        """Keep this depth (``keep``) and/or add its mean |difference| to the reference's (``reference``)."""
        if self.kept is not None and self._kept_bytes + depth.numel() * 4 <= self.KEEP_BYTES:
            self.kept[seq, frame] = depth.float().cpu()
            self._kept_bytes += depth.numel() * 4
        ref = None if self.reference is None or self.reference.kept is None else self.reference.kept.get((seq, frame))
        if ref is not None:
            self._acc["cut_change_m"] += self._masked_mean_abs(depth, ref)
            self._acc["cut_images"] += int(depth.shape[0])

    def _spread_depth(self, seq: str, frame: int, depth: torch.Tensor) -> torch.Tensor:
        """The hand-built propagator: `depth` (N, 1, h, w) corrected from the overlap's ground truth (within the
        ORACLE depth range, scene pixels) by `mcdp.oracle.spread_from_overlap`."""
        from mcdp.oracle import spread_from_overlap
        from mcdp.truth import ground_truth_at, overlap_at

        pred = self.pred
        size = tuple(depth.shape[-2:])
        gt, valid = ground_truth_at(pred.ds, pred.reader.mask_full, seq, frame, size, self.oracle_range)
        ov = overlap_at(pred.ds, pred.reader.mask_full, seq, frame, size)
        known = torch.where(valid & ov, gt, torch.zeros_like(gt)).to(depth.device)
        return spread_from_overlap(depth.float(), known)

    def _oracle_depth(self, seq: str, frame: int, out: dict) -> tuple[torch.Tensor, torch.Tensor]:
        """(depth at the weights fitted on every valid pixel, at those fitted on the overlap pixels only)."""
        from mcdp.methods.base import combine_bases
        from mcdp.oracle import fit_oracle_weights
        from mcdp.truth import ground_truth_at, overlap_at

        pred = self.pred
        bases = out["bases"][0]  # (N, n, h, w)
        size = tuple(bases.shape[-2:])
        gt, valid = ground_truth_at(pred.ds, pred.reader.mask_full, seq, frame, size, self.oracle_range)
        gt, valid = gt.to(pred.device), valid.to(pred.device)
        wts = fit_oracle_weights(bases, gt, valid, pred.network.to_depth)
        n = wts.shape[1]
        self._acc["oracle_weight_move"] += float((wts - 1.0 / n).abs().mean(1).sum())
        ov = overlap_at(pred.ds, pred.reader.mask_full, seq, frame, size).to(pred.device)
        w_ov = fit_oracle_weights(bases, gt, valid & ov, pred.network.to_depth)  # no overlap pixel: 1/n
        return (pred.network.to_depth(combine_bases(bases.float(), wts))[1],
                pred.network.to_depth(combine_bases(bases.float(), w_ov))[1])
