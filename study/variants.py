"""How a sweep evaluates one run: the variants, the one table of them, beside the method of every row of its results.

A sweep evaluates each (overlap, method, seed) run's checkpoint

- ``trained``: as trained;
- ``cut``: with its neighbours cut at inference (`study.probes`; only a network that reads them);
- ``oracle``: its own bases at per-image weights fitted to the ground truth on every valid pixel
  (`mcdp.oracle`; only a network with bases): a yardstick, it reads ground truth;
- ``oracle_overlap``: the same weights fitted on the overlap pixels only;
- ``oracle_spread``: the hand-built propagator (only a network that reads no other camera): its prediction
  corrected from the overlap's ground truth alone, the overlap's median log ratio everywhere and its local
  errors nearby (`mcdp.oracle.spread_from_overlap`): a yardstick, it reads ground truth.

A variant is one `Variant` in `VARIANTS` (table order = the order a method's evaluations are listed in). It is
made by its probe: either a pass of its own over the test split (``probe``: "module:function" or a callable
``probe(pred, oracle_range, earlier) -> object with predict(seq, frame) and refinement``, or None where the
run's network is not evaluated so; ``earlier``: {variant: probe} of the passes made before it, e.g. the
as-trained one a cut is compared with), or a depth the as-trained pass predicts beside its own
(``probe=None``: the stage named after the variant, `study.probes.Probed`). From that loop
(`study.probes.run_probes`) to the results a run's evaluations travel as ``{variant: entry}``
(`entries_of`): ``{"metrics": summary, "refinement": ..., "init": summary}``, the last two only where
there are; a sweep's row holds them as ``row["evaluations"]``, and `study.results.flat_rows` makes one
flat row per entry (``columns``: what a variant adds to the as-trained row and its own).

To add a variant: one entry here (or `register` from your own code; `unregister` removes it, e.g. in a
test's teardown: tests/study/test_toy_variant.py) plus its probe.

A row of the results (`study.results`: results.json's ``flat`` and ``aggregate``, results.csv) is one
`Evaluation`: the method's registry name (`mcdp.methods`) in ``method`` and one of `VARIANTS` in
``variant``.
"""
from __future__ import annotations

import importlib
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Callable

TRAINED, CUT, ORACLE, ORACLE_OVL, SPREAD = "trained", "cut", "oracle", "oracle_overlap", "oracle_spread"


@dataclass(frozen=True)
class Variant:
    """One way a sweep evaluates a run (module docstring)."""

    name: str
    #: one line: what it is (the sweep's log)
    doc: str
    #: its own pass's probe ("module:function" or a callable), or None: a stage of the as-trained pass
    probe: str | Callable | None = None
    #: its entry also keeps the network's init stage (``entry["init"]``: the refinement's gain and headroom)
    init: bool = False
    #: what it adds to the flat rows: ``columns(base, own, entry)`` (base: the as-trained row, own: its own), or
    #: None
    columns: str | Callable | None = None

    def resolved(self, what: str):
        """``probe`` or ``columns``, imported if given as "module:function"."""
        obj = getattr(self, what)
        if isinstance(obj, str):
            module, name = obj.split(":")
            return getattr(importlib.import_module(module), name)
        return obj


#: every variant by name, in the order a method's evaluations are listed (results.json's ``evaluations``)
VARIANTS: dict[str, Variant] = {}


def register(variant: Variant) -> Variant:
    """Add (or replace) a variant; its evaluations are listed after those registered before it."""
    VARIANTS[variant.name] = variant
    return variant


def unregister(name: str) -> Variant:
    """Remove a registered variant (e.g. a test's own, in its fixture's teardown); KeyError if none is so named."""
    return VARIANTS.pop(name)


for _v in (
    Variant(TRAINED, "as trained", "study.probes:trained_probe", init=True, columns="study.columns:trained_columns"),
    Variant(CUT, "again with the neighbours cut at inference", "study.probes:cut_probe",
            columns="study.columns:cut_columns"),
    Variant(ORACLE, "its bases at weights fitted to the ground truth", columns="study.columns:oracle_columns"),
    Variant(ORACLE_OVL, "its bases at weights fitted to the overlap's ground truth"),
    Variant(SPREAD, "corrected from the overlap's ground truth by the hand-built propagator"),
):
    register(_v)


def entries_of(passes: Mapping[str, dict]) -> dict[str, dict]:
    """{variant: entry} of a run from its passes' metrics ({variant with a probe: `mcdp.evaluate` metrics with
    ``refinement``}): each pass's last stage, and each stage of a pass named after a variant, `VARIANTS` order."""
    from study.records import summarize_metrics

    out: dict[str, dict] = {}
    for v in VARIANTS.values():
        m = passes.get(v.name)
        if m is not None:
            out[v.name] = {"metrics": summarize_metrics(m), "refinement": m.get("refinement")}
            if v.init and "init" in m["stages"] and len(m["stages"]) > 2:
                out[v.name]["init"] = summarize_metrics(m, "init")
            continue
        for p in passes.values():
            if v.probe is None and v.name in p["stages"]:
                out[v.name] = {"metrics": summarize_metrics(p, v.name)}
                break
    return out


@dataclass(frozen=True)
class Evaluation:
    """One evaluation of a method: ``Evaluation("mcdp_m2", CUT)``; the variant defaults to as trained."""

    method: str
    variant: str = TRAINED

    def __post_init__(self):
        if self.variant not in VARIANTS:
            raise ValueError(f"variant {self.variant!r} is not one of {', '.join(VARIANTS)}")
        if "@" in self.method:  # a name of results written before the variant field: study.results.read_results
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


