"""study/stats/power.py: the t distribution against scipy and known values, the nested (worlds x seeds) interval and
variance components on numbers whose answer is known, MDE, TOST and the report's verdict phrases. Pure math:
fast and deterministic (scipy only where a test says so: the package does not depend on it)."""
from __future__ import annotations

import math
import random

import pytest

from study.stats.power import mde, nested, t_cdf, t_ppf, tost, verdict

DFS = (1, 2, 3, 5, 10.5, 30, 200)
XS = (-40.0, -12.0, -6.0, -3.5, -2.0, -1.3, -0.7, -0.2, -1e-4, 0.0, 1e-4, 0.2, 0.7, 1.3, 2.0, 3.5, 6.0, 12.0, 40.0)
PS = (0.8, 0.9, 0.95, 0.975, 0.995)


# --- the t distribution --------------------------------------------------------------------------------------


def test_t_cdf_matches_scipy():
    st = pytest.importorskip("scipy.stats")
    for df in DFS:
        for x in XS:
            assert t_cdf(x, df) == pytest.approx(float(st.t.cdf(x, df)), abs=1e-8, rel=0), (x, df)


def test_t_cdf_lower_tail_is_relatively_accurate():
    """Small tail probabilities keep their digits (no 1 - p cancellation): what TOST and small p-values need."""
    st = pytest.importorskip("scipy.stats")
    for df in DFS:
        for x in (-3.5, -6.0, -12.0, -40.0):
            assert t_cdf(x, df) == pytest.approx(float(st.t.cdf(x, df)), rel=1e-9), (x, df)


def test_t_ppf_matches_scipy():
    st = pytest.importorskip("scipy.stats")
    for df in DFS:
        for p in PS:
            for q in (p, 1.0 - p):
                assert t_ppf(q, df) == pytest.approx(float(st.t.ppf(q, df)), rel=1e-7), (q, df)


def test_t_ppf_extreme_probabilities_match_scipy():
    st = pytest.importorskip("scipy.stats")
    for df in (1, 1.5, 4, 17.25, 1000):
        for q in (1e-6, 1e-3, 0.3, 0.7, 1 - 1e-6):
            assert t_ppf(q, df) == pytest.approx(float(st.t.ppf(q, df)), rel=1e-9), (q, df)


def test_t_ppf_next_to_the_median():
    """(scipy 1.17 answers 0.0 here.) Next to 1/2 the quantile is (p - 1/2) / density(0); the t density at 0 with
    df = 4 is Gamma(5/2) / (sqrt(4 pi) Gamma(2)) = 3/8."""
    p = 0.5 + 1e-9
    assert t_ppf(p, 4) == pytest.approx((p - 0.5) / 0.375, rel=1e-8)
    assert t_ppf(1.0 - p, 4) == pytest.approx(-(p - 0.5) / 0.375, rel=1e-6)


def test_t_ppf_known_values():
    assert t_ppf(0.975, 2) == pytest.approx(4.302652729749464, rel=1e-12)
    assert t_ppf(0.975, 5) == pytest.approx(2.570581835636314, rel=1e-12)
    assert t_ppf(0.8, 2) == pytest.approx(1.0606601717798212, rel=1e-12)
    assert t_ppf(0.975, 1) == pytest.approx(12.706204736174696, rel=1e-12)      # Cauchy: tan(0.475 pi)
    assert t_ppf(0.975, math.inf) == pytest.approx(1.959963984540054, rel=1e-12)
    assert t_ppf(0.5, 7) == 0.0


def test_t_ppf_inverts_t_cdf():
    for df in (1, 2, 2.5, 3, 7, 10.5, 63, 1000, math.inf):
        for p in (1e-6, 0.01, 0.2, 0.5, 0.6, 0.975, 1 - 1e-6):
            x = t_ppf(p, df)
            assert t_cdf(x, df) == pytest.approx(p, rel=1e-10), (p, df)
            assert t_ppf(1.0 - p, df) == pytest.approx(-x, rel=1e-9, abs=1e-15)


