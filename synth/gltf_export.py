"""Export a dataset's scenes as glTF 2.0 binary (GLB) through trimesh, with the poses other renderers need.

``synth export DATA --format gltf --out DIR`` rebuilds every sequence's scene model from the manifest's
resolved config and seed (`scenes.build_scene` with the render's `SeedSequence([seed, index])`, checked
against the sequence's ego.json poses) and writes (docs/DATASET.md, "glTF export")::

    DIR/<seq>/scene.glb      nodes: "world_z_up" (the root: world frame z up -> glTF y up), under it
                             "static" (the world mesh, world coordinates), one node per mover (its
                             mesh in its own frame, placed at frame 0) and "ego" (the ego body, ego frame,
                             at frame 0); metres; one primitive per (material, tint) with the
                             procedural texture as its base-colour image (sRGB, repeat wrapping) and the
                             tint as baseColorFactor; under "ego" one glTF perspective camera node per
                             rig camera ("camera/<CAM>"), and the animation "sequence" that moves "ego"
                             and every mover through the frames (`synth.gltf_cameras`)
    DIR/<seq>/scene.json     per frame: timestamp_s, T_world_ego, every mover's T_world_obj, every
                             camera's T_world_cam (OpenCV axes) and K; the camera table of rig.json
    DIR/export.json          what was exported from what, written last

All poses in scene.json are in the dataset's world frame (z up); ``T_gltf_world`` in it is the root
node's matrix. Vertex count and positions are the scene model's (float32), so the same world can be
rendered again by Blender or a path tracer.

Example::

    export_gltf("data/tiny", "data/tiny_gltf")
"""
from __future__ import annotations

import time
from pathlib import Path

import numpy as np

from corelib.atomic import atomic_write_bytes
from corelib.configlib import build_config
from corelib.rundir import FolderError, claim
from synth.camera import pinhole_only
from synth.extras import VIZ_INSTALL as INSTALL
from synth.files import DatasetError, read_json, write_json

FORMAT = "mcdp-synth-gltf"
FORMAT_VERSION = 1
MARKER = "export.json"
# glTF is y up: x stays, world z -> glTF y, world y -> glTF -z
T_GLTF_WORLD = np.array([[1.0, 0, 0, 0], [0, 0, 1, 0], [0, -1, 0, 0], [0, 0, 0, 1]])
ROOT_NODE = "world_z_up"


def import_trimesh():
    try:
        import trimesh
    except ImportError:
        raise DatasetError(f"the glTF export needs the optional extra 'viz' (trimesh): {INSTALL}") from None
    return trimesh


def rebuild_scene(ds, seq: str):
    """The scene model of sequence `seq` as rendered (`synth.render.render_sequence`), checked against its
    ego.json; returns (DataConfig, Scene)."""
    from scenes import build_scene
    from synth.config import DataConfig

    cfg_dict = ds.manifest.get("config")
    if not isinstance(cfg_dict, dict):
        raise DatasetError(f"{ds.root / 'manifest.json'}: no resolved config to rebuild the scenes from")
    cfg = build_config(DataConfig, cfg_dict, f"{ds.root / 'manifest.json'} config")
    ego_json = read_json(ds.inside(ds.root / seq / "ego.json"))
    index = ego_json.get("index")
    if not isinstance(index, int) or isinstance(index, bool):
        raise DatasetError(f"{ds.root / seq / 'ego.json'}: no integer 'index' (the sequence's seed index)")
    scene_ss = np.random.SeedSequence([cfg.seed, index]).spawn(3)[0]
    scene = build_scene(cfg.scene, ds.n_frames(seq), ds.fps, np.random.default_rng(scene_ss))
    if not np.allclose(scene.T_world_ego, ds.T_world_ego(seq), atol=1e-9):
        raise DatasetError(f"{ds.root / seq / 'ego.json'}: the rebuilt scene's ego poses differ from the render's "
                           "(rendered by another generator version?); nothing of this sequence was exported")
    return cfg, scene


