"""A results page's preface as a template (issue 60, item 3): every figure a preface states is a field filled from
the page's committed results when the page is built, never typed by hand.

A field is ``{dotted.path}`` or ``{dotted.path:spec}``, resolved in the page's values (`sweep_values`, and a page's
own, e.g. `study.report.sections.sensor.preface_values`): ``spec`` is a `format` spec (``+.4f``) or ``diffN``, a paired difference
with its interval through the one formatter (`study.results.summary.fmt_diff`, N decimals). Example::

    fill("MCDP (m = 2) gains {gain.mcdp_m2.o030.all:diff3} at 0.30", sweep_values(results))
    # -> 'MCDP (m = 2) gains +0.005 ± 0.012 at 0.30'

Anything else in braces is left as it is. A field the values do not hold is a `PrefaceError` naming it.
"""
from __future__ import annotations

import re
from typing import Any, Callable, Mapping

#: ``{a.b.c}`` or ``{a.b.c:spec}``: names of letters, digits and underscores
FIELD = re.compile(r"\{([A-Za-z_]\w*(?:\.\w+)*)(?::([^{}\s]*))?\}")
#: a figure with its interval typed by hand: a digit, then ± (or +-) and a digit
TYPED_FIGURE = re.compile(r"\d\s*(?:±|\+-)\s*\d")


class PrefaceError(ValueError):
    """A template field the page's values do not hold, or a spec that does not fit its value; one line."""


def _resolve(values: Mapping | Callable, path: list[str], field: str) -> Any:
    node: Any = values
    for i, name in enumerate(path):
        if callable(node) and not isinstance(node, Mapping):  # a family computed on demand: it reads the rest
            return node(path[i:])
        if not isinstance(node, Mapping) or name not in node:
            raise PrefaceError(f"{{{field}}}: no {name!r} here (the page's values hold "
                               f"{', '.join(sorted(node)) if isinstance(node, Mapping) else 'a value, not a table'})")
        node = node[name]
    return node


def fill(text: str, values: Mapping, where: str = "preface") -> str:
    """``text`` with every field filled from ``values``; PrefaceError naming ``where`` and the field."""
    from study.results.summary import fmt_diff

    def one(m: re.Match) -> str:
        field, spec = m.group(1), m.group(2) or ""
        try:
            v = _resolve(values, field.split("."), field)
            if spec.startswith("diff"):
                return fmt_diff(v, int(spec[4:] or 4))
            return format(v, spec)
        except PrefaceError as exc:
            raise PrefaceError(f"{where}: {exc}") from None
        except (KeyError, TypeError, ValueError) as exc:
            raise PrefaceError(f"{where}: {{{field}:{spec}}}: {exc}") from None

    return FIELD.sub(one, text)


def typed_figures(text: str) -> list[str]:
    """The figures with an interval typed by hand in a template: each 'x ± y' outside a field."""
    bare = FIELD.sub("FIELD", text)
    return [bare[max(0, m.start() - 20):m.end() + 8] for m in TYPED_FIGURE.finditer(bare)]


#: the regions a sweep page's gain fields name -> the flat-row key (median scaling)
GAIN_KEYS = {"all": "median.mean.abs_rel", "overlap": "median.overlap.abs_rel",
             "non_overlap": "median.non_overlap.abs_rel", "dep_con": "dep_con.mean"}


def _overlap(name: str) -> float:
    """``o030`` -> 0.30."""
    if not re.fullmatch(r"o\d{3}", name):
        raise PrefaceError(f"{name!r} is not an overlap field (o010 for 0.10)")
    return int(name[1:]) / 100.0


#: a band of distance from the overlap (fractions of the image width) a primary field may name -> its column's name
BANDS = {"band1": "0-0.10", "band2": "0.10-0.20", "band3": "0.20-0.35", "band4": ">0.35"}


def _dig(node: Any, rest: list[str], field: str) -> Any:
    """``node`` followed along ``rest`` (the field's names after a family's own)."""
    for name in rest:
        if not isinstance(node, Mapping) or name not in node:
            raise PrefaceError(f"{field}: no {name!r} here (the value holds "
                               f"{', '.join(sorted(map(str, node))) if isinstance(node, Mapping) else 'a number'})")
        node = node[name]
    return node


def _who(a, b) -> str:
    """The name a primary comparison is read by: the variant it compares against (a hand-built propagator, e.g.
    ``oracle_spread``), else the method of its first arm (``mcdp_m2``, ``mcdp_m2_nocon`` for (b), ``oracle_local``)."""
    from study.sweep.variants import TRAINED, cut

    return b.variant if b.variant not in (TRAINED, cut()) else a.method


