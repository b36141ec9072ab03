"""The calibration's reading: each anchor's synthetic effect over worlds beside its real one, and the figures of
agreement (issue 57; the page docs/results/calibration.md, `scripts/publish_calibration.py`).

- An anchor's synthetic effect is a paired difference over worlds, base - changed: **positive = the change helps**,
  the project's one sign convention (docs/DESIGN.md, "Conventions"); its real effect is the source's before - after,
  the same way round. Read from each arm's sweep folder (`arm_values`), with its 95 % t interval and its MDE at
  80 % power. ``read: side_vs_front`` is one arm's front camera minus its four side cameras' mean (negative: the
  sides are worse); ``read: metric_vs_median`` one arm's median-scaled figure minus its metric (unscaled) one.
- Resolved: the interval excludes 0. Agrees: resolved with the real effect's sign. Unresolved anchors count neither
  way and are listed apart with their MDE; one whose interval also excludes a tenth of its real effect is said to be
  *absent* here (the benchmark would have seen it at a tenth of its real size), a disagreement in size, not in sign.
- Agreement: the same-sign rate over resolved anchors with its Wilson 95 % interval (scipy's ``binomtest``);
  Spearman and Kendall between real and synthetic effects over every measured anchor, with percentile bootstrap
  intervals over anchors; each anchor's synthetic / real size ratio; the mean maximum rank violation of SIMPLER
  (`simpler_env/utils/metrics.py`: for each anchor, the largest real gap to another anchor whose order the
  benchmark inverts; averaged).

Example::

    anchors = load_anchors("configs/calibration/anchors.yaml")
    values = {arm: arm_values(Path("sweeps/calibration") / arm, columns(anchors), anchors.arms[arm].method)
              for arm in anchors.arms}
    rows = read_anchors(anchors, values)
    print(agreement(rows))
"""
from __future__ import annotations

import csv
import io
import math
from pathlib import Path

import numpy as np

from study.report.sections.anchors import Anchor, Anchors

#: the sweep's column names (results.csv) this module reads
SIDE_CAMERAS = ("CAM_FRONT_RIGHT", "CAM_BACK_RIGHT", "CAM_BACK_LEFT", "CAM_FRONT_LEFT")
FRONT = "CAM_FRONT"
#: results.csv of one arm's sweep is read up to this many bytes
MAX_CSV_BYTES = 64 << 20
#: bootstrap resamples of the rank statistics, and their seed (fixed: the page rebuilds byte-identically)
BOOT, BOOT_SEED = 2000, 0


def columns(anchors: Anchors) -> set[str]:
    """Every results.csv column an anchor of ``anchors`` reads."""
    cols = {anchors.metric_of(a) for a in anchors.anchors}
    cols |= {f"median.camera.{c}.abs_rel" for c in (FRONT, *SIDE_CAMERAS)}
    cols |= {"none.mean.abs_rel", "median.mean.abs_rel"}
    return cols


def arm_values(folder: Path, columns: set[str], method: str) -> dict[int, dict[str, float]]:
    """{world: {column: value}} of one arm's sweep folder: its results.csv's as-trained rows of ``method`` that
    finished ("ok"), or a yardstick's (``constant_reference``, ``flat_road_prior``) row over every world as world -1."""
    from corelib.readfile import read_text_inside

    text = read_text_inside(Path(folder) / "results.csv", Path(folder), MAX_CSV_BYTES)
    out: dict[int, dict[str, float]] = {}
    for row in csv.DictReader(io.StringIO(text)):
        if row.get("method") != method:
            continue
        if row.get("status") == "reference" and not row.get("world"):  # a yardstick's row: over every world
            world = -1
        elif row.get("variant", "trained") != "trained" or row.get("status") != "ok":
            continue
        else:
            try:
                world = int(row["world"])
            except (KeyError, ValueError):
                raise ValueError(f"{folder}/results.csv: a row without an integer world") from None
        vals = {}
        for c in columns:
            try:
                v = float(row.get(c, "nan") or "nan")
            except ValueError:
                raise ValueError(f"{folder}/results.csv: column {c!r} is not a number in world {world}") from None
            vals[c] = v
        out[world] = vals
    return out


def arm_train_seconds(folder: Path, method: str) -> list[float]:
    """The training seconds of one arm's runs of ``method`` (results.csv's as-trained rows that have them): what a
    page states its runs cost."""
    from corelib.readfile import read_text_inside

    text = read_text_inside(Path(folder) / "results.csv", Path(folder), MAX_CSV_BYTES)
    return [float(r["train_s"]) for r in csv.DictReader(io.StringIO(text))
            if r.get("method") == method and r.get("variant") == "trained" and r.get("train_s")]


