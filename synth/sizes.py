"""Per-camera image sizes (``rig.cameras.<CAM>.width`` / ``.height``): the manifest's size keys, and the checks
that a camera's files and a consumer that wants one size get them right.

A dataset of one size has ``image_size`` only (as every dataset rendered before per-camera sizes); one whose
cameras differ also has ``camera_sizes`` {camera: [width, height]} (docs/DATASET.md). A camera's size is
`synth.protocol.Camera`'s ``width`` / ``height``.

Example::

    camera_sizes(ds.manifest)["CAM_BACK"]      # (480, 192)
"""
from __future__ import annotations

from pathlib import Path

from synth.files import DatasetError, stored_size


def shared_size(where, cameras) -> tuple[int, int]:
    """(width, height) of `cameras` (`synth.protocol.Camera`s) when all have one size; DatasetError naming
    the cameras of another size when not (a consumer of such a rig reads each camera's ``width`` / ``height``)."""
    sizes = {c.name: (int(c.width), int(c.height)) for c in cameras}
    first = next(iter(sizes.values()))
    if any(wh != first for wh in sizes.values()):
        from synth.rig import sizes_text

        raise DatasetError(f"{where}: the cameras have different image sizes ({sizes_text(sizes)}); read each "
                           "camera's width and height")
    return first



class SharedSize:
    """``width`` / ``height`` of a reader whose cameras share one size (`shared_size`: a DatasetError naming the
    cameras when they do not): one definition for every reader (`synth.dataset.Dataset`,
    `synth.nuscenes.dataset.NuScenesDataset`). Not part of `synth.protocol.DatasetReader`, whose sizes are per
    camera; the class needs ``root`` and ``cameras``."""

    @property
    def width(self) -> int:
        """The image width every camera shares; a rig of several sizes has none."""
        return shared_size(self.root, self.cameras)[0]

    @property
    def height(self) -> int:
        """The image height every camera shares (`width`)."""
        return shared_size(self.root, self.cameras)[1]


def size_keys(default: tuple[int, int], cameras) -> dict:
    """The manifest's size keys: ``image_size`` (the dataset's ``camera.width`` x ``camera.height``) and, when a
    camera's size differs from it (``rig.cameras.<CAM>.width`` / ``.height``), ``camera_sizes``: {camera:
    [width, height]} of every camera in rig order."""
    out = {"image_size": {"width": int(default[0]), "height": int(default[1])}}
    if any((c.width, c.height) != tuple(default) for c in cameras):
        out["camera_sizes"] = {c.name: [int(c.width), int(c.height)] for c in cameras}
    return out


def camera_sizes(manifest: dict) -> dict[str, tuple[int, int]]:
    """{camera: (width, height)} of a checked manifest (`check_manifest_keys`): ``camera_sizes``, or every
    camera at ``image_size`` (a dataset of one size, every dataset rendered before per-camera sizes)."""
    if "camera_sizes" in manifest:
        return {c: tuple(manifest["camera_sizes"][c]) for c in manifest["cameras"]}
    size = manifest["image_size"]
    return {c: (size.get("width"), size.get("height")) for c in manifest["cameras"]}


def size_problems(p: Path, rel: str, sizes: dict[str, tuple[int, int]]) -> list[str]:
    """A camera's image, depth map or mask (``<seq>/<CAM>/...``, ``masks/<CAM>.png``) of another size than the
    manifest gives its camera: one problem naming the file and both sizes."""
    parts = rel.split("/")
    if len(parts) == 2 and parts[0] == "masks" and parts[1].endswith(".png"):
        cam = parts[1][:-4]
    else:
        cam = parts[1] if len(parts) == 3 else None
    if cam not in sizes:
        return []
    got = stored_size(p)
    if got is None or got == tuple(sizes[cam]):
        return []
    return [f"{p}: is {got[0]}x{got[1]}, the manifest gives {cam} {sizes[cam][0]}x{sizes[cam][1]}"]
