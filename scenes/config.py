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

#: the scene families, each with its default weight in `SceneConfig.family_weights` (the order is the draw's);
#: each has its builder in `scenes.families.BUILDERS` (a new family: its module, its BUILDERS line, its name
#: here, appended, with default weight 0: a "mixed" dataset then draws it only when asked, and every earlier
#: dataset keeps its renders and its hash; `SceneConfig.hashed_form`)
FAMILY_WEIGHTS = {"urban": 1.0, "residential": 1.0, "highway": 1.0}
FAMILIES = tuple(FAMILY_WEIGHTS)
#: the families of the positional ``family_weights`` of old configs and manifests, in its order (frozen)
POSITIONAL_FAMILIES = ("urban", "residential", "highway")
FamilyName = Literal[FAMILIES + ("mixed",)]  # type: ignore[valid-type]
MAX_FAMILY_WEIGHT = 1000.0


class SceneConfig(StrictModel):
    """Knobs of the scene generator (units in the names; densities are relative, 1 = typical).

    family:          "urban" | "residential" | "highway" | "mixed" ("mixed" draws one concrete
                     family per sequence from the sequence's rng, uniformly unless `family_weights`).
    family_weights:  relative weight of each family for "mixed", a mapping ``{urban: 1, highway: 0}``; a family
                     left out keeps its default (`FAMILY_WEIGHTS`); each in [0, 1000], not all 0. The
                     positional list of old configs and manifests, ``[urban, residential, highway]``, is read.
    traffic_density: moving vehicles, 0 = none, 1 = typical, up to 3.
    parked_density:  parked cars along kerbs (urban/residential), 0 = none, 1 = typical.
    vegetation_density: trees/hedges, 0 = none, 1 = typical.
    turn_probability: probability that the route contains a turn/curve.
    texture_size:    edge length S of each texture layer in pixels.
    view_radius_m:   geometry is generated within this distance of the ego route.
    speed_scale:     multiplies the family's ego speed range (0.5 = slower, denser frames).
    """

    family: FamilyName = "mixed"
    family_weights: dict[str, float] = Field(default_factory=lambda: dict(FAMILY_WEIGHTS), strict=False)
    traffic_density: float = Field(default=1.0, ge=0.0, le=3.0)
    parked_density: float = Field(default=1.0, ge=0.0, le=2.0)
    vegetation_density: float = Field(default=1.0, ge=0.0, le=2.0)
    turn_probability: float = Field(default=0.5, ge=0.0, le=1.0)
    texture_size: Literal[128, 256, 512] = 256
    view_radius_m: float = Field(default=90.0, ge=40.0, le=200.0)
    speed_scale: float = Field(default=1.0, ge=0.25, le=1.5)

    @field_validator("family_weights", mode="before")
    @classmethod
    def _weights_in(cls, w):
        """The positional list of old configs and manifests, as the mapping it meant."""
        if isinstance(w, (list, tuple)):
            if len(w) != len(POSITIONAL_FAMILIES):
                raise ValueError(f"family_weights: a mapping {{family: weight}} ({', '.join(FAMILIES)}); the "
                                 f"positional list of old configs has {len(POSITIONAL_FAMILIES)} numbers, got {len(w)}")
            return dict(zip(POSITIONAL_FAMILIES, w))
        return w

    @field_validator("family_weights")
    @classmethod
    def _weights_ok(cls, w: dict[str, float]) -> dict[str, float]:
        unknown = sorted(set(w) - set(FAMILIES))
        if unknown:
            raise ValueError(f"family_weights.{str(unknown[0])[:40]}: unknown scene family; known: {', '.join(FAMILIES)}")
        for name, x in w.items():
            if not 0 <= x <= MAX_FAMILY_WEIGHT:  # NaN fails too
                raise ValueError(f"family_weights.{name} must be in [0, {MAX_FAMILY_WEIGHT:g}], got {x}")
        full = {f: float(w.get(f, FAMILY_WEIGHTS[f])) for f in FAMILIES}  # in FAMILIES order: the draw's
        if sum(full.values()) <= 0:
            raise ValueError(f"family_weights must not all be 0 (got {full})")
        return full

    def hashed_form(self, d: dict) -> dict:
        """`corelib.configlib.config_hash` reads ``family_weights`` as the positional list it was before it
        became a mapping, while every family beyond those three holds its default: the same scenes, the same
        hash, so every dataset cached before (and after) keeps its renders."""
        w = self.family_weights
        if all(w[f] == FAMILY_WEIGHTS[f] for f in FAMILIES if f not in POSITIONAL_FAMILIES):
            d = {**d, "family_weights": [w[f] for f in POSITIONAL_FAMILIES]}
        return d
