"""The hybrid: measurement model (no double counting, shared per-frame error), the closed loop on a
tiny simulated drive with the shipped small network, identical starts across methods, compare."""

from __future__ import annotations

import dataclasses
import json
import shutil
from pathlib import Path

import numpy as np
import pytest

from factors.config import RadarPixelFactorConfig
from factors.correspondences import Correspondences
from hybrid_calib.geometry import project_points, retract, se3_exp
from hybrid_calib.hybrid.measurement import MeasurementConfig, frame_inputs, prior_trusted, shared_deflation
from hybrid_calib.hybrid.network import NetworkOutput
from tests.helpers import network_start

K = np.array([[100.0, 0, 48], [0, 100.0, 24], [0, 0, 1]])
T_TRUE = np.array([[0.0, -1, 0, 0.1], [0, 0, -1, -0.3], [1, 0, 0, -0.5], [0, 0, 0, 1]])  # radar x fwd -> cam z


def _rows(T: np.ndarray, g: np.random.Generator, n: int = 40, noise: float = 1.0) -> Correspondences:
    p = np.column_stack([g.uniform(8, 40, n), g.uniform(-10, 10, n), np.zeros(n)])
    uv, _ = project_points(K, T, p)
    return Correspondences(p, uv + noise * g.standard_normal((n, 2)), np.full(n, 2.0), np.ones(n), K, "f0", 0)


def _output(g: np.random.Generator) -> NetworkOutput:
    T_net = retract(T_TRUE, np.r_[0.004, -0.003, 0.002, 0.03, -0.02, 0.01])
    cov = np.diag([1e-4, 1e-4, 1e-4, 4e-3, 4e-3, 4e-3])
    # iteration 0: measured against the truth with noise; last: a restatement of the network's own SE(3)
    return NetworkOutput(T_TRUE, np.stack([T_net] * 3), cov, _rows(T_TRUE, g), _rows(T_net, g, noise=0.0), 0.01,
                         image_structure=0.95)  # a camera's view of a scene (learned.ood.image_structure)


FACTOR = RadarPixelFactorConfig(elevation_model="zero")


def test_last_iteration_rows_never_come_with_the_prior():
    out = _output(np.random.default_rng(0))
    fi = frame_inputs(out, T_TRUE, MeasurementConfig(rows="last", prior=True), FACTOR, 3.0, trusted=True)
    assert fi.prior is None and not fi.prior_used and len(fi.corr) == 40
    fi = frame_inputs(out, T_TRUE, MeasurementConfig(rows="first", prior=True), FACTOR, 3.0, trusted=True)
    assert fi.prior is not None and fi.prior_used
    fi = frame_inputs(out, T_TRUE, MeasurementConfig(rows="first", prior=True), FACTOR, 3.0, trusted=False)
    assert fi.prior is None and "outside its fitted range" in fi.note


def test_shared_deflation_never_exceeds_the_shared_error_model():
    g = np.random.default_rng(1)
    for _ in range(20):
        A = g.standard_normal((6, 6))
        H = A @ A.T * 10 ** g.uniform(-1, 4)
        std = 10 ** g.uniform(-3, -1, 6)
        s = shared_deflation(H, std)
        cap = np.linalg.inv(np.linalg.inv(H) + np.diag(std ** 2))
        eig = np.linalg.eigvalsh(cap - s * H)
        assert eig.min() > -1e-6 * np.abs(eig).max()  # s H <= (H^-1 + S)^-1
        assert eig.min() < 1e-6 * np.abs(eig).max()  # ... and touches it: the largest such s
    assert shared_deflation(np.eye(6), np.zeros(6)) == 1.0


def test_one_frame_enters_the_window_once():
    """The window's information after one frame is exactly the deflated rows plus the deflated prior:
    if the prior (or the rows) entered twice, or undeflated, this fails."""
    from hybrid_calib.calib.schedule import frame_information
    from hybrid_calib.calib.window import SlidingWindowCalibrator, WindowConfig

    out = _output(np.random.default_rng(2))
    conf = MeasurementConfig(rows="first", prior=True, shared_std=(0.002, 0.002, 0.002, 0.02, 0.02, 0.02))
    fi = frame_inputs(out, T_TRUE, conf, FACTOR, 3.0, trusted=True)
    assert 0 < fi.deflation < 1
    wconf = WindowConfig(factor=FACTOR, detect_steps=False)
    cal = SlidingWindowCalibrator(T_TRUE, wconf)
    fe = cal.update(fi.corr, fi.prior)
    _, H_rows, _ = frame_information(fe.T, fi.corr, FACTOR, wconf.schedule.final_gate)
    expected = H_rows + np.linalg.inv(fi.prior.cov)
    d = 1 / np.sqrt(np.diag(expected))  # compare in whitened units (GTSAM's prior Jacobian differs at 1e-4)
    assert np.abs(d[:, None] * (cal.info - expected) * d[None, :]).max() < 2e-3
    prior_alone = d[:, None] * np.linalg.inv(fi.prior.cov) * d[None, :]
    assert np.abs(prior_alone).max() > 0.05  # a second copy of the prior would be far outside the tolerance
    # and that is no more than the shared-error model allows for the undeflated frame
    H0 = frame_information(T_TRUE, out.rows_first, FACTOR, 3.0)[1] + np.linalg.inv(out.cov_raw)
    cap = np.linalg.inv(np.linalg.inv(H0) + np.diag(np.square(conf.shared_std)))
    assert np.linalg.eigvalsh(cap - expected).min() > -1e-3 * np.abs(cap).max()


def test_prior_trusted_only_inside_the_fitted_range():
    assert prior_trusted("R1", "R1", None, 0.1) and prior_trusted("reference", "R1", None, 0.1)
    assert not prior_trusted("R2", "R1", None, 0.1)
    assert prior_trusted("R2", "R1", np.diag(np.square([np.radians(0.5)] * 3 + [0.01] * 3)), 0.1)
    assert not prior_trusted("R2", "R1", np.diag(np.square([np.radians(5.0)] * 3 + [0.01] * 3)), 0.1)


def test_robust_average_rejects_an_outlier_and_weights_by_covariance():
    from hybrid_calib.hybrid.average import robust_average

    g = np.random.default_rng(3)
    Ts = [retract(T_TRUE, np.r_[1e-3 * g.standard_normal(3), 1e-2 * g.standard_normal(3)]) for _ in range(30)]
    Ts.append(T_TRUE @ se3_exp(np.r_[0.3, 0, 0, 1.0, 0, 0]))  # a gross outlier
    covs = np.stack([np.diag([1e-6] * 3 + [1e-4] * 3)] * len(Ts))
    M, cov, w = robust_average(np.stack(Ts), covs)
    from hybrid_calib.metrics import extrinsic_error

    e = extrinsic_error(M, T_TRUE)
    assert e.geodesic_deg < 0.05 and e.trans_norm_cm < 1.0 and w[-1] < 0.01
    assert np.allclose(np.diag(cov), np.diag(covs[0]) / w.sum(), rtol=1e-6)
    # the weight is Cauchy's in the Mahalanobis distance, at kernel_scale 2.5 (probe 74: in its square, the weights of
    # frames 2-3 sigma out fell 3x and pure-avg's sigma grew 1.46x, unseen): two estimates 2 x 3 sigma apart
    C = np.diag([1e-6] * 3 + [1e-4] * 3)
    pair = np.stack([retract(T_TRUE, np.r_[3e-3, 0, 0, 0, 0, 0]), retract(T_TRUE, np.r_[-3e-3, 0, 0, 0, 0, 0])])
    _, _, w2 = robust_average(pair, np.stack([C, C]), T0=T_TRUE)
    np.testing.assert_allclose(w2, 1 / (1 + (3.0 / 2.5) ** 2), rtol=1e-6)


# ---------------------------------------------------------------------------------- on a simulated drive


@pytest.fixture(scope="module")
def sim_root(tmp_path_factory):
    """2 vehicles x 3 keyframes, 200 x 112 images."""
    from hybrid_calib.sim.drive import SimConfig
    from hybrid_calib.sim.simulate import simulate

    return simulate(SimConfig(vehicles=2, frames=3, image_scale=0.125, seed=5), tmp_path_factory.mktemp("sim"),
                    progress=False)


BASE = {"start": "R1", "seed": 4, "threads": 1, "progress": False, "window": {"detect_steps": False}}


def test_the_network_estimates_the_frame_transform_and_is_read_back_on_the_mount(sim_root):
    """Session 40: the network follows the radar points it is given (turned by 1 deg of yaw, its output turned by
    about -1 deg), so it estimates the frame's ``X N``, not the mount; ``on_mount`` reads a pass on the mount:
    transforms by ``N^-1``, covariance by ``Ad_N``, rows' points by ``N``."""
    import torch

    from hybrid_calib.data.nuscenes import NuScenesRadarCamera
    from hybrid_calib.geometry import adjoint, se3_inverse, se3_log, transform_points
    from hybrid_calib.hybrid.network import build_runner, on_mount, shipped_checkpoint

    ds = NuScenesRadarCamera(sim_root, "v1.0-sim", conf={"load_lidar": True})
    runner = build_runner(shipped_checkpoint("R1"), None, ds, threads=1)
    turn = se3_exp(np.r_[0.0, 0.0, np.radians(1.0), 0.0, 0.0, 0.0])
    moved = []
    for i in range(len(ds)):
        s, XN = runner.sample(i), ds[i].T_cam_radar
        base = runner.forward(s, XN)
        pts, mask = s["radar"].numpy().astype(np.float64), s["radar_mask"].numpy()
        pts[mask] = transform_points(turn, pts[mask])
        out = runner.forward({**s, "radar": torch.from_numpy(pts.astype(np.float32))}, XN)
        moved.append(np.degrees(se3_log(se3_inverse(base.T) @ out.T)[2]))
    assert -1.4 < np.median(moved) < -0.6, moved
    N = runner.radar_motion(0)
    assert np.abs(N - np.eye(4)).max() > 1e-3  # the simulated drive moves between the two timestamps
    from hybrid_calib.hybrid.network import frames_motion
    from learned.dataset import ConcatFrames

    both = ConcatFrames([ds, ds])  # several roots read as one: each frame's own root says
    np.testing.assert_array_equal(frames_motion(both, len(ds) + 1), frames_motion(ds, 1))
    assert np.abs(frames_motion(both, 1) - frames_motion(ds, 0)).max() > 0
    m = on_mount(base, N)
    np.testing.assert_allclose(m.T_iters, base.T_iters @ se3_inverse(N))
    np.testing.assert_allclose(m.T_in, base.T_in @ se3_inverse(N))
    np.testing.assert_allclose(m.cov_raw, adjoint(N) @ base.cov_raw @ adjoint(N).T)
    np.testing.assert_allclose(m.rows_last.points_radar, transform_points(N, base.rows_last.points_radar))


