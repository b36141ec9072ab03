"""The ego car's body: a sedan mesh in the ego frame (boxes and wheel cylinders of `scenes.primitives`), whose
render gives the exact self-occlusion masks (`synth.render.render_masks`) and which the live appearance shades
(`synth.config.EgoConfig`). Its rear axle is at x = 0; the rig's mounts (`synth.rig`) sit on it.

Example::

    >>> from synth.ego_body import ego_body_mesh
    >>> mesh = ego_body_mesh(0, 1, 2, camera_height_m=1.6)
    >>> round(float(mesh.positions[:, 0].max()), 2), round(float(mesh.positions[:, 2].max()), 2)
    (3.6, 1.48)
"""
from __future__ import annotations

import math

import numpy as np

from scenes.model import Mesh


def ego_body_mesh(layer_body: int, layer_glass: int, layer_tyre: int, camera_height_m: float = 1.6) -> Mesh:
    """The ego car in the ego frame: a sedan (4.6 x 1.85 m) whose rear axle is at x = 0.

    The hood is low enough that CAM_FRONT does not see it (vertical fov up to ~55 deg).

    The roof sits 0.12 m below the cameras so the roof-mounted rear-side cameras see it.
    No two faces of the body are coplanar (each box reaches into its neighbour, none ends on
    another's face), so the depth test never has to break a tie: the glass ends 4 cm inside the
    roof panel and 2 cm inside the lower body, the hood starts 5 cm inside the lower body and 2 cm above its floor.
    """
    from scenes.primitives import box, cylinder

    roof = camera_height_m - 0.12
    tint_body = (0.55, 0.57, 0.6)
    parts = [
        box((3.3, 1.85, 0.62), layer_body, tint_body, T=_translate(0.65, 0.0, 0.33 + 0.31)),  # lower body
        box((1.35, 1.8, 0.5), layer_body, tint_body, T=_translate(2.925, 0.0, 0.35 + 0.25)),  # hood, kept low
        # glass: x -0.58..2.28 (the body's front face is at 2.3), z 0.93..roof - 0.04
        box((2.86, 1.6, roof - 0.97), layer_glass, (1, 1, 1), T=_translate(0.85, 0.0, 0.93 + (roof - 0.97) / 2)),
        box((2.6, 1.62, 0.06), layer_body, tint_body, T=_translate(0.8, 0.0, roof - 0.03)),  # roof panel
    ]
    for x in (0.0, 2.8):
        for y in (-0.8, 0.8):
            parts.append(cylinder(0.33, 0.24, layer_tyre, segments=12, tint=(1, 1, 1),
                                  T=_translate(x, y, 0.33) @ _rot_x(math.pi / 2) @ _translate(0, 0, -0.12)))
    return Mesh.merge(parts)


def _translate(x: float, y: float, z: float) -> np.ndarray:
    T = np.eye(4)
    T[:3, 3] = (x, y, z)
    return T


def _rot_x(a: float) -> np.ndarray:
    T = np.eye(4)
    c, s = math.cos(a), math.sin(a)
    T[1:3, 1:3] = [[c, -s], [s, c]]
    return T
