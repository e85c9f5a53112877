"""The consistency summary every command reports (``metrics.consistency``) and evaluate's per-axis block."""

from __future__ import annotations

import numpy as np


def test_the_consistency_summary_of_known_nees():
    """Mutation probe 25: an inverted coverage (NEES above the bound counted inside) survived range checks only."""
    from hybrid_calib.metrics import consistency

    assert consistency([1.0, 2.0, 3.0, 30.0]) == {"n": 4, "nees_mean": 9.0, "nees_median": 2.5, "coverage_95": 0.75}
    assert consistency([]) == {"n": 0, "nees_mean": None, "nees_median": None, "coverage_95": None}


def test_evaluates_per_axis_sigma_is_a_std_not_a_variance():
    from learned.evaluate import uncertainty_consistency

    u = uncertainty_consistency(np.zeros((2, 6)), np.stack([np.eye(6) * 1e-4] * 2))
    np.testing.assert_allclose(u["sigma_mean"], [np.degrees(0.01)] * 3 + [1.0] * 3)
    assert u["n"] == 2 and u["nees_mean"] == 0.0 and u["coverage_95"] == 1.0 and u["rmse"] == [0.0] * 6
