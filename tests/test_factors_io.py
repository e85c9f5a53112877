"""The measurement file (``factors.io``): round trip, layouts, and errors that name the file and key."""

import numpy as np
import pytest

from factors.correspondences import Correspondences
from factors.io import (
    SCHEMA_VERSION,
    FrameMeasurements,
    NetworkEstimate,
    at_camera_time,
    from_arrays,
    load_correspondence_dir,
    load_measurement_dir,
    load_measurements,
    save_measurements,
    to_arrays,
)
from hybrid_calib.errors import DataError
from tests.helpers import nominal_T_cam_radar, rng


def _frame(seed: int = 0, n: int = 7, vehicle: str = "veh-a", network: bool = True, ts: int = 1_000
           ) -> FrameMeasurements:
    g = rng(seed)
    K = np.array([[800.0, 0, 640], [0, 800, 360], [0, 0, 1]])
    corr = Correspondences(g.uniform(-20, 20, (n, 3)) * [1, 1, 0], g.uniform(0, 1280, (n, 2)), g.uniform(1, 4, n),
                           g.uniform(0, 1, n), K, f"tok-{seed}", ts)
    net = None
    if network:
        A = g.normal(size=(6, 6))
        T = nominal_T_cam_radar()
        net = NetworkEstimate(T, A @ A.T * 1e-4, 2, T @ np.diag([1.0, 1, 1, 1]))
    return FrameMeasurements(corr, vehicle, ts - 20, net)


def _assert_same(a: FrameMeasurements, b: FrameMeasurements):
    da, db = to_arrays(a), to_arrays(b)
    assert set(da) == set(db)
    for k in da:
        np.testing.assert_array_equal(da[k], db[k], err_msg=k)


def test_round_trip_with_and_without_the_network_block(tmp_path):
    for i, net in enumerate((True, False)):
        m = _frame(i, network=net)
        path = save_measurements(tmp_path / f"f{i}.npz", m, extra={"T_gt": np.eye(4)})
        back = load_measurements(path)
        _assert_same(m, back)
        assert (back.network is not None) == net and back.vehicle == "veh-a" and back.timestamp_radar_us == 980
        with np.load(path) as z:
            assert int(z["schema_version"]) == SCHEMA_VERSION and "T_gt" in z.files  # extras kept, ignored
    assert back.frame_id == "tok-1" and back.timestamp_us == 1_000
    np.testing.assert_array_equal(load_measurements(tmp_path / "f0.npz").network.cov, _frame(0).network.cov)
    # rows alone through the same format
    c = _frame(3).corr
    np.testing.assert_array_equal(from_arrays(to_arrays(FrameMeasurements(c))).corr.pixels, c.pixels)
    with pytest.raises(ValueError, match="format keys"):
        save_measurements(tmp_path / "x.npz", m, extra={"cov": np.eye(6)})


def test_points_as_recorded_move_to_the_camera_time_with_their_network_block(tmp_path):
    """``at_camera_time``: points by ``N``, the network's transforms by ``N^-1`` and its right-perturbation covariance
    by ``Ad_N`` (``T Exp(xi) N^-1 = T N^-1 Exp(Ad_N xi)``); a compensated file is kept; the flag round-trips."""
    from hybrid_calib.geometry import adjoint, se3_exp, se3_inverse, transform_points

    m = _frame(5)
    assert not m.compensated and not load_measurements(save_measurements(tmp_path / "a.npz", m)).compensated
    N = se3_exp(np.array([0.002, -0.001, 0.01, 0.4, 0.03, 0.0]))  # 0.4 m of travel and a small turn
    moved = at_camera_time(m, N)
    assert moved.compensated and at_camera_time(moved, N) is moved
    np.testing.assert_allclose(moved.corr.points_radar, transform_points(N, m.corr.points_radar))
    np.testing.assert_allclose(moved.network.T_cam_radar, m.network.T_cam_radar @ se3_inverse(N))
    np.testing.assert_allclose(moved.network.T_start, m.network.T_start @ se3_inverse(N))
    xi = np.array([0.01, -0.02, 0.015, 0.05, -0.1, 0.2])
    lhs = m.network.T_cam_radar @ se3_exp(xi) @ se3_inverse(N)
    np.testing.assert_allclose(moved.network.T_cam_radar @ se3_exp(adjoint(N) @ xi), lhs, atol=1e-12)
    A = adjoint(N)
    np.testing.assert_allclose(moved.network.cov, A @ m.network.cov @ A.T)
    back = load_measurements(save_measurements(tmp_path / "b.npz", moved))
    assert back.compensated
    _assert_same(moved, back)
    d = to_arrays(m)
    for bad in (np.array(2), np.array("yes"), np.array([True, False])):
        d["ego_motion_compensated"] = bad
        np.savez(tmp_path / "c.npz", **d)
        with pytest.raises(DataError, match="ego_motion_compensated.*expected true or false"):
            load_measurements(tmp_path / "c.npz")


