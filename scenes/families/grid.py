"""Street-grid families: "urban" (dense tall buildings, shops, parked cars) and
"residential" (detached houses with pitched roofs, yards, hedges, trees).

Layout: a Manhattan grid of straight two-way streets (horizontal ones at y = y_j,
vertical ones at x = x_k, blocks of random length); each crossing is an asphalt
square ("pad") of half-size = street half-width incl. sidewalks. The ego drives
along the horizontal street y = 0 in +x, in the outermost right-hand lane, and in
a fraction of sequences turns right at a crossing (a quarter circle inside the pad)
onto the vertical street, heading -y.

Example::

    scene = build_urban(SceneConfig(family="urban"), 20, 10.0, np.random.default_rng(0))
"""
from __future__ import annotations

from typing import NamedTuple

import numpy as np

from scenes.config import SceneConfig
from scenes.model import Mesh, Scene
from scenes.objects import CAR_LENGTH_M, building, bush, car, house, lamp_post, sign_post, tree
from scenes.meshing import from_quads
from scenes.primitives import box, ground_strip, pose_2d, quad, sweep
from scenes.route import Path, poses_4x4
from scenes.textures import LAYER, make_textures, uv_scale_for
from scenes.world import (KERB_H_M, MARK_Z_M, CrossSection, LaneTraffic, World, ground_tiles, lane_markings,
                          populate_lanes, random_paint)

FACADES = ("facade_windows_a", "facade_windows_b", "facade_windows_c", "facade_glass", "brick")
WALL_TINTS = np.array([[0.95, 0.93, 0.88], [0.9, 0.85, 0.72], [0.75, 0.82, 0.9], [0.7, 0.7, 0.7],
                       [0.85, 0.75, 0.6], [0.9, 0.9, 0.95], [0.65, 0.75, 0.65]])
ROOF_TINTS = np.array([[1.0, 1.0, 1.0], [0.45, 0.45, 0.5], [0.7, 0.5, 0.4], [0.35, 0.3, 0.28]])


def _blocks(rng: np.random.Generator, anchor: float, lo: float, hi: float, bmin: float, bmax: float) -> list[float]:
    """Street positions including `anchor`, spaced by random block lengths, covering [lo, hi]."""
    pos = [anchor]
    while pos[-1] < hi:
        pos.append(pos[-1] + rng.uniform(bmin, bmax))
    while pos[0] > lo:
        pos.insert(0, pos[0] - rng.uniform(bmin, bmax))
    return pos


def _sidewalk(poly: np.ndarray, xs: CrossSection, side: float) -> list[Mesh]:
    """Kerb face + sidewalk top (+ back face) on one side (+1 left, -1 right) of a street piece."""
    e, w, h = xs.asphalt_hw, xs.sidewalk_w, KERB_H_M
    if side > 0:
        kerb = [(e, h), (e, 0.0)]
        top = [(e + w, h), (e, h)]
        back = [(e + w, 0.0), (e + w, h)]
    else:
        kerb = [(-e, 0.0), (-e, h)]
        top = [(-e, h), (-e - w, h)]
        back = [(-e - w, h), (-e - w, 0.0)]
    return [sweep(poly, np.array(kerb), LAYER["kerb"], uv_scale=uv_scale_for("kerb")),
            sweep(poly, np.array(top), LAYER["sidewalk"], uv_scale=uv_scale_for("sidewalk")),
            sweep(poly, np.array(back), LAYER["kerb"], uv_scale=uv_scale_for("kerb"))]


def _frame(p0: np.ndarray, yaw: float):
    """Street frame helpers: point at (along, lateral) and the yaw."""
    t = np.array([np.cos(yaw), np.sin(yaw)])
    n = np.array([-np.sin(yaw), np.cos(yaw)])
    return lambda a, l: p0 + a * t + l * n


