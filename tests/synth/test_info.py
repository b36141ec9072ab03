"""`synth info DATA`: sequences, splits, families, per-pair measured overlap (from the manifest), size."""
from __future__ import annotations

import json

from synth.cli import main


def test_info_prints_sequences_splits_and_overlap(tiny_dataset, capsys):
    from synth.open import open_dataset

    ds = open_dataset(tiny_dataset)
    assert main(["info", str(tiny_dataset)]) == 0
    out = capsys.readouterr().out
    for seq in ds.sequences:
        assert seq in out
    for k in ("train", "val", "test"):
        assert f"split {k}" in out
    for pair, d in ds.overlap["per_pair_measured"].items():
        assert f"{pair}" in out and f"measured {d['measured']:.3f}" in out
    assert f"{ds.width}x{ds.height}" in out and "disk" in out


def test_info_json_matches_the_manifest(tiny_dataset, capsys):
    from synth.open import open_dataset

    ds = open_dataset(tiny_dataset)
    assert main(["info", str(tiny_dataset), "--json"]) == 0
    info = json.loads(capsys.readouterr().out)
    assert info["sequences"] == {s: ds.n_frames(s) for s in ds.sequences}
    assert info["splits"]["val"]["sequences"] == ds.split("val")
    assert info["families"] == ds.manifest["families"]
    assert info["bytes"] == sum(p.stat().st_size for p in tiny_dataset.rglob("*") if p.is_file())


def test_info_on_a_folder_that_is_not_a_dataset_is_one_line(tmp_path, capsys):
    assert main(["info", str(tmp_path)]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and str(tmp_path) in err
