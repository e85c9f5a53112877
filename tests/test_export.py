"""``hybrid-calib export``: the calibrated radar mounts as the root's calibrated_sensor table (calib/export.py)."""

import dataclasses
import json
import shutil
from pathlib import Path

import numpy as np
import pytest

from hybrid_calib.calib.covariance import camera_offset, report_basis, report_std
from hybrid_calib.calib.result import CalibrationRun
from hybrid_calib.errors import DataError, OptionError
from hybrid_calib.geometry import local, retract
from hybrid_calib.metrics import extrinsic_error, nees

VERSION = "v1.0-sim"


@pytest.fixture(scope="module")
def calibrated(tmp_path_factory):
    """A 2-vehicle simulated root and its oracle calibration (result.json with data_stamp.json beside it)."""
    from hybrid_calib.calib.pipeline import calibrate
    from hybrid_calib.config import merge
    from hybrid_calib.sim import simulate as sim
    from hybrid_calib.sim.drive import SimConfig

    root = tmp_path_factory.mktemp("sim")
    sim.simulate(merge(SimConfig, {"frames": 4, "vehicles": 2, "image_scale": 0.125, "seed": 5}), root,
                 overwrite=False, workers=1)
    out = tmp_path_factory.mktemp("cal")
    calibrate(root, VERSION, "oracle", out, {"window": {"window": 3}}, progress=False)
    return root, out / "result.json"


def _tables_T(root, vehicle: str, key: str = "T_cam_radar_static") -> np.ndarray:
    """The vehicle's T_cam_radar from the tables (``key`` "reference_T_cam_radar": what its verdict compares
    against; on a simulated root the factory calibration of sim_vehicle.json, the tables holding the truth)."""
    from hybrid_calib.data.nuscenes import NuScenesRadarCamera

    ds = NuScenesRadarCamera(root, VERSION, conf={"check_images": False, "vehicles": (vehicle,)})
    return ds[0].extras[key]


def _edited(result, path, vehicle: str, T=None, kind="recalibrate", status=None, pinned=("vertical offset",),
            undecided=("roll",)):
    """The result with one vehicle's estimate, verdict, status and per-axis decisions set (yaw differs, the
    ``undecided`` axes undecided, the others within; ``pinned`` prior-pinned); saved at ``path``."""
    run = CalibrationRun.load(result)
    vr = run.vehicles[vehicle]
    decide = {w: "undecided" if w in undecided + pinned else "differs" if w == "yaw" else "within"
              for w in vr.drift["axes"]}
    axes = {w: {**a, "prior_pinned": w in pinned, "decision": decide[w]} for w, a in vr.drift["axes"].items()}
    # its std and error follow the estimate (a std not its covariance's, or an error not its truth's, is refused)
    T = vr.final.T if T is None else T
    vr.final = dataclasses.replace(vr.final, T=T, std=report_std(T, vr.final.cov), status=status or vr.final.status)
    vr.error = {**extrinsic_error(T, vr.truth_T).as_dict(), "nees": nees(local(vr.truth_T, T), vr.final.cov)}
    vr.drift = {**vr.drift, "verdict_kind": kind, "verdict": f"{kind}: (edited for the test)", "axes": axes}
    run.save(path)
    return path


def _read_back(root, table, tmp_path, vehicle: str) -> np.ndarray:
    """T_cam_radar of ``vehicle`` as the data layer reads a copy of ``root`` whose calibrated_sensor.json is
    ``table``."""
    copy = tmp_path / "copy"
    shutil.copytree(root / VERSION, copy / VERSION)
    for top in ("samples", "sweeps", "maps", "sim_truth", "sim_depth"):
        if (root / top).exists():
            (copy / top).symlink_to(root / top)
    shutil.copy(table, copy / VERSION / "calibrated_sensor.json")
    return _tables_T(copy, vehicle)


