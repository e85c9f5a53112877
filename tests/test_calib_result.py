"""The calibrate result type (``calib.result``): JSON round trip, schema version, std keys with their frame."""

import json

import numpy as np
import pytest

from hybrid_calib.calib.covariance import report_std
from hybrid_calib.calib.result import SCHEMA_VERSION, CalibrationRun, Estimate, FrameEstimate, VehicleResult
from hybrid_calib.errors import DataError
from hybrid_calib.geometry import local
from hybrid_calib.metrics import STD_KEYS_CAM, STD_KEYS_RADAR, extrinsic_error, nees, std_dict, std_keys
from tests.helpers import nominal_T_cam_radar, random_pose, rng


def _estimate(g, status="ok") -> Estimate:
    A = g.normal(size=(6, 6))
    T, cov = random_pose(g), A @ A.T
    return Estimate(T, cov, report_std(T, cov), status, bool(g.integers(2)), ("rot x",))


def _run(g) -> CalibrationRun:
    traj = [FrameEstimate(index=k, frame_id=f"f{k}", timestamp_us=k * 500_000, estimate=_estimate(g),
                          n_window=min(k + 1, 3), n_total=k + 1, inlier_fraction=0.8,
                          step_statistic=None if k == 0 else 3.5, step_threshold=None if k == 0 else 20.0,
                          step_alarm=k == 2, solve_ms=1.5, cov_ms=0.25, events=("reset",) if k == 2 else ())
            for k in range(3)]
    T_true = nominal_T_cam_radar()
    v1 = VehicleResult("veh-a", traj[-1].estimate, traj, truth_T=T_true,
                       error={**extrinsic_error(traj[-1].T, T_true).as_dict(),
                              "nees": nees(local(T_true, traj[-1].T), traj[-1].cov)}, crb_std=g.uniform(0, 1, 6),
                       drift={"drifted": False, "p_value": 0.3, "dof": 6},
                       skipped=[{"index": 7, "token": "t7", "reason": "no points"}], n_frames=3,
                       network={"n_frames": 3, "frame_id": "f2", "iteration": 2, "T_cam_radar": T_true.tolist(),
                                "cov_right_radar": None, "std_cam": None, "error": None})
    v2 = VehicleResult("veh-b", _estimate(g, "weak: translation along camera y"), n_frames=5)  # batch, no truth
    return CalibrationRun("/data/root", "v1.0-sim", "/exports/E", "window", {"veh-a": v1, "veh-b": v2})


def test_run_round_trips_through_json(tmp_path):
    run = _run(rng(0))
    text = run.to_json()
    back = CalibrationRun.from_json(text)
    assert back.to_json() == text
    a, b = run.vehicles["veh-a"], back.vehicles["veh-a"]
    np.testing.assert_array_equal(a.final.cov, b.final.cov)
    np.testing.assert_array_equal(a.trajectory[1].estimate.std, b.trajectory[1].estimate.std)
    np.testing.assert_array_equal(a.crb_std, b.crb_std)
    assert b.trajectory[2].step_alarm and b.trajectory[2].events == ("reset",)
    assert b.trajectory[0].step_statistic is None
    assert back.vehicles["veh-b"].truth_T is None and back.vehicles["veh-b"].trajectory == []
    assert VehicleResult.from_json(a.to_json()).to_dict() == a.to_dict()
    # the file: schema version, std keys that name their (camera) frame
    path = run.save(tmp_path / "result.json")
    doc = json.loads(path.read_text())
    assert doc["schema_version"] == SCHEMA_VERSION and doc["vehicles"]["veh-a"]["step_alarms"] == [2]
    assert tuple(doc["vehicles"]["veh-a"]["final"]["std_cam"]) == STD_KEYS_CAM
    assert tuple(doc["vehicles"]["veh-a"]["trajectory"][0]["std_cam"]) == STD_KEYS_CAM
    assert CalibrationRun.load(path).to_dict() == doc


def test_a_frame_that_fitted_no_rows_is_null_in_strict_json():
    """method pure fits no rows: its NaN inlier fraction was written as a bare NaN, which strict JSON readers (a
    browser's JSON.parse) refuse (probe 40)."""
    g = rng(1)
    fe = FrameEstimate(0, "f0", 0, _estimate(g), 1, 1, float("nan"), None, None, False, 1.0, 1.0)
    text = json.dumps(fe.to_dict(), allow_nan=False)
    assert json.loads(text)["inlier_fraction"] is None
    assert np.isnan(FrameEstimate.from_dict(json.loads(text)).inlier_fraction)


