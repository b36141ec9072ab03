"""The report's comparison of the overlap mechanisms (study/mechanisms.py): the 'from which overlap on'
verdict and the table, on hand-made results whose answer is known."""
from __future__ import annotations

from study.mechanisms import format_mechanisms, from_which_overlap
from study.variants import CUT, TRAINED

D = {-1: {"differs": -1}, 0: {"differs": 0}, 1: {"differs": 1}}


def test_from_which_overlap_needs_every_larger_overlap_better():
    assert from_which_overlap({0.1: D[-1], 0.3: D[-1], 0.6: D[-1]}) == \
        "gains from overlap 0.10 on (every overlap of the sweep)"
    assert from_which_overlap({0.1: D[0], 0.3: D[-1], 0.6: D[-1]}) == "gains from overlap 0.30 on"
    assert from_which_overlap({0.1: D[-1], 0.3: D[0], 0.6: D[1]}) == \
        "better at 0.10 only, not from one overlap on; worse at 0.60"
    assert from_which_overlap({0.1: D[0], 0.3: D[1], 0.6: D[0]}) == "gains at no overlap of the sweep; worse at 0.30"


def _results():
    """mono2, fsm (better from 0.30 on, no cut), surround (never better; uses its neighbours at 0.60)."""
    xs, flat = (0.1, 0.3, 0.6), []
    for o in xs:
        for s, noise in enumerate((0.0, 0.01, -0.01)):
            base = 0.25 + noise
            gain = 0.02 if o >= 0.3 else 0.0
            cut_gain = 0.01 if o == 0.6 else 0.0
            vals = {("mono2", TRAINED): base, ("fsm", TRAINED): base - gain + 0.001 * s,
                    ("surround", TRAINED): base + 0.001 * s,
                    ("surround", CUT): base + 0.001 * s + cut_gain + 0.0001 * s}
            for (m, variant), v in vals.items():
                flat.append({"overlap": o, "method": m, "variant": variant, "seed": s, "median.mean.abs_rel": v,
                             "median.overlap.abs_rel": v, "median.non_overlap.abs_rel": v, "dep_con.mean": v / 5})
    return {"methods": ["mono2", "fsm", "surround"], "seeds": [0, 1, 2], "flat": flat,
            "evaluations": [{"method": m, "variant": v} for m, v in vals],
            "data": [{"overlap": o, "measured": {"measured_mean": o * 0.7}} for o in xs],
            "aggregate": [{"overlap": o, "method": "surround", "variant": TRAINED,
                           "metrics": {"cut.depth_change_m": {"mean": 0.05 * o, "ci95": 0.01, "n": 3}}} for o in xs]}


def test_the_section_states_each_mechanisms_verdict():
    md = format_mechanisms(_results(), lambda m: {"fsm": "FSM", "surround": "SurroundDepth"}.get(m, m))
    fsm = next(line for line in md.splitlines() if line.startswith("- **FSM**"))
    sur = next(line for line in md.splitlines() if line.startswith("- **SurroundDepth**"))
    assert "accuracy vs Mono2 gains from overlap 0.30 on" in fsm and "by construction" in fsm
    assert "accuracy vs Mono2 gains at no overlap of the sweep" in sur
    assert "its accuracy with them differs from without (as trained − cut beyond the interval and >= 0.0005) at 0.60" in sur
    assert "- **In one line**: FSM gain(s) accuracy over Mono2 from some overlap on" in md
    assert "| 0.60 | 0.420 | SurroundDepth |" in md and "0 (reads no other camera)" in md
    assert "its depth reads the other cameras: cutting them changes it by 0.0050 to 0.0300 m" in sur
    assert "| 0.0300 ± 0.0100 |" in md
    one_seed = {**_results(), "seeds": [0]}
    assert "One seed only: no interval, no verdict." in format_mechanisms(one_seed, str)
    assert format_mechanisms({**_results(), "methods": ["fsm", "surround"]}, str) == ""
