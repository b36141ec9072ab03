"""Shared machinery of the scene families: street cross-sections, the keep-out rule,
ground cover, lane markings, traffic.

The keep-out rule (tested): no static vertex higher than `KEEPOUT_Z_M` lies within
`KEEPOUT_M` metres (horizontally) of the ego's driven path, and no mover's origin
comes within `MOVER_CLEARANCE_M` of the ego's origin at any frame. `World.add`
enforces the first by dropping whole objects that violate it.

Example::

    w = World(ego_path_xy, view_center_xy, view_radius_m=90.0)
    w.add(tree(8.0, 2.5, False).transformed(pose_2d(10.0, 8.0, 0.0)))
    static = w.static_mesh()
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from scenes.model import Mesh, Mover
from scenes.objects import car
from scenes.polyline import arc_length, check_polyline, distance_to_polyline, interpolate
from scenes.meshing import from_quads
from scenes.primitives import ground_strip, quad
from scenes.route import Path, poses_4x4
from scenes.textures import LAYER, uv_scale_for

KEEPOUT_M = 3.0
KEEPOUT_Z_M = 0.2
MOVER_CLEARANCE_M = 5.0
MAX_INSTANCES = 60000  # static objects of one scene; movers follow, all below 2^16 (16-bit instance maps)
MARK_Z_M = 0.01
KERB_H_M = 0.15

PAINTS = np.array([
    [0.85, 0.85, 0.85], [0.1, 0.1, 0.11], [0.55, 0.06, 0.05], [0.08, 0.15, 0.45], [0.5, 0.5, 0.52],
    [0.75, 0.72, 0.6], [0.1, 0.3, 0.15], [0.8, 0.55, 0.1], [0.3, 0.3, 0.33], [0.6, 0.62, 0.7],
])


def random_paint(rng: np.random.Generator) -> np.ndarray:
    """A plausible car paint tint (3,) linear RGB: a palette colour with small jitter."""
    base = PAINTS[rng.integers(len(PAINTS))]
    return np.clip(base * rng.uniform(0.85, 1.15, 3), 0.02, 1.0)


@dataclass(frozen=True)
class CrossSection:
    """Road layout across the centreline, symmetric for both directions (metres).

    From the centre outwards on each side: median_w / 2, `lanes_per_dir` lanes of `lane_w`,
    a bike lane `bike_w`, a parking lane `parking_w`, a shoulder `shoulder_w` (all asphalt);
    then a kerb of KERB_H_M and a raised sidewalk of `sidewalk_w` (0 = none).
    """

    lane_w: float
    lanes_per_dir: int
    median_w: float = 0.0
    bike_w: float = 0.0
    parking_w: float = 0.0
    shoulder_w: float = 0.0
    sidewalk_w: float = 0.0

    @property
    def lanes_hw(self) -> float:
        """Lateral distance from the centre to the outer edge of the outermost driving lane."""
        return self.median_w / 2 + self.lanes_per_dir * self.lane_w

    @property
    def asphalt_hw(self) -> float:
        return self.lanes_hw + self.bike_w + self.parking_w + self.shoulder_w

    @property
    def outer_hw(self) -> float:
        """Half-width including the sidewalks."""
        return self.asphalt_hw + self.sidewalk_w

    def lane_offset(self, i: int) -> float:
        """Lateral offset (left positive) of the centre of lane i on the right-hand side,
        i = 0 next to the median, lanes_per_dir - 1 outermost (the ego's lane)."""
        return -(self.median_w / 2 + (i + 0.5) * self.lane_w)

    @property
    def ego_offset(self) -> float:
        return self.lane_offset(self.lanes_per_dir - 1)


class World:
    """Accumulates static meshes, dropping objects that violate the keep-out rule or are far away.

    Every object added with the keep-out check is an instance of its own (ids 1, 2, ... in the order
    they are kept, `scenes.labels`); ground cover added unchecked (road, markings, lawns) is "stuff", id 0.
    """

    def __init__(self, ego_path_xy: np.ndarray, view_radius_m: float) -> None:
        self.ego_xy = np.asarray(ego_path_xy, dtype=np.float64)
        self.view_radius = float(view_radius_m)
        self.meshes: list[Mesh] = []
        self.n_dropped = 0
        self.n_instances = 0
        self.instance_class: dict[int, str] = {}

    def near(self, xy: np.ndarray, extra_m: float = 0.0) -> bool:
        """Whether the 2D point is within view radius (+ extra) of the ego path."""
        return float(distance_to_polyline(np.asarray(xy, dtype=np.float64)[None], self.ego_xy)[0]) <= self.view_radius + extra_m

    def clear_of_ego(self, mesh: Mesh) -> bool:
        """True when no vertex above KEEPOUT_Z_M is within KEEPOUT_M of the ego path."""
        p = mesh.positions[mesh.positions[:, 2] > KEEPOUT_Z_M, :2].astype(np.float64)
        if not len(p):
            return True
        c = 0.5 * (p.min(0) + p.max(0))
        r = float(np.linalg.norm(p - c, axis=1).max())
        d_c = float(distance_to_polyline(c[None], self.ego_xy)[0])
        if d_c > r + KEEPOUT_M + 0.1:
            return True
        return bool(distance_to_polyline(p, self.ego_xy).min() > KEEPOUT_M + 0.05)

    def add(self, mesh: Mesh, check: bool = True, label: str | None = None) -> bool:
        """Add a static mesh (world frame); returns False (and drops it) if it violates keep-out. A checked
        mesh is one object (its own instance id); `label` names its class where its materials do not."""
        if check and not self.clear_of_ego(mesh):
            self.n_dropped += 1
            return False
        if check:
            self.n_instances += 1
            if self.n_instances > MAX_INSTANCES:
                raise ValueError(f"a scene holds more than {MAX_INSTANCES} objects (instance maps are 16-bit)")
            mesh = mesh.tagged(self.n_instances)
            if label is not None:
                self.instance_class[self.n_instances] = label
        self.meshes.append(mesh)
        return True

    def static_mesh(self) -> Mesh:
        return Mesh.merge(self.meshes)


def ground_tiles(xmin: float, xmax: float, ymin: float, ymax: float, z: float, layer_name: str,
                 tile_m: float = 40.0, tint=(1.0, 1.0, 1.0)) -> Mesh:
    """Horizontal quads covering [xmin, xmax] x [ymin, ymax] at height z (facing +z)."""
    xs = np.linspace(xmin, xmax, max(2, int(np.ceil((xmax - xmin) / tile_m)) + 1))
    ys = np.linspace(ymin, ymax, max(2, int(np.ceil((ymax - ymin) / tile_m)) + 1))
    su, sv = uv_scale_for(layer_name)
    parts = []
    for x0, x1 in zip(xs[:-1], xs[1:]):
        for y0, y1 in zip(ys[:-1], ys[1:]):
            c = np.array([[x0, y0, z], [x1, y0, z], [x1, y1, z], [x0, y1, z]])
            uv = np.stack([c[:, 0] * su, c[:, 1] * sv], 1)
            parts.append(quad(c, LAYER[layer_name], uv, tint))
    return Mesh.merge(parts)


def dashed_line(polyline: np.ndarray, lateral_m: float, half_w: float, dash_m: float, gap_m: float,
                phase_m: float = 0.0) -> Mesh:
    """Dashed lane marking at `lateral_m` along the polyline, raised MARK_Z_M; one quad per dash
    (dashes are short: on curves of radius > 20 m a chord is exact to millimetres)."""
    p = check_polyline(polyline)
    total = float(arc_length(p)[-1])
    period = dash_m + gap_m
    s0 = np.arange(-phase_m % period, total - 0.2, period)
    s1 = np.minimum(s0 + dash_m, total)
    keep = s1 - s0 > 0.2
    s0, s1 = s0[keep], s1[keep]
    if not len(s0):
        return Mesh.empty()
    pa, pb = interpolate(p, s0), interpolate(p, s1)
    t = pb - pa
    t /= np.linalg.norm(t, axis=1, keepdims=True)
    nl = np.stack([-t[:, 1], t[:, 0]], 1)
    ca, cb = pa + lateral_m * nl, pb + lateral_m * nl
    c = np.zeros((len(s0), 4, 3))
    c[:, 0, :2], c[:, 1, :2] = ca - half_w * nl, cb - half_w * nl
    c[:, 2, :2], c[:, 3, :2] = cb + half_w * nl, ca + half_w * nl
    c[..., 2] = MARK_Z_M
    su, sv = uv_scale_for("lane_marking")
    uv = np.zeros((len(s0), 4, 2))
    uv[:, 0, 0] = uv[:, 3, 0] = s0 * su
    uv[:, 1, 0] = uv[:, 2, 0] = s1 * su
    uv[:, 2:, 1] = 2 * half_w * sv
    return from_quads(c, uv, np.array([0.0, 0.0, 1.0]), LAYER["lane_marking"])


def solid_line(polyline: np.ndarray, lateral_m: float, half_w: float) -> Mesh:
    return ground_strip(polyline, half_w, MARK_Z_M, LAYER["lane_marking"], uv_scale=uv_scale_for("lane_marking"),
                        lateral_offset=lateral_m)


def lane_markings(polyline: np.ndarray, xs: CrossSection, phase_m: float, centre: str) -> list[Mesh]:
    """Markings of a two-way road: centre line(s), dashed lane separators, solid edge lines.

    centre: "double" (two solid lines 0.25 m apart or at the median edges), "dashed" or "none".
    """
    out: list[Mesh] = []
    hw = 0.06
    if centre == "double":
        d = max(xs.median_w / 2, 0.12)
        out += [solid_line(polyline, d, hw), solid_line(polyline, -d, hw)]
    elif centre == "dashed":
        out.append(dashed_line(polyline, 0.0, hw, 3.0, 6.0, phase_m))
    for side in (1.0, -1.0):
        for i in range(1, xs.lanes_per_dir):
            d = xs.median_w / 2 + i * xs.lane_w
            out.append(dashed_line(polyline, side * d, hw, 3.0, 6.0, phase_m))
        if xs.bike_w > 0 or xs.shoulder_w > 0 or xs.parking_w > 0:
            out.append(solid_line(polyline, side * xs.lanes_hw, hw * 1.3))
        if xs.bike_w > 0 and xs.parking_w > 0:
            out.append(solid_line(polyline, side * (xs.lanes_hw + xs.bike_w), hw))
    return out


# ------------------------------------------------------------------------------------- traffic
@dataclass
class LaneTraffic:
    """Vehicles on one lane of a reference path: lateral offset, direction, s-speed."""

    path: Path
    lateral_m: float
    direction: int          # +1 along the path, -1 against
    speed_mps: float
    s_range: tuple[float, float]  # arc lengths on `path` where vehicles may start


def mover_poses(lane: LaneTraffic, s0: float, t: np.ndarray) -> np.ndarray:
    """(F, 4, 4) world poses of a vehicle starting at path arc length s0 at times t (F,) seconds."""
    s = s0 + lane.direction * lane.speed_mps * t
    xy, yaw = lane.path.pose(s)
    xy = xy + lane.lateral_m * np.stack([-np.sin(yaw), np.cos(yaw)], 1)
    if lane.direction < 0:
        yaw = yaw + np.pi
    return poses_4x4(xy, yaw)


def populate_lanes(lanes: list[LaneTraffic], t: np.ndarray,
                   T_world_ego: np.ndarray, density: float, max_movers: int,
                   rng: np.random.Generator, min_gap_m: float = 12.0) -> list[Mover]:
    """Place vehicles along each lane with random gaps (>= min_gap_m, same speed per lane,
    so gaps stay constant), dropping any that would come within MOVER_CLEARANCE_M (+ margin)
    of the ego at any frame. Vehicles of different lanes never meet (lanes >= lane width apart).
    """
    if density <= 0 or max_movers <= 0:
        return []
    movers: list[Mover] = []
    ego_xy = T_world_ego[:, :2, 3]
    mean_gap = 35.0 / density
    cands = []
    for li, lane in enumerate(lanes):
        s = lane.s_range[0] + rng.uniform(0, mean_gap)
        while s < lane.s_range[1]:
            cands.append((li, s))
            s += max(min_gap_m, rng.exponential(mean_gap) + min_gap_m)
    order = rng.permutation(len(cands))
    for k in order:
        if len(movers) >= max_movers:
            break
        li, s0 = cands[k]
        T = mover_poses(lanes[li], s0, t)
        if np.min(np.linalg.norm(T[:, :2, 3] - ego_xy, axis=1)) < MOVER_CLEARANCE_M + 1.0:
            continue
        movers.append(Mover(f"car_{len(movers):02d}", car(random_paint(rng)), T))
    return movers
