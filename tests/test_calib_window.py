"""Sliding window vs batch, recovery from R1/R2 starts, GTSAM vs Ceres, small consistency check."""

import numpy as np
import pytest

from hybrid_calib.calib.batch import solve_batch
from hybrid_calib.calib.covariance import report_std
from hybrid_calib.calib.oracle import synthetic_drive
from hybrid_calib.calib.schedule import GaussianPrior
from hybrid_calib.calib.window import (
    SlidingWindowCalibrator,
    convergence_note,
    needs_relinearisation,
    random_walk_information,
)
from hybrid_calib.geometry import local, perturb_camera_frame, retract
from hybrid_calib.metrics import extrinsic_error
from tests.helpers import nominal_T_cam_radar, rng


def _start(g, rot_deg, trans_m):
    T = nominal_T_cam_radar()
    return perturb_camera_frame(T, np.radians(g.uniform(-rot_deg, rot_deg, 3)), g.uniform(-trans_m, trans_m, 3))


def test_window_matches_batch_on_small_drive():
    T = nominal_T_cam_radar()
    frames, _ = synthetic_drive(T, 12, rng(1))
    T0 = _start(rng(2), 10, 0.25)
    cal = SlidingWindowCalibrator(T0, {"window": 4, "detect_steps": False})
    outs = [cal.update(f) for f in frames]
    batch = solve_batch(frames, T0)
    d = local(batch.estimate.T, outs[-1].T)
    # agreement well inside the batch's own uncertainty (marginalisation is a linearisation)
    z = d / np.sqrt(np.diag(batch.estimate.cov))
    assert np.all(np.abs(z) < 0.3), z
    np.testing.assert_allclose(np.diag(outs[-1].cov), np.diag(batch.estimate.cov), rtol=0.05)
    assert outs[-1].n_total == 12 and outs[-1].n_window == 4
    # the std grows tighter as frames arrive
    assert outs[-1].estimate.std[0] < outs[0].estimate.std[0]


@pytest.mark.parametrize("rot_deg,trans_m,seed", [(10, 0.25, 3), (20, 1.5, 4), (20, 1.5, 5)])
def test_recovery_from_r1_r2_starts(rot_deg, trans_m, seed):
    T = nominal_T_cam_radar()
    frames, _ = synthetic_drive(T, 6, rng(seed))
    T0 = _start(rng(seed + 100), rot_deg, trans_m)
    assert extrinsic_error(T0, T).rot_mean_deg > 2.0
    uniform = {"elevation_model": "anisotropic"}  # the synthetic elevations are uniform in the beam
    cal = SlidingWindowCalibrator(T0, {"window": 6, "detect_steps": False, "factor": uniform})
    for f in frames:
        out = cal.update(f)
    e = extrinsic_error(out.T, T)
    assert e.rot_mean_deg < 0.15 and e.trans_norm_cm < 15, e
    b = solve_batch(frames, T0, {"factor": uniform}).estimate
    eb = extrinsic_error(b.T, T)
    assert eb.rot_mean_deg < 0.15 and eb.trans_norm_cm < 15, eb


def test_gtsam_and_ceres_batch_agree():
    T = nominal_T_cam_radar()
    frames, _ = synthetic_drive(T, 2, rng(6), {"n_per_frame": 40})
    T0 = _start(rng(7), 5, 0.2)
    g = solve_batch(frames, T0, {"backend": "gtsam"}).estimate
    c = solve_batch(frames, T0, {"backend": "ceres"}).estimate
    sd = np.sqrt(np.diag(g.cov))
    assert np.all(np.abs(local(g.T, c.T)) < 1e-3 * sd + 1e-9)
    np.testing.assert_allclose(c.cov, g.cov, rtol=1e-3, atol=1e-3 * np.abs(g.cov).max())


