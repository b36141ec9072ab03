"""Published results are compact (issue 60, item 5): docs/results/<name>/results.json keeps the summaries and names
records.json.gz beside it; `read_results` joins them back, and the pages rebuild from them byte for byte
(tests/test_results_docs.py). Their results.csv is published gzip'd (results.csv.gz), the same bytes inside."""
from __future__ import annotations

import gzip
import json
from pathlib import Path

import pytest

from study.report.sections import lcon
from study.results.files import (ABS_REL_ONLY, CSV_GZ, PER_SEQUENCE_KEPT, RECORDS, RECORDS_KEY, compact_results,
                                 gzip_csv, join_results, read_results, results_from_csv, write_csv)
from study.sweep.variants import CUT

ROOT = Path(__file__).resolve().parents[2]
RESULTS = ROOT / "docs" / "results"
SWEEPS = sorted(p.parent for p in RESULTS.glob("*/results.json"))


def test_every_published_sweep_is_compact_and_docs_results_is_small():
    assert len(SWEEPS) >= 15
    for folder in SWEEPS:
        summary = json.loads((folder / "results.json").read_text())
        assert summary[RECORDS_KEY]["file"] == RECORDS and (folder / RECORDS).is_file(), folder.name
        assert "rows" not in summary and "flat" not in summary, folder.name
        assert (folder / "results.json").stat().st_size < 60_000, folder.name
        assert (folder / CSV_GZ).is_file() and not (folder / "results.csv").exists(), folder.name
    total = sum(p.stat().st_size for p in RESULTS.rglob("*") if p.is_file())
    assert total < 15e6, f"docs/results holds {total / 1e6:.1f} MB (106 MB before issue 60, 16.8 MB before csv.gz)"


def test_the_published_csv_is_the_sweeps_results_csv_gzipped(tmp_path):
    """results.csv.gz holds, byte for byte, the results.csv `write_csv` writes of the committed results (a fixed
    gzip time stamp: publishing again gives the same bytes); the standard library reads it as a CSV, and
    `read_results` reads it as it reads the plain file."""
    import csv

    folder = RESULTS / "sensor_ideal"
    write_csv(read_results(folder / "results.json"), tmp_path / "results.csv")
    plain = (tmp_path / "results.csv").read_bytes()
    assert gzip.decompress((folder / CSV_GZ).read_bytes()) == plain
    assert gzip_csv(plain) == (folder / CSV_GZ).read_bytes()
    with gzip.open(folder / CSV_GZ, "rt", newline="") as f:
        rows = list(csv.DictReader(f))
    assert rows and rows[0]["method"] and "world" in rows[0]
    assert json.dumps(read_results(folder / CSV_GZ), sort_keys=True) == \
        json.dumps(read_results(tmp_path / "results.csv"), sort_keys=True)


def test_a_csv_gz_that_is_not_one_is_refused_naming_it(tmp_path):
    bad = tmp_path / CSV_GZ
    bad.write_bytes(b"method,overlap\n")
    with pytest.raises(ValueError, match=rf"{CSV_GZ}: not gzip of a UTF-8 CSV"):
        results_from_csv(bad)
    bad.write_bytes(gzip.compress(b"\xff\xfe,1\n"))
    with pytest.raises(ValueError, match=rf"{CSV_GZ}: not gzip of a UTF-8 CSV"):
        results_from_csv(bad)


def test_compacting_the_joined_results_gives_the_committed_bytes():
    """join then compact is the identity on a committed pair (a fixed gzip time stamp: the same bytes anywhere)."""
    folder = RESULTS / "sensor_ideal"
    summary, blob = compact_results(read_results(folder / "results.json"))
    assert blob == (folder / RECORDS).read_bytes()
    assert summary == json.loads((folder / "results.json").read_text())


def test_left_out_is_what_no_page_reads_and_the_rest_comes_back():
    res = read_results(RESULTS / "lcon_pilot" / "results.json")
    i = next(i for i, r in enumerate(res["rows"]) if CUT in r["evaluations"])
    row = json.loads(json.dumps(res["rows"][i]))
    for ev, m in ((e, row["evaluations"][e]["metrics"]["median"]) for e in ("trained", CUT)):
        m["per_sequence"] = {"all": {"s0": {"sum": [1.0], "n": [4]}}, "non_overlap": {"s0": {"sum": [2.0], "n": [4]}}}
        next(iter(m["bands"].values()))["a1"] = 0.5
    res = dict(res, rows=res["rows"][:i] + [row] + res["rows"][i + 1:])
    summary, blob = compact_results(res)
    back = join_results(summary, blob)
    assert list(back) == list(res) and back["data"] == res["data"] and back["aggregate"] == res["aggregate"]
    got = {e: back["rows"][i]["evaluations"][e]["metrics"]["median"] for e in ("trained", CUT)}
    assert "per_sequence" not in got["trained"]  # a page reads the cut's only, on non-overlap pixels
    assert got[CUT]["per_sequence"] == {"non_overlap": {"s0": {"sum": [2.0], "n": [4]}}}
    assert all(set(v) == {"abs_rel"} for v in got[CUT]["bands"].values())  # a split keeps abs_rel only
    assert set(got[CUT]["non_overlap"]) > {"abs_rel", "a1"}  # a region keeps every metric
    assert PER_SEQUENCE_KEPT == (lcon.cut(), lcon.REGION) and "bands" in ABS_REL_ONLY


def test_a_records_file_that_is_not_one_is_refused_naming_it():
    summary = json.loads((RESULTS / "sensor_ideal" / "results.json").read_text())
    with pytest.raises(ValueError, match=r"records\.json\.gz: not gzip of JSON"):
        join_results(summary, b"not gzip")
    with pytest.raises(ValueError, match="more than"):  # a gzip bomb is not unpacked past the bound
        import study.results.files as rf

        old, rf.MAX_RECORDS_BYTES = rf.MAX_RECORDS_BYTES, 1000
        try:
            join_results(summary, gzip.compress(b" " * 5000 + b"{}"))
        finally:
            rf.MAX_RECORDS_BYTES = old


@pytest.mark.parametrize("name", ["../records.json.gz", "/etc/passwd", "sub/records.json.gz", 7])
def test_a_records_file_outside_its_results_folder_is_refused(tmp_path, name):
    """read_results reads the records file only as a plain name beside results.json (issue 61, c3c0f37)."""
    from study.results.files import read_results

    summary = json.loads((RESULTS / "sensor_ideal" / "results.json").read_text())
    summary[RECORDS_KEY] = {**summary[RECORDS_KEY], "file": name}
    (tmp_path / "results.json").write_text(json.dumps(summary))
    with pytest.raises(ValueError, match="its records file must be a name beside it"):
        read_results(tmp_path / "results.json")


def test_a_linked_results_json_is_refused_in_one_line(tmp_path):
    from corelib.readfile import ReadRefused
    from study.results.files import read_results

    (tmp_path / "real.json").write_text("{}")
    (tmp_path / "results.json").symlink_to(tmp_path / "real.json")
    with pytest.raises(ReadRefused, match="symbolic link"):
        read_results(tmp_path / "results.json")
