"""A label kind is one row of `synth.label_kinds`: a toy kind declared here (and nowhere else) is written by a
render, listed and checked by `synth verify`, read through the dataset reader and shown on the preview sheet's
tiles; the table's ``Example::`` runs in tests/test_doctests.py."""
from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

import synth.label_kinds as lk
from synth.label_kinds import LabelFile, LabelKind

TINY = Path(__file__).resolve().parents[2] / "configs" / "data" / "tiny.yaml"

SKY = LabelFile("sky.png", "uint8", "png8", "the sky mask")


def _write(w, f) -> None:
    w.png(SKY, f, np.where(f.res["depth"] > 0, 0, 255).astype(np.uint8))


def _read(ds, seq, cam, frame) -> np.ndarray:
    return ds.read_label_file("sky", SKY, seq, cam, frame) > 127


def _show(ds, seq, cam, frame) -> list:
    return [(np.repeat(ds.read_label("sky", seq, cam, frame)[..., None].astype(np.uint8) * 255, 3, 2), "sky")]


TOY = LabelKind("sky", (SKY,), default_on=True, bytes_per_pixel=1, about="<seq>/<CAM>/<frame>.sky.png: 255 = no surface",
                write=_write, read=_read, show=_show)


@pytest.fixture(scope="module")
def toy_dataset(tmp_path_factory):
    from synth.config import load_data_config
    from synth.render import render_dataset
    cfg = load_data_config(TINY, ["dataset.sequences=1", "dataset.frames=3", "labels.semantic=false",
                                  "labels.instance=false"])
    out = tmp_path_factory.mktemp("toy") / "data"
    with pytest.MonkeyPatch.context() as mp:  # the row only while this render runs (no other fixture sees it)
        mp.setattr(lk, "LABEL_KINDS", (*lk.LABEL_KINDS, TOY))
        render_dataset(cfg, out, workers=1, progress=False, log=lambda *a: None)
    return out


def test_a_toy_kind_is_written_verified_read_and_shown(toy_dataset, monkeypatch):
    from synth.config import bytes_per_pixel, load_data_config
    from synth.label_kinds import preview_tiles
    from synth.open import open_dataset
    from synth.verify import verify_dataset

    monkeypatch.setattr(lk, "LABEL_KINDS", (*lk.LABEL_KINDS, TOY))  # the one place a kind is declared
    m = json.loads((toy_dataset / "manifest.json").read_text())
    assert m["labels"]["kinds"] == ["sky"] and m["labels"]["sky"] == TOY.about
    assert "seq_00000/CAM_FRONT/000001.sky.png" in m["files"]
    assert verify_dataset(toy_dataset) == []
    ds = open_dataset(toy_dataset)
    sky = ds.read_label("sky", "seq_00000", "CAM_FRONT", 1)
    np.testing.assert_array_equal(sky, ds.read_depth("seq_00000", "CAM_FRONT", 1) <= 0)
    assert sky.any() and not sky.all()  # the sky and the road, both in the front camera's view
    (tile, caption), = preview_tiles(ds, "seq_00000", "CAM_FRONT", 0)
    assert caption == "sky" and tile.shape == sky.shape + (3,)
    assert bytes_per_pixel(load_data_config(TINY)) == 7 + 1 + 2 + 1  # RGB, depth, semantic, instance and the toy

    (toy_dataset / "seq_00000" / "CAM_FRONT" / "000000.sky.png").unlink()
    assert any("000000.sky.png: missing" in p for p in verify_dataset(toy_dataset))


def test_a_dataset_without_the_toy_kind_says_what_it_lacks(tiny_dataset):
    from synth.files import DatasetError
    from synth.open import open_dataset

    ds = open_dataset(tiny_dataset)
    with pytest.MonkeyPatch.context() as mp:
        mp.setattr(lk, "LABEL_KINDS", (*lk.LABEL_KINDS, TOY))
        assert "sky" not in ds.label_kinds
        with pytest.raises(DatasetError, match="has no sky labels"):
            ds.read_label("sky", "seq_00000", "CAM_FRONT", 0)


def test_every_row_names_its_files_once_and_the_config_defaults_agree():
    from synth.config import LabelsConfig

    suffixes = [f.suffix for k in lk.label_kinds() for f in k.files]
    assert len(suffixes) == len(set(suffixes))
    assert {k.name: k.default_on for k in lk.label_kinds()} == LabelsConfig().model_dump()
