"""The Python API meets bad input as the command line does (probe 31): a clear ``ValueError`` naming the argument,
never a numpy traceback, a confident answer from a broken covariance, a frame counted twice, or a calibrator that a
rejected frame leaves broken."""

import dataclasses

import numpy as np
import pytest

from factors.correspondences import Correspondences, repeated_frames
from hybrid_calib.calib.batch import solve_batch
from hybrid_calib.calib.drift import reference_test
from hybrid_calib.calib.oracle import synthetic_drive
from hybrid_calib.calib.window import SlidingWindowCalibrator
from hybrid_calib.geometry import local, perturb_camera_frame
from hybrid_calib.metrics import extrinsic_error, nees
from tests.helpers import nominal_T_cam_radar, rng

WINDOW = {"window": 4, "detect_steps": False}


def _drive(n=8):
    T = nominal_T_cam_radar()
    frames, _ = synthetic_drive(T, n, rng(1))
    return T, frames, perturb_camera_frame(T, np.radians([1.0, -1.0, 1.5]), [0.05, -0.03, 0.04])


def _copy(c: Correspondences, frame_id: str, ts: int) -> Correspondences:
    return Correspondences(c.points_radar, c.pixels, c.sigma_px, c.confidence, c.K, frame_id, ts)


def test_a_frame_whose_update_fails_costs_only_itself(monkeypatch):
    """The frame was pushed into the window before its solve: after one failure the next 20 good frames failed."""
    import hybrid_calib.calib.window as window

    T, frames, T0 = _drive()
    clean = SlidingWindowCalibrator(T0, WINDOW)
    want = [clean.update(f) for f in frames]
    cal = SlidingWindowCalibrator(T0, WINDOW)
    for f in frames[:3]:
        cal.update(f)
    real, calls = window.robust_solve, []

    def failing(*a, **k):
        calls.append(1)
        raise np.linalg.LinAlgError("Eigenvalues did not converge")

    monkeypatch.setattr(window, "robust_solve", failing)
    with pytest.raises(np.linalg.LinAlgError):
        cal.update(_copy(frames[3], "bad", frames[3].timestamp_us))
    assert calls and [fr.corr.frame_id for fr in cal.frames] == [f.frame_id for f in frames[:3]]
    monkeypatch.setattr(window, "robust_solve", real)
    got = [cal.update(f) for f in frames[3:]]  # as if the failed frame had never come
    np.testing.assert_allclose(got[-1].T, want[-1].T, atol=1e-12)
    np.testing.assert_allclose(got[-1].cov, want[-1].cov, rtol=1e-9, atol=1e-15)
    assert got[-1].n_total == want[-1].n_total


def test_a_repeated_frame_is_not_counted_as_a_second_measurement(tmp_path):
    """20 copies of one frame: the estimate stayed, the std shrank as 1/sqrt(20): NEES 62."""
    T, frames, T0 = _drive()
    copies = [_copy(frames[0], f"copy{k}", 1000 * k) for k in range(5)]
    assert repeated_frames([frames[1], *copies, frames[2]]) == {2: 1, 3: 1, 4: 1, 5: 1}
    with pytest.raises(ValueError, match="4 of the 5 frames repeat .* frame copy1 repeats the rows of frame copy0"):
        solve_batch(copies, T0)
    cal = SlidingWindowCalibrator(T0, WINDOW)
    first = cal.update(copies[0])
    with pytest.raises(ValueError, match="frame copy1 repeats the rows of frame copy0 \\(the same radar points"):
        cal.update(copies[1])
    assert cal.update(frames[1]).n_total == 2  # the refused copy left nothing behind
    assert first.n_total == 1
    # the command line's pipeline leaves repeats out and lists them
    from hybrid_calib.calib.pipeline import CalibrateConfig, VehicleInput, calibrate_vehicle

    vi = VehicleInput("veh", [frames[1], *copies], truth=[T] * 6, reference=T)
    from hybrid_calib.config import merge

    res = calibrate_vehicle(vi, merge(CalibrateConfig, {"start": "reference", "window": WINDOW}), progress=False)
    assert res.n_frames == 2 and len(res.trajectory) == 2
    assert [s["token"] for s in res.skipped] == [f"copy{k}" for k in range(1, 5)]
    assert all("repeats the rows of frame copy0" in s["reason"] for s in res.skipped)


