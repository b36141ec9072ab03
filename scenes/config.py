"""Configuration of the procedural scene recipes (`SceneConfig`).

All defaults live here; a dataset preset lists only what differs, e.g.::

    synth render configs/data/tiny.yaml --out DATA scene.family=urban scene.traffic_density=0.5

Example::

    from scenes.config import SceneConfig
    cfg = SceneConfig(family="highway", traffic_density=0.8)
"""
from __future__ import annotations

from typing import Literal

from pydantic import Field, field_validator

from corelib.configlib import StrictModel

#: the scene families, in the order of `SceneConfig.family_weights`; each has its builder in
#: `scenes.families.BUILDERS` (a new family: its module, its BUILDERS line, its name here)
FAMILIES = ("urban", "residential", "highway")
FamilyName = Literal[FAMILIES + ("mixed",)]  # type: ignore[valid-type]


class SceneConfig(StrictModel):
    """Knobs of the scene generator (units in the names; densities are relative, 1 = typical).

    family:          "urban" | "residential" | "highway" | "mixed" ("mixed" draws one concrete
                     family per sequence from the sequence's rng, uniformly unless `family_weights`).
    family_weights:  relative weights of (urban, residential, highway) for "mixed".
    traffic_density: moving vehicles, 0 = none, 1 = typical, up to 3.
    parked_density:  parked cars along kerbs (urban/residential), 0 = none, 1 = typical.
    vegetation_density: trees/hedges, 0 = none, 1 = typical.
    turn_probability: probability that the route contains a turn/curve.
    texture_size:    edge length S of each texture layer in pixels.
    view_radius_m:   geometry is generated within this distance of the ego route.
    speed_scale:     multiplies the family's ego speed range (0.5 = slower, denser frames).
    """

    family: FamilyName = "mixed"
    # strict=False only so that a YAML list is accepted as the tuple
    family_weights: tuple[float, ...] = Field(default=(1.0,) * len(FAMILIES), strict=False)
    traffic_density: float = Field(default=1.0, ge=0.0, le=3.0)
    parked_density: float = Field(default=1.0, ge=0.0, le=2.0)
    vegetation_density: float = Field(default=1.0, ge=0.0, le=2.0)
    turn_probability: float = Field(default=0.5, ge=0.0, le=1.0)
    texture_size: Literal[128, 256, 512] = 256
    view_radius_m: float = Field(default=90.0, ge=40.0, le=200.0)
    speed_scale: float = Field(default=1.0, ge=0.25, le=1.5)

    @field_validator("family_weights")
    @classmethod
    def _weights_ok(cls, w: tuple[float, ...]) -> tuple[float, ...]:
        if len(w) != len(FAMILIES) or not all(0 <= x <= 1000 for x in w) or sum(w) <= 0:  # NaN fails 0 <= x
            raise ValueError(f"family_weights must be {len(FAMILIES)} numbers in [0, 1000] with a positive sum "
                             f"({', '.join(FAMILIES)})")
        return w
