"""The overlap experiment's passes over a run's predictions: as trained and cut, what the refinement does, and
the columns they add to the flat rows. Inference (`mcdp.predict.Predictor`) only predicts; this module changes its
inputs and observes its outputs, so that the predictor knows nothing of the experiment.

- **variant** ``trained`` or ``cut``. ``cut`` cuts the neighbours at inference: every camera's neighbour
  table entry is -1, so each weight network sees zeros and valid = 0 for both neighbours, exactly as a
  camera without neighbours, and an ORACLE-local input is emptied. As trained minus cut is what the
  neighbours contribute.
- **refinement** (`Probed.refinement`): accumulated over every predicted image, how much the refinement
  acts: mean |w - 1/n| of the last stage's weights and the mean |refined - init| depth (metres, scene
  pixels, training size). Near zero means an inert refinement. A cut probe given the as-trained one as
  ``reference`` (which then keeps its depths: ``keep=True``) also records ``cut_change_m``, the mean
  |as trained - cut| depth of the same images: what cutting the neighbours changes, in metres.
- **stages** (``stages``: the `study.sweep.variants.Variant` rows whose stage rides on this pass, e.g. the ORACLE
  weights and the hand-built propagator of `study.sweep.oracle_stages`): after "final" (= the network's last stage),
  each variant's ``predict_stage(probe, seq, frame, out, depth)``; a stage may add to the refinement record
  (`Probed.accumulate`, e.g. ``oracle_weight_move``).

This module knows no table: `run_probes` is given the variants (`study.sweep.variants.VARIANTS`), which name
`trained_probe` / `cut_probe` and `trained_columns` / `cut_columns` as theirs.

The passes are evaluated together, sample by sample (`mcdp.evaluate.evaluate_passes`): each sample's ground truth is
read once, for every pass, and a probe's stages that read ground truth take it from the same `TruthCache`
(``Probed.truths``); what one stage computes of a sample and another reuses lives in ``Probed.sample_memo``.

Example::

    pred = Predictor(run_dir, ds)
    trained = Probed(pred, oracle_range=(0.5, 80.0), keep=True, stages=stages_on(TRAINED, pred, (0.5, 80.0)))
    cut = Probed(pred, CUT, reference=trained)
    passes = evaluate_passes(ds, {TRAINED: trained.predict, CUT: cut.predict}, "test", ecfg)
    passes[TRAINED]["refinement"] = trained.refinement
"""
from __future__ import annotations

import math
from collections.abc import Iterable, Sequence
from typing import TYPE_CHECKING

from study.sweep.records import number, flat_row

if TYPE_CHECKING:  # the report reads the variant table without torch: it is imported where a probe runs
    import numpy as np
    import torch

#: the names of the two passes a `Probed` makes (the variants `trained` and `cut` of `study.sweep.variants`)
TRAINED, CUT = "trained", "cut"
PROBED = (TRAINED, CUT)
#: a refinement whose refined depth differs from its init stage by < 1 cm on average is inert
INERT_M = 0.01


def trained_probe(pred, oracle_range, earlier: dict, stages: Sequence = ()) -> "Probed":
    """The probe of variant ``trained``: as trained, with the stages that ride on it; it keeps its depths
    (<= 64 MiB), which the cut evaluation of a network that reads its neighbours is compared with."""
    return Probed(pred, oracle_range=oracle_range, keep=True, stages=stages)


def cut_probe(pred, oracle_range, earlier: dict, stages: Sequence = ()) -> "Probed | None":
    """The probe of variant ``cut``: only for a network whose depth reads its neighbours at inference
    (``uses_neighbours``: MCDP's refinement, the cross-view attention of `mcdp.methods.surround`,
    ORACLE-local's input), compared with the as-trained probe."""
    if not pred.network.uses_neighbours:
        return None
    return Probed(pred, CUT, oracle_range=oracle_range, reference=earlier.get(TRAINED), stages=stages)


