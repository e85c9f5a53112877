"""R1 / R2 starts: one definition, read back exactly by the error metrics."""

from __future__ import annotations

import numpy as np
import pytest

from hybrid_calib.errors import HybridCalibError
from hybrid_calib.metrics import signed_errors
from hybrid_calib.perturbation import RANGES, perturbation_bounds, perturbed_start, sample_perturbation
from tests.helpers import nominal_T_cam_radar


def test_ranges_of_the_paper_and_unknown_names():
    assert RANGES == {"R0": (2.0, 0.10), "R1": (10.0, 0.25), "R2": (20.0, 1.5)}
    assert perturbation_bounds("R2") == (20.0, 1.5)
    with pytest.raises(HybridCalibError, match="R3"):
        perturbation_bounds("R3")


@pytest.mark.parametrize("name", sorted(RANGES))
def test_start_is_the_sampled_perturbation(name):
    T = nominal_T_cam_radar()
    xi = sample_perturbation(np.random.default_rng(3), name)
    T0 = perturbed_start(T, np.random.default_rng(3), name)  # the same draws
    rot_deg, trans_m = RANGES[name]
    assert np.all(np.abs(np.degrees(xi[:3])) <= rot_deg) and np.all(np.abs(xi[3:]) <= trans_m)
    np.testing.assert_allclose(signed_errors(T0, T), xi, atol=1e-9)


@pytest.mark.parametrize("name", sorted(RANGES))
def test_perturbations_fill_their_range_on_both_sides(name):
    """Each axis uniform in [-bound, +bound]: both signs reached, centred (a one-sided draw passed the bound check)."""
    rot_deg, trans_m = perturbation_bounds(name)
    if rot_deg == 0 and trans_m == 0:
        return
    g = np.random.default_rng(0)
    xi = np.array([sample_perturbation(g, name) for _ in range(2000)])
    bound = np.array([np.radians(rot_deg)] * 3 + [trans_m] * 3)
    for a in range(6):
        if bound[a] == 0:
            continue
        assert xi[:, a].min() < -0.9 * bound[a] and xi[:, a].max() > 0.9 * bound[a], a
        assert abs(xi[:, a].mean()) < 0.05 * bound[a], a


def test_a_seeded_start_is_the_one_the_documented_figures_were_measured_from():
    """Probe 149 (mutation testing): swapping the draw order (three angles, then three offsets) changed every seeded
    start, and with it every seeded figure in docs/benchmarks.md, with every test passing. The stream is pinned: the
    (seed, vehicle) start and a plain generator's draw, to the last digit."""
    from hybrid_calib.perturbation import vehicle_rng

    np.testing.assert_allclose(sample_perturbation(vehicle_rng(7, "veh-a"), "R1"),
                               [-0.08866985, -0.08675271, 0.13202637, 0.15655725, 0.2398715, 0.0845887], atol=1e-8)
    np.testing.assert_allclose(sample_perturbation(np.random.default_rng(0), "R2"),
                               [0.0956173, -0.16071919, -0.32046093, -1.45041709, 0.93981072, 1.23826673], atol=1e-8)