def build_grid(kind: str, cfg: SceneConfig, n_frames: int, fps: float, rng: np.random.Generator) -> Scene:
    """Build one urban or residential sequence (see module docstring). kind: "urban" | "residential"."""
    urban = kind == "urban"
    R_view = cfg.view_radius_m
    xs, bmin, bmax = _cross_section(urban, cfg, rng)
    route = _ego_route(xs, cfg, n_frames, fps, rng)
    world = World(route.ego_line, R_view)

    # ---------------------------------------------------------------- grid
    lo, hi = route.ego_line.min(0) - R_view - 10.0, route.ego_line.max(0) + R_view + 10.0
    xk = _blocks(rng, route.x_turn, lo[0], hi[0], bmin, bmax)
    yj = _blocks(rng, 0.0, lo[1], hi[1], bmin, bmax)
    xmin, xmax, ymin, ymax = xk[0], xk[-1], yj[0], yj[-1]
    ground = "plaza" if urban else "grass"
    world.add(ground_tiles(xmin - 20, xmax + 20, ymin - 20, ymax + 20, -0.02, ground), check=False)
    for p0, yaw, crossings, total, depths in _streets(xk, yj, xs.outer_hw):
        _street(world, p0, yaw, crossings, total, depths, xs, urban, cfg, rng)

    movers = _traffic(xs, route, xmin, xmax, R_view, cfg, rng)
    static = world.static_mesh()
    textures, materials = make_textures(rng, cfg.texture_size)
    info = {"family": kind, "speed_mps": route.speed, "n_movers": len(movers), "n_triangles": int(static.n_triangles),
            "turn": route.turn, "lanes_per_dir": int(xs.lanes_per_dir), "lane_w_m": float(xs.lane_w),
            "parking": bool(xs.parking_w > 0), "turn_radius_m": float(route.R_turn) if route.turn else None,
            "n_dropped_objects": int(world.n_dropped)}
    return Scene(static, movers, textures, materials, route.T_world_ego, kind, info,
                 instance_class=world.instance_class)


def _cross_section(urban: bool, cfg: SceneConfig, rng: np.random.Generator) -> tuple[CrossSection, float, float]:
    """The streets' cross-section and the range of block lengths (centre to centre)."""
    if urban:
        n = int(rng.choice([1, 2], p=[0.3, 0.7]))
        lane_w = rng.uniform(3.2, 3.6)
        median = 2.0 if n == 1 else 0.3
        parking = 2.3 if rng.random() < min(1.0, 0.75 * cfg.parked_density) else 0.0
        xs = CrossSection(lane_w, n, median, bike_w=1.5, parking_w=parking, sidewalk_w=rng.uniform(3.0, 5.0))
        bmin, bmax = 55.0, 110.0
    else:
        lane_w = rng.uniform(3.2, 3.5)
        parking = 2.3 if rng.random() < min(1.0, 0.6 * cfg.parked_density) else 0.0
        xs = CrossSection(lane_w, 1, 2.0, bike_w=1.5, parking_w=parking, sidewalk_w=rng.uniform(2.5, 3.5))
        bmin, bmax = 70.0, 130.0
    # block lengths are centre-to-centre: keep >= 40 m (urban) / 50 m (residential) between pads
    bmin = max(bmin, 2 * xs.outer_hw + (40.0 if urban else 50.0))
    bmax = max(bmax, bmin + 45.0)
    return xs, bmin, bmax


class _Route(NamedTuple):
    turn: bool
    R_turn: float
    speed: float
    x_turn: float              # the crossing street where a turn happens (or a reference)
    path: Path
    t: np.ndarray              # (F,) s
    ego_xy: np.ndarray         # (F, 2)
    T_world_ego: np.ndarray    # (F, 4, 4)
    ego_line: np.ndarray       # the polyline the world is built around


