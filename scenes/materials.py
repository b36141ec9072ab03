"""The one table of the scene's materials: name (its texture layer is its position), the metres one texture
tile covers, and the semantic class its surfaces get (`scenes.labels`). `scenes.textures` makes each one's
texture; meshes name a layer with `LAYER[name]` and scale its uvs with `uv_scale_for(name)`.

A new material is one row here and its texture maker in `scenes.textures` (checked at import). The order
never changes within a schema version: datasets store layer indices only through the labels' classes.

Example::

    from scenes.materials import LAYER, uv_scale_for
    LAYER["brick"], uv_scale_for("brick")     # (7, (0.5, 0.833...))
"""
from __future__ import annotations

from dataclasses import dataclass


@dataclass(frozen=True)
class Material:
    name: str
    tile_m: tuple[float, float]  # metres (width, height) one texture tile covers on a surface
    semantic: str                # its class in scenes.labels.CLASSES


TABLE: tuple[Material, ...] = (
    Material("asphalt", (4.0, 4.0), "road"),                       # 0  road surface
    Material("lane_marking", (3.0, 0.15), "lane_marking"),         # 1  painted lines (white, worn)
    Material("sidewalk", (2.4, 2.4), "sidewalk"),                  # 2  paving slabs
    Material("kerb", (2.0, 0.3), "sidewalk"),                      # 3  granite/concrete kerb stones
    Material("grass", (3.0, 3.0), "other_ground"),                 # 4  lawn, verges
    Material("gravel", (3.0, 3.0), "other_ground"),                # 5  shoulders, embankments
    Material("plaza", (4.0, 4.0), "sidewalk"),                     # 6  large concrete slabs (urban ground)
    Material("brick", (2.0, 1.2), "building"),                     # 7  brick courses with mortar
    Material("facade_windows_a", (3.2, 3.2), "building"),          # 8  plaster facade, a window per tile
    Material("facade_windows_b", (4.0, 3.6), "building"),          # 9  stone facade, two tall windows
    Material("facade_windows_c", (3.0, 3.0), "building"),          # 10 brick facade, window with sill
    Material("facade_glass", (3.0, 3.6), "building"),              # 11 office curtain wall
    Material("shopfront", (6.0, 4.0), "building"),                 # 12 ground-floor shop windows
    Material("house_siding", (2.0, 2.0), "building"),              # 13 horizontal boards (tinted)
    Material("roof_tiles", (2.0, 2.0), "building"),                # 14 pitched roof tiles
    Material("roof_flat", (4.0, 4.0), "building"),                 # 15 flat roof membrane / gravel
    Material("foliage", (2.0, 2.0), "vegetation"),                 # 16 tree crowns
    Material("bark", (1.0, 1.0), "vegetation"),                    # 17 tree trunks
    Material("hedge", (1.5, 1.5), "vegetation"),                   # 18 hedges, bushes
    Material("metal_pole", (0.5, 2.0), "pole"),                    # 19 lamp posts, sign posts
    Material("car_paint", (2.0, 2.0), "parked_vehicle"),           # 20 light grey, tinted per car
    Material("car_glass", (2.0, 1.0), "parked_vehicle"),           # 21 dark windows with reflections
    Material("tyre", (0.6, 0.3), "parked_vehicle"),                # 22 tyres with tread
    Material("barrier_concrete", (4.0, 1.0), "barrier"),           # 23 New-Jersey barriers, walls
    Material("guardrail", (4.0, 0.4), "barrier"),                  # 24 corrugated steel rail
    Material("sign", (1.0, 1.0), "pole"),                          # 25 sign face (tinted)
    Material("house_windows", (3.0, 2.8), "building"),             # 26 house wall with a window
)
MATERIALS: tuple[str, ...] = tuple(m.name for m in TABLE)
LAYER: dict[str, int] = {name: i for i, name in enumerate(MATERIALS)}
#: metres (width, height) one texture tile covers on a surface
TILE_M: dict[str, tuple[float, float]] = {m.name: m.tile_m for m in TABLE}


def uv_scale_for(name: str) -> tuple[float, float]:
    """Tiles per metre (su, sv) for material `name`, from `TILE_M`."""
    if name not in TILE_M:
        raise ValueError(f"unknown material {name!r}; known: {', '.join(MATERIALS)}")
    w, h = TILE_M[name]
    return 1.0 / w, 1.0 / h