def test_prior_input_tightens_the_estimate():
    T = nominal_T_cam_radar()
    frames, _ = synthetic_drive(T, 1, rng(8))
    prior = GaussianPrior(T, np.diag([np.radians(0.01) ** 2] * 3 + [0.001**2] * 3))
    a = SlidingWindowCalibrator(T, {"detect_steps": False}).update(frames[0])
    b = SlidingWindowCalibrator(T, {"detect_steps": False}).update(frames[0], prior=prior)
    assert np.all(b.estimate.std < a.estimate.std)
    assert np.all(b.estimate.std < report_std(T, prior.cov) * 1.001)
    # the batch adds the prior's information, not its covariance (probe 73: summing covariances left the batch's
    # std at the rows' alone, and with the height model the status "weak": prior-pinned, while the prior pinned them)
    c = solve_batch(frames, T, priors=[prior]).estimate
    assert np.all(c.std < report_std(T, prior.cov) * 1.001), (c.std, report_std(T, prior.cov))


def test_consistency_small_monte_carlo():
    """30 runs x 3 frames, 20 % gross outliers: the final error inside the 95 % ellipsoid of the
    reported covariance in a loose band around 95 %, mean NEES near 6."""
    T = nominal_T_cam_radar()
    nees = []
    for r in range(30):
        g = rng(1000 + r)
        frames, _ = synthetic_drive(T, 3, g)
        cal = SlidingWindowCalibrator(_start(g, 10, 0.25), {"window": 3, "detect_steps": False})
        for f in frames:
            out = cal.update(f)
        e = local(T, out.T)
        nees.append(float(e @ np.linalg.solve(out.cov, e)))
    nees = np.array(nees)
    inside = np.mean(nees < 12.592)  # chi2(6) 95 % quantile
    assert 0.8 <= inside <= 1.0, (inside, nees)
    assert 3.5 < nees.mean() < 9.0, nees.mean()


def test_update_rejects_bad_input():
    cal = SlidingWindowCalibrator(nominal_T_cam_radar())
    with pytest.raises(TypeError, match="Correspondences"):
        cal.update(np.zeros((3, 3)))
    with pytest.raises(ValueError, match="T_init"):
        SlidingWindowCalibrator(np.eye(3))


def test_a_random_walk_refuses_a_frame_from_before_the_previous_one():
    """With a random walk, a timestamp that went backwards was read as one default step without a word (probe 31);
    the frame is refused (the calibrator as before it) and the stream goes on. Without a walk time order is free."""
    T = nominal_T_cam_radar()
    frames, _ = synthetic_drive(T, 3, rng(7))
    walk = SlidingWindowCalibrator(T, {"random_walk_rot_deg_per_sqrt_s": 0.01, "detect_steps": False})
    walk.update(frames[0], timestamp_us=2_000_000)
    with pytest.raises(ValueError, match=r"timestamp 1000000 us is 1.000 s before the previous frame's .* time order"):
        walk.update(frames[1], timestamp_us=1_000_000)
    assert walk.update(frames[1], timestamp_us=2_500_000).n_total == 2
    still = SlidingWindowCalibrator(T, {"detect_steps": False})
    still.update(frames[0], timestamp_us=2_000_000)
    assert still.update(frames[1], timestamp_us=1_000_000).n_total == 2


def test_needs_relinearisation_thresholds_and_missing_points():
    T = nominal_T_cam_radar()
    near = retract(T, np.array([np.radians(0.05), 0, 0, 0.01, 0, 0]))
    far_rot = retract(T, np.array([0, np.radians(0.2), 0, 0, 0, 0]))
    far_trans = retract(T, np.array([0, 0, 0, 0, 0.03, 0]))
    assert not needs_relinearisation([], T, 0.1, 2.0)
    assert not needs_relinearisation([near, near], T, 0.1, 2.0)
    assert needs_relinearisation([near, None], T, 0.1, 2.0)
    assert needs_relinearisation([near, far_rot], T, 0.1, 2.0)
    assert needs_relinearisation([far_trans], T, 0.1, 2.0) and not needs_relinearisation([far_trans], T, 0.1, 5.0)


def test_random_walk_information_widens_the_covariance():
    g = rng(12)
    A = g.normal(size=(6, 6))
    L = A @ A.T + np.eye(6)
    Q = np.diag([1e-4] * 3 + [1e-3] * 3)
    out = random_walk_information(L, Q)
    np.testing.assert_allclose(np.linalg.inv(out), np.linalg.inv(L) + Q, rtol=1e-6)
    np.testing.assert_allclose(random_walk_information(L, np.zeros((6, 6))), L, rtol=1e-6)
    assert np.allclose(out, out.T)
    # the window's process noise from its options, in the documented units (deg and cm per sqrt(s); probe 73: the
    # rotation read as radians survived, the default being 0)
    cal = SlidingWindowCalibrator(nominal_T_cam_radar(), {"random_walk_rot_deg_per_sqrt_s": 0.01,
                                                          "random_walk_trans_cm_per_sqrt_s": 2.0})
    np.testing.assert_allclose(cal._q(4.0), np.diag([np.radians(0.01) ** 2 * 4] * 3 + [0.02 ** 2 * 4] * 3), rtol=1e-12)