def test_other_schema_or_broken_file_is_named(tmp_path):
    doc = _run(rng(1)).to_dict()
    doc["schema_version"] = 1
    (tmp_path / "old.json").write_text(json.dumps(doc))
    with pytest.raises(DataError, match="schema_version 2.*old.json"):
        CalibrationRun.load(tmp_path / "old.json")
    (tmp_path / "cut.json").write_text('{"schema_version": 2')
    with pytest.raises(DataError, match="unreadable.*cut.json"):
        CalibrationRun.load(tmp_path / "cut.json")
    del doc["vehicles"]
    doc["schema_version"] = 2
    (tmp_path / "part.json").write_text(json.dumps(doc))
    with pytest.raises(DataError, match="incomplete.*vehicles"):
        CalibrationRun.load(tmp_path / "part.json")


def test_a_truth_path_that_is_not_one_is_named():
    """The true mount along a drive (``truth.path``: a knocked simulated radar) is read back checked, as every field."""
    from hybrid_calib.calib.result import VehicleResult

    vr = _run(rng(1)).vehicles["veh-a"]
    doc = vr.to_dict()
    assert "path" not in doc["truth"]  # a mount that did not move: no path
    doc["truth"]["path"] = [{"index": 0, "T_cam_radar": doc["truth"]["T_cam_radar"]}, {"index": "3"}]
    with pytest.raises(ValueError, match=r"veh-a'\]\.truth\.path\[1\]\.index is not a frame index"):
        VehicleResult.from_dict(doc, "veh-a")
    other, end = np.eye(4).tolist(), doc["truth"]["T_cam_radar"]
    doc["truth"]["path"] = [{"index": 0, "T_cam_radar": other}, {"index": 3, "T_cam_radar": end}]
    assert [k for k, _ in VehicleResult.from_dict(doc, "veh-a").truth_path] == [0, 3]
    # in drive order, and ending at the drive end's truth (probe 59: edited paths drew the plots against others)
    for path, words in (([3, 0], "path\\[1\\].index 0 is not after the entry before it"),
                        ([-5, 3], "path\\[0\\].index -5 is not after"), ([0, 0], "index 0 is not after")):
        doc["truth"]["path"] = [{"index": path[0], "T_cam_radar": other},
                                {"index": path[1], "T_cam_radar": end}]
        with pytest.raises(ValueError, match=words):
            VehicleResult.from_dict(doc, "veh-a")
    doc["truth"]["path"] = [{"index": 0, "T_cam_radar": end}, {"index": 3, "T_cam_radar": other}]
    with pytest.raises(ValueError, match="truth.path ends at another mount than"):
        VehicleResult.from_dict(doc, "veh-a")


@pytest.mark.parametrize("edit, words", [
    (lambda v: v["trajectory"][0].update(step_alarm="false"), r"trajectory\[0\]\.step_alarm is a JSON string, not a "
                                                               "true or false"),
    (lambda v: v["trajectory"][0].update(events=3), r"trajectory\[0\]\.events is a JSON number, not a list"),
    (lambda v: v["trajectory"][0].update(timestamp_us=1.5), r"timestamp_us is a JSON number, not a whole number"),
    (lambda v: v["final"].update(status=7), r"final\.status is a JSON number, not a string"),
])
def test_result_fields_are_read_as_the_types_written(edit, words):
    """Probe 59: a step_alarm "false" read as an alarm (bool("false")), a numeric status was an internal error in
    report and export, non-list events and a fractional timestamp named neither the field nor the frame."""
    from hybrid_calib.calib.result import VehicleResult

    doc = _run(rng(1)).vehicles["veh-a"].to_dict()
    edit(doc)
    with pytest.raises(TypeError, match=words):
        VehicleResult.from_dict(doc, "veh-a")


def test_std_keys_name_their_frame():
    assert STD_KEYS_CAM == ("rot_x_cam_deg", "rot_y_cam_deg", "rot_z_cam_deg", "t_x_cam_cm", "t_y_cam_cm", "t_z_cam_cm")
    assert STD_KEYS_RADAR == std_keys("radar") and not set(STD_KEYS_CAM) & set(STD_KEYS_RADAR)
    assert list(std_dict(np.arange(6.0), "radar").values()) == list(range(6))
    with pytest.raises(ValueError, match="valid"):
        std_keys("camera")


