"""An earlier export as a later drive's reference (``data.reference``; calibrate's and fleet's ``--reference``).

The workflow it exists for: a radar knocked 2 deg in yaw before a drive reads "recalibrate" against its tables; its
calibration is exported; every later drive of that vehicle is then checked against the exported mount (without it,
each read "recalibrate" again: the tables still hold the mount before the knock)."""

import json
import shutil

import numpy as np
import pytest

from hybrid_calib.errors import DataError
from hybrid_calib.geometry import se3_inverse

VERSION = "v1.0-sim"
KNOCK = {"kind": "step", "frame": 0, "rotation_deg": [0.0, 0.0, 2.0], "translation_m": [0.0, 0.0, 0.0]}


def _sim(root, frames: int, seed: int = 17, scenario: str = "urban", knock: dict = KNOCK, vehicles: int = 2):
    from hybrid_calib.config import merge
    from hybrid_calib.sim import simulate as sim
    from hybrid_calib.sim.drive import SimConfig

    sim.simulate(merge(SimConfig, {"frames": frames, "vehicles": vehicles, "image_scale": 0.125, "seed": seed,
                                   "scenario": scenario, "extrinsic_change": knock}), root, overwrite=False, workers=1)
    return root


@pytest.fixture(scope="module")
def knocked(tmp_path_factory):
    """(root of a drive with both radars knocked before it, its oracle calibration's result.json, the export
    folder of it, root of a later drive of the same vehicles: the same seed (the same mounts) in another scenario,
    so its frames and rows are not drive 1's again, probe 77)."""
    from hybrid_calib.calib.export import export_mounts
    from hybrid_calib.calib.pipeline import calibrate

    root = _sim(tmp_path_factory.mktemp("drive1"), 6)
    out = tmp_path_factory.mktemp("cal1")
    calibrate(root, VERSION, "oracle", out, {"window": {"window": 3}}, progress=False)
    exp = tmp_path_factory.mktemp("export")
    export_mounts([out / "result.json"], exp)
    return root, out / "result.json", exp, _sim(tmp_path_factory.mktemp("drive2"), 8, scenario="highway")


def _reader(root, reference=None):
    from hybrid_calib.data.nuscenes import NuScenesRadarCamera

    return NuScenesRadarCamera(root, VERSION, conf={"check_images": False, "reference": reference})


def test_the_knock_reads_recalibrate_against_the_tables_and_is_exported(knocked):
    from hybrid_calib.calib.result import CalibrationRun

    _, result, exp, _ = knocked
    run = CalibrationRun.load(result)
    for vr in run.vehicles.values():  # the premise of every test below
        assert vr.drift["verdict_kind"] == "recalibrate"
        assert vr.drift["reference"] == {"kind": "tables"}
    doc = json.loads((exp / "export.json").read_text())
    assert doc["exported"] == ["sim-veh-000", "sim-veh-001"]
    for entry in doc["vehicles"].values():
        assert {"camera", "after"} <= set(entry["records"][0])


def test_the_reference_is_the_exported_extrinsic_and_radar_mount(knocked):
    from hybrid_calib.data.reference import load_export_reference
    from hybrid_calib.geometry import pose_from_nuscenes

    _, _, exp, later = knocked
    plain, ds = _reader(later), _reader(later, str(exp))
    rec = json.loads((exp / "export.json").read_text())["vehicles"]["sim-veh-000"]["records"][0]
    cam, after = (pose_from_nuscenes(rec[k]["rotation"], rec[k]["translation"]) for k in ("camera", "after"))
    i = ds.frames_by_vehicle()["sim-veh-000"][0]
    f, f0 = ds[i], plain[i]
    np.testing.assert_allclose(f.extras["reference_T_cam_radar"], se3_inverse(cam) @ after, atol=1e-12)
    np.testing.assert_allclose(ds.reference_T_cam_radar(ds.frames[i]), se3_inverse(cam) @ after, atol=1e-12)
    np.testing.assert_allclose(f.extras["reference_T_ego_radar"], after, atol=1e-12)  # the mount monitor's
    # the later drive's own tables (its factory calibration) are 2 deg from it; the data themselves unchanged
    assert not np.allclose(f0.extras["reference_T_cam_radar"], f.extras["reference_T_cam_radar"], atol=1e-3)
    np.testing.assert_array_equal(f0.T_cam_radar, f.T_cam_radar)
    src = ds.reference_source("sim-veh-000")
    assert src["kind"] == "export" and src["sha256"] == load_export_reference(exp).sha256
    assert plain.reference_source("sim-veh-000") == {"kind": "tables"}
    assert ds.reference_notes()[0].startswith("reference: sim-veh-000, sim-veh-001 checked against")
    # a run of some vehicles names those only (session 38 listed every vehicle of the export)
    assert ds.reference_notes(("sim-veh-001",))[0].startswith("reference: sim-veh-001 checked against the mount "
                                                               "exported in")
    assert ds.reference_notes(("sim-veh-009",)) == [f"reference: none of the vehicles asked for is in "
                                                    f"{(exp / 'export.json').absolute()}: each is checked against "
                                                    "its tables"]
    # the export.json itself names the same reference as its folder
    np.testing.assert_allclose(_reader(later, str(exp / "export.json")).reference_T_cam_radar(ds.frames[i]),
                               se3_inverse(cam) @ after, atol=1e-12)


def test_a_later_drive_checked_against_the_export_does_not_read_recalibrate(knocked, tmp_path):
    from hybrid_calib.calib.pipeline import calibrate

    _, _, exp, later = knocked
    tables = calibrate(later, VERSION, "oracle", tmp_path / "t", {"window": {"window": 3}}, progress=False)
    ref = calibrate(later, VERSION, "oracle", tmp_path / "r", {"window": {"window": 3}, "reference": str(exp)},
                    progress=False)
    for name in ("sim-veh-000", "sim-veh-001"):
        assert tables.vehicles[name].drift["verdict_kind"] == "recalibrate"  # the old tables: the knock again
        d = ref.vehicles[name].drift
        assert d["verdict_kind"] != "recalibrate", d["verdict"]
        assert abs(d["axes"]["yaw"]["delta"]) < 0.3, d["axes"]["yaw"]  # the knock is in the reference
        assert d["reference"]["kind"] == "export"
        assert d["reference"]["path"] == str((exp / "export.json").absolute())
        assert d["since_export"]["tested"] is False and "the export recorded no Doppler level" in d["verdict"]
        # start=reference starts each vehicle at its reference: the exported mount
        assert ref.vehicles[name].start["T_cam_radar"] != tables.vehicles[name].start["T_cam_radar"]


