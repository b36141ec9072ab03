"""The README is a front page (issue 60, item 6): what it is, a picture above the fold, the two commands first, a
five-line quickstart, a short table of headline answers each linking to its page (every figure in a row is its
page's, verbatim), links to the docs; everything else lives in docs/GUIDE.md, docs/RESULTS.md and docs/TRUST.md."""
from __future__ import annotations

import re
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
README = ROOT / "README.md"
#: the README's first two command lines before issue 60, kept as they were (.ci/run runs the second)
FIRST_TWO = ("bash scripts/setup.sh && .venv/bin/mcdp sweep configs/sweep/cpu.yaml --out sweeps/cpu",
             "bash scripts/setup.sh --test && .venv/bin/python -m pytest -q -n 2 --dist loadfile")
FIGURE = re.compile(r"[+-]?\d+\.\d+(?:e[+-]\d+)? ± \d+\.\d+(?:e[+-]\d+)?")


def _lines() -> list[str]:
    return README.read_text().splitlines()


def test_the_readme_is_a_front_page():
    lines = _lines()
    assert len(lines) <= 150, len(lines)
    picture = next(i for i, line in enumerate(lines) if re.match(r"!\[.+\]\((.+\.png)\)", line))
    assert picture < 15 and (ROOT / re.match(r"!\[.+\]\((.+\.png)\)", lines[picture]).group(1)).is_file()
    commands = [line for line in lines if line and not line.startswith("#") and "&&" in line]
    assert tuple(commands[:2]) == FIRST_TWO
    assert FIRST_TWO[1] in (ROOT / ".ci" / "run").read_text()
    quick = re.search(r"Quickstart.*?```bash\n(.*?)```", README.read_text(), re.S).group(1).strip().splitlines()
    assert len(quick) == 5, quick
    for doc in ("docs/GUIDE.md", "docs/RESULTS.md", "docs/TRUST.md", "docs/DESIGN.md"):
        assert f"]({doc}" in README.read_text() and (ROOT / doc).is_file(), doc


def test_every_headline_figure_is_its_pages():
    rows = [line for line in _lines() if line.startswith("| ") and "](docs/results/" in line]
    assert len(rows) >= 5
    for row in rows:
        page = re.findall(r"\]\((docs/results/[\w.-]+\.md)\)", row)[-1]
        figures = FIGURE.findall(row)
        text = " ".join((ROOT / page).read_text().split())
        if page == "docs/results/calibration.md":  # its sentence: the same-sign count and rho, as the page has them
            k = re.search(r"reproduces (\d+ of \d+) resolved", row).group(1)
            rho = re.search(r"ρ = ([+-]\d\.\d\d)", row).group(1)
            assert f"reproduces {k} resolved" in text and f"ρ = {rho}" in text, row
        assert figures, row
        for fig in figures:
            assert fig in text, f"{fig} is not on {page}"
        for number in re.findall(r"(?<![\d.])[+-]?\d+\.\d{3,}(?:e[+-]\d+)?", row):  # a level, a yardstick, a rate
            assert re.search(rf"(?<![\d.]){re.escape(number)}(?![\d])", text), f"{number} is not on {page}"


def test_the_docs_links_resolve():
    """Every relative link of the README and of the files its text moved to points at a file that exists."""
    for doc in (README, ROOT / "docs" / "GUIDE.md", ROOT / "docs" / "RESULTS.md", ROOT / "docs" / "TRUST.md"):
        for target in re.findall(r"\]\(([^)#\s]+)(?:#[^)]*)?\)", doc.read_text()):
            if re.match(r"https?:", target):
                continue
            assert (doc.parent / target).exists(), f"{doc.name}: {target}"
