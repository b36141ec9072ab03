"""Hardening, round four (issue 41), item 9: a non-ASCII or non-UTF-8 folder name.

- ``PYTHONIOENCODING=ascii``: ``synth render`` and ``synth preview`` did their work, then ended with exit 2 when
  they printed the non-ASCII path (a UnicodeEncodeError is a ValueError); the streams now write it escaped
  (`corelib.text.safe_streams`).
- ``LC_ALL=C`` and a folder whose name is not UTF-8 (Latin-1 ``é``): OpenEXR, which takes a name only as UTF-8
  text, failed unnamed and left a ``.partial``; EXR depth maps are now encoded in memory and written (and read)
  by Python, so such a folder works.
"""
from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
TINY = str(ROOT / "configs" / "data" / "tiny.yaml")


def _run(argv: list, **env: str) -> subprocess.CompletedProcess:
    e = {**os.environ, "OMP_NUM_THREADS": "1", "PYTHONPATH": str(ROOT), **env}
    return subprocess.run([sys.executable, "-m", "synth.cli", *argv], cwd=ROOT, env=e, capture_output=True,
                          timeout=900)


def test_render_and_preview_into_a_latin1_folder_under_lc_all_c_and_ascii_output(tmp_path):
    out = os.fsencode(tmp_path) + b"/donn\xe9es"  # not UTF-8: a Latin-1 name
    res = _run(["render", TINY, "--out", out, "--no-progress", "dataset.sequences=1", "dataset.frames=3"],
               LC_ALL="C", PYTHONIOENCODING="ascii")
    assert res.returncode == 0, res.stderr[-3000:]
    assert b"donn\\udce9es" in res.stdout or b"donn\\xe9es" in res.stdout, res.stdout[-2000:]
    names = os.listdir(out)
    assert b"manifest.json" in names and not any(n.endswith(b".partial") for n in names), names
    res = _run(["verify", out], LC_ALL="C")
    assert res.returncode == 0, res.stderr[-3000:]
    sheet = os.fsencode(tmp_path) + "/aperçu.png".encode()
    res = _run(["preview", out, "--out", sheet], PYTHONIOENCODING="ascii")
    assert res.returncode == 0 and os.path.isfile(sheet), res.stderr[-3000:]
    assert b"aper\\xe7u.png" in res.stdout, res.stdout


def test_depth_maps_are_written_and_read_under_a_name_that_is_not_utf8(tmp_path):
    from synth.files import read_depth_exr, stored_size, write_depth_exr

    folder = Path(os.fsdecode(os.fsencode(tmp_path) + b"/d\xe9"))  # a lone surrogate in the str
    folder.mkdir()
    d = np.arange(12, dtype=np.float32).reshape(3, 4)
    write_depth_exr(folder / "x.depth.exr", d)
    assert np.array_equal(read_depth_exr(folder / "x.depth.exr"), d)
    assert stored_size(folder / "x.depth.exr") == (4, 3)
