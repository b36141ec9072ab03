"""The results of a sweep as one JSON-able dict: flat per-run rows, mean / std and 95 % Student-t
intervals over seeds, paired differences between methods, and the yardsticks per overlap.

`build_results` turns the per-run rows of `study.sweep.stages.run_stage` into that dict; `study.report.compose`
and `study.report.plots` only read it. Nothing here chooses or filters numbers: NaN stays NaN.

Every flat row and aggregate entry is one evaluation of a run (`study.sweep.variants.Evaluation`): its
``method`` (the registry name) and ``variant`` (as trained, cut, ORACLE weights, ...); a lookup takes
either an Evaluation or a method name (that method as trained). `study.results.files.read_results` reads a
results.json or results.csv, also one written before the variant field (`upgrade_results`).
"""
from __future__ import annotations

import math
import time
from typing import Any

from mcdp.methods import baseline
from study.stats.power import t_halfwidth
from study.sweep.records import flat_row
from study.sweep.variants import CUT, ORACLE, ORACLE_OVL, SPREAD, TRAINED, VARIANTS, Evaluation


SCALE_LABEL = {"none": "metric", "median": "median", "rig_median": "rig median"}


#: how a paired difference reads in the report (`paired_difference`'s ``differs``), by which way its metric is
#: better (`mcdp.metrics.better`)
VERDICT_WORD = {"lower": {-1: "**lower (better)**", 1: "**higher (worse)**", 0: "no difference beyond the interval"},
                "higher": {-1: "**lower (worse)**", 1: "**higher (better)**", 0: "no difference beyond the interval"}}
#: how a gain reads (a paired difference taken worse minus better, the one sign of every page: positive = helps)
GAIN_WORD = {1: "**helps**", -1: "**hurts**", 0: "no difference beyond the interval"}


def fmt_num(x, digits: int = 3) -> str:
    """A number for the report; 'nan' for anything not finite."""
    return f"{x:.{digits}f}" if isinstance(x, (int, float)) and math.isfinite(x) else "nan"


#: a difference of median-scaled abs_rel (or of the Dep Con ratio, an error ratio of the same size) smaller than
#: this is negligible even when beyond its interval: a tenth of a percent of a typical abs_rel of 0.2 (float noise
#: of identical seeds is ~1e-5; a network whose cut moves its depth by 0.1 mm differs by ~1e-8)
USE_FLOOR = 0.0005


def fmt_diff(pd: dict, digits: int = 3) -> str:
    """The one formatter of a paired difference (every page's tables, verdicts and headlines): 'mean ± half-width'
    of a dict with ``mean`` and ``ci95`` (`paired_difference`, `study.stats.power.nested`, `study.stats.design.reading_over_worlds`).
    A non-zero mean that rounds to zero at `digits` is written in scientific notation (so '+0.0000' never stands
    for a difference that is there); a mean without an interval (one world or seed) says so, '+0.0123 (no
    interval)', never '± nan'; nothing measured (no finite mean) is '—'. The sign is the page's, one for the
    whole project: positive = helps (docs/DESIGN.md, "Sign convention")."""
    mu, ci = pd.get("mean"), pd.get("ci95")
    if not (isinstance(mu, (int, float)) and math.isfinite(mu)):
        return "—"
    has_ci = isinstance(ci, (int, float)) and math.isfinite(ci)
    tiny = mu != 0 and abs(mu) < 0.5 * 10 ** -digits
    head = f"{mu:+.1e}" if tiny else f"{mu:+.{digits}f}"
    if not has_ci:
        return f"{head} (no interval)"
    return f"{head} ± " + (f"{ci:.1e}" if tiny else f"{ci:.{digits}f}")


def verdict_word(pd: dict, floor: float = 0.0, *, key: str) -> str:
    """VERDICT_WORD of a paired difference of column ``key`` (its metric says which way is better,
    `mcdp.metrics.better`); beyond its interval but smaller than `floor` in size is said to be negligible, not
    better or worse."""
    from mcdp.metrics import better

    if pd["differs"] != 0 and abs(pd["mean"]) < floor:
        return f"beyond the interval but negligible (< {floor:g})"
    return VERDICT_WORD[better(key)][pd["differs"]]


def gain_word(pd: dict, floor: float = 0.0) -> str:
    """GAIN_WORD of a gain (a paired difference taken worse minus better: positive = helps), as `verdict_word`."""
    if pd["differs"] != 0 and abs(pd["mean"]) < floor:
        return f"beyond the interval but negligible (< {floor:g})"
    return GAIN_WORD[pd["differs"]]


#: the method every other one is compared with (paired differences, the "vs Mono2" columns of the report): the
#: registry's row with ``baseline=True`` (`mcdp.methods.baseline`)
BASELINE = baseline()
#: the file name of the figure of every method's paired gain over the baseline (`study.report.plots.paired_plot`)
PAIRED_PLOT = f"paired_vs_{BASELINE}.png"


