"""Vectorised analytic ray casting against upright boxes, vertical cylinders, spheres and the ground.

One caster serves the camera, the LiDAR and the radar, so their depths agree exactly. Rays come on a
2D grid (camera pixels, or elevation x azimuth for the spinning / scanning sensors) and share one
origin. Each primitive only tests the rays of the grid rectangle its bounds cover (a z-buffer over
rectangles), so the cost grows with the image area objects cover, not with rays x primitives.

Frames: everything here is in the **global** frame (x east, y north, z up, metres); the ground is the
plane z = 0.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

BOX, CYLINDER, SPHERE = 0, 1, 2
NO_HIT = -1  # primitive index of a ray that hit nothing
GROUND = -2  # primitive index of a ray that hit the ground plane
_EPS = 1e-9


@dataclass
class Primitives:
    """A struct of arrays of M primitives, global frame.

    kind: (M,) int8, BOX / CYLINDER / SPHERE.
    center: (M, 3) float64 metres (box / cylinder: the volume centre; sphere: its centre).
    half: (M, 3) float64 metres: box half extents along its local x, y, z; cylinder (r, r, half
      height); sphere (r, r, r).
    yaw: (M,) float64 radians, rotation of the box's local x about global z (0 for the others).
    colour: (M, 3) float32 in [0, 1], base albedo.
    material: (M,) int16, index into ``hybrid_calib.sim.world.MATERIALS``.
    object_id: (M,) int32, the object the primitive belongs to (several primitives per object).
    velocity: (M, 3) float64 m/s, global frame.
    """

    kind: np.ndarray
    center: np.ndarray
    half: np.ndarray
    yaw: np.ndarray
    colour: np.ndarray
    material: np.ndarray
    object_id: np.ndarray
    velocity: np.ndarray

    def __len__(self) -> int:
        return len(self.kind)

    @staticmethod
    def concat(parts: list[Primitives]) -> Primitives:
        parts = [p for p in parts if len(p)]
        if not parts:
            return empty_primitives()
        return Primitives(*(np.concatenate([getattr(p, f) for p in parts]) for f in _FIELDS))

    def subset(self, idx: np.ndarray) -> Primitives:
        return Primitives(*(getattr(self, f)[idx] for f in _FIELDS))

    @property
    def bounding_radius(self) -> np.ndarray:
        """(M,) radius of a sphere about ``center`` enclosing each primitive."""
        r = np.linalg.norm(self.half, axis=1)
        return np.where(self.kind == SPHERE, self.half[:, 0],
                        np.where(self.kind == CYLINDER, np.hypot(self.half[:, 0], self.half[:, 2]), r))

    def corners(self) -> np.ndarray:
        """(M, 8, 3) corners of each primitive's bounding box (upright, rotated by yaw)."""
        signs = np.array([[sx, sy, sz] for sx in (-1, 1) for sy in (-1, 1) for sz in (-1, 1)], float)
        local = signs[None] * self.half[:, None, :]
        c, s = np.cos(self.yaw)[:, None], np.sin(self.yaw)[:, None]
        x = c * local[..., 0] - s * local[..., 1]
        y = s * local[..., 0] + c * local[..., 1]
        return np.stack([x, y, local[..., 2]], -1) + self.center[:, None, :]


_FIELDS = ("kind", "center", "half", "yaw", "colour", "material", "object_id", "velocity")


def check_pose(T: np.ndarray, name: str) -> np.ndarray:
    """A (4, 4) finite rigid transform as float64, else ``ValueError`` naming it."""
    T = np.asarray(T, dtype=np.float64)
    if T.shape != (4, 4) or not np.all(np.isfinite(T)):
        raise ValueError(f"{name} must be a finite (4, 4) transform, got shape {T.shape}")
    if not np.allclose(T[:3, :3] @ T[:3, :3].T, np.eye(3), atol=1e-6) or not np.allclose(T[3], [0, 0, 0, 1]):
        raise ValueError(f"{name} is not a rigid transform (rotation not orthonormal or last row not [0, 0, 0, 1])")
    return T


def empty_primitives() -> Primitives:
    return Primitives(np.zeros(0, np.int8), np.zeros((0, 3)), np.zeros((0, 3)), np.zeros(0),
                      np.zeros((0, 3), np.float32), np.zeros(0, np.int16), np.zeros(0, np.int32),
                      np.zeros((0, 3)))