def test_closed_loop_runs_the_network_from_the_fused_estimate(sim_root, tmp_path, monkeypatch):
    import hybrid_calib.hybrid.corrections as corrections
    from hybrid_calib.calib.result import CalibrationRun
    from hybrid_calib.hybrid import run_calibration
    from hybrid_calib.hybrid.network import OutputCache

    asked = []  # the LiDAR's forward offset is judged against the loop's own forward std (probe 53)
    real_refusal = corrections.forward_refusal
    monkeypatch.setattr(corrections, "forward_refusal", lambda a, conf, loop_std_x=None: asked.append(
        loop_std_x) or real_refusal(a, conf, loop_std_x))

    run = run_calibration(sim_root, "v1.0-sim", tmp_path / "h", {**BASE, "method": "hybrid",
                                                                  "vehicles": ("sim-veh-000",),
                                                                  "lidar": {"min_rows": 15, "max_std_m": 1.0,
                                                                            "stationary": False}})
    (v,) = run.vehicles.values()
    assert v.method == "hybrid" and v.errors_against == "truth" and v.checkpoint.endswith("small-sim-r1.json")
    assert len(v.trajectory) == len(v.frame_rows) == 3 and v.error["nees"] > 0
    # the shipped checkpoint's fitted model uses no rows: no height plane (probe 138: "the hybrid's rows" were named)
    assert v.config["measurement_effective"]["rows"] == "none" and v.height_plane is None
    cache = OutputCache(tmp_path / "h" / "network-cache")
    starts = [np.asarray(v.start["T_cam_radar"])] + [f.T for f in v.trajectory[:-1]]
    for f, T_in in zip(v.trajectory, starts):  # frame k ran from the window's estimate after frame k-1 (as T N)
        assert cache.get(f.frame_id, network_start(sim_root, "v1.0-sim", f.frame_id, T_in)) is not None
        assert cache.get(f.frame_id, T_in) is None  # not from the mount itself: the network estimates X N
    assert not np.allclose(starts[1], starts[0])
    back = CalibrationRun.load(tmp_path / "h" / "result.json").vehicles["sim-veh-000"]
    assert back.method == "hybrid" and back.frame_rows == v.frame_rows and back.start == v.start
    # the LiDAR's lateral offset was measured on the loop's frames and folded into the last estimate only
    assert v.lidar["applied"] and v.lidar["frames"] == 3 and back.lidar == v.lidar, v.lidar
    assert asked and all(s is not None and s > 0 for s in asked), asked
    h = np.r_[-np.asarray(v.lidar["coupling_m_per_rad"]), 0.0, 1.0, 0.0]  # what dy measures (its Kalman row)
    # at most the measurement's noise: its variance and its coupling's spread with the rotation's variance (before
    # the last frame: the window's only shrinks)
    from hybrid_calib.calib.lidar_alignment import spread_var

    noise = v.lidar["dy_std_m"] ** 2 + spread_var(v.lidar["coupling_spread_m_per_rad"], v.trajectory[-2].cov)
    assert h @ v.trajectory[-1].cov @ h <= noise * (1 + 1e-9)
    assert h @ v.trajectory[-2].cov @ h > v.lidar["dy_std_m"] ** 2
    # the Doppler's forward offset needs turns over many frames: 3 frames give pairs in 2 (the first has no
    # partner), and it says so
    assert v.doppler == back.doppler and not v.doppler["applied"], v.doppler
    assert "usable sweep pairs in 2 frames (need 10 of each)" in v.doppler["note"], v.doppler


def test_a_damaged_network_cache_entry_is_recomputed_not_a_failure(tmp_path):
    """Probe 63: an entry whose T_in was a string array was an internal error in compare, and a misshapen one failed
    the trial: an entry that is not a network output of finite numbers of the right shapes is a miss."""
    from factors.correspondences import Correspondences
    from hybrid_calib.hybrid.network import NetworkOutput, OutputCache

    K = np.array([[800.0, 0, 400], [0, 800, 225], [0, 0, 1]])
    rows = Correspondences(np.array([[5.0, 1, 0]]), np.array([[10.0, 20]]), np.array([6.0]), np.array([1.0]), K,
                           "tok")
    out = NetworkOutput(np.eye(4), np.stack([np.eye(4)] * 2), np.eye(6), rows, rows, 0.1, np.zeros(3), np.zeros(2), 0.9)
    cache = OutputCache(tmp_path, "net")
    cache.put("tok", out)
    assert cache.get("tok", np.eye(4)) is not None
    # another frame's pass (or another start's) under this one's name: a miss (probe 109: used in silence)
    import shutil

    shutil.copy(cache.path("tok", np.eye(4)), cache.path("other", np.eye(4)))
    assert cache.get("other", np.eye(4)) is None
    moved = np.eye(4)
    moved[0, 3] = 0.5
    shutil.copy(cache.path("tok", np.eye(4)), cache.path("tok", moved))
    assert cache.get("tok", moved) is None
    good = dict(np.load(cache.path("tok", np.eye(4))))
    for key, bad in (("T_in", np.array("x")), ("T_iters", np.eye(4)), ("cov_raw", np.eye(5)),
                     ("T_in", np.full((4, 4), np.nan)), ("ood_signals", np.array(["a", "b"])),
                     ("ood_signals", np.full(2, np.nan)), ("seconds", np.array(np.nan)),  # probe 65
                     ("first_K", np.zeros((3, 3))), ("image_structure", np.array(np.nan))):
        np.savez(cache.path("tok", np.eye(4)), **{**good, key: bad})
        assert cache.get("tok", np.eye(4)) is None, key
    # a pass whose out-of-domain features do not fit the checkpoint's fitted model is recomputed, not a run that fails
    # blaming the checkpoint (probe 65)
    from types import SimpleNamespace

    from hybrid_calib.hybrid.network import NetworkRunner
    from learned.ood import OODError

    def unfit(_):
        raise OODError("features have 2 dimensions, the fitted model 6")

    assert not NetworkRunner._fits(SimpleNamespace(ood_score=unfit), out)
    assert NetworkRunner._fits(SimpleNamespace(ood_score=lambda _: 0.5), out)


def test_an_interrupted_run_keeps_its_finished_vehicles_and_goes_on_from_there(sim_root, tmp_path, monkeypatch):
    from hybrid_calib.calib.result import CalibrationRun
    from hybrid_calib.hybrid import loop, run_calibration

    conf = {**BASE, "method": "pure", "max_frames": 2}

    def stop(vr):
        raise KeyboardInterrupt  # Ctrl-C once the first vehicle is done

    with pytest.raises(KeyboardInterrupt):
        run_calibration(sim_root, "v1.0-sim", tmp_path / "p", conf, on_vehicle=stop)
    kept = sorted((tmp_path / "p" / "vehicles-done").glob("sim-veh-*.json"))
    assert [f.name for f in kept] == ["sim-veh-000.json"] and not (tmp_path / "p" / "result.json").exists()
    ran = []
    real = loop._Session.vehicle
    monkeypatch.setattr(loop._Session, "vehicle", lambda self, name: ran.append(name) or real(self, name))
    run = run_calibration(sim_root, "v1.0-sim", tmp_path / "p", conf)
    assert ran == ["sim-veh-001"] and sorted(run.vehicles) == ["sim-veh-000", "sim-veh-001"]
    assert not (tmp_path / "p" / "vehicles-done").exists()  # result.json holds everything now
    assert CalibrationRun.load(tmp_path / "p" / "result.json").vehicles["sim-veh-000"].final.status
    # another configuration neither reuses nor silently discards what an interrupted run of this one kept
    from hybrid_calib.errors import HybridCalibError

    with pytest.raises(KeyboardInterrupt):
        run_calibration(sim_root, "v1.0-sim", tmp_path / "q", conf, on_vehicle=stop)
    with pytest.raises(HybridCalibError, match=r"holds 1 vehicle\(s\) finished by an interrupted run of another "
                                               r"configuration \(seed: 4 -> 9\).*--overwrite"):
        run_calibration(sim_root, "v1.0-sim", tmp_path / "q", {**conf, "seed": 9})
    # a record copied from another run, or renamed, is recomputed, not trusted
    done = tmp_path / "q" / "vehicles-done"
    record = json.loads((done / "sim-veh-000.json").read_text())
    (done / "sim-veh-001.json").write_text(json.dumps({**record, "vehicle": "sim-veh-001"}))
    ran.clear()
    run = run_calibration(sim_root, "v1.0-sim", tmp_path / "q", conf)
    assert ran == ["sim-veh-001"] and run.vehicles["sim-veh-001"].vehicle == "sim-veh-001"
    with pytest.raises(KeyboardInterrupt):
        run_calibration(sim_root, "v1.0-sim", tmp_path / "r", conf, on_vehicle=stop)
    ran.clear()
    run_calibration(sim_root, "v1.0-sim", tmp_path / "r", {**conf, "seed": 9}, overwrite=True)
    assert ran == ["sim-veh-000", "sim-veh-001"]
    # a damaged stamp loses nothing: the kept records carry their run's key
    with pytest.raises(KeyboardInterrupt):
        run_calibration(sim_root, "v1.0-sim", tmp_path / "t", conf, on_vehicle=stop)
    (tmp_path / "t" / "vehicles-done" / "stamp.json").write_text("{garbage")
    ran.clear()
    run_calibration(sim_root, "v1.0-sim", tmp_path / "t", conf)
    assert ran == ["sim-veh-001"]
    # a moved folder resumes (the caches' paths in its config are how the run ran, not what it gave)
    with pytest.raises(KeyboardInterrupt):
        run_calibration(sim_root, "v1.0-sim", tmp_path / "s", conf, on_vehicle=stop)
    (tmp_path / "s").rename(tmp_path / "s2")
    ran.clear()
    run_calibration(sim_root, "v1.0-sim", tmp_path / "s2", conf)
    assert ran == ["sim-veh-001"]
    # a relative folder resumed from another one: every vehicle names the same caches (probe 72: "u/network-cache"
    # for the first vehicle, "../u/network-cache" for the second, each relative to a folder no file records)
    monkeypatch.chdir(tmp_path)
    with pytest.raises(KeyboardInterrupt):
        run_calibration(sim_root, "v1.0-sim", "u", conf, on_vehicle=stop)
    (tmp_path / "sub").mkdir()
    monkeypatch.chdir(tmp_path / "sub")
    run = run_calibration(sim_root, "v1.0-sim", "../u", conf)
    for vr in run.vehicles.values():
        assert vr.config["cache_dir"] == str((tmp_path / "u").resolve() / "network-cache"), vr.config["cache_dir"]
        assert vr.config["depth_cache"] == str((tmp_path / "u").resolve() / "depth-cache")
    # the oracle pipeline keeps them the same way, and the resumed run is the uninterrupted one
    from hybrid_calib.calib import pipeline

    with pytest.raises(KeyboardInterrupt):
        pipeline.calibrate(sim_root, "v1.0-sim", "oracle", tmp_path / "o", {"start": "R1"}, on_vehicle=stop,
                           progress=False)
    resumed = pipeline.calibrate(sim_root, "v1.0-sim", "oracle", tmp_path / "o", {"start": "R1"}, progress=False)
    whole = pipeline.calibrate(sim_root, "v1.0-sim", "oracle", tmp_path / "w", {"start": "R1"}, progress=False)
    for name in ("sim-veh-000", "sim-veh-001"):
        np.testing.assert_allclose(resumed.vehicles[name].final.T, whole.vehicles[name].final.T, atol=1e-12)