def test_t_cdf_symmetry_limits_and_normal():
    for df in (1, 3.5, 40):
        for x in (0.3, 2.0, 9.0):
            assert t_cdf(x, df) + t_cdf(-x, df) == pytest.approx(1.0, abs=1e-14)
        assert t_cdf(0.0, df) == 0.5
        assert t_cdf(math.inf, df) == 1.0 and t_cdf(-math.inf, df) == 0.0
    for x in (-7.0, -1.0, 0.5, 3.0):
        assert t_cdf(x, math.inf) == pytest.approx(0.5 * math.erfc(-x / math.sqrt(2.0)), rel=1e-14)
        assert abs(t_cdf(x, 1e6) - t_cdf(x, math.inf)) < 1e-5    # the t tends to the normal
    assert t_cdf(-1.5, 4) > t_cdf(-1.5, 40) > t_cdf(-1.5, math.inf)    # heavier tails at fewer df


def test_t_invalid_inputs():
    assert math.isnan(t_cdf(math.nan, 3)) and math.isnan(t_cdf(1.0, math.nan))
    assert math.isnan(t_cdf(1.0, 0)) and math.isnan(t_cdf(1.0, -2))
    assert math.isnan(t_ppf(math.nan, 3)) and math.isnan(t_ppf(0.9, 0)) and math.isnan(t_ppf(0.9, math.nan))
    assert math.isnan(t_ppf(-0.1, 3)) and math.isnan(t_ppf(1.1, 3))
    assert t_ppf(0.0, 3) == -math.inf and t_ppf(1.0, 3) == math.inf


# --- MDE and TOST -------------------------------------------------------------------------------------------


def test_mde_matches_scipy():
    st = pytest.importorskip("scipy.stats")
    for df in DFS:
        for power, alpha in ((0.8, 0.05), (0.9, 0.05), (0.8, 0.01), (0.5, 0.1)):
            want = (st.t.ppf(1 - alpha / 2, df) + st.t.ppf(power, df)) * 0.013
            assert mde(0.013, df, power=power, alpha=alpha) == pytest.approx(float(want), rel=1e-7), (df, power)


def test_mde_has_about_its_power():
    """At the MDE a two-sided t test rejects with about the asked power (noncentral t; the formula is the usual
    approximation, close once df is not tiny)."""
    st = pytest.importorskip("scipy.stats")
    for df in (10, 30, 200):
        se = 0.01
        crit = st.t.ppf(0.975, df)
        nc = mde(se, df) / se
        power = st.nct.sf(crit, df, nc) + st.nct.cdf(-crit, df, nc)
        assert power == pytest.approx(0.8, abs=0.01), df


def test_mde_edge_cases():
    assert mde(0.01, 9) == pytest.approx((t_ppf(0.975, 9) + t_ppf(0.8, 9)) * 0.01, rel=1e-14)
    assert mde(0.0, 9) == 0.0
    assert mde(0.01, math.inf) == pytest.approx((1.959963984540054 + 0.8416212335729143) * 0.01, rel=1e-12)
    for se, df in ((math.nan, 9), (math.inf, 9), (-0.01, 9), (0.01, math.nan), (0.01, 0), (0.01, 0.5)):
        assert math.isnan(mde(se, df)), (se, df)
    with pytest.raises(ValueError, match="power"):
        mde(0.01, 9, power=1.0)
    with pytest.raises(ValueError, match="alpha"):
        mde(0.01, 9, alpha=0.0)


def test_tost_matches_scipy_one_sided_t_tests():
    """TOST on a sample = the larger p of two one-sided one-sample t tests (H0: mu <= -delta, H0: mu >= delta)."""
    st = pytest.importorskip("scipy.stats")
    rng = random.Random(3)
    for n, loc, delta in ((5, 0.001, 0.02), (12, 0.004, 0.01), (30, -0.003, 0.006), (8, 0.02, 0.01), (3, 0.0, 0.05)):
        xs = [rng.gauss(loc, 0.01) for _ in range(n)]
        mean = math.fsum(xs) / n
        se = math.sqrt(math.fsum((x - mean) ** 2 for x in xs) / (n - 1) / n)
        res = tost(mean, se, n - 1, delta)
        p_lo = st.ttest_1samp(xs, -delta, alternative="greater").pvalue
        p_hi = st.ttest_1samp(xs, delta, alternative="less").pvalue
        assert res["p"] == pytest.approx(max(p_lo, p_hi), rel=1e-7, abs=1e-12), (n, loc, delta)
        assert res["equivalent"] is bool(max(p_lo, p_hi) < 0.05)
        assert res["delta"] == delta
        lo, hi = st.t.interval(0.90, n - 1, loc=mean, scale=se)
        assert res["ci90"] == pytest.approx((lo, hi), rel=1e-7)