def test_a_result_without_a_stored_verdict_is_kept_and_says_why(calibrated, tmp_path):
    """Probe 88: export read "the verdict against them is 'none'" where the report derived "recalibrate" from the
    same drift block's numbers."""
    from hybrid_calib.calib.export import export_mounts

    root, result = calibrated
    run = CalibrationRun.load(result)
    for vr in run.vehicles.values():
        vr.drift = {k: v for k, v in vr.drift.items() if k not in ("verdict_kind", "verdict", "axes")}
    run.save(tmp_path / "r" / "result.json")
    exp = export_mounts([tmp_path / "r" / "result.json"], tmp_path / "out")
    why = exp.vehicles["sim-veh-000"]["why"]
    assert not exp.exported and "stores no verdict against them" in why and "'none'" not in why
    assert "calibrate --overwrite" in why and "hybrid-calib report` derives one" in why


def test_export_writes_the_estimate_where_measured_and_keeps_the_tables_where_pinned(calibrated, tmp_path):
    from hybrid_calib.calib.export import export_mounts

    root, result = calibrated
    T_ref = _tables_T(root, "sim-veh-000", "reference_T_cam_radar")  # the factory calibration the verdict uses
    assert not np.allclose(T_ref, _tables_T(root, "sim-veh-000"))  # not the simulator's truth in the tables
    B = report_basis(T_ref)
    d_cam = np.radians([0.0, 1.5, 0.4, 0, 0, 0]) + np.r_[0, 0, 0, 0.04, 0.30, -0.03]  # yaw, roll; x, y, z in m
    T_est = retract(T_ref, B.T @ d_cam)
    path = _edited(result, tmp_path / "r" / "result.json", "sim-veh-000", T=T_est)
    exp = export_mounts([path], tmp_path / "out")
    assert exp.exported == ["sim-veh-000"] and not exp.vehicles["sim-veh-001"]["exported"]
    assert "kept the tables: the verdict against them is 'cannot tell', not 'recalibrate'" in \
        exp.vehicles["sim-veh-001"]["why"]
    v = exp.vehicles["sim-veh-000"]
    assert v["tables_kept"] == ["roll", "vertical offset"] and "roll, vertical offset kept" in v["why"]
    assert v["std_ego"] is not None and set(v["std_ego"]) >= {"rot_z_ego_deg", "t_x_ego_cm"}
    # per camera axis: the kept ones hold the tables' value, whose std is not the estimate's
    assert {w for w, a in v["std_camera"].items() if a["written"] == "tables"} == {"roll", "vertical offset"}
    assert v["std_camera"]["roll"]["std"] is None and v["std_camera"]["yaw"]["std"] > 0
    # read back through the data layer: the estimate along every decided axis, the reference's roll (undecided)
    # and vertical offset (prior-pinned)
    # and vertical offset (prior-pinned), each as every change is reported (camera_offset: R_ref w, t - t_ref); the
    # SE(3) tangent masked instead leaked the kept roll times the kept vertical offset into the written translation
    T_back = _read_back(root, tmp_path / "out" / "calibrated_sensor.json", tmp_path, "sim-veh-000")
    want = camera_offset(T_ref, T_est)
    want[[2, 4]] = 0.0
    np.testing.assert_allclose(camera_offset(T_ref, T_back), want, atol=1e-9)
    assert abs(want[5] - 100 * (B @ local(T_ref, T_est))[5]) > 1e-3  # where the tangent's translation differs
    # the other vehicle's records, and every other record, are unchanged
    before = json.loads((root / VERSION / "calibrated_sensor.json").read_text())
    after = json.loads((tmp_path / "out" / "calibrated_sensor.json").read_text())
    changed = [a["token"] for a, b in zip(after, before) if a != b]
    assert len(after) == len(before) and changed == [r["token"] for r in v["records"]] and len(changed) == 1
    np.testing.assert_allclose(_read_back(root, tmp_path / "out" / "calibrated_sensor.json", tmp_path / "2",
                                          "sim-veh-001"), _tables_T(root, "sim-veh-001"), atol=1e-12)
    saved = json.loads((tmp_path / "out" / "export.json").read_text())
    assert saved["exported"] == ["sim-veh-000"] and saved["which"] == "recalibrate"
    # the record's change is measured from the reference it names, which is what the verdict compared with
    rec = saved["vehicles"]["sim-veh-000"]["records"][0]
    ref_t, after_t = np.array(rec["reference"]["translation"]), np.array(rec["after"]["translation"])
    np.testing.assert_allclose(rec["change"]["t_ego_cm"], 100 * (after_t - ref_t), atol=1e-9)
    assert rec["change_from"] == "reference"


