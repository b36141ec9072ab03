"""`synth preview` with labels (`synth.preview_labels`): per camera the class map and the flow (the mover mask
at the last frame) beside the four tiles of before, and a legend row; a dataset without labels gets the sheet
of before, pixel for pixel."""
from __future__ import annotations

import numpy as np
from PIL import Image

from synth.open import open_dataset
from synth.preview import key_row, make_preview
from synth.preview_labels import colorize_classes, colorize_flow, legend


def _sheet(ds, path, **kw) -> np.ndarray:
    return np.asarray(Image.open(make_preview(ds, path, **kw)).convert("RGB"))


def test_labels_add_class_and_flow_tiles_and_a_legend_row(flow_dataset, tiny_dataset_without_labels, tmp_path):
    """With flow (labels.flow=true) two tiles more per camera; the RGB and depth of the tiny preset are the same
    bytes with or without labels, so the dataset without them gives the sheet of before."""
    ds, old = open_dataset(flow_dataset), open_dataset(tiny_dataset_without_labels)
    cams = list(ds.cameras)
    H, W = cams[0].height, cams[0].width
    seq = ds.sequences[0]
    before = _sheet(old, tmp_path / "old.png", seq=seq, frame=1)
    sheet = _sheet(ds, tmp_path / "new.png", seq=seq, frame=1)
    keys, keys_flow = key_row(4 * W, flow=False), key_row(6 * W, flow=True)  # the depth bar (and the flow key)
    assert before.shape == (6 * H + keys.shape[0], 4 * W, 3)
    leg = legend(ds.classes, 6 * W)
    assert sheet.shape == (6 * H + leg.shape[0] + keys_flow.shape[0], 6 * W, 3)  # two tiles more per camera
    assert np.array_equal(sheet[:6 * H, :4 * W], before[:6 * H])  # the tiles of before, unchanged
    assert np.array_equal(sheet[6 * H:6 * H + leg.shape[0]], leg) and np.array_equal(before[6 * H:], keys)
    assert np.array_equal(sheet[6 * H + leg.shape[0]:], keys_flow)
    for i, cam in enumerate(cams):  # the class tile below its caption (up to two lines): the class map in the table's colours
        want = colorize_classes(ds.read_semantic(seq, cam.name, 1), ds.classes)
        assert np.array_equal(sheet[i * H + 32:(i + 1) * H, 4 * W:5 * W], want[32:])
        flow, valid = ds.read_flow(seq, cam.name, 1)
        rgb, _ = colorize_flow(flow, valid)
        assert np.array_equal(sheet[i * H + 32:(i + 1) * H, 5 * W:6 * W], rgb[32:])
    last = _sheet(ds, tmp_path / "last.png", seq=seq, frame=ds.n_frames(seq) - 1)
    movers = ds.read_movers(seq, cams[0].name, ds.n_frames(seq) - 1)
    assert np.array_equal(last[20:H, 5 * W:6 * W, 0] == 255, movers[20:])


def test_flow_colours():
    flow = np.zeros((4, 4, 2), np.float32)
    flow[0, :, 0] = 2.0   # to the right: red
    flow[1, :, 1] = 2.0   # down (image v): hue 90 deg, yellow-green
    valid = np.ones((4, 4), bool)
    valid[3] = False
    rgb, scale = colorize_flow(flow, valid)
    assert scale == 2.0
    assert tuple(rgb[0, 0]) == (255, 0, 0)
    assert rgb[1, 0, 1] == 255 and rgb[1, 0, 2] == 0 and 120 <= rgb[1, 0, 0] <= 135
    assert not rgb[2].any() and not rgb[3].any()  # no flow: black; invalid: black
