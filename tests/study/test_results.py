"""The statistics of the sweep's results (study.results): Student-t intervals and paired differences."""
from __future__ import annotations

import math

import pytest

from study.results import paired_difference, t_halfwidth


def test_t_halfwidth_matches_the_t_table():
    # n = 3: t(0.975, 2) = 4.303; sd 1 -> 4.303 / sqrt(3)
    assert t_halfwidth(1.0, 3) == pytest.approx(4.303 / math.sqrt(3))
    assert t_halfwidth(2.0, 10) == pytest.approx(2.262 * 2 / math.sqrt(10))
    assert math.isnan(t_halfwidth(1.0, 1))


def _results(a, b):
    flat = [{"overlap": 0.3, "method": "mcdp_m2", "seed": s, "x": v} for s, v in enumerate(a)]
    flat += [{"overlap": 0.3, "method": "mono2", "seed": s, "x": v} for s, v in enumerate(b)]
    return {"flat": flat}


def test_paired_difference_pairs_by_seed_and_says_which_side():
    # the seeds move both methods together: paired, the difference is clear though each spread is wide
    r = _results([1.10, 2.12, 3.09], [1.00, 2.00, 3.00])
    d = paired_difference(r, 0.3, "mcdp_m2", "mono2", "x")
    assert d["n"] == 3 and d["mean"] == pytest.approx(0.1033, abs=1e-3) and d["differs"] == 1
    same = paired_difference(_results([1.0, 2.1, 2.9], [1.05, 2.0, 3.0]), 0.3, "mcdp_m2", "mono2", "x")
    assert same["differs"] == 0
    nan = paired_difference(_results([float("nan"), 1.0], [1.0, 1.0]), 0.3, "mcdp_m2", "mono2", "x")
    assert nan["n"] == 1 and nan["differs"] == 0