def test_export_says_what_its_change_is_measured_from(calibrated, tmp_path, capsys):
    """The terminal said "moved 0.11 deg, 0.0 cm from the tables", a change from no table a user can open on a
    simulated root (its reference is the factory calibration; probe 30): it names the verdict's reference."""
    from hybrid_calib.cli import main

    root, result = calibrated
    T_ref = _tables_T(root, "sim-veh-000", "reference_T_cam_radar")
    T_est = retract(T_ref, report_basis(T_ref).T @ np.r_[0.0, np.radians(1.5), 0.0, 0.0, 0.0, 0.0])
    path = _edited(result, tmp_path / "r" / "result.json", "sim-veh-000", T=T_est)
    assert main(["export", str(path), "--out", str(tmp_path / "out")]) == 0
    out = capsys.readouterr().out
    assert "sim-veh-000: exported" in out and "cm from the camera-radar calibration the verdict compared with" in out


def test_an_export_that_fails_writing_its_record_leaves_no_table_and_reruns(calibrated, tmp_path, capsys,
                                                                              monkeypatch):
    """Probe 84: a disk full between the two files left the new calibrated_sensor.json alone, and the rerun the error
    promised was refused ("no export wrote it: a copy of a root's table")."""
    import errno

    from hybrid_calib import config
    from hybrid_calib.cli import main

    root, result = calibrated
    T_ref = _tables_T(root, "sim-veh-000", "reference_T_cam_radar")
    T_est = retract(T_ref, report_basis(T_ref).T @ np.r_[0.0, np.radians(1.5), 0.0, 0.0, 0.0, 0.0])
    path = _edited(result, tmp_path / "r" / "result.json", "sim-veh-000", T=T_est)
    save = config.save_json_atomic

    def full(p, *a, **k):
        if Path(p).name == "export.json":
            raise OSError(errno.ENOSPC, "No space left on device", str(p))
        return save(p, *a, **k)

    monkeypatch.setattr(config, "save_json_atomic", full)
    assert main(["export", str(path), "--out", str(tmp_path / "out")]) == 2
    assert "no space left on the device" in capsys.readouterr().err
    assert not (tmp_path / "out" / "calibrated_sensor.json").exists()
    monkeypatch.setattr(config, "save_json_atomic", save)
    assert main(["export", str(path), "--out", str(tmp_path / "out")]) == 0, capsys.readouterr().err
    assert (tmp_path / "out" / "export.json").is_file() and (tmp_path / "out" / "calibrated_sensor.json").is_file()


def test_an_export_whose_runs_log_cannot_be_written_is_complete_and_says_so(calibrated, tmp_path, capsys,
                                                                              monkeypatch):
    """Probe 86: with room for both tables but not for runs.json, export said "wrote ..." then exited 2 with "a rerun
    resumes", and the rerun refused the complete export it found."""
    import errno

    from hybrid_calib import cli

    root, result = calibrated
    T_ref = _tables_T(root, "sim-veh-000", "reference_T_cam_radar")
    T_est = retract(T_ref, report_basis(T_ref).T @ np.r_[0.0, np.radians(1.5), 0.0, 0.0, 0.0, 0.0])
    path = _edited(result, tmp_path / "r" / "result.json", "sim-veh-000", T=T_est)

    def full(*a, **k):
        raise OSError(errno.ENOSPC, "No space left on device", str(tmp_path / "out" / "runs.json"))

    monkeypatch.setattr(cli, "record_run", full)
    assert cli.main(["export", str(path), "--out", str(tmp_path / "out")]) == 0
    err = capsys.readouterr().err
    assert "warning: it finished (exit status 0) and what it wrote is complete" in err and "runs.json" in err, err
    assert (tmp_path / "out" / "export.json").is_file() and (tmp_path / "out" / "calibrated_sensor.json").is_file()
    assert not (tmp_path / "out" / ".hybrid-calib.lock").exists()


