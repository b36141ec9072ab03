"""How many worlds a comparison needs, when a sweep may stop early, and a reading over worlds that one
outlying world cannot carry alone (issue 47; docs/results/lcon.md).

- `worlds_needed`: the fewest worlds (one paired difference each) for which a two-sided paired t test at
  ``alpha`` detects ``effect`` with ``power``, from the spread ``sd`` of the per-world differences: the
  smallest n with (t_{1-alpha/2, n-1} + t_{power, n-1}) * sd / sqrt(n) <= effect, the same shifted-t formula
  as `study.stats.power.mde`, so the two agree: mde(sd / sqrt(n), n - 1) <= effect. (34 worlds for effect / sd = 0.5
  and 10 for 1, as G*Power's exact noncentral t gives.)
- `obf_bounds`: the O'Brien-Fleming group-sequential boundaries for two looks, at information fraction ``t1``
  and at the end: |Z| >= c / sqrt(t_k), with c chosen so the two-sided type I error over both looks is
  ``alpha`` (c = 1.977, bounds 2.796 and 1.977 at t1 = 1/2, alpha = 0.05: Jennison & Turnbull, Table 2.3), and
  `obf_inflation`, the factor R by which the fixed design's number of worlds grows for the same power (1.008 for
  alpha = 0.05, power 0.8: their Table 2.4). The bivariate normal probabilities are one-dimensional integrals
  (Simpson's rule, 4000 panels: about 1e-12).
- `sequential_look`: one look of a sweep: the t statistic of the worlds so far against the look's boundary,
  as its nominal two-sided level (a z boundary b is the nominal level 2 (1 - Phi(b)), and the t test at
  that level with worlds - 1 degrees of freedom: the usual small-sample reading of a z boundary).
- `reading_over_worlds`: the one reading of a paired difference over worlds that every page gives (lcon,
  primary, sensor): `study.stats.power.nested` (clustered by world), the two-sided t p-value (`t_p_two_sided`), the MDE
  at 80 % power, TOST against the plan's ``delta`` and the signed-rank reading of the world means.
- `signed_rank`: Wilcoxon's signed-rank test over worlds (exact without ties or zeros and n <= 50, else the
  normal approximation with the tie correction: scipy.stats.wilcoxon's defaults) with the Hodges-Lehmann
  estimate and its confidence interval (the Walsh averages' order statistics at the exact critical value).

Pure Python (`math` and `study.stats.power`'s t distribution), as `study.stats.power`; tests compare with scipy where it
is installed and with the published tables.

Example::

    worlds_needed(sd=0.02, effect=0.005)            # 128 worlds
    c1, c2 = obf_bounds(0.5)                          # (2.796..., 1.977...)
    signed_rank([0.01, 0.03, -0.002, 0.02, 0.015])   # {"p": 0.125, "hl": 0.015, "ci": (lo, hi), ...}
"""
from __future__ import annotations

import math
from collections.abc import Iterable, Mapping, Sequence

from study.stats.power import mde, nested, t_cdf, t_ppf, tost

__all__ = ["worlds_needed", "obf_bounds", "obf_inflation", "sequential_look", "signed_rank", "norm_cdf",
           "norm_ppf", "t_p_two_sided", "reading_over_worlds"]

_PANELS = 4000  # Simpson panels of the bivariate normal integrals (even)


def norm_cdf(x: float) -> float:
    return 0.5 * math.erfc(-x / math.sqrt(2.0))


def norm_ppf(p: float) -> float:
    """The standard normal quantile (the t quantile at infinite degrees of freedom)."""
    return t_ppf(p, math.inf)


def _pdf(x: float) -> float:
    return math.exp(-0.5 * x * x) / math.sqrt(2.0 * math.pi)


