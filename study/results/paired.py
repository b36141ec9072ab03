"""Paired differences between two evaluations of a sweep, per (world, seed) pair: the report's every comparison of
two methods (or two evaluations of one), with its 95 % interval, clustered by world in a design that nests
several seeds in each world (`clustered`: then no comparison of a page reads a narrower interval than its
primary test)."""
from __future__ import annotations

import math

from study.results.summary import flat_of, mean_std
from study.sweep.variants import Evaluation


def paired_difference(results: dict, overlap: float, a: str | Evaluation, b: str | Evaluation, key: str) -> dict:
    """Mean and 95 % t-interval over seeds of (a - b) for the same seed (seeds pair the runs:
    same data order and pretraining); {"mean", "ci95", "n", "differs", "sd"} where differs is
    -1 (a lower), +1 (a higher) or 0 (the interval contains 0). a, b: evaluations (`Evaluation`, e.g.
    ``Evaluation(m, CUT)``) or method names (as trained)."""
    return paired_columns(results, overlap, (a, key), (b, key))


def paired_gain(results: dict, overlap: float, ref: str | Evaluation, new: str | Evaluation, key: str) -> dict:
    """What ``new`` gains over ``ref`` in column ``key``, paired as `paired_difference`, taken worse minus better
    (the one sign of every page: positive = ``new`` helps): ref − new where lower is better, new − ref where
    higher is (`mcdp.metrics.better`: e.g. a1)."""
    from mcdp.metrics import better

    return paired_difference(results, overlap, *((ref, new) if better(key) == "lower" else (new, ref)), key)


def world_of(results: dict) -> dict:
    """seed -> world id of the sweep (`study.sweep.config.world_of_seed`, from the recorded config); with one shared
    world, or one seed per world, each seed is its own cluster."""
    cfg = results.get("sweep_config", {}) or {}
    seeds = list(results.get("seeds", []))
    per = int(cfg.get("seeds_per_world", 1) or 1)
    if cfg.get("worlds") != "per_seed" or per == 1:
        return {s: s for s in seeds}
    return {s: i // per for i, s in enumerate(seeds)}


def clustered(results: dict) -> bool:
    """Whether the design nests several training seeds in each world (``worlds: per_seed``, ``seeds_per_world`` >
    1): then every paired interval of the report is clustered by world (`paired_columns`)."""
    ids = world_of(results)
    return len(set(ids.values())) < len(ids)


def paired_columns(results: dict, overlap: float, a: tuple[str | Evaluation, str],
                   b: tuple[str | Evaluation, str]) -> dict:
    """`paired_difference` of column a[1] of evaluation a[0] minus column b[1] of evaluation b[0] (e.g. a run's
    init stage against its ORACLE-overlap row). In a design with worlds (`clustered`) the interval is the primary
    comparisons' one, clustered by world (`study.stats.power.nested`: the mean of the world means, t with W - 1 degrees
    of freedom), so no comparison of the page reads a narrower interval than the primary test; ``n`` is then the
    number of (world, seed) pairs and ``sd`` the spread of the world means."""
    va = {f["seed"]: f.get(a[1]) for f in flat_of(results, overlap, a[0])}
    vb = {f["seed"]: f.get(b[1]) for f in flat_of(results, overlap, b[0])}
    keep = [s for s in va if s in vb and all(isinstance(x, (int, float)) and math.isfinite(x)
                                             for x in (va[s], vb[s]))]
    d = [va[s] - vb[s] for s in keep]
    if clustered(results):
        from study.stats.power import nested

        wo = world_of(results)
        groups: dict = {}
        for s, x in zip(keep, d):
            groups.setdefault(wo.get(s, s), []).append(float(x))
        ne = nested(groups)
        means = [sum(v) / len(v) for v in groups.values() if v]
        sd = mean_std(means)["std"]
        mu, hw, n = ne["mean"], ne["ci95"], ne["n"]
    else:
        ms = mean_std(d)
        mu, hw, n, sd = ms["mean"], ms["ci95"], ms["n"], ms["std"]
    differs = 0
    if math.isfinite(mu) and math.isfinite(hw):
        differs = -1 if mu + hw < 0 else (1 if mu - hw > 0 else 0)
    return {"mean": mu, "ci95": hw, "n": n, "differs": differs, "sd": sd}