def test_untrusted_stale_and_misdirected_exports_are_refused(calibrated, tmp_path):
    from hybrid_calib.calib.export import export_mounts
    from hybrid_calib.cli import main

    root, result = calibrated
    # an untrusted estimate is never written, even with --which trusted
    path = _edited(result, tmp_path / "u" / "result.json", "sim-veh-000",
                   status="weak: x (last solve: NOT CONVERGED after 50 iterations)")
    exp = export_mounts([path], tmp_path / "o1", which="trusted")
    assert exp.exported == ["sim-veh-001"] and "did not converge" in exp.vehicles["sim-veh-000"]["why"]
    assert any("no data stamp beside it" in n for n in exp.notes)  # an edited copy: not checked, and said
    # a result of data that changed since: refused, said
    stale = _edited(result, tmp_path / "s" / "result.json", "sim-veh-000")
    (stale.parent / "data_stamp.json").write_text(json.dumps({"digest": "0" * 40}))
    exp = export_mounts([stale], tmp_path / "o2", which="trusted")
    assert exp.exported == [] and "computed from other data" in exp.vehicles["sim-veh-000"]["why"]
    # the run's folder, as the result file (probe 127: its stamp was looked for in the folder's parent, and written)
    exp = export_mounts([stale.parent], tmp_path / "o2f", which="trusted")
    assert exp.exported == [] and "computed from other data" in exp.vehicles["sim-veh-000"]["why"]
    with pytest.raises(OptionError, match="is given twice .as a run's folder and its result.json"):  # probe 130
        export_mounts([stale.parent, stale], tmp_path / "o2g")
    (stale.parent / "data_stamp.json").write_text('{"dig')  # damaged: read as no stamp, it exported (probe 109)
    exp = export_mounts([stale], tmp_path / "o2b", which="trusted")
    assert exp.exported == [] and "data_stamp.json is damaged" in exp.vehicles["sim-veh-000"]["why"], exp.vehicles
    # an estimate that decides no axis against the tolerance writes nothing: the record would be the tables'
    from hybrid_calib.calib.drift import AXIS_WORDS

    vague = _edited(result, tmp_path / "v" / "result.json", "sim-veh-000", undecided=AXIS_WORDS)
    exp = export_mounts([vague], tmp_path / "o5")
    assert exp.exported == [] and "decide no axis against the tolerance" in exp.vehicles["sim-veh-000"]["why"]
    # never into the root's own tables; an unknown vehicle is named
    with pytest.raises(OptionError, match="root's own version folder"):
        export_mounts([result], root / VERSION)
    with pytest.raises(OptionError, match="is the data root itself"):  # the root from the result, no --data
        export_mounts([result], root)
    # a result without the per-axis test (an older version's) says so, not "decides no axis"
    run = CalibrationRun.load(result)
    for vr in run.vehicles.values():
        vr.drift = {k: v for k, v in vr.drift.items() if k != "axes"}
    run.save(tmp_path / "old" / "result.json")
    exp = export_mounts([tmp_path / "old" / "result.json"], tmp_path / "o6", which="trusted")
    assert exp.exported == [] and "holds no per-axis test" in exp.vehicles["sim-veh-000"]["why"]
    with pytest.raises(OptionError, match="sim-veh-009 not in the results"):
        export_mounts([result], tmp_path / "o3", vehicles=["sim-veh-009"])
    # a vehicle that failed in the run is said so (probe 40: "holds no calibrated vehicle" beside a calibrated one)
    run = CalibrationRun.load(result)
    run.vehicles_failed["sim-veh-007"] = "vehicle sim-veh-007: no readable frame (a zero focal length)"
    run.save(tmp_path / "failed" / "result.json")
    with pytest.raises(DataError, match=r"vehicle sim-veh-007 failed in the run, nothing to export for it \(vehicle "
                                        r"sim-veh-007: no readable frame \(a zero focal length\)\); calibrated there: "
                                        "sim-veh-000, sim-veh-001"):
        export_mounts([tmp_path / "failed" / "result.json"], tmp_path / "o9", vehicles=["sim-veh-007"])
    with pytest.raises(OptionError, match=r"sim-veh-009 not in the results; they hold sim-veh-000, sim-veh-001 \(and "
                                          r"failed: sim-veh-007\)"):
        export_mounts([tmp_path / "failed" / "result.json"], tmp_path / "o9", vehicles=["sim-veh-009"])
    # the command: one line per vehicle, then what was written; exit 1 when a vehicle was refused
    assert main(["export", str(path), "--out", str(tmp_path / "o4"), "--which", "trusted"]) == 1
    assert not (root / VERSION / "export.json").exists()
    # an export already in --out is not replaced silently (exported vehicle by vehicle, only the last was kept)
    with pytest.raises(OptionError, match="holds an export already.*--overwrite"):
        export_mounts([path], tmp_path / "o4", which="trusted")
    assert export_mounts([path], tmp_path / "o4", which="trusted", overwrite=True).exported == ["sim-veh-001"]
    # nor a calibrated_sensor.json no export wrote (probe 40: a user's backup of a root's table was replaced)
    backup = tmp_path / "backup"
    backup.mkdir()
    (backup / "calibrated_sensor.json").write_bytes((root / VERSION / "calibrated_sensor.json").read_bytes())
    with pytest.raises(OptionError, match="calibrated_sensor.json exists and no export wrote it.*--overwrite"):
        export_mounts([path], backup, which="trusted")
    assert (backup / "calibrated_sensor.json").read_bytes() == (root / VERSION / "calibrated_sensor.json").read_bytes()
    assert export_mounts([path], backup, which="trusted", overwrite=True).exported == ["sim-veh-001"]
    # a result of another root without a data stamp is not written into this one (vehicle names repeat)
    other = CalibrationRun.load(path)
    other.data = str(tmp_path / "elsewhere")
    other.save(tmp_path / "x" / "result.json")
    exp = export_mounts([tmp_path / "x" / "result.json"], tmp_path / "o7", data=root, which="trusted")
    assert exp.exported == [] and "was computed on" in exp.vehicles["sim-veh-001"]["why"]
    # the radar did not move on the vehicle (its Doppler agrees with its tables): its record is not moved
    side = _edited(result, tmp_path / "c" / "result.json", "sim-veh-000")
    run = CalibrationRun.load(side)
    run.vehicles["sim-veh-000"].drift["camera_side"] = "the camera side is the likelier cause of the yaw difference"
    run.save(side)
    exp = export_mounts([side], tmp_path / "o8")
    assert exp.exported == [] and "the camera side is the likelier cause" in exp.vehicles["sim-veh-000"]["why"]