def test_tost_matches_scipy_formula():
    st = pytest.importorskip("scipy.stats")
    for df in DFS:
        for mean, se, delta, alpha in ((0.002, 0.003, 0.01, 0.05), (-0.004, 0.002, 0.005, 0.05),
                                       (0.0, 0.01, 0.01, 0.1), (0.03, 0.004, 0.01, 0.05)):
            want = max(st.t.sf((mean + delta) / se, df), st.t.cdf((mean - delta) / se, df))
            res = tost(mean, se, df, delta, alpha=alpha)
            assert res["p"] == pytest.approx(float(want), abs=1e-8), (df, mean)
            half = st.t.ppf(1 - alpha, df) * se
            assert res["ci90"] == pytest.approx((mean - half, mean + half), rel=1e-7)


def test_tost_decision_and_ci90():
    """Equivalent exactly when the 90 % interval lies within (-delta, delta) (alpha = 0.05)."""
    for mean, se, df, delta in ((0.001, 0.002, 9, 0.006), (0.001, 0.002, 9, 0.004), (-0.002, 0.001, 3, 0.01),
                                (0.02, 0.001, 30, 0.01)):
        res = tost(mean, se, df, delta)
        lo, hi = res["ci90"]
        assert res["equivalent"] == (-delta < lo and hi < delta), (mean, se, df, delta)
    assert tost(0.001, 0.002, 9, 0.006)["equivalent"] is True
    assert tost(0.02, 0.001, 30, 0.01)["equivalent"] is False


def test_tost_edge_cases():
    for se, df in ((math.nan, 5), (math.inf, 5), (-0.1, 5), (0.01, 0), (0.01, math.nan)):
        res = tost(0.0, se, df, 0.01)
        assert math.isnan(res["p"]) and res["equivalent"] is False, (se, df)
    assert tost(0.003, 0.0, 4, 0.01) == {"p": 0.0, "equivalent": True, "ci90": (0.003, 0.003), "delta": 0.01}
    res = tost(0.03, 0.0, 4, 0.01)          # a point estimate outside the bound: no test
    assert math.isnan(res["p"]) and res["equivalent"] is False
    assert math.isnan(tost(math.nan, 0.01, 4, 0.01)["p"]) and math.isnan(tost(0.0, 0.01, 4, math.nan)["p"])
    with pytest.raises(ValueError, match="alpha"):
        tost(0.0, 0.01, 4, 0.01, alpha=1.5)


# --- nested: worlds x seeds ---------------------------------------------------------------------------------


def test_nested_exact_balanced_construction():
    """mu = 0.3, world effects +1, 0, -1, seed deviations +-0.5 in every world (S = 2): world means 1.3, 0.3,
    -0.7 (sd 1), MSW = 3 * 0.5 / 3 = 0.5, MSB = 2 * 2 / 2 = 2, var_world = (2 - 0.5) / 2 = 0.75."""
    diffs = {"w1": [1.8, 0.8], "w2": [0.8, -0.2], "w3": [-0.2, -1.2]}
    r = nested(diffs)
    assert r["mean"] == pytest.approx(0.3, abs=1e-15)
    assert r["se"] == pytest.approx(1.0 / math.sqrt(3.0), rel=1e-12)
    assert r["df"] == 2 and r["n_worlds"] == 3 and r["n"] == 6 and r["per_world"] == [2, 2, 2]
    assert r["ci95"] == pytest.approx(4.302652729749464 / math.sqrt(3.0), rel=1e-12)
    assert r["var_seed"] == pytest.approx(0.5, rel=1e-12)
    assert r["var_world"] == pytest.approx(0.75, rel=1e-12)
    assert r["share_world"] == pytest.approx(0.6, rel=1e-12)
    assert r["differs"] == 0                        # 0.3 +- 2.48
    assert r["values"] == [("w1", 1.8), ("w1", 0.8), ("w2", 0.8), ("w2", -0.2), ("w3", -0.2), ("w3", -1.2)]
    assert list(r) == ["mean", "se", "df", "ci95", "n_worlds", "n", "per_world", "var_world", "var_seed",
                       "share_world", "differs", "values"]


