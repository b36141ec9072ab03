"""Weather on the formed image, from the exact depth: fog (issue 48, item 3).

Fog is the single-scattering model ``I = I0 * t + A * (1 - t)``, ``t = exp(-density * ray_dist)``, with
``ray_dist`` the distance along each pixel's ray to its surface, made from the rendered z-depth and K
(``ray_dist = depth * |K^-1 (u + 0.5, v + 0.5, 1)|``): one point seen by two cameras is fogged alike, which
z-depth would not do. Pixels with no surface (depth 0: the sky, or beyond ``rig.zfar_m``) take the airlight
A. It acts on linear light and never on the depth, masks or labels, which stay exact. The renderer's own
distance haze (``fog_dist_m`` in `synth.gl_backend`, 900 m) is part of the ideal image and stays.

Example::

    density = draw_fog_density(cfg.weather, cfg.seed, index)
    linear = apply_fog(linear, ray_distance(depth, cam.K), density, airlight)
"""
from __future__ import annotations

import math

import numpy as np
from pydantic import Field, field_validator

from corelib.configlib import StrictModel

WEATHER_DRAWS = 0xF06  # the seed stream of a sequence's weather


class WeatherConfig(StrictModel):
    """Weather applied to the formed image (`synth.weather`); off by default (the section is then not hashed).

    fog_density: the extinction coefficient in 1/m (0 = no fog; 0.02 halves the contrast at 35 m), or a
        range [lo, hi] drawn uniformly once per sequence.
    airlight_rgb: the fog's linear colour; null = the sequence's horizon colour (`synth.lighting`), so that
        fogged distance fades into the sky. Either is times the camera's lighting gain, as every surface is.
    """

    fog_density: float | list[float] = Field(0.0, description="1/m, or [lo, hi] per sequence")
    airlight_rgb: list[float] | None = None

    @field_validator("fog_density")
    @classmethod
    def _density(cls, v):
        vals = v if isinstance(v, list) else [v]
        if isinstance(v, list) and not (len(v) == 2 and v[0] <= v[1]):
            raise ValueError(f"a fog density range is [lo, hi] with lo <= hi, got {v}")
        if not all(math.isfinite(x) and 0.0 <= x <= 1.0 for x in vals):
            raise ValueError(f"fog density is in [0, 1] per metre, got {v}")
        return v

    @field_validator("airlight_rgb")
    @classmethod
    def _airlight(cls, v):
        if v is not None and not (len(v) == 3 and all(math.isfinite(c) and 0.0 <= c <= 10.0 for c in v)):
            raise ValueError(f"airlight_rgb is a linear (R, G, B) triple in [0, 10], got {v}")
        return v

    def is_identity(self) -> bool:
        """True when no weather is asked for: the renderer's bytes are left as they are."""
        return self.fog_density in (0.0, [0.0, 0.0])


def draw_fog_density(cfg: WeatherConfig, seed: int, index: int) -> float:
    """Sequence `index`'s fog density: the configured value, or a uniform draw from its range."""
    if not isinstance(cfg.fog_density, list):
        return float(cfg.fog_density)
    lo, hi = cfg.fog_density
    rng = np.random.default_rng(np.random.SeedSequence([seed, index, WEATHER_DRAWS]))
    return float(rng.uniform(lo, hi))


def ray_distance(depth: np.ndarray, K) -> np.ndarray:
    """(H, W) depth in metres of the camera's depth kind (0 = no surface) -> (H, W) distance along each pixel
    centre's ray (0 stays 0). `K`: a pinhole K, or a `synth.camera.Intrinsics` of any lens row (a ``range``
    camera's depth is the distance itself; a pixel without a ray has none, 0)."""
    from synth import camera
    from synth.protocol import pixel_rays

    H, W = depth.shape
    if isinstance(K, camera.Intrinsics) and K.model != "pinhole":
        if camera.depth_kind(K) == "range":
            return depth.astype(np.float64)
        norm = np.linalg.norm(camera.rays(K, H, W), axis=0).reshape(H, W)  # z = 1 rays
        return depth.astype(np.float64) * np.nan_to_num(norm, nan=0.0)
    rays = pixel_rays(K.K if isinstance(K, camera.Intrinsics) else K, W, H)  # (H, W, 3) at z = 1
    return depth.astype(np.float64) * np.linalg.norm(rays, axis=-1)


def apply_fog(linear: np.ndarray, ray_dist: np.ndarray, density: float, airlight) -> np.ndarray:
    """(H, W, 3) linear light fogged towards `airlight` (3,) over (H, W) `ray_dist` (0 = no surface: the
    airlight); density 0 returns `linear` itself."""
    if density <= 0:
        return linear
    t = np.where(ray_dist > 0, np.exp(-density * ray_dist), 0.0)[..., None]
    return linear * t + np.asarray(airlight, np.float64) * (1.0 - t)
