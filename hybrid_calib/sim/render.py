"""Camera image shading: sky, textured road (markings, sidewalk tiles, grass), textured objects
(building windows, vehicle glass, foliage), Lambert shading, haze, weather contrast, sensor noise.

Input is the ray-cast hit buffer of ``hybrid_calib.sim.raycast.cast_pinhole``; output an RGB image.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from hybrid_calib.config import require_ranges
from hybrid_calib.sim.raycast import BOX, GROUND, HitBuffer, Primitives
from hybrid_calib.sim.world import GROUND_CLASSES, MATERIAL_INDEX, World

SUN = np.array([0.45, 0.3, 0.84]) / np.linalg.norm([0.45, 0.3, 0.84])  # global frame, towards the sun
GROUND_COLOURS = np.array([
    (0.24, 0.24, 0.25),  # asphalt
    (0.9, 0.9, 0.88),  # marking
    (0.92, 0.75, 0.2),  # centre marking
    (0.62, 0.61, 0.58),  # sidewalk
    (0.48, 0.44, 0.38),  # shoulder
    (0.28, 0.44, 0.2),  # grass
], np.float32)


@dataclass(frozen=True)
class ShadingConfig:
    """Appearance of the rendered camera image."""

    ambient: float = 0.5  # ambient light fraction
    diffuse: float = 0.6  # Lambert term weight
    contrast: float = 1.0  # global contrast (rain < 1)
    fog_distance: float = 400.0  # haze reaches 63 % at this distance, metres
    rain: bool = False  # wet road, grey sky
    overcast: bool = False  # grey sky and haze, no sun shadows (dry road); implied by rain
    noise_std: float = 0.012  # per-pixel Gaussian noise (fraction of full scale)
    exposure: float = 1.0  # brightness gain (applied after haze and contrast)
    gamma: float = 1.0  # output gamma: image ** gamma (> 1 darkens the mid-tones)
    saturation: float = 1.0  # colour saturation multiplier (0 = grey)
    white_balance: tuple[float, float, float] = (1.0, 1.0, 1.0)  # per-channel gains (R, G, B)
    blur_sigma_px: float = 0.0  # Gaussian blur (optics / motion), pixels of the rendered image
    object_tint: float = 0.0  # per-object, per-channel albedo gain spread (uniform +- this, hashed from the id)
    ground_tint: float = 0.0  # per ground class and channel albedo gain spread (uniform +- this)
    tint_seed: int = 0  # seed of the object and ground tints

    def __post_init__(self):
        # contrast / fog_distance: the scenario's times the randomised factors; tint_seed: hashed in int64
        require_ranges(self, {"ambient": "[0, 10]", "diffuse": "[0, 10]", "contrast": "(0, 100]",
                              "fog_distance": "[0.01, 1e6]", "noise_std": "[0, 1]", "exposure": "(0, 10]",
                              "gamma": "(0, 10]", "saturation": "[0, 10]", "white_balance": "[0, 10]",
                              "blur_sigma_px": "[0, 100]", "object_tint": "[0, 1]", "ground_tint": "[0, 1]",
                              "tint_seed": "[0, 2147483647]"})


def hash_noise(ix: np.ndarray, iy: np.ndarray, seed: int = 0) -> np.ndarray:
    """Deterministic value noise in [0, 1) for integer cell coordinates (any equal shapes)."""
    h = (ix.astype(np.int64) * 374761393 + iy.astype(np.int64) * 668265263 + seed * 1442695041) & 0xFFFFFFFF
    h = ((h ^ (h >> 13)) * 1274126177) & 0xFFFFFFFF
    h = h ^ (h >> 16)
    return (h & 0xFFFF).astype(np.float32) / 65536.0


SHADOW_CASTERS = ("vehicle", "glass", "building", "foliage", "trunk", "pedestrian", "tyre")


def sunlit(prims: Primitives, ground: np.ndarray, origin: np.ndarray, radius: float = 120.0,
           max_casters: int = 80) -> np.ndarray:
    """(N,) 1 where ground points (N, 3) see the sun, 0 in the shadow of a nearby box or sphere.

    Shadow rays go from each ground point towards ``SUN``; only the ``max_casters`` casters nearest to
    ``origin`` (within ``radius`` m) are tested, each against the ground points inside its shadow's
    bounding box."""
    lit = np.ones(len(ground), np.float32)
    mats = np.isin(prims.material, [MATERIAL_INDEX[m] for m in SHADOW_CASTERS]) & (prims.kind != 1)
    d = np.linalg.norm(prims.center[:, :2] - origin[:2], axis=1)
    idx = np.flatnonzero(mats & (d < radius))
    idx = idx[np.argsort(d[idx])[:max_casters]]
    shift = -SUN[:2] / SUN[2]  # ground displacement of a shadow per metre of height
    gx, gy = ground[:, 0], ground[:, 1]
    for j in idx:
        c, h = prims.center[j], prims.half[j]
        r = float(np.linalg.norm(h[:2])) if prims.kind[j] == BOX else float(h[0])
        top = c[2] + h[2]
        far = c[:2] + shift * top
        lo = np.minimum(c[:2], far) - r
        hi = np.maximum(c[:2], far) + r
        sel = np.flatnonzero((gx > lo[0]) & (gx < hi[0]) & (gy > lo[1]) & (gy < hi[1]) & (lit > 0))
        if len(sel) == 0:
            continue
        q = ground[sel] - c
        if prims.kind[j] == BOX:
            cy, sy = np.cos(prims.yaw[j]), np.sin(prims.yaw[j])
            R = np.array([[cy, sy, 0.0], [-sy, cy, 0.0], [0.0, 0.0, 1.0]])
            p = q @ R.T
            dl = R @ SUN
            dl = np.where(np.abs(dl) < 1e-9, 1e-9, dl)
            t1, t2 = (-h - p) / dl, (h - p) / dl
            hit = np.minimum(t1, t2).max(1) <= np.maximum(t1, t2).min(1)
            hit &= np.maximum(t1, t2).min(1) > 0
        else:
            b = q @ SUN
            cc = np.einsum("ij,ij->i", q, q) - h[0] ** 2
            disc = b * b - cc
            hit = (disc >= 0) & (-b + np.sqrt(np.maximum(disc, 0)) > 0)
        lit[sel[hit]] = 0.0
    return lit


def shade(world: World, prims: Primitives, buf: HitBuffer, dirs: np.ndarray, origin: np.ndarray,
          conf: ShadingConfig, rng: np.random.Generator) -> np.ndarray:
    """(H, W) hit buffer + global ray directions (H, W, 3) -> RGB image (H, W, 3) uint8."""
    H, W = buf.t.shape
    img = np.empty((H, W, 3), np.float32)
    t = buf.t
    hit_g = buf.prim == GROUND
    hit_o = buf.prim >= 0
    sky = ~(hit_g | hit_o)
    # sky: a vertical gradient
    e = np.clip(dirs[..., 2][sky] * 4.0, 0, 1)[:, None]
    grey = conf.rain or conf.overcast
    horizon, zenith = ((0.7, 0.72, 0.74), (0.55, 0.58, 0.62)) if grey else ((0.8, 0.86, 0.92), (0.36, 0.55, 0.85))
    img[sky] = np.asarray(horizon, np.float32) * (1 - e) + np.asarray(zenith, np.float32) * e
    # ground
    if hit_g.any():
        P = origin + t[hit_g][:, None] * dirs[hit_g]
        cls, s, l = world.ground_class(P[:, :2])
        palette = GROUND_COLOURS
        if conf.ground_tint:
            idx = np.arange(len(GROUND_COLOURS))[:, None]
            gain = 2 * hash_noise(idx + np.zeros((1, 3), int), np.arange(3)[None, :] + 7, conf.tint_seed) - 1
            palette = np.clip(GROUND_COLOURS * (1 + conf.ground_tint * gain), 0, 1).astype(np.float32)
        col = palette[cls].copy()
        fine = hash_noise(np.floor(P[:, 0] * 8), np.floor(P[:, 1] * 8), 1)
        coarse = hash_noise(np.floor(P[:, 0] * 0.5), np.floor(P[:, 1] * 0.5), 2)
        col *= (0.85 + 0.2 * fine + 0.1 * coarse)[:, None]
        walk = cls == GROUND_CLASSES.index("sidewalk")
        joints = walk & ((np.mod(s, 1.5) < 0.04) | (np.mod(l, 1.5) < 0.04))
        col[joints] *= 0.75
        if conf.rain:
            col[cls == 0] *= 0.7
        lit = np.ones(len(P), np.float32) if grey else sunlit(prims, P, origin)  # overcast: no shadows
        img[hit_g] = col * (conf.ambient + conf.diffuse * SUN[2] * lit)[:, None]
    # objects
    if hit_o.any():
        j = buf.prim[hit_o]
        P = origin + t[hit_o][:, None] * dirs[hit_o]
        col = prims.colour[j].copy()
        if conf.object_tint:
            oid = prims.object_id[j][:, None] + np.zeros((1, 3), np.int64)
            gain = 2 * hash_noise(oid, np.arange(3)[None, :], conf.tint_seed) - 1
            col = np.clip(col * (1 + conf.object_tint * gain), 0, 1).astype(np.float32)
        mat = prims.material[j]
        local = P - prims.center[j]
        cy, sy = np.cos(prims.yaw[j]), np.sin(prims.yaw[j])
        lx = cy * local[:, 0] + sy * local[:, 1]
        ly = -sy * local[:, 0] + cy * local[:, 1]
        z = P[:, 2]
        n = buf.normal[hit_o]
        # building windows on the facades
        b = (mat == MATERIAL_INDEX["building"]) & (prims.kind[j] == BOX) & (np.abs(n[:, 2]) < 0.5)
        if b.any():
            nl_x = np.abs(cy[b] * n[b, 0] + sy[b] * n[b, 1]) > 0.7
            u = np.where(nl_x, ly[b], lx[b])
            mu, mz = np.mod(u, 3.0), np.mod(z[b], 3.2)
            win = (mu > 0.7) & (mu < 2.3) & (mz > 1.1) & (mz < 2.6)
            win &= z[b] > 3.0
            cb = col[b]
            cb[win] = (0.16, 0.2, 0.26) + 0.15 * hash_noise(np.floor(u[win] / 3), np.floor(z[b][win] / 3.2), 3)[:, None]
            door = (z[b] < 2.4) & (np.mod(u, 9.0) < 1.4)
            cb[door] *= 0.45
            col[b] = cb
        fol = mat == MATERIAL_INDEX["foliage"]
        if fol.any():
            nz = hash_noise(np.floor(P[fol, 0] * 6), np.floor(P[fol, 1] * 6 + P[fol, 2] * 6), 4)
            col[fol] *= (0.6 + 0.7 * nz)[:, None]
        rail = mat == MATERIAL_INDEX["guardrail"]
        if rail.any():
            col[rail] *= (0.8 + 0.25 * (np.mod(z[rail], 0.11) < 0.055))[:, None]
        veh = mat == MATERIAL_INDEX["vehicle"]
        if veh.any():  # a little speckle and darker lower edge
            col[veh] *= (0.92 + 0.1 * hash_noise(np.floor(lx[veh] * 4), np.floor(z[veh] * 4), 5))[:, None]
        lam = np.clip(n @ SUN, 0, 1)
        img[hit_o] = col * (conf.ambient + conf.diffuse * lam)[:, None]
    # haze with distance
    haze = np.asarray((0.72, 0.74, 0.76) if grey else (0.78, 0.83, 0.88), np.float32)
    d = np.where(np.isfinite(t), t, np.inf)
    f = (1 - np.exp(-d / conf.fog_distance)).astype(np.float32)[..., None]
    img = img * (1 - f) + haze * f
    if conf.contrast != 1.0:
        mean = img.reshape(-1, 3).mean(0)
        img = mean + (img - mean) * conf.contrast
    img = _camera_response(img, conf)
    img += rng.normal(0, conf.noise_std, img.shape).astype(np.float32)
    return (np.clip(img, 0, 1) * 255 + 0.5).astype(np.uint8)


def _camera_response(img: np.ndarray, conf: ShadingConfig) -> np.ndarray:
    """Exposure, white balance, saturation, gamma and blur of a (H, W, 3) float image in [0, 1]-ish;
    the identity at the defaults (and then the image is returned untouched)."""
    if conf.exposure != 1.0 or tuple(conf.white_balance) != (1.0, 1.0, 1.0):
        img = img * (conf.exposure * np.asarray(conf.white_balance, np.float32))
    if conf.saturation != 1.0:
        grey = img @ np.asarray([0.299, 0.587, 0.114], np.float32)
        img = grey[..., None] + (img - grey[..., None]) * conf.saturation
    if conf.gamma != 1.0:
        img = np.clip(img, 0, 1) ** conf.gamma
    if conf.blur_sigma_px > 0.05:
        import cv2

        img = cv2.GaussianBlur(np.ascontiguousarray(img, np.float32), (0, 0), conf.blur_sigma_px)
    return img.astype(np.float32)