#: the keys a row of results written before ``row["evaluations"]`` held its evaluations under: {variant: (metrics
#: key, refinement key)}, and the as-trained init stage under ``metrics_init`` (`row_evaluations`)
LEGACY_ROW_KEYS = {TRAINED: ("metrics", "refinement"), CUT: ("metrics_cut", "refinement_cut"),
                   ORACLE: ("metrics_oracle", None), ORACLE_OVL: ("metrics_oracle_overlap", None),
                   SPREAD: ("metrics_oracle_spread", None)}


def row_evaluations(row: dict) -> dict[str, dict]:
    """A run's evaluations, {variant: entry} (`study.sweep.variants.entries_of`): ``row["evaluations"]``, or for a row
    written before it (its legacy keys, `LEGACY_ROW_KEYS`: the one reader of them) the same entries."""
    if "evaluations" in row:
        return row["evaluations"]
    out: dict[str, dict] = {}
    for variant, (mk, rk) in LEGACY_ROW_KEYS.items():
        if row.get(mk):
            out[variant] = {"metrics": row[mk], **({"refinement": row.get(rk)} if rk else {})}
    if TRAINED in out and row.get("metrics_init"):
        out[TRAINED]["init"] = row["metrics_init"]
    return out


def flat_rows(row: dict) -> list[dict[str, Any]]:
    """A run's CSV rows, one per evaluation (`study.sweep.variants`, in `VARIANTS` order): as trained, and where
    evaluated, e.g. with its neighbours cut at inference (variant ``cut``) and its bases at weights fitted to
    ground truth (``oracle``, ``oracle_overlap``: ORACLE yardsticks); each variant's ``columns`` adds its own."""
    evs = row_evaluations(row)
    base = flat_row({**row, "metrics": evs.get(TRAINED, {}).get("metrics")})
    base["variant"] = TRAINED
    out = [base]
    for name, variant in VARIANTS.items():
        entry = evs.get(name, {} if name == TRAINED else None)  # a run without metrics: its NaN refine columns
        if entry is None:
            continue
        own = base if name == TRAINED else flat_row({"metrics": entry["metrics"]})
        if variant.columns is not None:
            variant.columns(base, own, entry)
        if name != TRAINED:
            for k in ("overlap", "method", "seed", "world", "status", "steps", "checkpoint_step"):
                if k in base:
                    own[k] = base[k]
            own["variant"] = name
            out.append(own)
    return out


def mean_std(values: list[float]) -> dict:
    """Mean, sample std and 95 % t half-width of the finite `values` (NaN when none), with the counts."""
    v = [x for x in values if isinstance(x, (int, float)) and math.isfinite(x)]
    n_nan = len(values) - len(v)
    if not v:
        return {"mean": float("nan"), "std": float("nan"), "ci95": float("nan"), "n": 0, "n_nan": n_nan,
                "values": values}
    mu = sum(v) / len(v)
    sd = math.sqrt(sum((x - mu) ** 2 for x in v) / (len(v) - 1)) if len(v) > 1 else 0.0
    return {"mean": mu, "std": sd, "ci95": t_halfwidth(sd, len(v)), "n": len(v), "n_nan": n_nan, "values": values}


def flat_of(results: dict, overlap: float, ev: str | Evaluation) -> list[dict]:
    """The flat rows (one per seed) of one evaluation at one overlap; a method name: as trained."""
    ev = Evaluation.of(ev)
    return [f for f in results["flat"] if f["overlap"] == overlap and ev.matches(f)]


def build_results(cfg, data: list[dict], rows: list[dict], counters: dict, total_s: float,
                  previews: list[str]) -> dict:
    """Everything the report shows, JSON-able (NaN allowed)."""
    from corelib.configlib import config_hash, config_to_dict

    flats = [f for r in rows for f in flat_rows(r)]
    evs = evaluations_of(cfg.methods, flats)
    aggregate = aggregate_flat(flats, [d["overlap"] for d in data], evs)
    timing = {
        "render_s": sum(_nz(d["render_s"]) for d in data),
        "train_s": sum(_nz(r.get("train_s")) for r in rows),
        "eval_s": sum(_nz(r.get("eval_s")) for r in rows),
        "this_invocation_s": total_s,
        "note": "render/train/eval seconds are those of the invocation that did the work (skipped stages keep "
                "their recorded time); this_invocation_s is the wall time of the latest invocation",
    }
    return {
        "schema": SCHEMA,
        "created": time.strftime("%Y-%m-%d %H:%M:%S"),
        "sweep_config": config_to_dict(cfg),
        "sweep_config_hash": config_hash(cfg),
        "split": "test",
        "overlaps": list(cfg.overlaps),
        "methods": list(cfg.methods),
        "evaluations": [e.record() for e in evs],
        "seeds": list(cfg.seeds),
        "counters": counters,
        "timing": timing,
        "data": data,
        "rows": rows,
        "flat": flats,
        "aggregate": aggregate,
        "previews": previews,
    }