def worlds_needed(sd: float, effect: float, power: float = 0.8, alpha: float = 0.05, most: int = 100_000) -> int:
    """The fewest worlds n >= 2 with (t_{1-alpha/2, n-1} + t_{power, n-1}) * sd / sqrt(n) <= effect (a two-sided
    paired t test over worlds). ValueError for sd < 0, effect <= 0, or a level outside (0, 1); ``most`` + 1 when
    even ``most`` worlds do not suffice."""
    if not (math.isfinite(sd) and sd >= 0.0):
        raise ValueError(f"sd must be finite and >= 0, not {sd!r}")
    if not (math.isfinite(effect) and effect > 0.0):
        raise ValueError(f"effect must be finite and > 0, not {effect!r}")
    for name, v in (("power", power), ("alpha", alpha)):
        if not 0.0 < v < 1.0:
            raise ValueError(f"{name} must lie in (0, 1), not {v!r}")

    def detects(n: int) -> bool:
        return (t_ppf(1.0 - alpha / 2.0, n - 1) + t_ppf(power, n - 1)) * sd / math.sqrt(n) <= effect

    lo, hi = 2, 2
    while not detects(hi):  # the left side falls with n: double, then bisect
        if hi > most:
            return most + 1
        lo, hi = hi + 1, hi * 2
    while lo < hi:
        mid = (lo + hi) // 2
        lo, hi = (lo, mid) if detects(mid) else (mid + 1, hi)
    return lo