def _one_arm(vals: dict[str, float], read: str, metric: str) -> float:
    if read == "side_vs_front":  # base = the front camera, changed = the side cameras: base - changed
        return float(vals[f"median.camera.{FRONT}.abs_rel"]
                     - np.mean([vals[f"median.camera.{c}.abs_rel"] for c in SIDE_CAMERAS]))
    if read == "metric_vs_median":  # base = median-scaled, changed = metric
        return vals["median.mean.abs_rel"] - vals["none.mean.abs_rel"]
    return vals[metric]


def paired(diffs: list[float]) -> dict:
    """Mean, sd, 95 % t interval (``half``), p (two-sided t), MDE at 80 % power of paired differences, one per world:
    the project's one reading over worlds (`study.stats.design.reading_over_worlds`), without an equivalence bound."""
    from study.stats.design import reading_over_worlds

    d = [float(x) for x in diffs]
    n = len(d)
    out = {"n": n, "mean": float(np.mean(d)) if n else float("nan"), "diffs": d, "sd": float("nan"),
           "half": float("nan"), "p": float("nan"), "mde": float("nan")}
    if n < 2:
        return out
    r = reading_over_worlds({w: [x] for w, x in enumerate(d)}, {})
    out.update(mean=float(r["mean"]), sd=float(np.std(d, ddof=1)), half=float(r["ci95"]), p=float(r["p"]),
               mde=float(r["mde80"]))
    return out


def read_anchor(anchors: Anchors, a: Anchor, values: dict[str, dict[int, dict[str, float]]]) -> dict:
    """One anchor's row: its real effect, its synthetic paired difference over the worlds both arms have, and
    whether it is resolved and agrees (module docstring). An arm not run yet: ``n`` 0."""
    metric = anchors.metric_of(a)
    base, changed = values.get(a.base, {}), values.get(a.changed, {})
    worlds = sorted(set(base) & set(changed))
    if a.read == "arms":
        diffs = [base[w][metric] - changed[w][metric] for w in worlds]  # positive = the change helps
    else:
        diffs = [_one_arm(base[w], a.read, metric) for w in worlds]
    diffs = [x for x in diffs if math.isfinite(x)]
    st = paired(diffs)
    resolved = st["n"] >= 2 and math.isfinite(st["half"]) and abs(st["mean"]) > st["half"]
    syn_sign = 0 if not resolved else (1 if st["mean"] > 0 else -1)
    real = a.real.before - a.real.after  # positive = the change helps, as the synthetic effect
    return {"name": a.name, "set": a.set, "effect": a.effect, "metric": metric, "read": a.read,
            "base": a.base, "changed": a.changed, "worlds": worlds,
            "source": f"{a.source.paper}, {a.source.table}, {a.source.dataset}",
            "real_before": a.real.before, "real_after": a.real.after, "real": real,
            "also": [{"source": f"{x.paper}, {x.table}, {x.dataset}", "real": x.before - x.after} for x in a.also],
            **{k: st[k] for k in ("n", "mean", "sd", "half", "p", "mde", "diffs")},
            "resolved": bool(resolved), "agrees": bool(resolved and syn_sign == (1 if real > 0 else -1)),
            # unresolved, and its interval excludes a tenth of the real effect: absent here, not merely unseen
            "absent": bool(not resolved and st["n"] >= 2 and math.isfinite(st["half"])
                           and abs(real / 10 - st["mean"]) > st["half"]),
            "ratio": st["mean"] / real if st["n"] else float("nan")}


def read_anchors(anchors: Anchors, values: dict[str, dict[int, dict[str, float]]]) -> list[dict]:
    return [read_anchor(anchors, a, values) for a in anchors.anchors]


def wilson(k: int, n: int) -> tuple[float, float]:
    """The Wilson score 95 % interval of k successes in n (scipy.stats.binomtest's)."""
    from scipy import stats

    if n == 0:
        return float("nan"), float("nan")
    ci = stats.binomtest(k, n).proportion_ci(confidence_level=0.95, method="wilson")
    return float(ci.low), float(ci.high)


