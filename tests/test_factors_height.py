"""The ``height`` elevation model: per-row prior from the range, truncated-Gaussian moments, and the
exact equivalence of a common height offset with a radar-z translation."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.stats import truncnorm

from factors.config import RadarPixelFactorConfig
from factors.projection import height_elevation_prior, row_model, truncated_normal_moments, whitened_residuals
from factors.synthetic import synthetic_correspondences
from hybrid_calib.calib.batch import solve_batch
from hybrid_calib.geometry import local, se3_exp, transform_points
from tests.helpers import nominal_T_cam_radar, rng


@pytest.mark.parametrize("mu,sd,lo,hi", [(0.5, 2.0, -1.2, 1.2), (0.0, 1.0, -7.0, 7.0), (3.0, 0.5, -1.0, 1.0),
                                         (-0.4, 0.3, -0.6, 5.0)])
def test_truncated_normal_moments_match_scipy(mu, sd, lo, hi):
    m, s = truncated_normal_moments(mu, sd, np.array([lo]), np.array([hi]))
    a, b = (lo - mu) / sd, (hi - mu) / sd
    np.testing.assert_allclose(m[0], truncnorm.mean(a, b, loc=mu, scale=sd), rtol=1e-7, atol=1e-9)
    np.testing.assert_allclose(s[0], truncnorm.std(a, b, loc=mu, scale=sd), rtol=1e-6, atol=1e-9)


def test_truncated_normal_moments_window_without_mass():
    m, s = truncated_normal_moments(100.0, 0.1, np.array([-1.0]), np.array([1.0]))
    assert m[0] == 1.0 and 0 < s[0] <= 0.1


def test_height_prior_depends_on_range():
    conf = RadarPixelFactorConfig(elevation_model="height", reflector_height_mean_m=0.5, reflector_height_std_m=0.3)
    r = np.array([2.0, 5.0, 20.0, 80.0])
    phi, sig = height_elevation_prior(r, conf)
    beam = np.radians(conf.elevation_beam_deg)
    # far: the beam does not truncate: phi = asin(mu / r), sigma = sd / (r cos phi)
    np.testing.assert_allclose(phi[2:], np.arcsin(0.5 / r[2:]), rtol=1e-6)
    np.testing.assert_allclose(sig[2:], 0.3 / (r[2:] * np.cos(phi[2:])), rtol=1e-6)
    # near: the beam truncates the heights, the elevation stays inside it and sigma is capped
    assert np.all(np.abs(phi) <= beam) and np.all(sig <= beam / np.sqrt(3) + 1e-12)
    assert np.all(np.diff(sig[1:]) < 0)  # the same height spread is a smaller angle further away


def test_row_model_height_is_the_expected_point_with_the_arc_tangent():
    """p_bar = E[p(phi)] under the truncated height distribution (Monte Carlo), dp the arc tangent."""
    T = nominal_T_cam_radar()
    corr, _ = synthetic_correspondences(T, n=30, rng=rng(3), outlier_frac=0.0)
    conf = RadarPixelFactorConfig(elevation_model="height", reflector_height_mean_m=0.5, reflector_height_std_m=2.0)
    rows = row_model(corr, conf)
    p = corr.points_radar
    r = np.linalg.norm(p[:, :2], axis=1)
    phi, sig = height_elevation_prior(r, conf)
    g = rng(6)
    beam = np.radians(conf.elevation_beam_deg)
    for i in range(0, 30, 6):
        lo, hi = -r[i] * np.sin(beam), r[i] * np.sin(beam)
        h = truncnorm.rvs((lo - 0.5) / 2.0, (hi - 0.5) / 2.0, loc=0.5, scale=2.0, size=200_000, random_state=g)
        c = np.sqrt(1 - (h / r[i]) ** 2)
        mc = np.array([p[i, 0] * c.mean(), p[i, 1] * c.mean(), h.mean()])
        np.testing.assert_allclose(rows.p_bar[i], mc, atol=5 * h.std() / np.sqrt(len(h)) + 2e-4)
    np.testing.assert_allclose(rows.p_bar[:, 2], r * np.sin(phi), rtol=1e-12)
    tangent = np.stack([-p[:, 0] * np.sin(phi), -p[:, 1] * np.sin(phi), r * np.cos(phi)], 1)
    np.testing.assert_allclose(rows.dp, tangent, rtol=1e-12)
    np.testing.assert_allclose(rows.kappa, rows.w * sig, rtol=1e-12)


def test_common_height_offset_is_a_radar_z_translation():
    """p + dh e_z seen through T == p seen through T Exp([0, dh e_z]) (exact), so shifting the
    assumed mean height by dh moves the estimate along radar z by -dh and nothing else."""
    T = nominal_T_cam_radar()
    g = rng(11)
    P = g.normal(size=(20, 3)) * [5, 3, 0.5] + [20, 0, 0]
    dh = 0.37
    xi = np.array([0, 0, 0, 0, 0, dh])
    np.testing.assert_allclose(transform_points(T, P + [0, 0, dh]), transform_points(T @ se3_exp(xi), P), atol=1e-12)
    frames = [synthetic_correspondences(T, n=80, rng=g, outlier_frac=0.0, height_m=(0.3, 0.4),
                                        range_m=(15.0, 60.0))[0] for _ in range(3)]
    est = {}
    for mu in (0.3, 0.3 + dh):
        conf = RadarPixelFactorConfig(kernel="none", elevation_model="height", reflector_height_mean_m=mu,
                                      reflector_height_std_m=0.4)
        est[mu] = solve_batch(frames, T, {"factor": conf}).estimate.T
    d = local(est[0.3], est[0.3 + dh])
    assert abs(d[5] + dh) < 0.1 * dh, d
    assert np.all(np.abs(d[:3]) < np.radians(0.05)) and np.all(np.abs(d[3:5]) < 0.02), d


def test_height_model_is_consistent_on_height_data():
    """Data with heights drawn from the height model: the height model's covariance is consistent
    (NEES near 6 over seeds; its mean height is known here, so no offset inflation is involved) and
    its pixel residuals at the truth are whitened (unit variance)."""
    T = nominal_T_cam_radar()
    nees, e2 = [], []
    # the mean height is known: no prior-pinned inflation of radar z / pitch (docs/conventions.md)
    conf = RadarPixelFactorConfig(elevation_model="height", reflector_height_mean_m=0.5, reflector_height_std_m=0.8,
                                  reflector_height_mean_std_m=0.0, reflector_tilt_std_deg=0.0)
    for seed in range(6):
        g = rng(400 + seed)
        frames = [synthetic_correspondences(T, n=60, rng=g, outlier_frac=0.0, height_m=(0.5, 0.8))[0]
                  for _ in range(3)]
        res = solve_batch(frames, T, {"factor": conf}).estimate
        xi = local(res.T, T)
        nees.append(xi @ np.linalg.solve(res.cov, xi))
        e, _, _ = whitened_residuals(T, row_model(frames[0], conf))
        e2.append(np.mean(e**2))
    assert 2.0 < np.mean(nees) < 12, nees
    assert 0.7 < np.mean(e2) < 1.4, e2
