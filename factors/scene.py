"""Per-drive scene nuisance of the radar-pixel factor: how one drive's reflector heights differ
from the factor's fixed height model (issue 10; ``RadarPixelFactorConfig.scene_*``).

The factor compares each pixel with the expected point ``p_bar`` of a reflector whose height follows
one fixed distribution (``projection.height_elevation_prior``). Real scenes are structured (ground
returns near, kerbs and vehicles, poles and facades far, more on one side of the road), and the
structure is shared by every frame of a drive, so its error does not average out over frames. It is
modelled as ``c`` (K,) Gaussian nuisance parameters per drive, ``c ~ N(0, diag(prior_std^2))``:

- ``scene_height_std_m``: a height offset ``delta_h(r) = B(r) c_h`` (``B``: piecewise-linear hats
  over ``scene_knots_m``): the point moves along its elevation arc, ``p_bar += dp / |dp_z| delta_h``;
- ``scene_lateral_slope_std``: heights growing to one side, ``delta_h = c_y y`` (``y``: the recorded
  point's left coordinate, metres);
- ``scene_height_sq_std_m2``: an offset of the mean squared height ``B(r) c_q`` (m^2): the expected
  point's horizontal range ``E[sqrt(r^2 - h^2)] ~ r - E[h^2] / (2 r)`` moves by ``-B(r) c_q / (2 r)``
  along the recorded azimuth.

``scene_jacobian`` gives ``d e / d c`` (N, 2, K) of the whitened residuals; the estimate holds ``c``
at 0 and its covariance adds ``A P A^T`` with ``A = info^-1 J^T G`` (Schmidt "consider" covariance,
``hybrid_calib.calib.covariance.marginalise_scene_nuisance``).
"""

from __future__ import annotations

import numpy as np

from factors.config import RadarPixelFactorConfig
from factors.projection import RowModel, point_shift_jacobian


def range_hats(r: np.ndarray, knots_m) -> np.ndarray:
    """(N, K) piecewise-linear "hat" basis over range: ``f(r) = B(r) c`` interpolates ``c`` at the knots.

    r: (N,) metres; knots_m: (K,) increasing metres. Each row sums to 1; ranges outside the knots
    take the end values.
    """
    knots = np.asarray(knots_m, np.float64)
    r = np.clip(np.asarray(r, np.float64), knots[0], knots[-1])
    k = np.clip(np.searchsorted(knots, r, side="right") - 1, 0, len(knots) - 2)
    t = (r - knots[k]) / (knots[k + 1] - knots[k])
    B = np.zeros((len(r), len(knots)))
    B[np.arange(len(r)), k] = 1.0 - t
    B[np.arange(len(r)), k + 1] = t
    return B


def scene_prior_std(conf: RadarPixelFactorConfig) -> np.ndarray:
    """(K,) prior std of the enabled nuisance parameters, in the column order of ``scene_jacobian``:
    height offsets per knot (m), the lateral slope (m/m), mean-squared-height offsets per knot (m^2).
    Empty when all three are off."""
    k = len(conf.scene_knots_m)
    parts = []
    if conf.scene_height_std_m > 0:
        parts.append(np.full(k, conf.scene_height_std_m))
    if conf.scene_lateral_slope_std > 0:
        parts.append(np.array([conf.scene_lateral_slope_std]))
    if conf.scene_height_sq_std_m2 > 0:
        parts.append(np.full(k, conf.scene_height_sq_std_m2))
    return np.concatenate(parts) if parts else np.zeros(0)


def _directions(rows: RowModel, p: np.ndarray, r: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(N, 3) point shift per metre of height (along the elevation arc, ``dp / |dp_z|``; 0 without an
    arc) and per metre of horizontal range (along the recorded azimuth)."""
    dz = np.abs(rows.dp[:, 2])
    along_arc = np.where((dz > 1e-9)[:, None], rows.dp / np.maximum(dz, 1e-9)[:, None], 0.0)
    radial = np.stack([p[:, 0] / r, p[:, 1] / r, np.zeros(len(p))], axis=1)
    return along_arc, radial


def scene_jacobian(T_cam_radar: np.ndarray, rows: RowModel, points_radar: np.ndarray,
                   conf: RadarPixelFactorConfig) -> np.ndarray:
    """d e / d c (N, 2, K) of the whitened residuals (``projection.whitened_residuals``) w.r.t. the
    enabled scene nuisance parameters (module doc; K = ``len(scene_prior_std(conf))``).

    rows: ``projection.row_model(corr, conf)``; points_radar: (N, 3) the recorded points (metres,
    radar frame, z = 0). Rows of the ``zero`` model (no elevation arc) get no height columns.
    """
    p = np.asarray(points_radar, np.float64)
    n = len(p)
    r = np.maximum(np.linalg.norm(p[:, :2], axis=1), 1e-6)
    B = range_hats(r, conf.scene_knots_m)
    cols = []
    along_arc, radial = _directions(rows, p, r)
    if conf.scene_height_std_m > 0 or conf.scene_lateral_slope_std > 0:
        g_h = point_shift_jacobian(T_cam_radar, rows, along_arc)  # (N, 2) per metre of height
        if conf.scene_height_std_m > 0:
            cols.append(g_h[:, :, None] * B[:, None, :])
        if conf.scene_lateral_slope_std > 0:
            cols.append((g_h * p[:, 1:2])[:, :, None])
    if conf.scene_height_sq_std_m2 > 0:
        g_r = point_shift_jacobian(T_cam_radar, rows, radial)  # (N, 2) per metre of range
        cols.append(g_r[:, :, None] * (-B / (2.0 * r[:, None]))[:, None, :])
    return np.concatenate(cols, axis=2) if cols else np.zeros((n, 2, 0))


def scene_shift(rows: RowModel, points_radar: np.ndarray, conf: RadarPixelFactorConfig, c: np.ndarray) -> np.ndarray:
    """(N, 3) metres, radar frame: how the rows' modelled points move for the scene nuisance ``c`` (K,)
    (module doc; linear in ``c``, so ``scene_jacobian`` at ``p_bar + scene_shift`` is the exact
    derivative there). The factor itself uses ``c = 0``; this is the model the nuisance stands for."""
    p = np.asarray(points_radar, np.float64)
    c = np.asarray(c, np.float64).reshape(-1)
    n, k = len(p), len(conf.scene_knots_m)
    if len(c) != len(scene_prior_std(conf)):
        raise ValueError(f"scene_shift: expected {len(scene_prior_std(conf))} nuisance values, got {len(c)}")
    r = np.maximum(np.linalg.norm(p[:, :2], axis=1), 1e-6)
    B = range_hats(r, conf.scene_knots_m)
    dh, drho, i = np.zeros(n), np.zeros(n), 0
    if conf.scene_height_std_m > 0:
        dh, i = dh + B @ c[i:i + k], i + k
    if conf.scene_lateral_slope_std > 0:
        dh, i = dh + c[i] * p[:, 1], i + 1
    if conf.scene_height_sq_std_m2 > 0:
        drho = -(B @ c[i:i + k]) / (2.0 * r)
    along_arc, radial = _directions(rows, p, r)
    return along_arc * dh[:, None] + radial * drho[:, None]
