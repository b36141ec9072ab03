"""The propagation report's primary section (study/report/sections/primary.py) on synthetic results: the copy test, the
clustered intervals, the verdicts and the headline, including when the control fails."""
from __future__ import annotations

import random

from study.report.sections.primary import control_passes, copy_test, format_primary, headline, paired_nested, world_of
from study.sweep.variants import CUT, SPREAD, TRAINED, Evaluation

SCALINGS = ("none", "median", "rig_median")
BANDS = ("overlap", "0-0.10", ">0.35")


def _row(o, method, variant, seed, overlap_err, non_err):
    f = {"overlap": o, "method": method, "variant": variant, "seed": seed}
    for sc in SCALINGS:
        f[f"{sc}.overlap.abs_rel"] = overlap_err
        f[f"{sc}.non_overlap.abs_rel"] = non_err
        f[f"{sc}.mean.abs_rel"] = 0.5 * (overlap_err + non_err)
        for b in BANDS:
            f[f"{sc}.band.{b}.abs_rel"] = overlap_err if b == "overlap" else non_err
    return f


def _results(copy_err=0.05, mech_gain=0.0, control_gain=0.03, noise=0.001, seed=0, worlds=3, per=2):
    """Mono2 at 0.25; ORACLE-local filled `copy_err` on the overlap and `control_gain` better elsewhere than
    emptied; MCDP (m = 2) and MCDP-local whose cut is `mech_gain` worse than as trained; L_con: none."""
    rnd = random.Random(seed)
    seeds = list(range(worlds * per))
    flat = []
    for o in (0.10, 0.60):
        for s in seeds:
            w_eff = 0.01 * (s // per)  # a world effect every method shares
            e = lambda: rnd.gauss(0.0, noise)  # noqa: E731
            base = 0.25 + w_eff
            flat.append(_row(o, "mono2", TRAINED, s, base, base))
            flat.append(_row(o, "mono2", SPREAD, s, 0.0, base - 0.02 + e()))
            flat.append(_row(o, "oracle_local", TRAINED, s, copy_err, base - control_gain + e()))
            flat.append(_row(o, "oracle_local", CUT, s, base, base + e()))
            for m in ("mcdp_m2", "mcdp_local", "mcdp_m2_nocon"):
                v = base + e()
                flat.append(_row(o, m, TRAINED, s, v, v))
                flat.append(_row(o, m, CUT, s, v, v + (mech_gain if m != "mcdp_m2_nocon" else 0.0) + e()))
    data = [{"overlap": o, "measured": {"measured_mean": o}} for o in (0.10, 0.60)]
    return {"flat": flat, "data": data, "seeds": seeds,
            "sweep_config": {"worlds": "per_seed", "seeds_per_world": per}}


def test_worlds_group_the_seeds_as_the_sweep_trained_them():
    assert world_of(_results()) == {0: 0, 1: 0, 2: 1, 3: 1, 4: 2, 5: 2}
    r = _results(per=1)
    assert world_of(r) == {s: s for s in r["seeds"]}


def test_the_copy_test_passes_or_fails_on_the_overlap_pixels_against_half_of_mono2():
    ok = copy_test(_results(copy_err=0.05))
    assert [r["passes"] for r in ok] == [True, True] and control_passes(_results(copy_err=0.05)) is True
    assert control_passes(_results(copy_err=0.2)) is False  # 0.2 > 0.5 x 0.26
    f, b, q = ok[0]["median"]
    assert abs(f - 0.05) < 1e-12 and abs(q - 0.05 / b) < 1e-12


def test_a_clustered_interval_uses_the_world_means():
    r = _results(mech_gain=0.002, noise=0.0005)
    n = paired_nested(r, 0.10, (Evaluation("mcdp_m2", CUT), "median.non_overlap.abs_rel"),
                      (Evaluation("mcdp_m2"), "median.non_overlap.abs_rel"))
    assert n["n_worlds"] == 3 and n["df"] == 2 and n["n"] == 6
    assert abs(n["mean"] - 0.002) < 0.002


def test_a_null_is_equivalent_only_with_the_power_to_say_so_and_a_passing_control():
    tight = _results(mech_gain=0.0, noise=1e-5)
    assert headline(tight) == "nothing propagates (< 0.005)"  # the plan's delta (the default: none recorded)
    assert "equivalent at 95 %" in format_primary(tight)
    loose = _results(mech_gain=0.0, noise=0.02, seed=3)
    h = headline(loose)  # too noisy to bound: not "nothing propagates", and it names what it could detect
    assert h.startswith("nothing is seen to propagate: not resolved: ") and "detectable at 80 %" in h
    failed = _results(copy_err=0.2, mech_gain=0.0, noise=1e-5)
    assert headline(failed).startswith("inconclusive: the positive control fails")
    text = format_primary(failed)
    assert "FAILS its copy test" in text and "inconclusive (the positive control fails its copy test)" in text


def test_a_mechanism_that_helps_beyond_its_interval_is_said_to_propagate():
    r = _results(mech_gain=0.02, noise=1e-4)
    h = headline(r)
    assert h.startswith("propagates: ") and "MCDP (m = 2)" in h and "MCDP-local" in h


def test_the_section_reports_every_scaling_the_mde_and_the_bands():
    text = format_primary(_results(noise=0.001))
    assert "| (a) |" in text and "| (b) |" in text and "| (c) |" in text
    assert "MDE 80 %" in text and "none" in text and "rig_median" in text
    assert "| 0-0.10 |" in text and "| >0.35 |" in text
    r = _results()
    assert format_primary({**r, "flat": [f for f in r["flat"] if f["method"] != "oracle_local"]}) == ""
