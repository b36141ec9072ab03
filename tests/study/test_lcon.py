"""study/report/sections/lcon.py: (b) read over worlds at one step, its answer sentence, the noise split and the looks; the world
column of results.csv (study/report/outputs.py)."""
import csv
import json
import math
from pathlib import Path

import numpy as np
import pytest

from study.report.sections import lcon
from study.results.files import read_results, write_csv
from study.report.sections.primary import plan_of

PLAN = {"delta": 0.005}  # today's bound (study.sweep.config.SweepPlan's default, the committed presets' plan.delta)
DELTA = PLAN["delta"]
from study.sweep.variants import CUT

ROOT = Path(__file__).resolve().parents[2]


def _metrics(value, seqs, rng, noise):
    per = {}
    for sc in ("none", "median", "rig_median"):
        rec = {s: {"sum": [value + rng.normal(0, noise)], "n": [1]} for s in seqs}
        mean = float(np.mean([r["sum"][0] for r in rec.values()]))
        per[sc] = {"non_overlap": {"abs_rel": mean}, "per_sequence": {"non_overlap": rec}}
    return per


def _results(effects, steps=None, plan=None, noise=0.002):
    rng = np.random.default_rng(0)
    seqs = [f"seq_{k:03d}" for k in range(8)]
    rows = []
    for w, eff in enumerate(effects):
        for method, v in (("mcdp_m2_nocon", 0.25 + eff), ("mcdp_m2", 0.25)):
            step = (steps or {}).get((w, method), 200)
            rows.append({"overlap": 0.1, "method": method, "seed": w, "world": 100 + w, "status": "ok",
                         "checkpoint_step": step, "evaluations": {CUT: {"metrics": _metrics(v, seqs, rng, noise)}}})
    return {"methods": ["mcdp_m2_nocon", "mcdp_m2"], "data": [{"overlap": 0.1}], "rows": rows,
            "sweep_config": {"worlds": "per_seed", "checkpoint": "last", "plan": plan}}


def test_a_pair_is_scored_at_one_step_and_said_so():
    res = _results([0.01] * 4)
    assert all(p["same_step"] and p["steps"] == (200, 200) for p in lcon.pairs(res))
    text, _ = lcon.format_lcon(res)
    assert "**Every pair scored at one step** (200)" in text
    res = _results([0.01] * 4, steps={(2, "mcdp_m2"): 75})
    text, _ = lcon.format_lcon(res)
    assert "**1 of 4 pairs were scored at two different steps**: world 102: 200 / 75" in text


def test_answer_follows_the_primary_test():
    helps = lcon.reading(lcon.pairs(_results([0.010, 0.012, 0.011, 0.009, 0.013, 0.010])), "median", PLAN)
    assert lcon.answer(helps).startswith("L_con improves non-overlap depth by +0.0103 ± 0.0021")  # noise 0.002 per sequence
    null = lcon.reading(lcon.pairs(_results([0.0005, -0.0004, 0.0002, -0.0001, 0.0003, -0.0002])), "median", PLAN)
    assert lcon.answer(null).startswith(f"Equivalent to 0 within ±{DELTA:g}")
    wide = lcon.reading(lcon.pairs(_results([0.03, -0.02, 0.01, -0.025])), "median", PLAN)
    assert lcon.answer(wide).startswith("Not resolved with 4 worlds") and "detectable at" in lcon.answer(wide)


def test_the_world_column_is_each_rows_world_and_the_split_is_in_the_section(tmp_path):
    res = _results([0.01, 0.02, 0.0, 0.015, 0.005], plan={"worlds": 10, "first_look": 5, "why": "pilot"})
    text, plots = lcon.format_lcon(res, tmp_path)
    assert "test-sampling noise" in text and "heterogeneity" in text and len(plots) == 1 and plots[0].exists()
    assert "look at 5 worlds" in text and "look at 10 worlds: not reached (5 worlds measured)" in text