def test_the_hybrids_mount_monitor_reads_the_radar_at_its_exported_yaw(knocked, tmp_path):
    from hybrid_calib.errors import HybridCalibError
    from hybrid_calib.hybrid import run_calibration

    _, _, exp, later = knocked
    mine = tmp_path / "exp"
    shutil.copytree(exp, mine)
    conf = {"method": "hybrid", "vehicles": ["sim-veh-000"], "progress": False, "lidar": {"enabled": False}}
    plain = run_calibration(later, VERSION, tmp_path / "h", conf).vehicles["sim-veh-000"]
    ref = run_calibration(later, VERSION, tmp_path / "hr", {**conf, "reference": str(mine)}).vehicles["sim-veh-000"]
    (lv0,), (lv,) = plain.mount["levels"], ref.mount["levels"]  # no step: one level over the drive
    assert abs(lv0["level_deg"]) > 1.5  # the knock, against the tables
    assert abs(lv["level_deg"]) < 0.3, lv  # against the exported mount: where the radar is
    assert ref.drift["reference"]["kind"] == "export" and plain.drift["reference"] == {"kind": "tables"}
    # the oracle's export recorded no Doppler level: the turn since it went untested, and the verdict says so
    assert ref.drift["since_export"]["tested"] is False and "the export recorded no Doppler level" in ref.drift[
        "verdict"] and "since_export" not in plain.drift
    # its export records the Doppler level against the mount it writes (a later drive compares its own with it)
    from scipy.spatial.transform import Rotation

    from hybrid_calib.calib.export import export_mounts
    from hybrid_calib.data.reference import load_export_reference

    # (an 8-frame drive decides no axis: it carries the earlier export's mount, and records its own Doppler level
    # against it, the earlier export being an oracle one without)
    entry = export_mounts([tmp_path / "hr" / "result.json"], tmp_path / "e2", which="trusted").vehicles["sim-veh-000"]
    assert entry["exported"], entry["why"]
    M = load_export_reference(mine).mounts["sim-veh-000"][1]  # what the level was measured against
    after = load_export_reference(tmp_path / "e2").mounts["sim-veh-000"][1]
    turn = np.degrees(Rotation.from_matrix(after[:3, :3] @ M[:3, :3].T).as_rotvec()[2])
    assert entry["doppler"]["level_deg"] == pytest.approx(lv["level_deg"] - turn, abs=1e-9)
    assert entry["doppler"]["std_deg"] == lv["std_deg"]
    assert load_export_reference(tmp_path / "e2").source("sim-veh-000")["doppler"]["level_deg"] == pytest.approx(
        lv["level_deg"] - turn, abs=1e-9)
    # a drive after it on which the radar turned another 1.5 deg: its Doppler level against export 2's record
    again = {**KNOCK, "rotation_deg": [0.0, 0.0, 3.5]}
    turned = _sim(tmp_path / "d3", 8, scenario="highway", knock=again)
    res = run_calibration(turned, VERSION, tmp_path / "h3", {**conf, "reference": str(tmp_path / "e2")})
    d = res.vehicles["sim-veh-000"].drift
    assert d["verdict_kind"] == "recalibrate", d["verdict"]
    assert "since the export it is checked against" in d["verdict"] and "to the left" in d["verdict"], d["verdict"]
    assert d["since_export"]["beyond"] and d["since_export"]["delta_deg"] == pytest.approx(1.5, abs=0.35)
    pa = run_calibration(turned, VERSION, tmp_path / "pa", {**conf, "method": "pure-avg", "reference": str(
        tmp_path / "e2")}).vehicles["sim-veh-000"].drift  # no mount monitor: untested, and said
    assert "not tested for a turn of the radar since the export by its Doppler: method pure-avg runs no radar " \
           "mount monitor" in pa["verdict"], pa["verdict"]
    # exported: the earlier export's mount turned by the Doppler's turn (the hybrid's yaw cannot decide 1.5 deg on
    # 8 frames), so the drive after it is checked against where the radar is (probe 78: carried unchanged, and
    # every later drive read "recalibrate" again)
    e4 = export_mounts([tmp_path / "h3" / "result.json"], tmp_path / "e4").vehicles["sim-veh-000"]
    assert e4["exported"] and not e4.get("carried"), e4["why"]
    assert e4["doppler_turn"]["delta_deg"] == d["since_export"]["delta_deg"]
    assert e4["std_camera"]["yaw"]["written"] == "doppler" and "yaw" not in e4["tables_kept"]
    before, now = (load_export_reference(tmp_path / e).mounts["sim-veh-000"][1] for e in ("e2", "e4"))
    turned = np.degrees(Rotation.from_matrix(now[:3, :3] @ before[:3, :3].T).as_rotvec())
    assert turned[2] == pytest.approx(d["since_export"]["delta_deg"], abs=0.05), turned  # about the up axis
    np.testing.assert_allclose(now[:3, 3], before[:3, 3], atol=0.01)  # its position as it was (kept axes), in m
    # its own estimate written (the per-axis test edited to decide yaw and lateral): the level turned onto it
    from hybrid_calib.calib.result import CalibrationRun

    run = CalibrationRun.load(tmp_path / "hr" / "result.json")
    vr = run.vehicles["sim-veh-000"]
    vr.drift = {**vr.drift, "verdict_kind": "within tolerance", "verdict": "within tolerance: (edited)", "axes": {
        w: {**a, "decision": "within" if w in ("yaw", "lateral offset") else "undecided"}
        for w, a in vr.drift["axes"].items()}}
    run.save(tmp_path / "hr" / "result.json")
    entry = export_mounts([tmp_path / "hr" / "result.json"], tmp_path / "e3", which="trusted",
                          overwrite=True).vehicles["sim-veh-000"]
    assert entry["exported"] and not entry.get("carried"), entry["why"]
    after = load_export_reference(tmp_path / "e3").mounts["sim-veh-000"][1]
    turn = np.degrees(Rotation.from_matrix(after[:3, :3] @ M[:3, :3].T).as_rotvec()[2])
    assert abs(turn) > 1e-4  # the estimate's yaw, not the reference's, is written
    assert entry["doppler"]["level_deg"] == pytest.approx(lv["level_deg"] - turn, abs=1e-9)
    doc = json.loads((mine / "export.json").read_text())
    doc["notes"] = ["exported again"]
    (mine / "export.json").write_text(json.dumps(doc))  # the same path, another file: not the result's reference
    with pytest.raises(HybridCalibError, match="the --reference export.s file .exported again at the same path since."):
        run_calibration(later, VERSION, tmp_path / "hr", {**conf, "reference": str(mine)})


