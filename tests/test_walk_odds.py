"""Issue 49, item 13 ("odds and ends from the walk"): what a newcomer walking the README met, each reproduced
here as it was and checked as it is now: the dataset page's label defaults, `synth verify` on a nuScenes
dataroot, `synth merge`'s words for an incomplete shard set, the preview sheet's titles and keys, the
evaluation tables' `nan`, help text for every option, one spelling of the sequence option, the ignored sheet.
"""
from __future__ import annotations

import argparse
import re
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]


# --------------------------------------------------------------------------- docs/DATASET.md: label defaults
def test_dataset_page_states_each_labels_default_as_the_config_has_it():
    from synth.config import LabelsConfig

    text = (ROOT / "docs" / "DATASET.md").read_text()
    line = next(ln for ln in text.splitlines() if ln.strip().startswith("labels (`labels."))
    block = line + text.split(line, 1)[1].split("\n", 2)[1]  # the sentence may wrap onto the next line
    clauses = re.split(r"[,;]", block)
    for name, field in LabelsConfig.model_fields.items():
        clause = next((c for c in clauses if re.search(rf"`(labels)?\.{name}`", c)), "")
        said = re.search(r"\b(on|off) by default", clause)
        assert said, f"docs/DATASET.md does not say whether labels.{name} is on by default: {block!r}"
        assert said.group(1) == ("on" if field.default else "off"), f"labels.{name}: {block!r}"
    movers = next(ln for ln in text.splitlines() if ".movers.png" in ln)
    after = text.split(movers, 1)[1].split("\n", 2)[1]
    assert "labels.flow=true" in movers + after, "movers.png is written only with the flow"


# --------------------------------------------------------------------------- help text, option spellings
def _parsers():
    """(prog, its build_parser parser) for `synth` and `mcdp` (every command, the study's included)."""
    import study.cli
    import study.method_commands
    import synth.cli
    from corelib.cli import build_parser

    return [("synth", build_parser("synth", "", synth.cli.COMMANDS)),
            ("mcdp", build_parser("mcdp", "", study.method_commands.COMMANDS + study.cli.COMMANDS))]


def _subparsers(parser: argparse.ArgumentParser) -> dict:
    return next(a for a in parser._actions if isinstance(a, argparse._SubParsersAction)).choices


def test_every_option_of_every_command_has_help_text():
    bare = []
    for prog, parser in _parsers():
        for name, sub in [("", parser)] + list(_subparsers(parser).items()):
            for a in sub._actions:
                if isinstance(a, argparse._SubParsersAction) or a.help == argparse.SUPPRESS:
                    continue
                if not (a.help or "").strip():
                    bare.append(f"{prog} {name} {'/'.join(a.option_strings) or a.dest}".replace("  ", " "))
    assert bare == []


def test_render_help_names_the_labels(capsys):
    from synth.cli import main

    assert main(["render", "--help"]) == 0
    text = " ".join(capsys.readouterr().out.split())
    assert "labels" in text and "labels.flow=true" in text and "semantic" in text


@pytest.mark.parametrize("command", [["preview", "DATA", "--out", "sheet.png"], ["view", "DATA", "--out", "a.rrd"]])
@pytest.mark.parametrize("spelling", ["--seq", "--sequence"])
def test_preview_and_view_take_both_spellings_of_the_sequence(command, spelling):
    from corelib.cli import parse_command_line

    parser = dict(_parsers())["synth"]
    args = parse_command_line(parser, command + [spelling, "seq_00002"])
    assert (args.sequence if command[0] == "preview" else args.seq) == "seq_00002"


