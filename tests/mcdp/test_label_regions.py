"""The evaluation's class regions come from the dataset's own class table (`mcdp.label_regions.LabelIndex`), not
from the generator's class list: the method library imports no scene module (issue 60 item 8)."""
from __future__ import annotations

import ast
from pathlib import Path

import numpy as np
import pytest

from mcdp.label_regions import HOLE_REGIONS, LabelIndex

ROOT = Path(__file__).resolve().parents[2]


def test_a_rendered_datasets_table_gives_the_groups_the_evaluation_always_had():
    from scenes.labels import GROUPS, class_table  # the generator's table, as a rendered manifest carries it

    index = LabelIndex(class_table())
    assert set(index.groups) == set(GROUPS) | {"vehicle_parked", "vehicle_moving"}
    assert index.groups[:2] == ("road", "other")  # the table's order: road, then sidewalk's group
    assert set(HOLE_REGIONS) <= set(index.regions) and index.regions[-2:] == ("static", "moving")
    sem = np.array([0, 1, 2, 3, 8, 9, 11, 99])  # sky, road, lane marking, sidewalk, parked, moving, ego, beyond
    sel = index.selectors(sem)
    assert sel["class_road"].tolist() == [False, True, True, False, False, False, False, False]
    assert sel["class_vehicle"].tolist() == [False] * 4 + [True, True, False, False]
    assert sel["moving"].tolist() == [False] * 5 + [True, False, False]
    assert (sel["static"] == ~sel["moving"]).all()


def test_another_table_gives_its_own_groups_and_a_table_without_road_is_one_line():
    table = [{"index": 0, "name": "void", "group": "sky"}, {"index": 1, "name": "asphalt", "group": "road"},
             {"index": 2, "name": "car", "group": "vehicle"}, {"index": 3, "name": "tree", "group": "nature"}]
    index = LabelIndex(table)
    assert index.groups == ("road", "vehicle", "vehicle_parked", "vehicle_moving", "nature")
    assert index.selectors(np.array([3]))["class_nature"].tolist() == [True]
    with pytest.raises(ValueError, match=r"no 'road' group: .* \(its groups: sky, vehicle\)"):
        LabelIndex([{"index": 0, "name": "void", "group": "sky"}, {"index": 1, "name": "car", "group": "vehicle"}])


def test_the_method_library_imports_no_scene_module():
    bad = []
    for p in sorted((ROOT / "mcdp").rglob("*.py")):
        for node in ast.walk(ast.parse(p.read_text())):
            names = [a.name for a in node.names] if isinstance(node, ast.Import) else \
                [node.module or ""] if isinstance(node, ast.ImportFrom) else []
            bad += [f"{p.relative_to(ROOT)}: {n}" for n in names if n == "scenes" or n.startswith("scenes.")]
    assert not bad, bad
