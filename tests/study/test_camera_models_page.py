"""The camera-model page's primary (scripts/publish_camera_models.py) states what it could have seen: the MDE at 80 %
power and the equivalence test against the preset's `plan.delta`, from the committed values, computed here again
from the per-world differences with scipy."""
from __future__ import annotations

import importlib
import json
import math
import re
import sys
from pathlib import Path

import numpy as np
from scipy import stats

ROOT = Path(__file__).resolve().parents[2]


def _page() -> tuple[dict, str]:
    """The committed values.json and the page `publish_camera_models.build` makes of it."""
    sys.path.insert(0, str(ROOT / "scripts"))
    pcm = importlib.import_module("publish_camera_models")
    values = json.loads((ROOT / "docs" / "results" / "camera_models" / "values.json").read_text())
    return values, pcm.build(values)


def test_the_primary_states_its_mde_and_equivalence_test_as_scipy_computes_them():
    values, page = _page()
    m = re.search(r"an effect of ±(\d\.\d{4}) at 80 % power; (not shown equivalent|equivalent) to 0 within "
                  r"±([\d.]+) \(two one-sided tests, p = (\d\.\d{3})", page)
    assert m, page[:800]
    a, b = values["arms"]["mono2_pinhole"], values["arms"]["mono2_lens"]
    d = np.array([a[w]["median.mean.abs_rel"] - b[w]["median.mean.abs_rel"] for w in sorted(set(a) & set(b))])
    n, delta = len(d), float(m.group(3))
    assert n >= 2 and delta == 0.005
    se, df = d.std(ddof=1) / math.sqrt(n), n - 1
    p_tost = max(stats.t.sf((d.mean() + delta) / se, df), stats.t.cdf((d.mean() - delta) / se, df))
    mde = (stats.t.ppf(0.975, df) + stats.t.ppf(0.80, df)) * se
    assert float(m.group(4)) == round(p_tost, 3)
    assert abs(float(m.group(1)) - mde) < 1e-4
    assert (m.group(2) == "equivalent") == (p_tost < 0.05)


def test_the_primary_stands_beside_its_level_and_a_yardstick():
    values, page = _page()
    m = re.search(r"Its level: Mono2 through the lens (\d\.\d{3}), as if pinhole (\d\.\d{3}) .*a constant depth on "
                  r"the same rig (\d\.\d{3})", page)
    assert m, page[:1500]
    lens, pin = (np.mean([x["median.mean.abs_rel"] for x in values["arms"][a].values()])
                 for a in ("mono2_lens", "mono2_pinhole"))
    assert (float(m[1]), float(m[2])) == (round(lens, 3), round(pin, 3))
    assert float(m[3]) > max(lens, pin)  # trained depth beats a constant
    assert abs((pin - lens) - 0.005) < 0.001  # the level's difference is the primary's mean (+0.005)


def test_one_world_says_it_has_no_interval():
    sys.path.insert(0, str(ROOT / "scripts"))
    pcm = importlib.import_module("publish_camera_models")
    line = pcm._power_line([0.01])
    assert "not measured (1 world" in line and "nan" not in line
