"""How a sweep evaluates one run: the variants, the one table of them, beside the method of every row of its results.

A sweep evaluates each (overlap, method, seed) run's checkpoint

- ``trained``: as trained;
- ``cut``: with its neighbours cut at inference (`study.sweep.probes`; only a network that reads them);
- ``oracle``: its own bases at per-image weights fitted to the ground truth on every valid pixel
  (`study.sweep.oracle_stages`; only a network with bases): a yardstick, it reads ground truth;
- ``oracle_overlap``: the same weights fitted on the overlap pixels only;
- ``oracle_spread``: the hand-built propagator (only a network that reads no other camera): its prediction
  corrected from the overlap's ground truth alone, the overlap's median log ratio everywhere and its local
  errors nearby (`mcdp.oracle.spread_from_overlap`): a yardstick, it reads ground truth.

A variant is one `Variant` in `VARIANTS` (table order = the order a method's evaluations are listed in), and its
row names everything of it, imported, never by a string:

- what makes it: either a pass of its own over the test split (``probe(pred, oracle_range, earlier, stages)`` ->
  an object with ``predict(seq, frame)`` and ``refinement``, or None where the run's network is not evaluated so;
  ``earlier``: {variant: probe} of the passes made before it, e.g. the as-trained one a cut is compared with;
  ``stages``: the variants that ride on it), or a stage of another variant's pass (``on``, as trained by default):
  ``adds_stage(pred, oracle_range)`` says whether it applies to the run, and ``predict_stage(probe, seq, frame,
  out, depth)`` gives its depth (N, 1, h, w) at training size from the network's output ``out`` and the last
  stage's ``depth`` (the probe: `study.sweep.probes.Probed`, whose ``accumulate`` adds to the refinement record);
- what it adds to the flat rows (``columns(base, own, entry)``: base is the as-trained row, own its own);
- what a report reads it as (``capabilities``, `having`): "cut" (the network without the other cameras: as
  trained minus it is what reading them gives; one variant at most), "ceiling" (a yardstick: the best the bases
  can express, on every pixel), "overlap_ceiling" (the same from the overlap's ground truth alone: the global
  yardstick), "spread" (a propagator from the overlap's ground truth, of a network that reads no other camera).
  A report section chooses its variants by capability (`having`, `cut`), never by name, and names them by their
  ``label`` (``short`` in a table column), so a new variant with a capability appears in every section that
  reads it.

From the probe loop (`study.sweep.probes.run_probes`) to the results a run's evaluations travel as ``{variant: entry}``
(`entries_of`): ``{"metrics": summary, "refinement": ..., "init": summary}``, the last two only where there
are; a sweep's row holds them as ``row["evaluations"]``, and `study.results.summary.flat_rows` makes one flat row per
entry.

To add a variant: one row here (or `register` from your own code; `unregister` removes it, e.g. in a test's
teardown: tests/study/test_toy_variant.py) plus its probe or stage, and its columns if any.

Example::

    >>> from study.sweep.variants import Variant, Evaluation, having, register, unregister
    >>> def twice(probe, seq, frame, out, depth):   # a stage of the as-trained pass: its depth, doubled
    ...     return 2.0 * depth
    >>> v = register(Variant("doubled", "as trained at twice the depth", adds_stage=lambda pred, rng: True,
    ...                      predict_stage=twice, capabilities=("spread",), label="doubling", short="doubled"))
    >>> [x.name for x in having("spread")]
    ['oracle_spread', 'doubled']
    >>> str(Evaluation("mono2", "doubled"))
    'mono2 (doubled)'
    >>> unregister("doubled") is v
    True

A row of the results (`study.results.summary`: results.json's ``flat`` and ``aggregate``, results.csv) is one
`Evaluation`: the method's registry name (`mcdp.methods`) in ``method`` and one of `VARIANTS` in
``variant``.
"""
from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import Callable

from study.sweep.oracle_stages import (ORACLE, ORACLE_OVL, SPREAD, has_bases, oracle_columns, oracle_depth,
                                 oracle_overlap_depth, reads_no_other_camera, spread_depth)
from study.sweep.probes import CUT, TRAINED, cut_columns, cut_probe, trained_columns, trained_probe
from study.sweep.records import summarize_metrics

#: what a report may read a variant as (`Variant.capabilities`); those in `SINGLE` one variant at most has
CAPABILITIES = ("cut", "ceiling", "overlap_ceiling", "spread")
SINGLE = ("cut",)


@dataclass(frozen=True)
class Variant:
    """One way a sweep evaluates a run (module docstring)."""

    name: str
    #: one line: what it is (the sweep's log)
    doc: str
    #: its own pass's probe ``probe(pred, oracle_range, earlier, stages)``, or None: a stage of variant ``on``'s pass
    probe: Callable | None = None
    #: a stage: whether it applies to a run, ``adds_stage(pred, oracle_range) -> bool``
    adds_stage: Callable | None = None
    #: a stage: its depth, ``predict_stage(probe, seq, frame, out, depth) -> (N, 1, h, w)`` at training size
    predict_stage: Callable | None = None
    #: a stage: the variant whose pass predicts it
    on: str = TRAINED
    #: its entry also keeps the network's init stage (``entry["init"]``: the refinement's gain and headroom)
    init: bool = False
    #: what it adds to the flat rows: ``columns(base, own, entry)``, or None
    columns: Callable | None = None
    #: what a report reads it as (`CAPABILITIES`)
    capabilities: tuple[str, ...] = ()
    #: its name in a report's prose (default: ``name``) and in a table's column (default: ``label``)
    label: str = ""
    short: str = ""

    def __post_init__(self) -> None:
        stage = self.adds_stage is not None and self.predict_stage is not None
        if (self.probe is None) != stage or (not stage and (self.adds_stage or self.predict_stage)):
            raise ValueError(f"variant {self.name!r}: either a probe of its own or a stage (adds_stage and "
                             "predict_stage), not both")
        unknown = [c for c in self.capabilities if c not in CAPABILITIES]
        if unknown:
            raise ValueError(f"variant {self.name!r}: capability {unknown[0]!r} is not one of {', '.join(CAPABILITIES)}")
        object.__setattr__(self, "label", self.label or self.name)
        object.__setattr__(self, "short", self.short or self.label)


