"""Reusable scene objects built from primitives: cars, trees, lamps, signs, buildings, houses.

Every function returns a `Mesh` in the object's own frame: x forward (or along the
street), y left, z up, origin on the ground (z = 0); place it with `Mesh.transformed`
and `scenes.primitives.pose_2d`. Sizes are metres.

Example::

    from scenes.objects import car
    from scenes.primitives import pose_2d
    m = car((0.6, 0.1, 0.1)).transformed(pose_2d(10.0, -3.0, 0.0))   # a red car at (10, -3)
"""
from __future__ import annotations

import functools

import numpy as np

from scenes.model import Mesh
from scenes.primitives import box, cone, cylinder, gable_roof, pose_2d, sphere_low
from scenes.textures import LAYER, uv_scale_for

#: car body extent in its frame (origin on the ground below the rear axle), metres
CAR_LENGTH_M = 4.5
CAR_WIDTH_M = 1.8
CAR_REAR_OVERHANG_M = 1.0
CAR_WHEELBASE_M = 2.7


def _T(x: float = 0.0, y: float = 0.0, z: float = 0.0, yaw: float = 0.0) -> np.ndarray:
    return pose_2d(x, y, yaw, z)


def car(paint_rgb) -> Mesh:
    """A simple car (~4.5 x 1.8 x 1.5 m, 180 triangles), origin on the ground below the rear axle.

    paint_rgb: (3,) linear RGB tint of the `car_paint` layer (other parts keep tint 1). The
    body spans x in [-1.0, 3.5], y in [-0.9, 0.9], z in [0.3, 1.56] (wheels reach z = 0).
    """
    paint = np.asarray(paint_rgb, dtype=np.float64)
    if paint.shape != (3,) or np.any(paint < 0) or not np.all(np.isfinite(paint)):
        raise ValueError(f"paint_rgb must be 3 non-negative numbers, got {paint_rgb!r}")
    base = _car_template()
    tints = base.tints.copy()
    tints[base.layers == LAYER["car_paint"]] = paint
    return Mesh(base.positions.copy(), base.normals.copy(), base.uvs.copy(), base.layers.copy(), tints,
                base.indices.copy())


@functools.lru_cache(maxsize=1)
def _car_template() -> Mesh:
    """The car geometry with all tints 1 (built once: cars are the most numerous objects)."""
    paint = np.ones(3)
    tyre_tint = (1.0, 1.0, 1.0)
    L, W = CAR_LENGTH_M, CAR_WIDTH_M
    xc = L / 2 - CAR_REAR_OVERHANG_M
    su = uv_scale_for("car_paint")
    parts = [
        box((L, W, 0.72), LAYER["car_paint"], paint, _T(xc, 0, 0.3 + 0.36), su, faces="+x-x+y-y+z"),
        # cabin: glass on the sides/front/back, painted roof
        box((2.3, 1.56, 0.48), LAYER["car_glass"], (1, 1, 1), _T(xc - 0.25, 0, 1.02 + 0.24),
            uv_scale_for("car_glass"), faces="+x-x+y-y"),
        box((2.3, 1.56, 0.06), LAYER["car_paint"], paint, _T(xc - 0.25, 0, 1.5 + 0.03), su, faces="+x-x+y-y+z"),
        # dark bumpers/lights strip low at the front and back: gradients at the car's ends
        box((0.06, W * 0.9, 0.18), LAYER["tyre"], (1, 1, 1), _T(3.5 + 0.03, 0, 0.45), 1.0, faces="+x+z"),
        box((0.06, W * 0.9, 0.18), LAYER["tyre"], (1, 1, 1), _T(-1.0 - 0.03, 0, 0.45), 1.0, faces="-x+z"),
    ]
    # wheels: rotation about x by -90 deg maps the cylinder's axis (local z) to +y
    rx = np.array([[1, 0, 0, 0], [0, 0, 1, 0], [0, -1, 0, 0], [0, 0, 0, 1]], dtype=np.float64)
    for x in (0.0, CAR_WHEELBASE_M):
        for side in (1.0, -1.0):
            T = _T(x, side * (W / 2 - 0.05), 0.33) @ rx @ _T(0, 0, -0.11)
            parts.append(cylinder(0.33, 0.22, LAYER["tyre"], 10, tyre_tint, T, uv_scale_for("tyre")))
    return Mesh.merge(parts)