def test_a_nudged_replay_and_doubled_rows_are_one_measurement():
    """Probe 51: a replay nudged by 1e-6 px, or every row doubled inside a frame, passed as new measurements and
    shrank the std; pixels that moved by their own noise are another measurement of the same points."""
    from hybrid_calib.calib.pipeline import CalibrateConfig, VehicleInput, calibrate_vehicle
    from hybrid_calib.config import merge

    T, frames, T0 = _drive()
    c = frames[0]
    rng = np.random.default_rng(0)
    order = rng.permutation(len(c))
    nudged = Correspondences(c.points_radar[order] + 1e-6, c.pixels[order] + 1e-6, c.sigma_px[order],
                             c.confidence[order], c.K, "nudged", c.timestamp_us + 1)
    assert nudged.repeats(c) and c.repeats(nudged) and repeated_frames([c, nudged]) == {1: 0}
    noisy = Correspondences(c.points_radar, c.pixels + rng.normal(0, 1, c.pixels.shape) * c.sigma_px[:, None],
                            c.sigma_px, c.confidence, c.K, "noisy")
    assert not noisy.repeats(c) and repeated_frames([c, noisy]) == {}
    twice = Correspondences(np.vstack([c.points_radar, c.points_radar + 1e-7]), np.vstack([c.pixels, c.pixels]),
                            np.r_[c.sigma_px, c.sigma_px], np.r_[c.confidence, c.confidence], c.K, "twice")
    n = len(c)
    assert twice.doubled_rows() == [(n + i, i) for i in range(n)] and c.doubled_rows() == []
    assert len(twice.once()) == n and twice.repeats(c)
    cal = SlidingWindowCalibrator(T0, WINDOW)
    cal.update(c)
    with pytest.raises(ValueError, match="frame nudged repeats the rows of frame " + c.frame_id):
        cal.update(nudged)
    with pytest.raises(ValueError, match="frame twice repeats the rows of frame " + c.frame_id):
        cal.update(twice)  # its rows kept once: the first frame's again
    assert cal.update(noisy).n_total == 2  # neither refused frame left anything behind
    # a frame with every row twice weighs as the frame once: the same estimate and covariance, and it says so
    a, b = SlidingWindowCalibrator(T0, WINDOW), SlidingWindowCalibrator(T0, WINDOW)
    ea, eb = a.update(c), b.update(dataclasses.replace(twice, frame_id=c.frame_id))
    np.testing.assert_allclose(eb.T, ea.T, atol=1e-9)
    np.testing.assert_allclose(eb.cov, ea.cov, rtol=1e-6, atol=1e-15)
    assert any(f"{n} of the frame's {2 * n} rows repeat another row of it (first: row {n} = row 0" in e
               for e in eb.events) and not ea.events
    ba, bb = solve_batch([c, frames[1]], T0), solve_batch([twice, frames[1]], T0)
    np.testing.assert_allclose(bb.estimate.cov, ba.estimate.cov, rtol=1e-6, atol=1e-15)
    assert (f"1 frame(s) hold a row twice; first: frame twice: {n} of the frame's {2 * n} rows repeat another row "
            "of it") in bb.estimate.status and "twice" not in ba.estimate.status
    # a replay whose rows are also doubled counts the frame's rows once, as the window does (probe 70: 2n)
    b = frames[1]
    both = Correspondences(np.vstack([twice.points_radar, b.points_radar[:1]]), np.vstack([twice.pixels, b.pixels[:1]]),
                           np.r_[twice.sigma_px, b.sigma_px[:1]], np.r_[twice.confidence, b.confidence[:1]], c.K,
                           "both", c.timestamp_us + 5)
    assert f"{n} of the frame's {n + 1} rows repeat rows of frame {c.frame_id}" in solve_batch([c, both],
                                                                                             T0).estimate.status
    vi = VehicleInput("veh", [c, nudged, twice, frames[1]], truth=[T] * 4, reference=T)
    res = calibrate_vehicle(vi, merge(CalibrateConfig, {"start": "reference", "window": WINDOW}), progress=False)
    assert res.n_frames == 2 and [s["token"] for s in res.skipped] == ["nudged", "twice"]
    assert all("repeats the rows of frame " + c.frame_id in s["reason"] for s in res.skipped)