def test_a_vehicle_the_export_kept_keeps_its_tables(knocked, tmp_path):
    from hybrid_calib.calib.export import export_mounts

    root, result, _, later = knocked
    exp = tmp_path / "one"
    export_mounts([result], exp, vehicles=["sim-veh-001"])
    doc = json.loads((exp / "export.json").read_text())
    doc["vehicles"]["sim-veh-002"] = {"exported": False, "why": "kept the tables: (a test)", "records": []}
    (exp / "export.json").write_text(json.dumps(doc))
    ds, plain = _reader(later, str(exp)), _reader(later)
    i = ds.frames_by_vehicle()["sim-veh-000"][0]
    np.testing.assert_array_equal(ds.reference_T_cam_radar(ds.frames[i]), plain.reference_T_cam_radar(ds.frames[i]))
    assert ds.reference_source("sim-veh-000")["kind"] == "tables"
    assert "does not name it" in ds.reference_source("sim-veh-000")["why"]
    assert "kept its tables (kept the tables: (a test))" in ds.reference_source("sim-veh-002")["why"]
    assert ds.reference_source("sim-veh-001")["kind"] == "export"


def test_an_export_of_other_vehicles_or_another_camera_is_said(knocked, tmp_path):
    _, _, exp, later = knocked
    doc = json.loads((exp / "export.json").read_text())
    other = tmp_path / "other"
    other.mkdir()
    (other / "export.json").write_text(json.dumps({**doc, "vehicles": {"n015": doc["vehicles"]["sim-veh-000"]}}))
    notes = _reader(later, str(other)).reference_notes()
    assert notes[0].startswith("warning: the reference export") and "none of this root's vehicles" in notes[0]
    assert "n015" in notes[0] and "every vehicle is checked against its tables" in notes[0]
    # a camera record 1 deg away from the one the export read: the camera was recalibrated since (or another car)
    moved = json.loads(json.dumps(doc))
    q = np.array(moved["vehicles"]["sim-veh-000"]["records"][0]["camera"]["rotation"])
    dq = np.array([np.cos(np.radians(0.5)), 0.0, 0.0, np.sin(np.radians(0.5))])  # 1 deg about z
    w1, v1, w2, v2 = dq[0], dq[1:], q[0], q[1:]
    moved["vehicles"]["sim-veh-000"]["records"][0]["camera"]["rotation"] = [
        w1 * w2 - v1 @ v2, *(w1 * v2 + w2 * v1 + np.cross(v1, v2))]
    (other / "export.json").write_text(json.dumps(moved))
    notes = _reader(later, str(other)).reference_notes()
    assert any(n.startswith("warning: vehicle sim-veh-000: its camera record here is 1.00 deg") for n in notes), notes
    assert not any("sim-veh-001: its camera" in n for n in notes)
    # kept with the result and shown on its page: it had been said on the console only (probe 109)
    from hybrid_calib.calib.pipeline import calibrate
    from hybrid_calib.report.vehicle import write_report

    conf = {"window": {"window": 3}, "vehicles": ["sim-veh-000"], "max_frames": 2, "reference": str(other)}
    run = calibrate(later, VERSION, "oracle", tmp_path / "r", conf, progress=False)
    assert any("its camera record here is 1.00 deg" in n for n in run.notes), run.notes
    page = write_report(tmp_path / "r" / "result.json", tmp_path / "r.html", conf={"frames": 1}).read_text()
    assert "the run said: warning: vehicle sim-veh-000: its camera record here is 1.00 deg" in page


@pytest.mark.parametrize("case, words", [
    ("missing", "does not exist"),
    ("empty folder", "holds no export.json"),
    ("not json", "export unreadable (JSONDecodeError"),
    ("other schema", "not a hybrid-calib export"),
    ("no camera", "names no camera mount (an export written before"),
    ("bad after", "'after' record does not read"),
    ("two extrinsics", "hold 2 radar-camera extrinsics that differ"),
    ("vehicles list", "'vehicles' is not an object"),
    ("exported string", "'exported' is 'true', not true or false"),
    ("after 3 m off", "farther than any radar mount sits from its tables"),  # probe 109: read, the tables blamed
    ("after turned 180 deg", "is 180.0 deg / 0 cm from the record it replaced"),
    ("no before", "holds no 'before' (the record it replaced"),  # probe 150: the check above was skipped
    ("before null", "holds no 'before' (the record it replaced"),
])
def test_a_reference_that_is_not_an_export_is_refused_by_name(knocked, tmp_path, case, words):
    from hybrid_calib.data.reference import load_export_reference

    _, _, exp, later = knocked
    doc = json.loads((exp / "export.json").read_text())
    rec = doc["vehicles"]["sim-veh-000"]["records"][0]
    path = tmp_path / "x"
    if case != "missing":
        path.mkdir()
    text = json.dumps(doc)
    if case == "not json":
        text = text[:-5]
    elif case == "other schema":
        text = json.dumps({**doc, "schema": "hybrid-calib/fleet-prior/v1"})
    elif case == "no camera":
        rec.pop("camera")
        text = json.dumps(doc)
    elif case == "bad after":
        rec["after"]["rotation"] = [1.0, 0.5, 0.0, 0.0]
        text = json.dumps(doc)
    elif case == "two extrinsics":
        rec2 = json.loads(json.dumps(rec))
        rec2["after"]["translation"][1] += 0.01
        doc["vehicles"]["sim-veh-000"]["records"].append(rec2)
        text = json.dumps(doc)
    elif case in ("no before", "before null"):
        rec["after"] = {**rec["after"], "rotation": [0.0, 0.0, 0.0, 1.0]}  # and its 'after' turned 180 deg
        if case == "no before":
            rec.pop("before")
        else:
            rec["before"] = None
        text = json.dumps(doc)
    elif case == "vehicles list":
        text = json.dumps({**doc, "vehicles": []})
    elif case == "exported string":
        doc["vehicles"]["sim-veh-000"]["exported"] = "true"
        text = json.dumps(doc)
    elif case.startswith("after"):
        rec["after"] = {**rec["before"], **({"translation": [rec["before"]["translation"][0] + 3.0,
                                                             *rec["before"]["translation"][1:]]}
                                            if "3 m" in case else {"rotation": [0.0, 0.0, 0.0, 1.0]})}
        rec["after"]["rotation"] = rec["after"]["rotation"] if "3 m" in case else \
            _turned_180(rec["before"]["rotation"])
        text = json.dumps(doc)
    if case not in ("missing", "empty folder"):
        (path / "export.json").write_text(text)
    with pytest.raises(DataError) as e:
        load_export_reference(path)
    assert words in str(e.value), str(e.value)
    assert str(path) in str(e.value)
    with pytest.raises(DataError):  # the reader refuses it before any frame
        _reader(later, str(path))


