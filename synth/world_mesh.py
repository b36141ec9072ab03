"""The world mesh a render writes beside its images (label kind ``mesh``, `synth.label_kinds`; off unless
``labels.mesh=true``), so a viewer shows the world from the dataset alone, never from the generator config.

``<seq>/world_mesh.npz``: a zip of ``.npy`` arrays (numpy's npz, read with ``allow_pickle=False``), written
deterministically (fixed entry order, fixed timestamps 1980-01-01, deflate): the same scene gives the same
bytes. Every mesh is a vertex-coloured triangle mesh (metres; colour = its texture's mean colour x its tint,
sRGB uint8, as the Rerun recording shows it)::

    static.positions  (N, 3) float32, world frame        static.normals  (N, 3) float32
    static.indices    (M, 3) uint32                      static.colors   (N, 3) uint8
    ego.*             the ego body, ego frame (the same four arrays)
    movers            (K,) unicode: the movers' names (scene model: car_00, ...), entity-safe
    mover<k>.*        mover k's mesh in its own frame (the four arrays), and
    mover<k>.T_world_obj  (F, 4, 4) float64: its pose per frame

Example::

    wm = world_mesh(scene, ego_mesh)                 # scenes.model.Scene, Mesh -> WorldMesh
    write_bytes(path, world_mesh_bytes(wm)); read_world_mesh(path, n_frames=F).static.positions
"""
from __future__ import annotations

import io
import re
import zipfile
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from synth.files import DatasetError, read_regular

#: uncompressed bytes a world mesh file may hold (all arrays together): about 40 M vertices
MAX_MESH_BYTES = 2**30
#: movers a world mesh file may hold
MAX_MOVERS = 4096
_PARTS = ("positions", "indices", "normals", "colors")
_NAME = re.compile(r"^[A-Za-z0-9][A-Za-z0-9_-]{0,63}$")  # one entity path segment: world/scene/<name>
_FIXED_TIME = (1980, 1, 1, 0, 0, 0)  # the zip's earliest date: no wall clock in the file


@dataclass(frozen=True)
class ColoredMesh:
    """A triangle mesh with a colour per vertex: positions and normals (N, 3) float32, indices (M, 3) uint32,
    colors (N, 3) uint8."""

    positions: np.ndarray
    indices: np.ndarray
    normals: np.ndarray
    colors: np.ndarray


@dataclass(frozen=True)
class WorldMesh:
    """A sequence's world as a viewer shows it: the static mesh (world frame), each mover's mesh (its own frame)
    with its pose per frame (name, mesh, (F, 4, 4) T_world_obj) and the ego body (ego frame)."""

    static: ColoredMesh
    movers: tuple[tuple[str, ColoredMesh, np.ndarray], ...]
    ego: ColoredMesh


def vertex_colors(mesh, textures: np.ndarray) -> np.ndarray:
    """(N, 3) uint8: each vertex of `mesh` (`scenes.model.Mesh`) coloured by its texture layer's mean colour x
    its tint."""
    mean = textures.reshape(len(textures), -1, 3).mean(axis=1)
    return np.clip(mean[mesh.layers] * mesh.tints, 0, 255).astype(np.uint8)


def colored(mesh, textures: np.ndarray) -> ColoredMesh:
    return ColoredMesh(np.ascontiguousarray(mesh.positions, np.float32), np.ascontiguousarray(mesh.indices, np.uint32),
                       np.ascontiguousarray(mesh.normals, np.float32), vertex_colors(mesh, textures))


def world_mesh(scene, ego_mesh) -> WorldMesh:
    """The world mesh of `scene` (`scenes.model.Scene`) with the ego body `ego_mesh` (`scenes.model.Mesh`)."""
    t = scene.textures
    movers = tuple((m.name, colored(m.mesh, t), np.asarray(m.T_world_obj, np.float64)) for m in scene.movers)
    return WorldMesh(colored(scene.static, t), movers, colored(ego_mesh, t))


def _arrays(wm: WorldMesh) -> dict[str, np.ndarray]:
    out: dict[str, np.ndarray] = {}
    for prefix, m in [("static", wm.static), ("ego", wm.ego)] + [(f"mover{k}", mv[1]) for k, mv in
                                                                  enumerate(wm.movers)]:
        out.update({f"{prefix}.{p}": getattr(m, p) for p in _PARTS})
    out["movers"] = np.array([name for name, _, _ in wm.movers], dtype="<U64")
    out.update({f"mover{k}.T_world_obj": np.asarray(T, np.float64) for k, (_, _, T) in enumerate(wm.movers)})
    return out