def _ego_route(xs: CrossSection, cfg: SceneConfig, n_frames: int, fps: float, rng: np.random.Generator) -> _Route:
    """The ego's drive along y = 0 in its outermost right lane, turning right at x = 0 in some sequences."""
    R_view = cfg.view_radius_m
    P = xs.outer_hw                      # pad half-size
    c = -xs.ego_offset                   # ego lane centre is at y = -c on a horizontal street
    turn = bool(rng.random() < cfg.turn_probability)
    R_turn = max(4.5, P - c - 0.5)
    v_hi = 12.0 if not turn else max(6.5, min(12.0, np.sqrt(7.0 * R_turn)))
    speed = float(rng.uniform(6.0, v_hi) * cfg.speed_scale)
    duration = (n_frames - 1) / fps
    D = speed * duration
    arc_len = 0.5 * np.pi * R_turn
    x_turn = 0.0
    s_a = float(rng.uniform(0.0, max(D - 0.5 * arc_len, 1.0))) if turn else float(rng.uniform(-40.0, 40.0))
    x_start = x_turn - c - R_turn - s_a
    if turn:
        path = Path((x_start, -c), 0.0, [("line", s_a), ("arc", arc_len, -1.0 / R_turn), ("line", D + R_view)])
    else:
        path = Path((x_start, -c), 0.0, [("line", D + R_view + 50.0)])
    t = np.arange(n_frames) / fps
    ego_xy, ego_yaw = path.pose(speed * t)
    return _Route(turn, R_turn, speed, x_turn, path, t, ego_xy, poses_4x4(ego_xy, ego_yaw),
                  path.polyline(-2.0, D + 6.0, step_m=0.5))


def _streets(xk: list[float], yj: list[float], P: float) -> list[tuple]:
    """Every street as (p0, yaw, crossings along it, total length, (block depth left, right)): the horizontal
    ones at y = y_j heading +x, then the vertical ones at x = x_k heading -y. P: pad half-size."""
    xmin, xmax, ymin, ymax = xk[0], xk[-1], yj[0], yj[-1]

    def _depths(pos, j):  # block interiors: the depth available to buildings on the left/right of each street
        left = pos[j + 1] - pos[j] - 2 * P if j + 1 < len(pos) else 60.0
        right = pos[j] - pos[j - 1] - 2 * P if j > 0 else 60.0
        return left, right
    streets = []
    for j, y in enumerate(yj):
        streets.append((np.array([xmin - 20.0, y]), 0.0, [x - (xmin - 20.0) for x in xk], xmax - xmin + 40.0,
                        _depths(yj, j)))
    for k, x in enumerate(xk):
        # heading -y: the left side is +x
        streets.append((np.array([x, ymax + 20.0]), -np.pi / 2, [ymax + 20.0 - y for y in yj[::-1]], ymax - ymin + 40.0,
                        _depths(xk, k)))
    return streets


def _street(world: World, p0: np.ndarray, yaw: float, crossings: list[float], total: float,
            depths: tuple[float, float], xs: CrossSection, urban: bool, cfg: SceneConfig,
            rng: np.random.Generator) -> None:
    """One street near the route: asphalt, markings, sidewalks and what stands beside each piece between
    crossings, then the pads of its crossings (horizontal streets only, so each is laid once)."""
    P = xs.outer_hw
    depth_l, depth_r = depths
    at = _frame(p0, yaw)
    bounds = [0.0] + [v for cr in crossings for v in (cr - P, cr + P)] + [total]
    for a, b in zip(bounds[0::2], bounds[1::2]):
        if b - a < 2.0:
            continue
        mid = at(0.5 * (a + b), 0.0)
        if not world.near(mid, 0.5 * (b - a) + 30.0):
            continue
        poly = np.stack([at(s, 0.0) for s in np.arange(a, b, 30.0).tolist() + [b]])
        if len(poly) > 2 and np.linalg.norm(poly[-1] - poly[-2]) < 1.0:
            poly = np.delete(poly, -2, axis=0)
        world.add(ground_strip(poly, xs.asphalt_hw, 0.0, LAYER["asphalt"], uv_scale=uv_scale_for("asphalt")),
                  check=False)
        for m in lane_markings(poly, xs, phase_m=float(rng.uniform(0, 9)), centre="double"):
            world.add(m, check=False)
        for side in (1.0, -1.0):
            for m in _sidewalk(poly, xs, side):
                world.add(m, check=False)
            room = 0.5 * (depth_l if side > 0 else depth_r) - 0.5
            _furnish_side(world, at, yaw, a, b, side, xs, urban, cfg, rng, room)
    for cr in crossings:
        ctr = at(cr, 0.0)
        if world.near(ctr, P + 10.0) and yaw == 0.0:
            _pad(world, ctr, P, xs, urban)


