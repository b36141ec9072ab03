"""study/stats/design.py: sample size, the two-look O'Brien-Fleming design and the signed-rank reading, against published
tables and (where installed) scipy; study/stats/variance.py: the noise / heterogeneity split on synthetic numbers."""
import math

import numpy as np
import pytest

from study.stats.design import obf_bounds, obf_inflation, sequential_look, signed_rank, worlds_needed
from study.stats.power import mde
from study.stats.variance import OUTLIER_Z, variance_split, world_bootstrap


# --------------------------------------------------------------------------- sample size
@pytest.mark.parametrize("effect_size, n", [(0.5, 34), (1.0, 10), (0.8, 15), (0.25, 128)])
def test_worlds_needed_matches_gpower(effect_size, n):
    """G*Power (paired t, two-sided 0.05, power 0.8): d = 0.5 -> 34, 1.0 -> 10, 0.8 -> 15, 0.25 -> 128."""
    assert worlds_needed(1.0, effect_size) == n


def test_worlds_needed_agrees_with_mde():
    n = worlds_needed(0.02, 0.005)
    assert mde(0.02 / math.sqrt(n), n - 1) <= 0.005 < mde(0.02 / math.sqrt(n - 1), n - 2)
    assert worlds_needed(0.0, 0.005) == 2
    with pytest.raises(ValueError, match="effect must be finite and > 0"):
        worlds_needed(0.02, 0.0)


def test_worlds_needed_exact_power_is_near_80_percent():
    stats = pytest.importorskip("scipy.stats")
    for d in (0.3, 0.5, 1.0):
        n = worlds_needed(1.0, d)
        crit = stats.t.ppf(0.975, n - 1)
        power = stats.nct.sf(crit, n - 1, d * math.sqrt(n)) + stats.nct.cdf(-crit, n - 1, d * math.sqrt(n))
        assert 0.78 <= power <= 0.86


# --------------------------------------------------------------------------- group-sequential
def test_obf_two_looks_match_jennison_turnbull():
    """Jennison & Turnbull (2000), Table 2.3: C_B(2, 0.05) = 1.977 (bounds 2.796, 1.977); Table 2.4: R_B = 1.008."""
    c1, c2 = obf_bounds(0.5, 0.05)
    assert c2 == pytest.approx(1.977, abs=5e-4) and c1 == pytest.approx(1.977 * math.sqrt(2), abs=1e-3)
    assert obf_inflation(0.5, 0.05, 0.8) == pytest.approx(1.008, abs=5e-4)
    c1, c2 = obf_bounds(0.5, 0.01)  # Table 2.3: C_B(2, 0.01) = 2.580
    assert c2 == pytest.approx(2.580, abs=5e-4)


def test_obf_error_is_alpha_by_scipy():
    stats = pytest.importorskip("scipy.stats")
    c1, c2 = obf_bounds(0.5, 0.05)
    rho = math.sqrt(0.5)
    mvn = stats.multivariate_normal(mean=[0, 0], cov=[[1, rho], [rho, 1]])
    inside = (mvn.cdf([c1, c2]) - mvn.cdf([-c1, c2]) - mvn.cdf([c1, -c2]) + mvn.cdf([-c1, -c2]))
    assert 1 - inside == pytest.approx(0.05, abs=2e-5)


def test_sequential_look_stops_only_beyond_its_bound():
    strong = [0.02 + 0.001 * k for k in range(10)]
    weak = [0.01, -0.01, 0.02, -0.005, 0.004, 0.0, 0.012, -0.02, 0.006, 0.001]
    first = sequential_look(strong, planned=20, final=False)
    assert first["stop"] and first["nominal"] == pytest.approx(2 * (1 - 0.5 * math.erfc(-2.7965 / math.sqrt(2))),
                                                               rel=1e-3)
    assert not sequential_look(weak, planned=20, final=False)["stop"]
    last = sequential_look(weak + strong, planned=20, final=True)
    assert last["n"] == 20 and last["df"] == 19 and last["nominal"] == pytest.approx(0.048, abs=5e-4)


# --------------------------------------------------------------------------- signed rank
FIXED = [0.010018, 0.014481, 0.005888, -0.003359, 0.00318, -0.004875, 0.010902, 0.030103, 0.002617, 0.000693,
         0.017348]  # no two Walsh averages equal: no ties in |d - mu| at the interval's ends


