"""The one solver stack: the schedule's stage sequence (any back end), the Ceres back end driven by
the same ``ScheduleConfig``, and ``factors/`` kept below ``calib/``."""

from __future__ import annotations

import ast
from pathlib import Path

import numpy as np
import pytest

from factors.config import RadarPixelFactorConfig
from factors.synthetic import synthetic_correspondences
from hybrid_calib.calib.batch import solve_batch
from hybrid_calib.calib.schedule import ScheduleConfig, Stage, run_schedule
from hybrid_calib.geometry import local, perturb_camera_frame
from tests.helpers import nominal_T_cam_radar, rng


def _recording_solver(failure_at: int | None = None):
    """A stage solver that returns its start unchanged and records (n_rows, kernel, scale)."""
    calls = []

    def solve(frames, conf, T0):
        calls.append((sum(len(f) for f in frames), conf.kernel, conf.kernel_scale))
        return Stage(np.asarray(T0), 2, 1.0, None, "gave up" if len(calls) == failure_at else "")

    return solve, calls


@pytest.fixture(scope="module")
def frames():
    T = nominal_T_cam_radar()
    g = rng(31)
    return T, [synthetic_correspondences(T, n=30, rng=g, outlier_frac=0.2)[0] for _ in range(2)]


def test_schedule_stages_convex_then_kernel_then_gated_least_squares(frames):
    T, fr = frames
    sched = ScheduleConfig(convex_kernel="huber", convex_scale=0.9, final_gate=3.0)
    solve, calls = _recording_solver()
    last, iters = run_schedule(fr, T, RadarPixelFactorConfig(kernel="cauchy", kernel_scale=2.5), sched, solve)
    # the convex kernel and scale come from the ScheduleConfig; the gate keeps the inliers (about 48 of 60);
    # the start does not move, so the second gating gives the same sets and stops the loop
    assert calls[:2] == [(60, "huber", 0.9), (60, "cauchy", 2.5)]
    assert len(calls) == 3 and calls[2][1] == "none" and 40 <= calls[2][0] < 60, calls
    assert iters == 6 and np.array_equal(last.T, T)


@pytest.mark.parametrize("kernel,convex_start,gate,want", [
    ("none", True, 3.0, ["none"]),  # least squares: no convex stage, nothing to gate
    ("huber", True, 0.0, ["huber"]),  # the kernel is the convex one
    ("cauchy", False, 0.0, ["cauchy"]),  # warm start inside the basin
    ("cauchy", True, 0.0, ["huber", "cauchy"]),
])
def test_schedule_skips_stages_that_do_nothing(frames, kernel, convex_start, gate, want):
    T, fr = frames
    solve, calls = _recording_solver()
    run_schedule(fr, T, RadarPixelFactorConfig(kernel=kernel), ScheduleConfig(final_gate=gate), solve, convex_start)
    assert [c[1] for c in calls] == want


def test_schedule_stops_at_a_failed_stage(frames):
    T, fr = frames
    solve, calls = _recording_solver(failure_at=1)
    last, _ = run_schedule(fr, T, RadarPixelFactorConfig(), ScheduleConfig(), solve)
    assert len(calls) == 1 and last.failure == "gave up"


def test_ceres_batch_runs_the_same_schedule(frames, monkeypatch):
    """The Ceres back end gets each stage's kernel and scale from the ScheduleConfig (no kernel of its own)."""
    import factors.ceres_costs as cc

    T, fr = frames
    seen = []
    real = cc.solve_ceres_stage

    def spy(stage_frames, T0, conf, prior=None, max_iterations=50):
        seen.append((conf.kernel, conf.kernel_scale, max_iterations))
        return real(stage_frames, T0, conf, prior, max_iterations)

    monkeypatch.setattr(cc, "solve_ceres_stage", spy)
    T0 = perturb_camera_frame(T, np.radians([1.0, -1.0, 0.5]), [0.03, -0.03, 0.03])
    sched = {"convex_kernel": "huber", "convex_scale": 2.0, "max_iterations": 40}
    b = solve_batch(fr, T0, {"backend": "ceres", "schedule": sched})
    assert seen[:2] == [("huber", 2.0, 40), ("cauchy", 2.5, 40)] and seen[2][0] == "none", seen
    g = solve_batch(fr, T0, {"backend": "gtsam", "schedule": sched})
    assert b.iterations > 0 and not b.estimate.status.startswith("degenerate")
    sd = np.sqrt(np.diag(g.estimate.cov))
    assert np.all(np.abs(local(g.estimate.T, b.estimate.T)) < 1e-3 * sd)


def test_factors_do_not_import_calib():
    """``factors/`` is below ``calib/`` (docs: ARCHITECTURE.md): no solver or status of its own."""
    root = Path(__file__).resolve().parents[1] / "factors"
    bad = []
    for path in sorted(root.glob("*.py")):
        for node in ast.walk(ast.parse(path.read_text())):
            names = [a.name for a in node.names] if isinstance(node, ast.Import) else \
                [node.module or ""] if isinstance(node, ast.ImportFrom) else []
            bad += [f"{path.name}: {n}" for n in names if n.startswith("hybrid_calib.calib")]
    assert not bad, bad
    assert not (root / "solve.py").exists()
    import factors.config

    assert not hasattr(factors.config, "SolverConfig")  # one schedule: calib.schedule.ScheduleConfig


def test_a_row_behind_the_camera_never_fits():
    """Rows whose point lies behind the camera have no weight at T and must not count as fitting, however small their
    clamped residual (probe 74: the mask dropped, they counted in the window's fitting fractions and rescues)."""
    from factors.correspondences import Correspondences
    from hybrid_calib.calib.schedule import inlier_mask
    from tests.helpers import nominal_T_cam_radar, rng

    T = nominal_T_cam_radar()
    corr, _ = synthetic_correspondences(T, n=6, rng=rng(2), outlier_frac=0.0)
    conf = RadarPixelFactorConfig(elevation_model="zero")
    pts = corr.points_radar.copy()
    pts[0] = (np.array([0.0, 0.0, -3.0]) - T[:3, 3]) @ T[:3, :3]  # 3 m behind the camera, on its axis
    behind = Correspondences(pts, corr.pixels, corr.sigma_px, corr.confidence, corr.K)
    from factors.gtsam_factors import frame_residuals

    e = frame_residuals(T, behind, conf)[0].reshape(-1, 2)
    gate = 2.0 * np.linalg.norm(e, axis=1).max() + 1.0  # a gate every row's residual passes
    assert inlier_mask(T, behind, conf, gate).tolist() == [False] + [True] * 5