def test_every_method_starts_a_vehicle_from_the_same_extrinsic(sim_root, tmp_path):
    from hybrid_calib.calib.pipeline import CalibrateConfig, calibrate
    from hybrid_calib.hybrid import run_vehicle

    starts = {}
    for m in ("hybrid", "pure", "pure-avg", "oracle"):
        v = run_vehicle(sim_root, "v1.0-sim", "sim-veh-001", {**BASE, "method": m, "max_frames": 2,
                                                              "cache_dir": str(tmp_path / "cache")})
        starts[m] = np.asarray(v.start["T_cam_radar"])
        assert v.method == m and v.vehicle == "sim-veh-001"
        # what the method does not measure is prior-pinned in its verdict: a learned method's roll, pitch and height
        # (corrections.LEARNED_NOT_MEASURED), the oracle's pitch and height (the elevation prior; compare's oracle
        # lost them)
        pinned = {a for a, x in v.drift["axes"].items() if x["prior_pinned"]}
        assert pinned == ({"pitch", "vertical offset"} if m == "oracle" else {"pitch", "roll", "vertical offset"}), m
    for m, T in starts.items():
        np.testing.assert_array_equal(T, starts["hybrid"], err_msg=m)
    # the oracle pipeline of `calibrate` (all vehicles, one rng) draws the same start for this vehicle
    run = calibrate(sim_root, "v1.0-sim", "oracle", tmp_path / "o", CalibrateConfig(start="R1", seed=4, max_frames=1))
    first = run.vehicles["sim-veh-001"].trajectory[0]
    assert first.frame_id  # ran; the start it used:
    from hybrid_calib.perturbation import vehicle_start

    np.testing.assert_array_equal(vehicle_start(run.vehicles["sim-veh-001"].truth_T, "R1", 4, "sim-veh-001"),
                                  starts["oracle"])
    # another seed, another start
    v = run_vehicle(sim_root, "v1.0-sim", "sim-veh-001", {**BASE, "seed": 5, "method": "pure", "max_frames": 1,
                                                          "cache_dir": str(tmp_path / "cache")})
    assert not np.allclose(v.start["T_cam_radar"], starts["pure"])


def test_compare_smoke_resumes_and_writes_the_table(sim_root, tmp_path, capsys):
    from hybrid_calib.cli import main

    out = tmp_path / "cmp"
    argv = ["compare", "--data", str(sim_root), "--range", "R1", "--trials", "2", "--methods", "pure,pure-avg,hybrid",
            "--max-frames", "2", "--out", str(out), "--set", "threads=1", "window.detect_steps=false",
            "--no-progress"]
    assert main(argv) == 0
    s = json.loads((out / "compare.json").read_text())
    assert set(s["methods"]) == {"pure", "pure-avg", "hybrid"}
    for m in s["methods"].values():
        assert m["trials"] == 2 and 0 <= m["consistency"]["coverage_95"] <= 1 and "rot_mean_deg" in m["median"]
    md = (out / "compare.md").read_text()
    assert "| hybrid |" in md and "coverage" in md and (out / "error_vs_frames.png").stat().st_size > 1000
    assert "Command: `hybrid-calib compare --data" in md
    # how far a mean of 2 trials moves, and which methods look for a step (probe 131)
    assert "Spread over the trials (std of R.Mean, T.Mean): pure " in md and "within the trials' noise" in md
    assert "Step tests: hybrid looks for a step inside the drive" in md and "pure and pure-avg look for none" in md
    assert all(set(m["std"]) == set(m["mean"]) for m in s["methods"].values())
    trials = {m: [json.loads((out / "trials" / m / f"{k:04d}.json").read_text()) for k in range(2)]
              for m in ("pure", "pure-avg", "hybrid")}
    for k in range(2):
        assert trials["pure"][k]["start"] == trials["hybrid"][k]["start"] == trials["pure-avg"][k]["start"]
    mtime = (out / "trials" / "hybrid" / "0000.json").stat().st_mtime_ns
    capsys.readouterr()
    assert main(argv) == 0  # resumed: nothing recomputed, and said
    assert (out / "trials" / "hybrid" / "0000.json").stat().st_mtime_ns == mtime
    assert "kept 6 trial(s) an earlier run finished" in capsys.readouterr().out
    # the record says the trials ran from the range's starts (it said the default "reference"), and the folder
    # says which commands made and resumed it, and when
    record = json.loads((out / "compare_config.json").read_text())
    assert record["range"] == record["hybrid"]["start"] == "R1" and "method" not in record["hybrid"]
    runs = json.loads((out / "runs.json").read_text())
    assert [r["command"] for r in runs] == ["hybrid-calib " + " ".join(argv)] * 2
    assert all(r["exit_status"] == 0 and r["started_utc"] <= r["finished_utc"] for r in runs)
    assert main([*argv[:-1], "--seed", "3", "--no-progress"]) == 2  # another config in the same folder
    assert len(json.loads((out / "runs.json").read_text())) == 2  # a refused run is not a run of this folder
    assert "another configuration (seed: 0 -> 3)" in capsys.readouterr().err  # what differs, named
    # what does not change a trial does not block the rerun: the methods' order or a subset, the threads, the default
    # checkpoint spelled out (its contents are what counts)
    from hybrid_calib.hybrid.network import shipped_checkpoint

    same = [*argv[:8], "hybrid,pure", *["threads=2" if a == "threads=1" else a for a in argv[9:-1]], "--checkpoint",
            str(shipped_checkpoint("R1")), "--no-progress"]
    assert main(same) == 0 and (out / "trials" / "hybrid" / "0000.json").stat().st_mtime_ns == mtime
    # another method's or another trial's result in a trial's file is said and run again, never reported as it
    trial = out / "trials" / "hybrid" / "0000.json"
    for source in ("pure/0000.json", "hybrid/0001.json"):
        trial.write_text((out / "trials" / source).read_text())
        assert main(argv) == 0
        back = json.loads(trial.read_text())
        assert back["method"] == "hybrid" and back["config"]["trial"] == 0, source


def test_cascade_runs_the_refining_network_from_the_coarse_estimate(sim_root, tmp_path):
    from hybrid_calib.hybrid import run_vehicle
    from hybrid_calib.hybrid.network import CascadeRunner, OutputCache, build_runner, shipped_checkpoint
    from learned.dataset import open_frames

    frames = open_frames(sim_root, "v1.0-sim")
    r1 = shipped_checkpoint("R1")
    runner = build_runner(r1, r1, frames, cache_dir=tmp_path / "c", threads=1)
    assert isinstance(runner, CascadeRunner) and runner.range == "R1"
    T0 = frames[0].T_cam_radar @ np.array([[1, 0, 0, 0.05], [0, 1, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1.0]])
    out = runner.run(0, T0)
    coarse = OutputCache(tmp_path / "c" / "coarse").get(runner.token(0), T0)
    fine = OutputCache(tmp_path / "c" / "refine").get(runner.token(0), coarse.T)
    assert coarse is not None and fine is not None  # the refining pass started where the coarse one ended
    assert len(out.T_iters) == len(coarse.T_iters) + len(fine.T_iters)
    np.testing.assert_array_equal(out.T, fine.T)
    np.testing.assert_array_equal(out.cov_raw, fine.cov_raw)
    np.testing.assert_array_equal(out.rows_first.pixels, coarse.rows_first.pixels)  # measured against T0 only
    np.testing.assert_array_equal(out.T_in, T0)
    np.testing.assert_array_equal(runner.network_cov(out), runner.refine.network_cov(out))  # the last stage's
    for method in ("hybrid", "pure", "pure-avg"):  # pure and pure-avg ended in "no attribute 'network_cov'"
        v = run_vehicle(sim_root, "v1.0-sim", "sim-veh-000", {**BASE, "method": method, "max_frames": 2,
                                                              "refine": str(r1)})
        assert "->" in v.checkpoint and len(v.trajectory) == 2, method


def test_a_checkpoint_without_its_fitted_models_is_never_trusted(sim_root, tmp_path):
    import json
    import shutil

    from hybrid_calib.hybrid import run_vehicle
    from hybrid_calib.hybrid.network import shipped_checkpoint

    src = shipped_checkpoint("R1")
    meta = json.loads(src.read_text())
    meta["export"].pop("hybrid")  # e.g. a fine-tuned network whose measurement model was never refitted
    (tmp_path / src.name).write_text(json.dumps(meta))
    shutil.copy(src.with_suffix(".safetensors"), tmp_path / src.with_suffix(".safetensors").name)
    conf = {**BASE, "checkpoint": str(tmp_path / src.name)}  # all 3 frames: enough for the OOD rule
    v = run_vehicle(sim_root, "v1.0-sim", "sim-veh-000", {**conf, "method": "pure-avg"})
    assert v.final.status.startswith("inconclusive:") and "export.hybrid" in v.final.status
    # the first stage of a cascade too (probe 106: read 'weak' with the refining stage's drive error alone)
    v = run_vehicle(sim_root, "v1.0-sim", "sim-veh-000", {**conf, "method": "pure-avg", "refine": "shipped",
                                                          "max_frames": 2})
    assert v.final.status.startswith("inconclusive:") and "(the cascade's first stage) has no fitted export.hybrid" \
        in v.final.status, v.final.status
    v = run_vehicle(sim_root, "v1.0-sim", "sim-veh-000", {**conf, "method": "pure"})  # needs cov_scale only
    assert not v.final.status.startswith("inconclusive"), v.final.status
    # without its out-of-domain model no input is checked: inconclusive as the README says (probe 105: read 'weak' with
    # no word of the test), unless the test is switched off, which the status then names
    meta = json.loads(src.read_text())
    meta["export"].pop("ood")
    (tmp_path / src.name).write_text(json.dumps(meta))
    v = run_vehicle(sim_root, "v1.0-sim", "sim-veh-000", {**conf, "method": "pure"})
    assert v.final.status.startswith("inconclusive:") and "export.ood" in v.final.status, v.final.status
    assert "no frame was checked to be like the network's training drives" in v.final.status
    assert "--set ood.enabled=false" in v.final.status and v.ood["available"] is False
    assert "benchmarks/ood_fit.py --fit-into" in v.final.status  # the script stores nothing without it (probe 106)
    meta["export"].pop("hybrid")  # and its measurement model: the opt-out alone would not make it trusted
    (tmp_path / src.name).write_text(json.dumps(meta))
    v = run_vehicle(sim_root, "v1.0-sim", "sim-veh-000", {**conf, "method": "pure-avg"})
    assert "export.hybrid / export.ood" in v.final.status and "ood.enabled=false" not in v.final.status
    v = run_vehicle(sim_root, "v1.0-sim", "sim-veh-000", {**conf, "method": "pure", "ood": {"enabled": False}})
    assert not v.final.status.startswith("inconclusive") and "the out-of-domain test is off" in v.final.status