def test_signed_rank_matches_scipy_wilcoxon():
    stats = pytest.importorskip("scipy.stats")
    for d in (FIXED, FIXED[:6], [-v for v in FIXED[:8]]):
        r = signed_rank(d)
        ref = stats.wilcoxon(d, method="exact")
        assert r["method"] == "exact" and r["p"] == pytest.approx(ref.pvalue, rel=1e-12)
    tied = [0.01, 0.01, -0.02, 0.03, 0.03, 0.0, 0.05, -0.01]   # ties and a zero: the normal approximation
    r = signed_rank(tied)
    ref = stats.wilcoxon(tied, method="approx")
    assert r["method"] == "approx" and r["p"] == pytest.approx(ref.pvalue, rel=1e-9)


def test_hodges_lehmann_interval_is_where_wilcoxon_stops_rejecting():
    stats = pytest.importorskip("scipy.stats")
    r = signed_rank(FIXED)
    walsh = sorted((a + b) / 2 for i, a in enumerate(FIXED) for b in FIXED[i:])
    assert r["hl"] == pytest.approx(float(np.median(walsh)))
    lo, hi = r["ci"]
    eps = 1e-9
    p = lambda mu: stats.wilcoxon([v - mu for v in FIXED], method="exact").pvalue  # noqa: E731
    assert p(lo + eps) > 0.05 >= p(lo - eps)
    assert p(hi - eps) > 0.05 >= p(hi + eps)
    assert r["ci_level"] >= 0.95


def test_hodges_lehmann_resists_one_outlying_world():
    base = [0.001, -0.002, 0.0005, 0.0015, -0.001, 0.002, -0.0005, 0.0]
    r = signed_rank(base + [0.2])
    assert abs(r["hl"]) < 0.002 and r["ci"][0] < 0 < r["ci"][1]
    assert np.mean(base + [0.2]) > 0.02  # the mean is carried by the one world


# --------------------------------------------------------------------------- variance split
def _worlds(tau, sig, n_seq, n_worlds, seed, planted=None):
    rng = np.random.default_rng(seed)
    out = {}
    for w in range(n_worlds):
        a_w = rng.normal(0.0, tau) + (planted if planted is not None and w == 0 else 0.0)
        rec_a = {f"s{s}": {"sum": [0.2 + a_w + rng.normal(0.0, sig)], "n": [1]} for s in range(n_seq)}
        rec_b = {f"s{s}": {"sum": [0.2], "n": [1]} for s in range(n_seq)}
        out[w] = (rec_a, rec_b)
    return out


@pytest.mark.parametrize("seed", [1, 2, 3])
def test_variance_split_recovers_noise_and_heterogeneity(seed):
    tau, sig, n_seq = 0.02, 0.03, 8
    sp = variance_split(_worlds(tau, sig, n_seq, 250, seed), draws=300)
    assert sp["var_noise"] == pytest.approx(sig ** 2 / n_seq, rel=0.12)
    assert sp["tau2"] == pytest.approx(tau ** 2, rel=0.3)
    assert 0.1 < sp["noise_share"] < 0.4   # truth: 0.0001125 / 0.0005125 = 0.22


def test_variance_split_without_heterogeneity_is_all_noise():
    sp = variance_split(_worlds(0.0, 0.03, 8, 250, 4), draws=300)
    assert sp["tau2"] < 0.25 * sp["var_noise"] and sp["noise_share"] > 0.75


def test_variance_split_flags_a_planted_outlier():
    sp = variance_split(_worlds(0.005, 0.01, 8, 30, 5, planted=0.08), draws=300)
    assert [w for w, _ in sp["outliers"]] == [0] and sp["z"][0] > OUTLIER_Z


def test_world_bootstrap_is_paired_and_refuses_other_sequences():
    rec = {"s0": {"sum": [0.1], "n": [1]}, "s1": {"sum": [0.5], "n": [1]}}
    r = world_bootstrap(rec, rec, draws=200)
    assert r["d"] == 0.0 and r["var"] == 0.0   # the same draw for both arms: no noise in a difference with itself
    with pytest.raises(ValueError, match="different sequences"):
        world_bootstrap(rec, {"s0": rec["s0"]})