def test_a_partial_replay_is_one_measurement_too():
    """Probe 59: an earlier frame's rows again with one row added, or one taken away, passed as a new frame and shrank
    the std by 30 %. Rows of an earlier frame are one measurement: a frame of nothing else is refused (window, batch)
    and listed (pipeline); the new rows of a frame are kept, the repeated ones left out, and the window says so."""
    from hybrid_calib.calib.pipeline import CalibrateConfig, VehicleInput, calibrate_vehicle
    from hybrid_calib.config import merge

    T, frames, T0 = _drive()
    a, b = frames[0], frames[1]
    keep = np.arange(len(a)) != 3
    cut = dataclasses.replace(a.subset(keep), frame_id="cut", timestamp_us=a.timestamp_us + 1)
    plus = Correspondences(np.vstack([a.points_radar, b.points_radar[:1]]), np.vstack([a.pixels, b.pixels[:1]]),
                           np.r_[a.sigma_px, b.sigma_px[:1]], np.r_[a.confidence, b.confidence[:1]], a.K, "plus",
                           a.timestamp_us + 2)
    assert cut.repeats(a) and not a.repeats(cut) and not plus.repeats(a)
    # radar points 0.9 mm away (inside REPEAT_RADAR_M, mostly in the next 1 mm cell) are the same points
    shifted = dataclasses.replace(a, points_radar=a.points_radar + [9e-4, -9e-4, 0.0])
    far = dataclasses.replace(a, points_radar=a.points_radar + [2e-3, 0.0, 0.0])
    assert shifted.repeats(a) and not far.repeats(a)
    assert repeated_frames([a, cut, plus]) == {1: 0}
    cal = SlidingWindowCalibrator(T0, WINDOW)
    cal.update(a)
    with pytest.raises(ValueError, match="frame cut repeats the rows of frame " + a.frame_id):
        cal.update(cut)
    got = cal.update(plus)  # only its one new row counts: as a frame of that row alone
    ref = SlidingWindowCalibrator(T0, WINDOW)
    ref.update(a)
    want = ref.update(dataclasses.replace(b.subset(np.arange(1)), frame_id="plus", timestamp_us=a.timestamp_us + 2))
    np.testing.assert_allclose(got.cov, want.cov, rtol=1e-6, atol=1e-15)
    assert any(f"{len(a)} of the frame's {len(a) + 1} rows repeat rows of frame {a.frame_id}" in e
               for e in got.events) and not want.events
    with pytest.raises(ValueError, match="1 of the 2 frames repeat .* frame cut repeats the rows of frame"):
        solve_batch([a, cut], T0)
    new_row = plus.subset(np.arange(len(plus)) == len(a))
    replayed, fresh = solve_batch([a, plus, b], T0), solve_batch([a, new_row, b], T0)
    np.testing.assert_allclose(replayed.estimate.cov, fresh.estimate.cov, rtol=1e-6, atol=1e-15)
    # and batch says so, as the window's event (it left them out without a word before session 36)
    # (b's first row is plus's new row)
    assert (f"{len(a) + 1} row(s) of 2 frame(s) repeat an earlier frame's rows; first: frame plus: {len(a)} of the "
            f"frame's {len(a) + 1} rows repeat rows of frame {a.frame_id}") in replayed.estimate.status
    assert f"1 row(s) of 1 frame(s) repeat an earlier frame's rows; first: frame {b.frame_id}: 1 of the frame's " \
        in fresh.estimate.status
    assert "repeat" not in solve_batch([a, b], T0).estimate.status
    vi = VehicleInput("veh", [a, cut, plus, b], truth=[T] * 4, reference=T)
    res = calibrate_vehicle(vi, merge(CalibrateConfig, {"start": "reference", "window": WINDOW}), progress=False)
    assert res.n_frames == 3 and [s["token"] for s in res.skipped] == ["cut"]


