"""The dataset seam: what training, evaluation and prediction (`mcdp`), the sweep (`study`) and the rig
viewer (`synth.view`, which `mcdp predict --rrd` records through) read from a dataset, and nothing more.

Implemented by `synth.dataset.Dataset` (a rendered dataset), `synth.nuscenes.dataset.NuScenesDataset` (a
nuScenes dataroot) and the tests' fake (tests/conftest.py); tests/synth/test_protocol.py checks
all three. A reader may have more (`Dataset.manifest`, `read_bytes`, `NuScenesDataset.lidar_points_world`,
...), but a consumer that takes any dataset reads only these members; it reads an extra only after `format`
says which reader it has (``ds.format == "synth"``: the manifest, ``read_bytes``; ``"nuscenes"``: the LiDAR
sweeps), never by probing with ``getattr`` / ``hasattr``. docs/INTERFACES.md lists the same members.

Conventions (docs/INTERFACES.md): metres; OpenCV camera axes; ``T_a_b`` maps points of frame b into
frame a; `K` in pixels of the stored image with pixel centres at +0.5; depth is of the camera's lens's depth kind
(`Camera.intrinsics`, `synth.camera`): z-depth for pinhole and radtan, range (ray length) for kannala_brandt; 0 =
no value.

Image size is per camera: `Camera.width` x `Camera.height`, which may differ between the cameras of one
rig (``rig.cameras.<CAM>.width``; a nuScenes dataroot's channels); `read_rgb`, `read_depth` and `mask` of a
camera are at its size. There is no dataset-wide size in the seam: a consumer that needs one checks that
the cameras share it (`synth.sizes.shared_size`, a DatasetError naming the cameras otherwise).
"""
from __future__ import annotations

from pathlib import Path
from typing import Protocol, Sequence, runtime_checkable

import numpy as np

from synth import camera

SPLITS = ("train", "val", "test")  # the split names `DatasetReader.split` knows


@runtime_checkable
class Camera(Protocol):
    """One camera of the rig (`synth.rig.CameraSpec`)."""

    @property
    def name(self) -> str: ...

    @property
    def width(self) -> int:
        """This camera's image width in pixels (cameras may differ)."""

    @property
    def height(self) -> int:
        """This camera's image height in pixels."""

    @property
    def K(self) -> np.ndarray:
        """(3, 3) float64 camera matrix in pixels of this camera's stored image (its lens: `intrinsics`)."""

    @property
    def intrinsics(self) -> camera.Intrinsics:
        """Its lens: the camera-table row, `K` and the distortion parameters (a pinhole camera: ``model ==
        "pinhole"``, no parameters). Every projection of this camera goes through it (`synth.camera`)."""

    @property
    def T_ego_cam(self) -> np.ndarray:
        """(4, 4) float64 camera -> ego."""

    def to_json(self) -> dict:
        """The camera as plain JSON (a run's ``run.json`` ``rig``, compared by ``mcdp eval``)."""


def pixel_rays(K, width: int, height: int) -> np.ndarray:
    """(height, width, 3) float64 rays through every pixel centre (a point at depth d of pixel (v, u) is
    ``d * rays[v, u]``): the camera table's back-projection (`synth.camera.rays`; a bare K is the pinhole row,
    rays K^-1 [u + 0.5, v + 0.5, 1] at z = 1)."""
    return np.ascontiguousarray(camera.rays(K, height, width).T).reshape(height, width, 3)


def pixel_rays_at(K, u: np.ndarray, v: np.ndarray) -> np.ndarray:
    """(3, M) float64 rays of the M pixels of integer columns `u` and rows `v` (1-D), element by element, so a
    pixel's ray is the one `pixel_rays` gives, bit for bit (`synth.camera.rays_at`)."""
    return camera.rays_at(K, u, v)


