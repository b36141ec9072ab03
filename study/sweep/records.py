"""What the sweep's stages share (`study.sweep.stages` for the runs, `study.sweep.worlds` for the worlds): the sweep's
small JSON records, the counters of what was done or skipped, and the summary of one metrics.json that the
report reads, and its flat form (`flat_row`: one CSV row's numbers, `study.results.summary.flat_rows`).
"""
from __future__ import annotations

import json
import math
from pathlib import Path
from typing import Any

from corelib.atomic import atomic_write_json
from mcdp.metrics import metric_names


def read_json(path: Path, root: Path | None = None) -> dict | None:
    """A sweep's own record (``sweep_status.json``, ``metrics_test*.json``, ``data/overlap_X.status.json``) by the
    one rule (`corelib.readfile.read_json_file`: no link, non-blocking, at most ``LIMITS["record"]``); None when
    it is absent or not JSON (written again). A link (one from outside may hold forged numbers), a FIFO or a file
    over the bound is `corelib.readfile.ReadRefused`, one line naming it: the sweep never made such a file."""
    from corelib.readfile import FileMissing, ReadRefused, read_file

    try:
        data = read_file(path, root, "record")
    except FileMissing:
        return None
    try:
        return json.loads(data.decode("utf-8"))
    except (ValueError, RecursionError):  # ValueError: UnicodeDecodeError and JSONDecodeError
        return None


def write_json(path: Path, obj, root: Path | None = None) -> None:
    """``obj`` written whole to ``path``, its folders made; given ``root`` (the sweep's folder), never through a
    link below it (`corelib.nolinks.write_json_in`: `corelib.atomic.LinkRefused` names the link)."""
    if root is not None:
        from corelib.nolinks import write_json_in

        write_json_in(root, path, obj, indent=1, allow_nan=True)
        return
    path.parent.mkdir(parents=True, exist_ok=True)
    atomic_write_json(path, obj, allow_nan=True)


def finite(x) -> bool:
    return isinstance(x, (int, float)) and math.isfinite(x)


def summarize_metrics(metrics: dict, stage: str = "final") -> dict:
    """The numbers the report uses, from one metrics.json (`mcdp.evaluate` layout)."""
    st = metrics["stages"][stage]
    out: dict[str, Any] = {}
    for sc in ("none", "median", "rig_median"):
        if sc not in st:
            continue
        out[sc] = {
            "mean": dict(st[sc]["mean"]),
            "overlap": dict(st[sc]["overlap"]),
            "non_overlap": dict(st[sc]["non_overlap"]),
            "per_camera_abs_rel": {c: v["abs_rel"] for c, v in st[sc]["per_camera"].items()},
        }
        if "bands" in st[sc]:  # metrics written before the distance bands have none
            out[sc]["bands"] = {b: dict(v) for b, v in st[sc]["bands"].items()}
        if stage == "final" and "per_sequence" in st[sc]:  # a pass's own result only (not its ORACLE stages); metrics
            out[sc]["per_sequence"] = st[sc]["per_sequence"]  # written before it have none (a bootstrap's input)
        for key in ("classes", "motion", "road_bands", "holes"):  # a dataset with semantic labels only
            if key in st[sc]:
                out[sc][key] = {k: (dict(v) if isinstance(v, dict) else v) for k, v in st[sc][key].items()}
    dc = st["dep_con"]
    out["dep_con"] = {"mean": dc["mean"], "per_camera": dict(dc["per_camera"]), "per_pair": dict(dc["per_pair"])}
    out["spread"] = dict(st.get("spread", {}))
    out["n_samples"] = metrics.get("n_samples")
    out["stages"] = list(metrics["stages"])
    return out


def number(x) -> float:
    """``x`` as a float, NaN for anything that is not a number (a missing record, None)."""
    return float(x) if isinstance(x, (int, float)) and x is not None else float("nan")


def flat_row(row: dict) -> dict[str, Any]:
    """One run's numbers as a flat dict of scalars (the CSV row; ``variant``: set by `flat_rows`)."""
    out: dict[str, Any] = {k: row.get(k) for k in ("overlap", "method", "variant", "seed", "status", "steps",
                                                     "checkpoint_step", "train_s", "eval_s", "train_skipped",
                                                     "eval_skipped")}
    if row.get("world") is not None:  # its data seed (rows written before issue 47 have none: `data_seeds`)
        out["world"] = row["world"]
    m = row.get("metrics")
    if not m:
        return out
    for sc in ("none", "median", "rig_median"):
        if sc not in m:
            continue
        for region in ("mean", "overlap", "non_overlap"):
            for k in metric_names():  # a metric the record predates is absent, as in its results.csv (no NaN column)
                if k in m[sc][region]:
                    out[f"{sc}.{region}.{k}"] = number(m[sc][region][k])
        for cam, v in m[sc]["per_camera_abs_rel"].items():
            out[f"{sc}.camera.{cam}.abs_rel"] = number(v)
        for band, v in m[sc].get("bands", {}).items():  # distance to the overlap (mcdp.evaluate)
            out[f"{sc}.band.{band}.abs_rel"] = number(v.get("abs_rel"))
        for key, name in (("classes", "class"), ("motion", "motion"), ("road_bands", "road_band")):  # labels
            for region, v in m[sc].get(key, {}).items():
                out[f"{sc}.{name}.{region}.abs_rel"] = number(v.get("abs_rel"))
        for kind, v in m[sc].get("holes", {}).items():
            out[f"{sc}.holes.{kind}"] = number(v)
    out["dep_con.mean"] = number(m["dep_con"]["mean"])
    out["spread.ratio"] = number(m.get("spread", {}).get("ratio"))
    for cam, v in m["dep_con"]["per_camera"].items():
        out[f"dep_con.camera.{cam}"] = number(v)
    for pair, v in m["dep_con"]["per_pair"].items():
        out[f"dep_con.pair.{pair}"] = number(v)
    return out


class Counters(dict):
    def bump(self, key: str) -> None:
        self[key] = self.get(key, 0) + 1