def test_drive_scale_brings_the_validation_nees_to_six_and_never_shrinks():
    from hybrid_calib.hybrid.fit import fit_drive_scale

    g = np.random.default_rng(3)
    true_std = np.array([0.02, 0.02, 0.03, 0.2, 0.1, 0.2])  # the drive-common error really is this big
    W = np.diag((0.1 * true_std) ** 2)  # the window's own covariance: small
    errors = g.normal(0.0, 1.0, (400, 6)) * np.sqrt(true_std ** 2 + np.diag(W))
    half = 0.5 * true_std  # fitted too small (few drives)
    covs = np.broadcast_to(W + np.diag(half ** 2), (400, 6, 6))
    k = fit_drive_scale(errors, covs, half)
    assert 1.8 < k < 2.2  # recovers the missing factor of 2
    D = np.diag((k * half) ** 2)
    assert abs(np.mean([e @ np.linalg.solve(W + D, e) for e in errors]) - 6.0) < 1e-6
    big = 3.0 * true_std  # already conservative: left alone
    assert fit_drive_scale(errors, np.broadcast_to(W + np.diag(big ** 2), (400, 6, 6)), big) == 1.0


def test_the_fitted_prior_scale_and_shared_std_are_not_biased_low_by_trimming():
    """Gaussian network errors whose covariance is really twice the exported one: the prior scale reads 2 (the
    trimmed mean alone read 1.52), and a per-frame shared error of known std is recovered, not shrunk (probe 28)."""
    from hybrid_calib.hybrid.fit import _trimmed_scale, fit_shared_std

    g = np.random.default_rng(11)
    ratio = 2.0 * g.normal(size=(20000, 6)) ** 2  # xi_k^2 / C_kk with the true variance 2 C_kk
    assert all(abs(_trimmed_scale(ratio[:, k]) - 2.0) < 0.08 for k in range(6))
    heavy = np.where(g.random(20000) < 0.03, 50.0, 1.0) * g.normal(size=20000) ** 2  # 3 % gross: the core's scale
    assert 0.9 < _trimmed_scale(heavy) < 1.25
    C = np.broadcast_to(np.diag(np.full(6, 0.01 ** 2)), (3000, 6, 6))
    shared = np.array([0.02, 0.0, 0.01, 0.03, 0.0, 0.015])
    xi = g.normal(size=(3000, 6)) * np.sqrt(0.01 ** 2 + shared ** 2)
    std = fit_shared_std(xi, C)
    big = shared > 0
    assert np.all(np.abs(std[big] / shared[big] - 1.0) < 0.1), std
    assert np.all(std[~big] < 0.006), std


def test_fit_calibrates_the_drive_term_on_the_loop_as_it_ships(sim_root, tmp_path):
    """Round 3 of the fit runs the chosen model with the motion constraint on (the product's loop) and
    only ever widens the drive-common term it calibrated without it."""
    from hybrid_calib.calib.result import CalibrationRun
    from hybrid_calib.hybrid.fit import fit_measurement

    res = fit_measurement([sim_root], "v1.0-sim", "learned/checkpoints/small-sim-r1.json", tmp_path, "R1",
                          rows_options=("none",), max_frames=3, seed=4)
    fitted = res["candidates"]["none"]
    s = fitted["summary"]
    assert s["drive_scale"] >= s["drive_scale_without_motion"] >= 1.0
    assert fitted["validation_with_motion"]["vehicles"] == 2
    assert fitted["validation_with_motion"]["nees_mean"] <= fitted["validation_with_motion"]["nees_mean_before"] + 1e-9
    assert res["chosen"]["drive_std"] == fitted["values"]["drive_std"]
    round2 = json.loads((tmp_path / "round2-none-0" / "config.json").read_text())
    round3 = json.loads((tmp_path / "round3-none-0" / "config.json").read_text())
    assert round2["motion"]["enabled"] is False and round3["motion"]["enabled"] is True
    assert CalibrationRun.load(tmp_path / "round3-none-0" / "result.json").vehicles
    # the fit reads the cached passes on the mount, as the loop does (probe 86: as the frame's X N, it took 7 of 24
    # passes for inside the range): each vehicle's first pass started from that vehicle's start, a mount
    from hybrid_calib.hybrid.fit import drive_truths, load_passes

    passes = load_passes(tmp_path / "network-cache-round1-none", drive_truths([sim_root], "v1.0-sim"))
    round1 = CalibrationRun.load(tmp_path / "round1-none-0" / "result.json")
    for v in round1.vehicles.values():
        T0 = np.asarray(v.start["T_cam_radar"])
        assert any(np.allclose(out.T_in, T0, atol=1e-9) for out, _ in passes), v.vehicle


def test_a_non_finite_network_pass_is_a_skipped_frame_not_the_end_of_the_run(sim_root, tmp_path, monkeypatch):
    """A depth map of NaN made the pass NaN and the run ended in 'internal error: GaussianPrior has NaN/inf
    entries' (calibrate, compare and a whole fleet)."""
    import dataclasses

    from hybrid_calib.hybrid import run_vehicle
    from hybrid_calib.hybrid.network import NetworkRunner

    out = _output(np.random.default_rng(0))
    assert out.finite and not dataclasses.replace(out, cov_raw=out.cov_raw * np.nan).finite
    real = NetworkRunner.forward
    poisoned = {}

    def forward(self, s, T_in):
        o = real(self, s, T_in)
        if not poisoned or poisoned.get("index") == s.get("index", 0):
            poisoned["index"] = s.get("index", 0)
            return dataclasses.replace(o, T_iters=o.T_iters * np.nan)
        return o

    monkeypatch.setattr(NetworkRunner, "forward", forward)
    for method in ("hybrid", "pure"):
        v = run_vehicle(sim_root, "v1.0-sim", "sim-veh-000", {**BASE, "method": method, "max_frames": 3,
                                                              "cache_dir": str(tmp_path / method)})
        assert np.isfinite(v.final.T).all() and len(v.skipped) >= 1, v.skipped
        assert "is not finite (NaN/inf)" in v.skipped[0]["reason"]


def test_compare_says_when_a_method_finished_fewer_trials():
    """A failed trial left its method's row averaged over fewer trials than the others', said nowhere near it."""
    from hybrid_calib.compare import CompareConfig, CompareResult, MethodSummary, TrialsRun, _markdown
    from hybrid_calib.config import merge
    from hybrid_calib.metrics import METRIC_KEYS

    conf = merge(CompareConfig, {"trials": 4, "methods": ("pure", "pure-avg", "hybrid")})
    errs = {k: 0.0 for k in METRIC_KEYS}

    def row(trials):
        return MethodSummary(trials, errs, errs, {"nees_mean": 6.0, "nees_median": 5.0, "coverage_95": 0.9}, {},
                             0.0, 0.0, 1.0, 3)

    def result(methods, left_out=None):
        return CompareResult("R1", 4, ("r",), "cmd", {}, methods, TrialsRun(left_out or {}, (), 0, 4))

    text = _markdown(result({"pure": row(4), "hybrid": row(3)}), conf, "cmd")
    assert "**Not every trial finished** (pure-avg: 0 of 4; hybrid: 3 of 4)" in text
    full = _markdown(result({m: row(4) for m in conf.methods}), conf, "cmd")
    assert "Not every trial" not in full and "Left out" not in full and "Inconclusive trials" not in full
    # inconclusive trials are said where their figures are read (probe 54: compare.json alone said so)
    unsure = dataclasses.replace(row(4), inconclusive_fraction=0.5)
    text = _markdown(result({"pure": row(4), "hybrid": unsure}), conf, "cmd")
    assert "| hybrid | 4 | 6.00 | 5.00 | 90 % | 0 % | 50 % |" in text
    assert "**Inconclusive trials** (hybrid: 2 of 4): their estimates are in the tables above but are not" in text
    assert "**Left out** (none of their frames reads" in _markdown(result({}, {"v": "why"}), conf, "cmd")
    # compare.json is the result's to_dict: the keys its readers use
    d = result({"pure": row(4)}).to_dict()
    assert set(d) >= {"methods", "vehicles_left_out", "trials_failed", "trials_kept", "trials_run", "roots"}
    assert d["methods"]["pure"]["trials"] == 4 and d["methods"]["pure"]["consistency"]["coverage_95"] == 0.9


def test_compare_refuses_kept_trials_of_other_data_and_leaves_out_a_root_that_does_not_read(sim_root, tmp_path,
                                                                                             capsys):
    """Trials of a re-simulated root at the same path were reported with the new root's as one row; oracle on a real
    root was refused only after trials had been written (and the corrected rerun then refused); one root with no
    readable vehicle ended the whole comparison."""
    import shutil

    from hybrid_calib.cli import main

    root = tmp_path / "root"
    shutil.copytree(sim_root, root)
    out = tmp_path / "cmp"
    argv = ["compare", "--data", str(root), "--methods", "oracle", "--trials", "2", "--out", str(out), "--set",
            "window.window=3", "--no-progress"]
    assert main(argv) == 0
    table = root / "v1.0-sim" / "sample_data.json"
    table.write_text(table.read_text() + "\n")  # the same path, other data (a re-simulation, a re-download)
    assert main(argv) == 2
    assert f"the data in {root.resolve()} as it was before" in capsys.readouterr().err
    assert main([*argv, "--overwrite"]) == 0 and main(argv) == 0
    # oracle on a real root: refused before anything is written
    real = tmp_path / "real"
    shutil.copytree(sim_root, real)
    (real / "v1.0-sim" / "sim_vehicle.json").unlink()
    assert main(["compare", "--data", str(real), "--methods", "pure,oracle", "--trials", "1", "--out",
                 str(tmp_path / "c2")]) == 2
    assert "oracle needs simulated roots" in capsys.readouterr().err and not (tmp_path / "c2").exists()
    # a root none of whose vehicles reads is left out (said, in compare.md too); the other root is compared
    bad = tmp_path / "bad"
    shutil.copytree(sim_root, bad)
    for d in (bad / "samples").iterdir():
        for f in d.iterdir():
            f.write_bytes(b"")
    assert main(["compare", "--data", str(root), str(bad), "--methods", "oracle", "--trials", "2", "--out",
                 str(tmp_path / "c3"), "--set", "window.window=3", "--no-progress"]) == 1
    s = json.loads((tmp_path / "c3" / "compare.json").read_text())
    assert s["methods"]["oracle"]["trials"] == 2 and f"every vehicle of {bad}" in s["vehicles_left_out"]
    assert "**Left out**" in (tmp_path / "c3" / "compare.md").read_text()
    # a root without the version folder (the trainval tables' root, a wrong folder): left out as fleet does, not the
    # whole comparison refused; alone, it is refused before anything is written
    tables_only = tmp_path / "tables-only"
    tables_only.mkdir()
    assert main(["compare", "--data", str(root), str(tables_only), "--methods", "oracle", "--trials", "1", "--out",
                 str(tmp_path / "c4"), "--set", "window.window=3", "--no-progress"]) == 1
    s = json.loads((tmp_path / "c4" / "compare.json").read_text())
    assert s["roots"] == [str(root)] and "version folder 'v1.0-sim' does not exist" in s["vehicles_left_out"][
        f"every vehicle of {tables_only}"]
    assert main(["compare", "--data", str(tables_only), "--methods", "oracle", "--trials", "1", "--out",
                 str(tmp_path / "c5")]) == 2
    assert "does not exist under the nuScenes root" in capsys.readouterr().err and not (tmp_path / "c5").exists()