def test_nested_differs_sign():
    up = nested({w: [1.0 + 0.1 * w, 1.1 + 0.1 * w] for w in range(4)})
    assert up["differs"] == 1 and up["mean"] - up["ci95"] > 0
    down = nested({w: [-x for x in v] for w, v in {w: [1.0 + 0.1 * w, 1.1 + 0.1 * w] for w in range(4)}.items()})
    assert down["differs"] == -1 and down["mean"] == pytest.approx(-up["mean"], rel=1e-15)


def test_nested_recovers_simulated_variance_components():
    """400 worlds x 4 seeds, sigma_world = 0.02, sigma_seed = 0.01: the ANOVA estimates lie within 15 % of the
    true components, and the clustered se near its true value sqrt((sw^2 + ss^2 / S) / W)."""
    rng = random.Random(0)
    diffs = {}
    for w in range(400):
        a = rng.gauss(0.0, 0.02)
        diffs[w] = [0.003 + a + rng.gauss(0.0, 0.01) for _ in range(4)]
    r = nested(diffs)
    assert r["n_worlds"] == 400 and r["n"] == 1600 and r["df"] == 399
    assert r["var_world"] == pytest.approx(0.02 ** 2, rel=0.15)
    assert r["var_seed"] == pytest.approx(0.01 ** 2, rel=0.15)
    assert r["share_world"] == pytest.approx(0.8, rel=0.15)
    assert r["se"] == pytest.approx(math.sqrt((0.02 ** 2 + 0.01 ** 2 / 4) / 400), rel=0.15)
    assert abs(r["mean"] - 0.003) < 3 * r["se"]


def test_nested_unbalanced_by_hand():
    """A: [1, 3] (mean 2), B: [0], C: [4, 5, 6] (mean 5); N = 6, W = 3, grand mean 19/6. MSW = (2 + 0 + 2) / 3,
    MSB = (2 (2 - 19/6)^2 + (19/6)^2 + 3 (5 - 19/6)^2) / 2 = 411/36, n0 = (6 - 14/6) / 2 = 11/6,
    var_world = (411/36 - 48/36) / (11/6) = 5.5; world means 2, 0, 5: mean 7/3, se = sqrt(19/3) / sqrt(3)."""
    r = nested({"A": [1, 3], "B": [0], "C": [4, 5, 6]})
    assert r["mean"] == pytest.approx(7 / 3, rel=1e-14)
    assert r["se"] == pytest.approx(math.sqrt(19) / 3, rel=1e-12)
    assert r["var_seed"] == pytest.approx(4 / 3, rel=1e-12)
    assert r["var_world"] == pytest.approx(5.5, rel=1e-12)
    assert r["share_world"] == pytest.approx(5.5 / (5.5 + 4 / 3), rel=1e-12)
    assert r["per_world"] == [2, 1, 3] and r["n"] == 6 and r["df"] == 2


def test_nested_var_world_truncated_at_zero():
    """World means closer than the seed noise allows: MSB < MSW, the estimate is 0, not negative."""
    r = nested({0: [1.0, -1.0], 1: [1.1, -0.9], 2: [0.9, -1.1]})
    assert r["var_world"] == 0.0 and r["share_world"] == 0.0 and r["var_seed"] == pytest.approx(2.0, rel=1e-12)


def test_nested_one_seed_per_world():
    """S = 1: the plain t interval over the worlds; the components cannot be told apart (NaN)."""
    vals = [0.01, 0.03, -0.005, 0.02]
    r = nested({w: [v] for w, v in enumerate(vals)})
    m = sum(vals) / 4
    sd = math.sqrt(sum((v - m) ** 2 for v in vals) / 3)
    assert r["mean"] == pytest.approx(m, rel=1e-14) and r["se"] == pytest.approx(sd / 2, rel=1e-12)
    assert r["ci95"] == pytest.approx(t_ppf(0.975, 3) * sd / 2, rel=1e-12) and r["df"] == 3
    assert math.isnan(r["var_seed"]) and math.isnan(r["var_world"]) and math.isnan(r["share_world"])
    assert r["per_world"] == [1, 1, 1, 1] and r["differs"] == 0


