"""A sweep's results on disk: results.csv written (`write_csv`: one row per overlap x method x variant x seed, with
its world, then the yardsticks) beside its reader (`results_from_csv`), and `read_results`, which reads a
results.json or a results.csv, also one written before the variant field (`study.results.upgrade_results`).
results.json is `study.results.build_results`' dict as JSON (`study.outputs.write_all`).

Example::

    results = read_results("SWEEP/results.json")   # or SWEEP/results.csv: the part the plots read
"""
from __future__ import annotations

import csv
import io
import json
from pathlib import Path

from corelib.atomic import atomic_write_text
from study.results import SCHEMA, YARDSTICKS, aggregate_flat, evaluations_of, upgrade_results, yardstick_row
from study.worlds import data_seeds


def write_csv(results: dict, path: Path) -> None:
    flats = results["flat"]
    meas = {d["overlap"]: d["measured"] for d in results["data"]}
    keys: list[str] = []
    for f in flats:
        for k in f:
            if k not in keys:
                keys.append(k)
    seeds = data_seeds(results)  # the world (its data seed) of rows written before their own field
    flats = [{**f, "world": f.get("world", seeds.get((f["overlap"], f["seed"])))} for f in flats]
    head = [k for k in ("overlap", "method", "variant", "seed", "world") if k in keys or k == "world"]
    keys = head + ["target_overlap", "measured_overlap"] + [k for k in keys if k not in head]
    fh = io.StringIO(newline="")
    with fh:
        w = csv.DictWriter(fh, fieldnames=keys, restval="")
        w.writeheader()
        for f in flats:
            m = meas.get(f["overlap"], {})
            w.writerow({**f, "target_overlap": m.get("target"), "measured_overlap": m.get("measured_mean")})
        for which, _, name in YARDSTICKS:  # the yardsticks, one row per overlap each
            for d in results["data"]:
                ref = yardstick_row(results, d["overlap"], which)
                if ref:
                    w.writerow({**{k: v for k, v in ref.items() if k in keys}, "overlap": d["overlap"],
                                "method": name, "status": "reference",
                                "target_overlap": d["measured"].get("target"),
                                "measured_overlap": d["measured"].get("measured_mean")})
        atomic_write_text(path, fh.getvalue())


def read_results(path) -> dict:
    """A sweep's results.json, or its results.csv (`results_from_csv`), in the current `SCHEMA`: one written
    before the variant field is upgraded on reading (`upgrade_results`)."""
    path = Path(path)
    if path.suffix == ".csv":
        return results_from_csv(path)
    return upgrade_results(json.loads(path.read_text()))


def results_from_csv(path) -> dict:
    """The part of `build_results`' dict that the plots read (overlaps, methods, seeds, flat, aggregate, the
    measured overlap and the yardsticks' rows), rebuilt from a results.csv (`write_csv`) for a
    sweep whose results.json was not kept. Empty cells are left out of the rows, as they were absent. A
    results.csv without a ``variant`` column (written before it) is read through `upgrade_results`."""
    with open(path, newline="") as fh:
        reader = csv.DictReader(fh)
        table = [{k: _cell(v) for k, v in r.items() if v != ""} for r in reader]
        legacy = "variant" not in (reader.fieldnames or [])
    if not table or "method" not in table[0]:
        raise ValueError(f"{path}: not a sweep's results.csv (no rows, or no 'method' column)")
    yard = {name: which for which, _, name in YARDSTICKS}
    flats = [r for r in table if r["method"] not in yard]
    if legacy:
        flats = upgrade_results({"flat": flats})["flat"]
    overlaps = sorted({r["overlap"] for r in table})
    methods = list(dict.fromkeys(r["method"] for r in flats))
    data = []
    for o in overlaps:
        rows = [r for r in table if r["overlap"] == o]
        d = {"overlap": o, "measured": {"target": rows[0].get("target_overlap", o),
                                        "measured_mean": rows[0].get("measured_overlap", float("nan"))}}
        for r in rows:
            if r["method"] in yard:
                d[yard[r["method"]]] = {"row": {k: v for k, v in r.items() if "." in k}}
        data.append(d)
    evs = evaluations_of(methods, flats)
    return {"schema": SCHEMA, "overlaps": overlaps, "methods": methods, "evaluations": [e.record() for e in evs],
            "seeds": sorted({r["seed"] for r in flats if "seed" in r}), "flat": flats, "data": data,
            "aggregate": aggregate_flat(flats, overlaps, evs)}


def _cell(v: str):
    if v in ("True", "False"):
        return v == "True"
    try:
        return int(v) if v.lstrip("-").isdigit() else float(v)
    except ValueError:
        return v