# --------------------------------------------------------------------------- synth merge of an incomplete set
def test_merge_of_an_incomplete_shard_set_says_so_in_one_named_line(tiny_dataset, tmp_path, capsys):
    import shutil

    from synth.cli import main

    shard = tmp_path / "s0"
    shutil.copytree(tiny_dataset, shard)
    (shard / "manifest.json").unlink()            # a shard: no manifest, and one sequence not rendered here
    shutil.rmtree(shard / "seq_00002")
    out = tmp_path / "full"
    assert main(["merge", "--out", str(out), str(shard)]) == 1
    cap = capsys.readouterr()
    lines = cap.err.strip().splitlines()
    assert cap.out == "" and len(lines) == 1 and lines[0].startswith("synth merge: ")
    assert "2 of 3 sequences" in lines[0] and "missing seq_00002" in lines[0] and "{" not in lines[0]
    shutil.copytree(tiny_dataset / "seq_00002", tmp_path / "s1" / "seq_00002")  # the other shard's sequence
    shutil.copytree(shard / ".synth", tmp_path / "s1" / ".synth")
    shutil.copy(shard / "rig.json", tmp_path / "s1" / "rig.json")
    assert main(["merge", "--out", str(out), str(tmp_path / "s1")]) == 0
    assert capsys.readouterr().out.strip() == f"synth merge: {out}: complete, 3 sequences; manifest written"


# --------------------------------------------------------------------------- mcdp eval's nan, explained
def _metrics(vehicle: float, pair: float) -> dict:
    from mcdp.metrics import metric_names

    row = {k: 0.1 for k in metric_names()}
    cams = ["CAM_FRONT", "CAM_BACK"]
    none = {"per_camera": {c: row for c in cams}, "mean": row, "overlap": row, "non_overlap": row,
            "classes": {"road": row, "vehicle": {k: vehicle for k in row}}, "motion": {"static": row},
            "holes": {"ratio": 2.0, "moving": float("nan"), "moving_pixels": 0, "parked": 0.0, "parked_pixels": 5}}
    dep_con = {"mean": 0.05, "per_camera": {"CAM_FRONT": 0.05, "CAM_BACK": 0.05},
               "per_pair": {"CAM_FRONT->CAM_BACK": 0.05, "CAM_BACK->CAM_FRONT": pair}}
    return {"split": "test", "n_samples": 2, "min_depth": 0.1, "max_depth": 80.0, "cameras": cams,
            "stages": {"final": {"none": none, "dep_con": dep_con}}}


def test_eval_tables_say_once_what_a_nan_means():
    from mcdp.tables import NAN_DEP_CON, NAN_ROWS, format_tables

    nan = float("nan")
    clean = format_tables(_metrics(0.2, 0.05))
    assert "nan:" not in clean                                  # no nan printed, no note
    text = format_tables(_metrics(nan, nan)).splitlines()
    assert any(ln.startswith("vehicle") and ln.split()[1] == "nan" for ln in text)
    assert text.count(NAN_ROWS) == 1 and text.count(NAN_DEP_CON) == 1
    assert text.index(NAN_ROWS) < text.index("Dep Con (unscaled predictions; lower is better)") < text.index(NAN_DEP_CON)
    assert "absent from the split" in NAN_ROWS and "hit" in NAN_DEP_CON
    only_pair = format_tables(_metrics(0.2, nan)).splitlines()
    assert NAN_ROWS not in only_pair and only_pair[-1] == NAN_DEP_CON


# --------------------------------------------------------------------------- synth verify on a nuScenes dataroot
def test_verify_names_a_nuscenes_dataroot_and_checks_what_it_can(ns_root, tmp_path, capsys):
    import shutil

    from synth.cli import main
    from synth.nuscenes.read import open_nuscenes
    from synth.verify import verify_dataset

    assert main(["verify", str(ns_root)]) == 0
    out = capsys.readouterr().out
    assert out.startswith(f"OK {ns_root}: a nuScenes dataroot (version v1.0-synth)") and "missing" not in out
    ds = open_nuscenes(ns_root)
    n = sum(ds.n_frames(s) for s in ds.sequences) * len(ds.camera_names)
    assert n > 0 and "tables load" in out and f"{len(ds.sequences)} scenes, {n} camera images present" in out
    assert "nuScenes dataroot" in verify_dataset(ns_root)[0]
    broken = tmp_path / "root"
    shutil.copytree(ns_root, broken)
    gone = sorted((broken / "samples" / "CAM_BACK").iterdir())[0]
    gone.unlink()
    assert main(["verify", str(broken)]) == 1
    err = capsys.readouterr().err.splitlines()
    assert len(err) == 2 and err[0].startswith(f"FAIL {gone}: image file is missing")  # named by the reader
    assert err[1] == f"synth verify: 1 problem(s) in {broken}, a nuScenes dataroot"