def sweep_values(results: dict, parts: Mapping[str, dict] | None = None) -> dict:
    """The values a sweep page's preface reads from its results.json (and, for a page whose row of `study.report.pages`
    names more parts, theirs):

    - ``gain.<method>.o<overlap>.<region>``: what ``method`` gains over the baseline, paired (`study.results.paired.
      paired_gain`: baseline - method on a lower-is-better figure, positive = helps), at overlap o030 = 0.30, on
      ``region`` (`GAIN_KEYS`: all, overlap, non_overlap pixels at median scaling, or dep_con);
    - ``primary.<id>.<who>[.o<overlap>][.<scaling>][.<band>]``: a primary comparison of the propagation experiment
      (`study.report.sections.primary.comparisons`; ``who``: `_who`, e.g. ``a.mcdp_m2`` = MCDP (m = 2) cut - as trained), its
      `study.stats.design.reading_over_worlds` on non-overlap pixels (or a band of `BANDS`) at the plan's overlap and
      median scaling unless named; the names after it read into the reading (``.tost.p``, ``.mde80``, ``.rank.hl``);
    - ``copy.o<overlap>.<scaling>.{filled,base,ratio}``: the positive control's copy test (`study.report.sections.primary.copy_test`);
    - ``lcon.<scaling>``: L_con's (b) over the worlds (`study.report.sections.lcon.reading` of the sweep's pairs);
    - ``part.<name>``: these values of another part the page's row names, e.g. ``part.lcon_main.lcon.median``;
    - ``plan``: the sweep's plan (`study.report.sections.primary.plan_of`), e.g. ``plan.delta``."""
    from mcdp.methods import baseline
    from study.report.sections.primary import SCALINGS, comparisons, copy_test, measure, plan_of

    plan = plan_of(results)

    def gain(path: list[str]) -> dict:
        if len(path) != 3 or path[2] not in GAIN_KEYS:
            raise PrefaceError(f"gain.{'.'.join(path)}: want gain.<method>.o<overlap>.<region>, region one of "
                               f"{', '.join(GAIN_KEYS)}")
        from study.results.paired import paired_gain

        method, o, region = path[0], _overlap(path[1]), path[2]
        if method not in results.get("methods", []):
            raise PrefaceError(f"gain.{'.'.join(path)}: {method!r} is not one of the sweep's methods")
        return paired_gain(results, o, baseline(), method, GAIN_KEYS[region])

    def primary(path: list[str]) -> Any:
        field = "primary." + ".".join(path)
        if len(path) < 2:
            raise PrefaceError(f"{field}: want primary.<id>.<who>[.o<overlap>][.<scaling>][.<band>]")
        rest, o, sc, region = list(path[2:]), plan["overlap"], "median", "non_overlap"
        if rest and re.fullmatch(r"o\d{3}", rest[0]):
            o = _overlap(rest.pop(0))
        if rest and rest[0] in SCALINGS:
            sc = rest.pop(0)
        if rest and rest[0] in BANDS:
            region = BANDS[rest.pop(0)]
        for cid, _, a, b, _ in comparisons(results, o):
            if cid == path[0] and _who(a, b) == path[1]:
                return _dig(measure(results, o, a, b, region)[sc], rest, field)
        raise PrefaceError(f"{field}: no such primary comparison in this sweep")

    def copy(path: list[str]) -> Any:
        field = "copy." + ".".join(path)
        if len(path) != 3 or path[1] not in SCALINGS or path[2] not in ("filled", "base", "ratio"):
            raise PrefaceError(f"{field}: want copy.o<overlap>.<scaling>.filled|base|ratio")
        o = _overlap(path[0])
        row = next((r for r in copy_test(results) if abs(r["overlap"] - o) < 1e-9), None)
        if row is None:
            raise PrefaceError(f"{field}: no copy test at overlap {o:.2f} in this sweep")
        return row[path[1]][("filled", "base", "ratio").index(path[2])]

    def lcon(path: list[str]) -> Any:
        from study.report.sections.lcon import pairs, reading

        if not path or path[0] not in SCALINGS:
            raise PrefaceError(f"lcon.{'.'.join(path)}: want lcon.<scaling> ({', '.join(SCALINGS)})")
        ps = pairs(results)
        if not ps:
            raise PrefaceError(f"lcon.{'.'.join(path)}: this sweep has no L_con pair")
        return _dig(reading(ps, path[0], plan), path[1:], "lcon." + ".".join(path))

    out = {"gain": gain, "primary": primary, "copy": copy, "lcon": lcon, "plan": plan}
    if parts:
        out["part"] = {name: sweep_values(r) for name, r in parts.items() if r is not None}
    return out
