"""The tables the benchmarks print and the data files docs/results/<doc>/ keep them in (not a benchmark).

A Markdown table is printed by `show` and, given ``--record PATH``, written as CSV rows (header first) that
`scripts/publish_bench.py` turns back into the same Markdown (`markdown`). A fixed-width table printed as
text is recorded as that text (`tee`): the committed .txt file is the block the doc quotes.
"""
from __future__ import annotations

import contextlib
import csv
import io
import sys
from pathlib import Path

from corelib.atomic import atomic_write_text

MAX_BYTES = 1 << 20  # a data file is ours and small; a bigger one is a mistake


class TableError(ValueError):
    """A data file that cannot be read as a table; its message is one line naming the file."""


def markdown(header: list[str], rows: list[list[str]], align: str = "") -> str:
    """The Markdown table of `header` and `rows` (cells as text); `align` has one letter per column,
    ``r`` for right-aligned (``---:``), anything else (or nothing) for the default (``---``)."""
    def line(cells):
        return "|" + "|".join(f" {c} " if c else " " for c in cells) + "|"

    rule = ["---:" if align[i:i + 1] == "r" else "---" for i in range(len(header))]
    return "\n".join([line(header), "|" + "|".join(rule) + "|"] + [line(r) for r in rows])


def write_rows(path: Path | str, header: list[str], rows: list[list[str]]) -> None:
    """The table as CSV at `path` (UTF-8, header first)."""
    buf = io.StringIO(newline="")
    csv.writer(buf, lineterminator="\n").writerows([list(header)] + [list(r) for r in rows])
    atomic_write_text(path, buf.getvalue(), fsync=False)  # whole or not at all


def read_text(path: Path | str, root: Path | str | None = None) -> str:
    """A data file's text, bounded; with ``root``, only a regular file inside it (`corelib.readfile`: a link out
    of it, a FIFO, a device are refused unread); any failure is a TableError naming the file."""
    from corelib.readfile import ReadRefused, read_text_inside

    path = Path(path)
    try:
        return read_text_inside(path, path.parent if root is None else root, MAX_BYTES)
    except ReadRefused as exc:
        raise TableError(str(exc)) from None


def read_rows(path: Path | str, root: Path | str | None = None) -> tuple[list[str], list[list[str]]]:
    """(header, rows) of a CSV written by `write_rows`; every row as wide as the header."""
    try:
        table = list(csv.reader(io.StringIO(read_text(path, root), newline=""), strict=True))
    except csv.Error as exc:
        raise TableError(f"{path}: not CSV ({exc})") from None
    if not table or not table[0]:
        raise TableError(f"{path}: empty (no header row)")
    for n, row in enumerate(table[1:], start=2):
        if len(row) != len(table[0]):
            raise TableError(f"{path}: row {n} has {len(row)} cells, the header {len(table[0])}")
    return table[0], table[1:]


def record_path(record: Path | str | None, name: str | None = None) -> Path | None:
    """Where ``--record PATH`` puts table `name` of a script that prints several: PATH with ``_<name>``
    before its suffix (``out.csv`` -> ``out_render.csv``); PATH itself for a script's only table."""
    if record is None:
        return None
    p = Path(record)
    return p if name is None else p.with_name(f"{p.stem}_{name}{p.suffix}")


def show(header: list[str], rows: list[list[str]], align: str = "", record: Path | str | None = None) -> str:
    """Print the Markdown table and, given `record`, write its rows there (CSV); returns the printed text."""
    text = markdown(header, rows, align)
    print(text)
    if record is not None:
        write_rows(record, header, rows)
    return text


class _Tee(io.TextIOBase):
    def __init__(self, out, copy):
        self.out, self.copy = out, copy

    def write(self, s):
        self.copy.write(s)
        return self.out.write(s)

    def flush(self):
        self.out.flush()


@contextlib.contextmanager
def tee(record: Path | str | None):
    """Inside, what is printed to stdout is also written to `record` (a text file), as printed."""
    if record is None:
        yield
        return
    copy = io.StringIO()
    out, sys.stdout = sys.stdout, _Tee(sys.stdout, copy)
    try:
        yield
    finally:
        sys.stdout = out
    atomic_write_text(record, copy.getvalue(), fsync=False)  # only a run that finished leaves a record