# --------------------------------------------------------------------------- mcdp pretrain: done, then exit
@pytest.mark.parametrize("argv", [None, ["presets"]])
def test_a_console_script_freezes_its_heap_before_the_exit_and_a_caller_does_not(argv, monkeypatch):
    import gc

    from study.cli import main

    frozen = []
    monkeypatch.setattr(gc, "freeze", lambda: frozen.append(1))
    monkeypatch.setattr("sys.argv", ["mcdp", "presets"])
    assert main(argv) == 0
    assert frozen == ([1] if argv is None else [])  # the shutdown's collections skip what the command left


# --------------------------------------------------------------------------- preview: titles that fit, colour keys
@pytest.mark.parametrize("title", ["CAM_FRONT_RIGHT", "CAM_BACK_LEFT", "mask (12% ego)", "flow (12.3 px)",
                                   "a title of many words that no scale fits on one line"])
def test_preview_titles_fit_a_96_pixel_tile(title):
    import numpy as np

    from synth.preview import _label

    tile = _label(np.zeros((64, 96, 3), np.uint8), title)
    lit = np.nonzero(tile.max(axis=(0, 2)) > 0)[0]
    assert lit.size and lit.max() < 94            # nothing drawn into the right margin: the title is not cut
    assert tile[-8:].max() == 0 or len(title) > 40   # one line for a camera's name


def test_depth_bar_colours_its_ticks_as_the_depth_tiles_do():
    import numpy as np

    from synth.preview import BAR_TICKS_M, colorize_depth, depth_bar

    bar, ticks = depth_bar(300)
    assert sorted(ticks) == list(BAR_TICKS_M) and list(ticks.values()) == sorted(ticks.values(), reverse=True)  # far (left) to near
    for d, x in ticks.items():
        want = colorize_depth(np.array([[float(d)]]))[0, 0].astype(int)
        assert np.abs(bar[5, x].astype(int) - want).max() <= 12, d


def test_flow_key_hue_is_the_direction_and_the_sheet_carries_both_keys(flow_dataset, tmp_path):
    import numpy as np
    from PIL import Image

    from synth.open import open_dataset
    from synth.preview import depth_bar, flow_key, make_preview

    key = flow_key(49).astype(int)
    right, left, down = key[24, 46], key[24, 2], key[46, 24]
    assert right[0] > 200 and right[1] < 80 and right[2] < 80      # to the right: red
    assert left[0] < 80 and left[1] > 150 and left[2] > 150        # to the left: cyan
    assert key[24, 24].max() < 30 and key[0, 0].max() == 0         # no length at the centre; outside: invalid
    assert down[1] > down[2]                                       # down (v > 0): hue 90 deg, yellow-green
    sheet = np.asarray(Image.open(make_preview(open_dataset(flow_dataset), tmp_path / "sheet.png")))
    W = sheet.shape[1]
    bar, _ = depth_bar(W - (48 + 150) - 70)                        # key_row's layout with a flow key
    top = sheet.shape[0] - (48 + 14) + 14                          # the last row: 14 px of caption, then the keys
    assert (sheet[top:top + bar.shape[0], 66:66 + bar.shape[1]] == bar).all()
    assert (sheet[top:top + 48, W - 52:W - 4] == flow_key()).all()