def intersect(prims: Primitives, j: int, origin: np.ndarray, dirs: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """First hit of rays ``origin + t dirs`` (t > 0) with primitive ``j``.

    origin: (3,) metres; dirs: (K, 3) unit vectors. Returns t (K,) metres (inf = miss) and the
    outward unit normal (K, 3) at the hit (undefined where missed).
    """
    with np.errstate(divide="ignore", invalid="ignore"):
        return _intersect(prims, j, origin, dirs)


def _intersect(prims: Primitives, j: int, origin: np.ndarray, dirs: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    k = prims.kind[j]
    c, h = prims.center[j], prims.half[j]
    if k == BOX:
        cy, sy = np.cos(prims.yaw[j]), np.sin(prims.yaw[j])
        R = np.array([[cy, sy, 0.0], [-sy, cy, 0.0], [0.0, 0.0, 1.0]])  # global -> local
        p = R @ (origin - c)
        d = dirs @ R.T
        inv = 1.0 / np.where(np.abs(d) < _EPS, _EPS, d)
        t1 = (-h - p) * inv
        t2 = (h - p) * inv
        tn = np.minimum(t1, t2)
        tf = np.maximum(t1, t2)
        axis = np.argmax(tn, axis=1)
        tmin = tn[np.arange(len(d)), axis]
        tmax = tf.min(axis=1)
        hit = (tmax >= tmin) & (tmin > _EPS)
        t = np.where(hit, tmin, np.inf)
        n_local = np.zeros_like(d)
        n_local[np.arange(len(d)), axis] = -np.sign(d[np.arange(len(d)), axis])
        return t, n_local @ R  # local -> global is R^T: n_g = R^T n_l  <=> n_l @ R
    if k == CYLINDER:
        r, hz = h[0], h[2]
        p = origin - c
        a = dirs[:, 0] ** 2 + dirs[:, 1] ** 2
        b = 2 * (p[0] * dirs[:, 0] + p[1] * dirs[:, 1])
        cc = p[0] ** 2 + p[1] ** 2 - r * r
        disc = b * b - 4 * a * cc
        t_side = np.where((disc >= 0) & (a > _EPS), (-b - np.sqrt(np.maximum(disc, 0))) / (2 * a), np.inf)
        z_side = p[2] + t_side * dirs[:, 2]
        t_side = np.where((t_side > _EPS) & (np.abs(z_side) <= hz), t_side, np.inf)
        t_cap = np.where(dirs[:, 2] < -_EPS, (hz - p[2]) / dirs[:, 2], np.inf)
        cap_xy = p[:2] + t_cap[:, None] * dirs[:, :2]
        t_cap = np.where((t_cap > _EPS) & (np.einsum("ij,ij->i", cap_xy, cap_xy) <= r * r), t_cap, np.inf)
        use_cap = t_cap < t_side
        t = np.minimum(t_side, t_cap)
        q = p + np.where(np.isfinite(t), t, 0.0)[:, None] * dirs
        n = np.stack([q[:, 0], q[:, 1], np.zeros(len(q))], 1) / max(r, _EPS)
        n[use_cap] = (0.0, 0.0, 1.0)
        return t, n
    # sphere
    r = h[0]
    p = origin - c
    b = dirs @ p
    cc = p @ p - r * r
    disc = b * b - cc
    t = np.where(disc >= 0, -b - np.sqrt(np.maximum(disc, 0)), np.inf)
    t = np.where(t > _EPS, t, np.inf)
    q = p + np.where(np.isfinite(t), t, 0.0)[:, None] * dirs
    return t, q / max(r, _EPS)


@dataclass
class HitBuffer:
    """Per-ray result of casting a grid of rays (shape G = grid shape).

    t: G float64 metres along the unit ray (inf = no hit); prim: G int32 primitive index, GROUND or
    NO_HIT; normal: G + (3,) float32 outward unit normal, global frame.
    """

    t: np.ndarray
    prim: np.ndarray
    normal: np.ndarray


def cast_ground(origin: np.ndarray, dirs: np.ndarray, max_range: float) -> HitBuffer:
    """Hit the ground plane z = 0 with rays (..., 3) from ``origin`` (3,); beyond max_range is a miss."""
    dz = dirs[..., 2]
    with np.errstate(divide="ignore", invalid="ignore"):
        t = np.where(dz < -_EPS, -origin[2] / dz, np.inf)
    t = np.where(t <= max_range, t, np.inf)
    prim = np.where(np.isfinite(t), GROUND, NO_HIT).astype(np.int32)
    normal = np.zeros(dirs.shape, np.float32)
    normal[..., 2] = 1.0
    return HitBuffer(t, prim, normal)


def zbuffer_update(buf: HitBuffer, prims: Primitives, j: int, origin: np.ndarray, dirs: np.ndarray,
                   rows: slice, cols: slice) -> None:
    """Test primitive j against the rays ``dirs[rows, cols]`` and keep the nearer hits in ``buf``."""
    sub = dirs[rows, cols]
    if sub.size == 0:
        return
    t, n = intersect(prims, j, origin, sub.reshape(-1, 3))
    t = t.reshape(sub.shape[:2])
    bt = buf.t[rows, cols]
    m = t < bt
    if not m.any():
        return
    bt[m] = t[m]
    buf.prim[rows, cols][m] = j
    buf.normal[rows, cols][m] = n.reshape(sub.shape)[m]


def cull(prims: Primitives, origin: np.ndarray, max_range: float) -> np.ndarray:
    """Indices of primitives whose bounding sphere comes within ``max_range`` of ``origin``."""
    if not len(prims):
        return np.zeros(0, int)
    d = np.linalg.norm(prims.center - origin, axis=1) - prims.bounding_radius
    return np.flatnonzero(d <= max_range)


def cast_pinhole(prims: Primitives, T_global_cam: np.ndarray, rays_cam: np.ndarray, K: np.ndarray,
                 max_range: float, near: float = 0.05) -> tuple[HitBuffer, np.ndarray]:
    """Cast every pixel ray of a pinhole camera.

    T_global_cam: (4, 4) camera -> global. rays_cam: (H, W, 3) unit rays in the camera frame
    (``PinholeCamera.rays()``). K: (3, 3). Returns the hit buffer (H, W) and the global ray
    directions (H, W, 3).
    """
    H, W = rays_cam.shape[:2]
    R, o = T_global_cam[:3, :3], T_global_cam[:3, 3]
    dirs = rays_cam @ R.T
    buf = cast_ground(o, dirs, max_range)
    idx = cull(prims, o, max_range)
    if len(idx) == 0:
        return buf, dirs
    corners = prims.subset(idx).corners()  # (m, 8, 3)
    pc = (corners - o) @ R  # camera frame
    edges = np.array([(a, b) for a in range(8) for b in range(a + 1, 8) if bin(a ^ b).count("1") == 1])
    for k, j in enumerate(idx):
        P = pc[k]
        front = P[:, 2] > near
        if not front.any():
            continue
        pts = P[front]
        if not front.all():
            za, zb = P[edges[:, 0], 2], P[edges[:, 1], 2]
            cross = (za > near) != (zb > near)
            if cross.any():
                a, b = P[edges[cross, 0]], P[edges[cross, 1]]
                s = (near - a[:, 2]) / (b[:, 2] - a[:, 2])
                pts = np.concatenate([pts, a + s[:, None] * (b - a)])
        u = K[0, 0] * pts[:, 0] / pts[:, 2] + K[0, 2]
        v = K[1, 1] * pts[:, 1] / pts[:, 2] + K[1, 2]
        u0, u1 = max(int(np.floor(u.min())), 0), min(int(np.ceil(u.max())) + 1, W)
        v0, v1 = max(int(np.floor(v.min())), 0), min(int(np.ceil(v.max())) + 1, H)
        if u0 >= u1 or v0 >= v1:
            continue
        zbuffer_update(buf, prims, j, o, dirs, slice(v0, v1), slice(u0, u1))
    return _clip_range(buf, max_range), dirs


def angular_grid_dirs(elevations: np.ndarray, azimuths: np.ndarray) -> np.ndarray:
    """(E,) x (A,) radians -> (E, A, 3) unit rays in a sensor frame: (cos el cos az, cos el sin az, sin el)."""
    el = elevations[:, None]
    az = azimuths[None, :]
    return np.stack(np.broadcast_arrays(np.cos(el) * np.cos(az), np.cos(el) * np.sin(az), np.sin(el)), -1)


def cast_angular(prims: Primitives, T_global_sensor: np.ndarray, elevations: np.ndarray, azimuths: np.ndarray,
                 max_range: float, wrap: bool = False, reach: tuple[tuple[float, float], ...] = ()
                 ) -> tuple[HitBuffer, np.ndarray]:
    """Cast an (elevation x azimuth) grid of rays from a sensor (LiDAR, radar).

    elevations: (E,) increasing radians; azimuths: (A,) increasing radians in the sensor frame
    (atan2(y, x)); wrap: True when the azimuths cover the full circle. Returns the hit buffer (E, A)
    and the global directions (E, A, 3).
    reach: ((range m, half azimuth rad), ...), the scans of a sensor that uses a hit only at a range and
    azimuth inside one of them (the radar's near and far scans): a primitive is not cast against the rays
    where no hit on it could be used (beyond every scan's range at its azimuth). Rays whose first surface
    was such a primitive then report a farther one or none, equally unusable; every usable hit is the same.
    Not with ``wrap`` (a sensor whose scans are limited in azimuth does not cover the full circle).
    """
    if reach and wrap:
        raise ValueError("cast_angular: reach limits the azimuths, wrap covers the full circle; use one of them")
    R, o = T_global_sensor[:3, :3], T_global_sensor[:3, 3]
    dirs = angular_grid_dirs(elevations, azimuths) @ R.T
    buf = cast_ground(o, dirs, max_range)
    idx = cull(prims, o, max_range)
    if len(idx) == 0:
        return buf, dirs
    c = (prims.center[idx] - o) @ R
    rad = prims.bounding_radius[idx] * 1.02 + 1e-3
    d = np.linalg.norm(c, axis=1)
    dh = np.hypot(c[:, 0], c[:, 1])
    az_c = np.arctan2(c[:, 1], c[:, 0])
    el_c = np.arcsin(np.clip(c[:, 2] / np.maximum(d, _EPS), -1, 1))
    with np.errstate(invalid="ignore", divide="ignore"):
        half_az = np.where(rad < dh, np.arcsin(np.clip(rad / dh, 0, 1)), np.pi)
        half_el = np.where(rad < d, np.arcsin(np.clip(rad / d, 0, 1)), np.pi)
    A = len(azimuths)
    if reach:  # per primitive, the widest half azimuth of a scan that reaches its nearest point (-1: none does)
        ranges, halves = np.array(reach, np.float64).T
        usable = np.where((d - rad)[:, None] <= ranges, halves, -1.0).max(axis=1)
    for k, j in enumerate(idx):
        e0 = np.searchsorted(elevations, el_c[k] - half_el[k], "left")
        e1 = np.searchsorted(elevations, el_c[k] + half_el[k], "right")
        if e0 >= e1:
            continue
        lo, hi = az_c[k] - half_az[k], az_c[k] + half_az[k]
        if reach:
            lo, hi = max(lo, -usable[k]), min(hi, usable[k])
            if lo > hi:  # also where no scan reaches the primitive (usable -1)
                continue
            spans = [(np.searchsorted(azimuths, lo, "left"), np.searchsorted(azimuths, hi, "right"))]
        elif half_az[k] >= np.pi:
            spans = [(0, A)]
        elif wrap and (lo < -np.pi or hi > np.pi):
            lo_w = lo + 2 * np.pi if lo < -np.pi else lo
            hi_w = hi - 2 * np.pi if hi > np.pi else hi
            spans = [(np.searchsorted(azimuths, lo_w, "left"), A), (0, np.searchsorted(azimuths, hi_w, "right"))]
        else:
            spans = [(np.searchsorted(azimuths, lo, "left"), np.searchsorted(azimuths, hi, "right"))]
        for a0, a1 in spans:
            if a0 < a1:
                zbuffer_update(buf, prims, j, o, dirs, slice(e0, e1), slice(a0, a1))
    return _clip_range(buf, max_range), dirs


def _clip_range(buf: HitBuffer, max_range: float) -> HitBuffer:
    """Hits beyond ``max_range`` become misses."""
    far = buf.t > max_range
    buf.t[far] = np.inf
    buf.prim[far] = NO_HIT
    return buf
