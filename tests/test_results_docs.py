"""Every benchmark script names the doc it feeds ("Feeds: docs/...") and that doc names the script back;
every committed report under docs/results/ names the command that made it (a benchmark, the sweep preset
with scripts/publish_sweep.py)."""
from __future__ import annotations

import re
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def _feeds(script: Path) -> list[str]:
    m = re.search(r"^Feeds: (.+)$", script.read_text(), re.M)
    return [d.strip() for d in m.group(1).split(",")] if m else []


def test_every_benchmark_names_its_doc_and_back():
    scripts = sorted(s for s in (ROOT / "benchmarks").glob("*.py") if not s.name.startswith("_"))  # _table: a helper
    assert len(scripts) >= 10
    for s in scripts:
        docs = _feeds(s)
        assert docs, f"{s.name}: no 'Feeds: docs/...' line in its docstring"
        for d in docs:
            assert (ROOT / d).is_file() and d.startswith("docs/"), f"{s.name} feeds {d}, which does not exist"
            assert f"benchmarks/{s.name}" in (ROOT / d).read_text(), f"{d} does not name benchmarks/{s.name}"


def test_every_report_names_its_command():
    fed = {d for s in (ROOT / "benchmarks").glob("*.py") for d in _feeds(s)}
    for doc in sorted((ROOT / "docs" / "results").glob("*.md")):
        rel = f"docs/results/{doc.name}"
        text = doc.read_text()
        by_sweep = "scripts/publish_sweep.py" in text and re.search(r"mcdp sweep configs/sweep/\S+\.yaml", text)
        assert rel in fed or by_sweep, f"{rel}: names neither a benchmark that feeds it nor its sweep command"