@pytest.mark.parametrize("change, message", [
    (lambda d: d.pop("pixels"), "missing key.*pixels"),
    (lambda d: d.update(pixels=np.zeros((3, 2))), "'pixels' has shape \\(3, 2\\), expected \\(7, 2\\)"),
    (lambda d: d["sigma_px"].__setitem__(2, np.nan), "'sigma_px' has NaN"),
    (lambda d: d.update(schema_version=np.array(99)), "schema_version 99"),
    (lambda d: d.pop("schema_version"), "no 'schema_version'"),
    (lambda d: d.update(cov=np.triu(np.ones((6, 6)))), "'cov' is not symmetric"),
    (lambda d: d.pop("T_cam_radar"), "without 'T_cam_radar'"),
    (lambda d: d.update(T_start=np.ones((4, 4))), "'T_start' is not a rigid transform"),
    # probe 27: a zero K passed, a file of 2 million rows stalled the run
    (lambda d: d.update(K=np.zeros((3, 3))), "'K' is not a camera intrinsic matrix"),
    (lambda d: d.update(**{k: np.repeat(d[k], 20_000, axis=0) for k in ("points_radar", "pixels", "sigma_px",
                                                                          "confidence")}), "140000 rows, more than"),
])
def test_bad_file_names_file_and_key(tmp_path, change, message):
    d = to_arrays(_frame(0))
    change(d)
    path = tmp_path / "bad-frame.npz"
    np.savez(path, **d)
    with pytest.raises(DataError, match=message) as e:
        load_measurements(path)
    assert "bad-frame.npz" in str(e.value)


def test_old_evaluate_file_is_rejected_with_a_reason(tmp_path):
    np.savez(tmp_path / "old.npz", **{f"corr_{k}": v for k, v in to_arrays(FrameMeasurements(_frame(0).corr)).items()})
    with pytest.raises(DataError, match="no 'schema_version'") as e:
        load_measurement_dir(tmp_path)
    assert "old.npz" in str(e.value)


def test_directory_layouts_group_by_vehicle(tmp_path):
    # evaluate output: DIR/frames/*.npz, vehicles from the files, each sorted by camera timestamp
    for i, (veh, ts) in enumerate([("veh-b", 30), ("veh-a", 20), ("veh-a", 10)]):
        save_measurements(tmp_path / "E" / "frames" / f"{i}.npz", _frame(i, vehicle=veh, ts=ts))
    groups = load_measurement_dir(tmp_path / "E")
    assert list(groups) == ["veh-a", "veh-b"] and [m.timestamp_us for m in groups["veh-a"]] == [10, 20]
    assert [c.timestamp_us for c in load_correspondence_dir(tmp_path / "E")] == [10, 20, 30]
    # one sub-directory per vehicle with files that carry no vehicle; a flat directory
    for i, veh in enumerate(["x", "x", "y"]):
        save_measurements(tmp_path / "V" / veh / f"{i}.npz", _frame(i, vehicle="", network=False))
    assert {k: len(v) for k, v in load_measurement_dir(tmp_path / "V").items()} == {"x": 2, "y": 1}
    save_measurements(tmp_path / "F" / "0.npz", _frame(0, vehicle=""))
    assert list(load_measurement_dir(tmp_path / "F")) == [""]


def test_a_frame_file_copied_under_another_name_is_used_once(tmp_path):
    """A copy of one frame file was fused twice (7 frames of a 6-frame vehicle: its information counted twice;
    probe 27): the copy is skipped, named, and the frame used once."""
    import shutil

    for i in range(3):
        save_measurements(tmp_path / "E" / "frames" / f"{i}.npz", _frame(i, ts=10 * (i + 1)))
    shutil.copy(tmp_path / "E" / "frames" / "1.npz", tmp_path / "E" / "frames" / "1-copy.npz")
    skipped = []
    groups = load_measurement_dir(tmp_path / "E", skipped)
    assert [m.frame_id for m in groups["veh-a"]] == ["tok-0", "tok-1", "tok-2"]
    (_, path, e), = skipped
    assert path.name == "1.npz" and "is also in" in str(e) and "1-copy.npz" in str(e)
    with pytest.raises(DataError, match="used once, remove the copy"):
        load_measurement_dir(tmp_path / "E")


def test_a_file_that_fails_its_checks_is_skipped_under_the_vehicle_it_names(tmp_path):
    """A bad file of a flat directory was listed as skipped under every vehicle (probe 27): where its `vehicle` still
    reads, the skip is that vehicle's."""
    save_measurements(tmp_path / "E" / "a.npz", _frame(0, vehicle="veh-a"))
    save_measurements(tmp_path / "E" / "b.npz", _frame(1, vehicle="veh-b"))
    d = to_arrays(_frame(2, vehicle="veh-b"))
    d["sigma_px"] = -np.abs(d["sigma_px"])
    np.savez(tmp_path / "E" / "c.npz", **d)
    (tmp_path / "E" / "d.npz").write_bytes(b"garbage")
    skipped = []
    load_measurement_dir(tmp_path / "E", skipped)
    assert [(sub, p.name) for sub, p, _ in skipped] == [("veh-b", "c.npz"), ("", "d.npz")]
