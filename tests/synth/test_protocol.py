"""The dataset seam (`synth.protocol.DatasetReader`): the rendered dataset's reader, the nuScenes reader and
the tests' fake each have every member of it (isinstance, and member by member: properties present,
methods callable with the protocol's number of arguments); their cameras are `synth.protocol.Camera`s.
Built from in-memory records: nothing is rendered and the nuScenes devkit is not needed."""
from __future__ import annotations

import inspect
import re
from pathlib import Path

import numpy as np
import pytest

from synth.dataset import Dataset
from synth.nuscenes.dataset import NuScenesDataset
from synth.nuscenes.layout import NUSCENES_CAMERAS
from synth.protocol import Camera, DatasetReader
from synth.rig import CameraSpec

W, H = 8, 6


def _cameras(names) -> list[CameraSpec]:
    K = np.array([[4.0, 0, W / 2], [0, 4.0, H / 2], [0, 0, 1]])
    return [CameraSpec(n, W, H, K, np.eye(4), 90.0, 60.0 * i, 0.0) for i, n in enumerate(names)]


def synth_dataset() -> Dataset:
    cams = _cameras(["CAM_A", "CAM_B"])
    manifest = {"fps": 10, "splits": {"train": ["seq_0000"], "val": [], "test": []},
                "sequences": {"seq_0000": {"frames": 3}}, "cameras": ["CAM_A", "CAM_B"]}
    return Dataset(Path("ds"), manifest, {"cameras": [c.to_json() for c in cams], "neighbours": [[0, 1]]})


def nuscenes_dataset() -> NuScenesDataset:
    frames = {"scene-1": [{"sample_token": "s0", "scene_token": "t0", "timestamp_s": 0.0, "T_world_ego": np.eye(4),
                           "cams": {}}]}
    masks = {n: np.ones((H, W), bool) for n in NUSCENES_CAMERAS}
    return NuScenesDataset(Path("ns"), "v1.0-test", _cameras(NUSCENES_CAMERAS), frames, {"train": ["scene-1"]}, "test",
                           2.0, masks, "none", True, "half")


#: the readers by name; the tests' fake (tests/conftest.py) comes from its fixture
READERS = {"synth.dataset.Dataset": synth_dataset, "synth.nuscenes.dataset.NuScenesDataset": nuscenes_dataset,
           "tests' FakeDataset": None}


def missing_members(obj, protocol: type) -> list[str]:
    """The members of `protocol` that `obj` lacks, that are methods of it but not callable on `obj`, or
    that take another number of arguments."""
    out = []
    for name, member in vars(protocol).items():
        if name.startswith("_"):
            continue
        if isinstance(member, property):
            if not hasattr(obj, name):
                out.append(name)
        elif callable(member):
            got = getattr(obj, name, None)
            if not callable(got):
                out.append(name)
            elif len(inspect.signature(got).parameters) != len(inspect.signature(member).parameters) - 1:
                out.append(f"{name} (takes {len(inspect.signature(got).parameters)} arguments)")
    return out


def test_the_protocol_lists_what_the_interfaces_page_lists():
    members = {n for n in vars(DatasetReader) if not n.startswith("_")}
    assert members == {"format", "root", "cameras", "camera_names", "neighbours", "sequences", "fps", "has_depth",
                       "ground_truth", "split", "n_frames", "ego", "T_world_ego", "rgb_path", "depth_path",
                       "read_rgb", "read_depth", "mask", "label_kinds", "classes", "read_semantic", "read_instance",
                       "read_movers", "read_flow", "instances"}
    doc = (Path(__file__).resolve().parents[2] / "docs" / "INTERFACES.md").read_text()
    block = doc.split("## The dataset seam", 1)[1].split("```", 2)[1]
    assert set(re.findall(r"^ds\.(\w+)", block, re.M)) == members


@pytest.mark.parametrize("name", list(READERS))
def test_each_reader_satisfies_the_dataset_protocol(name, fake_dataset):
    ds = (READERS[name] or fake_dataset)()
    assert isinstance(ds, DatasetReader)
    assert missing_members(ds, DatasetReader) == []
    for cam in ds.cameras:
        assert isinstance(cam, Camera) and missing_members(cam, Camera) == []
    assert ds.camera_names == [c.name for c in ds.cameras]


def test_an_object_short_of_a_member_is_not_a_reader(fake_dataset):
    class NoMask(fake_dataset):
        mask = None

    assert missing_members(NoMask(), DatasetReader) == ["mask"]
    assert not isinstance(object(), DatasetReader)


def test_both_readers_take_their_shared_size_from_one_definition():
    """The dataset-wide width / height (where the cameras share one size) is defined once, `synth.sizes.SharedSize`,
    not copied into each reader."""
    from synth.dataset import Dataset
    from synth.nuscenes.dataset import NuScenesDataset
    from synth.sizes import SharedSize

    for reader in (Dataset, NuScenesDataset):
        assert "width" not in vars(reader) and "height" not in vars(reader), reader.__name__
        assert reader.width is SharedSize.width and reader.height is SharedSize.height


def test_the_ground_truth_kind_says_range_where_a_lens_gives_range(tmp_path):
    """A rendered dataset's ground-truth provenance is "dense z-depth (rendered)" on pinhole cameras, and names the
    range where a Kannala-Brandt lens gives it (the evaluator copies it into metrics.json)."""
    from types import SimpleNamespace

    from synth import camera
    from synth.dataset import Dataset

    K = [[50.0, 0, 48], [0, 50.0, 32], [0, 0, 1]]
    pin = SimpleNamespace(intrinsics=camera.Intrinsics("pinhole", K, ()))
    kb = SimpleNamespace(intrinsics=camera.Intrinsics("kannala_brandt", K, (0.0, 0.0, 0.0, 0.0)))
    assert Dataset.ground_truth.fget(SimpleNamespace(cameras=[pin, pin]))["kind"] == "dense z-depth (rendered)"
    assert "range" in Dataset.ground_truth.fget(SimpleNamespace(cameras=[pin, kb]))["kind"]