def world_mesh_bytes(wm: WorldMesh) -> bytes:
    """The file's bytes: the same `wm` gives the same bytes (no timestamp, fixed order)."""
    buf = io.BytesIO()
    with zipfile.ZipFile(buf, "w") as zf:
        for name, arr in _arrays(wm).items():
            one = io.BytesIO()
            np.lib.format.write_array(one, np.ascontiguousarray(arr), allow_pickle=False)
            info = zipfile.ZipInfo(f"{name}.npy", date_time=_FIXED_TIME)
            info.compress_type = zipfile.ZIP_DEFLATED
            info.external_attr = 0o644 << 16
            zf.writestr(info, one.getvalue())
    return buf.getvalue()


def _mesh(a: dict, prefix: str, path: Path) -> ColoredMesh:
    want = {"positions": (np.float32, 3), "normals": (np.float32, 3), "colors": (np.uint8, 3),
            "indices": (np.uint32, 3)}
    for part, (dtype, cols) in want.items():
        x = a.get(f"{prefix}.{part}")
        if x is None or x.dtype != dtype or x.ndim != 2 or x.shape[1] != cols:
            raise DatasetError(f"{path}: {prefix}.{part} must be an (N, {cols}) {np.dtype(dtype).name} array, got "
                               f"{'none' if x is None else f'{x.shape} {x.dtype}'}")
    n = len(a[f"{prefix}.positions"])
    if len(a[f"{prefix}.normals"]) != n or len(a[f"{prefix}.colors"]) != n:
        raise DatasetError(f"{path}: {prefix}'s positions, normals and colors must have one row per vertex")
    idx = a[f"{prefix}.indices"]
    if len(idx) and int(idx.max()) >= n:
        raise DatasetError(f"{path}: {prefix}.indices refers to vertex {int(idx.max())}; the mesh has {n}")
    if not (np.isfinite(a[f"{prefix}.positions"]).all() and np.isfinite(a[f"{prefix}.normals"]).all()):
        raise DatasetError(f"{path}: {prefix} holds non-finite positions or normals")
    return ColoredMesh(*(a[f"{prefix}.{p}"] for p in _PARTS))


def _load(path: Path) -> dict[str, np.ndarray]:
    try:
        zf = zipfile.ZipFile(io.BytesIO(read_regular(path)))
    except zipfile.BadZipFile as exc:
        raise DatasetError(f"{path}: not a world mesh file (npz): {exc}") from None
    with zf:
        infos = zf.infolist()
        if len(infos) > 9 + 5 * MAX_MOVERS or sum(i.file_size for i in infos) > MAX_MESH_BYTES:
            raise DatasetError(f"{path}: more than {MAX_MESH_BYTES} bytes or {MAX_MOVERS} movers; not read")
        out = {}
        for i in infos:
            if not i.filename.endswith(".npy"):
                raise DatasetError(f"{path}: holds {i.filename[:60]!r}, not an array (.npy)")
            try:
                with zf.open(i) as fh:
                    out[i.filename[:-4]] = np.lib.format.read_array(fh, allow_pickle=False)
            except (ValueError, OSError, zipfile.BadZipFile, EOFError) as exc:
                raise DatasetError(f"{path}: {i.filename[:60]} is not readable ({str(exc)[:80]})") from None
    return out


def read_world_mesh(path: str | Path, n_frames: int | None = None) -> WorldMesh:
    """The world mesh file at `path`, checked (every array's shape and dtype, indices inside the mesh, finite
    values, mover names entity-safe, with `n_frames` one pose per frame); DatasetError naming the file and the
    array otherwise."""
    path = Path(path)
    a = _load(path)
    names = a.get("movers")
    if names is None or names.dtype.kind != "U" or names.ndim != 1 or len(names) > MAX_MOVERS:
        raise DatasetError(f"{path}: movers must be a list of at most {MAX_MOVERS} names")
    movers = []
    for k, name in enumerate(names.tolist()):
        if not _NAME.match(name) or name in [m[0] for m in movers]:
            raise DatasetError(f"{path}: movers[{k}] {name[:40]!r} must be a distinct name of letters, digits, _ -")
        T = a.get(f"mover{k}.T_world_obj")
        if (T is None or T.dtype != np.float64 or T.ndim != 3 or T.shape[1:] != (4, 4) or not np.isfinite(T).all()
                or (n_frames is not None and len(T) != n_frames)):
            raise DatasetError(f"{path}: mover{k}.T_world_obj must be ({n_frames or 'F'}, 4, 4) finite float64, got "
                               f"{'none' if T is None else f'{T.shape} {T.dtype}'}")
        movers.append((name, _mesh(a, f"mover{k}", path), T))
    return WorldMesh(_mesh(a, "static", path), tuple(movers), _mesh(a, "ego", path))