def _traffic(xs: CrossSection, route: _Route, xmin: float, xmax: float, R_view: float, cfg: SceneConfig,
             rng: np.random.Generator) -> list:
    """The movers: both directions of the ego's street along a reference line, and the ego's own lane."""
    ref = Path((xmin - 20.0, 0.0), 0.0, [("line", xmax - xmin + 40.0)])
    s_ego0 = float(route.ego_xy[0, 0] - (xmin - 20.0))
    ref_range = (s_ego0 - 0.8 * R_view, s_ego0 + 0.8 * R_view)
    lanes = []
    for i in range(xs.lanes_per_dir):
        if i != xs.lanes_per_dir - 1:
            lanes.append(LaneTraffic(ref, xs.lane_offset(i), +1, route.speed * rng.uniform(0.8, 1.2), ref_range))
        lanes.append(LaneTraffic(ref, -xs.lane_offset(i), -1, rng.uniform(6.0, 12.0), ref_range))
    # ego lane: along the ego's own path at the ego's speed, so gaps stay constant (also in the turn)
    lanes.append(LaneTraffic(route.path, 0.0, +1, route.speed, (-0.6 * R_view, 0.6 * R_view)))
    return populate_lanes(lanes, route.t, route.T_world_ego, cfg.traffic_density,
                          int(round(10 * cfg.traffic_density)), rng)


def _pad(world: World, ctr: np.ndarray, P: float, xs: CrossSection, urban: bool) -> None:
    """Asphalt square at a crossing, with zebra crossings on its four approaches."""
    x, y = ctr
    su, sv = uv_scale_for("asphalt")
    c = np.array([[x - P, y - P, 0], [x + P, y - P, 0], [x + P, y + P, 0], [x - P, y + P, 0]], dtype=np.float64)
    world.add(quad(c, LAYER["asphalt"], np.stack([c[:, 0] * su, c[:, 1] * sv], 1)), check=False)
    if not urban:
        return
    hw = xs.lanes_hw
    zs = []
    for k in np.arange(-hw + 0.3, hw - 0.3, 1.0):
        for sgn in (1.0, -1.0):
            # stripes across the horizontal street (at x = ctr +- (P - 2)) and the vertical one
            ax = x + sgn * (P - 2.2)
            zs.append([[ax - 1.5, y + k, MARK_Z_M], [ax + 1.5, y + k, MARK_Z_M], [ax + 1.5, y + k + 0.5, MARK_Z_M],
                       [ax - 1.5, y + k + 0.5, MARK_Z_M]])
            ay = y + sgn * (P - 2.2)
            zs.append([[x + k, ay - 1.5, MARK_Z_M], [x + k + 0.5, ay - 1.5, MARK_Z_M], [x + k + 0.5, ay + 1.5, MARK_Z_M],
                       [x + k, ay + 1.5, MARK_Z_M]])
    if zs:
        c = np.array(zs, dtype=np.float64)
        world.add(from_quads(c, c[..., :2] * np.array(uv_scale_for("lane_marking")), np.array([0.0, 0.0, 1.0]),
                             LAYER["lane_marking"]), check=False)