def test_convergence_note():
    assert convergence_note(0.25, 0.25) == ""
    assert convergence_note(0.1, 0.25).startswith("NOT CONVERGED: only 10 %")


def test_window_solve_changes_nothing_until_adopted():
    T = nominal_T_cam_radar()
    frames, _ = synthetic_drive(T, 3, rng(13))
    T0 = _start(rng(14), 5, 0.2)
    cal = SlidingWindowCalibrator(T0, {"window": 3, "detect_steps": False})
    for f in frames:
        cal.update(f)
    before_T, before_lin = cal.T.copy(), [fr.lin for fr in cal.frames]
    res, lins = cal._solve_window(T0, convex=True)
    assert np.array_equal(cal.T, before_T) and all(fr.lin is b for fr, b in zip(cal.frames, before_lin))
    assert len(lins) == 3 and all(lin.T_lin is lins[0].T_lin for lin in lins)  # one shared linearisation point
    cal._adopt(res, lins)
    assert np.array_equal(cal.T, res.T) and [fr.lin for fr in cal.frames] == lins


def test_far_start_is_rescued_from_the_initial_extrinsic():
    """A 40 deg / 3 m start: the convex-start solve of one frame of 25 rows diverges (4 % of the rows fit). The
    window is re-solved from the start without the convex stage, and with it from the initial extrinsic, and the
    solve that fits most rows is kept (before: the frame stayed NOT CONVERGED until the next one)."""
    T = nominal_T_cam_radar()
    frames, _ = synthetic_drive(T, 3, rng(7), {"n_per_frame": 25})
    g = rng(602)
    T0 = perturb_camera_frame(T, np.radians(g.uniform(-40, 40, 3)), g.uniform(-3, 3, 3))
    cal = SlidingWindowCalibrator(T0, {"window": 5})
    outs = [cal.update(f) for f in frames]
    assert outs[0].events and outs[0].events[0].startswith("not converged (inlier fraction 0.0")
    assert outs[0].inlier_fraction > 0.5 and "NOT CONVERGED" not in outs[0].status
    assert extrinsic_error(outs[-1].T, T).rot_mean_deg < 0.5


@pytest.mark.parametrize("seed,how", [(630, "re-solved progressively"),
                                      (628, "re-solved from the sliding window's estimate")])
def test_a_batch_in_a_wrong_basin_is_re_solved_progressively_or_from_the_window(seed, how):
    """A 40 deg / 3 m start: the batch solved on all frames at once can end where almost no row fits.
    Then it re-solves progressively (1, 4, then all frames) and, when the first frames alone settle wrong
    too (seed 628; a 5-frame urban drive of real reflector heights ended 66 deg off), from the sliding
    window's estimate, keeping what fits more rows."""
    T = nominal_T_cam_radar()
    frames, _ = synthetic_drive(T, 8, rng(7), {"n_per_frame": 25})
    g = rng(seed)
    T0 = perturb_camera_frame(T, np.radians(g.uniform(-40, 40, 3)), g.uniform(-3, 3, 3))
    direct = solve_batch(frames, T0, {"min_inlier_fraction": 0.0})  # the guard off: as before
    assert direct.inlier_fraction < 0.25 and extrinsic_error(direct.estimate.T, T).rot_mean_deg > 20
    assert "NOT CONVERGED" not in direct.estimate.status  # nothing told the user
    b = solve_batch(frames, T0)
    assert b.inlier_fraction > 0.7 and extrinsic_error(b.estimate.T, T).rot_mean_deg < 0.5
    assert how in b.estimate.status and "NOT CONVERGED" not in b.estimate.status