def _simpson(f, a: float, b: float, panels: int = _PANELS) -> float:
    if b <= a:
        return 0.0
    h = (b - a) / panels
    s = f(a) + f(b)
    s += 4.0 * math.fsum(f(a + (2 * k - 1) * h) for k in range(1, panels // 2 + 1))
    s += 2.0 * math.fsum(f(a + 2 * k * h) for k in range(1, panels // 2))
    return s * h / 3.0


def _continue_prob(c1: float, c2: float, t1: float, theta: float) -> float:
    """P(|Z1| < c1 and |Z2| < c2) for the two looks' z statistics of a Brownian score with drift ``theta`` (Z_k
    has mean theta * sqrt(t_k)): Z2 | Z1 = z ~ N(z sqrt(t1) + theta (1 - t1), 1 - t1)."""
    m1, s2 = theta * math.sqrt(t1), math.sqrt(1.0 - t1)

    def inner(z: float) -> float:
        mu2 = z * math.sqrt(t1) + theta * (1.0 - t1)
        return _pdf(z - m1) * (norm_cdf((c2 - mu2) / s2) - norm_cdf((-c2 - mu2) / s2))

    return _simpson(inner, -c1, c1)


def _bisect(f, lo: float, hi: float, it: int = 200) -> float:
    """A root of the increasing f on [lo, hi]."""
    for _ in range(it):
        mid = 0.5 * (lo + hi)
        if f(mid) < 0.0:
            lo = mid
        else:
            hi = mid
    return 0.5 * (lo + hi)


def _check_t1(t1: float) -> None:
    if not 0.0 < t1 < 1.0:
        raise ValueError(f"the first look's information fraction must lie in (0, 1), not {t1!r}")


def obf_bounds(t1: float = 0.5, alpha: float = 0.05) -> tuple[float, float]:
    """O'Brien-Fleming z boundaries (look at fraction ``t1``, look at the end) for a two-sided test at ``alpha``:
    (c / sqrt(t1), c) with P(reject at either look | no effect) = alpha."""
    _check_t1(t1)
    if not 0.0 < alpha < 1.0:
        raise ValueError(f"alpha must lie in (0, 1), not {alpha!r}")
    c = _bisect(lambda c: (1.0 - _continue_prob(c / math.sqrt(t1), c, t1, 0.0)) * -1.0 + alpha, 0.5, 10.0)
    return c / math.sqrt(t1), c


def obf_inflation(t1: float = 0.5, alpha: float = 0.05, power: float = 0.8) -> float:
    """R = (drift the two-look design needs for ``power`` / drift the fixed design needs)^2: the factor on the
    fixed design's number of worlds."""
    c1, c2 = obf_bounds(t1, alpha)
    theta = _bisect(lambda th: (1.0 - _continue_prob(c1, c2, t1, th)) - power, 0.0, 20.0)
    fixed = norm_ppf(1.0 - alpha / 2.0) + norm_ppf(power)
    return (theta / fixed) ** 2


def sequential_look(diffs: Sequence[float], planned: int, final: bool, t1: float = 0.5,
                    alpha: float = 0.05) -> dict:
    """One look of the two-look design over the per-world ``diffs`` so far (``planned`` worlds in all; the first
    look at ``t1`` of them, ``final`` for the last look): {"n", "mean", "t", "df", "p", "bound_z", "nominal",
    "stop"}: ``stop`` when the two-sided t test's p is at most the look's nominal level."""
    c1, c2 = obf_bounds(t1, alpha)
    bound = c2 if final else c1
    nominal = 2.0 * (1.0 - norm_cdf(bound))
    x = [float(v) for v in diffs if math.isfinite(v)]
    n = len(x)
    out = {"n": n, "planned": planned, "bound_z": bound, "nominal": nominal, "final": final}
    if n < 2:
        return {**out, "mean": math.nan, "t": math.nan, "df": max(n - 1, 0), "p": math.nan, "stop": False}
    mean = math.fsum(x) / n
    sd = math.sqrt(math.fsum((v - mean) ** 2 for v in x) / (n - 1))
    t = mean / (sd / math.sqrt(n)) if sd > 0 else math.copysign(math.inf, mean) if mean else 0.0
    p = t_p_two_sided(t, n - 1)
    return {**out, "mean": mean, "t": t, "df": n - 1, "p": p, "stop": p <= nominal}


def t_p_two_sided(t: float, df: float) -> float:
    """The two-sided p-value of a t statistic with ``df`` degrees of freedom: 2 t_cdf(-|t|) (no 1 - x
    cancellation); 0 for an infinite t (no spread, a mean off zero), NaN for NaN or df < 1."""
    if math.isnan(t) or not df >= 1:
        return math.nan
    return 2.0 * t_cdf(-abs(t), df) if math.isfinite(t) else 0.0


def reading_over_worlds(diffs: Mapping[object, Iterable[float]], plan: Mapping) -> dict:
    """The one reading of a paired difference over worlds (every page's: `study.report.sections.lcon`, `study.report.sections.primary`,
    `study.report.sections.sensor`). ``diffs`` maps a world to its seeds' paired differences (`study.stats.power.nested`); ``plan`` is
    the sweep's pre-stated analysis (its ``delta``, the equivalence bound; absent: no TOST).

    Returns `study.stats.power.nested`'s dict (mean, se, df, ci95, the variance split, ``values``: the per-world rows)
    with ``p`` (two-sided t, `t_p_two_sided`), ``mde80`` (80 % power), ``tost`` (against ``plan["delta"]``:
    {"p", "equivalent", ...}; p NaN and not equivalent with fewer than 2 worlds or no delta; ``delta``: the bound)
    and ``rank``
    (`signed_rank` of the world means: Wilcoxon p, Hodges-Lehmann and its interval)."""
    n = nested(diffs)
    enough = n["n_worlds"] >= 2
    n["p"] = t_p_two_sided(n["mean"] / n["se"], n["df"]) if enough and n["se"] > 0 else math.nan
    n["mde80"] = mde(n["se"], n["df"]) if enough else math.nan
    delta = plan.get("delta")
    n["tost"] = tost(n["mean"], n["se"], n["df"], float(delta)) if enough and delta else \
        {"p": math.nan, "equivalent": False}
    n["delta"] = delta
    means: dict = {}
    for w, v in n["values"]:
        means.setdefault(w, []).append(v)
    n["rank"] = signed_rank([math.fsum(v) / len(v) for v in means.values()])
    return n


def _signed_rank_counts(n: int) -> list[int]:
    """counts[w] = the number of sign patterns of ranks 1..n whose positive ranks sum to w (exact null of W+)."""
    counts = [1]
    for r in range(1, n + 1):
        new = counts + [0] * r
        for w, c in enumerate(counts):
            new[w + r] += c
        counts = new
    return counts


def _ranks(values: list[float]) -> list[float]:
    """Average ranks (1-based) of the values."""
    order = sorted(range(len(values)), key=lambda i: values[i])
    ranks = [0.0] * len(values)
    i = 0
    while i < len(order):
        j = i
        while j + 1 < len(order) and values[order[j + 1]] == values[order[i]]:
            j += 1
        for k in range(i, j + 1):
            ranks[order[k]] = (i + j) / 2.0 + 1.0
        i = j + 1
    return ranks


def signed_rank(diffs: Sequence[float], alpha: float = 0.05) -> dict:
    """Wilcoxon's signed-rank test of the per-world differences against 0, with the Hodges-Lehmann estimate (the
    median of the Walsh averages) and its 1 - alpha interval.

    Returns {"n", "w_plus", "p", "method" ("exact" | "approx"), "hl", "ci": (lo, hi), "ci_level"}: zeros are
    dropped (Wilcoxon's rule, scipy's default), ties get average ranks; exact for n <= 50 without ties or zeros,
    else the normal approximation with the tie correction and no continuity correction (scipy's defaults). The
    interval is [A_(k+1), A_(M-k)] of the M = n (n + 1) / 2 sorted Walsh averages (1-based), k the largest count with
    P(W+ <= k) <= alpha / 2 (exact null; its level is at least 1 - alpha, and ``ci_level`` says the exact one);
    with the normal approximation k comes from the normal quantile. NaN entries when fewer than 2 values."""
    x = [float(v) for v in diffs if math.isfinite(v)]
    nan = math.nan
    if len(x) < 2:
        return {"n": len(x), "w_plus": nan, "p": nan, "method": "none", "hl": nan, "ci": (nan, nan), "ci_level": nan}
    walsh = sorted((x[i] + x[j]) / 2.0 for i in range(len(x)) for j in range(i, len(x)))
    m = len(walsh)
    hl = walsh[m // 2] if m % 2 else 0.5 * (walsh[m // 2 - 1] + walsh[m // 2])
    nz = [v for v in x if v != 0.0]
    n = len(nz)
    ranks = _ranks([abs(v) for v in nz])
    w_plus = math.fsum(r for r, v in zip(ranks, nz) if v > 0)
    ties = len(set(abs(v) for v in nz)) < n
    total = n * (n + 1) / 2.0
    exact = n <= 50 and not ties and n == len(x)
    if n == 0:
        p = 1.0
    elif exact:
        counts = _signed_rank_counts(n)
        whole = float(2 ** n)
        w = int(round(w_plus))
        lower = math.fsum(counts[: w + 1]) / whole
        upper = math.fsum(counts[w:]) / whole
        p = min(1.0, 2.0 * min(lower, upper))
    else:
        mean = total / 2.0
        tie_term = 0.0
        for v in set(ranks):
            t = ranks.count(v)
            tie_term += t ** 3 - t
        var = n * (n + 1) * (2 * n + 1) / 24.0 - tie_term / 48.0
        z = (w_plus - mean) / math.sqrt(var) if var > 0 else 0.0
        p = min(1.0, 2.0 * norm_cdf(-abs(z)))
    # the interval: the exact null of the n values (no zeros dropped: shifts move every value off zero)
    nn = len(x)
    if nn <= 50:
        counts = _signed_rank_counts(nn)
        whole = float(2 ** nn)
        cum, k = 0.0, -1
        for w, c in enumerate(counts):
            if cum + c / whole > alpha / 2.0:
                break
            cum += c / whole
            k = w
        level = 1.0 - 2.0 * cum
    else:
        k = int(math.floor(nn * (nn + 1) / 4.0 - norm_ppf(1.0 - alpha / 2.0)
                           * math.sqrt(nn * (nn + 1) * (2 * nn + 1) / 24.0))) - 1
        level = 1.0 - alpha
    k = max(k, 0)   # A_(k+1) and A_(M-k), 1-based: at most k Walsh averages lie beyond either end
    ci = (walsh[k], walsh[m - k - 1]) if k <= m - k - 1 else (walsh[0], walsh[-1])
    return {"n": len(x), "w_plus": w_plus, "p": p, "method": "exact" if exact else "approx", "hl": hl,
            "ci": ci, "ci_level": level}