def test_of_a_doubled_row_the_weaker_claim_is_kept():
    """A row twice with other sigmas kept the first copy (its sigma 2 px beside the copy's 6 px): the covariance
    stood on the stronger claim of the two."""
    K = np.array([[800.0, 0, 400], [0, 800, 225], [0, 0, 1]])
    p = np.array([[5.0, 1, 0], [5, 1, 0], [7, 2, 0], [5, 1, 0], [7, 2, 0]])
    px = np.array([[10.0, 10], [10, 10], [20, 20], [10, 10], [20, 20]])
    c = Correspondences(p, px, np.array([2.0, 6, 3, 4, 3]), np.array([1.0, 1, 1, 1, 0.5]), K, "a", 0)
    once = c.once()
    assert once.sigma_px.tolist() == [6.0, 3.0] and once.confidence.tolist() == [1.0, 0.5]
    # copies with another row between them in sorted order are copies too (probe 65)
    between = Correspondences(np.array([[1.0, 5, 0], [1.0002, 1, 0], [1.0005, 5, 0]]),
                              np.array([[10.0, 10], [50, 50], [10, 10]]), np.full(3, 6.0), np.ones(3), K, "b", 0)
    assert between.doubled_rows() == [(2, 0)] and len(between.once()) == 2


def test_seen_rows_forget_the_oldest_frames_beyond_their_memory():
    from factors.correspondences import SeenRows

    _, frames, _ = _drive()
    seen = SeenRows(keep=2)
    for f in frames[:3]:
        seen.add(f)
    assert len(seen) == 2 and (seen.match(frames[0]) == -1).all()  # forgotten
    assert (seen.match(frames[2]) == 2).all() and (seen.match(frames[1]) == 1).all() and seen.frame_id(2) == \
        frames[2].frame_id
    assert (seen.match(frames[3]) == -1).all()


@pytest.mark.parametrize("change, message", [
    (dict(confidence=-1.0), "confidence must lie in \\[0, 1\\]"),
    (dict(confidence=1e6), "confidence must lie in \\[0, 1\\]"),
    (dict(K=np.full((3, 3), np.nan)), "K is not a pinhole camera matrix"),
    (dict(K=np.diag([-500.0, 500.0, 1.0])), "K is not a pinhole camera matrix"),
    (dict(K=np.zeros((3, 3))), "K is not a pinhole camera matrix"),
    (dict(pixels="abc"), "pixels: not an array of numbers"),
    (dict(sigma_px=1e-300), "sigma_px holds \\|1e-300\\| px, outside \\[1e-12, 1e\\+06\\] px"),
    (dict(points_radar=1e300), "points_radar holds \\|1e\\+300\\| m, outside"),
    (dict(pixels=-1e300), "pixels holds \\|1e\\+300\\| px, outside"),
    (dict(K=np.diag([1e200, 1e200, 1.0])), "focal lengths must lie in \\[1, 1e\\+07\\] px"),
    (dict(K=np.array([[500.0, 0, 1e300], [0, 500, 200], [0, 0, 1]])), "every entry within 1e\\+07 px"),
    (dict(K=np.diag([1e-200, 1e-200, 1.0])), "focal lengths must lie in"),
    (dict(pixels=1j), "pixels: complex numbers"),
    (dict(timestamp_us="abc"), "timestamp_us must be an integer number of microseconds .*, got str 'abc'"),
    (dict(timestamp_us=1.9), "timestamp_us must be an integer"),
    (dict(frame_id=None), "frame_id must be a str"),
])
def test_correspondences_refuse_what_no_factor_can_use(change, message):
    _, frames, _ = _drive(1)
    c = frames[0]
    fields = dict(points_radar=c.points_radar, pixels=c.pixels, sigma_px=c.sigma_px, confidence=c.confidence, K=c.K)
    key, value = next(iter(change.items()))
    if key in fields and isinstance(value, (float, complex)):  # one value for every row of that field
        change = {key: np.full(np.shape(fields[key]), value)}
    with pytest.raises(ValueError, match=message):
        Correspondences(**{"frame_id": "f7", **fields, **change})


def test_an_integer_frame_id_is_its_string_and_numpy_timestamps_are_ints():
    _, frames, _ = _drive(1)
    c = frames[0]
    own = Correspondences(c.points_radar, c.pixels, c.sigma_px, c.confidence, c.K, 42, np.int64(7))
    assert own.frame_id == "42" and own.timestamp_us == 7 and type(own.timestamp_us) is int


