"""How results_v1.json and results_v1.csv (beside this file) were made: a small sweep's results in the format
written before the variant field (schema 1: "mcdp_m2@cut", "mcdp_m2@oracle", ... as method names), by the
code of that day (commit 70c9c30: study.results.summary.flat_rows / evaluation_names / aggregate_flat and
study.results.files.write_csv), from synthetic per-run rows. Kept as a record; with today's code it no longer runs
(those functions changed), which is the point of the fixture:

    git archive 70c9c30 study mcdp corelib synth scenes | tar -x -C /tmp/oldcode
    PYTHONPATH=/tmp/oldcode python tests/study/data/make_results_v1.py

tests/study/test_results.py reads both files with today's code and checks them against the same rows
evaluated by it (results.json's ``rows`` are unchanged between the formats).
"""
from __future__ import annotations

import json
import random
from pathlib import Path

from mcdp.metrics import metric_names
from study.results.files import write_csv
from study.results.summary import aggregate_flat, evaluation_names, flat_rows

HERE = Path(__file__).resolve().parent
CAMS = ("CAM_A", "CAM_B")


def metrics(rng: random.Random, base: float) -> dict:
    def block():
        return {k: round(base * rng.uniform(0.8, 1.2), 5) for k in metric_names()}
    sc = {s: {"mean": block(), "overlap": block(), "non_overlap": block(),
              "per_camera_abs_rel": {c: round(base * rng.uniform(0.8, 1.2), 5) for c in CAMS}}
          for s in ("none", "median")}
    return {**sc, "dep_con": {"mean": round(base / 5, 5), "per_camera": {c: round(base / 5, 5) for c in CAMS},
                              "per_pair": {"CAM_A-CAM_B": round(base / 5, 5)}},
            "spread": {"ratio": round(rng.uniform(2, 4), 3)}}


def row(rng: random.Random, o: float, method: str, seed: int) -> dict:
    base = 0.25 - 0.05 * o + 0.01 * seed
    r = {"overlap": o, "method": method, "seed": seed, "status": "ok", "steps": 10, "checkpoint_step": 10,
         "train_s": 1.0, "eval_s": 0.5, "train_skipped": False, "eval_skipped": False,
         "metrics": metrics(rng, base), "refinement": None}
    if method == "mcdp_m2":
        r["refinement"] = {"weight_move": 0.01, "depth_change_m": 0.02 + 0.01 * seed, "oracle_weight_move": 0.2}
        r["metrics_init"] = metrics(rng, base + 0.01)
        r["metrics_oracle"] = metrics(rng, base - 0.05)
        r["metrics_oracle_overlap"] = metrics(rng, base - 0.02)
    if method in ("mcdp_m2", "surround"):
        r["metrics_cut"] = metrics(rng, base + 0.005)
        r["refinement_cut"] = {"weight_move": 0.005, "depth_change_m": 0.01, "cut_change_m": 0.03}
    return r


def main() -> None:
    rng = random.Random(0)
    overlaps, methods, seeds = [0.3, 0.6], ["mono2", "mcdp_m2", "surround"], [0, 1]
    rows = [row(rng, o, m, s) for o in overlaps for m in methods for s in seeds]
    flats = [f for r in rows for f in flat_rows(r)]
    names = evaluation_names(methods, flats)
    data = [{"overlap": o, "measured": {"target": o, "measured_mean": round(0.8 * o, 4)},
             "reference": {"depth_m": 10.0, "metrics": metrics(rng, 0.5)},
             "prior": {"far_m": 10.0, "metrics": metrics(rng, 0.4)}} for o in overlaps]
    results = {"overlaps": overlaps, "methods": methods, "evaluations": names, "seeds": seeds, "data": data,
               "rows": rows, "flat": flats, "aggregate": aggregate_flat(flats, overlaps, names)}
    (HERE / "results_v1.json").write_text(json.dumps(results) + "\n")
    write_csv(results, HERE / "results_v1.csv")


if __name__ == "__main__":
    main()