def rebuilt_world_mesh(ds, seq: str):
    """The world mesh (`synth.world_mesh.WorldMesh`) of a synth dataset's sequence rebuilt from its manifest
    config (`rebuild_scene`): the Rerun recording's mesh for a dataset rendered without ``labels.mesh``. None
    for a dataset without a manifest config (a nuScenes dataroot) or whose scene cannot be rebuilt (one line
    why)."""
    from corelib.logs import logger
    from synth.render import make_ego_mesh
    from synth.world_mesh import world_mesh

    if ds.format != "synth" or "config" not in ds.manifest:
        return None
    try:
        cfg, scene = rebuild_scene(ds, seq)
    except DatasetError as e:
        logger("synth.view").warning(f"synth view: no world mesh for {seq}: {e}")
        return None
    return world_mesh(scene, make_ego_mesh(cfg))


def mesh_parts(trimesh, mesh, textures: np.ndarray, materials: list[str], name: str) -> list:
    """One trimesh.Trimesh per (texture layer, tint) of `mesh` (a `scenes.model.Mesh`), vertices kept as
    they are (a vertex shared by two groups is duplicated; none is in the scene families)."""
    from PIL import Image
    from trimesh.visual.material import PBRMaterial
    from trimesh.visual.texture import TextureVisuals

    if not mesh.n_triangles:
        return []
    key = np.concatenate([mesh.layers[:, None].astype(np.float32), mesh.tints], axis=1)
    groups, inverse = np.unique(key[mesh.indices[:, 0]], axis=0, return_inverse=True)
    parts = []
    for g, (layer, *tint) in enumerate(groups):
        faces = mesh.indices[inverse.ravel() == g]
        used, local = np.unique(faces, return_inverse=True)
        uv = mesh.uvs[used].astype(np.float64)
        uv[:, 1] = 1.0 - uv[:, 1]  # trimesh writes 1 - v: glTF's v (rows top-down) is then ours
        mat = PBRMaterial(name=f"{materials[int(layer)]}", baseColorTexture=Image.fromarray(textures[int(layer)]),
                          baseColorFactor=[float(t) for t in tint] + [1.0], metallicFactor=0.0, roughnessFactor=1.0)
        parts.append(trimesh.Trimesh(vertices=mesh.positions[used], faces=local.reshape(-1, 3),
                                     vertex_normals=mesh.normals[used], visual=TextureVisuals(uv=uv, material=mat),
                                     process=False, validate=False,
                                     metadata={"name": f"{name}/{materials[int(layer)]}_{g}"}))
    return parts


def camera_frames(ds, seq: str) -> list[dict]:
    """Per frame, per camera: T_world_cam (OpenCV axes, camera -> world) and K (pixels, centres at +0.5)."""
    out = []
    for f, T_we in enumerate(ds.T_world_ego(seq)):
        out.append({c.name: {"T_world_cam": (T_we @ np.asarray(c.T_ego_cam)).tolist(), "K": np.asarray(c.K).tolist(),
                             "width": c.width, "height": c.height} for c in ds.cameras})
    return out


