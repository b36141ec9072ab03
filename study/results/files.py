"""A sweep's results on disk: results.csv written (`write_csv`: one row per overlap x method x variant x seed, with
its world, then the yardsticks) beside its reader (`results_from_csv`), and `read_results`, which reads a
results.json or a results.csv, also one written before the variant field (`study.results.summary.upgrade_results`).
results.json is `study.results.summary.build_results`' dict as JSON (`study.report.outputs.write_all`). A published one
(docs/results/<name>/) is compact (`compact_results`): results.json keeps the summaries (config, timing, counters)
and names records.json.gz beside it, the per-run and per-world records; `read_results` joins them back. Its
results.csv is published gzip'd (`CSV_GZ`, `gzip_csv`: the same bytes a sweep writes, at a fixed time stamp);
`read_results` and `results_from_csv` read a results.csv.gz as they read a results.csv.

Example::

    results = read_results("SWEEP/results.json")   # or SWEEP/results.csv: the part the plots read
    results = read_results("docs/results/propagation/results.csv.gz")   # pandas.read_csv reads it as is too
"""
from __future__ import annotations

import csv
import gzip
import io
import json
import zlib
from pathlib import Path

from corelib.atomic import atomic_write_text
from study.results.summary import (LEGACY_ROW_KEYS, SCHEMA, YARDSTICKS, aggregate_flat, evaluations, evaluations_of,
                           flat_rows, upgrade_results, yardstick_row)
from study.sweep.variants import CUT
from study.sweep.worlds import data_seeds


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
    from corelib.readfile import read_file, read_json_file

    path = Path(path)
    if path.suffix == ".csv" or path.name.endswith(".csv.gz"):
        return results_from_csv(path)
    obj = read_json_file(path, kind="results")  # the rule of the project's own files (corelib.readfile)
    if isinstance(obj, dict) and RECORDS_KEY in obj:
        name = obj[RECORDS_KEY].get("file") if isinstance(obj[RECORDS_KEY], dict) else None
        if not isinstance(name, str) or Path(name).name != name:
            raise ValueError(f"{path}: its records file must be a name beside it, got {str(name)[:100]!r}")
        obj = join_results(obj, read_file(path.parent / name, path.parent, kind="results"))
    return upgrade_results(obj)


# ------------------------------------------------------------------------------------------- compact results
#: a published sweep's results.csv (docs/results/<name>/): gzip'd, about 2.3 times smaller (4.3 MB -> 1.9 MB over
#: the 15 committed sweeps); pandas (``read_csv``, compression inferred from the name) and the standard library
#: (``csv.reader(gzip.open(path, "rt"))``) read it as is. A sweep's own folder keeps its plain results.csv.
CSV_GZ = "results.csv.gz"
#: at most this many bytes of text out of a results.csv.gz (a gzip bomb is refused, not unpacked)
MAX_CSV_TEXT_BYTES = 64 * 2**20


def gzip_csv(data: bytes) -> bytes:
    """The bytes of `CSV_GZ` for a results.csv's bytes: gzip at level 9 and a fixed time stamp, no file name (the
    same results.csv gives the same bytes, so a rebuilt page's folder is byte-identical to the committed one)."""
    return gzip.compress(data, compresslevel=9, mtime=0)


def _gunzip_text(blob: bytes, path) -> str:
    """The text of a results.csv.gz's bytes, at most `MAX_CSV_TEXT_BYTES`; ValueError naming ``path``."""
    try:
        d = zlib.decompressobj(wbits=31)
        raw = d.decompress(blob, MAX_CSV_TEXT_BYTES)
        if d.unconsumed_tail:
            raise ValueError(f"{path}: more than {MAX_CSV_TEXT_BYTES} bytes of CSV; refused")
        return raw.decode("utf-8")
    except (zlib.error, UnicodeDecodeError) as exc:
        raise ValueError(f"{path}: not gzip of a UTF-8 CSV ({str(exc)[:120]})") from None


#: the file beside a published results.json that holds its records (gzip of compact JSON: the records are nested
#: dicts whose keys vary by metric, region and variant, not one table; the standard library reads it, and a
#: columnar file would store the same float64 values in about the same bytes, the floats being what is big)
RECORDS = "records.json.gz"
#: the key of a compact results.json that names its records file, and what it holds and left out
RECORDS_KEY = "records"
#: the parts of the results that go into the records file; ``flat`` and ``aggregate`` are recomputed on reading
#: (`study.results.summary.flat_rows`, `aggregate_flat`) where that gives them back exactly, else kept there too
_HELD = ("data", "rows")
_DERIVED = ("flat", "aggregate")
#: the per-sequence records a page reads (the L_con page's variance split, `study.report.sections.lcon.split_of`: each test
#: sequence's abs_rel sums of the cut evaluation on non-overlap pixels); every other one is left out
PER_SEQUENCE_KEPT = (CUT, "non_overlap")
#: the region splits whose records keep abs_rel only, the one metric of them that results.csv and every page read
#: (`study.sweep.records.flat_row`)
ABS_REL_ONLY = ("bands", "classes", "motion", "road_bands")
#: at most this many bytes of JSON out of a records file (a gzip bomb is refused, not unpacked)
MAX_RECORDS_BYTES = 512 * 2**20
LEFT_OUT = ("per-sequence records other than the cut evaluation's on non-overlap pixels (the L_con page's variance "
            "split); the region splits (distance bands, classes, motion, road bands) other than abs_rel; the full "
            "records are in the sweep's own results.json")


