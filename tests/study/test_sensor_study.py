"""study/report/sections/sensor.py: each method's change from the ideal camera, paired by world (ideal - condition: positive = the
condition helps), and MCDP's change against FSM's (the paper's argument about photometric losses between cameras)."""
import numpy as np

from study.report.sections import sensor
from study.sweep.variants import TRAINED


def _results(shift: dict, seed: int = 0, worlds: int = 3) -> dict:
    """``worlds`` worlds x (Mono2, FSM, MCDP (m = 2)); ``shift``: added to a method's abs_rel and Dep Con."""
    rng = np.random.default_rng(seed)
    base = {"mono2": 0.20, "fsm": 0.19, "mcdp_m2": 0.195}
    flat = []
    for w in range(worlds):
        world = rng.normal(0, 0.01)  # a world's difficulty, shared by its conditions
        for m, v in base.items():
            d = shift.get(m, 0.0)
            flat.append({"overlap": 0.3, "method": m, "variant": TRAINED, "seed": w, "world": w, "status": "ok",
                         "median.mean.abs_rel": v + world + d + rng.normal(0, 0.0005),
                         "dep_con.mean": 0.05 + world / 4 + d / 2})
    return {"overlaps": [0.3], "methods": list(base), "flat": flat,
            "data": [{"overlap": 0.3, "worlds": [{"reference": {"metrics": {"median": {"mean": {"abs_rel": 0.6}}}}}]}]}


def test_each_change_is_paired_by_world_and_the_contrast_says_who_suffers():
    ideal, cond = _results({}), _results({"fsm": 0.02, "mcdp_m2": 0.002})
    ch = sensor.change(ideal, cond, "fsm", "median.mean.abs_rel")
    assert ch["n_worlds"] == 3 and abs(ch["mean"] + 0.02) < 0.002 and ch["differs"] == -1  # the world cancels
    assert abs(sensor.change(ideal, ideal, "mono2", "median.mean.abs_rel")["mean"]) < 1e-12
    c = sensor.contrast(ideal, cond, "median.mean.abs_rel")
    assert abs(c["mean"] - 0.018) < 0.002 and c["differs"] == 1  # MCDP's change - FSM's: MCDP suffers less
    text = sensor.format_sensor(ideal, [("Exposure", "a spread", cond)])
    assert "FSM suffers more than MCDP (m = 2), beyond the interval" in text
    assert "constant-depth reference scores 0.6000" in text and "**(worse)**" in text
    assert "ideal - condition, paired by world, **positive = the condition helps**" in text
    assert "| MCDP (m = 2)'s change - FSM's | +0.018" in text and "**(FSM suffers more)**" in text
    fsm = [line for line in text.splitlines() if line.startswith("| FSM |")][-1]  # the first: the ideal's level
    assert fsm.startswith("| FSM | -0.02") and "**(worse)**" in fsm, fsm
    same = sensor.format_sensor(ideal, [("Null", "nothing", _results({}, seed=0))])
    assert "not resolved with 3 worlds" in same


def test_a_failed_run_is_left_out_of_its_pair():
    ideal, cond = _results({}), _results({"fsm": 0.02})
    cond["flat"][1]["status"] = "diverged"  # world 0's FSM
    assert sensor.change(ideal, cond, "fsm", "median.mean.abs_rel")["n_worlds"] == 2


def test_between_two_conditions_reads_each_methods_change_and_zero_where_nothing_differs():
    compensate, assume = _results({}), _results({"fsm": 0.01, "mcdp_m2": 0.004})
    text = sensor.format_between(("`sync: compensate`", compensate), ("`sync: assume`", assume))
    assert text.startswith("`sync: compensate` - `sync: assume`, paired by world, **positive = `sync: assume` helps**")
    mono = next(line for line in text.splitlines() if line.startswith("| Mono2 |"))
    assert mono.startswith("| Mono2 | +0.0000") and "(worse)" not in mono  # same results: exactly no change
    fsm = next(line for line in text.splitlines() if line.startswith("| FSM |"))
    assert fsm.startswith("| FSM | -0.010") and "**(worse)**" in fsm


def test_the_follow_up_reads_its_primary_contrast_with_the_rank_based_reading_and_every_world():
    ideal, cond = _results({}, worlds=14), _results({"fsm": 0.01}, worlds=14)
    text = sensor.format_followup(ideal, cond, 14, "primary: the contrast")
    assert "14 worlds, one look at the end, primary: the contrast. Read here: 14 worlds" in text
    primary = next(line for line in text.splitlines() if line.startswith("**Primary:"))
    assert "MCDP (m = 2)'s change - FSM's = +0.010" in primary and "13 df" in primary, primary
    assert "Wilcoxon p = 0.000" in primary and "beyond the interval; the rank-based reading agrees" in primary
    assert sum(line.startswith("| ") and line[2].isdigit() for line in text.splitlines()) == 14  # a row a world
    # the t interval clears 0 but the ranks do not (a few worlds carry the mean): said, not hidden
    n = {"mean": 0.01, "ci95": 0.008, "se": 0.004, "df": 13, "n_worlds": 14, "mde80": 0.011, "differs": 1, "p": 0.03}
    rank = {"p": 0.2, "hl": 0.001, "ci": (-0.001, 0.01), "ci_level": 0.951}
    lone = sensor._primary_line(n, rank, "FSM", "MCDP")
    assert "beyond the interval; the rank-based reading does not reject, so a few worlds may carry it" in lone
    assert "the opposite of the paper's argument" in sensor._primary_line({**n, "mean": -0.01, "differs": -1},
                                                                          rank, "FSM", "MCDP")
    null = next(line for line in sensor.format_followup(ideal, _results({}, seed=0, worlds=14), 14, "x").splitlines()
                if line.startswith("**Primary:"))
    assert "+0.0000 ± 0.0000" in null and "Not resolved" in null, null
