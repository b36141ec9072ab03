"""Publish the calibration page, docs/results/calibration.md, from committed data: never edited by hand (issue 57).

    python scripts/publish_calibration.py --collect sweeps/calibration [--point x4=sweeps/calibration_x4] \
        [--point live=sweeps/calibration_live] [--point sensor=sweeps/calibration_sensor]
        # once, after the runs: -> docs/results/calibration/values.json
    python scripts/publish_calibration.py           # the page from values.json + configs/calibration/anchors.yaml

``--collect`` reads every arm's sweep folder (`mcdp calibrate`) and keeps, per arm and world, only the columns the
anchors read (the yardsticks' too), with each sweep's run times: a few kB, not the sweeps' records. The page then
reads that file and the anchors file, and docs/results/calibration/preface.md (what the numbers cannot say: the
commands, the machine, the hypotheses for each disagreement). It writes the page and its scatter plot
(calibration/scatter.png), each whole (`corelib.atomic`).
"""
from __future__ import annotations

import argparse
import json
import math
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "scripts"))

RESULTS = ROOT / "docs" / "results"
DIR = RESULTS / "calibration"
VALUES = DIR / "values.json"
ANCHORS = ROOT / "configs" / "calibration" / "anchors.yaml"
YARDSTICKS = ("constant_reference", "flat_road_prior")
#: the ceiling a synthetic benchmark is held to: six surround methods ranked on DDAD against nuScenes
#: (GaussianOcc, arXiv 2408.11447, Table 2; computed from its rows, ../shared/calibration/SOURCES.md)
REAL_TO_REAL = {"spearman": 0.83, "kendall": 0.73}
POINT_WORDS = {"base": "96x64, 200 steps (the L_con recipe)", "x4": "96x64, 800 steps (4x the compute)",
               "live": "96x64, 200 steps, the ego body's live appearance (`ego.appearance=live`), tuning worlds",
               "sensor": "96x64, 200 steps, the realistic camera's photometry (configs/data/realistic.yaml's exposure, "
                         "white balance, vignetting, noise, motion blur, JPEG and fog, without its trigger and rolling "
                         "shutter), tuning worlds"}
#: points that are diagnostics of a generator setting: they judge tuning anchors only (issue 57 item 6)
DIAGNOSTICS = ("live", "sensor")
#: each point's marker in the scatter plot and its legend's words
MARKERS = {"base": ("o", "200 steps"), "x4": ("s", "800 steps"), "live": ("^", "live ego"),
           "sensor": ("D", "realistic camera")}


def collect(folders: dict[str, Path]) -> dict:
    """{point: {"arms": {arm: {world: {column: value}}}, "yardsticks": {...}, "train_s": {arm: [..]}}}."""
    from study.report.sections.anchors import load_anchors
    from study.report.sections.calibration import arm_train_seconds, arm_values, columns

    anchors = load_anchors(ANCHORS)
    cols = columns(anchors)
    out: dict = {}
    for point, folder in folders.items():
        arms, train_s = {}, {}
        for name, arm in anchors.arms.items():
            sub = folder / name
            if not (sub / "results.csv").is_file():
                continue
            arms[name] = {str(w): v for w, v in sorted(arm_values(sub, cols, arm.method).items())}
            train_s[name] = arm_train_seconds(sub, arm.method)
        first = folder / anchors.order[0]
        yard = {}
        if (first / "results.csv").is_file():
            yard = {y: {str(w): v for w, v in sorted(arm_values(first, cols, y).items())} for y in YARDSTICKS}
        out[point] = {"arms": arms, "yardsticks": yard, "train_s": train_s}
    return out


def _fmt(x: float, nd: int = 3) -> str:
    if x is None or not math.isfinite(x):
        return "n/a"
    s = f"{x:+.{nd}f}"
    if float(s) == 0.0 and x != 0.0:  # never "+0.000" for an effect that is there
        return f"{x:+.1e}"
    return s


