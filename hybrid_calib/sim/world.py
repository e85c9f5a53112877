"""The procedural world: a road centre line, its cross-section, and the objects along it.

Frames: global (x east, y north, z up, metres; ground plane z = 0). Positions along the road are
given in road coordinates (s = arc length along the centre line, l = lateral offset, positive to
the left of the driving direction); ``RoadPath`` converts. Traffic keeps to the right, so the ego
lane has l < 0.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from scipy.spatial import cKDTree

from hybrid_calib.sim.raycast import BOX, CYLINDER, SPHERE, Primitives, empty_primitives


@dataclass(frozen=True)
class Material:
    """Sensor-facing surface properties of a primitive."""

    name: str
    radar_reflectivity: float  # radar cross-section per m^2 of projected area at normal incidence (m^2/m^2)
    lidar_reflectivity: float  # LiDAR intensity at normal incidence, 0..1
    radar_visible: bool = True  # False: the radar's clutter filter drops it (e.g. foliage returns)


# Indices into MATERIALS are stored in Primitives.material.
MATERIALS: tuple[Material, ...] = (
    Material("vehicle", 30.0, 0.35),
    Material("glass", 8.0, 0.08),
    Material("building", 2.0, 0.25),
    Material("metal_pole", 25.0, 0.40),
    Material("sign", 40.0, 0.95),
    Material("guardrail", 20.0, 0.55),
    Material("kerb", 1.5, 0.30),
    Material("trunk", 3.0, 0.20),
    Material("foliage", 0.3, 0.15, radar_visible=False),
    Material("pedestrian", 1.2, 0.25),
    Material("tyre", 5.0, 0.05),
)
MATERIAL_INDEX = {m.name: i for i, m in enumerate(MATERIALS)}
RADAR_REFLECTIVITY = np.array([m.radar_reflectivity if m.radar_visible else 0.0 for m in MATERIALS])
LIDAR_REFLECTIVITY = np.array([m.lidar_reflectivity for m in MATERIALS])

# Object classes (WorldObject.cls); VEHICLE_CLASSES are what the radar mostly sees.
VEHICLE_CLASSES = ("car", "van", "truck", "bus")


@dataclass(frozen=True)
class Part:
    """One primitive of an object template, in the object's local frame (x forward, y left, z up,
    origin on the ground under the object's centre)."""

    kind: int  # BOX / CYLINDER / SPHERE
    center: tuple[float, float, float]  # metres, local frame
    half: tuple[float, float, float]  # metres (see Primitives.half)
    material: str  # a MATERIALS name
    colour: tuple[float, float, float]  # albedo in [0, 1]


@dataclass
class WorldObject:
    """An object in the world. Static ones have a fixed pose; moving ones follow the road:
    s(t) = s0 + speed * t at lateral offset ``lateral`` (heading flipped when speed < 0)."""

    object_id: int
    cls: str
    parts: tuple[Part, ...]
    s0: float
    lateral: float
    speed: float = 0.0  # m/s along s (negative: oncoming)
    yaw_offset: float = 0.0  # radians, added to the road heading
    size: tuple[float, float, float] = (0.0, 0.0, 0.0)  # length, width, height (metres)