def test_a_batch_nothing_fits_says_not_converged():
    """Rows of no geometry (every one a gross outlier): no re-solve finds a fit, and the status says NOT CONVERGED
    (the report's verdict: inconclusive)."""
    T = nominal_T_cam_radar()
    frames, _ = synthetic_drive(T, 6, rng(7), {"n_per_frame": 25, "outlier_frac": 1.0})
    b = solve_batch(frames, perturb_camera_frame(T, np.radians([3.0, -2.0, 4.0]), [0.1, 0.0, -0.1]))
    assert b.inlier_fraction < 0.25 and "NOT CONVERGED: only" in b.estimate.status


def test_the_batch_s_fitting_fraction_counts_rows_not_frames():
    """One frame of many rows that fit and three small frames of outliers: most of the drive's rows fit, so no
    re-solve and no NOT CONVERGED (the mean of per-frame fractions read 24 % here: probe 28)."""
    T = nominal_T_cam_radar()
    good, _ = synthetic_drive(T, 1, rng(7), {"n_per_frame": 300, "outlier_frac": 0.0})
    bad, _ = synthetic_drive(T, 3, rng(8), {"n_per_frame": 5, "outlier_frac": 1.0})
    b = solve_batch(good + bad, perturb_camera_frame(T, np.radians([0.5, -0.5, 0.5]), [0.02, 0.0, -0.02]))
    assert b.inlier_fraction > 0.85 and "NOT CONVERGED" not in b.estimate.status
    assert extrinsic_error(b.estimate.T, T).rot_mean_deg < 0.5


def test_a_knocked_sensor_never_pulls_the_window_into_a_basin_only_the_new_frames_support(tmp_path):
    """Measured on a simulated urban drive with a 1.5 deg / 1 deg knock at frame 6: a convex start jumped to 83 deg
    with 7 % of frame 2 fitting (and came back), and after the knock the rescue kept a 72 deg / 48 m estimate that
    fitted 8 % of the new frame, to the drive's end, with a 1-sigma of ~1 deg. Now the rescue keeps what fits most
    rows of the window: frame 2 is re-solved from the previous estimate, and after the knock (too few frames for the
    step detector) the estimate stays at the mount before it, said NOT CONVERGED."""
    import json

    from hybrid_calib.calib.pipeline import calibrate
    from hybrid_calib.config import merge
    from hybrid_calib.sim.drive import SimConfig
    from hybrid_calib.sim.simulate import simulate

    conf = merge(SimConfig, {"vehicles": 1, "frames": 12, "seed": 3, "image_scale": 0.125,
                             "extrinsic_change": {"kind": "step", "frame": 6}})
    root = simulate(conf, tmp_path / "sim", progress=False)
    run = calibrate(root, "v1.0-sim", "oracle", tmp_path / "out", {"start": "R1"})
    vr = next(iter(run.vehicles.values()))
    assert vr.error["geodesic_deg"] < 5, vr.error  # was 71.5 deg (the knock itself is ~1.8 deg)
    assert "NOT CONVERGED" in vr.final.status and "cannot tell" in vr.drift["verdict"]
    assert all(json.dumps(list(f.events)).count("not converged") <= 1 for f in vr.trajectory)
    # the true mount moved at frame 6: each frame is scored against its own (probe 54: the plots scored every frame
    # against the end's, the knock drawn as an error of the frames before it)
    from hybrid_calib.calib.result import CalibrationRun, truth_at
    from hybrid_calib.hybrid.drives import _truth_path
    from hybrid_calib.metrics import signed_errors
    from hybrid_calib.plots.calibration import trajectory_errors
    from learned.dataset import open_frames

    (k0, T0), (k1, T1) = vr.truth_path
    assert (k0, k1) == (0, 6) and np.allclose(T1, vr.truth_T) and not np.allclose(T0, T1, atol=1e-3)
    assert truth_at(vr, 5) is T0 and truth_at(vr, 6) is T1 and truth_at(vr, 11) is T1
    err = trajectory_errors(vr)
    first = vr.trajectory[0]
    np.testing.assert_allclose(np.radians(err[0, :3]), signed_errors(first.T, T0)[:3], atol=1e-12)
    back = next(iter(CalibrationRun.load(tmp_path / "out" / "result.json").vehicles.values()))
    assert [k for k, _ in back.truth_path] == [0, 6] and np.allclose(back.truth_path[0][1], T0)
    frames = open_frames(root, "v1.0-sim", lidar=False)
    (vehicle, idx), = frames.frames_by_vehicle().items()
    assert [k for k, _ in _truth_path(frames, idx)] == [0, 6]  # the learned methods' drives say the same