def test_metrics_and_priors_refuse_what_is_not_a_transform_or_a_covariance():
    """A 5 % sheared rotation measured as 0 error; the Ceres back end took a sheared prior mean ("ok") and ended a
    non-positive-definite prior covariance in a bare LinAlgError, where GTSAM's named both (probe 51); a singular
    covariance's NEES was a bare "Singular matrix"."""
    from hybrid_calib.calib.schedule import GaussianPrior

    T, frames, T0 = _drive(2)
    sheared = T.copy()
    sheared[:3, 0] *= 1.05
    with pytest.raises(ValueError, match="extrinsic_error T_est: rotation block is not a proper rotation"):
        extrinsic_error(sheared, T)
    assert extrinsic_error(T.astype(np.float32), T).geodesic_deg < 1e-3  # a float32 network output is measured
    for cov, message in ((1e-4 * np.eye(6), "GaussianPrior.T: rotation block"), (-1e-4 * np.eye(6), "not positive"),
                         (np.zeros((6, 6)), "not positive")):
        with pytest.raises(ValueError, match=message):
            GaussianPrior(sheared if "T:" in message else T, cov)
    with pytest.raises(ValueError, match="NEES of a singular covariance"):
        nees(np.ones(6), np.diag([1.0] * 5 + [0.0]))


def test_validated_rows_cannot_be_changed_behind_the_check():
    _, frames, _ = _drive(1)
    c = frames[0]
    pixels = np.array(c.pixels)
    own = Correspondences(c.points_radar, pixels, c.sigma_px, c.confidence, c.K, "f")
    pixels[0, 0] = np.nan  # the caller's array: not the frame's
    assert np.all(np.isfinite(own.pixels))
    with pytest.raises(ValueError, match="read-only"):
        own.pixels[0, 0] = np.nan


@pytest.mark.parametrize("T_init, message", [
    (lambda T: np.diag([1.5, 1.5, 1.5, 1.0]) @ T, "T_init: rotation block is not a proper rotation"),
    (lambda T: np.vstack([T[:3], [1.0, 2.0, 3.0, 4.0]]), "T_init: last row"),
    (lambda T: T[:3], "T_init: expected a finite \\(4, 4\\) transform"),
    (lambda T: np.full((4, 4), np.nan), "T_init: transform holds non-finite"),
])
def test_a_start_that_is_not_a_transform_is_named_by_every_entry_point(T_init, message):
    """The Ceres backend took a scaled rotation GTSAM refused; a 3x4 start was a pybind constructor error."""
    T, frames, _ = _drive(2)
    bad = T_init(T)
    for backend in ("gtsam", "ceres"):
        with pytest.raises(ValueError, match=message):
            solve_batch(frames, bad, {"backend": backend})
    with pytest.raises(ValueError, match=message):
        SlidingWindowCalibrator(bad)


def test_the_reference_test_refuses_a_covariance_it_cannot_read():
    """A negative-definite or zero covariance read "within tolerance" (chi2 -0.36, p 1.0); NaN was a LinAlgError."""
    T = nominal_T_cam_radar()
    T_est = perturb_camera_frame(T, np.radians([0.0, 0.3, 0.0]), [0.0, 0.0, 0.0])
    good = np.diag([np.radians(0.5) ** 2] * 3 + [0.05 ** 2] * 3)
    assert reference_test(T_est, good, T).verdict_kind == "cannot tell"
    for cov, message in ((-good, "not positive semidefinite"), (np.zeros((6, 6)), "not positive semidefinite"),
                         (np.full((6, 6), np.nan), "non-finite"), (np.triu(good + 1e-3), "not symmetric")):
        with pytest.raises(ValueError, match=f"reference_test cov_est: .*{message}"):
            reference_test(T_est, cov, T)
    with pytest.raises(ValueError, match="reference_test T_est: rotation block"):
        reference_test(np.diag([1.5, 1.5, 1.5, 1.0]) @ T_est, good, T)