def test_a_vehicle_whose_records_do_not_resolve_is_named_with_the_index_problem(calibrated, tmp_path):
    """A radar record deleted from calibrated_sensor.json read as "no frame of ROOT is of vehicle X; pass the root it
    was calibrated on" (probe 8): the root's index problem is named."""
    from hybrid_calib.calib.export import export_mounts
    from hybrid_calib.data.nuscenes import NuScenesRadarCamera

    root, result = calibrated
    copy = tmp_path / "copy"
    shutil.copytree(root / VERSION, copy / VERSION)
    for top in ("samples", "sweeps", "maps", "sim_truth", "sim_depth"):
        if (root / top).exists():
            (copy / top).symlink_to(root / top)
    ds = NuScenesRadarCamera(copy, VERSION, conf={"check_images": False})
    token = ds.frames[ds.frames_by_vehicle()["sim-veh-001"][0]].radar_sd["calibrated_sensor_token"]
    table = json.loads((copy / VERSION / "calibrated_sensor.json").read_text())
    (copy / VERSION / "calibrated_sensor.json").write_text(json.dumps([r for r in table if r["token"] != token]))
    run = CalibrationRun.load(result)
    run.data = str(copy)  # computed there, no data stamp beside it
    run.save(tmp_path / "r" / "result.json")
    exp = export_mounts([tmp_path / "r" / "result.json"], tmp_path / "out", which="trusted")
    why = exp.vehicles["sim-veh-001"]["why"]
    assert "no frame of" in why and "the root's index skipped" in why and token in why, why


