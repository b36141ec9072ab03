"""Honest intervals, power and equivalence for paired comparisons in a sweep of worlds x seeds.

A sweep trains its runs on W worlds (data seeds) and S training seeds per world, the seeds nested in the worlds
(each world has its own S seeds). A comparison of two methods then gives one paired difference d[w][s] per
(world, seed). The seeds of a world share that world, so the W * S differences are not independent: the honest
interval for the mean difference is clustered by world (`nested`: the t interval over the W world means), and
the one-way random-effects model d_ws = mu + a_w + e_ws says how much of the spread comes from the worlds and how
much from the seeds (more worlds help against the first, more seeds only against the second).

Beyond "does the interval exclude 0", a report needs to say what a null result means: `mde` is the smallest
effect the design detects with a given power, `tost` the two one-sided tests of equivalence (the effect lies
within +-delta), and `verdict` the one phrase a report prints for a comparison.

Everything here is pure Python (`math` only; no numpy, no scipy): `t_cdf` and `t_ppf` are the Student t
distribution's CDF and quantile, computed from the regularized incomplete beta function (continued fraction,
modified Lentz) and a Newton iteration: about 1e-13 relative (lower tail of the CDF, and the quantile) for df in
[1, 1e4]. For larger df the accuracy falls roughly as df * 3e-17 (1e-11 at df = 1e6, 3e-8 at df = 1e9: the
continued fraction needs x = df / (df + t^2) closer to 1 than a double holds), and above df = 1e10 the normal,
closer than that, stands in; a sweep's df (worlds - 1) is far below either.

Example::

    nest = nested({0: [0.011, 0.007], 1: [-0.002, 0.004], 2: [0.009, 0.013]})
    nest["mean"], nest["ci95"], nest["differs"]      # mean of the world means, 95 % half-width, -1 / 0 / +1
    verdict(nest, delta=0.03)                         # 'equivalent to 0 within ±0.03 (TOST p = 0.009)'
    verdict(nest, delta=0.01)                         # 'inconclusive: neither beyond the interval nor ...'
"""
from __future__ import annotations

import math
from collections.abc import Callable, Iterable, Mapping

__all__ = ["t_cdf", "t_ppf", "T975", "t_halfwidth", "nested", "mde", "tost", "verdict"]

_EPS = 1e-16        # relative convergence of the continued fraction
_TINY = 1e-300      # the modified Lentz algorithm's stand-in for 0
_MAXIT = 100_000    # continued-fraction terms at most (about sqrt(df) are needed for large df)
_LN_SQRT_PI = 0.5 * math.log(math.pi)
_SQRT2 = math.sqrt(2.0)
_NORMAL_DF = 1e10   # above it the normal is closer to the t distribution than the continued fraction's rounding
_BIG_T = 1e150      # beyond |t| = 1e150 the t CDF is 0 or 1 to double precision (df >= 1: tail < 1e-150)


def _ln_gamma_ratio(a: float) -> float:
    """ln Gamma(a + 1/2) - ln Gamma(a) for a > 0, without the cancellation of two large lgamma values."""
    if a < 50.0:
        return math.lgamma(a + 0.5) - math.lgamma(a)

    def s(z: float) -> float:  # the Stirling series' tail: ln Gamma(z) - ((z - 1/2) ln z - z + ln sqrt(2 pi))
        z2 = z * z
        return (1.0 / 12.0 - (1.0 / 360.0 - (1.0 / 1260.0 - (1.0 / 1680.0 - 1.0 / (1188.0 * z2)) / z2) / z2) / z2) / z

    # ((a) ln(a + 1/2) - (a + 1/2)) - ((a - 1/2) ln a - a) = a ln(1 + 1/(2a)) + ln(a) / 2 - 1/2
    return a * math.log1p(0.5 / a) + 0.5 * math.log(a) - 0.5 + s(a + 0.5) - s(a)


def _betacf(a: float, b: float, x: float) -> float:
    """The continued fraction of the regularized incomplete beta function I_x(a, b) (Numerical Recipes `betacf`,
    modified Lentz); it converges fast for x < (a + 1) / (a + b + 2)."""
    qab, qap, qam = a + b, a + 1.0, a - 1.0
    c = 1.0
    d = 1.0 - qab * x / qap
    d = 1.0 / (d if abs(d) > _TINY else _TINY)
    h = d
    for m in range(1, _MAXIT + 1):
        m2 = 2 * m
        aa = m * (b - m) * x / ((qam + m2) * (a + m2))
        d = 1.0 + aa * d
        d = 1.0 / (d if abs(d) > _TINY else _TINY)
        c = 1.0 + aa / c
        c = c if abs(c) > _TINY else _TINY
        h *= d * c
        aa = -(a + m) * (qab + m) * x / ((a + m2) * (qap + m2))
        d = 1.0 + aa * d
        d = 1.0 / (d if abs(d) > _TINY else _TINY)
        c = 1.0 + aa / c
        c = c if abs(c) > _TINY else _TINY
        de = d * c
        h *= de
        if abs(de - 1.0) < _EPS:
            break
    return h