def test_a_checkpoint_changed_in_place_is_another_network(sim_root, tmp_path):
    """calibrate reused its result ("the same data and options") after the checkpoint at --checkpoint was retrained;
    compare mixed trials of the two networks."""
    import shutil

    from hybrid_calib.compare import _differences
    from hybrid_calib.errors import HybridCalibError
    from hybrid_calib.hybrid import run_calibration
    from hybrid_calib.hybrid.network import shipped_checkpoint

    ck = tmp_path / "ck"
    ck.mkdir()
    for f in shipped_checkpoint("R1").parent.glob("small-sim-r1.*"):
        shutil.copy(f, ck / f.name)
    conf = {**BASE, "method": "pure", "checkpoint": str(ck / "small-sim-r1.json"), "max_frames": 1,
            "vehicles": ["sim-veh-000"]}
    run_calibration(sim_root, "v1.0-sim", tmp_path / "c", conf)
    run_calibration(sim_root, "v1.0-sim", tmp_path / "c", conf)  # unchanged: reused
    from hybrid_calib.hybrid.drives import trained_depth

    kept = (tmp_path / "c" / "result.json").stat().st_mtime_ns  # the default depth spelled out is the same run
    run_calibration(sim_root, "v1.0-sim", tmp_path / "c", {**conf, "depth": trained_depth(conf["checkpoint"])})
    assert (tmp_path / "c" / "result.json").stat().st_mtime_ns == kept
    weights = ck / "small-sim-r1.safetensors"
    weights.write_bytes(weights.read_bytes()[:-1] + b" ")  # retrained at the same path (its JSON with it)
    from learned.checkpoint import weights_sha256

    meta = json.loads((ck / "small-sim-r1.json").read_text())
    meta["files"]["weights_sha256"] = weights_sha256(weights)
    (ck / "small-sim-r1.json").write_text(json.dumps(meta))
    with pytest.raises(HybridCalibError, match="network checkpoint's files"):
        run_calibration(sim_root, "v1.0-sim", tmp_path / "c", conf)
    # --overwrite recomputes from the data as they are now: the run's own caches (keyed by frame token, which a
    # re-made root keeps) go too; measured: the old answer came back from them after the data had changed
    stale = tmp_path / "c" / "network-cache" / "stale-entry.npz"
    stale.write_bytes(b"x")
    run_calibration(sim_root, "v1.0-sim", tmp_path / "c", conf, overwrite=True)
    assert not stale.exists() and any((tmp_path / "c" / "network-cache").iterdir())
    a = {"range": "R1", "network": {"checkpoint": "aa"}, "data": {"roots": ["r"], "version": "v", "stamps": ["s"]}}
    assert _differences(a, {**a, "network": {"checkpoint": "bb"}}) == [
        "another network checkpoint (the checkpoint's files differ: another file, or retrained or edited at the same "
        "path)"]
    assert _differences(a, dict(a)) == []
    # no --checkpoint either time: another --range chose another shipped checkpoint (probe 45: it read as if the
    # user's checkpoint had been retrained or edited)
    other_range = _differences(a, {**a, "range": "R2", "network": {"checkpoint": "bb"}})
    assert other_range[0] == "another --range (R1 -> R2), and with it the shipped network checkpoint of that range"
    assert _differences({**a, "hybrid": {"checkpoint": "x.json"}}, {**a, "range": "R2", "hybrid": {
        "checkpoint": "x.json"}, "network": {"checkpoint": "bb"}})[0].startswith("another network checkpoint")


def test_compare_takes_each_root_once_and_tells_roots_of_one_folder_name_apart(sim_root, tmp_path, capsys):
    """The same root given twice made identical trials count as independent ones; the per-root rows merged roots
    that share a folder name (runs/urban/sim and runs/highway/sim read as one "sim")."""
    import shutil

    from hybrid_calib.cli import main

    a, b = tmp_path / "urban" / "sim", tmp_path / "highway" / "sim"
    shutil.copytree(sim_root, a)
    shutil.copytree(sim_root, b)
    base = ["compare", "--methods", "oracle", "--trials", "4", "--set", "window.window=3", "--no-progress"]
    assert main([*base, "--data", str(a), str(tmp_path / "urban" / ".." / "urban" / "sim"),
                 "--out", str(tmp_path / "c1")]) == 2
    assert "names the root" in capsys.readouterr().err and not (tmp_path / "c1").exists()
    assert main([*base, "--data", str(a), str(b), "--out", str(tmp_path / "c2")]) == 0
    rows = json.loads((tmp_path / "c2" / "compare.json").read_text())["methods"]["oracle"]["consistency_per_root"]
    assert set(rows) == {"urban/sim", "highway/sim"} and all(r["n"] == 2 for r in rows.values())


def test_a_network_reads_the_radar_sweeps_it_was_trained_on(tmp_path, capsys):
    """A network trained with --nsweeps 3 was fed 1 sweep per frame by calibrate and evaluate, silently: the
    checkpoint's run records its data, and the default now follows it (a differing --set is said)."""
    import shutil

    from hybrid_calib.config import merge
    from hybrid_calib.hybrid.loop import HybridConfig, _Session
    from hybrid_calib.hybrid.network import shipped_checkpoint
    from learned.checkpoint import trained_data

    ck = tmp_path / "run" / "checkpoints"
    ck.mkdir(parents=True)
    for f in shipped_checkpoint("R1").parent.glob("small-sim-r1.*"):
        shutil.copy(f, ck / f.name.replace("small-sim-r1", "ckpt-0001"))
    (tmp_path / "run" / "train_config.json").write_text(json.dumps({"data": {"roots": ["/r"], "nsweeps": 3}}))
    assert trained_data(tmp_path / "run")["nsweeps"] == 3 and trained_data(shipped_checkpoint("R1")) == {}
    session = _Session.__new__(_Session)
    conf = session._trained_sweeps(merge(HybridConfig, {}), ck / "ckpt-0001.json")
    assert conf.data["nsweeps"] == 3 and "3 radar sweeps per frame" in capsys.readouterr().err
    asked = merge(HybridConfig, {"data": {"nsweeps": 1}})
    assert session._trained_sweeps(asked, ck / "ckpt-0001.json") is asked
    assert "trained on 3 sweeps" in capsys.readouterr().err



def test_frames_that_do_not_read_do_not_widen_the_drive_error(sim_root, tmp_path, monkeypatch):
    """The hybrid's drive-common network error is counted over the network priors it fused: a drive of 3 frames
    whose last one does not read gives the 2-frame drive's covariance (it was wider by sqrt(3/2) along the
    network's axes: the error counted N / n times, N the drive's frames; probe 7: x1.35 with 5 of 10 unreadable)."""
    from hybrid_calib.hybrid import run_vehicle
    from hybrid_calib.hybrid.network import NetworkRunner

    conf = {**BASE, "method": "hybrid", "lidar": {"enabled": False}, "doppler": {"enabled": False}}
    two = run_vehicle(sim_root, "v1.0-sim", "sim-veh-000", {**conf, "max_frames": 2, "cache_dir": str(tmp_path / "a")})
    real, seen, bad = NetworkRunner.run, [], {}

    def run(self, index, T_in):  # the drive's last frame: its files do not read (``bad``)
        if index == bad.get("index"):
            return None
        seen.append(index)
        return real(self, index, T_in)

    monkeypatch.setattr(NetworkRunner, "run", run)
    full = run_vehicle(sim_root, "v1.0-sim", "sim-veh-000", {**conf, "cache_dir": str(tmp_path / "b")})
    assert full.n_frames == 3 and "drive_error_priors" not in full.config  # every frame read: no rerun
    bad["index"] = seen[-1]
    short = run_vehicle(sim_root, "v1.0-sim", "sim-veh-000", {**conf, "cache_dir": str(tmp_path / "c")})
    assert short.n_frames == 2 and short.config["drive_error_priors"] == 2 and len(short.skipped) == 1
    np.testing.assert_allclose(short.final.cov, two.final.cov, rtol=1e-6)
    np.testing.assert_allclose(short.final.T, two.final.T, atol=1e-9)
    assert np.all(np.diag(full.final.cov) < np.diag(two.final.cov))  # the third frame's information, when it reads



def test_a_drive_that_did_not_move_is_not_trusted(tmp_path):
    """A stand-still drive's frames repeat one view: its 1-sigma shrank from 1 frame to 10 with the same estimate
    (NEES 13.7 -> 23.3 on real data, probe 7). A learned result of it is 'inconclusive', saying why."""
    from hybrid_calib.data.nuscenes import NuScenesRadarCamera
    from hybrid_calib.hybrid.drives import Drive, standstill_reason
    from tests.tiny_nuscenes import VERSION, make_tiny_root

    said = {}
    for speed in (0.0, 15.0):
        tiny = make_tiny_root(tmp_path / f"v{speed:g}", n_samples=3, speed=speed)
        ds = NuScenesRadarCamera(tiny.root, VERSION, conf={"check_images": False})
        (idx,) = ds.frames_by_vehicle().values()
        said[speed] = standstill_reason(ds, Drive("tiny", idx, np.eye(4), np.eye(4), simulated=False))
    assert said[0.0].startswith("the vehicle did not move (its ego poses travel 0.00 m over 3 frames)")
    assert said[15.0] == ""  # 15 m/s for a second: it moved


