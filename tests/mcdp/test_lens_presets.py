"""The lens presets end to end (issue 59): a tiny render of configs/data/distorted.yaml (six radtan cameras, z-depth)
and configs/data/fisheye.yaml (four 190-degree Kannala-Brandt cameras, range depth) trains two steps with
``mcdp train`` and evaluates with ``mcdp eval``: finite metrics, the overlap found, Dep Con measured on every pair
that overlaps, and metrics.json naming each camera's lens and depth kind. ``model.lens=pinhole`` (the "as if
pinhole" ablation) trains on the radtan rig and is refused in one line for the fisheye rig."""
from __future__ import annotations

import json
import math
from pathlib import Path

import pytest

pytestmark = [pytest.mark.slow, pytest.mark.usefixtures("one_thread")]  # renders and trains

ROOT = Path(__file__).resolve().parents[2]
PRESETS = {"distorted": ("radtan", "z_depth", 6), "fisheye": ("kannala_brandt", "range", 4)}
#: the tiny preset's sizes (configs/data/tiny.yaml), a sequence per split and 4 frames (2 evaluated)
TINY = ["camera.width=96", "camera.height=64", "dataset.sequences=3", "dataset.frames=4", "scene.texture_size=128",
        "render.shadow_map_size=1024"]


@pytest.fixture(scope="module")
def lens_data(tmp_path_factory):
    """``lens_data(name)``: the path of a tiny render of configs/data/<name>.yaml, rendered once per module."""
    from synth.config import load_data_config
    from synth.render import render_dataset

    done = {}

    def get(name):
        if name not in done:
            out = tmp_path_factory.mktemp(name) / "data"
            render_dataset(load_data_config(ROOT / "configs" / "data" / f"{name}.yaml", TINY), out, workers=1,
                           progress=False, log=lambda *a: None)
            done[name] = out
        return done[name]
    return get


def _train_and_eval(data, run, preset, *overrides):
    from study.method_commands import main

    assert main(["train", str(ROOT / "configs" / "train" / "tiny" / f"{preset}.yaml"), "--data", str(data), "--out",
                 str(run), "--no-progress", "train.steps=2", *overrides]) == 0
    assert main(["eval", str(run), "--data", str(data), "--out", str(run / "m.json"), "--no-progress"]) == 0
    return json.loads((run / "m.json").read_text())


@pytest.mark.parametrize("name", list(PRESETS))
def test_a_lens_preset_trains_and_evaluates(lens_data, tmp_path, name):
    model, kind, n_cams = PRESETS[name]
    m = _train_and_eval(lens_data(name), tmp_path / "run", "mcdp_m2")
    assert len(m["cameras"]) == n_cams
    assert m["lenses"] == {c: {"model": model, "depth_kind": kind} for c in m["cameras"]}
    st = m["stages"]["final"]
    assert math.isfinite(st["none"]["mean"]["abs_rel"]) and math.isfinite(st["none"]["overlap"]["abs_rel"])
    assert math.isfinite(st["dep_con"]["mean"]) and st["dep_con"]["mean"] > 0
    seen = [k for k, v in st["dep_con"]["per_pair"].items() if math.isfinite(v)]
    assert len(seen) >= n_cams  # at least one direction of every adjacent pair, as a rule both


def test_as_if_pinhole_trains_on_radtan_and_is_refused_for_a_fisheye(lens_data, tmp_path, capsys):
    from study.method_commands import main

    m = _train_and_eval(lens_data("distorted"), tmp_path / "flat", "mono2", "model.lens=pinhole")
    assert m["lenses"]["CAM_FRONT"] == {"model": "radtan", "depth_kind": "z_depth"}  # evaluated through the lens
    assert math.isfinite(m["stages"]["final"]["none"]["mean"]["abs_rel"])
    capsys.readouterr()
    rc = main(["train", str(ROOT / "configs" / "train" / "tiny" / "mono2.yaml"), "--data", str(lens_data("fisheye")),
               "--out", str(tmp_path / "fish"), "--no-progress", "train.steps=2", "model.lens=pinhole"])
    err = capsys.readouterr().err.strip().splitlines()
    assert rc != 0 and any(line.count("model.lens=pinhole") == 1 and "range depth" in line for line in err), err