def evaluations_of(methods, flats: list[dict]) -> list[Evaluation]:
    """The sweep's methods as trained, each followed by those of its other evaluations (cut, ORACLE weights,
    ...: `study.sweep.variants.VARIANTS` order) that have rows."""
    return [e for m in methods for e in (Evaluation(m, v) for v in VARIANTS)
            if e.variant == TRAINED or any(e.matches(f) for f in flats)]


def evaluations(results: dict) -> list[Evaluation]:
    """The results' evaluations (``results["evaluations"]``) as `Evaluation` keys."""
    return [Evaluation.of(e) for e in results.get("evaluations", [])]


def aggregate_flat(flats: list[dict], overlaps, evs: list[Evaluation]) -> list[dict]:
    """Per (overlap, evaluation): `mean_std` over seeds of every dotted column of its first row."""
    aggregate = []
    for o in overlaps:
        for ev in evs:
            fr = [f for f in flats if f["overlap"] == o and ev.matches(f)]
            keys = [k for k in (fr[0] if fr else {}) if "." in k]
            aggregate.append({"overlap": o, **ev.record(), "seeds": [f["seed"] for f in fr],
                              "status": sorted({f["status"] for f in fr}),
                              "metrics": {k: mean_std([f.get(k, float("nan")) for f in fr]) for k in keys}})
    return aggregate


#: results.json's ``schema``. 2: every flat row and aggregate entry has ``method`` (the registry name) and
#: ``variant`` (`study.sweep.variants`) fields, results.csv a ``variant`` column. A results.json without it, or a
#: results.csv without that column (1), named an evaluation by a suffix on its method ("mcdp_m2@cut"):
#: `upgrade_results` reads them.
SCHEMA = 2


def upgrade_results(results: dict) -> dict:
    """``results`` in the current `SCHEMA` (the same dict if it is). Results written before the variant field
    (no ``schema``: 1) named each evaluation by a suffix on its method ("mcdp_m2", "mcdp_m2@cut",
    "mcdp_m2@oracle", "mcdp_m2@oracle_overlap"): their flat rows, aggregate and evaluations get the method's
    registry name and a ``variant`` field instead. The one reader of such names; a results.csv's rows come
    here as ``{"flat": rows}`` (`study.results.files.results_from_csv`)."""
    schema = results.get("schema", 1)
    if schema == SCHEMA:
        return results
    if schema != 1:
        raise ValueError(f"results schema {schema!r}: this code reads schema {SCHEMA} and the legacy 1")

    def split(rec: dict) -> dict:  # "mcdp_m2@cut" -> method "mcdp_m2", variant "cut", in the method's place
        method, _, variant = rec["method"].partition("@")
        ev = Evaluation(method, variant or TRAINED)
        out: dict[str, Any] = {}
        for k, v in rec.items():
            out[k] = v
            if k == "method":
                out.update(ev.record())
        return out

    out = {"schema": SCHEMA, **results}
    for part in ("flat", "aggregate"):
        if part in results:
            out[part] = [split(r) for r in results[part]]
    if "evaluations" in results:
        out["evaluations"] = [split({"method": name}) for name in results["evaluations"]]
    return out


def _nz(x) -> float:
    return x if isinstance(x, (int, float)) and math.isfinite(x) else 0.0


def method_agg(results: dict, overlap: float, ev: str | Evaluation, key: str) -> dict:
    """An evaluation's aggregate over seeds of `key` at one overlap (``{"mean", "std", "n", ...}``; NaN if
    absent); ``ev``: an `Evaluation` (e.g. ``Evaluation(m, CUT)``) or a method name (as trained)."""
    ev = Evaluation.of(ev)
    for a in results["aggregate"]:
        if a["overlap"] == overlap and ev.matches(a):
            return a["metrics"].get(key, {"mean": float("nan"), "std": float("nan"), "n": 0})
    return {"mean": float("nan"), "std": float("nan"), "n": 0}


REF_LABEL = "Constant depth (ref.)"


PRIOR_LABEL = "Flat-road prior (ref.)"


YARDSTICKS = (("reference", REF_LABEL, "constant_reference"), ("prior", PRIOR_LABEL, "flat_road_prior"))


def yardstick_row(results: dict, overlap: float, which: str = "reference") -> dict:
    """A yardstick's numbers at one overlap as a flat row (`flat_row`; {} if absent)."""
    for d in results["data"]:
        if d["overlap"] == overlap and d.get(which):  # "row": already flat (`study.results.files.results_from_csv`)
            return d[which]["row"] if "row" in d[which] else flat_row({"metrics": d[which]["metrics"]})
    return {}


def yardstick_agg(results: dict, overlap: float, key: str, which: str = "reference") -> dict:
    """A yardstick's value of `key` at one overlap (``which``: reference = constant, prior = flat road),
    in `method_agg`'s shape (NaN if absent)."""
    v = yardstick_row(results, overlap, which).get(key, float("nan"))
    return {"mean": v, "std": 0.0, "n": 1 if math.isfinite(v) else 0}