def trained_columns(base: dict, own: dict, entry: dict) -> None:
    """Variant ``trained``'s columns: how much the refinement acted, and its init stage's numbers and gain."""
    ref = entry.get("refinement") or {}
    base["refine.weight_move"] = number(ref.get("weight_move"))
    base["refine.depth_change_m"] = number(ref.get("depth_change_m"))
    base["refine.oracle_weight_move"] = number(ref.get("oracle_weight_move"))
    if math.isfinite(base["refine.depth_change_m"]):
        base["refine.inert"] = bool(base["refine.depth_change_m"] < INERT_M)
    if entry.get("init"):
        init = flat_row({"metrics": entry["init"]})
        for k in ("median.mean.abs_rel", "median.overlap.abs_rel", "median.non_overlap.abs_rel"):
            base[f"init.{k}"] = init.get(k, float("nan"))
        base["refine.gain"] = base["init.median.mean.abs_rel"] - base.get("median.mean.abs_rel", float("nan"))


def cut_columns(base: dict, own: dict, entry: dict) -> None:
    """Variant ``cut``'s columns: how much the refinement acted when cut, and (on the as-trained row) the mean
    |as trained - cut| depth, metres."""
    rc = entry.get("refinement") or {}
    own["refine.weight_move"] = number(rc.get("weight_move"))
    own["refine.depth_change_m"] = number(rc.get("depth_change_m"))
    base["cut.depth_change_m"] = number(rc.get("cut_change_m"))


