"""Highway family: a divided motorway (2-3 lanes per direction, 4-6 in all) with a concrete
median barrier, shoulders, guardrails or barriers, embankments with tree rows, lamp posts,
signs, occasional noise walls and warehouses; in a fraction of sequences a gentle curve.

The ego drives in the rightmost lane at 18-28 m/s. The road centreline is the ego path
shifted left by the ego lane's offset, so every lane follows the curve exactly.

Example::

    scene = build_highway(SceneConfig(family="highway"), 20, 10.0, np.random.default_rng(0))
"""
from __future__ import annotations

import numpy as np

from scenes.config import SceneConfig
from scenes.model import Scene
from scenes.objects import building, lamp_post, sign_post, tree
from scenes.polyline import offset_polyline, vertex_tangents
from scenes.primitives import box, ground_strip, pose_2d, sweep
from scenes.route import Path, poses_4x4
from scenes.textures import LAYER, make_textures, uv_scale_for
from scenes.world import CrossSection, LaneTraffic, World, ground_tiles, lane_markings, populate_lanes


def build_highway(cfg: SceneConfig, n_frames: int, fps: float, rng: np.random.Generator) -> Scene:
    """Build one highway sequence (see module docstring)."""
    R_view = cfg.view_radius_m
    n = int(rng.integers(2, 4))
    lane_w = rng.uniform(3.5, 3.75)
    xs = CrossSection(lane_w, n, median_w=rng.uniform(3.0, 6.0), shoulder_w=rng.uniform(2.5, 3.5))
    c = -xs.ego_offset
    speed = float(rng.uniform(18.0, 28.0) * cfg.speed_scale)
    D = speed * (n_frames - 1) / fps
    turn = bool(rng.random() < cfg.turn_probability)
    pre = R_view + 30.0
    post = D + R_view + 30.0
    if turn:
        radius = rng.uniform(250.0, 700.0)
        angle = np.deg2rad(rng.uniform(10.0, 35.0))
        arc = radius * angle
        k = (1.0 if rng.random() < 0.5 else -1.0) / radius
        s_arc = float(rng.uniform(-arc / 2, max(D, 1.0)))  # the ego meets the curve during the sequence
        pieces = [("line", pre + max(s_arc, 1.0))]
        pieces.append(("arc", arc, k))
        pieces.append(("line", post))
    else:
        pieces = [("line", pre + post)]
    path = Path((0.0, 0.0), float(rng.uniform(-np.pi, np.pi)), pieces)
    s_ego0 = pre  # the ego starts with `pre` metres of road behind it
    t = np.arange(n_frames) / fps
    ego_xy, ego_yaw = path.pose(s_ego0 + speed * t)
    T_world_ego = poses_4x4(ego_xy, ego_yaw)
    world = World(path.polyline(s_ego0 - 2.0, s_ego0 + D + 6.0, step_m=0.5), R_view)

    road = path.polyline(s_ego0 - R_view - 20, s_ego0 + D + R_view + 20, step_m=4.0, offset_m=c)
    _carriageway(world, road, xs, R_view, rng)
    tang = vertex_tangents(road)
    yaw = np.arctan2(tang[:, 1], tang[:, 0])
    _roadside(world, road, yaw, xs, cfg, rng)

    # traffic: every lane of both directions follows the road (lanes are offsets of the ego path)
    lanes = []
    rng_s = (s_ego0 - 0.8 * R_view, s_ego0 + 0.8 * R_view)
    for i in range(n):
        dl = xs.lane_offset(i) + c  # lateral offset relative to the ego lane
        if i == n - 1:
            lanes.append(LaneTraffic(path, 0.0, +1, speed, rng_s))  # ego lane: constant gaps
        else:
            lanes.append(LaneTraffic(path, dl, +1, speed * rng.uniform(0.85, 1.25), rng_s))
        lanes.append(LaneTraffic(path, -xs.lane_offset(i) + c, -1, rng.uniform(20.0, 32.0), rng_s))
    movers = populate_lanes(lanes, t, T_world_ego, cfg.traffic_density, int(round(14 * cfg.traffic_density)), rng,
                            min_gap_m=20.0)

    static = world.static_mesh()
    textures, materials = make_textures(rng, cfg.texture_size)
    info = {"family": "highway", "speed_mps": speed, "n_movers": len(movers), "n_triangles": int(static.n_triangles),
            "turn": turn, "lanes_per_dir": int(n), "lane_w_m": float(lane_w), "n_dropped_objects": int(world.n_dropped)}
    return Scene(static, movers, textures, materials, T_world_ego, "highway", info,
                 instance_class=world.instance_class)