def test_a_first_solve_that_left_the_starts_basin_is_solved_again_locally(tmp_path):
    """Probe 54 (oracle rows, R1 start): frame 0 solved 74 deg from the truth with 29 % of its rows fitting, and from
    a good frame-1 estimate frame 2 solved 26 deg away with 28 % fitting, each under a "weak" status and a tight
    covariance (the 25 % rule did not see them). A convex-start update whose frame fits less than half its rows is
    solved again locally from the previous estimate and the start, and the solve that fits most rows is kept."""
    from hybrid_calib.calib.pipeline import calibrate
    from hybrid_calib.calib.result import truth_at
    from hybrid_calib.config import merge
    from hybrid_calib.metrics import extrinsic_error
    from hybrid_calib.sim.drive import SimConfig
    from hybrid_calib.sim.simulate import simulate

    conf = merge(SimConfig, {"vehicles": 1, "frames": 4, "seed": 3, "image_scale": 0.25})
    run = calibrate(simulate(conf, tmp_path / "sim", progress=False), "v1.0-sim", "oracle", tmp_path / "out",
                    {"start": "R1"}, progress=False)
    vr = next(iter(run.vehicles.values()))
    err = [extrinsic_error(f.T, truth_at(vr, f.index)).geodesic_deg for f in vr.trajectory]
    assert max(err) < 3, err  # was 74.3 and 26.4 deg at frames 0 and 2
    assert "(inlier fraction 0.29 after a convex start from 1 frame(s)): re-solved the window locally" in \
        vr.trajectory[0].events[0]


def test_a_start_on_rows_alone_that_fits_less_than_half_of_them_is_not_converged():
    """Probe 58 (oracle rows, R2 starts): frame 0 ended 38-54 deg off with 30-32 % of its rows fitting, a plain "weak"
    and a degree-level std (the 25 % rule's NOT CONVERGED needs fewer). In the convex start on rows alone, a frame
    fitting fewer than convex_check_fraction of its rows is not converged; later frames, or a start with a prior,
    keep the 25 % rule."""
    from factors.correspondences import Correspondences
    from hybrid_calib.calib.oracle import synthetic_drive
    from hybrid_calib.calib.schedule import GaussianPrior
    from hybrid_calib.geometry import perturb_camera_frame
    from tests.helpers import nominal_T_cam_radar, rng

    T = nominal_T_cam_radar()
    frames, _ = synthetic_drive(T, 5, rng(1))
    g = np.random.default_rng(0)

    def spoil(c):  # 60 % of the rows gross outliers: the right answer fits ~30-40 %
        px = c.pixels.copy()
        idx = g.choice(len(c), int(0.6 * len(c)), replace=False)
        px[idx] = g.uniform([0, 0], [1600, 900], (len(idx), 2))
        return Correspondences(c.points_radar, px, c.sigma_px, c.confidence, c.K, c.frame_id, c.timestamp_us)

    bad = [spoil(c) for c in frames]
    T0 = perturb_camera_frame(T, np.radians([1.0, -1.0, 1.5]), [0.05, -0.03, 0.04])
    cal = SlidingWindowCalibrator(T0, {"detect_steps": False})
    said = [("NOT CONVERGED" in (e := cal.update(c)).status, e.inlier_fraction) for c in bad]
    assert [s for s, _ in said] == [True, True, True, False, False], said
    assert all(0.25 < f < 0.5 for _, f in said)
    prior = GaussianPrior(T0, np.diag([np.radians(2.0) ** 2] * 3 + [0.1 ** 2] * 3))
    with_prior = SlidingWindowCalibrator(T0, {"detect_steps": False}).update(bad[0], prior=prior)
    assert "NOT CONVERGED" not in with_prior.status