def test_a_straight_road_is_named_in_the_hybrids_status():
    """Probe 16: no hybrid status named a straight road, the oracle's always did (the along-road rule of
    calib.degeneracy on the reflectors the network matched, its thresholds)."""
    from hybrid_calib.calib.degeneracy import RowGeometry
    from hybrid_calib.calib.result import Estimate, FrameEstimate
    from hybrid_calib.hybrid.corrections import with_road_words
    from hybrid_calib.hybrid.loop import HybridConfig

    def traj(status):
        est = Estimate(np.eye(4), np.eye(6) * 1e-4, np.ones(6), status)
        return [FrameEstimate(0, "f", 0, est, 1, 1, float("nan"), None, None, False, 0.0, 0.0)]

    g = np.random.default_rng(0)
    road, town = RowGeometry(), RowGeometry()
    for _ in range(5):  # kerbs 4 m either side, 5-60 m ahead; a town: reflectors all around
        x = g.uniform(5, 60, 40)
        road.add(np.column_stack([x, np.where(np.arange(40) % 2, 4.0, -4.0) + g.normal(0, 0.2, 40), 0 * x]))
        town.add(np.column_stack([x, g.uniform(-25, 25, 40), 0 * x]))
    conf = HybridConfig()
    assert with_road_words(traj("ok"), town, conf)[-1].estimate.status == "ok"
    assert with_road_words(traj("ok"), road, conf)[-1].estimate.status.startswith("weak: all the reflectors the "
                                                                                   "network matched lie along the road")
    weak = with_road_words(traj("weak: vertical offset is poorly observed"), road, conf)[-1].estimate.status
    assert weak.startswith("weak: vertical offset is poorly observed; all the reflectors") and "% on two lines" in weak
    assert with_road_words(traj("inconclusive: why"), road, conf)[-1].estimate.status == "inconclusive: why"


def test_what_a_learned_method_does_not_measure_is_named_in_its_status():
    """Session 22: the hybrid's roll and pitch moved by at most 0.18 deg whatever the radar's tilt (1.5-2 deg in roll
    and / or pitch, simulated, same seeds), and its height is the start's; probe 16 saw a pitched radar read "differs
    by 0.07 deg +- 0.82 deg" with a status naming only offsets. The status names the three prior-pinned, each once."""
    from hybrid_calib.calib.result import Estimate, FrameEstimate
    from hybrid_calib.hybrid.corrections import with_prior_words

    def traj(status, weak=()):
        est = Estimate(np.eye(4), np.eye(6) * 1e-4, np.array([0.8, 0.3, 0.7, 2.0, 14.0, 9.0]), status,
                       weak_directions=weak)
        return [FrameEstimate(0, "f", 0, est, 1, 1, float("nan"), None, None, False, 0.0, 0.0)]

    ok = with_prior_words(traj("ok"))[-1].estimate.status
    assert ok.startswith("weak: roll, pitch and vertical offset are prior-pinned, not measured by this drive (")
    assert "std roll 0.70 deg, pitch 0.80 deg, vertical offset 14 cm" in ok and "tilted or raised" in ok
    named = "weak: vertical offset (translation along camera y) is prior-pinned, not measured (std 14 cm)"
    weak = with_prior_words(traj(named))[-1].estimate.status
    assert weak.startswith(named + "; roll and pitch are prior-pinned") and weak.count("vertical offset") == 1
    # the directions the data could not pin list them too (probe 120: the report's "could not pin" left them out)
    assert with_prior_words(traj("ok"))[-1].estimate.weak_directions == (
        "roll (rotation about camera z)", "pitch (rotation about camera x)",
        "vertical offset (translation along camera y)")
    vertical = ("vertical offset (translation along camera y)",)
    assert with_prior_words(traj(named, vertical))[-1].estimate.weak_directions == (
        *vertical, "roll (rotation about camera z)", "pitch (rotation about camera x)")
    assert with_prior_words(traj("inconclusive: why", vertical))[-1].estimate.weak_directions == vertical
    assert "the vertical offset is the start's" not in weak
    assert with_prior_words(traj("inconclusive: why"))[-1].estimate.status == "inconclusive: why"
    assert with_prior_words([]) == []


@pytest.mark.parametrize("motion", [True, False])
def test_the_drive_common_network_error_reaches_the_reported_covariance(sim_root, tmp_path, motion):
    """The network's error common to a drive (``export.hybrid.drive_std``) does not average over frames: with the
    motion constraint it enters each prior N times (N frames fused: ``C / N + D``), without it it is added to the
    fused covariance. Either way no axis the network alone measures may end below ``D`` (a mutation probe found both
    terms unpinned: a covariance 3x too small passed)."""
    from hybrid_calib.hybrid import run_vehicle

    D = np.array([0.01] * 3 + [1.0] * 3)  # 1 m on translation: far above what 3 frames of the network resolve
    v = run_vehicle(sim_root, "v1.0-sim", "sim-veh-000", {
        **BASE, "method": "hybrid", "lidar": {"enabled": False}, "doppler": {"enabled": False},
        "motion": {"enabled": motion}, "measurement": {"rows": "none", "drive_std": D.tolist()},
        "ood": {"enabled": False}, "cache_dir": str(tmp_path / "cache")})
    assert v.n_frames == 3
    assert np.all(np.diag(v.final.cov)[3:] >= 0.99 * D[3:] ** 2), np.sqrt(np.diag(v.final.cov))


def test_the_hybrid_s_rows_name_the_plane_their_heights_are_measured_from(sim_root, tmp_path):
    from hybrid_calib.hybrid import run_vehicle

    v = run_vehicle(sim_root, "v1.0-sim", "sim-veh-000", {
        **BASE, "method": "hybrid", "lidar": {"enabled": False}, "doppler": {"enabled": False},
        "measurement": {"rows": "first"}, "ood": {"enabled": False}, "cache_dir": str(tmp_path / "cache")})
    assert sum(r["used"] for r in v.frame_rows) > 0
    assert v.height_plane["plane"] == "radar" and "the hybrid's rows" in v.height_plane["words"], v.height_plane


@pytest.mark.parametrize("case", ["network stayed", "network moved", "window restarted"])
def test_the_loop_gives_the_motion_gate_the_networks_own_residual_and_restarts_it_with_the_window(
        sim_root, tmp_path, monkeypatch, case):
    """The wiring of ``MotionGate`` in the loop: the residual at the network's own output of the frame decides a
    consensus against a confirmed estimate (probe 41), the refusal is recorded with its reason, and a window restart
    (a step alarm) makes the estimate unconfirmed again. Frame 1's residual agrees; frame 2's is 10 deg beyond the
    gate (``confirm`` and ``consensus`` 1 on this 3-frame drive)."""
    from types import SimpleNamespace

    from hybrid_calib.calib.window import SlidingWindowCalibrator
    from hybrid_calib.hybrid import loop, run_vehicle
    from hybrid_calib.hybrid.motion import Innovation, MotionSource

    s = np.radians(1.13)
    r_deg = iter([0.2, 10.0])
    r_net_deg = iter([0.2, 1.0 if case == "network moved" else 10.0])
    monkeypatch.setattr(MotionSource, "measurement",
                        lambda self, ia, ib, R, ego=True: (SimpleNamespace(speed=10.0, n_vo_inliers=20), ""))
    monkeypatch.setattr(loop, "gated_innovation", lambda T, m, conf, covs, simulated=True: Innovation(
        np.radians(next(r_deg)), np.array([0.0, 0.0, 1.0, 0.0, 0.0, 0.0]), s, 1.2 * s))
    monkeypatch.setattr(loop, "heading_residual", lambda T, m: (np.radians(next(r_net_deg)), np.zeros(6)))
    if case == "window restarted":
        real, calls = SlidingWindowCalibrator.update, []

        def update(self, corr, prior=None, timestamp_us=None):
            calls.append(1)
            fe = real(self, corr, prior, timestamp_us)
            return dataclasses.replace(fe, step_alarm=True) if len(calls) == 2 else fe

        monkeypatch.setattr(SlidingWindowCalibrator, "update", update)
    v = run_vehicle(sim_root, "v1.0-sim", "sim-veh-000", {
        **BASE, "method": "hybrid", "lidar": {"enabled": False}, "doppler": {"enabled": False},
        "ood": {"enabled": False}, "motion": {"confirm": 1, "consensus": 1}, "cache_dir": str(tmp_path / "cache")})
    rows = v.frame_rows
    assert len(rows) == 3 and rows[1]["motion"]["residual_deg"] == pytest.approx(0.2)
    if case == "network stayed":
        assert "motion" not in rows[2] and "did not move toward them" in rows[2]["motion_skipped"], rows[2]
    else:
        assert rows[2]["motion"]["admitted"] == "consensus", rows[2]


def test_each_step_of_the_mount_monitor_raises_its_own_alarm_in_a_drift(sim_root, tmp_path):
    """Probe 43: in a drift the monitor's next step changes from the frame of its last step's alarm, and the loop took
    that alarm for the new step's ("the same step as the window's alarm at frame 23"): 4 steps, 2 alarms. Each step
    applied raises its own alarm unless the window's test fired for it."""
    from types import SimpleNamespace

    from hybrid_calib.config import merge
    from hybrid_calib.hybrid import loop
    from hybrid_calib.hybrid.drives import start_of

    conf = merge(loop.HybridConfig, {**BASE, "method": "hybrid", "vehicles": ["sim-veh-000"], "ood": {"enabled": False},
                                     "lidar": {"enabled": False}, "doppler": {"enabled": False},
                                     "cache_dir": str(tmp_path / "cache")})
    session = loop._Session(sim_root, "v1.0-sim", conf)
    drive = session.drives["sim-veh-000"]

    class Monitor:  # a step found at frames 1 and 2, each changing from the frame before it
        def update(self, k, i):
            step = SimpleNamespace(change=k - 1, step_deg=0.3, describe=lambda threshold: f"step from {k - 1}")
            return SimpleNamespace(step=step if k in (1, 2) else None, record=lambda: {})

    traj = loop._hybrid(session.runner, drive, start_of(drive, session.conf), session.conf, loop._Trace(), None,
                        Monitor())
    assert [f.step_alarm for f in traj] == [False, True, True], [f.events for f in traj]
    assert not any("the same step as" in e for f in traj for e in f.events)


def test_with_drive_error_adds_the_drive_common_term_to_every_frame():
    from hybrid_calib.calib.covariance import report_std
    from hybrid_calib.calib.result import Estimate, FrameEstimate
    from hybrid_calib.hybrid.corrections import with_drive_error
    from hybrid_calib.hybrid.loop import HybridConfig

    T = np.eye(4)
    cov = np.diag([1e-6] * 3 + [1e-4] * 3)
    traj = [FrameEstimate(k, "f", 0, Estimate(T, cov, np.ones(6), "ok"), 1, 1, float("nan"), None, None, False, 0.0,
                          0.0) for k in range(2)]
    std = np.array([0.002, 0.003, 0.004, 0.05, 0.06, 0.07])
    out = with_drive_error(traj, std, HybridConfig())
    for f in out:
        np.testing.assert_allclose(f.cov, cov + np.diag(std ** 2), rtol=1e-12)
        np.testing.assert_allclose(f.estimate.std, report_std(T, cov + np.diag(std ** 2)))  # re-read, not kept
    assert with_drive_error(traj, np.zeros(6), HybridConfig()) is traj