def _carriageway(world: World, road: np.ndarray, xs: CrossSection, R_view: float, rng: np.random.Generator) -> None:
    """Ground (to `R_view` beyond the road), asphalt, lane markings, gravel verges, the median barrier, guardrails
    or barriers, noise walls."""
    lo, hi = road.min(0) - R_view, road.max(0) + R_view
    world.add(ground_tiles(lo[0], hi[0], lo[1], hi[1], -0.03, "grass"), check=False)
    world.add(ground_strip(road, xs.asphalt_hw, 0.0, LAYER["asphalt"], uv_scale=uv_scale_for("asphalt")), check=False)
    for m in lane_markings(road, xs, float(rng.uniform(0, 9)), centre="double"):
        world.add(m, check=False)
    gw = rng.uniform(1.0, 2.5)
    for side in (1.0, -1.0):
        world.add(ground_strip(road, gw / 2, -0.01, LAYER["gravel"], uv_scale=uv_scale_for("gravel"),
                               lateral_offset=side * (xs.asphalt_hw + gw / 2)), check=False)
    # median barrier (New Jersey profile), listed counter-clockwise in the (d, z) drawing
    jersey = np.array([[0.3, 0.0], [0.25, 0.25], [0.1, 0.8], [-0.1, 0.8], [-0.25, 0.25], [-0.3, 0.0]])
    world.add(sweep(road, jersey, LAYER["barrier_concrete"], uv_scale=uv_scale_for("barrier_concrete")))
    # outer edges: guardrail on posts or concrete barrier
    for side in (1.0, -1.0):
        d = side * (xs.asphalt_hw + 0.6)
        if rng.random() < 0.6:
            rail = np.array([[d - 0.05 * side, 0.55], [d - 0.05 * side, 0.85]])
            if side > 0:  # the road-facing surface must face the road (profile edges: CCW rule)
                rail = rail[::-1]
            world.add(sweep(road, rail, LAYER["guardrail"], uv_scale=uv_scale_for("guardrail")))
            world.add(sweep(road, rail[::-1] + [0.04 * side, 0], LAYER["guardrail"], uv_scale=uv_scale_for("guardrail")))
            _posts(world, road, d + 0.1 * side, 0.15, 0.9, 4.0)
        else:
            prof = jersey + [d, 0.0]
            world.add(sweep(road, prof, LAYER["barrier_concrete"], uv_scale=uv_scale_for("barrier_concrete")))
    # noise walls
    if rng.random() < 0.35:
        side = 1.0 if rng.random() < 0.5 else -1.0
        d = side * (xs.asphalt_hw + rng.uniform(5.0, 10.0))
        h = rng.uniform(3.0, 4.5)
        wall = np.array([[d, 0.0], [d, h], [d + 0.3 * side, h], [d + 0.3 * side, 0.0]])
        if side > 0:
            wall = wall[::-1]
        world.add(sweep(road, wall, LAYER["barrier_concrete"], uv_scale=uv_scale_for("barrier_concrete")))