def test_a_file_in_place_of_the_kept_vehicles_folder_is_named(tmp_path):
    """'File exists [file OUT/vehicles-done]' said neither what the folder is for nor what to do."""
    from hybrid_calib.calib.result import VehicleProgress
    from hybrid_calib.errors import HybridCalibError

    (tmp_path / "vehicles-done").write_text("hi")
    with pytest.raises(HybridCalibError, match="vehicles-done is a file, not the folder where hybrid-calib keeps the "
                                               "vehicles an interrupted run finished; move it away"):
        VehicleProgress(tmp_path, tmp_path, "v1.0-sim", "hybrid", {"seed": 0})
    (tmp_path / "vehicles-done").unlink()
    done = VehicleProgress(tmp_path, tmp_path, "v1.0-sim", "hybrid", {"seed": 0})
    (tmp_path / "vehicles-done" / "v.json").mkdir()  # one vehicle's file cannot be written: warned, the run goes on
    done.record("v", "no usable frame")


def test_a_run_that_only_failed_leaves_nothing_that_blocks_the_corrected_command(tmp_path, capsys):
    """calibrate --depth corrupted-truth on a real root failed every vehicle; the corrected command (as the error
    advised) was refused: "holds 1 vehicle(s) finished by an interrupted run of another configuration"."""
    from hybrid_calib.calib.result import VehicleProgress
    from hybrid_calib.errors import HybridCalibError

    first = VehicleProgress(tmp_path, tmp_path, "v1.0-mini", "pure", {"depth": "corrupted-truth"})
    first.record("n015", "no usable frame")
    VehicleProgress(tmp_path, tmp_path, "v1.0-mini", "pure", {"depth": ""})  # runs: nothing finished was kept
    done = VehicleProgress(tmp_path, tmp_path, "v1.0-mini", "pure", {"depth": "x"})
    done.record("n015", "no usable frame")
    # a finished vehicle is work: another configuration is still refused
    done.record("n008", VehicleResult("n008", _estimate(rng(1)), n_frames=2))
    capsys.readouterr()
    again = VehicleProgress(tmp_path, tmp_path, "v1.0-mini", "pure", {"depth": "x"})  # the same run resumed: said
    assert set(again.done) == {"n015", "n008"}
    assert ("kept 1 vehicle(s) an interrupted run into this --out finished (same data and options): n008"
            in capsys.readouterr().err)
    run = CalibrationRun(str(tmp_path), "v1.0-mini", "oracle", "window")
    again.fill(run, ["n008", "n015"], lambda name: pytest.fail("kept vehicles are not computed"))
    assert "resuming" not in capsys.readouterr().err  # said once, not twice (probe 50)
    with pytest.raises(HybridCalibError, match="holds 1 vehicle"):
        VehicleProgress(tmp_path, tmp_path, "v1.0-mini", "pure", {"depth": ""})


def test_a_resumed_run_with_another_seed_is_refused(tmp_path):
    """The seed draws the starts: a rerun with another --seed must not keep vehicles computed from the old starts
    (probe 74: "seed" among the run-only keys passed every test)."""
    from hybrid_calib.calib.result import VehicleProgress
    from hybrid_calib.errors import HybridCalibError

    VehicleProgress(tmp_path, tmp_path, "v1.0-sim", "hybrid", {"seed": 0}).record(
        "sim-veh-000", VehicleResult("sim-veh-000", _estimate(rng(1)), n_frames=2))
    with pytest.raises(HybridCalibError, match=r"seed: 0 -> 7"):
        VehicleProgress(tmp_path, tmp_path, "v1.0-sim", "hybrid", {"seed": 7})


