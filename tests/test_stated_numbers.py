"""Numbers the README and the reports' hand-written prefaces state about a committed sweep report agree with that
report's committed results.json, whatever it holds (issue 41, item 12: the README said "2.1 GB for its 27 runs" of
the 36-run main job, and two disk sizes for it; budget.md spoke of the committed sweep's "nine runs").

Each claim is a pattern in a file and what results.json says it must be: the run count (its rows), the (world, seed)
pairs (its seeds), the wall minutes of an invocation (`timing.this_invocation_s`, the latest one: a preface's
`[sweep] finished: N/N runs in ...` line or its minutes), the runs under the 1 cm INERT line. When a report is
regenerated from a new run, this test names every sentence to update, with the number it should say.
"""
from __future__ import annotations

import json
import math
import re
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
RESULTS = ROOT / "docs" / "results"
WORDS = {"one": 1, "two": 2, "three": 3, "four": 4, "five": 5, "six": 6, "seven": 7, "eight": 8, "nine": 9,
         "ten": 10, "eleven": 11, "twelve": 12}


def _results(name: str) -> dict:
    from study.results.files import read_results  # a compact results.json joined with its records

    return read_results(RESULTS / name / "results.json")


def _int(word: str) -> int:
    return int(word) if word.isdigit() else WORDS[word.lower()]


def _hms(seconds: float) -> str:
    """The sweep's own format of a wall time (`[sweep] finished: ... in 1h24m48s`)."""
    s = int(round(seconds))
    h, m, s = s // 3600, s // 60 % 60, s % 60
    return f"{h}h{m:02d}m{s:02d}s" if h else f"{m}m{s:02d}s" if m else f"{s}s"


def _runs(r: dict) -> int:
    return len(r["rows"])


def _wall_min(r: dict) -> float:
    return r["timing"]["this_invocation_s"] / 60


def _from_empty_min(name: str) -> str:
    """The wall minutes a preface states for its run from an empty folder (a report re-evaluated later records only
    the latest invocation in results.json, so the README is held to the preface)."""
    text = (RESULTS / name / "preface.md").read_text()
    m = re.search(r"from an empty folder: \*\*([\d.]+) min\*\*", text)
    assert m, f"docs/results/{name}/preface.md states no 'from an empty folder: **N min**'"
    return m.group(1)


def _inert(r: dict, method: str) -> tuple[int, int]:
    fl = [f for f in r["flat"] if f["method"] == method and f.get("variant", "trained") == "trained"]
    return sum(1 for f in fl if f.get("refine.depth_change_m", math.inf) < 0.01), len(fl)