def test_averages_errors_and_fleet_priors_name_what_is_wrong():
    from hybrid_calib.fleet.prior import fit_fleet_prior
    from hybrid_calib.hybrid.average import robust_average

    T = nominal_T_cam_radar()
    Ts = [perturb_camera_frame(T, np.radians([0.1 * k, 0, 0]), [0, 0, 0]) for k in range(6)]
    C = np.diag([1e-4] * 3 + [1e-3] * 3)
    with pytest.raises(ValueError, match="robust_average covs\\[0\\]: covariance is not positive definite"):
        robust_average(np.stack(Ts), np.zeros((6, 6, 6)))
    with pytest.raises(ValueError, match="robust_average Ts\\[2\\]: transform holds non-finite"):
        robust_average(np.stack([*Ts[:2], np.full((4, 4), np.nan), *Ts[3:]]), np.stack([C] * 6))
    # valid inputs are checked at once, not item by item (probe 57: the per-item checks and tangents of every
    # earlier frame, at every frame, made pure-avg quadratic: 35 min of averaging extrapolated for 2400 frames)
    import hybrid_calib.hybrid.average as average

    calls = []
    real = average.check_transform
    average.check_transform = lambda *a, **k: calls.append(1) or real(*a, **k)
    try:
        M, cov, w = robust_average(np.stack(Ts), np.stack([C] * 6))
    finally:
        average.check_transform = real
    assert not calls and np.all(w > 0) and np.all(np.isfinite(cov))
    M, cov, _ = robust_average(np.stack(Ts), np.stack([C] * 6))
    assert np.all(np.diag(cov) > 0) and nees(local(T, M), cov) >= 0
    with pytest.raises(ValueError, match="extrinsic_error T_est: .*NaN"):
        extrinsic_error(np.full((4, 4), np.nan), T)
    names = [f"v{k}" for k in range(6)]
    with pytest.raises(ValueError, match="6 names, 5 transforms and 6 covariances"):
        fit_fleet_prior(names, Ts[:5], [C] * 6, T)
    with pytest.raises(ValueError, match="a vehicle named twice"):
        fit_fleet_prior(["v"] * 6, Ts, [C] * 6, T)
    with pytest.raises(ValueError, match="covs\\[5\\] \\(v5\\): covariance is not positive definite"):
        fit_fleet_prior(names, Ts, [C] * 5 + [-C], T)
    with pytest.raises(ValueError, match="Ts\\[1\\] \\(v1\\): rotation block"):
        fit_fleet_prior(names, [Ts[0], 2 * Ts[1], *Ts[2:]], [C] * 6, T)


def test_a_measurement_file_with_a_scaled_network_rotation_is_refused(tmp_path):
    """Only the last row was checked: a 2x rotation read as a perfect one (network error 0.0 deg)."""
    from factors.io import FrameMeasurements, NetworkEstimate, from_arrays, to_arrays
    from hybrid_calib.errors import DataError

    T, frames, _ = _drive(1)
    d = to_arrays(FrameMeasurements(frames[0], "veh", 0, NetworkEstimate(T, None, 0, None)))
    assert from_arrays(d).network is not None
    d["T_cam_radar"] = np.diag([2.0, 2.0, 2.0, 1.0]) @ T
    with pytest.raises(DataError, match="'T_cam_radar' is not a rigid transform \\(its rotation block"):
        from_arrays(d, "f.npz")
    d = to_arrays(FrameMeasurements(frames[0]))
    d["confidence"][0] = -1.0
    with pytest.raises(DataError, match="confidence must lie in \\[0, 1\\]"):
        from_arrays(d, "f.npz")
    # a symmetric network covariance of a negative eigenvalue, or all zeros, was reported as ordinary stds; a
    # timestamp that is not an integer read "unreadable (ValueError ...)" without the key (probe 51)
    for cov, message in ((np.diag([1e-4] * 6) + 3e-4 * (np.eye(6, k=1) + np.eye(6, k=-1)), "eigenvalue"),
                         (np.zeros((6, 6)), "all zeros")):
        d = to_arrays(FrameMeasurements(frames[0], "veh", 0, NetworkEstimate(T, cov, 0, None)))
        with pytest.raises(DataError, match=f"key 'cov' is .*{message}"):
            from_arrays(d, "f.npz")
    d = to_arrays(FrameMeasurements(frames[0]))
    d["timestamp_radar_us"] = np.asarray("abc")
    with pytest.raises(DataError, match="key 'timestamp_radar_us' is .*expected an integer"):
        from_arrays(d, "f.npz")