#: every variant by name, in the order a method's evaluations are listed (results.json's ``evaluations``)
VARIANTS: dict[str, Variant] = {}


def register(variant: Variant) -> Variant:
    """Add (or replace) a variant; its evaluations are listed after those registered before it. A second variant
    with a capability of `SINGLE` is refused."""
    for c in SINGLE:
        other = next((v.name for v in having(c) if v.name != variant.name), None)
        if c in variant.capabilities and other is not None:
            raise ValueError(f"variant {variant.name!r}: capability {c!r} is {other!r}'s already (one variant at most)")
    VARIANTS[variant.name] = variant
    return variant


def unregister(name: str) -> Variant:
    """Remove a registered variant (e.g. a test's own, in its fixture's teardown); KeyError if none is so named."""
    return VARIANTS.pop(name)


def having(capability: str) -> list[Variant]:
    """The variants a report reads as ``capability`` (`CAPABILITIES`), in table order."""
    if capability not in CAPABILITIES:
        raise ValueError(f"capability {capability!r} is not one of {', '.join(CAPABILITIES)}")
    return [v for v in VARIANTS.values() if capability in v.capabilities]


def cut() -> str | None:
    """The name of the variant with capability "cut" (the network without the other cameras), or None."""
    return next((v.name for v in having("cut")), None)


def stages_on(variant: str, pred, oracle_range) -> list[Variant]:
    """The variants whose stage rides on ``variant``'s pass and applies to this run (`study.sweep.probes.Probed`'s
    ``stages``)."""
    return [v for v in VARIANTS.values() if v.on == variant and v.adds_stage is not None
            and v.adds_stage(pred, oracle_range)]


for _v in (
    Variant(TRAINED, "as trained", trained_probe, init=True, columns=trained_columns),
    Variant(CUT, "again with the neighbours cut at inference", cut_probe, columns=cut_columns,
            capabilities=("cut",)),
    Variant(ORACLE, "its bases at weights fitted to the ground truth", adds_stage=has_bases,
            predict_stage=oracle_depth, columns=oracle_columns, capabilities=("ceiling",), label="ORACLE weights",
            short="ORACLE"),
    Variant(ORACLE_OVL, "its bases at weights fitted to the overlap's ground truth", adds_stage=has_bases,
            predict_stage=oracle_overlap_depth, capabilities=("overlap_ceiling",), label="ORACLE-overlap weights"),
    Variant(SPREAD, "corrected from the overlap's ground truth by the hand-built propagator",
            adds_stage=reads_no_other_camera, predict_stage=spread_depth, capabilities=("spread",),
            label="hand-built propagator", short="corrected"),
):
    register(_v)


def entries_of(passes: Mapping[str, dict]) -> dict[str, dict]:
    """{variant: entry} of a run from its passes' metrics ({variant with a probe: `mcdp.evaluate` metrics with
    ``refinement``}): each pass's last stage, and each stage variant's stage of the pass it rides on, `VARIANTS`
    order."""
    out: dict[str, dict] = {}
    for v in VARIANTS.values():
        m = passes.get(v.name if v.probe is not None else v.on)
        if m is None:
            continue
        if v.probe is not None:
            out[v.name] = {"metrics": summarize_metrics(m), "refinement": m.get("refinement")}
            if v.init and "init" in m["stages"] and len(m["stages"]) > 2:
                out[v.name]["init"] = summarize_metrics(m, "init")
        elif v.name in m["stages"]:
            out[v.name] = {"metrics": summarize_metrics(m, v.name)}
    return out


@dataclass(frozen=True)
class Evaluation:
    """One evaluation of a method: ``Evaluation("mcdp_m2", CUT)``; the variant defaults to as trained."""

    method: str
    variant: str = TRAINED

    def __post_init__(self):
        if self.variant not in VARIANTS:
            raise ValueError(f"variant {self.variant!r} is not one of {', '.join(VARIANTS)}")
        if "@" in self.method:  # a name of results written before the variant field: study.results.files.read_results
            raise ValueError(f"method {self.method!r}: the variant is a field (Evaluation(method, variant)), "
                             "not a suffix of the method's name")

    @classmethod
    def of(cls, x: "str | Evaluation | Mapping") -> "Evaluation":
        """``x`` as an Evaluation: a method name is that method as trained; a mapping (a row of the results,
        an entry of their ``evaluations``) is its ``method`` and ``variant`` fields."""
        if isinstance(x, Evaluation):
            return x
        if isinstance(x, str):
            return cls(x)
        return cls(x["method"], x["variant"])

    def matches(self, row: Mapping) -> bool:
        """Whether a row of the results (``method`` and ``variant`` fields) is this evaluation."""
        return row["method"] == self.method and row["variant"] == self.variant

    def record(self) -> dict:
        """The JSON form: ``{"method": ..., "variant": ...}``."""
        return {"method": self.method, "variant": self.variant}

    def __str__(self) -> str:
        return self.method if self.variant == TRAINED else f"{self.method} ({self.variant})"