def _t_lower(t: float, df: float) -> float:
    """P(T <= t) for t <= 0 and finite df > 0: I_x(df/2, 1/2) / 2 with x = df / (df + t^2), computed with its
    complement 1 - x = t^2 / (df + t^2) and both logarithms directly, so small tails keep their relative accuracy."""
    if t == 0.0:
        return 0.5
    if t < -_BIG_T:
        return 0.0
    a, b = 0.5 * df, 0.5
    u = t * t / df                 # x = 1 / (1 + u), y = 1 - x = u / (1 + u)
    if u == 0.0:                   # |t| < 1e-154 or so: 0.5 to double precision
        return 0.5
    if u <= 1.0:
        ln_x = -math.log1p(u)
        ln_y = math.log(u) + ln_x
        x, y = 1.0 / (1.0 + u), u / (1.0 + u)
    else:
        r = 1.0 / u                # x = r / (1 + r), y = 1 / (1 + r)
        ln_y = -math.log1p(r)
        ln_x = math.log(r) + ln_y
        x, y = r / (1.0 + r), 1.0 / (1.0 + r)
    ln_beta = _LN_SQRT_PI - _ln_gamma_ratio(a)       # ln B(df/2, 1/2)
    front = math.exp(a * ln_x + b * ln_y - ln_beta)
    if x < (a + 1.0) / (a + b + 2.0):
        ix = front * _betacf(a, b, x) / a
    else:
        ix = 1.0 - front * _betacf(b, a, y) / b
    return 0.5 * ix


def _t_pdf(t: float, df: float) -> float:
    """The density of Student's t with finite df > 0 at t."""
    ln_c = _ln_gamma_ratio(0.5 * df) - _LN_SQRT_PI - 0.5 * math.log(df)
    return math.exp(ln_c - 0.5 * (df + 1.0) * math.log1p(t * t / df))


def _norm_lower(t: float) -> float:
    """P(Z <= t) for the standard normal (accurate in the lower tail)."""
    return 0.5 * math.erfc(-t / _SQRT2)


def _norm_pdf(t: float) -> float:
    """The standard normal density at t."""
    return math.exp(-0.5 * t * t) / math.sqrt(2.0 * math.pi)


def _check_df(df: float) -> bool:
    """Whether df is a usable number of degrees of freedom (> 0, not NaN; math.inf is the normal)."""
    return not math.isnan(df) and df > 0.0


def t_cdf(x: float, df: float) -> float:
    """P(T <= x) for Student's t with ``df`` degrees of freedom (df > 0, not necessarily an integer;
    ``math.inf``, or anything above 1e10: the standard normal). NaN for NaN input or df <= 0."""
    x, df = float(x), float(df)
    if math.isnan(x) or not _check_df(df):
        return math.nan
    lower = _norm_lower if df > _NORMAL_DF else (lambda t: _t_lower(t, df))
    return lower(x) if x <= 0.0 else 1.0 - lower(-x)


def _newton_lower(q: float, cdf: Callable[[float], float], pdf: Callable[[float], float]) -> float:
    """The x <= 0 with cdf(x) = q for 0 < q <= 1/2. The cdf is convex on x <= 0 (the density rises towards 0), so
    Newton's iteration from x = 0 (right of the root) descends monotonically onto the root, no bracket needed."""
    x = 0.0
    for _ in range(500):
        f = pdf(x)
        if not f > 0.0:
            break
        step = (cdf(x) - q) / f
        x -= step
        if step <= 0.0 or abs(step) <= 1e-15 * abs(x):   # converged, or past the root by a rounding error
            break
    return x


def t_ppf(p: float, df: float) -> float:
    """The quantile of Student's t with ``df`` degrees of freedom: the x with ``t_cdf(x, df) == p`` (df > 0, not
    necessarily an integer; ``math.inf``, or anything above 1e10: the standard normal). -inf / +inf at p = 0 / 1;
    NaN for p outside [0, 1], NaN input or df <= 0."""
    p, df = float(p), float(df)
    if math.isnan(p) or not _check_df(df) or p < 0.0 or p > 1.0:
        return math.nan
    if p == 0.0 or p == 1.0:
        return -math.inf if p == 0.0 else math.inf
    if p == 0.5:
        return 0.0
    q = min(p, 1.0 - p)      # the lower-tail probability (1 - p is exact for p >= 1/2)
    if df == 1.0:            # Cauchy: tan(pi (q - 1/2)) = -1 / tan(pi q)
        x = -1.0 / math.tan(math.pi * q)
    elif df == 2.0:
        x = (2.0 * q - 1.0) / math.sqrt(2.0 * q * (1.0 - q))
    elif df > _NORMAL_DF:
        x = _newton_lower(q, _norm_lower, _norm_pdf)
    else:
        x = _newton_lower(q, lambda t: _t_lower(t, df), lambda t: _t_pdf(t, df))
    return x if p < 0.5 else -x