#: (file, pattern with one or more groups, report, what the groups must be, given its results.json)
CLAIMS = [
    ("README.md", r"main job on its defaults: .*?\((\d+) min measured", "sweep_cpu",
     lambda r: (str(round(float(_from_empty_min("sweep_cpu")))),)),
    ("docs/RESULTS.md", r"one\s+run from an empty folder, ([\d.]+) min measured", "sweep_cpu",
     lambda r: (_from_empty_min("sweep_cpu"),)),
    ("docs/RESULTS.md", r"with seed k on world k \((\w+) \(world, seed\) pairs", "sweep_cpu", lambda r: (len(r["seeds"]),)),
    ("docs/RESULTS.md", r"paired over the (\w+) \(world, seed\) pairs", "sweep_cpu", lambda r: (len(r["seeds"]),)),
    ("docs/GUIDE.md", r"`cpu.yaml`: [\d.]+ GB of disk for its (\d+) runs", "sweep_cpu", lambda r: (_runs(r),)),
    ("docs/RESULTS.md", r"Without L_con the refinement barely moves: .*?(\d+) of (\d+) runs stay under 1 cm", "sweep_cpu",
     lambda r: _inert(r, "mcdp_m1_nocon")),
    ("docs/RESULTS.md", r"cpu_compare.yaml --out sweeps/cpu`, (\d+) min measured", "sweep_compare",
     lambda r: (round(_wall_min(r)),)),
    ("docs/RESULTS.md", r"reusing its\s+runs; (\w+) \(world, seed\) pairs\)", "sweep_compare", lambda r: (len(r["seeds"]),)),
    ("docs/RESULTS.md", r"90 min measured, (\w+) worlds x (\w+)\s+seeds", "propagation",
     lambda r: (len(r["seeds"]) // r["sweep_config"]["seeds_per_world"], r["sweep_config"]["seeds_per_world"])),
]
for _name in ("sweep_cpu", "propagation", "sweep_compare", "propagation_budget"):
    CLAIMS += [
        (f"docs/results/{_name}/preface.md", r"=[\s>]*(\d+) runs\.\*\*", _name, lambda r: (_runs(r),)),
        (f"docs/results/{_name}/preface.md", r"(\d+)/(\d+) runs in [0-9hms]+`", _name, lambda r: (_runs(r), _runs(r))),
    ]
CLAIMS += [
    ("docs/results/sweep_cpu/preface.md", r"one invocation: \*\*([\d.]+) min\*\*", "sweep_cpu",
     lambda r: (f"{_wall_min(r):.1f}",)),
    ("docs/results/sweep_compare/preface.md", r"one invocation:[\s>]+\*\*([\d.]+) min\*\*", "sweep_compare",
     lambda r: (f"{_wall_min(r):.1f}",)),
]


def _norm(x) -> str:
    return str(_int(x)) if isinstance(x, str) and x.lower() in WORDS else str(x)


@pytest.mark.parametrize("file,pattern,name,want", CLAIMS, ids=[f"{c[0]}:{c[2]}:{i}" for i, c in enumerate(CLAIMS)])
def test_a_stated_number_is_the_committed_reports(file, pattern, name, want):
    text = (ROOT / file).read_text()
    ms = list(re.finditer(pattern, text, re.S))
    assert ms, f"{file}: no sentence matching {pattern!r} (reworded? then update this test's claim)"
    expect = tuple(str(x) for x in want(_results(name)))
    for m in ms:
        got = tuple(_norm(g) for g in m.groups())
        assert got == expect, f"{file} says {m.group(0)!r}; docs/results/{name}/results.json says {expect}"


@pytest.mark.parametrize("name", ["sweep_cpu", "propagation", "sweep_compare", "propagation_budget"])
def test_each_preface_states_its_latest_invocations_wall_time(name):
    """results.json records the wall time of the sweep's latest invocation; the preface, which adds up every
    invocation, quotes it (as the sweep's `runs in 1h24m48s`, or in seconds)."""
    s = _results(name)["timing"]["this_invocation_s"]
    text = (RESULTS / name / "preface.md").read_text()
    assert f"runs in {_hms(s)}`" in text or f"{round(s)} s" in text, (name, _hms(s))


def test_the_main_job_has_one_disk_size_in_the_readme():
    """"3.2 GB of disk" at the top and "2.1 GB" for its 27 runs further down: one figure, stated the same way."""
    top = re.search(r"main job on its defaults: .*?\d+ min measured, ([\d.]+) GB of disk",
                    (ROOT / "README.md").read_text()).group(1)
    limits = re.search(r"`cpu.yaml`: ([\d.]+) GB of disk for its", (ROOT / "docs" / "GUIDE.md").read_text()).group(1)
    assert top == limits


def test_no_page_counts_the_committed_sweeps_runs_by_hand():
    """A page's words about "the committed sweep's N ... runs" must be the committed sweep_cpu's count (budget.md
    said "nine" of a sweep that has 12 such runs; it now names the 2026-12-02 data it was measured from)."""
    r = _results("sweep_cpu")
    per_method = len(r["overlaps"]) * len(r["seeds"])
    docs = [ROOT / "README.md", ROOT / "docs" / "GUIDE.md", ROOT / "docs" / "RESULTS.md"]
    for page in sorted(RESULTS.glob("*/page.md")) + sorted(RESULTS.glob("*/preface.md")) + docs:
        for m in re.finditer(r"committed sweep's (\w+) (?:such )?runs", page.read_text()):
            assert _norm(m.group(1)) in (str(per_method), str(_runs(r))), f"{page}: {m.group(0)!r}"


def test_the_sensor_follow_ups_stated_numbers_are_its_committed_results():
    """The sensor preface's primary figure and wall times are those of docs/results/sensor14_*/results.json (the
    figures are template fields, `study.report.preface`: read here as the page fills them)."""
    import importlib

    from study.report.sections.sensor import FIGURES, change, contrast

    ideal, cond = _results("sensor14_ideal"), _results("sensor14_exposure")
    page = importlib.import_module("scripts.publish_sensor").build().split("> Generated by")[0]
    text = " ".join(line.lstrip("> ") for line in page.splitlines())
    n = contrast(ideal, cond, FIGURES[0][0])
    assert n["n_worlds"] == 14 and f"MCDP (m = 2)'s change minus FSM's on median abs_rel is {n['mean']:+.4f} ± {n['ci95']:.4f}" in text
    for m, label in (("mono2", "Mono2"), ("fsm", "FSM"), ("mcdp_m2", "MCDP (m = 2)")):
        c = change(ideal, cond, m, FIGURES[0][0])
        assert f"{label} {c['mean']:+.4f} ± {c['ci95']:.4f}" in text, label
    dep = contrast(ideal, cond, FIGURES[1][0])
    assert f"their difference, {dep['mean']:+.4f} ± {dep['ci95']:.4f}" in text
    for name in ("sensor14_ideal", "sensor14_exposure"):
        assert _hms(_results(name)["timing"]["this_invocation_s"]) in text, name
