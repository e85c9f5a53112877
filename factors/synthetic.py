"""Geometry-only synthetic correspondences ("oracle correspondences") for tests and benchmarks.

Reflectors are drawn at slant ranges and azimuths inside the radar's field of view and at
elevations that really vary inside the vertical beam; the radar records each one with z = 0 (same
slant range and azimuth); its pixel is the projection of the TRUE reflector plus Gaussian noise.
A fraction of rows are gross outliers (uniformly random pixels in the image).
"""

from __future__ import annotations

import numpy as np

from factors.correspondences import Correspondences
from hybrid_calib.sensors.camera import PinholeCamera

# nuScenes CAM_FRONT-like intrinsics (1600 x 900).
DEFAULT_CAMERA = PinholeCamera(1266.4, 1266.4, 816.3, 491.5, 1600, 900)


def _height_elevations(r: np.ndarray, height_m: tuple[float, float], mean_deg: float, beam_deg: float,
                        rng: np.random.Generator) -> np.ndarray:
    """(m,) elevations (rad) of reflectors at slant ranges ``r`` whose heights are ``N(mu, std^2)``
    truncated to the beam ``[r sin(mean - beam), r sin(mean + beam)]``."""
    from scipy.stats import truncnorm

    mu, sd = float(height_m[0]), float(height_m[1])
    if not sd > 0:
        raise ValueError(f"synthetic_correspondences: height_m std must be > 0, got {height_m}")
    lo, hi = r * np.sin(np.deg2rad(mean_deg - beam_deg)), r * np.sin(np.deg2rad(mean_deg + beam_deg))
    h = truncnorm.rvs((lo - mu) / sd, (hi - mu) / sd, loc=mu, scale=sd, size=len(r), random_state=rng)
    return np.arcsin(np.clip(h / r, -1.0, 1.0))


def synthetic_correspondences(
    T_cam_radar: np.ndarray,
    camera_or_K: PinholeCamera | np.ndarray = DEFAULT_CAMERA,
    n: int = 100,
    rng: np.random.Generator | None = None,
    sigma_px: float = 2.0,
    outlier_frac: float = 0.2,
    elevation_beam_deg: float = 7.0,
    elevation_mean_deg: float = 0.0,
    range_m: tuple[float, float] = (5.0, 60.0),
    azimuth_deg: tuple[float, float] = (-35.0, 35.0),
    cell_px: float = 0.0,
    height_m: tuple[float, float] | None = None,
    frame_id: str = "synthetic",
    timestamp_us: int = 0,
) -> tuple[Correspondences, dict]:
    """``n`` correspondences seen through ``T_cam_radar`` (4, 4).

    camera_or_K: a ``PinholeCamera`` (distortion ignored) or a (3, 3) K (image size 2 cx + 1 by
    2 cy + 1). Elevations are uniform in ``elevation_mean_deg +- elevation_beam_deg``; ranges
    uniform in ``range_m`` (metres); azimuths uniform in ``azimuth_deg``. With ``height_m = (mu, std)``
    (metres) the reflector HEIGHTS above the radar plane are ``N(mu, std^2)`` truncated to the beam
    instead (the ``height`` elevation model of ``RadarPixelFactorConfig``). ``cell_px > 0``
    quantises every pixel to the centre of its cell (a network cell, e.g. 8) and sets
    ``sigma_px = sqrt(sigma^2 + cell^2/12)``. Confidence is 1 for every row.

    Returns the ``Correspondences`` and a truth dict: ``points_true`` (n, 3) radar frame,
    ``inlier`` (n,) bool, ``elevation_rad`` (n,), ``pixels_clean`` (n, 2) projections of the true
    reflectors. Raises ValueError if the geometry puts (almost) no reflector in the image.
    """
    rng = np.random.default_rng() if rng is None else rng
    if isinstance(camera_or_K, PinholeCamera):
        K, width, height = camera_or_K.K, camera_or_K.width, camera_or_K.height
    else:
        K = np.asarray(camera_or_K, np.float64)
        width, height = int(round(2 * K[0, 2] + 1)), int(round(2 * K[1, 2] + 1))
    T = np.asarray(T_cam_radar, np.float64)
    if n < 1:
        raise ValueError(f"synthetic_correspondences: n must be >= 1, got {n}")
    pts, pix, elev = [], [], []
    got, tries = 0, 0
    while got < n:
        tries += 1
        if tries > 50:
            raise ValueError("synthetic_correspondences: the radar field of view barely overlaps the image; "
                             "check T_cam_radar, azimuth_deg and range_m")
        m = 4 * (n - got) + 16
        r = rng.uniform(*range_m, m)
        a = np.deg2rad(rng.uniform(*azimuth_deg, m))
        if height_m is None:
            phi = np.deg2rad(elevation_mean_deg + rng.uniform(-elevation_beam_deg, elevation_beam_deg, m))
        else:
            phi = _height_elevations(r, height_m, elevation_mean_deg, elevation_beam_deg, rng)
        p = np.stack([r * np.cos(phi) * np.cos(a), r * np.cos(phi) * np.sin(a), r * np.sin(phi)], axis=1)
        P = p @ T[:3, :3].T + T[:3, 3]
        ok = P[:, 2] > 1.0
        uv = np.full((m, 2), -1e9)
        uv[ok] = (P[ok] @ K.T)[:, :2] / P[ok, 2:3]
        ok &= (uv[:, 0] >= 0) & (uv[:, 0] <= width - 1) & (uv[:, 1] >= 0) & (uv[:, 1] <= height - 1)
        take = np.flatnonzero(ok)[: n - got]
        pts.append(p[take])
        pix.append(uv[take])
        elev.append(phi[take])
        got += len(take)
    points_true = np.concatenate(pts)
    pixels_clean = np.concatenate(pix)
    elevation = np.concatenate(elev)
    rng_range = np.linalg.norm(points_true, axis=1)
    az = np.arctan2(points_true[:, 1], points_true[:, 0])
    points_radar = np.stack([rng_range * np.cos(az), rng_range * np.sin(az), np.zeros(n)], axis=1)
    pixels = pixels_clean + rng.normal(scale=sigma_px, size=(n, 2))
    inlier = np.ones(n, bool)
    n_out = int(round(outlier_frac * n))
    if n_out:
        idx = rng.choice(n, n_out, replace=False)
        inlier[idx] = False
        pixels[idx] = np.stack([rng.uniform(0, width - 1, n_out), rng.uniform(0, height - 1, n_out)], axis=1)
    sigma = float(sigma_px)
    if cell_px > 0:
        pixels = (np.floor(pixels / cell_px) + 0.5) * cell_px - 0.5
        sigma = float(np.sqrt(sigma**2 + cell_px**2 / 12.0))
    corr = Correspondences(points_radar, pixels, np.full(n, sigma), np.ones(n), K, frame_id, timestamp_us)
    truth = dict(points_true=points_true, inlier=inlier, elevation_rad=elevation, pixels_clean=pixels_clean)
    return corr, truth