class RoadPath:
    """A road centre line sampled every ``step`` metres, from (length m, curvature 1/m) segments."""

    _COARSE = 4  # k-d tree over every 4th sample (faster queries), refined on the fine samples

    def __init__(self, segments: list[tuple[float, float]], step: float = 0.5, start_heading: float = 0.0):
        if not segments:
            raise ValueError("a road needs at least one segment")
        xs, ys, hs = [0.0], [0.0], [start_heading]
        for length, kappa in segments:
            n = max(int(round(length / step)), 1)
            ds = length / n
            for _ in range(n):
                h0 = hs[-1]
                h1 = h0 + kappa * ds
                hm = 0.5 * (h0 + h1)
                xs.append(xs[-1] + ds * np.cos(hm))
                ys.append(ys[-1] + ds * np.sin(hm))
                hs.append(h1)
        self.xy = np.stack([xs, ys], 1)
        self.heading = np.array(hs)
        seg = np.linalg.norm(np.diff(self.xy, axis=0), axis=1)
        self.s = np.concatenate([[0.0], np.cumsum(seg)])
        self.length = float(self.s[-1])
        self.curvature = np.gradient(self.heading, self.s)
        self._step = float(self.s[-1] / max(len(self.s) - 1, 1))
        self._tree = cKDTree(self.xy[:: self._COARSE])

    def frame(self, s: np.ndarray | float) -> tuple[np.ndarray, np.ndarray]:
        """Arc length(s) -> centre-line points (..., 2) and headings (...) radians (linear interpolation)."""
        s = np.clip(np.asarray(s, dtype=np.float64), 0.0, self.length)
        x = np.interp(s, self.s, self.xy[:, 0])
        y = np.interp(s, self.s, self.xy[:, 1])
        h = np.interp(s, self.s, self.heading)
        return np.stack([x, y], -1), h

    def to_global(self, s, lateral) -> tuple[np.ndarray, np.ndarray]:
        """Road coordinates (s, l) -> global xy (..., 2) and road heading (...)."""
        p, h = self.frame(s)
        lateral = np.asarray(lateral, dtype=np.float64)
        normal = np.stack([-np.sin(h), np.cos(h)], -1)
        return p + lateral[..., None] * normal, h

    def to_road(self, xy: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Global xy (N, 2) -> road coordinates s (N,), l (N,).

        The nearest sample of a coarse copy of the centre line (every ``_COARSE``-th sample) is found
        with a k-d tree, then moved to the nearest fine sample along the local tangent."""
        xy = np.asarray(xy, dtype=np.float64).reshape(-1, 2)
        _, ic = self._tree.query(xy, workers=1)
        i = ic * self._COARSE
        along = self._along(xy, i)
        i = np.clip(i + np.rint(along / self._step).astype(np.int64), 0, len(self.s) - 1)
        d = xy - self.xy[i]
        h = self.heading[i]
        along = d[:, 0] * np.cos(h) + d[:, 1] * np.sin(h)
        lat = -d[:, 0] * np.sin(h) + d[:, 1] * np.cos(h)
        return self.s[i] + along, lat

    def _along(self, xy: np.ndarray, i: np.ndarray) -> np.ndarray:
        d = xy - self.xy[i]
        return d[:, 0] * np.cos(self.heading[i]) + d[:, 1] * np.sin(self.heading[i])


@dataclass(frozen=True)
class RoadLayout:
    """The road's cross-section (metres)."""

    lanes_per_direction: int = 1  # lanes each way; the ego drives in the rightmost
    lane_width: float = 3.5  # width of a lane
    kerb_width: float = 0.3  # kerb stone width (a raised box)
    kerb_height: float = 0.15  # kerb stone height
    sidewalk_width: float = 3.0  # sidewalk beyond the kerb (0: grass shoulder, e.g. highway)
    parking_width: float = 0.0  # parking strip between the outer lane and the kerb (0: none)
    dashed_centre: bool = False  # centre line dashed (else solid)

    @property
    def lanes_width(self) -> float:
        """Distance from the centre line to the outer edge line."""
        return self.lanes_per_direction * self.lane_width

    @property
    def half_width(self) -> float:
        """Distance from the centre line to the kerb face."""
        return self.lanes_width + self.parking_width

    def lane_centre(self, lane: int) -> float:
        """Lateral offset of lane ``lane`` (0 = innermost, going the +s direction); negative = right."""
        return -(lane + 0.5) * self.lane_width


@dataclass
class World:
    """A road, its layout and the objects on and beside it."""

    path: RoadPath
    layout: RoadLayout
    objects: list[WorldObject]
    static: Primitives = field(default_factory=empty_primitives)
    rain: bool = False

    def __post_init__(self):
        statics = [o for o in self.objects if o.speed == 0.0]
        self.static = Primitives.concat([self._place(o, 0.0) for o in statics])
        self._moving = [o for o in self.objects if o.speed != 0.0]
        self._moving_s0 = np.array([o.s0 for o in self._moving])
        self._moving_speed = np.array([o.speed for o in self._moving])
        self._moving_lat = np.array([o.lateral for o in self._moving])
        self.object_cls = {o.object_id: o.cls for o in self.objects}

    def object_pose(self, obj: WorldObject, t: float) -> tuple[np.ndarray, float, np.ndarray]:
        """Object pose at time t (s): ground point xy (2,), yaw (rad), velocity (3,) m/s global."""
        s = obj.s0 + obj.speed * t
        xy, h = self.path.to_global(s, obj.lateral)
        yaw = float(h) + obj.yaw_offset + (np.pi if obj.speed < 0 else 0.0)
        v = abs(obj.speed) * np.array([np.cos(yaw), np.sin(yaw), 0.0]) if obj.speed else np.zeros(3)
        return np.asarray(xy, float), yaw, v

    def _place(self, obj: WorldObject, t: float) -> Primitives:
        xy, yaw, v = self.object_pose(obj, t)
        return place_parts(obj.parts, xy, yaw, v, obj.object_id)

    def primitives_at(self, t: float, near: np.ndarray | None = None, radius: float = np.inf) -> Primitives:
        """Every primitive at time t (seconds since the start of the drive), global frame.

        Moving objects that have driven off either end of the road are left out; with ``near``
        (a global point, metres) only moving objects within ``radius`` metres of it are placed.
        Static primitives are always all included (sensors cull them)."""
        if not self._moving:
            return self.static
        s = self._moving_s0 + self._moving_speed * t
        keep = (s > 5.0) & (s < self.path.length - 5.0)
        if near is not None and np.isfinite(radius):
            xy, _ = self.path.to_global(s, self._moving_lat)
            keep &= np.linalg.norm(xy - np.asarray(near, float)[:2], axis=1) < radius + 20.0
        return Primitives.concat([self.static] + [self._place(self._moving[i], t) for i in np.flatnonzero(keep)])

    def ground_class(self, xy: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Ground points (N, 2) -> class (N,) int8 (see GROUND_CLASSES), s (N,), l (N,)."""
        s, l = self.path.to_road(xy)
        L = self.layout
        a = np.abs(l)
        cls = np.full(len(a), GROUND_CLASSES.index("grass"), np.int8)
        side = L.half_width + L.kerb_width
        if L.sidewalk_width > 0:
            cls[(a >= side) & (a < side + L.sidewalk_width)] = GROUND_CLASSES.index("sidewalk")
        else:
            cls[(a >= L.half_width) & (a < L.half_width + 2.0)] = GROUND_CLASSES.index("shoulder")
        road = a < L.half_width
        cls[road] = GROUND_CLASSES.index("asphalt")
        dash = (np.mod(s, 12.0) < 4.0)
        # lane dividers (dashed white), centre line (yellow), edge lines (solid white)
        for k in range(1, L.lanes_per_direction):
            m = road & (np.abs(a - k * L.lane_width) < 0.075) & dash
            cls[m] = GROUND_CLASSES.index("marking")
        centre = road & (a < 0.1)
        if L.dashed_centre:
            centre &= dash
        cls[centre] = GROUND_CLASSES.index("centre_marking")
        edge = L.lanes_width if L.parking_width > 0 else L.half_width - 0.3
        cls[road & (np.abs(a - edge) < 0.08)] = GROUND_CLASSES.index("marking")
        return cls, s, l


GROUND_CLASSES = ("asphalt", "marking", "centre_marking", "sidewalk", "shoulder", "grass")
GROUND_LIDAR_REFLECTIVITY = np.array([0.06, 0.8, 0.7, 0.2, 0.15, 0.1])


def place_parts(parts: tuple[Part, ...], xy: np.ndarray, yaw: float, velocity: np.ndarray,
                object_id: int) -> Primitives:
    """Object template parts at ground point ``xy`` with heading ``yaw`` -> Primitives (global)."""
    n = len(parts)
    c, s = np.cos(yaw), np.sin(yaw)
    loc = np.array([p.center for p in parts], float)
    center = np.stack([xy[0] + c * loc[:, 0] - s * loc[:, 1], xy[1] + s * loc[:, 0] + c * loc[:, 1], loc[:, 2]], 1)
    kinds = np.array([p.kind for p in parts], np.int8)
    return Primitives(
        kind=kinds,
        center=center,
        half=np.array([p.half for p in parts], float),
        yaw=np.where(kinds == BOX, yaw, 0.0),
        colour=np.array([p.colour for p in parts], np.float32),
        material=np.array([MATERIAL_INDEX[p.material] for p in parts], np.int16),
        object_id=np.full(n, object_id, np.int32),
        velocity=np.repeat(np.asarray(velocity, float)[None], n, 0),
    )


# ---- object templates (local frame: x forward, y left, z up, origin on the ground) ----

def vehicle_parts(cls: str, length: float, width: float, height: float, colour) -> tuple[Part, ...]:
    """A vehicle: tyre band, body, and a glass cabin (cars/vans) or a box cargo body (trucks, buses)."""
    L, W, H = length / 2, width / 2, height
    colour = tuple(float(c) for c in colour)
    tyre = Part(BOX, (0.0, 0.0, 0.18), (L * 0.92, W * 0.97, 0.18), "tyre", (0.05, 0.05, 0.05))
    if cls in ("car", "van"):
        body_h = 0.55 * H if cls == "car" else 0.6 * H
        body = Part(BOX, (0.0, 0.0, 0.36 + (body_h - 0.36) / 2), (L, W, (body_h - 0.36) / 2), "vehicle", colour)
        cab_len = 0.55 * L if cls == "car" else 0.85 * L
        cab_x = -0.1 * L if cls == "car" else -0.1 * L
        cab = Part(BOX, (cab_x, 0.0, body_h + (H - body_h) / 2), (cab_len, W * 0.92, (H - body_h) / 2), "glass",
                   (0.12, 0.16, 0.2))
        roof = Part(BOX, (cab_x, 0.0, H - 0.04), (cab_len * 0.9, W * 0.9, 0.04), "vehicle", colour)
        return (tyre, body, cab, roof)
    # truck / bus: a cab and a long box
    if cls == "truck":
        cab = Part(BOX, (L - 1.1, 0.0, 0.36 + 1.2), (1.1, W, 1.2), "vehicle", colour)
        cargo = Part(BOX, (-1.2, 0.0, 0.45 + (H - 0.45) / 2), (L - 1.2, W, (H - 0.45) / 2), "vehicle",
                     (0.8, 0.8, 0.78))
        return (tyre, cab, cargo)
    body = Part(BOX, (0.0, 0.0, 0.36 + (H - 0.36) / 2), (L, W, (H - 0.36) / 2), "vehicle", colour)
    band = Part(BOX, (0.0, 0.0, 0.55 * H + 0.4), (L * 0.96, W * 1.01, 0.4), "glass", (0.1, 0.13, 0.16))
    return (tyre, body, band)


def pedestrian_parts(height: float, shirt, trousers) -> tuple[Part, ...]:
    legs_h = 0.47 * height
    torso_h = 0.33 * height
    head_r = 0.11
    return (
        Part(CYLINDER, (0.0, 0.0, legs_h / 2), (0.14, 0.14, legs_h / 2), "pedestrian", tuple(trousers)),
        Part(CYLINDER, (0.0, 0.0, legs_h + torso_h / 2), (0.2, 0.2, torso_h / 2), "pedestrian", tuple(shirt)),
        Part(SPHERE, (0.0, 0.0, height - head_r), (head_r, head_r, head_r), "pedestrian", (0.85, 0.65, 0.5)),
    )


def pole_parts(height: float, radius: float = 0.08, lamp: bool = True) -> tuple[Part, ...]:
    parts = [Part(CYLINDER, (0.0, 0.0, height / 2), (radius, radius, height / 2), "metal_pole", (0.45, 0.46, 0.48))]
    if lamp:
        parts.append(Part(BOX, (0.0, 0.6, height - 0.1), (0.25, 0.6, 0.08), "metal_pole", (0.35, 0.35, 0.37)))
    return tuple(parts)


def sign_parts(height: float, colour) -> tuple[Part, ...]:
    """A post with a plate facing -x (towards traffic coming along +s when placed with the road yaw)."""
    return (
        Part(CYLINDER, (0.0, 0.0, height / 2), (0.05, 0.05, height / 2), "metal_pole", (0.5, 0.5, 0.52)),
        Part(BOX, (-0.07, 0.0, height + 0.35), (0.02, 0.4, 0.35), "sign", tuple(colour)),
    )


def tree_parts(height: float, crown: float, colour) -> tuple[Part, ...]:
    trunk_h = height - crown
    return (
        Part(CYLINDER, (0.0, 0.0, trunk_h / 2 + 0.3), (0.15, 0.15, trunk_h / 2 + 0.3), "trunk", (0.35, 0.25, 0.15)),
        Part(SPHERE, (0.0, 0.0, trunk_h + crown * 0.8), (crown, crown, crown), "foliage", tuple(colour)),
    )


def bush_parts(radius: float, colour) -> tuple[Part, ...]:
    return (Part(SPHERE, (0.0, 0.0, radius * 0.6), (radius, radius, radius), "foliage", tuple(colour)),)


def building_parts(length: float, depth: float, height: float, colour) -> tuple[Part, ...]:
    return (Part(BOX, (0.0, 0.0, height / 2), (length / 2, depth / 2, height / 2), "building", tuple(colour)),)


def guardrail_parts(length: float) -> tuple[Part, ...]:
    n_posts = max(int(length // 4), 1)
    parts = [Part(BOX, (0.0, 0.0, 0.62), (length / 2, 0.06, 0.17), "guardrail", (0.72, 0.73, 0.75))]
    for k in range(n_posts):
        x = -length / 2 + (k + 0.5) * length / n_posts
        parts.append(Part(BOX, (x, 0.12, 0.4), (0.06, 0.06, 0.4), "metal_pole", (0.5, 0.5, 0.5)))
    return tuple(parts)


def kerb_parts(length: float, width: float, height: float) -> tuple[Part, ...]:
    return (Part(BOX, (0.0, 0.0, height / 2), (length / 2, width / 2, height / 2), "kerb", (0.62, 0.62, 0.6)),)