def test_an_interrupted_run_of_other_options_names_the_option_that_differs(tmp_path):
    """The refusal cut both nested configs to the same 60 characters ('motion: {"enabled": true, ... ->
    {"enabled": true, ...'), and blamed a retrained checkpoint when --start chose the other shipped one (probe 7)."""
    from hybrid_calib.calib.result import VehicleProgress
    from hybrid_calib.errors import HybridCalibError

    conf = {"start": "R1", "checkpoint": "", "network": "aaa",
            "motion": {"enabled": True, "sigma_vo_deg": 1.13, "huber": 2.0, "gate": 3.0, "vo": {"features": 4000}}}
    done = VehicleProgress(tmp_path, tmp_path, "v1.0-sim", "hybrid", conf)
    done.record("v", VehicleResult("v", _estimate(rng(1)), n_frames=2))
    other = {**conf, "motion": {**conf["motion"], "vo": {"features": 3000}}}
    with pytest.raises(HybridCalibError, match=r"configuration \(motion\.vo\.features: 4000 -> 3000\)"):
        VehicleProgress(tmp_path, tmp_path, "v1.0-sim", "hybrid", other)
    with pytest.raises(HybridCalibError, match=r"start: \"R1\" -> \"R2\"; the network \(another checkpoint: start "
                                               r"changed; the shipped one follows --start\)") as e:
        VehicleProgress(tmp_path, tmp_path, "v1.0-sim", "hybrid", {**conf, "start": "R2", "network": "bbb"})
    assert "retrained" not in str(e.value)
    with pytest.raises(HybridCalibError, match="retrained or edited at the same path"):
        VehicleProgress(tmp_path, tmp_path, "v1.0-sim", "hybrid", {**conf, "network": "bbb"})


def test_an_estimate_holds_read_only_copies_of_its_arrays():
    """``Estimate.T`` / ``.cov`` were the caller's arrays, writeable: ``est.T[:3, 3] += 1`` on a window's output moved
    what the window and the result held (probe 33)."""
    g = rng(3)
    T, A = random_pose(g), g.normal(size=(6, 6))
    est = Estimate(T, A @ A.T, np.ones(6), "ok", info=np.eye(6))
    T[0, 3] += 1.0  # the caller's array changed afterwards: the estimate's did not
    assert est.T[0, 3] != T[0, 3]
    for name in ("T", "cov", "std", "info"):
        with pytest.raises(ValueError, match="read-only"):
            getattr(est, name)[0] += 1.0


def test_a_run_that_would_not_load_back_is_not_written(tmp_path):
    """``CalibrationRun.save`` wrote a NaN covariance as bare NaN, which ``load`` then refused (probe 31)."""
    run = _run(rng(4))
    cov = np.array(run.vehicles["veh-b"].final.cov)
    cov[2, 2] = np.nan
    run.vehicles["veh-b"] = VehicleResult("veh-b", Estimate(run.vehicles["veh-b"].final.T, cov, np.ones(6), "ok"))
    with pytest.raises(ValueError, match=r"not written: .*result.json would not load back .*cov_right_radar"):
        run.save(tmp_path / "result.json")
    assert not (tmp_path / "result.json").exists()


def test_an_estimate_whose_drive_ends_unseen_or_whose_pair_shares_no_view_is_not_trusted():
    """Probe 34: a radar turned 180 deg at frame 4 of 8: the oracle's frames 4-7 had no reflector in the image, and
    the result was "weak", scored against frame 3's truth; a rear radar with the front camera read "the solve went
    astray ... calibrate a longer drive"."""
    from hybrid_calib.calib.pipeline import trust_reason, unseen_end_reason

    g = rng(5)
    T = nominal_T_cam_radar()
    est = Estimate(T, np.eye(6) * 1e-4, np.ones(6), "weak: something")
    traj = [FrameEstimate(k, f"f{k}", k, est, 1, 1, 1.0, None, None, False, 1.0, 1.0) for k in range(4)]
    gap = [{"index": k, "token": f"f{k}", "reason": "no correspondence rows"} for k in range(4, 8)]
    vr = VehicleResult("v", est, traj, skipped=gap, errors_against="truth")
    why = unseen_end_reason(vr)
    assert why.startswith("the drive's last 4 of 8 frames (from frame 4 on) gave nothing to fuse") and \
        "(its errors are against frame 3's truth)" in why
    assert why in trust_reason(vr, T)
    absent = [{**s, "reason": "camera image not found; check the dataset root"} for s in gap]  # probe 101
    why = unseen_end_reason(VehicleResult("v", est, traj, skipped=absent))
    assert "have no sensor file on disk" in why and "a partial download" in why and "knocked" not in why
    batch = VehicleResult("v", est, [], skipped=gap)  # a batch result: the frames used are the ones not skipped
    assert unseen_end_reason(batch).startswith("the drive's last 4 of 8 frames") and "truth" not in \
        unseen_end_reason(batch)
    assert unseen_end_reason(VehicleResult("v", est, traj, skipped=gap[2:])) == ""  # 2 frames: not yet
    long = [FrameEstimate(k, f"f{k}", k, est, 1, 1, 1.0, None, None, False, 1.0, 1.0) for k in range(14)]
    tail = [{"index": k, "token": f"f{k}", "reason": "no correspondence rows"} for k in range(14, 17)]
    assert unseen_end_reason(VehicleResult("v", est, long, skipped=tail)) == ""  # 3 of 17: under a quarter
    ood = [{**s, "ood_score": 3.0} for s in gap]  # the domain test's drops: its own reason says them
    assert unseen_end_reason(VehicleResult("v", est, traj, skipped=ood)) == ""
    assert trust_reason(VehicleResult("v", est, traj), T) == ""
    rear = T @ np.diag([-1.0, -1.0, 1.0, 1.0])  # the radar turned 180 deg about its up axis: it looks backward
    away = trust_reason(VehicleResult("v", Estimate(rear, np.eye(6) * 1e-4, np.ones(6), "weak"), traj), rear)
    assert "the vehicle's tables turn the radar 18" in away and "share no view" in away and "astray" not in away
    assert g is not None