def run_probes(variants: Iterable, pred, oracle_range: tuple[float, float], evaluate,
               log=lambda line: None, truths=None) -> dict[str, dict]:
    """The probe loop over ``variants`` (`study.sweep.variants.VARIANTS`' values, in order): every variant with a probe of
    its own that applies to the run is a pass, given the stages that ride on it (``stages_on``:
    `study.sweep.variants.stages_on`), and the passes are evaluated together, ``evaluate({variant: probe.predict})`` ->
    {variant: metrics} (`mcdp.evaluate.evaluate_passes`: sample by sample, the ground truth read once for all);
    each pass's metrics get its ``refinement``. ``truths``: the evaluation's `mcdp.evaluate.TruthCache`, handed to
    each `Probed` so that its ground-truth stages read the sample's truth from it (None: they read their own).
    Returns {variant: metrics} (`study.sweep.variants.entries_of` makes the run's {variant: entry} of them)."""
    variants = list(variants)
    probes: dict = {}
    for v in variants:
        if v.probe is None:
            continue
        stages = [s for s in variants  # the stages riding on this pass (a row with a probe of its own has none)
                  if s.on == v.name and s.adds_stage is not None and s.adds_stage(pred, oracle_range)]
        probe = v.probe(pred, oracle_range, dict(probes), stages)
        if probe is None:
            continue
        log(f"{v.name}: {v.doc}" + (f" (+ {', '.join(s.name for s in stages)})" if stages else ""))
        if isinstance(probe, Probed):
            probe.truths = truths
        probes[v.name] = probe
    out = evaluate({name: probe.predict for name, probe in probes.items()})
    for name, probe in probes.items():
        out[name]["refinement"] = probe.refinement
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
        oracle_range: (min, max) depth in metres of the ground truth its stages read (the ORACLE weights, the
            hand-built propagator); None: no ground truth.
        keep: keep the last stage's depth of each image (at most ``KEEP_BYTES``) for a cut probe's comparison.
        reference: the as-trained probe whose kept depths ``cut_change_m`` is measured against.
        stages: the variants whose stage this pass predicts after "final" (`study.sweep.variants.stages_on`: those that
            ride on it and apply to the run), each by its ``predict_stage``.
    """

    #: at most this many bytes of depth maps kept for a cut probe's comparison (``keep=True``)
    KEEP_BYTES = 64 << 20
    #: the evaluation's ground truth of the sample being predicted (`mcdp.evaluate.TruthCache`, set by `run_probes`),
    #: which a stage reading ground truth takes instead of reading it again (`study.sweep.oracle_stages`); None: its own
    truths = None

    def __init__(self, pred, variant: str = TRAINED, oracle_range: tuple[float, float] | None = None,
                 keep: bool = False, reference: "Probed | None" = None, stages: Sequence = ()):
        if variant not in PROBED:
            raise ValueError(f"variant {variant!r} is not one of {', '.join(PROBED)}")
        self.pred = pred
        self.variant = variant
        self.oracle_range = None if oracle_range is None else (float(oracle_range[0]), float(oracle_range[1]))
        self.extra = list(stages)
        self.kept: dict | None = {} if keep else None  # (seq, frame) -> last stage's depth at training size
        self._kept_bytes = 0
        self.reference = reference
        self._acc = {"images": 0, "weight_move": 0.0, "depth_change_m": 0.0, "cut_images": 0, "cut_change_m": 0.0}
        self._stage_acc: dict[str, float] = {}  # what the stages add to the record (`accumulate`)
        #: what one stage computes of the sample being predicted and another of its stages reuses (e.g. the ground
        #: truth at the training size), emptied at each new sample
        self.sample_memo: dict = {}

    @property
    def stages(self) -> list[str]:
        """The stages `predict` answers: the network's, then "final" and each extra stage, if any."""
        return self.pred.stages + (["final"] + [v.name for v in self.extra] if self.extra else [])

    def accumulate(self, key: str, value: float) -> None:
        """Add ``value`` (a sum over the images of one prediction) to the refinement record's ``key`` (reported as
        the mean over the images predicted): a stage's own measure, e.g. ``oracle_weight_move``."""
        self._stage_acc[key] = self._stage_acc.get(key, 0.0) + float(value)

    @property
    def refinement(self) -> dict:
        """How much the refinement acted on the images predicted so far (module docstring)."""
        a, refined = self._acc, len(self.pred.stages) > 1
        k = max(a["images"], 1)
        out = {"images": a["images"], "cut": self.variant == CUT,
               "weight_move": a["weight_move"] / k if refined else float("nan"),
               "depth_change_m": a["depth_change_m"] / k if refined else float("nan")}
        out.update({key: v / k for key, v in self._stage_acc.items()})
        if self.reference is not None:
            out["cut_change_m"] = a["cut_change_m"] / a["cut_images"] if a["cut_images"] else float("nan")
        return out

    def predict(self, seq: str, frame: int) -> "dict[str, np.ndarray]":
        """{stage: (N, H, W) float32 metres at the dataset resolution} of this variant, stages in order."""
        import torch

        self.sample_memo = {}
        with torch.no_grad():
            inp = self.pred.inputs(seq, frame)
            out = self.pred.forward(cut_inputs(inp) if self.variant == CUT else inp)
            small = self.pred.stages_of(out)
            self._record(out)
            last = small[self.pred.stages[-1]]
            self._compare(seq, frame, last)
            if self.extra:  # "final" named explicitly: the extra stages (yardsticks) stay apart from it
                small["final"] = last
            for v in self.extra:
                small[v.name] = v.predict_stage(self, seq, frame, out, last)
            return self.pred.upsample(small)

    __call__ = predict

    def _masked_mean_abs(self, a: "torch.Tensor", b: "torch.Tensor") -> float:
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

    def _compare(self, seq: str, frame: int, depth: "torch.Tensor") -> None:
        """Keep this depth (``keep``) and/or add its mean |difference| to the reference's (``reference``)."""
        if self.kept is not None and self._kept_bytes + depth.numel() * 4 <= self.KEEP_BYTES:
            self.kept[seq, frame] = depth.float().cpu()
            self._kept_bytes += depth.numel() * 4
        ref = None if self.reference is None or self.reference.kept is None else self.reference.kept.get((seq, frame))
        if ref is not None:
            self._acc["cut_change_m"] += self._masked_mean_abs(depth, ref)
            self._acc["cut_images"] += int(depth.shape[0])