def test_a_repeat_is_a_repeat_in_any_row_order_and_paths_may_be_paths(tmp_path):
    """Reordered rows of one frame passed as a new frame (probe 33); a pathlib.Path for a checkpoint option was a
    ConfigError with a command-line hint (probe 33)."""
    from pathlib import Path

    from hybrid_calib.config import merge
    from hybrid_calib.hybrid.loop import HybridConfig

    _, frames, _ = _drive(1)
    c = frames[0]
    order = np.arange(len(c))[::-1]
    shuffled = Correspondences(c.points_radar[order], c.pixels[order], c.sigma_px[order], c.confidence[order], c.K,
                               "shuffled")
    assert repeated_frames([c, shuffled]) == {1: 0}
    moved = Correspondences(c.points_radar, c.pixels + 0.5, c.sigma_px, c.confidence, c.K, "moved")
    assert repeated_frames([c, moved]) == {}  # pixels a quarter of their sigma away: another measurement
    conf = merge(HybridConfig, {"checkpoint": tmp_path / "c.json", "cache_dir": Path("cache")})
    assert conf.checkpoint == str(tmp_path / "c.json") and conf.cache_dir == "cache"


def test_a_network_on_a_device_this_machine_lacks_is_named(tmp_path):
    from hybrid_calib.hybrid.network import shipped_checkpoint
    from learned.checkpoint import CheckpointError, load_model

    with pytest.raises(CheckpointError, match="cannot be placed on device 'tpu'.*use a device this machine has"):
        load_model(shipped_checkpoint("R1"), device="tpu")


def test_configs_built_directly_check_their_types_as_merge_does(tmp_path):
    """The constructors the examples call accepted SimConfig(frames=2.5) (a bare TypeError deep in simulate), a str
    kernel scale (a bare TypeError) and an unknown engine (refused only inside run_fleet, as the flag '--engine'); a
    list kept in a frozen config made it unhashable; one root given as a str was iterated letter by letter (probe
    51)."""
    from factors.config import RadarPixelFactorConfig
    from hybrid_calib.compare import compare
    from hybrid_calib.errors import DataError
    from hybrid_calib.fleet.driver import FleetOptions, run_fleet
    from hybrid_calib.sim.drive import SimConfig

    for build, message in ((lambda: SimConfig(frames=2.5), "frames=2.5 \\(float\\) is not a valid integer for Sim"),
                           (lambda: SimConfig(frames="20"), "frames='20' \\(str\\) is not a valid integer"),
                           (lambda: RadarPixelFactorConfig(kernel_scale="2"), "kernel_scale='2' \\(str\\)"),
                           (lambda: FleetOptions("local", 1.5), "workers=1.5"),
                           (lambda: FleetOptions("foo"), "need engine in \\('local', 'process', 'ray'\\)")):
        with pytest.raises(ValueError, match=message):
            build()
    conf = RadarPixelFactorConfig(scene_knots_m=[0.0, 10.0, 40.0])
    assert conf.scene_knots_m == (0.0, 10.0, 40.0) and hash(conf)
    missing = str(tmp_path / "no-such-root")
    for run in (lambda: run_fleet(missing, None, "v1.0-sim", "oracle", tmp_path / "fleet"),
                lambda: compare(missing, "v1.0-sim", tmp_path / "cmp", progress=False)):
        with pytest.raises(DataError) as e:
            run()
        assert "no-such-root" in str(e.value) and "[file n]" not in str(e.value)


def test_the_metrics_refuse_what_they_cannot_measure():
    """Probe 67: signed_errors of a scaled rotation was 0, nees of a non-symmetric covariance a number and of a NaN
    error NaN, consistency of a negative NEES "inside the ellipsoid"; a (6,) error with a (3, 3) covariance failed
    inside numpy."""
    from hybrid_calib.metrics import consistency, nees, signed_errors

    T = np.eye(4)
    with pytest.raises(ValueError, match="signed_errors T_est: rotation block is not a proper rotation"):
        signed_errors(np.diag([1.05, 1, 1, 1]), T)
    with pytest.raises(ValueError, match="signed_errors T_gt"):
        signed_errors(T, np.eye(3))
    np.testing.assert_allclose(signed_errors(T, T), np.zeros(6))
    with pytest.raises(ValueError, match=r"nees: xi \(6,\) or \(F, 6\) with cov .* got xi \(6,\) and cov \(3, 3\)"):
        nees(np.zeros(6), np.eye(3))
    with pytest.raises(ValueError, match="nees: xi or cov holds NaN"):
        nees(np.r_[np.nan, np.zeros(5)], np.eye(6))
    skew = np.eye(6)
    skew[0, 1] = 0.5
    with pytest.raises(ValueError, match="nees: cov is not symmetric"):
        nees(np.ones(6), skew)
    assert nees(np.ones(6), np.eye(6)) == pytest.approx(6.0)
    np.testing.assert_allclose(nees(np.ones((3, 6)), np.stack([np.eye(6)] * 3)), [6.0] * 3)
    with pytest.raises(ValueError, match=r"consistency: NEES values must be finite and >= 0.*\[-5.0\]"):
        consistency([-5.0, 1.0])
    assert consistency([1.0, 20.0])["coverage_95"] == 0.5


