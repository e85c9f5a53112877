"""Scenario presets (``urban``, ``highway``, ``rain``, ``straight``) and the procedural world builder."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from hybrid_calib.config import require, require_ranges
from hybrid_calib.sim.trajectory import EGO_FRONT_M, EGO_START_S, ego_catch_up_m
from hybrid_calib.sim.world import (
    RoadLayout,
    RoadPath,
    World,
    WorldObject,
    building_parts,
    bush_parts,
    guardrail_parts,
    kerb_parts,
    pedestrian_parts,
    pole_parts,
    sign_parts,
    tree_parts,
    vehicle_parts,
)


@dataclass(frozen=True)
class ScenarioConfig:
    """What a drive looks like. Densities are per 100 m of road (per side where it says so)."""

    name: str = "urban"  # preset name
    layout: RoadLayout = RoadLayout(lanes_per_direction=1, parking_width=2.5, sidewalk_width=3.0)  # cross-section
    ego_speed: float = 9.0  # mean ego speed, m/s
    ego_speed_variation: float = 0.1  # relative amplitude of the slow speed oscillation
    straight_length: tuple[float, float] = (60.0, 160.0)  # straight segment lengths, metres (min, max)
    turn_radius: tuple[float, float] = (45.0, 90.0)  # turn radii, metres (min, max)
    turn_angle_deg: tuple[float, float] = (30.0, 90.0)  # turn angles, degrees (min, max); 0 = no turns
    parked_per_100m: float = 3.0  # parked vehicles per 100 m per side (needs parking_width > 0)
    lead_vehicles: int = 1  # vehicles ahead of the ego in its own lane
    same_direction_per_km: float = 0.0  # moving vehicles per km in the other same-direction lanes
    oncoming_per_km: float = 15.0  # moving vehicles per km per oncoming lane
    pedestrians_per_100m: float = 2.0  # pedestrians per 100 m per side (on sidewalks)
    pole_spacing: float = 30.0  # street lights / poles every ~this many metres per side (0 = none)
    signs_per_100m: float = 1.0  # traffic signs per 100 m per side
    trees_per_100m: float = 3.0  # trees per 100 m per side
    bushes_per_100m: float = 2.0  # bushes per 100 m per side
    buildings: bool = True  # building facades beyond the sidewalk
    guardrails: bool = False  # guard rails at the road edges and in the median
    kerbs: bool = True  # raised kerb stones at the road edges
    rain: bool = False  # wet look: lower image contrast, haze, more radar clutter, fewer detections
    image_contrast: float = 1.0  # image contrast multiplier (1 = clear weather)
    fog_distance: float = 400.0  # distance (m) at which haze reaches 63 %
    radar_extra_loss_db: float = 0.0  # extra two-way radar loss (rain), dB
    radar_clutter_per_sweep: float = 4.0  # mean number of clutter detections per radar sweep
    radar_ghost_probability: float = 0.05  # probability that a strong return spawns a multipath ghost

    def __post_init__(self):
        require_ranges(self, {"ego_speed": "[0, 100]", "ego_speed_variation": "[0, 1)", "straight_length": "[1, 1e5]",
                              "turn_radius": "[1, 1e5]", "turn_angle_deg": "[0, 180]", "parked_per_100m": "[0, 100]",
                              "lead_vehicles": "[0, 100]", "same_direction_per_km": "[0, 1000]",
                              "oncoming_per_km": "[0, 1000]", "pedestrians_per_100m": "[0, 100]",
                              "pole_spacing": "[0, 1e4]", "signs_per_100m": "[0, 100]", "trees_per_100m": "[0, 100]",
                              "bushes_per_100m": "[0, 100]", "image_contrast": "(0, 10]", "fog_distance": "[1, 1e4]",
                              "radar_extra_loss_db": "[0, 100]", "radar_clutter_per_sweep": "[0, 1e4]",
                              "radar_ghost_probability": "[0, 1]"})
        require(self, {"pole_spacing = 0 (none) or >= 1": self.pole_spacing == 0 or self.pole_spacing >= 1,
                       # (min, max) ranges drawn from: [10, 5] was an internal error in numpy (probe 49)
                       **{f"{k} as (min, max) with min <= max": len(getattr(self, k)) == 2 and
                          getattr(self, k)[0] <= getattr(self, k)[1]
                          for k in ("straight_length", "turn_radius", "turn_angle_deg")}})


LEAD_SPEED_FACTOR = 1.02  # the lead vehicles in the ego's lane drive 2 % faster than the ego's mean speed
MIN_GAP_M = 2.0  # the least gap between the ego's front and a lead vehicle's rear (and between lead vehicles)


PRESETS: dict[str, ScenarioConfig] = {
    "urban": ScenarioConfig(),
    "highway": ScenarioConfig(
        name="highway",
        layout=RoadLayout(lanes_per_direction=2, sidewalk_width=0.0, parking_width=0.0, dashed_centre=False),
        ego_speed=25.0, straight_length=(300.0, 800.0), turn_radius=(500.0, 1200.0), turn_angle_deg=(8.0, 25.0),
        parked_per_100m=0.0, lead_vehicles=2, same_direction_per_km=12.0, oncoming_per_km=10.0,
        pedestrians_per_100m=0.0, pole_spacing=50.0, signs_per_100m=0.4, trees_per_100m=1.0, bushes_per_100m=3.0,
        buildings=False, guardrails=True, kerbs=False, radar_clutter_per_sweep=3.0,
    ),
    "rain": ScenarioConfig(
        name="rain", rain=True, image_contrast=0.55, fog_distance=120.0, radar_extra_loss_db=7.0,
        radar_clutter_per_sweep=18.0, radar_ghost_probability=0.08,
    ),
    "straight": ScenarioConfig(
        name="straight", layout=RoadLayout(lanes_per_direction=1, parking_width=0.0, sidewalk_width=2.0),
        ego_speed=15.0, turn_angle_deg=(0.0, 0.0), parked_per_100m=0.0, lead_vehicles=0, oncoming_per_km=0.0,
        pedestrians_per_100m=0.0, pole_spacing=40.0, signs_per_100m=0.0, trees_per_100m=0.0, bushes_per_100m=0.0,
        buildings=False, radar_clutter_per_sweep=3.0,
    ),
}


def scenario(name: str) -> ScenarioConfig:
    """A preset by name; ``ValueError`` naming the valid ones otherwise."""
    if name not in PRESETS:
        raise ValueError(f"unknown scenario {name!r}; valid scenarios: {sorted(PRESETS)}")
    return PRESETS[name]


def road_segments(conf: ScenarioConfig, length: float, g: np.random.Generator) -> list[tuple[float, float]]:
    """Alternating straights and turns (left or right) totalling at least ``length`` metres."""
    segs: list[tuple[float, float]] = []
    total = 0.0
    heading = 0.0
    while total < length:
        seg_len = g.uniform(*conf.straight_length)
        segs.append((seg_len, 0.0))
        total += seg_len
        if conf.turn_angle_deg[1] <= 0 or total >= length:
            continue
        r = g.uniform(*conf.turn_radius)
        ang = np.deg2rad(g.uniform(*conf.turn_angle_deg))
        sign = -np.sign(heading) if abs(heading) > np.deg2rad(60) else g.choice([-1.0, 1.0])
        heading += sign * ang
        segs.append((r * ang, sign / r))
        total += r * ang
    if conf.turn_angle_deg[1] <= 0:
        segs = [(total, 0.0)]
    return segs


class _Placer:
    """Places static objects in road coordinates, rejecting overlaps and spots too near the road.

    Placed footprints (circles) live in a 40 m grid, so a check looks at nine cells only."""

    CELL = 40.0  # metres; larger than any two footprint radii together

    def __init__(self, world_path: RoadPath, layout: RoadLayout):
        self.path, self.layout = world_path, layout
        self.cells: dict[tuple[int, int], list[tuple[float, float, float]]] = {}

    def ok(self, s: float, lateral: float, radius: float, min_abs_lateral: float) -> bool:
        if not (5.0 < s < self.path.length - 5.0):
            return False
        xy, _ = self.path.to_global(s, lateral)
        _, l_true = self.path.to_road(xy[None])
        if abs(l_true[0]) < min_abs_lateral or np.sign(l_true[0]) != np.sign(lateral):
            return False  # the inside of a curve brings it onto the road
        cx, cy = int(np.floor(xy[0] / self.CELL)), int(np.floor(xy[1] / self.CELL))
        for i in (cx - 1, cx, cx + 1):
            for j in (cy - 1, cy, cy + 1):
                for x, y, r in self.cells.get((i, j), ()):
                    if np.hypot(xy[0] - x, xy[1] - y) < r + radius:
                        return False
        self.cells.setdefault((cx, cy), []).append((float(xy[0]), float(xy[1]), float(radius)))
        return True


def _along(g: np.random.Generator, per_100m: float, limit: float):
    """A Poisson process along the road: positions s in [0, limit) with ``per_100m`` per 100 m.

    Drawn sequentially, so a longer road gets the same objects on its common prefix."""
    if per_100m <= 0:
        return
    s = g.exponential(100.0 / per_100m)
    while s < limit:
        yield s
        s += g.exponential(100.0 / per_100m)


def build_world(conf: ScenarioConfig, seed: int, length: float) -> World:
    """A procedural world with a road of at least ``length`` metres, deterministic for ``seed``.

    Every kind of object on every side draws from its own random stream along the road, so worlds
    built for different lengths agree on their common part (a longer drive starts the same way)."""
    path = RoadPath(road_segments(conf, length, np.random.default_rng([seed, 0])))
    L = conf.layout
    objects: list[WorldObject] = []
    placer = _Placer(path, L)

    def stream(*key: int) -> np.random.Generator:
        return np.random.default_rng([seed, 1, *key])

    def add(cls, parts, s, lateral, speed=0.0, yaw_offset=0.0, size=(0.0, 0.0, 0.0)):
        objects.append(WorldObject(len(objects), cls, parts, float(s), float(lateral), float(speed),
                                   float(yaw_offset), tuple(float(x) for x in size)))

    sides = (-1.0, 1.0)
    # kerbs and guard rails: short boxes following the centre line (shorter on curves)
    for enabled, cls, long_seg, short_seg, bend in ((conf.kerbs, "kerb", 8.0, 3.0, 150.0),
                                                     (conf.guardrails, "guardrail", 12.0, 4.0, 300.0)):
        s = 0.0
        while enabled and s < path.length:
            k = abs(np.interp(s, path.s, path.curvature))
            seg = min(long_seg if k < 1 / bend else short_seg, path.length - s)
            if seg > 0.5 and cls == "kerb":
                for side in sides:
                    add("kerb", kerb_parts(seg, L.kerb_width, L.kerb_height), s + seg / 2,
                        side * (L.half_width + L.kerb_width / 2))
            elif seg > 1.0:
                for lat in (-(L.half_width + 1.2), 0.0):
                    add("guardrail", guardrail_parts(seg), s + seg / 2, lat, yaw_offset=np.pi if lat == 0 else 0.0)
            s += seg
    # parked vehicles in the parking strip
    if L.parking_width > 0:
        for i, side in enumerate(sides):
            g = stream(1, i)
            for s in _along(g, conf.parked_per_100m, path.length):
                cls, dims, col = _random_vehicle(g, parked=True)
                lat = side * (L.lanes_width + L.parking_width / 2)
                yaw = g.normal(0, 0.03)
                if placer.ok(s, lat, dims[0] / 2 + 0.5, L.lanes_width):
                    add(cls, vehicle_parts(cls, *dims, col), s, lat, yaw_offset=yaw, size=dims)
    side_objects(conf, stream, path, placer, add)
    # moving traffic; all vehicles of a lane share its speed, so they never run into each other
    ego_lane = L.lanes_per_direction - 1
    g = stream(20)
    lead_speed = conf.ego_speed * LEAD_SPEED_FACTOR
    # each lead vehicle's rear at least MIN_GAP_M ahead of the ego's front (and of the vehicle before it) at the
    # ego's closest approach: drawn nearer, it is moved on (probe 35: 2 of 14 highway drives drove into the truck)
    clear = EGO_START_S + EGO_FRONT_M + ego_catch_up_m(conf.ego_speed, conf.ego_speed_variation, lead_speed)
    for k in range(conf.lead_vehicles):
        cls, dims, col = _random_vehicle(g)
        s_lead = max(EGO_START_S + 25.0 + 30.0 * k + g.uniform(0, 15), clear + MIN_GAP_M + dims[0] / 2)
        add(cls, vehicle_parts(cls, *dims, col), s_lead, L.lane_centre(ego_lane), speed=lead_speed, size=dims)
        clear = s_lead + dims[0] / 2
    for lane in range(L.lanes_per_direction):
        for d, (direction, rate) in enumerate(((1.0, conf.same_direction_per_km if lane != ego_lane else 0.0),
                                               (-1.0, conf.oncoming_per_km))):
            g = stream(21, lane, d)
            speed = direction * conf.ego_speed * g.uniform(0.8, 1.2)
            last = -np.inf
            # oncoming traffic also starts beyond the road's end and drives into it
            for s0 in _along(g, rate / 10.0, path.length * (2.0 if direction < 0 else 1.0) + 500.0):
                cls, dims, col = _random_vehicle(g)
                if s0 - last > 14.0:
                    lat = L.lane_centre(lane) * direction
                    add(cls, vehicle_parts(cls, *dims, col), s0, lat, speed=speed, size=dims)
                    last = s0
    return World(path=path, layout=L, objects=objects, rain=conf.rain)


def side_objects(conf: ScenarioConfig, stream, path: RoadPath, placer: _Placer, add) -> None:
    """Poles, signs, trees, bushes, pedestrians and buildings beside the road."""
    L = conf.layout
    kerb_out = L.half_width + L.kerb_width
    walk = kerb_out + L.sidewalk_width
    clear = L.half_width + 0.2
    palette = [(0.75, 0.1, 0.1), (0.1, 0.25, 0.7), (0.95, 0.95, 0.95), (0.95, 0.8, 0.1)]
    for i, side in enumerate((-1.0, 1.0)):
        if conf.pole_spacing > 0:
            g = stream(2, i)
            s = g.uniform(0, conf.pole_spacing)
            while s < path.length:
                lat = side * (kerb_out + 0.6)
                h = g.uniform(6.0, 8.0)
                if placer.ok(s, lat, 0.3, clear):
                    add("pole", pole_parts(h, lamp=True), s, lat, yaw_offset=np.pi / 2 * side, size=(0.2, 0.2, h))
                s += conf.pole_spacing * g.uniform(0.8, 1.2)
        g = stream(3, i)
        for s in _along(g, conf.signs_per_100m, path.length):
            lat = side * (kerb_out + 0.9)
            h, col = g.uniform(1.8, 2.4), palette[g.integers(len(palette))]
            if placer.ok(s, lat, 0.5, clear):
                add("sign", sign_parts(h, col), s, lat, yaw_offset=0.0 if side < 0 else np.pi, size=(0.1, 0.8, h + 0.7))
        g = stream(4, i)
        for s in _along(g, conf.trees_per_100m, path.length):
            lat = side * (walk + g.uniform(0.8, 3.0) if L.sidewalk_width > 0 else kerb_out + g.uniform(3.0, 8.0))
            crown, h = g.uniform(1.5, 2.8), g.uniform(5.0, 9.0)
            col = (g.uniform(0.12, 0.25), g.uniform(0.35, 0.55), g.uniform(0.1, 0.2))
            if placer.ok(s, lat, crown, clear + crown):
                add("tree", tree_parts(h, crown, col), s, lat, size=(crown * 2, crown * 2, h))
        g = stream(5, i)
        for s in _along(g, conf.bushes_per_100m, path.length):
            r = g.uniform(0.5, 1.2)
            lat = side * (walk + g.uniform(0.5, 2.0) if L.sidewalk_width > 0 else kerb_out + g.uniform(2.0, 6.0))
            col = (g.uniform(0.12, 0.25), g.uniform(0.35, 0.55), g.uniform(0.1, 0.2))
            if placer.ok(s, lat, r, clear + r):
                add("bush", bush_parts(r, col), s, lat, size=(2 * r, 2 * r, r))
        if L.sidewalk_width > 0:
            g = stream(6, i)
            for s in _along(g, conf.pedestrians_per_100m, path.length):
                lat = side * (kerb_out + g.uniform(0.5, L.sidewalk_width - 0.4))
                speed, h = g.choice([0.0, 1.3, -1.3]), g.uniform(1.55, 1.9)
                shirt, trousers = tuple(g.uniform(0.1, 0.9, 3)), tuple(g.uniform(0.1, 0.9, 3))
                if speed != 0.0 or placer.ok(s, lat, 0.4, clear):
                    add("pedestrian", pedestrian_parts(h, shirt, trousers), s, lat, speed=speed, size=(0.4, 0.5, h))
        if conf.buildings:
            g = stream(7, i)
            s = g.uniform(0, 10)
            while s < path.length:
                length, depth, h = g.uniform(10.0, 30.0), g.uniform(8.0, 15.0), g.uniform(6.0, 20.0)
                lat = side * (walk + 3.5 + depth / 2)
                col = tuple(g.uniform(0.45, 0.85) * np.array([1.0, g.uniform(0.85, 1.0), g.uniform(0.7, 1.0)]))
                if placer.ok(s + length / 2, lat, 0.5 * np.hypot(length, depth), walk + 1.0):
                    add("building", building_parts(length, depth, h, col), s + length / 2, lat, size=(length, depth, h))
                s += length + g.uniform(2.0, 12.0)


def _random_vehicle(g: np.random.Generator, parked: bool = False):
    """(class, (length, width, height) metres, body colour)."""
    cls = g.choice(["car", "car", "car", "van", "truck", "bus"] if not parked else ["car", "car", "car", "van"])
    dims = {
        "car": (g.uniform(4.0, 4.9), g.uniform(1.7, 1.9), g.uniform(1.4, 1.6)),
        "van": (g.uniform(4.8, 5.5), g.uniform(1.9, 2.1), g.uniform(1.9, 2.3)),
        "truck": (g.uniform(7.0, 9.0), g.uniform(2.3, 2.5), g.uniform(3.0, 3.6)),
        "bus": (g.uniform(10.0, 12.0), g.uniform(2.4, 2.55), g.uniform(3.0, 3.3)),
    }[str(cls)]
    colours = [(0.7, 0.05, 0.05), (0.9, 0.9, 0.9), (0.1, 0.1, 0.12), (0.15, 0.25, 0.6), (0.5, 0.5, 0.52),
               (0.8, 0.6, 0.1), (0.1, 0.4, 0.2)]
    return str(cls), dims, colours[g.integers(len(colours))]