def test_results_csv_world_is_the_data_seed_each_run_trained_on(tmp_path):
    """The committed propagation sweep: 3 worlds x 2 seeds (seeds 0, 1 on data seed 0, ...): the column is the data
    seed each run's world was rendered from."""
    res = read_results(ROOT / "docs/results/propagation/results.json")
    write_csv(res, tmp_path / "r.csv")
    rows = [r for r in csv.DictReader((tmp_path / "r.csv").open()) if r["status"] != "reference"]
    assert rows and {(r["seed"], r["world"]) for r in rows} == {("0", "0"), ("1", "0"), ("2", "1"), ("3", "1"),
                                                                ("4", "2"), ("5", "2")}
    for d in res["data"]:   # the data seed of each world's recorded render
        assert [w["data_seed"] for w in d["worlds"]] == [0, 1, 2]


def test_the_lcon_presets_score_both_arms_at_one_step_and_state_their_plan():
    """Rule 1 in the presets themselves: every L_con preset evaluates the last checkpoint; the main one states its
    plan (planned worlds, first look at about half) before the run."""
    from study.sweep.config import load_sweep_config

    for name in ("cpu_lcon_pilot", "cpu_lcon", "cpu_lcon_overlaps"):
        cfg = load_sweep_config(str(ROOT / f"configs/sweep/{name}.yaml"), [])
        assert cfg.checkpoint == "last" and cfg.worlds == "per_seed" and cfg.seeds_per_world == 1, name
        assert lcon.lcon_arms({"methods": cfg.methods}) == ("mcdp_m2_nocon", "mcdp_m2"), name
    prop = load_sweep_config(str(ROOT / "configs/sweep/cpu_propagation.yaml"), [])  # its (b) too, at 3 overlaps
    assert prop.checkpoint == "last" and prop.overlaps == [0.10, 0.30, 0.60] and {"mcdp_m2_nocon", "mcdp_m2"} <= set(
        prop.methods)
    main = load_sweep_config(str(ROOT / "configs/sweep/cpu_lcon.yaml"), [])
    assert main.plan.worlds == len(main.seeds) and main.plan.first_look == len(main.seeds) // 2


def test_the_readme_opens_with_the_committed_answer():
    """The README's headline table gives the L_con page's answer, as the committed results give it (its first row);
    the 1000-step reading stands in docs/RESULTS.md, where the README's narrative moved (issue 60)."""
    from study.results.files import read_results

    res = read_results(ROOT / "docs/results/lcon_main/results.json")
    n = lcon.reading(lcon.pairs(res), "median", plan_of(res))
    said = lcon.answer(n)
    readme = " ".join((ROOT / "README.md").read_text().split())
    page = (ROOT / "docs/results/lcon.md").read_text()
    assert f"**{said}**" in page.splitlines()[2]
    assert said in readme
    assert n["n_worlds"] == 14 and all(p["same_step"] for p in lcon.pairs(res))
    rows = [r for r in res["rows"] if r["method"] in ("mcdp_m2", "mcdp_m2_nocon")]
    seeds = {w["world"]: w["data_seed"] for w in res["data"][0]["worlds"]}
    assert all(r["world"] == seeds[r["seed"]] for r in rows)   # the world column is the data seed it trained on
    # the 1000-step reading (item 4) as docs/RESULTS.md states it, beside its control, on the main run's worlds
    narrative = " ".join((ROOT / "docs" / "RESULTS.md").read_text().split())
    br = lcon.budget_reading(read_results(ROOT / "docs/results/lcon_budget/results.json"), res)
    b, c, rig = br["b"]["median"], br["control"]["median"], br["b"]["rig_median"]
    assert b["n_worlds"] == 6 and br["short"]["median"]["n_worlds"] == 6 and c["differs"] == 1
    for figure in (f"{b['mean']:+.4f} ± {b['ci95']:.4f}", f"{c['mean']:+.4f} ± {c['ci95']:.4f}",
                   f"by {-rig['mean']:.4f} ± {rig['ci95']:.4f}", f"TOST p = {b['tost']['p']:.3f}"):
        assert figure in narrative, figure


