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