def test_frames_are_counted_by_their_position_in_the_drive(sim_root, tmp_path, monkeypatch):
    """A skipped frame's index is its position in the drive, as the trajectory's and the step alarms' (probe 24: a
    20-frame drive's hybrid result listed 'index 21', the root's count, for its frame 1); the oracle's trajectory
    counts drive positions too, not the frames its window used."""
    from hybrid_calib.calib.pipeline import calibrate
    from hybrid_calib.data.nuscenes import NuScenesRadarCamera
    from hybrid_calib.hybrid import run_vehicle
    from hybrid_calib.hybrid.network import NetworkRunner

    ds = NuScenesRadarCamera(sim_root, "v1.0-sim", conf={"check_images": False})
    idx = ds.frames_by_vehicle()["sim-veh-001"]
    assert idx[1] != 1  # the root's count and the drive's differ for this vehicle
    real = NetworkRunner.run
    monkeypatch.setattr(NetworkRunner, "run", lambda self, i, T: None if i == idx[1] else real(self, i, T))
    v = run_vehicle(sim_root, "v1.0-sim", "sim-veh-001", {**BASE, "method": "hybrid", "cache_dir": str(tmp_path / "h"),
                                                          "lidar": {"enabled": False}, "doppler": {"enabled": False}})
    assert [s["index"] for s in v.skipped] == [1] and [f.index for f in v.trajectory] == [0, 2]
    root = tmp_path / "root"
    shutil.copytree(sim_root, root)
    (root / ds.frames[idx[1]].radar_sd["filename"]).write_bytes(b"not a pcd file\x00\x01")
    run = calibrate(root, "v1.0-sim", "oracle", tmp_path / "o", {"vehicles": ["sim-veh-001"], "window": {"window": 3}},
                    progress=False)
    o = run.vehicles["sim-veh-001"]
    assert [s["index"] for s in o.skipped] == [1] and [f.index for f in o.trajectory] == [0, 2], o.skipped


def test_a_cache_shared_by_two_roots_of_the_same_tokens_keeps_them_apart(sim_root, tmp_path):
    """Probe 23: a root and its copy with other camera images (the same tokens) gave bit-identical answers through
    one --set cache_dir (and compare's one cache for all its roots); each root's answer is now its own."""
    import cv2

    from hybrid_calib.data.nuscenes import NuScenesRadarCamera
    from hybrid_calib.hybrid import run_vehicle

    copy = tmp_path / "copy"
    shutil.copytree(sim_root, copy)
    ds = NuScenesRadarCamera(copy, "v1.0-sim", conf={"check_images": False})
    for i in ds.frames_by_vehicle()["sim-veh-000"]:  # the camera looks elsewhere: its images mirrored
        p = copy / ds.frames[i].camera_sd["filename"]
        cv2.imwrite(str(p), cv2.imread(str(p))[:, ::-1])
    conf = {**BASE, "method": "pure", "max_frames": 2, "lidar": {"enabled": False}, "doppler": {"enabled": False}}
    shared = {**conf, "cache_dir": str(tmp_path / "shared"), "depth_cache": str(tmp_path / "shared-depth")}
    a = run_vehicle(sim_root, "v1.0-sim", "sim-veh-000", shared)
    b = run_vehicle(copy, "v1.0-sim", "sim-veh-000", shared)
    alone = run_vehicle(copy, "v1.0-sim", "sim-veh-000", {**conf, "cache_dir": str(tmp_path / "alone")})
    np.testing.assert_allclose(b.final.T, alone.final.T, atol=1e-9)
    assert not np.allclose(a.final.T, b.final.T, atol=1e-6)


def test_a_cascades_drive_common_error_is_not_below_its_coarse_networks():
    """The shipped R0 block (fitted on 3 drives for the cascade) put the lateral drive-common std at 1.1 mm against the
    R1 network's 10 cm: a 10-frame drive read "differs by 8.15 cm (+- 1.68 cm): recalibrate", 4.5 sigma from the
    truth (probe 32). The refining pass starts where the coarse one ended: no axis below the coarse network's."""
    from types import SimpleNamespace

    from hybrid_calib.hybrid.loop import HybridConfig, measurement_config
    from hybrid_calib.hybrid.network import shipped_checkpoint

    def runner(name):
        return SimpleNamespace(ckpt=SimpleNamespace(export=json.loads(shipped_checkpoint(name).read_text())["export"],
                                                    path=shipped_checkpoint(name)))

    fine, coarse = runner("R0"), runner("R1")
    r0, r1 = (np.array(r.ckpt.export["hybrid"]["drive_std"]) for r in (fine, coarse))
    assert r0[4] < 0.01 < r1[4]  # the shipped blocks this guards against
    alone = measurement_config(fine, HybridConfig())
    cascade = measurement_config(SimpleNamespace(ckpt=fine.ckpt, coarse=coarse), HybridConfig())
    np.testing.assert_array_equal(alone.drive_std, r0)
    np.testing.assert_array_equal(cascade.drive_std, np.maximum(r0, r1))
    assert cascade.prior_cov_scale == alone.prior_cov_scale  # the refining block otherwise as fitted
    # an explicit --set measurement.drive_std still wins
    mine = measurement_config(SimpleNamespace(ckpt=fine.ckpt, coarse=coarse),
                              HybridConfig(measurement={"drive_std": [0.01] * 6}))
    assert mine.drive_std == (0.01,) * 6


def _blown_up_checkpoint(folder):
    """The shipped R1 checkpoint with three conv weights x 1e30 (finite, hash updated): every pass is NaN / inf."""
    from safetensors import safe_open
    from safetensors.torch import load_file, save_file

    from hybrid_calib.hybrid.network import shipped_checkpoint
    from learned.checkpoint import weights_sha256

    src = shipped_checkpoint("R1")
    state = load_file(str(src.with_suffix(".safetensors")))
    for k in [k for k, v in state.items() if v.ndim == 4][:3]:
        state[k] = state[k] * 1e30
    with safe_open(str(src.with_suffix(".safetensors")), "pt") as f:
        metadata = f.metadata()
    folder.mkdir(parents=True, exist_ok=True)
    save_file(state, str(folder / "blown.safetensors"), metadata=metadata)
    meta = json.loads(src.read_text())
    meta["files"] = {**meta["files"], "weights": "blown.safetensors",
                     "weights_sha256": weights_sha256(folder / "blown.safetensors")}
    (folder / "blown.json").write_text(json.dumps(meta))
    return folder / "blown.json"


def test_a_network_whose_output_is_not_finite_skips_its_frames_and_says_why(sim_root, tmp_path, capsys):
    """An SVD of the NaN output ran before the finiteness check: exit 3 'internal error'; evaluate wrote the NaN
    passes as predictions and then called its own files corrupt on every rerun (probe 33)."""
    from hybrid_calib.cli import main
    from hybrid_calib.data.nuscenes import NuScenesRadarCamera
    from hybrid_calib.hybrid.network import build_runner

    ckpt = _blown_up_checkpoint(tmp_path / "ck")
    frames = NuScenesRadarCamera(sim_root, "v1.0-sim", conf={"check_images": False})
    runner = build_runner(ckpt, None, frames, depth="corrupted-truth")
    assert runner.run(0, frames[0].T_cam_radar) is None and "is not finite (NaN/inf)" in runner.bad_reason(0)
    # its inputs are finite: the weights are named, not the frame's depth map, image or radar (probe 45)
    assert "although its inputs are finite" in runner.bad_reason(0) and str(ckpt) in runner.bad_reason(0)
    argv = ["evaluate", "--data", str(sim_root), "--split", "all", "--range", "R1", "--checkpoint", str(ckpt),
            "--max-frames", "2", "--out", str(tmp_path / "ev"), "--no-progress"]
    for _ in range(2):  # and the same words on a rerun
        assert main(argv) == 2
        assert "every frame to export failed" in (err := capsys.readouterr().err) and "is not finite" in err
        skipped = json.loads((tmp_path / "ev" / "skipped.json").read_text())
        assert "although its inputs are finite" in json.dumps(skipped), skipped
        assert not list((tmp_path / "ev" / "frames").glob("*.npz")) if (tmp_path / "ev" / "frames").exists() else True


def test_a_non_finite_output_blames_the_inputs_only_when_they_are_not_finite():
    import torch

    from learned.export import not_finite_reason

    depth = torch.zeros(2, 1, 4, 4)
    depth[1, 0, 2, 2] = float("nan")
    inputs = {"depth": depth, "image": torch.zeros(2, 3, 4, 4), "n": torch.tensor([3, 4])}
    assert "inputs hold NaN/inf (depth:" in not_finite_reason("tok", inputs, 1)
    assert "although its inputs are finite" in not_finite_reason("tok", inputs, 0, "ck.json")
    assert "(ck.json)" in not_finite_reason("tok", inputs, 0, "ck.json")


def test_compare_says_once_when_its_range_is_wider_than_the_checkpoints(sim_root, tmp_path, capsys):
    """Probe 45: --range R2 with the R1 checkpoint wrote a pure row of NEES 64 and said nothing (calibrate notes it)."""
    from hybrid_calib.cli import main
    from hybrid_calib.hybrid.network import shipped_checkpoint

    argv = ["compare", "--data", str(sim_root), "--range", "R2", "--checkpoint", str(shipped_checkpoint("R1")),
            "--trials", "1", "--methods", "pure", "--max-frames", "1", "--out", str(tmp_path / "c"), "--no-progress"]
    assert main(argv) == 0
    said = capsys.readouterr().out
    assert said.count("note: the start range R2") == 1 and "wider than the R1 range" in said, said
    (note,) = json.loads((tmp_path / "c" / "compare.json").read_text())["notes"]
    assert "wider than the R1 range" in note and note in (tmp_path / "c" / "compare.md").read_text()