@runtime_checkable
class DatasetReader(Protocol):
    """Read access to a multi-camera dataset: a rig, sequences of frames, their images, depth and poses."""

    @property
    def format(self) -> str:
        """What kind of dataset this is: ``"synth"`` (a rendered dataset: its manifest records the generator
        config, its scenes can be rebuilt, its files read whole), ``"nuscenes"`` (a dataroot: LiDAR sweeps), or
        another reader's own name. Consumers branch on it, never on which members a reader happens to have."""

    @property
    def root(self) -> Path:
        """The dataset's folder (recorded in a run's ``run.json``, named in messages)."""

    @property
    def cameras(self) -> Sequence[Camera]:
        """The rig's cameras in rig order."""

    @property
    def camera_names(self) -> list[str]:
        """``[c.name for c in cameras]``."""

    @property
    def neighbours(self) -> list[tuple[int, int]]:
        """Adjacent camera pairs (i, j) as indices into `cameras`."""

    @property
    def sequences(self) -> list[str]:
        """Every sequence id, sorted."""

    @property
    def fps(self) -> float:
        """Frames per second of the sequences."""

    @property
    def has_depth(self) -> bool:
        """Whether `read_depth` has ground truth to read."""

    @property
    def ground_truth(self) -> dict:
        """Provenance of `read_depth` (``{"kind": ...}``; the evaluator copies it into metrics.json)."""

    def split(self, name: str) -> list[str]:
        """Sequence ids of split `name` (one of `SPLITS`); DatasetError for an unknown split."""

    def n_frames(self, seq: str) -> int:
        """Number of frames of sequence `seq`."""

    def ego(self, seq: str) -> list[dict]:
        """Per frame: ``timestamp_s`` (s from the sequence's start), ``T_world_ego`` (4x4 list), ..."""

    def T_world_ego(self, seq: str) -> np.ndarray:
        """(F, 4, 4) float64 ego -> world per frame."""

    def rgb_path(self, seq: str, cam: str, frame: int) -> Path:
        """The file `read_rgb` reads."""

    def depth_path(self, seq: str, cam: str, frame: int) -> Path:
        """The file `read_depth` reads (a rendered depth map, or the LiDAR sweep it is projected from)."""

    def read_rgb(self, seq: str, cam: str, frame: int) -> np.ndarray:
        """(H, W, 3) uint8 RGB at the camera's size (its ``height``, ``width``)."""

    def read_depth(self, seq: str, cam: str, frame: int) -> np.ndarray:
        """(H, W) float32 depth in metres at the camera's size, of its lens's depth kind (z-depth; range for
        kannala_brandt), 0 = no value."""

    def mask(self, cam: str) -> np.ndarray:
        """(H, W) bool at the camera's size, True = scene, False = ego body."""

    @property
    def label_kinds(self) -> tuple[str, ...]:
        """The labels the dataset holds: some of ("semantic", "instance", "flow", "mesh"); () for none (a dataset
        rendered before labels, a nuScenes dataroot: `synth.label_reader.NoLabels`)."""

    @property
    def classes(self) -> list[dict]:
        """The semantic class table: index, name, color (RGB), group (`scenes.labels`); [] without it."""

    def read_semantic(self, seq: str, cam: str, frame: int) -> np.ndarray:
        """(H, W) uint8 class index; DatasetError naming what is lacking when ``"semantic"`` is not held."""

    def read_instance(self, seq: str, cam: str, frame: int) -> np.ndarray:
        """(H, W) uint16 object id, 0 = none (``"instance"``)."""

    def read_movers(self, seq: str, cam: str, frame: int) -> np.ndarray:
        """(H, W) bool, True on moving objects (``"flow"``)."""

    def read_flow(self, seq: str, cam: str, frame: int) -> tuple[np.ndarray, np.ndarray]:
        """((H, W, 2) float32 forward flow to frame + 1 in pixels, (H, W) bool valid) (``"flow"``)."""

    def instances(self, seq: str) -> list[dict]:
        """The sequence's objects: id, class, moving, a mover's T_world_obj per frame (``"instance"``)."""