def _row_cells(r: dict) -> str:
    from study.results.summary import fmt_diff

    if r["n"] < 2:
        syn, verdict = "not run", "-"
    else:
        syn = f"{fmt_diff({'mean': r['mean'], 'ci95': r['half']})} ({r['n']} worlds)"
        verdict = ("**agrees**" if r["agrees"] else "**disagrees**") if r["resolved"] else \
            (f"**absent** (unresolved, MDE {r['mde']:.3f}, excludes a tenth of the real)" if r["absent"] else
             f"unresolved (MDE {r['mde']:.3f})")
    also = "".join(f"<br>{a['source']}: {_fmt(a['real'])}" for a in r["also"])
    ratio = "n/a" if r["n"] < 2 else f"{r['ratio']:+.2f}"
    return (f"| {r['name']} | {r['set']} | {r['effect']} | {r['source']}{also} | {r['real_before']:.3f} → "
            f"{r['real_after']:.3f} ({_fmt(r['real'])}) | {syn} | {verdict} | "
            f"{ratio} |")


def _figures_line(fig: dict, label: str) -> str:
    rk = fig["ranks"]
    lo, hi = fig["wilson"]
    rate = "n/a" if not fig["resolved"] else f"{fig['agree']} of {fig['resolved']} ({fig['rate']:.2f}, Wilson 95 % " \
        f"[{lo:.2f}, {hi:.2f}])"
    return (f"| {label} | {fig['measured']} | {rate} | {rk['spearman']:+.2f} [{rk['spearman_ci'][0]:+.2f}, "
            f"{rk['spearman_ci'][1]:+.2f}] | {rk['kendall']:+.2f} [{rk['kendall_ci'][0]:+.2f}, "
            f"{rk['kendall_ci'][1]:+.2f}] | {fig['mmrv']:.3f} |")


def scatter(rows_by_point: dict[str, list[dict]], path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(7.5, 6))
    colours = {"tuning": "tab:blue", "test": "tab:orange"}
    for point, rows in rows_by_point.items():
        for r in rows:
            if r["n"] < 2 or (point in DIAGNOSTICS and r["set"] != "tuning"):  # diagnostics judge tuning anchors
                continue
            ax.errorbar(r["real"], r["mean"], yerr=r["half"], fmt=MARKERS[point][0],
                        color=colours[r["set"]], alpha=0.85, capsize=3, markersize=6)
            if point == "base" and (r["resolved"] or r["absent"] or abs(r["real"]) >= 0.02):  # the crowd at 0 unnamed
                ax.annotate(r["name"], (r["real"], r["mean"]), fontsize=7, xytext=(4, 3), textcoords="offset points")
    lim = max([abs(r["real"]) for rows in rows_by_point.values() for r in rows] + [0.05]) * 1.1
    ax.axhline(0, color="grey", lw=0.6)
    ax.axvline(0, color="grey", lw=0.6)
    ax.plot([-lim, lim], [-lim, lim], ls=":", color="grey", lw=0.8, label="synthetic = real")
    for s, c in colours.items():
        ax.plot([], [], "o", color=c, label=f"{s} anchors")
    for p, (m, words) in MARKERS.items():
        if p in rows_by_point:
            ax.plot([], [], m, color="black", label=f"96x64, {words}")
    ax.set_xlabel("real effect (source's before - after; positive = the change helps)")
    ax.set_ylabel("synthetic effect, base - changed, over worlds (95 % t interval)")
    ax.set_title("Does the benchmark reproduce real-data effects? (one point per anchor;\n"
                 "unnamed points near 0: unresolved anchors whose real effect is under 0.02)", fontsize=10)
    ax.legend(fontsize=7, loc="upper left")
    fig.tight_layout()
    from corelib.atomic import atomic_path

    with atomic_path(path) as tmp:
        fig.savefig(tmp, dpi=110, format="png")
    plt.close(fig)