def test_the_reader_and_the_window_name_a_wrong_kind_of_argument(tiny):
    """Probe 67: a version None was "unsupported operand type(s) for /", a frame index 'a' a comparison error, and the
    window's timestamp_us 1.5 was truncated while Correspondences refuses it."""
    from hybrid_calib.data.nuscenes import NuScenesRadarCamera

    with pytest.raises(TypeError, match="version must be a non-empty str"):
        NuScenesRadarCamera(tiny.root, None)
    ds = NuScenesRadarCamera(tiny.root, tiny.version)
    with pytest.raises(TypeError, match="frame index must be an integer, got str 'a'"):
        ds["a"]
    assert ds[np.int64(0)].camera_token == ds[0].camera_token
    T, frames, T0 = _drive()
    cal = SlidingWindowCalibrator(T0, WINDOW)
    for bad in (1.5, float("nan"), "7", True):
        with pytest.raises(ValueError, match="timestamp_us must be an integer number of microseconds"):
            cal.update(frames[0], timestamp_us=bad)
    assert cal.update(frames[0], timestamp_us=np.int64(5)).n_total == 1


def test_the_factor_layer_refuses_what_it_would_read_as_something_else():
    """Probe 118: a camera matrix with K[1, 0] = 300 px was accepted and projected as if it were 0; a motion
    measurement of NaN gave a NaN residual and Jacobian without a word; a Ceres stage from a NaN start ended in numpy's
    "SVD did not converge"; a rotation error of 90 deg in pitch printed scipy's gimbal-lock warning with its source."""
    import warnings

    from factors.ceres_costs import solve_ceres_stage
    from factors.config import RadarPixelFactorConfig
    from factors.motion import MotionMeasurement
    from hybrid_calib.geometry import camera_euler_from_rotation, rotation_from_camera_euler

    K = np.array([[800.0, 0, 400], [0, 800, 225], [0, 0, 1]])
    rows = dict(points_radar=np.array([[10.0, 1, 0], [20, -2, 0], [15, 3, 0]]), pixels=np.full((3, 2), 300.0),
                sigma_px=np.ones(3), confidence=np.ones(3))
    Correspondences(K=K, frame_id="f", **rows)
    sheared = K.copy()
    sheared[1, 0] = 300.0
    with pytest.raises(ValueError, match=r"Correspondences\[f\].K is not a pinhole .*second row \[0, fy, cy\]"):
        Correspondences(K=sheared, frame_id="f", **rows)
    c, R = np.array([0.0, 0, 1]), np.eye(3)
    MotionMeasurement(c, R, 1.0, 0.1, 0.01, 5.0)
    for bad, needle in (((np.r_[np.nan, 0, 1], R, 1.0, 0.1, 0.01, 5.0), r"\.c must be a finite \(3,\) array"),
                        ((c, R, np.inf, 0.1, 0.01, 5.0), r"\.s is inf"),
                        ((c, R, 1.0, np.nan, 0.01, 5.0), r"\.psi is nan"),
                        ((c, R, 1.0, 0.1, 0.0, 5.0), "sigma must be > 0")):
        with pytest.raises(ValueError, match=needle):
            MotionMeasurement(*bad, frame_a="a", frame_b="b")
    with pytest.raises(ValueError, match="MotionMeasurement"):
        MotionMeasurement.from_dict({**MotionMeasurement(c, R, 1.0, 0.1, 0.01, 5.0).to_dict(), "speed": float("nan")})
    start = np.eye(4)
    start[0, 0] = np.nan
    with pytest.raises(ValueError, match="solve_ceres_stage T_init"):
        solve_ceres_stage([Correspondences(K=K, frame_id="f", **rows)], start, RadarPixelFactorConfig())
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        rpy = camera_euler_from_rotation(rotation_from_camera_euler(np.radians([10.0, 90.0, 20.0])))
    assert rpy[0] == 0.0 and np.degrees(rpy[1]) == pytest.approx(90.0)
