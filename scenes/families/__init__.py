"""Scene families: one builder per family, `(cfg, n_frames, fps, rng) -> Scene`.

Example::

    from scenes.families import BUILDERS
    scene = BUILDERS["urban"](SceneConfig(), 20, 10.0, np.random.default_rng(0))
"""
from scenes.families.grid import build_residential, build_urban
from scenes.families.highway import build_highway

BUILDERS = {"urban": build_urban, "residential": build_residential, "highway": build_highway}

__all__ = ["BUILDERS", "build_urban", "build_residential", "build_highway"]