def export_sequence(trimesh, ds, seq: str, out_dir: Path) -> dict:
    from synth.render import make_ego_mesh

    cfg, scene = rebuild_scene(ds, seq)
    sc = trimesh.Scene()
    sc.graph.update(frame_from=sc.graph.base_frame, frame_to=ROOT_NODE, matrix=T_GLTF_WORLD)
    nodes = {"static": scene.static, **{m.name: m.mesh for m in scene.movers}, "ego": make_ego_mesh(cfg)}
    if len(nodes) != 2 + len(scene.movers):
        raise DatasetError(f"{seq}: two movers share a name; the glTF nodes would collide")
    poses = {"static": np.eye(4), **{m.name: m.T_world_obj[0] for m in scene.movers}, "ego": scene.T_world_ego[0]}
    n_vertices = 0
    for name, mesh in nodes.items():
        sc.graph.update(frame_from=ROOT_NODE, frame_to=name, matrix=np.asarray(poses[name], np.float64))
        for part in mesh_parts(trimesh, mesh, scene.textures, scene.materials, name):
            sc.add_geometry(part, geom_name=part.metadata["name"], node_name=part.metadata["name"],
                            parent_node_name=name)
        n_vertices += mesh.n_vertices
    from trimesh.exchange.gltf import export_glb

    from synth.gltf_cameras import CameraHooks

    ego = ds.ego(seq)
    times = [float(ego[f].get("timestamp_s", f / ds.fps)) for f in range(scene.n_frames)]
    hooks = CameraHooks(ds.cameras, "ego", {"ego": scene.T_world_ego, **{m.name: m.T_world_obj for m in scene.movers}},
                        np.asarray(times))
    glb = export_glb(sc, include_normals=True, buffer_postprocessor=hooks.buffer, tree_postprocessor=hooks.tree)
    out_dir.mkdir(parents=True, exist_ok=True)
    atomic_write_bytes(out_dir / "scene.glb", glb)
    cams = camera_frames(ds, seq)
    frames = [{"frame": f, "timestamp_s": times[f],
               "T_world_ego": scene.T_world_ego[f].tolist(),
               "movers": {m.name: m.T_world_obj[f].tolist() for m in scene.movers},
               "cameras": cams[f]} for f in range(scene.n_frames)]
    meta = {"format": FORMAT, "format_version": FORMAT_VERSION, "sequence": seq, "glb": "scene.glb",
            "units": "metres", "fps": ds.fps, "family": scene.family,
            "world_frame": "the dataset's world frame: z up, road surface z = 0 (docs/DATASET.md)",
            "T_gltf_world": T_GLTF_WORLD.tolist(), "root_node": ROOT_NODE,
            "nodes": {"static": "static", "ego": "ego", "movers": [m.name for m in scene.movers]},
            "node_frames": "static: world coordinates; a mover: its own frame, placed by T_world_obj; ego: the ego "
                           "frame (x forward, y left, z up), placed by T_world_ego; the GLB's nodes hold frame 0's "
                           "pose and its animation 'sequence' every frame's (input: timestamp_s)",
            "gltf_cameras": "node 'camera/<CAM>' under 'ego': a perspective camera with K's fy and W/H (glTF has no "
                            "fx != fy nor off-centre principal point: the exact K is 'cameras' here)",
            "camera_convention": "T_world_cam maps OpenCV camera coordinates (x right, y down, z forward) to the "
                                 "world; K in pixels, pixel (c, r) has its centre at (c + 0.5, r + 0.5). A glTF / "
                                 "Blender camera (x right, y up, looking down -z) is T_world_cam @ diag(1, -1, -1, 1)",
            "cameras": [c.to_json() for c in ds.cameras], "vertices": n_vertices, "frames": frames}
    write_json(out_dir / "scene.json", meta)
    return {"vertices": n_vertices, "bytes": len(glb)}


def export_gltf(dataset: str | Path, out: str | Path, progress: bool = False) -> dict:
    """Export every sequence of `dataset` into `out` (module docstring); returns a summary."""
    from synth.dataset import dataset_containing
    from synth.open import open_dataset

    trimesh = import_trimesh()
    src, out = Path(dataset), Path(out)
    ds = open_dataset(src)
    if ds.format != "synth" or "config" not in ds.manifest:
        raise DatasetError(f"{src}: a glTF export needs a synth dataset (its scenes are rebuilt from the manifest's "
                           "config), not a nuScenes dataroot")
    pinhole_only(ds.cameras, f"{src}: a glTF export (glTF cameras are perspective)", DatasetError)
    if dataset_containing(out) is not None or out.resolve() == src.resolve():
        raise FolderError(f"--out {out} is inside the dataset {dataset_containing(out) or src}; export outside it")
    cfg_hash = str(ds.manifest.get("config_hash") or "")
    lock = claim(out, "gltf_export", legacy=(MARKER,))  # empty, new, or an earlier glTF export
    try:
        if (out / MARKER).is_file():
            prev = read_json(out / MARKER)
            if not isinstance(prev, dict) or (prev.get("source") or {}).get("config_hash") != cfg_hash:
                raise FolderError(f"--out {out} holds the glTF export of another dataset ({out / MARKER}); "
                                  "nothing was written: use a new --out")
        t0 = time.perf_counter()
        seqs = ds.sequences
        if progress:
            from corelib.progress import progress_bar
            seqs = progress_bar(seqs, desc="gltf", unit="seq")
        total = {"vertices": 0, "bytes": 0}
        for seq in seqs:
            s = export_sequence(trimesh, ds, seq, out / seq)
            total = {k: total[k] + s[k] for k in total}
        write_json(out / MARKER, {"format": FORMAT, "format_version": FORMAT_VERSION, "complete": True,
                                  "source": {"path": str(src.resolve()), "config_hash": cfg_hash},
                                  "sequences": list(ds.sequences), "trimesh": trimesh.__version__})
        return {"out": str(out), "sequences": len(ds.sequences), **total, "seconds": time.perf_counter() - t0}
    finally:
        lock.release()