def test_nested_single_world_and_empty():
    r = nested({"only": [0.1, 0.3, 0.2]})
    assert r["mean"] == pytest.approx(0.2) and r["n_worlds"] == 1 and r["df"] == 0 and r["differs"] == 0
    assert math.isnan(r["se"]) and math.isnan(r["ci95"]) and math.isnan(r["var_world"])
    assert r["var_seed"] == pytest.approx(0.01, rel=1e-12) and math.isnan(r["share_world"])
    for empty in ({}, {"a": [], "b": [math.nan]}):
        r = nested(empty)
        assert r["n_worlds"] == 0 and r["n"] == 0 and r["per_world"] == [] and r["values"] == []
        assert all(math.isnan(r[k]) for k in ("mean", "se", "ci95", "var_world", "var_seed", "share_world"))
        assert r["differs"] == 0 and r["df"] == 0


def test_nested_drops_non_finite_values_and_empty_worlds():
    clean = {"a": [0.1, 0.2], "b": [0.4], "c": [0.3, 0.5, 0.1]}
    dirty = {"a": [0.1, math.nan, 0.2], "gone": [math.inf, math.nan], "b": [-math.inf, 0.4],
             "c": [0.3, 0.5, float("nan"), 0.1]}
    r, s = nested(clean), nested(dirty)
    assert s["values"] == r["values"] and s["per_world"] == [2, 1, 3] and s["n_worlds"] == 3
    for k in ("mean", "se", "df", "ci95", "n", "var_world", "var_seed", "share_world", "differs"):
        assert s[k] == r[k], k


def test_nested_does_not_depend_on_order():
    """Exact sums: the worlds' and the seeds' order changes nothing but the order of ``values``."""
    rng = random.Random(7)
    diffs = {f"w{w}": [rng.gauss(0.01, 0.02) for _ in range(rng.randint(1, 5))] for w in range(9)}
    shuffled = {w: list(reversed(diffs[w])) for w in reversed(list(diffs))}
    r, s = nested(diffs), nested(shuffled)
    for k in ("mean", "se", "df", "ci95", "n_worlds", "n", "var_world", "var_seed", "share_world", "differs"):
        assert s[k] == r[k], k
    assert r["values"] == [(w, x) for w, v in diffs.items() for x in v]      # insertion order
    assert sorted(s["per_world"]) == sorted(r["per_world"])


# --- verdict ------------------------------------------------------------------------------------------------


def test_verdict_beyond_the_interval():
    up = nested({w: [0.05 + 0.001 * w, 0.052 + 0.001 * w] for w in range(5)})
    down = nested({w: [-0.05 - 0.001 * w, -0.052 - 0.001 * w] for w in range(5)})
    assert verdict(up, 0.01) == "beyond the interval (higher)"
    assert verdict(down, 0.01) == "beyond the interval (lower)"


def test_verdict_equivalent():
    nest = nested({w: [d, -d * 0.5] for w, d in enumerate((0.001, -0.002, 0.0015, -0.001, 0.0005, 0.002))})
    assert nest["differs"] == 0
    p = tost(nest["mean"], nest["se"], nest["df"], 0.01)["p"]
    assert p < 0.05
    assert verdict(nest, 0.01) == f"equivalent to 0 within ±0.01 (TOST p = {p:.3f})"


def test_verdict_inconclusive():
    nest = nested({w: [d, d + 0.001] for w, d in enumerate((0.03, -0.02, 0.01, -0.015))})
    assert nest["differs"] == 0
    p = tost(nest["mean"], nest["se"], nest["df"], 0.01)["p"]
    assert p >= 0.05
    m = mde(nest["se"], nest["df"])
    want = (f"inconclusive: neither beyond the interval nor within ±0.01 (TOST p = {p:.3f}); "
            f"detectable at 80 % power: ±{m:.4f}")
    assert verdict(nest, 0.01) == want
    assert verdict(nest, 0.01, mde80=0.0123).endswith("detectable at 80 % power: ±0.0123")
    assert verdict(nest, 0.005).startswith("inconclusive: neither beyond the interval nor within ±0.005 (TOST p = ")