def tree(height: float, crown_radius: float, conifer: bool, tint=(1.0, 1.0, 1.0)) -> Mesh:
    """A tree with a trunk (6-sided prism) and a low-poly crown; base at the origin.

    height: total height (metres); crown_radius: metres. conifer: cone crown, else ellipsoid.
    """
    if not (height > 1.0 and crown_radius > 0.2):
        raise ValueError(f"height must be > 1 m and crown_radius > 0.2 m, got {height}, {crown_radius}")
    trunk_r = 0.12 + 0.03 * crown_radius
    bark = uv_scale_for("bark")
    leaf = uv_scale_for("foliage")
    if conifer:
        trunk_h = 0.25 * height
        parts = [cylinder(trunk_r, trunk_h + 0.3, LAYER["bark"], 6, (1, 1, 1), None, bark, caps=False),
                 cone(crown_radius, height - trunk_h, LAYER["foliage"], 8, tint, _T(0, 0, trunk_h), leaf)]
    else:
        crown_h = min(0.6 * height, 2.2 * crown_radius)
        trunk_h = height - crown_h
        parts = [cylinder(trunk_r, trunk_h + 0.3 * crown_h, LAYER["bark"], 6, (1, 1, 1), None, bark, caps=False),
                 sphere_low((crown_radius, crown_radius, crown_h / 2), LAYER["foliage"], 8, 5, tint,
                            _T(0, 0, trunk_h + crown_h / 2), leaf)]
    return Mesh.merge(parts)


def bush(radius: float, tint=(1.0, 1.0, 1.0)) -> Mesh:
    """A low ellipsoid bush (hedge texture) sitting on the ground."""
    return sphere_low((radius, radius, 0.7 * radius), LAYER["hedge"], 7, 4, tint,
                      _T(0, 0, 0.5 * radius), uv_scale_for("hedge"))


def lamp_post(height: float, arm_m: float) -> Mesh:
    """Street lamp: pole at the origin, arm and lamp head pointing towards +x (the road)."""
    pole = uv_scale_for("metal_pole")
    return Mesh.merge([
        cylinder(0.09, height, LAYER["metal_pole"], 6, (1, 1, 1), None, pole, caps=False),
        box((arm_m, 0.1, 0.1), LAYER["metal_pole"], (1, 1, 1), _T(arm_m / 2, 0, height - 0.1), pole),
        box((0.6, 0.3, 0.15), LAYER["metal_pole"], (0.6, 0.6, 0.6), _T(arm_m, 0, height - 0.2), pole),
    ])


def sign_post(height: float, plate_w: float, plate_h: float, tint) -> Mesh:
    """Sign on a post: the plate faces +x (towards traffic coming from +x), bottom at `height`."""
    return Mesh.merge([
        cylinder(0.05, height + plate_h * 0.8, LAYER["metal_pole"], 6, (1, 1, 1), None,
                 uv_scale_for("metal_pole"), caps=False),
        box((0.04, plate_w, plate_h), LAYER["sign"], tint, _T(0.08, 0, height + plate_h / 2),
            (1.0 / plate_w, 1.0 / plate_h)),
    ])


def building(width: float, depth: float, height: float, facade: str, tint=(1.0, 1.0, 1.0),
             shop_height: float = 0.0) -> Mesh:
    """Flat-roofed block: footprint x in [-width/2, width/2] (facade along x, facing -y),
    y in [0, depth] (the street is at y < 0), z in [0, height]. Facade on all walls, `roof_flat`
    on top, optional `shopfront` ground floor of `shop_height` metres.
    """
    if not (width > 0 and depth > 0 and height > 0):
        raise ValueError(f"width, depth, height must be > 0, got {width}, {depth}, {height}")
    su = uv_scale_for(facade)
    parts = []
    z0 = 0.0
    if shop_height > 0:
        parts.append(box((width, depth, shop_height), LAYER["shopfront"], (1, 1, 1),
                         _T(0, depth / 2, shop_height / 2), uv_scale_for("shopfront"), faces="+x-x+y-y"))
        z0 = shop_height
    parts.append(box((width, depth, height - z0), LAYER[facade], tint, _T(0, depth / 2, z0 + (height - z0) / 2),
                     su, faces="+x-x+y-y"))
    parts.append(box((width + 0.4, depth + 0.4, 0.5), LAYER["roof_flat"], (1, 1, 1), _T(0, depth / 2, height + 0.25),
                     uv_scale_for("roof_flat"), faces="+x-x+y-y+z"))
    return Mesh.merge(parts)


def house(width: float, depth: float, floors: int, wall_tint, roof_tint, roof_pitch: float = 0.6) -> Mesh:
    """Detached house: walls (x in [-w/2, w/2], y in [0, depth], street at y < 0) with windows,
    a gable roof with its ridge along x, `floors` storeys of 2.8 m.
    """
    if floors < 1:
        raise ValueError(f"floors must be >= 1, got {floors}")
    wall_h = 2.8 * floors
    su = uv_scale_for("house_windows")
    walls = box((width, depth, wall_h), LAYER["house_windows"], wall_tint, _T(0, depth / 2, wall_h / 2),
                su, faces="+x-x+y-y")
    roof = gable_roof((width, depth), roof_pitch * depth / 2, LAYER["roof_tiles"], LAYER["house_siding"],
                      roof_tint, wall_tint, _T(0, depth / 2, wall_h), uv_scale_for("roof_tiles"))
    return Mesh.merge([walls, roof])
