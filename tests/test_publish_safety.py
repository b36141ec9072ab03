"""Writers never write through a link, and the publishing scripts read only what they publish from
(issue 41, items 2-4): `corelib.atomic`'s rule (a linked file is replaced, a linked folder refused), the sweep's
plots, `scripts/publish_bench.py` (regular files inside docs/results/, a FIFO refused unread) and
`scripts/publish_sweep.py --sweep` (everything read and checked before anything is written)."""
from __future__ import annotations

import importlib
import json
import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

from corelib.atomic import LinkRefused, atomic_write_bytes, make_folder

ROOT = Path(__file__).resolve().parents[1]
PROP = ROOT / "docs" / "results" / "propagation"


def _tree(folder: Path) -> dict[str, bytes | str]:
    """Every entry below ``folder``: a file's bytes, a link's target."""
    out: dict[str, bytes | str] = {}
    for p in sorted(folder.rglob("*")):
        rel = p.relative_to(folder).as_posix()
        out[rel] = f"-> {os.readlink(p)}" if p.is_symlink() else p.read_bytes() if p.is_file() else "dir"
    return out


# --------------------------------------------------------------------------- item 2: the writers' rule
def test_an_atomic_write_replaces_a_link_and_never_writes_through_it(tmp_path):
    target = tmp_path / "theirs.png"
    target.write_bytes(b"someone else's file")
    link = tmp_path / "plot.png"
    link.symlink_to(target)
    atomic_write_bytes(link, b"ours")
    assert target.read_bytes() == b"someone else's file"
    assert not link.is_symlink() and link.read_bytes() == b"ours"


def test_a_linked_folder_is_refused_in_one_line(tmp_path):
    (tmp_path / "elsewhere").mkdir()
    (tmp_path / "plots").symlink_to(tmp_path / "elsewhere")
    with pytest.raises(LinkRefused) as exc:
        make_folder(tmp_path / "plots")
    from corelib.atomic import file_error_message, is_user_file_error

    assert is_user_file_error(exc.value)
    line = file_error_message(exc.value)
    assert "\n" not in line and str(tmp_path / "plots") in line and "symbolic link" in line


def test_the_sweeps_plots_replace_linked_files_of_a_copied_sweep(tmp_path):
    """A `cp -a` copy of a sweep folder whose plots are links to the original's: a rerun's plots replace the
    links and leave the original's files as they were."""
    from study.report.plots import make_plots
    from study.results.files import read_results

    orig = tmp_path / "orig"
    orig.mkdir()
    copy = tmp_path / "copy" / "plots"
    copy.mkdir(parents=True)
    for name in ("abs_rel_vs_overlap.png", "paired_vs_mono2.png"):
        (orig / name).write_bytes(b"the original's plot")
        (copy / name).symlink_to(orig / name)
    made = make_plots(read_results(PROP / "results.json"), copy)
    assert {p.name for p in made} >= {"abs_rel_vs_overlap.png", "paired_vs_mono2.png"}
    assert all((orig / n).read_bytes() == b"the original's plot" for n in ("abs_rel_vs_overlap.png",
                                                                           "paired_vs_mono2.png"))
    assert not any(p.is_symlink() for p in copy.iterdir())


# --------------------------------------------------------------------------- publish_sweep (items 2 and 4)
@pytest.fixture
def publish(tmp_path, monkeypatch):
    """scripts/publish_sweep.py with docs/results/ in a temporary copy holding the committed propagation report
    (and the results of the other parts its preface reads: its row of study/report/pages.py)."""
    from study.report.pages import sweep_row

    mod = importlib.import_module("scripts.publish_sweep")
    results = tmp_path / "docs" / "results"
    shutil.copytree(PROP, results / "propagation")
    for part in sweep_row("propagation").parts[1:]:
        (results / part).mkdir()
        for n in ("results.json", "records.json.gz"):
            shutil.copy(PROP.parent / part / n, results / part / n)
    shutil.copy(PROP.with_suffix(".md"), results / "propagation.md")
    monkeypatch.setattr(mod, "RESULTS", results)
    return mod


@pytest.fixture
def sweep(tmp_path):
    """A sweep folder as `mcdp sweep` leaves it: results.json and its two rig previews."""
    s = tmp_path / "sweep"
    s.mkdir()
    from study.results.files import read_results

    for n in ("preview_overlap_0.10.png", "preview_overlap_0.60.png"):
        shutil.copy(PROP / n, s / n)
    (s / "results.json").write_text(json.dumps(read_results(PROP / "results.json"), indent=1))  # whole, as a sweep's
    return s


def _run(mod, argv, capsys) -> tuple[int, list[str]]:
    rc = mod.main(argv)
    return rc, capsys.readouterr().err.strip().splitlines()


def test_publish_sweep_rebuilds_the_committed_report(publish, sweep, capsys):
    rc, err = _run(publish, ["--name", "propagation", "--sweep", str(sweep)], capsys)
    assert rc == 0, err
    out = publish.RESULTS
    assert (out / "propagation.md").read_text() == PROP.with_suffix(".md").read_text()
    for n in ("results.json", "records.json.gz"):  # compact, the same bytes as committed (a fixed gzip time stamp)
        assert (out / "propagation" / n).read_bytes() == (PROP / n).read_bytes(), n