def _finite(values: Iterable[float]) -> list[float]:
    """The finite values, as floats, in their order."""
    out = []
    for v in values:
        v = float(v)
        if math.isfinite(v):
            out.append(v)
    return out


def nested(diffs: Mapping[object, Iterable[float]]) -> dict:
    """The mean paired difference over worlds x nested seeds, its interval clustered by world, and the one-way
    random-effects variance components (d_ws = mu + a_w + e_ws).

    ``diffs`` maps a world id to its seeds' paired differences; non-finite values are dropped, and worlds left
    empty with them. Returns a dict:

    - ``mean``: the mean of the world means (each world weighs the same; NaN without worlds);
    - ``se``: sd(world means) / sqrt(W), the standard error clustered by world (NaN when W < 2);
    - ``df``: W - 1 (0 without worlds);
    - ``ci95``: the 95 % half-width t_ppf(0.975, df) * se (NaN when W < 2);
    - ``n_worlds``: W; ``n``: the number of values; ``per_world``: the values per world (in ``diffs``' order);
    - ``var_world``: the between-world component sigma^2_a, the ANOVA (method of moments) estimate
      (MSB - MSW) / n0 with n0 = (N - sum n_w^2 / N) / (W - 1) (n0 = S when balanced), truncated at 0. NaN when
      W < 2 or when it cannot be told from the seed component (no world with 2 values or more, e.g. S = 1);
    - ``var_seed``: MSW, the within-world (seed) component (NaN when no world has 2 values or more);
    - ``share_world``: var_world / (var_world + var_seed) (NaN when undefined);
    - ``differs``: -1 / +1 / 0 when the 95 % interval lies below 0 / above 0 / contains 0 (or is undefined);
    - ``values``: the (world, value) pairs used, in ``diffs``' order.

    With one seed per world (S = 1) the interval is the plain t interval over the worlds. Sums are exact
    (`math.fsum`), so the statistics do not depend on the order of the worlds or of their seeds.
    """
    worlds: list[tuple[object, list[float]]] = []
    for w, vals in diffs.items():
        kept = _finite(vals)
        if kept:
            worlds.append((w, kept))
    n_worlds = len(worlds)
    per_world = [len(v) for _, v in worlds]
    n = sum(per_world)
    means = [math.fsum(v) / len(v) for _, v in worlds]
    nan = math.nan

    mean = math.fsum(means) / n_worlds if n_worlds else nan
    if n_worlds >= 2:
        var_means = math.fsum((m - mean) ** 2 for m in means) / (n_worlds - 1)
        se = math.sqrt(var_means / n_worlds)
        ci95 = t_ppf(0.975, n_worlds - 1) * se
    else:
        se = ci95 = nan

    df_within = n - n_worlds
    ss_within = math.fsum((x - m) ** 2 for (_, v), m in zip(worlds, means) for x in v)
    var_seed = ss_within / df_within if df_within > 0 else nan
    if n_worlds >= 2 and df_within > 0:
        grand = math.fsum(x for _, v in worlds for x in v) / n
        msb = math.fsum(k * (m - grand) ** 2 for k, m in zip(per_world, means)) / (n_worlds - 1)
        n0 = (n - math.fsum(k * k for k in per_world) / n) / (n_worlds - 1)
        var_world = max(0.0, (msb - var_seed) / n0)
    else:
        var_world = nan
    total = var_world + var_seed
    share_world = var_world / total if total > 0.0 else nan   # NaN compares False: NaN stays NaN

    if mean - ci95 > 0.0:
        differs = 1
    elif mean + ci95 < 0.0:
        differs = -1
    else:
        differs = 0
    return {"mean": mean, "se": se, "df": max(n_worlds - 1, 0), "ci95": ci95, "n_worlds": n_worlds, "n": n,
            "per_world": per_world, "var_world": var_world, "var_seed": var_seed, "share_world": share_world,
            "differs": differs, "values": [(w, x) for w, v in worlds for x in v]}


def _check_level(name: str, value: float) -> None:
    """Refuse a probability (power, alpha) outside (0, 1)."""
    if not 0.0 < value < 1.0:
        raise ValueError(f"{name} must lie in (0, 1), not {value!r}")