@pytest.mark.parametrize("status", ["INCONCLUSIVE: edited", "", "garbage status", "okay"])
def test_a_status_that_opens_with_no_status_word_is_refused(status):
    """Probe 71: export reads trust from the status; one it did not know ("INCONCLUSIVE: edited", "", "garbage") was
    exported as a trusted calibration."""
    from hybrid_calib.calib.result import VehicleResult

    doc = _run(rng(1)).vehicles["veh-a"].to_dict()
    doc["final"]["status"] = status
    with pytest.raises(ValueError, match=r"final\.status .* does not open with one of ok, weak, degenerate, "
                                         "inconclusive: the file was edited"):
        VehicleResult.from_dict(doc, "veh-a")
    doc["final"]["status"] = "ok"
    doc["trajectory"][0]["status"] = status
    with pytest.raises(ValueError, match=r"trajectory\[0\]"):
        VehicleResult.from_dict(doc, "veh-a")


def test_a_killed_write_s_temporary_record_is_not_a_kept_vehicle(tmp_path, capsys):
    """Probe 90: ``vehicles-done/*.json`` matched a SIGKILLed write's temporary file, read as a record."""
    from hybrid_calib.calib.result import VehicleProgress

    first = VehicleProgress(tmp_path, tmp_path, "v1.0-sim", "hybrid", {"seed": 0})
    first.record("sim-veh-000", "its radar file is truncated")
    (tmp_path / "vehicles-done" / "sim-veh-001.4242.hybrid-calib-tmp.json").write_text('{"vehic')
    again = VehicleProgress(tmp_path, tmp_path, "v1.0-sim", "hybrid", {"seed": 0})
    assert again.done == {"sim-veh-000": "its radar file is truncated"}
    assert "tmp" not in capsys.readouterr().err


def test_a_run_folder_reads_as_its_result(tmp_path):
    """Probe 93: ``report RUN`` failed with "[Errno 21] Is a directory" where RUN held result.json."""
    from hybrid_calib.calib.result import CalibrationRun

    (tmp_path / "run").mkdir()
    CalibrationRun("root", "v1.0-sim", "oracle", "window").save(tmp_path / "run" / "result.json")
    assert CalibrationRun.load(tmp_path / "run").mode == "window"
    with pytest.raises(DataError, match="pass the result.json"):
        CalibrationRun.load(tmp_path)  # a folder without one: still refused, named
    (tmp_path / "cmp").mkdir()
    (tmp_path / "cmp" / "compare.json").write_text("{}")
    with pytest.raises(DataError, match="is a compare run's folder") as e:  # probe 107: "[Errno 21] Is a directory"
        CalibrationRun.load(tmp_path / "cmp")
    assert "Errno" not in str(e.value)


def test_a_result_of_another_schema_name_is_refused():
    """A result.json whose "schema" was removed or names another schema was read when its schema_version matched
    (probe 109)."""
    import json

    from hybrid_calib.calib.result import SCHEMA, CalibrationRun
    from hybrid_calib.errors import DataError

    d = CalibrationRun("root", "v1.0-sim", "oracle", "window").to_dict()
    assert d["schema"] == SCHEMA and CalibrationRun.from_dict(d).data == "root"
    for bad in ({**d, "schema": "hybrid-calib/calibrate-result/v9"}, {k: v for k, v in d.items() if k != "schema"}):
        with pytest.raises(DataError, match="not a calibrate result: its \"schema\" is"):
            CalibrationRun.from_json(json.dumps(bad), "r.json")