def test_a_result_depends_on_the_exports_content_not_only_its_path(knocked, tmp_path):
    from hybrid_calib.calib.pipeline import calibrate
    from hybrid_calib.errors import HybridCalibError

    root, result, exp, _ = knocked
    mine = tmp_path / "exp"
    shutil.copytree(exp, mine)
    conf = {"window": {"window": 3}, "reference": str(mine), "vehicles": ["sim-veh-000"]}
    first = calibrate(root, VERSION, "oracle", tmp_path / "c", conf, progress=False)
    again = calibrate(root, VERSION, "oracle", tmp_path / "c", conf, progress=False)  # reused: the same export
    assert again.vehicles["sim-veh-000"].final.T.tolist() == first.vehicles["sim-veh-000"].final.T.tolist()
    doc = json.loads((mine / "export.json").read_text())
    doc["vehicles"]["sim-veh-000"]["records"][0]["after"]["translation"][1] += 0.05  # re-exported since
    (mine / "export.json").write_text(json.dumps(doc))
    with pytest.raises(HybridCalibError, match="the --reference export.s file .exported again at the same path since."):
        calibrate(root, VERSION, "oracle", tmp_path / "c", conf, progress=False)


def test_export_of_a_drive_checked_against_an_export_keeps_that_reference(knocked, tmp_path):
    """A later drive's export: the axes it keeps hold the earlier export's values (the reference its verdict used),
    not the old tables' (which would put the knock back); an export changed since the calibration is refused."""
    from hybrid_calib.calib.covariance import camera_offset
    from hybrid_calib.calib.drift import AXIS_WORDS
    from hybrid_calib.calib.export import export_mounts
    from hybrid_calib.calib.pipeline import calibrate
    from hybrid_calib.geometry import pose_from_nuscenes

    _, _, exp, later = knocked
    mine = tmp_path / "exp"
    shutil.copytree(exp, mine)
    run = calibrate(later, VERSION, "oracle", tmp_path / "c", {"window": {"window": 3}, "reference": str(mine)},
                    progress=False)
    new = export_mounts([tmp_path / "c" / "result.json"], tmp_path / "x2", which="trusted")
    ref = _reader(later, str(mine))
    for name, entry in new.vehicles.items():
        if not entry["exported"]:
            continue
        rec = entry["records"][0]
        cam, base = (pose_from_nuscenes(rec[k]["rotation"], rec[k]["translation"]) for k in ("camera", "reference"))
        i = ref.frames_by_vehicle()[name][0]
        np.testing.assert_allclose(se3_inverse(cam) @ base, ref.reference_T_cam_radar(ref.frames[i]), atol=1e-9)
        assert entry["reference"]["kind"] == "export"
        # the axes it keeps hold the earlier export's values (the old tables' would put the knock back)
        after = pose_from_nuscenes(rec["after"]["rotation"], rec["after"]["translation"])
        offset = camera_offset(se3_inverse(cam) @ base, se3_inverse(cam) @ after)
        kept = [AXIS_WORDS.index(w) for w in entry["tables_kept"]]
        assert kept, entry["tables_kept"]
        np.testing.assert_allclose(offset[kept], 0.0, atol=1e-7)
        # and its words say so (probe 106: "the tables' pitch, roll, ... kept" beside the export's values)
        assert "(the exported mount's " in entry["why"] and "the tables'" not in entry["why"], entry["why"]
    assert new.exported, {n: e["why"] for n, e in new.vehicles.items()}
    assert run.vehicles
    doc = json.loads((mine / "export.json").read_text())
    doc["notes"] = ["edited"]
    (mine / "export.json").write_text(json.dumps(doc))
    for which in ("trusted", "recalibrate"):  # the default too (probe 76: it said only "kept the tables")
        again = export_mounts([tmp_path / "c" / "result.json"], tmp_path / f"x3{which}", which=which)
        assert not again.exported
        assert all("has been replaced since the calibration" in e["why"] for e in again.vehicles.values())


def test_data_reference_is_one_option(tmp_path):
    from hybrid_calib.hybrid import HybridConfig

    with pytest.raises(ValueError, match="--reference"):
        HybridConfig(data={"reference": str(tmp_path)})


def test_the_commands_take_reference_and_refuse_a_bad_one_by_name(knocked, tmp_path, capsys):
    from hybrid_calib.cli import main

    _, _, exp, later = knocked
    for cmd in (["calibrate", "--data", str(later), "--out", str(tmp_path / "c"), "--no-plots"],
                ["fleet", "--data", str(later), "--out", str(tmp_path / "f"), "--no-plots", "--no-report"]):
        assert main([*cmd, "--reference", str(tmp_path / "nowhere")]) != 0
        err = capsys.readouterr().err
        assert "--reference" in err and "nowhere" in err and "does not exist" in err and "Traceback" not in err
        assert not (tmp_path / "c" / "result.json").exists() and not (tmp_path / "f" / "manifest.json").exists()
    assert main(["calibrate", "--data", str(later), "--out", str(tmp_path / "c"), "--no-plots", "--max-frames", "4",
                 "--set", "window.window=3", "--reference", str(exp)]) == 0
    out = capsys.readouterr()
    assert "reference: sim-veh-000, sim-veh-001 checked against the mounts exported in" in out.err
    for method in ("oracle", "pure-avg"):  # a run of one vehicle names it alone (pure-avg has no window to set)
        window = ["window.window=3"] if method == "oracle" else []
        assert main(["calibrate", "--data", str(later), "--out", str(tmp_path / method), "--no-plots", "--method",
                     method, "--max-frames", "3", "--set", *window, 'vehicles=["sim-veh-001"]',
                     "--reference", str(exp)]) == 0
        assert "reference: sim-veh-001 checked against the mount exported in" in capsys.readouterr().err, method
    assert f"vs reference (the export {(exp / 'export.json').absolute()}):" in out.out
    assert main(["fleet", "--data", str(later), "--out", str(tmp_path / "f"), "--no-plots", "--no-report",
                 "--max-frames", "4", "--set", "window.window=3", "--reference", str(exp)]) == 0
    for name in ("sim-veh-000", "sim-veh-001"):
        doc = json.loads((tmp_path / "f" / "vehicles" / name / "result.json").read_text())
        assert doc["vehicles"][name]["drift"]["reference"]["kind"] == "export"
        # the fleet view's offsets are from the same reference (from the old tables they read the 2 deg knock)
        summary = json.loads((tmp_path / "f" / "summary.json").read_text())
        off = summary["vehicles"][name]["offset_from_tables"]
        assert abs(off["rot_y_cam_deg"]) < 0.5, off  # yaw: about camera y
        assert summary["vehicles"][name]["reference"]["kind"] == "export"
    assert summary["reference"] == str(exp / "export.json")
    assert (f"Checked against the earlier export {exp / 'export.json'} (--reference): sim-veh-000, sim-veh-001"
            in (tmp_path / "f" / "summary.md").read_text())


