"""The consistency summary every command reports (``metrics.consistency``) and evaluate's per-axis block."""

from __future__ import annotations

import numpy as np
import pytest


def test_the_consistency_summary_of_known_nees():
    """Mutation probe 25: an inverted coverage (NEES above the bound counted inside) survived range checks only."""
    from hybrid_calib.metrics import consistency

    assert consistency([1.0, 2.0, 3.0, 30.0]) == {"n": 4, "nees_mean": 9.0, "nees_median": 2.5, "coverage_95": 0.75}
    assert consistency([]) == {"n": 0, "nees_mean": None, "nees_median": None, "coverage_95": None}


def test_the_95_percent_ellipsoid_is_the_chi_square_6_quantile():
    """Probe 73: the 5-dof quantile (11.07) in place of 12.59 read honest NEES as 91 % covered, and no test saw it
    (every NEES above sat far from the bound)."""
    from scipy.stats import chi2

    from hybrid_calib.metrics import CHI2_6_95, consistency

    assert CHI2_6_95 == pytest.approx(chi2.ppf(0.95, 6), rel=1e-12)
    assert consistency([11.5, 12.5, 12.7])["coverage_95"] == pytest.approx(2 / 3)
    honest = chi2.ppf((np.arange(2000) + 0.5) / 2000, 6)  # the quantiles of honest NEES
    assert consistency(honest)["coverage_95"] == pytest.approx(0.95, abs=1e-3)


def test_evaluates_per_axis_sigma_is_a_std_not_a_variance():
    from learned.evaluate import uncertainty_consistency

    u = uncertainty_consistency(np.zeros((2, 6)), np.stack([np.eye(6) * 1e-4] * 2))
    np.testing.assert_allclose(u["sigma_mean"], [np.degrees(0.01)] * 3 + [1.0] * 3)
    assert u["n"] == 2 and u["nees_mean"] == 0.0 and u["coverage_95"] == 1.0 and u["rmse"] == [0.0] * 6


def test_nees_refuses_a_covariance_that_is_not_positive():
    """A NEES of -3 read as inside the 95 % ellipsoid (probe 31). The reported std clips a negative variance to 0
    (raising there ended runs in "internal error" on a singular bound: probe 36)."""
    import pytest

    from hybrid_calib.calib.covariance import report_std
    from hybrid_calib.metrics import nees

    bad = np.diag([1.0, 1.0, -1.0, 1.0, 1.0, 1.0])
    with pytest.raises(ValueError, match="cov is not positive definite"):
        nees(np.array([0, 0, 1.0, 0, 0, 0]), bad)
    # an error that avoids the negative direction is refused too (probe 112: it read NEES 1.0)
    with pytest.raises(ValueError, match=r"cov is not positive definite \(estimate 1 of 2\)"):
        nees(np.array([[1.0, 0, 0, 0, 0, 0], [1.0, 0, 0, 0, 0, 0]]), np.stack([np.eye(6), bad]))
    assert nees(np.ones(6), np.eye(6)) == 6.0
    assert report_std(np.eye(4), bad)[2] == 0.0
    std = report_std(np.eye(4), np.diag([1e-4, 1e-4, -1e-20, 1e-4, 1e-4, 1e-4]))
    assert std[2] == 0.0 and np.isclose(std[3], 1.0)
