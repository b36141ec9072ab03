"""Procedural driving scenes: pure functions `(config, rng) -> Scene` (no rendering, no files).

Families: "urban" (dense street grid, tall buildings), "residential" (houses with pitched
roofs, yards, trees), "highway" (divided motorway, barriers, embankments); "mixed" draws
one per sequence. World frame: metres, z up, road surface z = 0; the ego frame is
x forward, y left, z up, origin on the road below the rear axle.

Example::

    import numpy as np
    from scenes import SceneConfig, build_scene
    rng = np.random.default_rng(np.random.SeedSequence([seed, sequence_index]))
    scene = build_scene(SceneConfig(family="mixed"), n_frames=40, fps=10.0, rng=rng)
    scene.static.n_triangles, scene.T_world_ego.shape      # (~20k, (40, 4, 4))
"""
from __future__ import annotations

import numpy as np

from scenes.config import FAMILIES, SceneConfig
from scenes.families import BUILDERS
from scenes.model import Mesh, Mover, Scene
from scenes.textures import LAYER, MATERIALS



def pick_family(cfg: SceneConfig, rng: np.random.Generator) -> str:
    """The concrete family of one sequence: `cfg.family`, or a weighted draw for "mixed"."""
    if cfg.family != "mixed":
        return cfg.family
    w = np.asarray([cfg.family_weights[f] for f in FAMILIES], dtype=np.float64)
    return FAMILIES[int(rng.choice(len(FAMILIES), p=w / w.sum()))]


def build_scene(cfg: SceneConfig, n_frames: int, fps: float, rng: np.random.Generator) -> Scene:
    """Build one sequence's scene.

    cfg:      SceneConfig (family, densities, texture size, view radius).
    n_frames: number of ego poses F (>= 1); fps: frames per second (> 0).
    rng:      the sequence's generator, the only source of randomness (same state -> same arrays).
    Returns a Scene: static Mesh (world frame, merged), movers (T_world_obj (F, 4, 4)),
    textures (L, S, S, 3) uint8 with materials == list(MATERIALS), T_world_ego (F, 4, 4) float64,
    family, info {family, speed_mps, n_movers, n_triangles, turn, ...}.
    """
    if not isinstance(cfg, SceneConfig):
        raise ValueError(f"cfg must be a SceneConfig, got {type(cfg).__name__}")
    if isinstance(n_frames, bool) or not isinstance(n_frames, (int, np.integer)) or n_frames < 1:
        raise ValueError(f"n_frames must be an int >= 1, got {n_frames!r}")
    if isinstance(fps, bool) or not isinstance(fps, (int, float, np.floating, np.integer)) or not (0 < fps <= 1000):
        raise ValueError(f"fps must be a number in (0, 1000], got {fps!r}")
    if not isinstance(rng, np.random.Generator):
        raise ValueError(f"rng must be a numpy.random.Generator, got {type(rng).__name__}")
    family = pick_family(cfg, rng)
    scene = BUILDERS[family](cfg, int(n_frames), float(fps), rng)
    scene.info["fps"] = float(fps)
    return scene


__all__ = ["FAMILIES", "LAYER", "MATERIALS", "Mesh", "Mover", "Scene", "SceneConfig", "build_scene", "pick_family"]