def test_a_fleets_offsets_are_from_the_reference_it_was_given(knocked):
    from hybrid_calib.data.reference import load_export_reference
    from hybrid_calib.fleet.jobs import _root_vehicles

    _, _, exp, later = knocked
    T = load_export_reference(exp).T_cam_radar("sim-veh-000")
    with_ref = _root_vehicles(str(later), VERSION, [], str(exp))["sim-veh-000"]["tables_T"]
    np.testing.assert_allclose(with_ref, T, atol=1e-12)
    assert not np.allclose(_root_vehicles(str(later), VERSION, [])["sim-veh-000"]["tables_T"], T, atol=1e-3)


def test_the_report_page_says_what_the_verdict_compared_with(knocked, tmp_path, capsys):
    """The page of a drive checked against an export names it (and its replayed rows and start are the run's: the
    report rebuilds an oracle run's rows from its config.json, which holds the reference and its sha256)."""
    from hybrid_calib.calib.pipeline import calibrate
    from hybrid_calib.report.vehicle import write_report

    _, _, exp, later = knocked
    conf = {"window": {"window": 3}, "vehicles": ["sim-veh-000"], "max_frames": 4}
    calibrate(later, VERSION, "oracle", tmp_path / "t", conf, progress=False)
    calibrate(later, VERSION, "oracle", tmp_path / "r", {**conf, "reference": str(exp)}, progress=False)
    capsys.readouterr()
    plain = write_report(tmp_path / "t" / "result.json", tmp_path / "t.html", conf={"frames": 1}).read_text()
    page = write_report(tmp_path / "r" / "result.json", tmp_path / "r.html", conf={"frames": 1}).read_text()
    assert "reference:" not in capsys.readouterr().err  # said by the run; a page per vehicle repeated it
    assert ('<span id="reference">its calibration tables (a simulated vehicle&#x27;s factory calibration)</span>'
            in plain)
    assert f'<span id="reference">the mount exported in {(exp / "export.json").absolute()} (from' in page
    assert "no usable run config" not in page
    from hybrid_calib.report.fleet import write_fleet_page

    fleet = write_fleet_page([tmp_path / "r" / "result.json", tmp_path / "t" / "result.json"], tmp_path / "f.html",
                             labels=["later-ref", "later-tables"]).read_text()
    assert ('<p id="reference">Verdicts checked against an earlier export (--reference), not the tables: later-ref '
            f"against the mount in {(exp / 'export.json').absolute()}; the others against their tables.</p>") in fleet


def test_a_fleet_does_not_resume_against_a_reexported_reference(knocked, tmp_path, capsys):
    from hybrid_calib.cli import main

    _, _, exp, later = knocked
    mine = tmp_path / "exp"
    shutil.copytree(exp, mine)
    cmd = ["fleet", "--data", str(later), "--out", str(tmp_path / "f"), "--no-plots", "--no-report", "--max-frames",
           "3", "--set", "window.window=3", "--reference", str(mine)]
    assert main(cmd) == 0
    assert main(cmd) == 0  # resumed: every job done
    capsys.readouterr()
    doc = json.loads((mine / "export.json").read_text())
    doc["notes"] = ["exported again"]
    (mine / "export.json").write_text(json.dumps(doc))
    assert main(cmd) != 0
    err = capsys.readouterr().err
    assert "the --reference export's file (exported again at the same path, or another file)" in err, err


def test_the_folder_and_its_export_json_are_one_reference(knocked, tmp_path):
    from hybrid_calib.calib.pipeline import calibrate

    _, _, exp, later = knocked
    conf = {"window": {"window": 3}, "vehicles": ["sim-veh-000"], "max_frames": 3}
    first = calibrate(later, VERSION, "oracle", tmp_path / "c", {**conf, "reference": str(exp)}, progress=False)
    dotted = str(exp.parent / "." / exp.name / ".." / exp.name / "export.json")
    again = calibrate(later, VERSION, "oracle", tmp_path / "c", {**conf, "reference": dotted}, progress=False)
    assert again.vehicles["sim-veh-000"].drift == first.vehicles["sim-veh-000"].drift  # reused, not "another run"
    assert first.vehicles["sim-veh-000"].drift["reference"]["path"] == str(exp / "export.json")


def test_an_export_chain_carries_the_mount_of_a_drive_that_did_not_move(knocked, tmp_path, capsys):
    """drive 1 -> export 1 -> a later drive against it, nothing moved -> export 2 -> the next drive against export 2:
    export 2 holds export 1's mounts (carried), so the chain does not fall back to the tables from before the knock
    (probe 76: export 2 wrote nothing, and the third drive read "recalibrate")."""
    from hybrid_calib.cli import main
    from hybrid_calib.data.reference import load_export_reference

    _, _, exp, later = knocked
    conf = ["--set", "window.window=3", "--no-plots"]
    assert main(["calibrate", "--data", str(later), "--out", str(tmp_path / "c2"), "--reference", str(exp), *conf]) == 0
    assert main(["export", str(tmp_path / "c2" / "result.json"), "--out", str(tmp_path / "e2")]) == 0
    out = capsys.readouterr().out
    assert out.count("carried: 1 radar record(s) hold the mount of the export its verdict compared with") == 2, out
    # and why its own estimate was not written names that export, not the tables (probe 105: "kept the tables: the
    # verdict against them ..." beside a record holding the export's mount)
    assert "kept the tables" not in out and "its tables" not in out, out
    assert "kept the exported mount: the verdict against it is 'cannot tell'" in out, out
    e1, e2 = load_export_reference(exp), load_export_reference(tmp_path / "e2")
    for name in ("sim-veh-000", "sim-veh-001"):
        np.testing.assert_allclose(e2.T_cam_radar(name), e1.T_cam_radar(name), atol=1e-9)
    assert main(["calibrate", "--data", str(later), "--out", str(tmp_path / "c3"), "--reference",
                 str(tmp_path / "e2"), *conf]) == 0
    lines = [line for line in capsys.readouterr().out.splitlines() if line.startswith("sim-veh-")]
    assert len(lines) == 2 and not any(": recalibrate" in line for line in lines), lines