def _roadside(world: World, road: np.ndarray, yaw: np.ndarray, xs: CrossSection, cfg: SceneConfig,
              rng: np.random.Generator) -> None:
    """Lamp posts on the median, signs on the shoulders, trees on the embankments, warehouses set back."""
    # lamp posts on the median (one arm each way), signs on the right shoulder of each direction
    step = rng.uniform(40.0, 60.0)
    idx_step = max(1, int(round(step / 4.0)))
    for i in range(int(rng.integers(0, idx_step)), len(road), idx_step):
        p = road[i]
        if world.near(p, 5):
            h = rng.uniform(9.0, 11.0)
            world.add(lamp_post(h, 2.0).transformed(pose_2d(p[0], p[1], yaw[i] + np.pi / 2)))
            world.add(lamp_post(h, 2.0).transformed(pose_2d(p[0], p[1], yaw[i] - np.pi / 2)))
    sign_step = max(1, int(round(rng.uniform(80.0, 160.0) / 4.0)))
    for side in (1.0, -1.0):
        for i in range(int(rng.integers(0, sign_step)), len(road), sign_step):
            p = road[i] + side * (xs.asphalt_hw + 1.2) * np.array([-np.sin(yaw[i]), np.cos(yaw[i])])
            if world.near(p, 5):
                tint = [(0.15, 0.3, 0.85), (0.1, 0.5, 0.2), (0.95, 0.95, 0.95)][rng.integers(3)]
                face = yaw[i] + (np.pi if side < 0 else 0.0)
                world.add(sign_post(2.2, rng.uniform(1.5, 3.0), rng.uniform(1.0, 1.8), tint).transformed(
                    pose_2d(p[0], p[1], face)))
    # tree rows and clusters on the embankments
    if cfg.vegetation_density > 0:
        for side in (1.0, -1.0):
            row = offset_polyline(road, side * (xs.asphalt_hw + rng.uniform(8.0, 20.0)))
            spacing = 8.0 / cfg.vegetation_density
            acc = 0.0
            for i in range(1, len(row)):
                acc += float(np.linalg.norm(row[i] - row[i - 1]))
                if acc < spacing * rng.uniform(0.6, 1.4):
                    continue
                acc = 0.0
                if rng.random() < 0.75:
                    q = row[i] + rng.normal(0, 3.0, 2) + side * rng.exponential(6.0) * np.array([-np.sin(yaw[i]), np.cos(yaw[i])])
                    if world.near(q, 10):
                        world.add(tree(rng.uniform(6, 14), rng.uniform(1.8, 3.5), bool(rng.random() < 0.4),
                                       tuple(rng.uniform(0.8, 1.15, 3))).transformed(pose_2d(q[0], q[1], rng.uniform(0, 6.3))))
    # a few warehouses / offices set back from the road
    for _ in range(int(rng.integers(0, 5))):
        i = int(rng.integers(0, len(road)))
        side = 1.0 if rng.random() < 0.5 else -1.0
        q = road[i] + side * (xs.asphalt_hw + rng.uniform(35.0, 70.0)) * np.array([-np.sin(yaw[i]), np.cos(yaw[i])])
        if world.near(q, 30):
            facade = ["facade_glass", "barrier_concrete", "brick", "facade_windows_b"][rng.integers(4)]
            world.add(building(rng.uniform(20, 50), rng.uniform(15, 30), rng.uniform(6, 16), facade,
                               tuple(rng.uniform(0.85, 1.1, 3))).transformed(
                pose_2d(q[0], q[1], yaw[i] + (0.0 if side > 0 else np.pi))), label="building")


def _posts(world: World, road: np.ndarray, d: float, w: float, h: float, spacing: float) -> None:
    """Guardrail posts every `spacing` metres at lateral offset d."""
    line = offset_polyline(road, d)
    tang = vertex_tangents(line)
    acc = spacing
    parts = []
    for i in range(len(line)):
        if i:
            acc += float(np.linalg.norm(line[i] - line[i - 1]))
        if acc >= spacing and world.near(line[i], 5):
            acc = 0.0
            parts.append(box((w, w, h), LAYER["metal_pole"], (0.8, 0.8, 0.8),
                             pose_2d(line[i, 0], line[i, 1], float(np.arctan2(tang[i, 1], tang[i, 0])), h / 2),
                             uv_scale_for("metal_pole"), faces="+x-x+y-y+z"))
    for p in parts:
        world.add(p)