def test_a_result_computed_from_a_relative_root_exports_from_anywhere(calibrated, tmp_path, monkeypatch):
    """The result records its root as an absolute path: export (and report) read it from another folder."""
    from hybrid_calib.calib.export import export_mounts
    from hybrid_calib.calib.pipeline import calibrate

    root, _ = calibrated
    monkeypatch.chdir(root.parent)
    calibrate(root.name, VERSION, "oracle", tmp_path / "cal", {"window": {"window": 3}}, progress=False)
    run = CalibrationRun.load(tmp_path / "cal" / "result.json")
    assert run.data == str(root.resolve())
    elsewhere = tmp_path / "elsewhere"
    elsewhere.mkdir()
    monkeypatch.chdir(elsewhere)
    exp = export_mounts([tmp_path / "cal" / "result.json"], which="trusted")  # the root from the result
    assert exp.data == str(root.resolve()) and set(exp.vehicles) == {"sim-veh-000", "sim-veh-001"}
    # the results it read are named wherever it was typed (probe 72: as typed, relative to a folder not recorded)
    monkeypatch.chdir(tmp_path)
    exp = export_mounts(["cal/result.json"], tmp_path / "out_rel", which="trusted")
    named = str((tmp_path / "cal" / "result.json").absolute())
    assert exp.results == [named] and {v["result"] for v in exp.vehicles.values()} == {named}


def test_a_pure_result_is_never_exported(calibrated, tmp_path):
    """One pass of the network alone (method pure) is no calibration, whatever its verdict (probe 10)."""
    from hybrid_calib.calib.export import export_mounts

    _, result = calibrated
    path = _edited(result, tmp_path / "r" / "result.json", "sim-veh-000")
    run = CalibrationRun.load(path)
    run.vehicles["sim-veh-000"].method = "pure"
    run.save(path)
    exp = export_mounts([path], tmp_path / "out", which="trusted")
    v = exp.vehicles["sim-veh-000"]
    assert not v["exported"] and "one pass of the network alone (method pure) is no calibration" in v["why"]


def test_a_knock_the_estimate_after_it_cannot_decide_is_said_not_kept_in_silence(calibrated, tmp_path):
    """The demo's knocked vehicle reads "recalibrate" (the mount monitor's step), but its estimate after the knock
    decides no axis: export said "kept the tables: the data decide no axis", as for a healthy mount."""
    from hybrid_calib.calib.drift import AXIS_WORDS
    from hybrid_calib.calib.export import export_mounts

    _, result = calibrated
    path = _edited(result, tmp_path / "r" / "result.json", "sim-veh-000", pinned=(), undecided=AXIS_WORDS)
    run = CalibrationRun.load(path)
    run.vehicles["sim-veh-000"].drift["at_end"] = {"verdict_kind": "cannot tell", "verdict": "cannot tell: ..."}
    run.save(path)
    v = export_mounts([path], tmp_path / "out").vehicles["sim-veh-000"]
    assert not v["exported"] and v["why"].startswith("not exported: the radar turned on the vehicle during the drive")
    # what the advised later drive can and cannot decide (probe 123: it read "cannot tell" and kept the tables)
    assert "stays 'cannot tell' and keeps the tables; then measure the radar's mount" in v["why"], v["why"]