def test_an_export_of_some_vehicles_carries_the_others_of_its_reference(knocked, tmp_path):
    """Results of one vehicle of a later drive (the other not calibrated there) exported: the other vehicle of the
    reference export keeps its exported mount in the new export (probe 77: it vanished, and the next drive read it
    against the tables from before the knock)."""
    from hybrid_calib.calib.export import export_mounts
    from hybrid_calib.calib.pipeline import calibrate
    from hybrid_calib.data.reference import load_export_reference

    _, _, exp, later = knocked
    calibrate(later, VERSION, "oracle", tmp_path / "c", {"window": {"window": 3}, "reference": str(exp),
                                                        "vehicles": ["sim-veh-000"]}, progress=False)
    new = export_mounts([tmp_path / "c" / "result.json"], tmp_path / "e2")
    assert new.vehicles["sim-veh-001"]["carried"] and new.vehicles["sim-veh-001"]["own_why"] == "not among the results"
    e1, e2 = load_export_reference(exp), load_export_reference(tmp_path / "e2")
    np.testing.assert_allclose(e2.T_cam_radar("sim-veh-001"), e1.T_cam_radar("sim-veh-001"), atol=1e-9)


def test_a_mount_change_in_a_real_root_s_tables_is_two_vehicles_each_exported_to_its_own_records(tmp_path):
    """A real-like root (no sim_vehicle.json) whose tables hold two radar-camera calibrations along one vehicle's drive:
    one estimate is never written into both calibrations' records (probe 77: the guard compared the export with
    itself). Since probe 137 each calibration is its own vehicle (NAME, NAME-cal2), whose export writes its own
    records only; a simulated root's knock stays one vehicle, judged on its factory calibration (probe 50)."""
    from hybrid_calib.calib.export import export_mounts
    from hybrid_calib.calib.pipeline import calibrate

    step = {"kind": "step", "frame": 4, "rotation_deg": [0.0, 0.0, 0.3], "translation_m": [0.0, 0.0, 0.0]}
    root = _sim(tmp_path / "d", 6, knock=step, vehicles=1)
    (root / VERSION / "sim_vehicle.json").unlink()
    calibrate(root, VERSION, "oracle", tmp_path / "split", {"window": {"window": 3}}, progress=False)
    new = export_mounts([tmp_path / "split" / "result.json"], tmp_path / "xsplit", which="trusted").vehicles
    assert set(new) == {"sim-veh-000", "sim-veh-000-cal2"}, new
    records = [{r["token"] for r in new[v]["records"]} for v in sorted(new)]
    assert any(records) and not records[0] & records[1], (records, {v: e["why"] for v, e in new.items()})


def test_the_report_replays_a_run_whose_reference_changed_since_from_its_recorded_start(knocked, tmp_path):
    from hybrid_calib.calib.pipeline import calibrate
    from hybrid_calib.calib.result import CalibrationRun
    from hybrid_calib.report.evidence import gather

    _, _, exp, later = knocked
    mine = tmp_path / "exp"
    shutil.copytree(exp, mine)
    calibrate(later, VERSION, "oracle", tmp_path / "r", {"window": {"window": 3}, "vehicles": ["sim-veh-000"],
                                                        "max_frames": 3, "reference": str(mine)}, progress=False)
    doc = json.loads((mine / "export.json").read_text())
    doc["vehicles"]["sim-veh-000"]["records"][0]["after"]["translation"][1] += 0.3  # re-exported since
    (mine / "export.json").write_text(json.dumps(doc))
    result = tmp_path / "r" / "result.json"
    run = CalibrationRun.load(result)
    ev = gather(run, result, "sim-veh-000", None, None, 0)
    np.testing.assert_array_equal(ev.start, run.vehicles["sim-veh-000"].start["T_cam_radar"])
    assert ev.residuals is not None  # the rows do not depend on the reference
    assert ev.start_label == f"the vehicle's reference (the mount exported in {mine / 'export.json'})"
    (mine / "export.json").unlink()  # removed since: the rows and the start still replay
    assert gather(run, result, "sim-veh-000", None, None, 0).residuals is not None


def _drift(level_then: float | None, kind: str = "cannot tell") -> dict:
    """A drift block checked against an export whose drive's Doppler level was ``level_then`` (None: not recorded)."""
    ref = {"kind": "export", "path": "/x/export.json", "sha256": "0"}
    if level_then is not None:
        ref["doppler"] = {"level_deg": level_then, "std_deg": 0.03}
    return {"verdict_kind": kind, "verdict": f"{kind}: (a test)", "drifted": kind == "recalibrate",
            "axes": {"yaw": {"tolerance": 0.5, "delta": 0.0, "std": 0.3}}, "reference": ref}


@pytest.mark.parametrize("then, now, turned", [
    (0.2, 1.25, True),  # 1.05 deg since the export: beyond 0.5 + 3 x 0.11
    (0.2, 1.0, False),  # 0.8 deg: not beyond its 3-sigma
    (-0.3, -1.4, True),  # the other way
    (None, 1.25, False),  # an export without the Doppler record: nothing to compare
])
def test_a_turn_since_the_export_is_told_by_the_doppler_drive_against_drive(then, now, turned):
    """The radar mount monitor's level on this drive against the level the export recorded on its own drive (both
    against the exported mount): the same measurement twice, so the Doppler's bias cancels; a 1 deg turn the
    hybrid's yaw (0.3 deg at 1 sigma) left at "cannot tell" on 9 of 9 radars (docs/benchmarks.md)."""
    from hybrid_calib.calib.drift import turned_since_export, with_turn_since_export
    from hybrid_calib.calib.result import Estimate, VehicleResult
    from hybrid_calib.report.verdict import verdict_of

    mount = {"levels": [{"level_deg": now, "std_deg": 0.03, "pairs": 200}], "steps": []}
    d = with_turn_since_export(_drift(then), mount)
    assert (d["verdict_kind"] == "recalibrate") is turned, d["verdict"]
    if turned:
        assert d["at_end"]["verdict_kind"] == "cannot tell"
        assert "since the export it is checked against (/x/export.json)" in d["verdict"]
        assert ("to the left" if now > then else "to the right") in d["verdict"]
        vr = VehicleResult("v", Estimate(np.eye(4), np.eye(6) * 1e-4, np.full(6, 0.01), "ok"), drift=d, mount=mount)
        assert verdict_of(vr).word == "recalibrate"  # the report says it too
    kept = with_turn_since_export(_drift(then, "recalibrate"), mount)  # its own verdict kept, the turn said beside
    assert kept["verdict"].startswith("recalibrate: (a test)") and "at_end" not in kept
    assert with_turn_since_export(d, mount) == d  # said once (probe 145: a fleet prior's calibration said it twice)
    unsaid = with_turn_since_export(_drift(then), {"levels": [], "steps": []})
    assert with_turn_since_export(unsaid, {"levels": [], "steps": []}) == unsaid
    steps = {**mount, "steps": [{"step_deg": 1.0, "std_deg": 0.1, "change": 3, "at": 5}],
             "levels": mount["levels"] * 2}
    assert turned_since_export(_drift(then), steps, 0.5) == ""  # a step inside the drive: with_mount_step's case


