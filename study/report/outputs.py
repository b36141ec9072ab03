"""The files a sweep writes, from its results dict (`study.results.summary.build_results`): results.json, results.csv
(`study.results.files.write_csv`), plots/ and report.md
(`study.report.compose.format_report`). `scripts/publish_sweep.py` builds the same from a committed results.json.

Example::

    python -c "import study.report.outputs as o, study.results.files as s; o.write_all(s.read_results('SWEEP/results.json'), 'SWEEP')"
"""
from __future__ import annotations

from pathlib import Path

from corelib.atomic import atomic_write_json, atomic_write_text
from study.report.sections.lcon import format_lcon
from study.report.plots import distance_plot, make_plots
from study.report.compose import format_report
from study.results.files import write_csv


def write_all(results: dict, out: str | Path) -> None:
    out = Path(out)
    atomic_write_json(out / "results.json", results, allow_nan=True)
    write_csv(results, out / "results.csv")
    plots = report_plots(results, out / "plots")
    atomic_write_text(out / "report.md", format_report(results, [p.relative_to(out).as_posix() for p in plots]))


def report_plots(results: dict, plot_dir: Path) -> list[Path]:
    """Every figure of the report, written into ``plot_dir``: the sweep's plots, the distance figure, and the L_con
    forest plots (`study.report.sections.lcon`) where the sweep has them."""
    plots = make_plots(results, plot_dir)
    extra = distance_plot(results, plot_dir)
    return plots + ([extra] if extra is not None else []) + format_lcon(results, plot_dir)[1]