def build(values: dict, plot_dir: Path | None = None) -> str:
    """The page's text from ``values`` (values.json's content); its scatter plot is written into ``plot_dir``
    (default docs/results/calibration/)."""
    from study.report.sections.anchors import load_anchors
    from study.report.sections.calibration import agreement, read_anchors
    from study.results.summary import fmt_diff

    anchors = load_anchors(ANCHORS)
    rows = {p: read_anchors(anchors, {a: {int(w): v for w, v in d.items()} for a, d in values[p]["arms"].items()})
            for p in values}
    base = rows.get("base", [])
    figs = {k: agreement(base, k) for k in ("tuning", "test")}
    figs["all"] = agreement(base)
    a = figs["all"]
    lines = ["# Calibration: does the benchmark reproduce the effects measured on real data?\n",
             "> Generated by `python scripts/publish_calibration.py` from `docs/results/calibration/values.json` and "
             "`configs/calibration/anchors.yaml`; never edited by hand.\n"]
    if a["resolved"]:
        lines.append(
            f"**The benchmark reproduces {a['agree']} of {a['resolved']} resolved real-data effects in sign** (Wilson "
            f"95 % [{a['wilson'][0]:.2f}, {a['wilson'][1]:.2f}]; {len(a['unresolved'])} of {a['measured']} measured "
            f"anchors unresolved at {max(len(r['worlds']) for r in base)} worlds); rank agreement between real and "
            f"synthetic effect sizes ρ = {a['ranks']['spearman']:+.2f} [{a['ranks']['spearman_ci'][0]:+.2f}, "
            f"{a['ranks']['spearman_ci'][1]:+.2f}] (Kendall τ = {a['ranks']['kendall']:+.2f}), against "
            f"{REAL_TO_REAL['spearman']} / {REAL_TO_REAL['kendall']} between two real datasets (DDAD against "
            f"nuScenes). Anchors that disagree in sign: {', '.join(a['disagree']) or 'none'}; absent here (unresolved, "
            f"the interval excluding a tenth of the real effect): {', '.join(a['absent']) or 'none'}.\n")
    else:
        lines.append("No anchor is resolved yet.\n")
    lines += ["Convention (the project's one): an effect is base - changed, **positive = the change helps**; the real "
              "effect is the source's before - after, the same way round. Median-scaled abs_rel over the six cameras "
              "unless the row's metric says otherwise, ± the 95 % t interval over worlds. The anchors file, with its "
              "tuning / test split, was committed before any run.\n"]
    yard = values.get("base", {}).get("yardsticks", {})
    lvl = values.get("base", {}).get("arms", {}).get(anchors.order[0], {})
    if lvl:
        m = [v["median.mean.abs_rel"] for v in lvl.values()]
        words = {"constant_reference": "a constant depth (the reference)", "flat_road_prior": "the flat-road prior"}
        ys = [f"{words.get(y, y)} {d['-1']['median.mean.abs_rel']:.3f}" for y, d in yard.items() if "-1" in d]
        lines.append(f"Level and yardsticks (median-scaled abs_rel over the six cameras): the base arm Mono2 "
                     f"{sum(m) / len(m):.3f} (mean over {len(m)} worlds; DDAD Mono2: 0.220, nuScenes 0.309); "
                     f"{'; '.join(ys) or 'no yardstick recorded'} (over the same worlds, no training).\n")
    lines += ["## The figures of agreement\n",
              "| anchors | measured | same sign (resolved) | Spearman ρ [bootstrap 95 %] | Kendall τ | mean max. "
              "rank violation |", "|---|---|---|---|---|---|",
              _figures_line(figs["tuning"], "tuning"), _figures_line(figs["test"], "test (read once, at the end)"),
              _figures_line(figs["all"], "all"),
              f"\nThe real-to-real ceiling: Spearman {REAL_TO_REAL['spearman']} / Kendall {REAL_TO_REAL['kendall']} "
              "(six surround methods, DDAD against nuScenes). The rank violation is SIMPLER's, in the real effects' "
              "units (abs_rel).\n", "![scatter](calibration/scatter.png)\n",
              f"## Every anchor ({POINT_WORDS['base']})\n",
              "| anchor | set | effect | source | real, before → after (before - after) | synthetic, base - changed | verdict | "
              "synthetic / real |",
              "|---|---|---|---|---|---|---|---|"]
    lines += [_row_cells(r) for r in base]
    unres = [r for r in base if r["n"] >= 2 and not r["resolved"]]
    if unres:
        lines += ["\n### Unresolved (neither agreeing nor disagreeing)\n"]
        lines += [f"- {r['name']}: {fmt_diff({'mean': r['mean'], 'ci95': r['half']})}; detectable at 80 % power: "
                  f"{r['mde']:.3f} (real {_fmt(r['real'])})" for r in unres]
    for point in ("x4", *DIAGNOSTICS):
        if point not in rows:
            continue
        pr = [r for r in rows[point] if r["n"] >= 2 and (point not in DIAGNOSTICS or r["set"] == "tuning")]
        lines += [f"\n## {POINT_WORDS[point]}\n", "| anchor | base point | this point | verdict here | from the base "
                  "point |", "|---|---|---|---|---|"]
        by = {r["name"]: r for r in base}

        def word(r: dict) -> str:
            return ("agrees" if r["agrees"] else "disagrees") if r["resolved"] else \
                ("absent" if r["absent"] else "unresolved")

        for r in pr:
            b = by[r["name"]]
            v = word(r) + ("" if r["resolved"] else f" (MDE {r['mde']:.3f})")
            moved = f"stays {word(r)}" if word(r) == word(b) else f"{word(b)} -> {word(r)}"
            lines.append(f"| {r['name']} | {fmt_diff({'mean': b['mean'], 'ci95': b['half']})} | "
                         f"{fmt_diff({'mean': r['mean'], 'ci95': r['half']})} ({r['n']} worlds) | {v} | {moved} |")
    times = values.get("base", {}).get("train_s", {})
    if times:
        tot = sum(sum(v) for v in times.values())
        lines.append(f"\nTraining time of the base point: {tot / 60:.1f} CPU-thread minutes over "
                     f"{sum(len(v) for v in times.values())} runs (one thread each, two at a time).\n")
    pre = DIR / "preface.md"
    if pre.is_file():
        from corelib.readfile import read_text_inside

        lines += ["", read_text_inside(pre, DIR, 1 << 20).rstrip("\n")]
    scatter(rows, (DIR if plot_dir is None else Path(plot_dir)) / "scatter.png")
    return "\n".join(lines) + "\n"


def main(argv: list[str] | None = None) -> int:
    from corelib.atomic import atomic_write_text

    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--collect", help="the calibration folder of the base point (mcdp calibrate --out)")
    p.add_argument("--point", action="append", default=[], help="NAME=FOLDER of another point (x4, live, sensor)")
    args = p.parse_args(argv)
    DIR.mkdir(parents=True, exist_ok=True)
    if args.collect:
        folders = {"base": Path(args.collect)}
        for item in args.point:
            name, _, folder = item.partition("=")
            if name not in POINT_WORDS or not folder:
                print(f"publish_calibration: --point {item!r}: NAME=FOLDER with NAME one of "
                      f"{', '.join(POINT_WORDS)}", file=sys.stderr)
                return 2
            folders[name] = Path(folder)
        atomic_write_text(VALUES, json.dumps(collect(folders), indent=1, sort_keys=True) + "\n")
    from republish import publish_one  # the page from its row of study.report.pages.PAGES, as `republish.py calibration`

    return publish_one("calibration", "publish_calibration")


if __name__ == "__main__":
    sys.exit(main())