def mde(se: float, df: float, power: float = 0.8, alpha: float = 0.05) -> float:
    """The minimum detectable effect of a two-sided t test at level ``alpha`` with the given ``power``:
    (t_ppf(1 - alpha/2, df) + t_ppf(power, df)) * se. NaN for NaN or infinite ``se``, negative ``se``, NaN ``df``
    or df < 1 (``df = math.inf`` is the normal test). ValueError for power or alpha outside (0, 1)."""
    _check_level("power", power)
    _check_level("alpha", alpha)
    se, df = float(se), float(df)
    if not math.isfinite(se) or se < 0.0 or math.isnan(df) or df < 1.0:
        return math.nan
    return (t_ppf(1.0 - alpha / 2.0, df) + t_ppf(power, df)) * se


def tost(mean: float, se: float, df: float, delta: float, alpha: float = 0.05) -> dict:
    """Two one-sided t tests (TOST) of equivalence: is the effect within the bound |effect| < ``delta``?

    p_lower = 1 - t_cdf((mean + delta) / se, df) (H0: effect <= -delta), p_upper = t_cdf((mean - delta) / se, df)
    (H0: effect >= delta), p = max(p_lower, p_upper). Returns ``{"p": p, "equivalent": p < alpha, "ci90": (lo, hi),
    "delta": delta}`` where ci90 is mean -+ t_ppf(1 - alpha, df) * se (the 90 % interval at alpha = 0.05:
    equivalence holds when it lies within (-delta, delta)). p is NaN and ``equivalent`` False when ``se`` is not
    finite or <= 0, df < 1 or an input is NaN; except that se == 0 with |mean| < delta gives p = 0, equivalent.
    ValueError for alpha outside (0, 1).
    """
    _check_level("alpha", alpha)
    mean, se, df, delta = float(mean), float(se), float(df), float(delta)
    nan = math.nan
    ok = not (math.isnan(mean) or math.isnan(delta) or math.isnan(df) or math.isnan(se)) and df >= 1.0
    if ok and se == 0.0 and abs(mean) < delta:
        return {"p": 0.0, "equivalent": True, "ci90": (mean, mean), "delta": delta}
    if not ok or not math.isfinite(se) or se <= 0.0:
        return {"p": nan, "equivalent": False, "ci90": (nan, nan), "delta": delta}
    p_lower = t_cdf(-(mean + delta) / se, df)     # = 1 - t_cdf((mean + delta) / se, df), without the cancellation
    p_upper = t_cdf((mean - delta) / se, df)
    p = max(p_lower, p_upper)
    half = t_ppf(1.0 - alpha, df) * se
    return {"p": p, "equivalent": p < alpha, "ci90": (mean - half, mean + half), "delta": delta}


def verdict(nest: Mapping, delta: float, mde80: float | None = None) -> str:
    """One short phrase for a report on a comparison ``nest`` (a `nested` result) with the equivalence bound
    ``delta``: "beyond the interval (lower)" / "beyond the interval (higher)" when the 95 % interval excludes 0;
    else "equivalent to 0 within ±delta (TOST p = ...)" when TOST at 0.05 passes; else "inconclusive: ..." with
    the effect detectable at 80 % power (``mde80``; computed from ``nest`` when None)."""
    if nest["differs"] < 0:
        return "beyond the interval (lower)"
    if nest["differs"] > 0:
        return "beyond the interval (higher)"
    eq = tost(nest["mean"], nest["se"], nest["df"], delta)
    if eq["equivalent"]:
        return f"equivalent to 0 within ±{delta:g} (TOST p = {eq['p']:.3f})"
    if mde80 is None:
        mde80 = mde(nest["se"], nest["df"])
    return (f"inconclusive: neither beyond the interval nor within ±{delta:g} (TOST p = {eq['p']:.3f}); "
            f"detectable at 80 % power: ±{mde80:.4f}")


#: two-sided 95 % Student-t quantiles t_0.975(df) for df = 1..30 (beyond: the normal 1.96; t is 2.04 at 31 df,
#: and a sweep has 3-4 seeds): the rounded table every interval over seeds of a report is computed with
#: (`study.results.summary.mean_std`; `t_ppf` gives the unrounded quantile, which would move the committed reports' last
#: digits); tests/study/test_results.py checks every entry against scipy where it is installed.
T975 = (12.706, 4.303, 3.182, 2.776, 2.571, 2.447, 2.365, 2.306, 2.262, 2.228, 2.201, 2.179, 2.160, 2.145,
        2.131, 2.120, 2.110, 2.101, 2.093, 2.086, 2.080, 2.074, 2.069, 2.064, 2.060, 2.056, 2.052, 2.048,
        2.045, 2.042)


def t_halfwidth(sd: float, n: int) -> float:
    """Half-width of the 95 % t-interval of a mean of n values with sample std sd (NaN for n < 2)."""
    if n < 2 or not math.isfinite(sd):
        return float("nan")
    t = T975[n - 2] if n - 1 <= len(T975) else 1.96
    return t * sd / math.sqrt(n)
