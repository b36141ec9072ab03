"""Where the spread of a paired difference between worlds comes from: test-sampling noise, training
heterogeneity, and outlying worlds (issue 47, rule 2; docs/results/lcon.md).

A sweep with one training seed per world gives one paired difference d_w per world (arm a minus arm b on the
same world, both scored at the same step). Its spread between worlds, V = var_w(d_w), has two parts:

- **test-sampling noise**: d_w is measured on the world's small test split. Resampling the split's sequences
  with replacement (the same draw for both arms: the difference is paired) and recomputing d_w each time gives
  its noise variance s_w^2 (`mcdp.per_sequence`: the evaluation's own pooling, exactly; times n / (n - 1) for
  n sequences, the bootstrap's known bias for a mean);
- **heterogeneity**: what is left, tau^2 = max(0, V - mean_w s_w^2): the worlds really differ, because training
  goes differently on each (more worlds help; larger test splits do not).

A world is flagged as **outlying** when its leave-one-out standardized residual exceeds `OUTLIER_Z`:
(d_w - mean of the others) / sqrt(tau^2_(-w) + s_w^2 + var of the others' mean).

`forest_plot` draws each world's d_w with its 95 % bootstrap interval and the pooled mean with its t interval.

Example::

    worlds = {w: (rec_a[w], rec_b[w]) for w in ...}      # {"seq": {"sum": [...], "n": [...]}} per arm
    split = variance_split(worlds, draws=2000)
    split["noise_share"], split["tau2"], split["outliers"]
"""
from __future__ import annotations

import math
from collections.abc import Mapping

import numpy as np

from mcdp.per_sequence import resampled
from study.stats.power import t_ppf

__all__ = ["world_bootstrap", "variance_split", "forest_plot", "OUTLIER_Z"]

#: a world whose leave-one-out standardized residual exceeds this is called outlying
OUTLIER_Z = 3.0


def world_bootstrap(rec_a: Mapping, rec_b: Mapping, draws: int = 2000, seed: int = 0) -> dict:
    """One world's paired difference d = figure(a) - figure(b) over its test sequences, and its bootstrap over
    them: {"d", "var", "lo", "hi", "n_seq", "draws"} (lo / hi: the 2.5 / 97.5 % percentiles). Both arms must
    hold the same sequences (they were scored on the same split)."""
    seqs = sorted(rec_a)
    if sorted(rec_b) != seqs:
        raise ValueError(f"the two arms were scored on different sequences ({len(seqs)} and {len(rec_b)})")
    d = resampled(rec_a, seqs) - resampled(rec_b, seqs)
    if len(seqs) < 2 or draws < 2:
        return {"d": d, "var": math.nan, "lo": math.nan, "hi": math.nan, "n_seq": len(seqs), "draws": 0}
    rng = np.random.default_rng(seed)
    idx = rng.integers(0, len(seqs), size=(draws, len(seqs)))
    ds = np.array([resampled(rec_a, [seqs[i] for i in row]) - resampled(rec_b, [seqs[i] for i in row])
                   for row in idx])
    ds = ds[np.isfinite(ds)]
    lo, hi = (np.percentile(ds, [2.5, 97.5]) if ds.size else (math.nan, math.nan))
    # the bootstrap variance of a mean of n sequences is (n - 1) / n of its sampling variance: undo that bias
    var = float(np.var(ds, ddof=1)) * len(seqs) / (len(seqs) - 1) if ds.size > 1 else math.nan
    return {"d": d, "var": var, "lo": float(lo), "hi": float(hi),
            "n_seq": len(seqs), "draws": int(ds.size)}


def _split(d: list[float], s2: list[float]) -> tuple[float, float, float]:
    """(V, mean noise variance, tau^2) of the per-world differences and their noise variances."""
    n = len(d)
    if n < 2:
        return math.nan, math.nan, math.nan
    m = math.fsum(d) / n
    v = math.fsum((x - m) ** 2 for x in d) / (n - 1)
    noise = math.fsum(s2) / n
    return v, noise, max(0.0, v - noise)


