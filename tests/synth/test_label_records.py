"""A dataset's label records read as untrusted input (issue 49, items 4 and 8): the manifest's ``labels`` and its
class table bounded (an object; at most 256 classes for a uint8 map; short printable names), instance ids checked
against instances.json by `synth verify`, instances.json parsed before `synth export` copies it, and a label file
that is a FIFO called one."""
from __future__ import annotations

import json
import os
import shutil

import numpy as np
import pytest

from synth.cli import main


@pytest.fixture
def data(tiny_dataset, tmp_path):
    """A copy of the tiny dataset (semantic and instance labels, the defaults) to damage."""
    d = tmp_path / "data"
    shutil.copytree(tiny_dataset, d)
    return d


def _edit_labels(d, fn) -> None:
    m = json.loads((d / "manifest.json").read_text())
    m["labels"] = fn(m["labels"])
    (d / "manifest.json").write_text(json.dumps(m))


def _run(capsys, *argv) -> tuple[int, str]:
    capsys.readouterr()
    code = main(list(argv))
    return code, capsys.readouterr().err


def _seq(d) -> str:
    return json.loads((d / "manifest.json").read_text())["splits"]["test"][0]


# --------------------------------------------------------------------------- item 4: the labels record
def test_verify_on_a_manifest_whose_labels_is_a_list_is_one_line(data, capsys):
    _edit_labels(data, lambda rec: rec["kinds"])  # ["semantic", "instance"]: before, an AttributeError
    code, err = _run(capsys, "verify", str(data))
    assert code == 1, err
    assert f"{data / 'manifest.json'}: labels must be an object {{kinds, classes, ...}}, not a list" in err, err
    assert "Traceback" not in err and len(err.splitlines()) == 2, err  # the problem and the count


@pytest.mark.parametrize("n", [257, 10**5])
def test_preview_on_a_class_table_of_more_than_256_classes_is_one_line(data, capsys, n):
    _edit_labels(data, lambda rec: {**rec, "classes": [{"index": i, "name": f"c{i}", "color": [i % 256, 0, 0],
                                                        "group": "other"} for i in range(n)]})
    code, err = _run(capsys, "preview", str(data), "--out", str(data.parent / "sheet.png"))
    assert code == 2 and not (data.parent / "sheet.png").exists(), err  # before: OverflowError in colorize_classes
    assert err.strip().endswith(f"labels.classes must list 1 to 256 classes (a semantic map is uint8), got {n}"), err
    assert len(err.splitlines()) == 1, err


@pytest.mark.parametrize("field,value,shown", [
    ("name", "x" * 100_000, "labels.classes[3] must be"),
    ("name", "\x1b]0;pwned\x07", "labels.classes[3] must be"),
    ("color", [300, 0, 0], "labels.classes[3] must be"),
    ("index", 7, "labels.classes[3] must be"),
])
def test_a_class_row_with_a_long_or_unprintable_name_or_a_bad_colour_is_refused_naming_it(data, capsys, field,
                                                                                          value, shown):
    def edit(rec):
        rec["classes"][3][field] = value
        return rec

    _edit_labels(data, edit)
    code, err = _run(capsys, "preview", str(data), "--out", str(data.parent / "sheet.png"))
    assert code == 2 and shown in err and len(err.splitlines()) == 1 and len(err) < 2200, err
    assert "\x1b" not in err


def test_the_rendered_class_table_passes_the_bound(tiny_dataset):
    from synth.label_reader import MAX_CLASSES, check_labels_record

    rec = json.loads((tiny_dataset / "manifest.json").read_text())["labels"]
    check_labels_record(rec, tiny_dataset / "manifest.json")
    assert 0 < len(rec["classes"]) <= MAX_CLASSES == 256


# --------------------------------------------------------------------------- item 8: instance ids, FIFO, export
def test_verify_names_an_instance_id_missing_from_instances_json(data, capsys):
    from synth.files import read_png

    seq = _seq(data)
    ids = np.unique(read_png(data / seq / "CAM_FRONT" / "000000.instance.png", depth16=True))
    gone = int(ids[ids > 0][0])
    table = json.loads((data / seq / "instances.json").read_text())
    table["instances"] = [r for r in table["instances"] if r["id"] != gone]
    (data / seq / "instances.json").write_text(json.dumps(table))
    code, err = _run(capsys, "verify", str(data))
    assert code == 1
    line = f"{data / seq / 'CAM_FRONT' / '000000.instance.png'}: object id(s) "
    hit = [ln for ln in err.splitlines() if line in ln]
    assert hit and str(gone) in hit[0].split("object id(s) ")[1].split(" not in ")[0].split(", "), err
    assert hit[0].endswith(f"not in {data / seq / 'instances.json'}"), hit


def test_verify_names_an_instances_json_with_a_repeated_id(data, capsys):
    seq = _seq(data)
    table = json.loads((data / seq / "instances.json").read_text())
    table["instances"].append(dict(table["instances"][0]))
    (data / seq / "instances.json").write_text(json.dumps(table))
    code, err = _run(capsys, "verify", str(data))
    n = len(table["instances"]) - 1
    assert code == 1 and (f"{data / seq / 'instances.json'}: instances[{n}].id must be an integer in 1..65535, "
                          "each once") in err, err


def test_verify_calls_a_fifo_label_file_a_fifo_not_missing(data, capsys):
    seq = _seq(data)
    p = data / seq / "CAM_FRONT" / "000000.semantic.png"
    p.unlink()
    os.mkfifo(p)
    code, err = _run(capsys, "verify", str(data))
    assert code == 1
    assert f"{p}: is a FIFO (named pipe), not a regular file" in err and f"{p}: missing" not in err, err


def test_export_parses_instances_json_before_copying_it(data, tmp_path, capsys):
    seq = _seq(data)
    (data / seq / "instances.json").write_text('{"instances": ' + "[" * 200_000 + "]" * 200_000 + "}")
    out = tmp_path / "ns"
    code, err = _run(capsys, "export", str(data), "--format", "nuscenes", "--out", str(out))
    assert code == 2, err  # before: copied as it was, and the export finished
    assert f"{data / seq / 'instances.json'}: JSON nested too deep" in err and len(err.splitlines()) == 1, err
    assert not list(out.rglob(f"{seq}.instances.json"))