def _with_control(res, emptied, filled):
    """``res`` with an ORACLE-local run per world (filled = as trained, emptied = cut) in its flat rows (the
    columns `study.report.sections.primary.measure` reads)."""
    from study.sweep.variants import TRAINED

    worlds = sorted({r["seed"]: r["world"] for r in res["rows"]}.items())
    res["flat"] = []
    for s, w in worlds:
        for variant, v in ((TRAINED, filled + 0.001 * s), (CUT, emptied)):
            res["flat"].append({"overlap": 0.1, "method": "oracle_local", "variant": variant, "seed": s, "world": w,
                                "status": "ok", **{f"{sc}.non_overlap.abs_rel": v for sc in ("none", "median",
                                                                                             "rig_median")}})
    res["methods"].append("oracle_local")
    res["seeds"] = [s for s, _ in worlds]
    return res


def test_the_budget_reading_puts_b_beside_its_control_and_pairs_it_with_the_short_budget_by_world():
    """Item 4: (b) at the long budget is read beside the positive control trained at that budget (emptied - filled,
    positive = the overlap's depth helps outside it), and its change from the short budget is paired by world."""
    long = _with_control(_results([0.004, 0.006, 0.005, 0.003]), emptied=0.30, filled=0.25)
    short = _results([0.001, 0.002, 0.000, 0.001, 0.009])  # a fifth world the long budget lacks: left out
    r = lcon.budget_reading(long, short)
    c = r["control"]["median"]
    assert c["n_worlds"] == 4 and 0.045 < c["mean"] < 0.050 and c["differs"] == 1
    assert r["short"]["median"]["n_worlds"] == 4
    ch = r["change"]["median"]
    assert ch["n_worlds"] == 4 and abs(ch["mean"] - (r["b"]["median"]["mean"] - r["short"]["median"]["mean"])) < 1e-12
    assert 0.002 < ch["mean"] < 0.005
    text = lcon.format_budget(r, "1000", "200")
    assert "**the control propagates**" in text and "Change from 200 to 1000 steps, paired by world" in text
    flat = _with_control(_results([0.004, 0.006, 0.005, 0.003]), emptied=0.25, filled=0.25)
    assert "does not propagate" in lcon.format_budget(lcon.budget_reading(flat, None), "1000", "200")
    bare = {**_results([0.004, 0.006]), "flat": []}  # no ORACLE-local run
    assert "No positive control" in lcon.format_budget(lcon.budget_reading(bare, None), "1000", "200")


def test_the_headline_stands_beside_its_arms_level_and_the_yardsticks():
    """issue 60 item 2: the L_con headline's arms' levels are the figures its difference is made of (their
    difference is the headline's mean), beside the yardsticks that use no training, read from the committed run."""
    import re

    from study.report.sections.lcon import levels, pairs, reading
    from study.report.sections.primary import plan_of
    from study.results.files import read_results
    from study.results.summary import yardstick_agg

    r = read_results(ROOT / "docs" / "results" / "lcon_main" / "results.json")
    ps = pairs(r)
    text = levels(r, ps, "median")
    m = re.search(r"w/o L_con (\d\.\d{4}), with L_con (\d\.\d{4}) .* over the (\d+) worlds\); .*a constant depth "
                  r"(\d\.\d{4}), the flat-road prior (\d\.\d{4})", text)
    assert m, text
    a, b, n, ref, prior = float(m[1]), float(m[2]), int(m[3]), float(m[4]), float(m[5])
    plan = plan_of(r)
    assert n == len(ps) == reading(ps, "median", plan)["n_worlds"] == 14
    assert abs((a - b) - reading(ps, "median", plan)["mean"]) < 1.5e-4  # the levels make the difference
    assert ref == round(yardstick_agg(r, plan["overlap"], "median.non_overlap.abs_rel")["mean"], 4)
    assert prior == round(yardstick_agg(r, plan["overlap"], "median.non_overlap.abs_rel", "prior")["mean"], 4)
    assert max(a, b) < prior < ref  # trained depth beats both yardsticks here
    assert levels(r, [], "median") == ""