def test_a_step_inside_the_later_drive_does_not_hide_a_turn_since_the_export():
    """The level of the mount at the drive's end (after a step the last one) is what is compared with the export's
    (probe 78: a 0.41 deg step inside the drive turned the test off, and a radar 1.5 deg from the export read a plain
    "cannot tell"); a turn within the tolerance is recorded and said beside the verdict, not as "recalibrate"."""
    from hybrid_calib.calib.drift import with_turn_since_export

    mount = {"levels": [{"level_deg": 1.09, "std_deg": 0.04, "frames": 14}, {"level_deg": 1.5, "std_deg": 0.05,
                                                                             "frames": 15}],
             "steps": [{"step_deg": 0.41, "std_deg": 0.06, "change": 15, "at": 18}]}
    d = with_turn_since_export(_drift(0.0), mount)
    assert d["verdict_kind"] == "recalibrate" and d["since_export"]["delta_deg"] == pytest.approx(1.5)
    small = with_turn_since_export(_drift(0.0), {"levels": [{"level_deg": 0.7, "std_deg": 0.03}], "steps": []})
    assert small["verdict_kind"] == "cannot tell" and {k: small["since_export"][k] for k in (
        "delta_deg", "std_deg", "beyond")} == pytest.approx(
        {"delta_deg": 0.7, "std_deg": float(np.sqrt(0.03 ** 2 * 2 + 0.1 ** 2)), "beyond": False})


def test_a_turn_since_the_export_within_the_tolerance_is_said_and_an_untested_one_too():
    """A turn since the export its Doppler measured but within the tolerance is said beside the verdict (it was only
    recorded: a radar 0.7 deg off its export read a plain verdict), a turn within the Doppler's own noise is not, and a
    drive checked against an export that could not be tested for a turn says why (pure and pure-avg run no mount
    monitor; an export without a Doppler record; no level at the drive's end). Against the tables: unchanged. A
    report's redo against another tolerance says each again, once."""
    from hybrid_calib.calib.drift import against_tolerance, reference_test, with_turn_since_export
    from tests.helpers import nominal_T_cam_radar

    one = {"levels": [{"level_deg": 0.7, "std_deg": 0.03}], "steps": []}
    small = with_turn_since_export(_drift(0.0), one)
    assert small["verdict_kind"] == "cannot tell" and small["verdict"].startswith("cannot tell: (a test); the radar")
    assert "turned on the vehicle by 0.70 +- 0.33 deg (3 sigma) to the left in yaw since the export, not clearly " \
           "beyond the 0.5 deg tolerance" in small["verdict"]
    noise = with_turn_since_export(_drift(0.0), {**one, "levels": [{"level_deg": 0.2, "std_deg": 0.03}]})
    assert noise["verdict"] == "cannot tell: (a test)" and noise["since_export"]["delta_deg"] == pytest.approx(0.2)
    for mount, method, why in [(None, "pure-avg", "method pure-avg runs no radar mount monitor"),
                               (None, "hybrid", "no radar mount monitor ran"),
                               ({"levels": [], "steps": []}, "hybrid", "read no level of the mount at the drive's")]:
        d = with_turn_since_export(_drift(0.0), mount, method)
        assert d["since_export"]["tested"] is False and d["verdict"].startswith("cannot tell: (a test); not tested "
                                                                                 "for a turn of the radar since the "
                                                                                 "export by its Doppler: ")
        assert why in d["verdict"], d["verdict"]
    assert "the export recorded no Doppler level" in with_turn_since_export(_drift(None), one)["verdict"]
    tables = {**_drift(0.0), "reference": {"kind": "tables"}}
    assert with_turn_since_export(tables, None, "pure") == tables
    T = nominal_T_cam_radar()
    full = {**reference_test(T, np.eye(6) * 1e-8, T).to_dict(), "reference": _drift(0.0)["reference"]}
    said = with_turn_since_export(full, one)
    assert said["verdict_kind"] == "within tolerance" and said["verdict"].count("since the export, not clearly") == 1
    assert against_tolerance(said, "ok", one)["verdict"].count("not clearly beyond the 0.5 deg") == 1
    assert "not clearly beyond the 1 deg tolerance" in against_tolerance(said, "ok", one, rot_deg=1.0)["verdict"]
    assert "since the export" not in against_tolerance(said, "ok", one, rot_deg=0.3)["verdict"]  # beyond: the report's
    untested = with_turn_since_export(full, None, "pure")
    assert against_tolerance(untested, "ok", None, rot_deg=1.0)["verdict"].count("method pure runs no") == 1


def test_the_words_name_the_exported_mount_not_the_tables():
    """Against an earlier export, the calibrator's sentences that name the reference "its tables" (the Doppler's note,
    the camera-side note, a radar too far off, the mount monitor's far level in a status) say the exported mount
    (session 38 left "its tables" there); against the tables they are unchanged; a report's redo says it too."""
    from hybrid_calib.calib.drift import against_tolerance, doppler_level_note, reference_test, unconverged
    from hybrid_calib.calib.pipeline import in_reference_nouns
    from hybrid_calib.calib.result import Estimate, VehicleResult
    from tests.helpers import nominal_T_cam_radar

    T = nominal_T_cam_radar()
    told = unconverged(reference_test(T, np.eye(6) * 1e-8, T).to_dict(), "inconclusive: out of domain")
    far = {"levels": [{"level_deg": -8.93, "std_deg": 0.10, "pairs": 40, "from": 0, "to": 40}], "steps": []}
    status = ("inconclusive: the radar's own heading on the vehicle lies 8.93 deg to the right of its tables' "
              "(frames 0-40): the radar is not mounted as its tables say; ok")
    for src, words in [(_drift(0.0)["reference"], "to the right of the exported mount's"),
                       ({"kind": "tables"}, "to the right of its tables'")]:
        d = {**doppler_level_note(told, far), "reference": src}
        vr = in_reference_nouns(VehicleResult("v", Estimate(T, np.eye(6), np.ones(6), status), drift=d))
        assert words in vr.drift["verdict"] and words in vr.final.status, (vr.drift["verdict"], vr.final.status)
        assert ("its tables" in vr.drift["verdict"]) is (src["kind"] == "tables")
        assert ("as the export says" in vr.final.status) is (src["kind"] == "export")
        redone = against_tolerance(vr.drift, "inconclusive: out of domain", far, rot_deg=1.0)
        assert words in redone["verdict"] and redone["verdict"].count("the radar's own Doppler") == 1
        # the Doppler level's note (the fleet page, summary.md), the monitor's implausible level and the lever arm's
        # note that repeats it (probe 107: "its tables' yaw is off", "within 10 deg of its tables" against an export)
        level = {**d, "doppler_level": {"level_deg": 1.97, "std_deg": 0.1, "words": "right of its tables': check the "
                                        "radar's yaw (if the ego poses are right, its tables' yaw is off)"}}
        said = "velocity fields or its mount in the tables are wrong (within 10 deg of its tables)"
        vr = VehicleResult("v", Estimate(T, np.eye(6), np.ones(6), status), drift=level)
        vr.mount, vr.doppler = {"implausible": said}, {"applied": False, "note": said}
        vr = in_reference_nouns(vr)
        export = src["kind"] == "export"
        assert ("the exported mount's yaw is off" in vr.drift["doppler_level"]["words"]) is export
        for text in (vr.mount["implausible"], vr.doppler["note"]):
            assert ("its tables" in text or "in the tables" in text) is not export, text
            assert ("its exported mount are wrong (within 10 deg of the exported mount)" in text) is export, text


