"""The rig's cameras and the sequence's poses inside the GLB of `synth.gltf_export`, through trimesh's own
export hooks (``export_glb(tree_postprocessor=, buffer_postprocessor=)``; trimesh itself writes at most one
camera, ``Scene.camera``)::

    node "ego"                     animated: translation + rotation of T_world_ego per frame (LINEAR)
      node "camera/<CAM>"          camera "<CAM>" (perspective), matrix T_ego_cam @ diag(1, -1, -1, 1)
    node "<mover>"                 animated: T_world_obj per frame
    animation "sequence"           one sampler per channel; input: the frames' timestamp_s

glTF cameras look down -z with y up, hence the flip of the OpenCV axes. A glTF perspective camera has
one focal length and a centred principal point: ``yfov = 2 atan(H / (2 fy))``, ``aspectRatio = W / H``;
the exact K (fx != fy, an off-centre principal point) stays in scene.json. The nodes' transforms are
relative to their parents ("world_z_up", then "ego"), i.e. in the dataset's world frame, as the meshes.
"""
from __future__ import annotations

import math

import numpy as np

#: OpenCV camera axes (x right, y down, z forward) -> glTF camera axes (x right, y up, looking down -z)
GL_FROM_CV = np.diag([1.0, -1.0, -1.0, 1.0])
ZNEAR = 0.05  # metres; the rig renders from 1 cm, but a glTF viewer needs no such near plane
ANIMATION = "sequence"
CAMERA_PREFIX = "camera/"
_FLOAT, _VIEW_KEY = 5126, "mcdp_synth_animation_"


def perspective(K: np.ndarray, width: int, height: int) -> dict:
    """The glTF perspective camera closest to K (its fy and the image's aspect ratio)."""
    fy = float(np.asarray(K)[1, 1])
    return {"type": "perspective", "perspective": {"yfov": 2.0 * math.atan(0.5 * height / fy),
                                                   "aspectRatio": width / height, "znear": ZNEAR}}


def quat_xyzw(R: np.ndarray) -> np.ndarray:
    """Unit quaternion (x, y, z, w) of a rotation matrix (glTF's order), w >= 0."""
    from trimesh.transformations import quaternion_from_matrix

    M = np.eye(4)
    M[:3, :3] = R
    w, x, y, z = quaternion_from_matrix(M)  # (w, x, y, z)
    q = np.array([x, y, z, w])
    return q * (1.0 if w >= 0 else -1.0)


def _continuous(q: np.ndarray) -> np.ndarray:
    """Quaternions with no sign flip between neighbours (so LINEAR interpolation takes the short way)."""
    q = q.copy()
    for i in range(1, len(q)):
        if float(q[i] @ q[i - 1]) < 0:
            q[i] = -q[i]
    return q


class CameraHooks:
    """The two hooks for ``trimesh.exchange.gltf.export_glb``: `buffer` appends the animation's samples to
    the binary chunk (as accessors), `tree` adds the cameras, their nodes and the animation.

    `tracks`: {node name: (N, 4, 4) poses relative to its parent}; `times`: (N,) seconds; `cameras`: the
    rig's cameras (name, K, width, height, T_ego_cam), placed under the node `rig_node`."""

    def __init__(self, cameras, rig_node: str, tracks: dict[str, np.ndarray], times: np.ndarray) -> None:
        self.cameras, self.rig_node = list(cameras), rig_node
        self.tracks = {k: np.asarray(v, np.float64) for k, v in tracks.items()}
        self.times = np.asarray(times, np.float32)
        self.accessors: dict[str, int] = {}

    def _add(self, buffer_items, accessors, key: str, data: np.ndarray, kind: str) -> None:
        data = np.ascontiguousarray(data, np.float32)
        buffer_items[_VIEW_KEY + key] = data.tobytes()  # float32: always a multiple of 4 bytes
        acc = {"bufferView": len(buffer_items) - 1, "componentType": _FLOAT, "count": len(data), "type": kind}
        if key == "time":  # the spec requires min / max on a sampler's input
            acc.update(min=[float(data.min())], max=[float(data.max())])
        accessors[_VIEW_KEY + key] = acc
        self.accessors[key] = len(accessors) - 1

    def buffer(self, buffer_items, tree) -> None:
        acc = tree["accessors"]  # trimesh's ordered {key: accessor}; turned into the list after this hook
        self._add(buffer_items, acc, "time", self.times, "SCALAR")
        for name, T in self.tracks.items():
            self._add(buffer_items, acc, f"{name}/translation", T[:, :3, 3], "VEC3")
            self._add(buffer_items, acc, f"{name}/rotation", _continuous(np.stack([quat_xyzw(t[:3, :3]) for t in T])),
                      "VEC4")

    def tree(self, tree) -> None:
        nodes = tree["nodes"]
        index = {n.get("name"): i for i, n in enumerate(nodes)}
        missing = [n for n in (self.rig_node, *self.tracks) if n not in index]
        if missing:
            raise ValueError(f"glTF export: no node named {', '.join(missing)} to animate or to hold the cameras")
        channels, samplers = [], []
        for name, T in self.tracks.items():
            node = nodes[index[name]]
            node.pop("matrix", None)  # an animated node has TRS, not a matrix (glTF 2.0, 5.25)
            node["translation"] = [float(x) for x in T[0, :3, 3]]
            node["rotation"] = [float(x) for x in quat_xyzw(T[0, :3, :3])]
            for path in ("translation", "rotation"):
                samplers.append({"input": self.accessors["time"], "output": self.accessors[f"{name}/{path}"],
                                 "interpolation": "LINEAR"})
                channels.append({"sampler": len(samplers) - 1, "target": {"node": index[name], "path": path}})
        tree.setdefault("cameras", [])
        rig = nodes[index[self.rig_node]]
        for cam in self.cameras:
            tree["cameras"].append({"name": cam.name, **perspective(cam.K, cam.width, cam.height)})
            M = np.asarray(cam.T_ego_cam, np.float64) @ GL_FROM_CV
            nodes.append({"name": CAMERA_PREFIX + cam.name, "camera": len(tree["cameras"]) - 1,
                          "matrix": [float(x) for x in M.T.ravel()]})  # glTF matrices are column-major
            rig.setdefault("children", []).append(len(nodes) - 1)
        if channels:
            tree.setdefault("animations", []).append({"name": ANIMATION, "channels": channels, "samplers": samplers})
