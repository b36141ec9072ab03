"""How a sweep evaluated one run: the variant, beside the method, of every row of its results.

A sweep evaluates each (overlap, method, seed) run's checkpoint

- ``trained``: as trained;
- ``cut``: with its neighbours cut at inference (`study.probes`; only a network that reads them);
- ``oracle``: its own bases at per-image weights fitted to the ground truth on every valid pixel
  (`mcdp.oracle`; only a network with bases): a yardstick, it reads ground truth;
- ``oracle_overlap``: the same weights fitted on the overlap pixels only;
- ``oracle_spread``: the hand-built propagator (only a network that reads no other camera): its prediction
  corrected from the overlap's ground truth alone, the overlap's median log ratio everywhere and its local
  errors nearby (`mcdp.oracle.spread_from_overlap`): a yardstick, it reads ground truth.

A row of the results (`study.results`: results.json's ``flat`` and ``aggregate``, results.csv) is one
`Evaluation`: the method's registry name (`mcdp.methods`) in ``method`` and one of `VARIANTS` in
``variant``. This module is the one list of them.
"""
from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass

TRAINED, CUT, ORACLE, ORACLE_OVL, SPREAD = "trained", "cut", "oracle", "oracle_overlap", "oracle_spread"
#: every variant, in the order a method's evaluations are listed (results.json's ``evaluations``)
VARIANTS = (TRAINED, CUT, ORACLE, ORACLE_OVL, SPREAD)


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