def _furnish_side(world: World, at, yaw: float, a: float, b: float, side: float, xs: CrossSection,
                  urban: bool, cfg: SceneConfig, rng: np.random.Generator, room: float) -> None:
    """Street furniture, parked cars, trees and buildings/houses on one side of one street piece.

    room: metres from the sidewalk's back edge into the block that buildings may use.
    """
    kerb = xs.asphalt_hw
    back = xs.outer_hw
    face_yaw = yaw if side > 0 else yaw + np.pi        # local +y of buildings points away from the street
    # lamp posts: arm towards the road
    s = a + rng.uniform(3, 15)
    while s < b - 2:
        p = at(s, side * (kerb + 0.6))
        if world.near(p, 5):
            world.add(lamp_post(rng.uniform(7, 9), 1.5).transformed(pose_2d(p[0], p[1], yaw - side * np.pi / 2, KERB_H_M)))
        s += rng.uniform(22, 35)
    # signs facing the traffic that drives on this side
    s = a + rng.uniform(5, 40)
    while s < b - 3:
        p = at(s, side * (kerb + 0.4))
        if world.near(p, 5) and rng.random() < 0.6:
            tint = [(0.9, 0.15, 0.1), (0.15, 0.3, 0.85), (0.95, 0.85, 0.2), (0.2, 0.6, 0.25)][rng.integers(4)]
            world.add(sign_post(2.1, 0.7, 0.7, tint).transformed(
                pose_2d(p[0], p[1], yaw + (np.pi if side < 0 else 0.0), KERB_H_M)))
        s += rng.uniform(30, 70)
    # street trees
    if cfg.vegetation_density > 0:
        spacing = (12.0 if urban else 9.0) / cfg.vegetation_density
        s = a + rng.uniform(2, spacing)
        while s < b - 2:
            p = at(s, side * (kerb + min(1.4, xs.sidewalk_w / 2)))
            if world.near(p, 10) and rng.random() < (0.5 if urban else 0.8):
                world.add(tree(rng.uniform(5, 9), rng.uniform(1.5, 2.8), bool(rng.random() < 0.2),
                               tuple(rng.uniform(0.8, 1.15, 3))).transformed(pose_2d(p[0], p[1], rng.uniform(0, 6.3), KERB_H_M)))
            s += spacing * rng.uniform(0.7, 1.3)
    # parked cars (facing the direction of traffic on this side)
    if xs.parking_w > 0 and cfg.parked_density > 0:
        s = a + rng.uniform(1, 6)
        lat = side * (kerb - xs.parking_w / 2)
        while s < b - CAR_LENGTH_M - 1:
            if rng.random() < min(0.95, 0.6 * cfg.parked_density):
                heading = yaw if side < 0 else yaw + np.pi
                # origin (rear axle) 1.0 m from the car's rear end
                if side < 0:
                    p = at(s + 1.0, lat)
                else:
                    p = at(s + CAR_LENGTH_M - 1.0, lat)
                if world.near(p, 5):
                    world.add(car(random_paint(rng)).transformed(pose_2d(p[0], p[1], heading)))
            s += CAR_LENGTH_M + rng.uniform(0.8, 4.0)
    # buildings / houses
    if urban:
        _urban_buildings(world, at, a, b, side, back, face_yaw, rng, room)
    else:
        _houses(world, at, a, b, side, back, face_yaw, cfg, rng, room)


def _urban_buildings(world, at, a, b, side, back, face_yaw, rng, room) -> None:
    s = a + rng.uniform(0.0, 2.0)
    while s < b - 6:
        facade = FACADES[rng.integers(len(FACADES))]
        tw, th = (3.2, 3.2) if facade == "brick" else (1.0 / uv_scale_for(facade)[0], 1.0 / uv_scale_for(facade)[1])
        k = int(rng.integers(2, 8))
        width = min(k * tw, b - s)
        if width < 6:
            break
        floors = int(rng.integers(3, 10)) if rng.random() > 0.15 else int(rng.integers(10, 16))
        setback = rng.uniform(0, 2.5) if rng.random() < 0.4 else 0.0
        depth = min(rng.uniform(12, 22), room - setback)
        if depth < 4:
            break
        shop = 4.0 if (rng.random() < 0.5 and facade != "facade_glass") else 0.0
        height = shop + floors * th
        p = at(s + width / 2, side * (back + setback))
        if world.near(p, width / 2 + 20):
            tint = tuple(rng.uniform(0.85, 1.1, 3))
            world.add(building(width, depth, height, facade, tint, shop).transformed(pose_2d(p[0], p[1], face_yaw)))
        s += width + (rng.uniform(2, 6) if rng.random() < 0.25 else 0.0)