def test_compare_on_a_broken_checkpoint_names_it_and_runs_once_it_is_repaired(sim_root, tmp_path, capsys):
    """It said "no vehicle in [root]: weights file ..." and kept compare_config.json, so the same command after the
    user copied the checkpoint again was refused as "holds trials of another network checkpoint" (none had run)."""
    import shutil

    from hybrid_calib.cli import main
    from hybrid_calib.hybrid.network import shipped_checkpoint

    for suffix in (".json", ".safetensors"):
        shutil.copy(shipped_checkpoint("R1").with_suffix(suffix), tmp_path / f"small-sim-r1{suffix}")
    weights = tmp_path / "small-sim-r1.safetensors"
    good = weights.read_bytes()
    weights.write_bytes(good[: len(good) // 2])
    argv = ["compare", "--data", str(sim_root), "--range", "R1", "--trials", "1", "--methods", "pure",
            "--max-frames", "1", "--checkpoint", str(tmp_path / "small-sim-r1.json"), "--out", str(tmp_path / "c"),
            "--set", "threads=1", "--no-progress"]
    assert main(argv) == 2
    err = capsys.readouterr().err
    assert "not a valid safetensors file" in err and "no vehicle in" not in err
    weights.write_bytes(good)  # copied again, as the message says
    assert main(argv) == 0, capsys.readouterr().err


def test_a_cascade_missing_fits_in_both_stages_names_both():
    from types import SimpleNamespace

    from hybrid_calib.hybrid.loop import unfitted_reason
    from hybrid_calib.hybrid.measurement import FITTED_KEYS

    def stage(path, export):
        return SimpleNamespace(ckpt=SimpleNamespace(path=path, export=export))

    block = {k: 1.0 for k in FITTED_KEYS}
    fitted = {"cov_scale": 1.0, "hybrid": block, "ood": {}}
    cascade = SimpleNamespace(**vars(stage("fine.json", {"cov_scale": 1.0})), coarse=stage("coarse.json", {}))
    why = unfitted_reason(cascade, "hybrid")
    assert "coarse.json (the cascade's first stage) has no fitted export.hybrid" in why, why
    assert "fine.json has no fitted export.hybrid / export.ood" in why, why  # the second stage too, in one status
    assert "ood.enabled=false" not in why  # that alone would not make the run trusted
    cascade = SimpleNamespace(**vars(stage("fine.json", fitted)), coarse=stage("coarse.json", {}))
    assert unfitted_reason(cascade, "hybrid").startswith(f"checkpoint {Path('coarse.json').resolve()} (the cascade's "
                                                         "first stage)")
    cascade = SimpleNamespace(**vars(stage("fine.json", {"cov_scale": 1.0, "hybrid": block})),
                              coarse=stage("coarse.json", fitted))
    assert unfitted_reason(cascade, "pure-avg").endswith("--set ood.enabled=false, which the status then names)")
    assert unfitted_reason(cascade, "pure-avg", ood_enabled=False) == ""


@pytest.mark.parametrize("block", [{}, "drive_std", "rows"], ids=["empty", "no-drive_std", "no-rows"])
def test_an_export_hybrid_block_that_is_not_a_whole_fit_is_unfitted(block):
    """An empty export.hybrid, or one lacking drive_std or rows, counted as fitted: its defaults (a drive error of 0)
    read "recalibrate" by 3.1 deg on an unchanged radar at NEES 223 (probe 109). It is unfitted, naming what it lacks,
    in a cascade's first stage too."""
    from types import SimpleNamespace

    from hybrid_calib.hybrid.loop import unfitted_reason
    from hybrid_calib.hybrid.measurement import FITTED_KEYS

    whole = {k: 1.0 for k in FITTED_KEYS}
    part = {} if block == {} else {k: v for k, v in whole.items() if k != block}
    ck = SimpleNamespace(ckpt=SimpleNamespace(path="c.json", export={"cov_scale": 1.0, "hybrid": part, "ood": {}}))
    why = unfitted_reason(ck, "hybrid")
    lacks = ", ".join(FITTED_KEYS) if block == {} else block
    assert why.startswith(f"checkpoint {Path('c.json').resolve()} has no fitted export.hybrid (its block lacks "
                          f"{lacks})"), why
    assert unfitted_reason(ck, "pure") == ""  # pure reads cov_scale only
    whole_ck = SimpleNamespace(ckpt=SimpleNamespace(path="f.json", export={"cov_scale": 1.0, "hybrid": whole,
                                                                             "ood": {}}))
    assert unfitted_reason(whole_ck, "hybrid") == ""
    cascade = SimpleNamespace(**vars(whole_ck), coarse=ck)
    assert "c.json (the cascade's first stage) has no fitted export.hybrid" in unfitted_reason(cascade, "pure-avg")


def test_a_result_names_its_checkpoint_by_its_absolute_path(sim_root, tmp_path, monkeypatch):
    """A relative --checkpoint was recorded as typed, and report run from another folder drew another network's
    attention under that name (probe 109)."""
    import shutil

    from hybrid_calib.hybrid import run_vehicle
    from hybrid_calib.hybrid.network import shipped_checkpoint

    src = shipped_checkpoint("R1")
    (tmp_path / "ck").mkdir()
    for p in (src, src.with_suffix(".safetensors")):
        shutil.copy(p, tmp_path / "ck" / p.name)
    monkeypatch.chdir(tmp_path)
    v = run_vehicle(sim_root, "v1.0-sim", "sim-veh-000", {**BASE, "method": "pure", "max_frames": 1,
                                                          "checkpoint": f"ck/{src.name}"})
    assert v.checkpoint == str(tmp_path / "ck" / src.name), v.checkpoint


def test_compare_counts_each_trial_under_its_own_root_however_it_was_typed(tmp_path, monkeypatch):
    """Probe 113: a compare resumed with its roots typed otherwise (absolute, then relative) put a root's kept trials
    under another root of the same folder name (a/sim, b/sim), silently: the per-root NEES rows were wrong."""
    from hybrid_calib.calib.result import Estimate, VehicleResult
    from hybrid_calib.compare import summarize_method
    from hybrid_calib.data.files import root_labels
    from hybrid_calib.metrics import METRIC_KEYS

    monkeypatch.chdir(tmp_path)
    for r in ("a/sim", "b/sim"):
        (tmp_path / r).mkdir(parents=True)

    def trial(root: str, nees: float) -> VehicleResult:
        return VehicleResult("v", Estimate(np.eye(4), np.eye(6), np.ones(6), "ok"), config={"root": root},
                             error={**dict.fromkeys(METRIC_KEYS, 0.1), "nees": nees})

    trials = [trial(str(tmp_path / "a/sim"), 1.0), trial(str(tmp_path / "a/sim"), 3.0),
              trial(str(tmp_path / "b/sim"), 20.0), trial("b/sim", 4.0), trial("./b/sim", 6.0)]
    rows = summarize_method(trials, root_labels(["a/sim", "b/sim"], "/")).consistency_per_root
    assert sorted(rows) == ["a/sim", "b/sim"], rows
    assert rows["a/sim"]["n"] == 2 and rows["a/sim"]["nees_mean"] == 2.0
    assert rows["b/sim"]["n"] == 3 and rows["b/sim"]["nees_mean"] == 10.0


def test_a_learned_roll_or_pitch_far_from_the_tables_is_not_trusted():
    """Probe 122: a camera mounted with an 8 deg roll (tables right) and a cropped image read the hybrid's roll or
    pitch 5.6-6.1 deg off, 6.6-8 sigma, under a `weak` status: the network's learned prior, which this drive does not
    measure, left the tables by more than 3 stds beyond the tolerance; said, and the result is not trusted."""
    from types import SimpleNamespace

    from hybrid_calib.hybrid.loop import learned_prior_reason

    def axes(roll, pitch=0.1, yaw=4.0):
        return {"roll": {"delta": roll, "std": 0.77, "tolerance": 0.5, "prior_pinned": True},
                "pitch": {"delta": pitch, "std": 0.8, "tolerance": 0.5, "prior_pinned": True},
                "yaw": {"delta": yaw, "std": 0.1, "tolerance": 0.5, "prior_pinned": False}}

    far = learned_prior_reason(SimpleNamespace(drift={"axes": axes(-6.07)}))
    assert far.startswith("the network's roll (its learned prior of the radar's mount, seen through the camera: this "
                          "drive does not measure it) differs from the tables' roll by 6.07 deg (7.9 stds)")
    assert "a rolled or tilted camera, a cropped image" in far
    assert learned_prior_reason(SimpleNamespace(drift={"axes": axes(2.0)})) == ""  # within 3 stds of the tolerance
    assert learned_prior_reason(SimpleNamespace(drift={"axes": axes(0.1, yaw=40.0)})) == ""  # a measured axis: not it
    assert learned_prior_reason(SimpleNamespace(drift=None)) == ""


def test_a_root_rewritten_while_a_run_reads_it_gives_no_result(sim_root, tmp_path):
    """Probe 142: ``simulate --overwrite`` started after a calibrate was refused nothing (a reader holds no lock):
    calibrate blamed each vanished frame on "a partial download" and wrote a result of old and new frames. The root's
    tables and sensor folders are looked at again at the end: a root rewritten meanwhile gives no result, said."""
    from hybrid_calib.errors import DataError
    from hybrid_calib.hybrid import run_calibration

    table = sim_root / "v1.0-sim" / "sample.json"

    def rewritten(vr):  # another process replaced the file (the same content here, so other tests read it as it was)
        text = table.read_text()
        table.unlink()
        table.write_text(text)

    def refilled(vr):  # a sensor folder replaced (simulate --overwrite removes them first): frames vanished meanwhile
        folder = sim_root / "samples" / "CAM_FRONT"
        folder.rename(folder.with_name("gone"))
        folder.with_name("gone").rename(folder)  # (the same files here, so other tests read them as they were)
        (folder / "x").write_text(""), (folder / "x").unlink()

    from hybrid_calib.calib.pipeline import calibrate

    # tables of the same bytes are the same data (probe 144: simulate run again on a complete root rewrites them)
    run = run_calibration(sim_root, "v1.0-sim", tmp_path / "same", {**BASE, "method": "oracle"}, on_vehicle=rewritten)
    assert len(run.vehicles) == 2
    for method in ("hybrid", "oracle"):  # the learned methods' loop; calibrate's oracle and --correspondences path
        with pytest.raises(DataError, match="changed while this run read it .* the vehicles it finished are discarded"):
            if method == "hybrid":
                run_calibration(sim_root, "v1.0-sim", tmp_path / method, {**BASE, "method": "pure-avg"},
                                on_vehicle=refilled)
            else:
                calibrate(sim_root, "v1.0-sim", "oracle", tmp_path / method, {"window": {"window": 3}},
                          on_vehicle=refilled, progress=False)
        assert not (tmp_path / method / "result.json").exists()
        assert not (tmp_path / method / "vehicles-done").exists()  # probe 144: a rerun reused them


def test_a_compare_row_takes_the_median_and_counts_every_status_that_is_not_ok():
    """Probe 151 (mutation testing): the median row computed as the mean, and "not ok" counting only `weak`, passed
    every compare test (two trials, where median and mean agree; no status but ok)."""
    from hybrid_calib.calib.result import Estimate, VehicleResult
    from hybrid_calib.compare import summarize_method
    from hybrid_calib.metrics import METRIC_KEYS

    def trial(err: float, status: str) -> VehicleResult:
        return VehicleResult("v", Estimate(np.eye(4), np.eye(6), np.ones(6), status), config={"root": "r"},
                             error={**dict.fromkeys(METRIC_KEYS, err), "nees": 6.0})

    row = summarize_method([trial(0.1, "ok"), trial(0.2, "weak: yaw"), trial(0.3, "inconclusive: few frames"),
                            trial(0.4, "degenerate: roll"), trial(9.0, "ok")])
    assert row.median["rot_mean_deg"] == pytest.approx(0.3) and row.mean["rot_mean_deg"] == pytest.approx(2.0)
    assert row.not_ok_fraction == pytest.approx(3 / 5) and row.inconclusive_fraction == pytest.approx(1 / 5)