def test_the_oracle_says_no_doppler_test_ran_against_an_export(knocked, tmp_path):
    from hybrid_calib.hybrid import run_calibration

    _, _, exp, later = knocked
    conf = {"method": "oracle", "vehicles": ["sim-veh-000"], "progress": False, "window": {"window": 3},
            "reference": str(exp)}
    d = run_calibration(later, VERSION, tmp_path / "o", conf).vehicles["sim-veh-000"].drift
    assert d["since_export"]["tested"] is False and "not tested for a turn of the radar since the export" in \
        d["verdict"], d["verdict"]


@pytest.mark.parametrize("doppler", [{"level_deg": 370.0, "std_deg": 0.03}, {"level_deg": 0.1, "std_deg": 1e9},
                                     {"level_deg": True, "std_deg": 0.03}, {"level_deg": "0.1", "std_deg": 0.03},
                                     {"level_deg": 0.1, "std_deg": 0.0}, "0.1"])
def test_an_impossible_doppler_record_is_refused(knocked, tmp_path, doppler):
    from hybrid_calib.data.reference import load_export_reference

    _, _, exp, _ = knocked
    doc = json.loads((exp / "export.json").read_text())
    doc["vehicles"]["sim-veh-000"]["doppler"] = doppler
    (tmp_path / "export.json").write_text(json.dumps(doc))
    with pytest.raises(DataError, match="sim-veh-000's 'doppler' record is .*, not .level_deg: a yaw within 90 deg"):
        load_export_reference(tmp_path)


def test_what_the_network_knows_is_not_renamed_against_an_export():
    """"the network knows radars within a few degrees of their tables" read "... of their exported mounts" against an
    export (probe 107): what the network learned does not depend on the reference; the sentence names neither."""
    from hybrid_calib.calib.mount_monitor import monitor_trust_reason
    from hybrid_calib.data.reference import reference_nouns

    far = {"levels": [{"level_deg": -15.0, "std_deg": 0.1, "pairs": 40, "from": 0, "to": 40}], "steps": [],
           "far": {"level_deg": -15.0, "std_deg": 0.1, "from": 0, "to": 40}}
    why = monitor_trust_reason(far, 10.0)
    assert "knows radars within a few degrees of a fleet's mounts" in why, why
    assert "a fleet's mounts" in reference_nouns(why, {"kind": "export"})


def _turned_180(q_wxyz: list) -> list:
    """The rotation ``q_wxyz`` (w, x, y, z) turned half a turn about its own z axis."""
    w, x, y, z = q_wxyz
    return [-z, y, -x, w]  # q * (0, 0, 0, 1)


def test_an_export_of_a_vehicle_whose_logs_define_its_frame_differently_gives_each_log_its_own_mount(knocked,
                                                                                                      tmp_path):
    """Probe 139: the reference was the export's first record for every frame, so a drive in a log whose tables turn
    the vehicle frame (both records exported, one calibration) read the radar 3 deg off the exported mount's."""
    from hybrid_calib.data.reference import load_export_reference
    from hybrid_calib.geometry import make_T, pose_from_nuscenes, pose_to_nuscenes, so3_exp

    _, _, exp, _ = knocked
    mine = tmp_path / "exp"
    shutil.copytree(exp, mine)
    doc = json.loads((mine / "export.json").read_text())
    records = doc["vehicles"]["sim-veh-000"]["records"]
    Rz_inv = make_T(so3_exp(np.radians([0.0, 0.0, -3.0])), np.zeros(3))
    other = json.loads(json.dumps(records[0]))
    other["token"] = "radar-record-of-log-b"
    for key in ("camera", "after", "before", "reference"):
        if isinstance(other.get(key), dict):
            T = pose_from_nuscenes(other[key]["rotation"], other[key]["translation"])
            rot, trans = pose_to_nuscenes(Rz_inv @ T)
            other[key] = {"rotation": list(rot), "translation": list(trans)}
    records.append(other)
    (mine / "export.json").write_text(json.dumps(doc))
    ref = load_export_reference(mine)
    first, b = ref.mounts_at("sim-veh-000", records[0]["token"]), ref.mounts_at("sim-veh-000", other["token"])
    np.testing.assert_allclose(b[1], Rz_inv @ first[1], atol=1e-9)
    np.testing.assert_allclose(np.linalg.inv(b[0]) @ b[1], np.linalg.inv(first[0]) @ first[1], atol=1e-9)
    assert ref.mounts_at("sim-veh-000", "a-record-of-a-later-log") is ref.mounts["sim-veh-000"]
    assert ref.mounts_at("no-such-vehicle", other["token"]) is None


@pytest.mark.parametrize("value", [None, "", 7])
def test_an_export_whose_root_is_not_named_says_so_not_none(knocked, tmp_path, value):
    """Probe 150: an export whose 'data' was edited to null or "" was named "(from None, v1.0-sim)"."""
    from hybrid_calib.data.reference import load_export_reference

    _, _, exp, _ = knocked
    doc = json.loads((exp / "export.json").read_text())
    doc["data"] = value
    (path := tmp_path / "x").mkdir()
    (path / "export.json").write_text(json.dumps(doc))
    ref = load_export_reference(path)
    assert ref.data == "an unnamed root" and ref.version == doc["version"]
