"""Semantic classes of the scene model: the class table, each material's class, each object's class.

A pixel's class is its material's (`MATERIAL_CLASS`, from `scenes.materials.TABLE`), except where the object it belongs to names its own
(`Scene.instance_class`: a highway building faced with barrier concrete is a building), on a mover (a
vehicle that moves: ``moving_vehicle``), on the ego body (``ego``) and where no surface is (``sky``, exactly
the pixels without depth). The table's colours are Cityscapes' where Cityscapes has the class.

Each class belongs to one of the evaluation's groups (`GROUPS`): road, building, vehicle, vegetation,
other, and the two never evaluated (sky has no depth, the ego body is masked).

Example::

    from scenes.labels import CLASS, class_table
    CLASS["road"]          # 1
"""
from __future__ import annotations

import numpy as np

from scenes.materials import TABLE

#: (name, RGB colour, evaluation group), index = position; stable (datasets store the indices)
CLASSES: tuple[tuple[str, tuple[int, int, int], str], ...] = (
    ("sky", (70, 130, 180), "sky"),
    ("road", (128, 64, 128), "road"),
    ("lane_marking", (255, 255, 255), "road"),
    ("sidewalk", (244, 35, 232), "other"),           # sidewalks, kerbs, plazas
    ("building", (70, 70, 70), "building"),
    ("vegetation", (107, 142, 35), "vegetation"),    # trees, hedges, bushes
    ("pole", (153, 153, 153), "other"),              # lamp posts, sign posts and their signs
    ("barrier", (102, 102, 156), "other"),           # jersey barriers, guardrails, walls
    ("parked_vehicle", (0, 0, 142), "vehicle"),
    ("moving_vehicle", (0, 60, 100), "vehicle"),
    ("other_ground", (152, 251, 152), "other"),      # lawns, verges, gravel
    ("ego", (0, 0, 0), "ego"),
)
CLASS: dict[str, int] = {name: i for i, (name, _, _) in enumerate(CLASSES)}
#: groups the evaluation reports, in order (sky and ego are never evaluated)
GROUPS = ("road", "building", "vehicle", "vegetation", "other")

#: class index of each material layer (`scenes.textures.LAYER`)
MATERIAL_CLASS = np.array([CLASS[m.semantic] for m in TABLE], np.uint8)


def class_table() -> list[dict]:
    """The table a dataset's manifest carries: index, name, colour, group."""
    return [{"index": i, "name": n, "color": list(c), "group": g} for i, (n, c, g) in enumerate(CLASSES)]


def instance_classes(scene) -> np.ndarray:
    """(n_instances + 1,) uint8 class index of every instance id of `scene` (`scenes.model.Scene`): a static
    object's named class, else the class most of its vertices' materials have; a mover's ``moving_vehicle``;
    id 0 (stuff) ``sky``, never used (stuff takes its material's class)."""
    n_static = scene.n_static_instances
    out = np.zeros(n_static + 1 + len(scene.movers), np.uint8)
    inst = scene.static.instances
    cls = MATERIAL_CLASS[scene.static.layers]
    keep = inst > 0
    if keep.any():
        counts = np.zeros((n_static + 1, len(CLASSES)), np.int64)
        np.add.at(counts, (inst[keep], cls[keep]), 1)
        out[:n_static + 1] = counts.argmax(1)
    for i, name in scene.instance_class.items():
        out[int(i)] = CLASS[name]
    out[n_static + 1:] = CLASS["moving_vehicle"]
    out[0] = CLASS["sky"]
    return out


def instance_table(scene) -> list[dict]:
    """Every object of `scene`: id, class, moving, and for a mover its pose per frame (4x4, world <- object)."""
    classes = instance_classes(scene)
    rows = [{"id": i, "class": CLASSES[int(classes[i])][0], "moving": False}
            for i in range(1, scene.n_static_instances + 1)]
    for k, m in enumerate(scene.movers):
        i = scene.mover_instance(k)
        rows.append({"id": i, "class": CLASSES[int(classes[i])][0], "moving": True, "name": m.name,
                     "T_world_obj": np.round(m.T_world_obj, 6).tolist()})
    return rows
