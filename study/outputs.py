"""The files a sweep writes, from its results dict (`study.results.build_results`): results.json, results.csv
(one row per overlap x method x variant x seed, with its world, then the yardsticks), plots/ and report.md
(`study.report.format_report`). `scripts/publish_sweep.py` builds the same from a committed results.json.

Example::

    python -c "import study.outputs as o, study.results as s; o.write_all(s.read_results('SWEEP/results.json'), 'SWEEP')"
"""
from __future__ import annotations

import csv
import io
from pathlib import Path

from corelib.atomic import atomic_write_json, atomic_write_text
from study.lcon import format_lcon
from study.plots import distance_plot, make_plots
from study.report import format_report
from study.results import YARDSTICKS, yardstick_row
from study.worlds import data_seeds


def write_all(results: dict, out: str | Path) -> None:
    out = Path(out)
    atomic_write_json(out / "results.json", results, allow_nan=True)
    write_csv(results, out / "results.csv")
    plots = report_plots(results, out / "plots")
    atomic_write_text(out / "report.md", format_report(results, [p.relative_to(out).as_posix() for p in plots]))


def report_plots(results: dict, plot_dir: Path) -> list[Path]:
    """Every figure of the report, written into ``plot_dir``: the sweep's plots, the distance figure, and the L_con
    forest plots (`study.lcon`) where the sweep has them."""
    plots = make_plots(results, plot_dir)
    extra = distance_plot(results, plot_dir)
    return plots + ([extra] if extra is not None else []) + format_lcon(results, plot_dir)[1]


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
