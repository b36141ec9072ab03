"""The live ego body (issue 57, item 6; `synth.config.EgoConfig`): ``ego.appearance=live`` changes the RGB of
the ego-body pixels only, and makes them change from frame to frame as the car moves; depth, masks and labels
stay byte-identical, and the key at its default keeps every dataset's hash."""
from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from corelib.configlib import config_hash, hashed_dict, load_config

TINY = Path(__file__).resolve().parents[2] / "configs" / "data" / "tiny.yaml"
TINY_HASH = "4c93be54b2f0ddb35c56d70e7fd2b087d4a0e648eeb11eb99ebc6a5727a1c9d8"  # before the key (as test_sensor.py)
# one straight sequence of the tiny world (seq_00000), no gain flicker: a static body is then the same image in
# every frame, and what changes on the live one is its reflection and lighting
SMALL = ["dataset.sequences=1", "dataset.frames=4", "lighting.flicker_sigma=0.0"]
CAM = "CAM_BACK_LEFT"  # sees the roof: 2704 of its 6144 pixels at 96x64
LIVE_FLOOR = 2.0  # mean |RGB(f+1) - RGB(f)| over the ego pixels, 8-bit levels: live above it, static below 0.5


def _cfg(overrides=()):
    from synth.config import DataConfig

    return load_config(DataConfig, TINY, [*SMALL, *overrides])


@pytest.fixture(scope="module")
def renders(tmp_path_factory):
    from synth.render import render_dataset

    out = {}
    for mode in ("static", "live"):
        out[mode] = tmp_path_factory.mktemp(f"ego_{mode}") / "data"
        render_dataset(_cfg([f"ego.appearance={mode}"]), out[mode], progress=False, log=lambda *a: None)
    return out


def test_the_key_at_its_default_keeps_the_hash_and_live_changes_it():
    from synth.config import DataConfig

    tiny = load_config(DataConfig, TINY)
    assert tiny.ego.appearance == "static" and "ego" not in hashed_dict(tiny)
    assert config_hash(tiny) == config_hash(load_config(DataConfig, TINY, ["ego.appearance=static"])) == TINY_HASH
    assert config_hash(load_config(DataConfig, TINY, ["ego.appearance=live"])) != TINY_HASH


def _files(root: Path) -> dict[str, str]:
    return json.loads((root / "manifest.json").read_text())["files"]


def test_live_changes_only_the_rgb_of_ego_pixels(renders):
    from synth.files import read_png

    static, live = _files(renders["static"]), _files(renders["live"])
    assert static.keys() == live.keys()
    differ = {k for k in static if static[k] != live[k]}
    # depth, semantic, instance, ego.json, the masks: byte-identical; only RGB images of cameras that see the body
    assert differ and all(k.count(".") == 1 and k.endswith(".png") for k in differ), sorted(differ)[:5]
    masks_equal = all((renders["static"] / "masks" / p.name).read_bytes() == p.read_bytes()
                      for p in (renders["live"] / "masks").glob("*.png"))
    assert masks_equal
    for k in differ:
        cam = k.split("/")[1]
        ego = read_png(renders["static"] / "masks" / f"{cam}.png", gray=True) == 0
        a, b = (read_png(renders[m] / k).astype(np.int16) for m in ("static", "live"))
        changed = np.any(a != b, axis=-1)
        assert ego.any() and not changed[~ego].any(), k  # exactly inside the ego body, nowhere else


def _ego_change(root: Path) -> float:
    """Mean |RGB(f+1) - RGB(f)| (8-bit levels) over CAM's ego pixels and its frames."""
    from synth.files import read_png

    ego = read_png(root / "masks" / f"{CAM}.png", gray=True) == 0
    ims = [read_png(p).astype(np.float64) for p in sorted((root / "seq_00000" / CAM).glob("??????.png"))]
    return float(np.mean([np.abs(b - a)[ego].mean() for a, b in zip(ims, ims[1:])]))


def test_the_live_body_changes_from_frame_to_frame_and_the_static_one_does_not(renders):
    static, live = _ego_change(renders["static"]), _ego_change(renders["live"])
    assert static < 0.5 < LIVE_FLOOR < live, (static, live)