def test_an_alarm_frame_that_fits_nothing_after_the_restart_is_not_converged(monkeypatch):
    """Probe 58: after a step alarm, the alarm frame's estimate was 56-68 deg off with 0-5 % of its rows fitting and
    its status said "recovering after a step change" alone (the restart dropped the 25 % rule's note)."""
    from factors.correspondences import Correspondences
    from hybrid_calib.calib.drift import StepOutcome, StepTest
    from hybrid_calib.calib.oracle import synthetic_drive
    from tests.helpers import nominal_T_cam_radar, rng

    T = nominal_T_cam_radar()
    frames, _ = synthetic_drive(T, 6, rng(1))
    g = np.random.default_rng(0)
    c = frames[5]
    junk = Correspondences(c.points_radar, g.uniform([0, 0], [1600, 900], c.pixels.shape), c.sigma_px, c.confidence,
                           c.K, "junk", c.timestamp_us)  # rows no mount fits
    cal = SlidingWindowCalibrator(T, {"detect_steps": True})
    for f in frames[:5]:
        cal.update(f)
    monkeypatch.setattr(cal, "_test_step", lambda inl: StepOutcome(StepTest(99.0, 27.9, True, True), T))
    e = cal.update(junk)
    assert e.step_alarm and e.inlier_fraction < 0.25
    assert "recovering after a step change" in e.status and "NOT CONVERGED" in e.status, e.status


@pytest.mark.parametrize("key,value,words", [
    ("min_inlier_fraction", 2.0, "0 <= min_inlier_fraction <= 1"),  # made every good solve "NOT CONVERGED"
    ("random_walk_rot_deg_per_sqrt_s", -1.0, "random_walk_rot_deg_per_sqrt_s >= 0"),  # silently read as 0
    ("default_dt_s", 0.0, "default_dt_s > 0"),
    ("convex_frames", -1, "convex_frames >= 0"),
    ("relinearize_trans_cm", float("nan"), "finite numbers"),
])
def test_window_options_no_window_can_have_are_refused(key, value, words):
    from hybrid_calib.calib.window import WindowConfig

    with pytest.raises(ValueError, match=words.replace("(", r"\(")):
        WindowConfig(**{key: value})


def test_the_progressive_re_solve_starts_each_stage_at_the_previous_optimum(monkeypatch):
    """What the status says of it ("each from the previous optimum"); probe 74: every stage from the first start
    passed every test."""
    from hybrid_calib.calib import batch

    starts, ends = [], []

    def solve(frames, T, conf, priors, covariance=True):
        starts.append(T)
        ends.append(retract(T, np.full(6, 0.01 * len(frames))))
        return ends[-1], None, None, None, 2, 0.5, None

    monkeypatch.setattr(batch, "_solve", solve)
    T0 = nominal_T_cam_radar()
    T, iters, secs = batch._progressive_start([None] * 20, T0, batch.BatchConfig(), None)
    assert len(starts) == 3 and starts[0] is T0 and starts[1] is ends[0] and starts[2] is ends[1] and T is ends[2]
    assert (iters, secs) == (6, 1.5)


def test_an_ill_conditioned_history_still_gives_a_prior():
    """Probe 95: tables 180 deg off on a highway drive: the history's information spanned ~1e13 with a free
    direction, np.linalg.inv of it gave an indefinite covariance, and the run ended on "covariance is not positive
    definite" (no result for either vehicle). Inverted in its eigenbasis, every such history is a prior; a
    well-conditioned one is inverted as before."""
    g = rng(7)
    for _ in range(300):
        Q, _ = np.linalg.qr(g.normal(size=(6, 6)))
        w = 10.0 ** g.uniform(-2, 13, 6)
        w[g.integers(6)] = 0.0
        prior = SlidingWindowCalibrator._as_prior((g.normal(size=6), (Q * w) @ Q.T), np.eye(4))
        assert np.linalg.eigvalsh(prior.cov).min() > 0
    A = g.normal(size=(6, 6))
    H, G = 100.0 * A @ A.T, g.normal(size=6)
    prior = SlidingWindowCalibrator._as_prior((G, H), np.eye(4))
    np.testing.assert_allclose(prior.cov, np.linalg.inv(H + 1e-8 * np.eye(6)), rtol=1e-8, atol=1e-14)
    np.testing.assert_allclose(local(np.eye(4), prior.T), -np.linalg.solve(H + 1e-8 * np.eye(6), G), atol=1e-9)