@pytest.mark.parametrize("frames,per_frame_deg", [(300, 0.005), (60, 0.008), (40, 0.03)])
def test_a_slowly_drifting_mount_ends_its_truth_path_at_the_drives_end(frames, per_frame_deg):
    """Probe 124: a simulated drift of more than ~184 frames (the README's 200-frame example), or slower than 0.01 deg
    per frame, ran to the end and wrote no result: "result.json would not load back (... truth.path ends at another
    mount than ... truth.T_cam_radar)" (the path kept an entry only where the mount had moved past the tables'
    tolerance since the last, so its last entry was a few frames before the end)."""
    import dataclasses

    from hybrid_calib.calib.result import VehicleResult, path_of
    from hybrid_calib.geometry import se3_exp

    vr = _run(rng(1)).vehicles["veh-a"]
    step = se3_exp(np.array([0.0, 0.0, np.radians(per_frame_deg), 1e-5, 0.0, 0.0]))
    truths = [vr.truth_T]
    for _ in range(frames - 1):
        truths.append(truths[-1] @ step)
    path = path_of(range(frames), truths)
    assert len(path) > 1 and path[-1][0] == frames - 1 and np.array_equal(path[-1][1], truths[-1])
    moved = dataclasses.replace(vr, truth_T=truths[-1], truth_path=path, error=None)
    back = VehicleResult.from_dict(moved.to_dict(), "veh-a")  # it raised
    assert [k for k, _ in back.truth_path] == [k for k, _ in path]


def test_a_run_of_several_vehicles_says_which_of_how_many_it_computes(tmp_path, capsys):
    """Probe 124: calibrate over several vehicles showed one bar per vehicle and nothing of the whole (no "k of N")."""
    from hybrid_calib.calib.result import CalibrationRun, VehicleProgress
    from hybrid_calib.errors import DataError

    vr = _run(rng(1)).vehicles["veh-a"]
    done = VehicleProgress(tmp_path, tmp_path, "v1.0-sim", "hybrid", {"seed": 0})

    def compute(name):
        if name == "c":
            raise DataError("no usable frame")
        return vr

    run = CalibrationRun(str(tmp_path), "v1.0-sim", "hybrid", "window")
    done.fill(run, ["a", "b", "c"], compute)
    err = capsys.readouterr().err
    assert "vehicle 1 of 3: a" in err and "vehicle 3 of 3: c" in err and set(run.vehicles) == {"a", "b"}
    VehicleProgress(tmp_path / "q", tmp_path, "v1.0-sim", "hybrid", {"seed": 0}).fill(
        CalibrationRun(str(tmp_path), "v1.0-sim", "hybrid", "window"), ["a", "b"], compute, announce=False)
    assert "vehicle" not in capsys.readouterr().err  # --no-progress: quiet


@pytest.mark.parametrize("edit, words", [
    (lambda v: v.update(final={}), r"final lacks T_cam_radar, cov_right_radar, std_cam, status: the file was edited"),
    (lambda v: v["final"].pop("cov_right_radar"), r"final lacks cov_right_radar: "),
    (lambda v: v["final"].update(std_cam=None), r"final\.std_cam is a JSON null, not an object"),
    (lambda v: v["final"]["std_cam"].pop("t_x_cam_cm"), r"final\.std_cam lacks t_x_cam_cm: "),
])
def test_a_missing_estimate_key_is_named_with_its_path(tmp_path, edit, words):
    """Probe 148: an edited result.json read "(KeyError: 'std_cam')" or "('NoneType' object is not subscriptable)"
    where its siblings name the key's path."""
    from hybrid_calib.errors import DataError

    run = _run(rng(1))
    doc = json.loads(run.to_json())
    edit(doc["vehicles"]["veh-a"])
    (path := tmp_path / "result.json").write_text(json.dumps(doc))
    with pytest.raises(DataError, match=words) as e:
        CalibrationRun.load(path)
    assert "object is not subscriptable" not in str(e.value) and "(KeyError: '" not in str(e.value)