def rank_stats(real: list[float], syn: list[float], boot: int = BOOT, seed: int = BOOT_SEED) -> dict:
    """Spearman's rho and Kendall's tau (scipy) between real and synthetic effects, with percentile bootstrap 95 %
    intervals over the items (resamples with fewer than 3 distinct items, or a constant side, are skipped)."""
    from scipy import stats

    r, s = np.asarray(real, float), np.asarray(syn, float)
    n = r.size
    out = {"n": int(n), "spearman": float("nan"), "kendall": float("nan"), "spearman_ci": [float("nan")] * 2,
           "kendall_ci": [float("nan")] * 2}
    if n < 3:
        return out
    out["spearman"] = float(stats.spearmanr(r, s).statistic)
    out["kendall"] = float(stats.kendalltau(r, s).statistic)
    rng = np.random.default_rng(seed)
    sp, kt = [], []
    for _ in range(boot):
        i = rng.integers(0, n, n)
        if len(set(i.tolist())) < 3 or np.ptp(r[i]) == 0 or np.ptp(s[i]) == 0:
            continue
        sp.append(stats.spearmanr(r[i], s[i]).statistic)
        kt.append(stats.kendalltau(r[i], s[i]).statistic)
    sp, kt = np.asarray(sp, float), np.asarray(kt, float)
    sp, kt = sp[np.isfinite(sp)], kt[np.isfinite(kt)]
    if sp.size:
        out["spearman_ci"] = [float(x) for x in np.percentile(sp, [2.5, 97.5])]
    if kt.size:
        out["kendall_ci"] = [float(x) for x in np.percentile(kt, [2.5, 97.5])]
    return out


def mmrv(real: list[float], syn: list[float]) -> float:
    """SIMPLER's mean maximum rank violation: for each item i, max over j of |real_i - real_j| where the benchmark
    orders i and j the other way round from the real data (ties count as no violation), averaged over items."""
    r, s = np.asarray(real, float), np.asarray(syn, float)
    n = r.size
    if n < 2:
        return float("nan")
    worst = []
    for i in range(n):
        v = [abs(r[i] - r[j]) for j in range(n) if j != i and (r[i] < r[j]) != (s[i] < s[j])
             and r[i] != r[j] and s[i] != s[j]]
        worst.append(max(v) if v else 0.0)
    return float(np.mean(worst))


def agreement(rows: list[dict], which: str | None = None) -> dict:
    """The calibration figures over ``rows`` (those of one set, or all when ``which`` is None)."""
    rows = [r for r in rows if (which is None or r["set"] == which) and r["n"] >= 2]
    resolved = [r for r in rows if r["resolved"]]
    k = sum(r["agrees"] for r in resolved)
    lo, hi = wilson(k, len(resolved))
    real = [r["real"] for r in rows]
    syn = [r["mean"] for r in rows]
    return {"measured": len(rows), "resolved": len(resolved), "agree": k,
            "rate": k / len(resolved) if resolved else float("nan"), "wilson": [lo, hi],
            "ranks": rank_stats(real, syn), "mmrv": mmrv(real, syn),
            "disagree": [r["name"] for r in resolved if not r["agrees"]],
            "absent": [r["name"] for r in rows if r.get("absent")],
            "unresolved": [r["name"] for r in rows if not r["resolved"]]}


#: the second scale point reruns every anchor that disagrees or is unresolved at the first, plus this many that
#: agree (those with the largest real effects), at most `SCALE_MAX_ARMS` arms, in the anchors file's order
SCALE_AGREEING, SCALE_MAX_ARMS = 3, 8


def scale_point_arms(anchors: Anchors, rows: list[dict]) -> list[str]:
    """The arms the second scale point trains, by the rule stated before the runs (issue 57, item 4): every anchor
    that disagrees or is unresolved at the first point, plus the `SCALE_AGREEING` agreeing anchors with the largest
    real effects; their arms in the file's order, at most `SCALE_MAX_ARMS` (the rest is said not run). It returns
    arms only: the verdicts of the test anchors are not shown by it."""
    measured = [r for r in rows if r["n"] >= 2]
    picked = [r for r in measured if not r["agrees"]]
    agreeing = sorted((r for r in measured if r["agrees"]), key=lambda r: -abs(r["real"]))
    picked += agreeing[:SCALE_AGREEING]
    arms = {a for r in picked for a in (r["base"], r["changed"])}
    return [a for a in anchors.order if a in arms][:SCALE_MAX_ARMS]


def main(argv: list[str] | None = None) -> int:
    """``python -m study.report.sections.calibration scale-arms ANCHORS FOLDER``: the second scale point's arms, comma-separated."""
    import sys

    from study.report.sections.anchors import load_anchors

    args = list(sys.argv[1:] if argv is None else argv)
    if len(args) != 3 or args[0] != "scale-arms":
        print("usage: python -m study.report.sections.calibration scale-arms ANCHORS FOLDER", file=sys.stderr)
        return 2
    anchors = load_anchors(args[1])
    cols = columns(anchors)
    values = {}
    for name, arm in anchors.arms.items():
        if (Path(args[2]) / name / "results.csv").is_file():
            values[name] = arm_values(Path(args[2]) / name, cols, arm.method)
    print(",".join(scale_point_arms(anchors, read_anchors(anchors, values))))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