def test_a_learned_yaw_the_radars_doppler_did_not_check_is_not_written():
    """Probe 23: with the mount monitor off (and the domain test loosened) the hybrid on the real scene read 'differs
    by 1.97 deg in yaw (+- 0.16 deg): recalibrate' and export wrote it; the radar's Doppler read 0.93 deg. A learned
    method's yaw is written only where the monitor checked it (its level, or a turn it measured)."""
    from types import SimpleNamespace

    from hybrid_calib.calib.export import _why_not

    drift = {"verdict_kind": "recalibrate", "axes": {"yaw": {"decision": "differs", "delta": -1.97}}}

    def vr(method, mount):
        return SimpleNamespace(final=SimpleNamespace(status="weak: x"), method=method, drift=drift, mount=mount)

    why = _why_not(vr("hybrid", None), "recalibrate")
    assert why.startswith("not exported: the yaw differs from the tables by 1.97 deg, and the radar's own Doppler did "
                          "not check it"), why
    assert _why_not(vr("pure-avg", {"pairs_tested": 0}), "recalibrate").startswith("not exported: the yaw differs")
    assert _why_not(vr("hybrid", {"yaw_check": {"disagree": False}}), "recalibrate") == ""
    assert _why_not(vr("hybrid", {"steps": [{"step_deg": 1.0}]}), "recalibrate") == ""
    assert _why_not(vr("oracle", None), "recalibrate") == ""  # the oracle's yaw is the reflectors', not a network's


# ---- tests the mutation probe (probe 25) found missing: each fails under its mutant

def test_axes_a_fleet_prior_dominates_keep_the_tables():
    from types import SimpleNamespace

    from hybrid_calib.calib.drift import AXIS_WORDS
    from hybrid_calib.calib.export import _kept_axes
    vr = SimpleNamespace(drift={"axes": {w: {"decision": "within"} for w in AXIS_WORDS},
                                "prior": {"dominated": ["roll"]}})
    assert _kept_axes(vr) == [AXIS_WORDS.index("roll")]


def test_a_record_that_would_move_the_radar_off_its_bracket_is_not_written(calibrated, tmp_path):
    """Probe 23: the cascade on the real scene (its domain test loosened) wrote a radar 97.4 cm from its tables, with a
    lateral 1-sigma of 0.96 cm. A record farther than MAX_MOVE_M from the tables is refused, saying why."""
    from hybrid_calib.calib.export import MAX_MOVE_M, export_mounts

    root, result = calibrated
    T_ref = _tables_T(root, "sim-veh-000", "reference_T_cam_radar")
    B = report_basis(T_ref)
    far = retract(T_ref, B.T @ (np.radians([0.0, 1.5, 0, 0, 0, 0]) + np.r_[0, 0, 0, MAX_MOVE_M + 0.05, 0, 0]))
    exp = export_mounts([_edited(result, tmp_path / "r" / "result.json", "sim-veh-000", T=far)], tmp_path / "out")
    v = exp.vehicles["sim-veh-000"]
    assert not v["exported"] and v["why"].startswith("not exported: it would move the radar 3") and \
        "farther than a radar moves on its bracket (30 cm)" in v["why"], v["why"]


def test_a_knocked_simulated_radar_is_judged_on_its_reference_not_on_the_truths_records(tmp_path):
    """A simulated step (--extrinsic-change step) writes the simulator's truth as two radar records, and export
    refused the vehicle as "more than one radar-camera calibration along the drive (a mount change)": the user's
    tables (the factory calibration the verdict used) hold one, as a real fleet's would (probe 50). On a simulated
    root export says that its table holds the truth."""
    from hybrid_calib.calib.export import export_mounts
    from hybrid_calib.calib.pipeline import calibrate
    from hybrid_calib.config import merge
    from hybrid_calib.sim import simulate as sim
    from hybrid_calib.sim.drive import SimConfig

    root = tmp_path / "sim"
    sim.simulate(merge(SimConfig, {"frames": 4, "vehicles": 1, "image_scale": 0.125, "seed": 5,
                                   "extrinsic_change": {"kind": "step", "frame": 2}}), root, workers=1)
    calibrate(root, VERSION, "oracle", tmp_path / "cal", {"window": {"window": 3}}, progress=False)
    path = _edited(tmp_path / "cal" / "result.json", tmp_path / "e" / "result.json", "sim-veh-000", status="ok")
    exp = export_mounts([path], tmp_path / "out")
    assert exp.exported == ["sim-veh-000"], exp.vehicles["sim-veh-000"]["why"]
    assert any("a simulated root: its calibrated_sensor.json holds the simulator's truth" in n for n in exp.notes)