def _houses(world, at, a, b, side, back, face_yaw, cfg, rng, room) -> None:
    s = a + rng.uniform(0.0, 3.0)
    while s < b - 10:
        lot = min(rng.uniform(15, 24), b - s)
        if lot < 10:
            break
        mid = s + lot / 2
        if world.near(at(mid, side * back), lot / 2 + 25):
            yard = rng.uniform(4, 10)
            w = min(rng.uniform(8, 13), lot - 2.5)
            d = min(rng.uniform(8, 11), room - yard - 0.5)
            if d < 5:
                yard = max(2.0, room - 8.0)
                d = room - yard - 0.5
            if d < 4:
                break
            p = at(mid + rng.uniform(-0.5, 0.5) * (lot - w - 2), side * (back + yard))
            wall = WALL_TINTS[rng.integers(len(WALL_TINTS))]
            roof = ROOF_TINTS[rng.integers(len(ROOF_TINTS))]
            world.add(house(w, d, int(rng.integers(1, 3)), wall, roof, rng.uniform(0.5, 0.9)).transformed(
                pose_2d(p[0], p[1], face_yaw)))
            if rng.random() < 0.55:  # hedge along the lot front
                h = rng.uniform(0.9, 1.7)
                q = at(mid, side * (back + 0.6))
                world.add(box((lot - 3.0, 0.8, h), LAYER["hedge"], tuple(rng.uniform(0.8, 1.1, 3)),
                              pose_2d(q[0], q[1], face_yaw, h / 2), uv_scale_for("hedge"), faces="+x-x+y-y+z"))
            for _ in range(int(rng.poisson(1.2 * cfg.vegetation_density))):
                q = at(s + rng.uniform(1.5, lot - 1.5), side * (back + rng.uniform(1.5, max(2.0, yard - 2.0))))
                if rng.random() < 0.6:
                    world.add(tree(rng.uniform(4, 10), rng.uniform(1.2, 3.0), bool(rng.random() < 0.3),
                                   tuple(rng.uniform(0.8, 1.15, 3))).transformed(pose_2d(q[0], q[1], rng.uniform(0, 6.3))))
                else:
                    world.add(bush(rng.uniform(0.6, 1.3), tuple(rng.uniform(0.8, 1.15, 3))).transformed(
                        pose_2d(q[0], q[1], rng.uniform(0, 6.3))))
            # a parked car on the driveway sometimes
            if yard >= 6.0 and rng.random() < 0.3 * cfg.parked_density:
                # car points away from the street; its x spans [-1.0, 3.5] around the origin
                q = at(s + 1.5 + CAR_WIDTH_HALF, side * (back + 2.0))
                yaw_c = face_yaw + np.pi / 2
                world.add(car(random_paint(rng)).transformed(pose_2d(q[0], q[1], yaw_c)))
        s += lot


CAR_WIDTH_HALF = 0.9


def build_urban(cfg: SceneConfig, n_frames: int, fps: float, rng: np.random.Generator) -> Scene:
    """Urban sequence: dense, tall buildings, shops, parked cars, 2-4 lanes, crossings with zebras."""
    return build_grid("urban", cfg, n_frames, fps, rng)


def build_residential(cfg: SceneConfig, n_frames: int, fps: float, rng: np.random.Generator) -> Scene:
    """Residential sequence: houses with pitched roofs, yards, hedges, trees, one lane per direction."""
    return build_grid("residential", cfg, n_frames, fps, rng)