def _prune(obj, keep_per_sequence: bool):
    """``obj`` (a metrics summary, or anything holding some) without what `LEFT_OUT` names."""
    if isinstance(obj, list):
        return [_prune(v, keep_per_sequence) for v in obj]
    if not isinstance(obj, dict):
        return obj
    out = {}
    for k, v in obj.items():
        if k == "per_sequence" and isinstance(v, dict):
            if keep_per_sequence and PER_SEQUENCE_KEPT[1] in v:
                out[k] = {PER_SEQUENCE_KEPT[1]: v[PER_SEQUENCE_KEPT[1]]}
        elif k in ABS_REL_ONLY and isinstance(v, dict):
            out[k] = {r: ({"abs_rel": x["abs_rel"]} if isinstance(x, dict) and "abs_rel" in x else x)
                      for r, x in v.items()}
        else:
            out[k] = _prune(v, keep_per_sequence)
    return out


def _pruned_row(row: dict) -> dict:
    if not isinstance(row.get("evaluations"), dict):  # a row written before them: its legacy keys
        cut_key = LEGACY_ROW_KEYS[PER_SEQUENCE_KEPT[0]][0]
        return {k: _prune(v, k == cut_key) for k, v in row.items()}
    return {k: ({ev: _prune(e, ev == PER_SEQUENCE_KEPT[0]) for ev, e in v.items()} if k == "evaluations"
                else _prune(v, False)) for k, v in row.items()}


def _derive(results: dict, part: str) -> list:
    if part == "flat":
        return [f for r in results["rows"] for f in flat_rows(r)]
    return aggregate_flat(results["flat"], [d["overlap"] for d in results["data"]], evaluations(results))


def _dumps(obj) -> str:
    return json.dumps(obj, separators=(",", ":"), allow_nan=True)


def compact_results(results: dict) -> tuple[dict, bytes]:
    """(the summary written as results.json, the bytes of `RECORDS` beside it) of a sweep's results (schema 2):
    the records without what `LEFT_OUT` names, gzip at a fixed time stamp (the same results give the same bytes).
    ``flat`` and ``aggregate`` are left to be recomputed where the pruned records give them back exactly."""
    rows = [_pruned_row(r) for r in results["rows"]]
    data = [_prune(d, False) for d in results["data"]]
    held = {"data": data, "rows": rows}
    probe = dict(results, data=data, rows=rows)
    derived = []
    for part in _DERIVED:  # flat first: the aggregate is recomputed from it
        if _dumps(_derive(probe, part)) == _dumps(results[part]):
            derived.append(part)
        else:
            held[part] = results[part]
    summary = {}
    for k, v in results.items():
        if k not in _HELD and k not in _DERIVED:
            summary[k] = v
    summary[RECORDS_KEY] = {"file": RECORDS, "holds": list(held), "derived": derived, "order": list(results),
                            "left_out": LEFT_OUT}
    blob = gzip.compress(_dumps(held).encode("utf-8"), compresslevel=9, mtime=0)
    return summary, blob


def join_results(summary: dict, blob: bytes) -> dict:
    """The results a compact results.json (``summary``) and its records file's bytes (``blob``) describe, in the
    order of keys they were written in; ValueError naming what is wrong with a records file that is not one."""
    rec = summary[RECORDS_KEY]
    if not isinstance(rec, dict) or not isinstance(rec.get("order"), list):
        raise ValueError(f"field '{RECORDS_KEY}' is not a records entry (file, holds, derived, order)")
    try:
        d = zlib.decompressobj(wbits=31)
        raw = d.decompress(blob, MAX_RECORDS_BYTES)
        if d.unconsumed_tail:
            raise ValueError(f"{RECORDS}: more than {MAX_RECORDS_BYTES} bytes of JSON; refused")
        held = json.loads(raw.decode("utf-8"))
    except (zlib.error, UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise ValueError(f"{RECORDS}: not gzip of JSON ({str(exc)[:120]})") from None
    if not isinstance(held, dict):
        raise ValueError(f"{RECORDS}: not a JSON object")
    whole = {k: v for k, v in summary.items() if k != RECORDS_KEY}
    whole.update(held)
    for part in rec.get("derived", []):
        whole[part] = _derive(whole, part)
    return {k: whole[k] for k in rec["order"] if k in whole}


def results_from_csv(path) -> dict:
    """The part of `build_results`' dict that the plots read (overlaps, methods, seeds, flat, aggregate, the
    measured overlap and the yardsticks' rows), rebuilt from a results.csv (`write_csv`) for a
    sweep whose results.json was not kept. Empty cells are left out of the rows, as they were absent. A
    results.csv without a ``variant`` column (written before it) is read through `upgrade_results`. A
    results.csv.gz (`CSV_GZ`, a published sweep's) is read the same, unpacked in memory."""
    from corelib.readfile import read_file, read_text_file

    if str(path).endswith(".gz"):
        text = _gunzip_text(read_file(path, kind="results"), path)
    else:
        text = read_text_file(path, kind="results")
    reader = csv.DictReader(io.StringIO(text, newline=""))
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