def variance_split(worlds: Mapping[object, tuple[Mapping, Mapping]], draws: int = 2000, seed: int = 0) -> dict:
    """The between-world spread of a paired difference split into test-sampling noise and heterogeneity.

    ``worlds`` maps a world id to its two arms' per-sequence records of one scaling and region (arm a, arm b).
    Returns {"per_world": {w: world_bootstrap}, "n_worlds", "mean", "ci95", "var_between" V, "var_noise" (the
    mean s_w^2), "tau2", "noise_share" (var_noise / V, may exceed 1 when the worlds agree better than their
    noise), "outliers": [(w, z)], "z": {w: z}}. Each world's bootstrap draws from its own seed (``seed`` + its
    position), so the result does not depend on the order of the other worlds."""
    per = {w: world_bootstrap(a, b, draws, seed + k) for k, (w, (a, b)) in enumerate(worlds.items())}
    ids = [w for w in per if math.isfinite(per[w]["d"]) and math.isfinite(per[w]["var"])]
    d = [per[w]["d"] for w in ids]
    s2 = [per[w]["var"] for w in ids]
    n = len(d)
    v, noise, tau2 = _split(d, s2)
    mean = math.fsum(d) / n if n else math.nan
    ci95 = t_ppf(0.975, n - 1) * math.sqrt(v / n) if n >= 2 else math.nan
    z: dict = {}
    if n >= 4:
        for i, w in enumerate(ids):
            rest_d, rest_s2 = d[:i] + d[i + 1:], s2[:i] + s2[i + 1:]
            v_r, _, tau2_r = _split(rest_d, rest_s2)
            m_r = math.fsum(rest_d) / len(rest_d)
            z[w] = (d[i] - m_r) / math.sqrt(tau2_r + s2[i] + v_r / len(rest_d))
    outliers = [(w, zw) for w, zw in z.items() if abs(zw) > OUTLIER_Z]
    return {"per_world": per, "n_worlds": n, "mean": mean, "ci95": ci95, "var_between": v, "var_noise": noise,
            "tau2": tau2, "noise_share": noise / v if v > 0 else math.nan, "outliers": outliers, "z": z}


def forest_plot(split: dict, path, title: str, hl: tuple[float, float, float] | None = None,
                xlabel: str = "paired difference (positive = helps)") -> None:
    """Each world's difference with its 95 % bootstrap interval over its test sequences, the pooled mean with its
    t interval over worlds, and (``hl``: estimate, lo, hi) the Hodges-Lehmann estimate with its interval; PNG."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    per = split["per_world"]
    ids = list(per)
    rows = len(ids) + (2 if hl else 1)
    fig, ax = plt.subplots(figsize=(6.4, 0.9 + 0.22 * rows))
    for k, w in enumerate(ids):
        r = per[w]
        y = rows - 1 - k
        ax.plot([r["lo"], r["hi"]], [y, y], color="0.45", lw=1)
        flag = any(w == o for o, _ in split["outliers"])
        ax.plot(r["d"], y, "s", color="tab:red" if flag else "0.15", ms=4)
    labels = [f"world {w}" for w in ids]
    m, h = split["mean"], split["ci95"]
    ax.errorbar([m], [1 if hl else 0], xerr=[[h], [h]], fmt="D", color="tab:blue", ms=6, capsize=3)
    labels.append(f"mean ± 95 % ({split['n_worlds']} worlds)")
    if hl:
        est, lo, hi = hl
        ax.errorbar([est], [0], xerr=[[est - lo], [hi - est]], fmt="o", color="tab:green", ms=6, capsize=3)
        labels.append("Hodges-Lehmann")
    ax.set_yticks(range(rows))
    ax.set_yticklabels(list(reversed(labels)), fontsize=6)
    ax.axvline(0.0, color="k", lw=0.8)
    ax.set_xlabel(xlabel, fontsize=8)
    ax.set_title(title, fontsize=8)
    ax.tick_params(axis="x", labelsize=7)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