def test_publish_sweep_replaces_linked_plots_and_refuses_a_linked_plots_folder(publish, tmp_path, capsys):
    theirs = tmp_path / "theirs.png"
    theirs.write_bytes(b"not ours")
    plot = publish.RESULTS / "propagation" / "plots" / "paired_vs_mono2.png"
    plot.unlink()
    plot.symlink_to(theirs)
    rc, err = _run(publish, ["--name", "propagation"], capsys)
    assert rc == 0, err
    assert theirs.read_bytes() == b"not ours" and not plot.is_symlink() and plot.read_bytes().startswith(b"\x89PNG")

    plots = publish.RESULTS / "propagation" / "plots"
    shutil.rmtree(plots)
    (tmp_path / "elsewhere").mkdir()
    plots.symlink_to(tmp_path / "elsewhere")
    rc, err = _run(publish, ["--name", "propagation"], capsys)
    assert rc == 2 and len(err) == 1 and str(plots) in err[0] and "symbolic link" in err[0], err
    assert list((tmp_path / "elsewhere").iterdir()) == []


@pytest.mark.parametrize("case", ["secret", "system", "preface", "not_json", "malformed", "fifo", "outside_json"])
def test_publish_sweep_reads_and_checks_everything_before_writing_anything(publish, sweep, tmp_path, capsys, case):
    results = json.loads((sweep / "results.json").read_text())
    secret = tmp_path / "secret.txt"
    secret.write_text("a private key")
    secret.chmod(0o600)
    named = str(sweep / "results.json")
    if case in ("secret", "system"):
        (sweep / "preview_overlap_0.10.png").unlink()
        (sweep / "preview_overlap_0.10.png").symlink_to(secret if case == "secret" else "/etc/passwd")
        named = str(sweep / "preview_overlap_0.10.png")
    elif case == "preface":
        (sweep / "preface.md").write_text("# not the committed preface\n")
        results["previews"] = ["preface.md"]
        (sweep / "results.json").write_text(json.dumps(results))
    elif case == "not_json":
        (sweep / "results.json").write_text("<html>not json</html>")
    elif case == "malformed":
        results["flat"] = {"not": "a list"}
        (sweep / "results.json").write_text(json.dumps(results))
    elif case == "fifo":
        (sweep / "results.json").unlink()
        os.mkfifo(sweep / "results.json")
    elif case == "outside_json":
        (sweep / "results.json").unlink()
        (sweep / "results.json").symlink_to(PROP / "results.json")
    before = _tree(publish.RESULTS)
    rc, err = _run(publish, ["--name", "propagation", "--sweep", str(sweep)], capsys)
    assert rc == 2 and len(err) == 1 and named in err[0], err
    assert {"preface": "'previews[0]'", "malformed": "'flat'", "not_json": "not JSON",
            "fifo": "FIFO"}.get(case, "") in err[0], err
    assert _tree(publish.RESULTS) == before  # nothing written, the committed preface and results.json kept


# --------------------------------------------------------------------------- item 3: publish_bench reads only docs/results/
def _bench(tmp_path: Path, page: str) -> Path:
    results = tmp_path / "results"
    (results / "doc").mkdir(parents=True)
    (results / "doc" / "page.md").write_text(page)
    return results


def _main_bench(results: Path, *argv: str) -> subprocess.CompletedProcess:
    """publish_bench.py in a child process (a read that blocks would hang the test: it is killed at 60 s)."""
    code = ("import sys; sys.path.insert(0, sys.argv[1]); import scripts.publish_bench as pb; from pathlib import Path; "
            "pb.RESULTS = Path(sys.argv[2]); raise SystemExit(pb.main(sys.argv[3:]))")
    return subprocess.run([sys.executable, "-c", code, str(ROOT), str(results), *argv], capture_output=True,
                          text=True, timeout=60)


@pytest.mark.parametrize("case", ["page_link", "data_link", "fifo", "name"])
def test_publish_bench_reads_only_regular_files_inside_docs_results(tmp_path, case):
    secret = tmp_path / "secret.csv"
    secret.write_text("key,value\nprivate,42\n")
    secret.chmod(0o600)
    results = _bench(tmp_path, "# T\n\n{{table data.csv}}\n")
    doc = results / "doc"
    if case == "page_link":
        (doc / "page.md").unlink()
        (doc / "page.md").symlink_to(secret)
        named = doc / "page.md"
    elif case == "data_link":
        (doc / "data.csv").symlink_to(secret)
        named = doc / "data.csv"
    elif case == "fifo":
        os.mkfifo(doc / "data.csv")
        named = doc / "data.csv"
    argv = ["--name", "../secret" if case == "name" else "doc"]
    if case == "name":
        named = "--name"
    got = _main_bench(results, *argv)
    err = got.stderr.strip().splitlines()
    assert got.returncode == 2 and len(err) == 1 and str(named) in err[0], got.stderr
    assert "private" not in got.stdout + got.stderr and not (results / "doc.md").exists()


def test_publish_bench_all_checks_every_page_before_writing_any(tmp_path, monkeypatch, capsys):
    """Issue 49, item 8: `--all` wrote the earlier pages before refusing a later one; now a bad page leaves every
    page as it was."""
    pb = importlib.import_module("scripts.publish_bench")
    for name, body in (("a_good", "# A\n\ntext\n"), ("b_bad", "# B\n\n{{not a placeholder}}\n")):
        (tmp_path / name).mkdir()
        (tmp_path / name / "page.md").write_text(body)
    monkeypatch.setattr(pb, "RESULTS", tmp_path)
    assert pb.main(["--all"]) == 2
    assert "b_bad/page.md: line 3: not a placeholder" in capsys.readouterr().err
    assert not (tmp_path / "a_good.md").exists()   # before: written, then b_bad refused
    (tmp_path / "b_bad" / "page.md").write_text("# B\n\nfixed\n")
    assert pb.main(["--all"]) == 0 and (tmp_path / "a_good.md").is_file() and (tmp_path / "b_bad.md").is_file()