def test_a_moved_root_is_not_blamed_on_a_data_option_not_given(calibrated, tmp_path):
    """Probe 71: export without --data, its results' root moved, said "--data: ... is not a folder"."""
    import json

    from hybrid_calib.calib.export import export_mounts
    from hybrid_calib.errors import OptionError

    _, result = calibrated
    doc = json.loads(result.read_text())
    moved = tmp_path / "run" / "result.json"
    moved.parent.mkdir()
    moved.write_text(json.dumps({**doc, "data": str(tmp_path / "gone")}))
    with pytest.raises(OptionError, match="the root the results record, .*gone/v1.0-sim, is not there \\(moved or "
                                          "removed\\?\\): pass where it is now with --data"):
        export_mounts([moved], tmp_path / "exp")


def test_a_record_that_would_keep_a_pinned_axis_far_from_the_estimate_is_not_written():
    """Probe 95: a 0.67 deg yaw "recalibrate" was exported with the tables' pitch kept, 20 deg from the truth; the
    run had measured that pitch 20 sigma from the tables on a prior-pinned axis."""
    from types import SimpleNamespace

    from hybrid_calib.calib.export import _why_not

    axes = {"yaw": {"decision": "differs", "delta": 0.67, "std": 0.03, "tolerance": 0.5, "prior_pinned": False},
            "pitch": {"decision": "undecided", "delta": 20.3, "std": 1.02, "tolerance": 0.5, "prior_pinned": True}}
    vr = SimpleNamespace(final=SimpleNamespace(status="weak: x"), method="oracle", mount=None,
                         drift={"verdict_kind": "recalibrate", "axes": axes})
    why = _why_not(vr, "recalibrate")
    assert why.startswith("not exported: the tables differ from the estimate along axes the data do not observe "
                          "(prior-pinned: pitch by 20 deg +- 1.02 deg at 1 sigma)"), why
    axes["pitch"]["delta"] = 3.0  # within 3 sigma of the tolerance: the tables' pitch is kept, the yaw written
    assert _why_not(vr, "recalibrate") == ""
    # probe 96: a vehicle nothing would be written for keeps its tables as before (rc 0), the conflict said by its
    # verdict; a "cannot tell" under --which recalibrate is "kept the tables", not a refusal
    axes["pitch"]["delta"] = 20.3
    axes["yaw"]["decision"] = "undecided"
    assert _why_not(vr, "trusted") == ""  # every axis kept: export_mounts says "the data decide no axis"
    vr.drift["verdict_kind"] = "cannot tell"
    assert _why_not(vr, "recalibrate").startswith("kept the tables: the verdict against them is 'cannot tell'")


def test_a_written_yaw_its_radars_doppler_puts_far_off_is_said():
    """Probe 129: a mount 1.39 deg off in yaw was written (its 1-sigma 0.55 deg) beside a Doppler record of the radar
    1.37 +- 0.06 deg from it, and nothing said."""
    from hybrid_calib.calib.drift import AXIS_WORDS
    from hybrid_calib.calib.export import _doppler_doubt

    std = {"yaw": {"written": "estimate", "std": 0.55, "unit": "deg"}}
    far = {"level_deg": -1.37, "std_deg": 0.06, "pairs": 60}
    words = _doppler_doubt(far, std, [], None)
    assert words.startswith("; but the radar's own Doppler against the ego poses puts its yaw -1.37 +- 0.12 deg") and \
        "2.4 of their combined 1-sigma" in words, words
    assert _doppler_doubt({**far, "level_deg": -0.5}, std, [], None) == ""  # within 2 of it
    assert _doppler_doubt(far, std, [AXIS_WORDS.index("yaw")], None) == ""  # the tables' yaw kept
    assert _doppler_doubt(None, std, [], None) == ""
