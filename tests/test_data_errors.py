"""Bad input to the nuScenes data layer: every case names the file or token, says what is wrong,
and iteration records a skip and goes on."""

from __future__ import annotations

import argparse
import json
import warnings

import cv2
import numpy as np
import pytest

from hybrid_calib.commands import inspect as inspect_cmd
from hybrid_calib.config import ConfigError
from hybrid_calib.data.image_header import image_header
from hybrid_calib.data.nuscenes import NuScenesRadarCamera
from hybrid_calib.data.pcd import read_radar_pcd, write_radar_pcd
from hybrid_calib.errors import DataError
from tests.tiny_nuscenes import VERSION, corrupt_jpeg_scan, make_tiny_root


@pytest.fixture
def tiny(tmp_path):
    return make_tiny_root(tmp_path / "root", n_samples=4)


def _open(tiny, **conf):
    return NuScenesRadarCamera(tiny.root, tiny.version, conf=conf)


def _iterate_and_check_skip(tiny, index: int, *needles: str):
    """Iterating skips exactly frame ``index`` with a reason containing every needle; the rest load."""
    ds = _open(tiny)
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # a skip is recorded, not warned
        frames = list(ds)
    assert [f.index for f in frames] == [i for i in range(len(ds)) if i != index]
    assert len(ds.skipped) == 1
    rec = ds.skipped[0]
    assert rec.index == index
    for needle in needles:
        assert needle in rec.reason, (needle, rec.reason)
    with pytest.raises(DataError) as e:  # direct access raises the same error
        ds[index]
    assert str(e.value) == rec.reason
    with pytest.raises(DataError):  # on_error="raise" stops iteration
        list(_open(tiny, on_error="raise"))
    return rec


def test_clean_root_loads(tiny):
    ds = _open(tiny)
    frames = list(ds)
    assert len(ds) == 4 and len(frames) == 4 and ds.skipped == []
    f = frames[1]
    assert f.vehicle == "tiny" and f.scene_name == "tiny-scene" and f.log_token == "log0"
    assert f.radar_points.shape == (6, 3) and f.radar_points.dtype == np.float64
    assert (f.camera.width, f.camera.height) == (160, 90)
    assert f.image_path.is_file() and f.load_image().shape == (90, 160, 3)
    # RGB, as the network, the visual odometry and the figures read it (probe 74: BGR passed every test)
    cv2.imwrite(str(f.image_path), np.dstack([np.zeros((90, 160), np.uint8)] * 2 + [np.full((90, 160), 255, np.uint8)]))
    r, g, b = f.load_image()[45, 80].tolist()  # OpenCV's BGR red read as RGB red (a JPEG: within its rounding)
    assert r > 230 and g < 25 and b < 25, (r, g, b)
    assert f.depth_path is None and "radar_truth_path" not in f.extras
    np.testing.assert_array_equal(f.extras["radar_rows"], np.arange(6))
    assert ds.frames_by_vehicle() == {"tiny": [0, 1, 2, 3]}
    assert ds.scenes()[0]["name"] == "tiny-scene"


# ---------------------------------------------------------------- root, version and tables
def test_version_missing_lists_versions(tiny):
    with pytest.raises(DataError, match="does not exist") as e:
        NuScenesRadarCamera(tiny.root, "v1.0-trainval")
    assert VERSION in str(e.value) and "v1.0-trainval" in str(e.value)


def test_root_not_a_directory(tmp_path):
    with pytest.raises(DataError, match="does not exist") as e:
        NuScenesRadarCamera(tmp_path / "nowhere", VERSION)
    assert "nowhere" in str(e.value)
    (tmp_path / "afile").write_text("x")
    with pytest.raises(DataError, match="is not a directory"):
        NuScenesRadarCamera(tmp_path / "afile", VERSION)


def test_missing_table(tiny):
    (tiny.vdir / "ego_pose.json").unlink()
    with pytest.raises(DataError, match="missing") as e:
        _open(tiny)
    assert "ego_pose.json" in str(e.value)


@pytest.mark.parametrize("content", ["{not json", '[{"token": "a"', ""])
def test_malformed_table(tiny, content):
    (tiny.vdir / "sample.json").write_text(content)
    with pytest.raises(DataError, match="not valid JSON") as e:
        _open(tiny)
    assert "sample.json" in str(e.value)


def test_table_not_a_list(tiny):
    (tiny.vdir / "log.json").write_text(json.dumps({"token": "log0"}))
    with pytest.raises(DataError, match="JSON list") as e:
        _open(tiny)
    assert "log.json" in str(e.value)


def test_record_missing_field(tiny):
    """One record of sample_data off the schema is left out and said (probe 80); every record: the table is refused."""
    del tiny.tables["sample_data"][2]["filename"]
    tiny.rewrite_table("sample_data")
    ds = _open(tiny)
    (said,) = [s for s in ds.skipped if s.token == tiny.tables["sample_data"][2]["token"]]
    assert "lacks field(s) ['filename']" in said.reason and "sample_data.json" in said.reason
    for rec in tiny.tables["sample_data"]:
        rec.pop("filename", None)
    tiny.rewrite_table("sample_data")
    with pytest.raises(DataError, match=r"lacks field\(s\) \['filename'\]") as e:
        _open(tiny)
    assert "sample_data.json" in str(e.value) and tiny.tables["sample_data"][0]["token"] in str(e.value)


def test_unknown_channel_lists_channels(tiny):
    with pytest.raises(DataError, match="RADAR_BACK_LEFT") as e:
        NuScenesRadarCamera(tiny.root, VERSION, radar_channel="RADAR_BACK_LEFT")
    assert "RADAR_FRONT" in str(e.value)


def test_unknown_scene_and_vehicle(tiny):
    with pytest.raises(DataError, match="tiny-scene"):
        _open(tiny, scenes=["scene-0001"])
    with pytest.raises(DataError, match="vehicles present"):
        _open(tiny, vehicles=["n008"])
    assert len(_open(tiny, scenes=["tiny-scene"], vehicles=["tiny"])) == 4


def test_bad_config():
    with pytest.raises(ConfigError, match="nsweep"):
        NuScenesRadarCamera("/", VERSION, conf={"nsweep": 2})
    with pytest.raises(ValueError, match="on_error"):
        NuScenesRadarCamera("/", VERSION, conf={"on_error": "ignore"})


# ---------------------------------------------------------------- tokens
def test_unresolved_ego_pose_token_is_skipped(tiny):
    tiny.radar_sd[2]["ego_pose_token"] = "deadbeef"
    tiny.rewrite_table("sample_data")
    rec = _iterate_and_check_skip(tiny, 2, "deadbeef", "does not resolve", "ego_pose")
    assert rec.token == "deadbeef"


def test_unresolved_calibrated_sensor_token_recorded_at_index(tiny):
    tiny.radar_sd[1]["calibrated_sensor_token"] = "nosuchcs"
    tiny.rewrite_table("sample_data")
    ds = _open(tiny)
    assert len(ds) == 3  # the sample lost its radar keyframe
    reasons = " | ".join(r.reason for r in ds.skipped)
    assert "nosuchcs" in reasons and "calibrated_sensor" in reasons
    assert "sample1" in reasons  # and the sample is reported as not a frame
    assert all(r.index is None for r in ds.skipped)
    assert len(list(ds)) == 3


def test_sample_without_radar_keyframe(tiny):
    tiny.tables["sample_data"].remove(tiny.radar_sd[3])
    tiny.rewrite_table("sample_data")
    ds = _open(tiny)
    assert len(ds) == 3
    assert ds.skipped[0].token == "sample3" and "RADAR_FRONT" in ds.skipped[0].reason


def test_broken_sample_chain_falls_back_to_time_order(tiny):
    tiny.tables["sample"][1]["next"] = "nosuchsample"
    tiny.rewrite_table("sample")
    ds = _open(tiny)
    assert [f.sample_token for f in ds.frames] == ["sample0", "sample1", "sample2", "sample3"]


# ---------------------------------------------------------------- radar files
def test_truncated_pcd_is_skipped(tiny):
    path = tiny.path(tiny.radar_sd[1])
    path.write_bytes(path.read_bytes()[:-30])
    rec = _iterate_and_check_skip(tiny, 1, "truncated PCD", str(path))
    assert rec.path == str(path)


def test_garbage_pcd_is_skipped(tiny):
    path = tiny.path(tiny.radar_sd[0])
    path.write_bytes(np.random.default_rng(3).bytes(500))
    _iterate_and_check_skip(tiny, 0, str(path))


def test_missing_pcd_is_skipped(tiny):
    path = tiny.path(tiny.radar_sd[3])
    path.unlink()
    _iterate_and_check_skip(tiny, 3, "not found", str(path))


def test_nan_points_dropped_and_counted(tiny):
    """A few NaN/inf points are dropped and counted; more than 10 % of a sweep is a corrupt file (probe 80: half of a
    real sweep NaN was read as a good frame and moved pure's answer by 2.8 deg)."""
    path = tiny.path(tiny.radar_sd[1])
    pts = np.tile(read_radar_pcd(path), 5)  # 30 points
    pts["x"][[0, 4]] = np.nan
    pts["y"][2] = np.inf
    write_radar_pcd(path, pts)
    f = _open(tiny)[1]
    keep = [i for i in range(30) if i not in (0, 2, 4)]
    assert f.extras["radar_nonfinite_dropped"] == 3 and f.extras["radar_points_raw"] == 30
    np.testing.assert_array_equal(f.extras["radar_rows"], keep)
    assert len(f.radar_points) == 27 and np.all(np.isfinite(f.radar_points))
    for name, values in f.radar_fields.items():
        np.testing.assert_array_equal(values, pts[name][keep], err_msg=name)
    pts["x"][::2] = np.nan  # half of them
    write_radar_pcd(path, pts)
    _iterate_and_check_skip(tiny, 1, "15 of the 30 radar points have NaN/inf coordinates", "more than 10 %",
                            "the file is corrupt", str(path))


def test_all_nan_sweep_is_skipped(tiny):
    path = tiny.path(tiny.radar_sd[2])
    pts = read_radar_pcd(path)
    pts["x"] = np.nan
    write_radar_pcd(path, pts)
    _iterate_and_check_skip(tiny, 2, "all 6 radar points have NaN", str(path))


def test_empty_sweep_after_filtering(tiny):
    path = tiny.path(tiny.radar_sd[1])
    pts = read_radar_pcd(path)
    pts["ambig_state"] = 0  # devkit default keeps ambig_state 3 only
    write_radar_pcd(path, pts)
    _iterate_and_check_skip(tiny, 1, "0 points after filtering", "skip_empty_radar", str(path))
    kept = _open(tiny, skip_empty_radar=False)[1]
    assert kept.radar_points.shape == (0, 3) and kept.extras["radar_rows"].shape == (0,)
    assert len(_open(tiny, radar_filter={"ambig_states": None})[1].radar_points) == 6
    assert len(_open(tiny, radar_filter={"enabled": False})[1].radar_points) == 6
    # an empty list keeps no value (it reads as "no invalid states"): said, with what the lists mean (probe 7)
    ds = _open(tiny, radar_filter={"invalid_states": []})
    list(ds)
    assert "radar_filter.invalid_states=[] keeps no value" in ds.skipped[-1].reason


def test_zero_point_pcd_is_empty_sweep(tiny):
    path = tiny.path(tiny.radar_sd[0])
    write_radar_pcd(path, read_radar_pcd(path)[:0])  # nothing to filter: the file itself is empty (probe 9)
    _iterate_and_check_skip(tiny, 0, "radar file holds no points", "skip_empty_radar",
                            "train and evaluate always skip them")


def test_filters_follow_devkit_defaults(tiny):
    path = tiny.path(tiny.radar_sd[0])
    pts = read_radar_pcd(path)
    pts["invalid_state"][0] = 1  # invalid
    pts["dyn_prop"][1] = 7  # dyn_prop 7 is not in range(7)
    pts["ambig_state"][2] = 4  # ambiguous
    write_radar_pcd(path, pts)
    f = _open(tiny)[0]
    np.testing.assert_array_equal(f.extras["radar_rows"], [3, 4, 5])
    g = _open(tiny, radar_filter={"invalid_states": [0, 1], "dynprop_states": None})[0]
    np.testing.assert_array_equal(g.extras["radar_rows"], [0, 1, 3, 4, 5])


# ---------------------------------------------------------------- images
def test_missing_image_is_skipped(tiny):
    path = tiny.path(tiny.cam_sd[2])
    path.unlink()
    _iterate_and_check_skip(tiny, 2, "camera image not found", str(path))


def test_not_an_image_is_skipped(tiny):
    path = tiny.path(tiny.cam_sd[0])
    path.write_bytes(b"GIF89a" + bytes(200))
    _iterate_and_check_skip(tiny, 0, "not a JPEG or PNG", str(path))


def test_truncated_jpeg_is_skipped(tiny):
    path = tiny.path(tiny.cam_sd[1])
    path.write_bytes(path.read_bytes()[: path.stat().st_size // 2])
    _iterate_and_check_skip(tiny, 1, "truncated", str(path))


def test_jpeg_that_does_not_decode_fails_lazily(tiny):
    # a JPEG whose header is sound (SOI, SOF with a size, EOI) but that has no image data: it passes the
    # eager check, and load_image raises when it tries to decode it.
    path = tiny.path(tiny.cam_sd[3])
    sof = bytes.fromhex("ffc0001108005a00a003011100021100031100")  # three components (colour)
    path.write_bytes(b"\xff\xd8" + sof + b"\xff\xd9")
    assert image_header(path) == (160, 90)
    ds = _open(tiny)
    frame = ds[3]
    with pytest.raises(DataError, match="does not decode") as e:
        frame.load_image()
    assert str(path) in str(e.value) and tiny.cam_sd[3]["token"] in str(e.value)


def _with_exif_orientation(jpeg: bytes, orientation: int) -> bytes:
    """``jpeg`` with an APP1 EXIF segment holding one tag: Orientation (0x0112) = ``orientation``."""
    import struct

    tiff = b"MM\x00\x2a" + struct.pack(">I", 8) + struct.pack(">H", 1) + \
        struct.pack(">HHIHH", 0x0112, 3, 1, orientation, 0) + struct.pack(">I", 0)
    body = b"Exif\x00\x00" + tiff
    return jpeg[:2] + b"\xff\xe1" + struct.pack(">H", len(body) + 2) + body + jpeg[2:]


def test_a_jpeg_with_an_exif_orientation_is_read_as_stored(tiny):
    """OpenCV turned an image tagged "rotate 90": every frame skipped as "900x1600 but the calibration says
    1600x900", while inspect read the header's size. The stored grid is what the intrinsics describe."""
    from hybrid_calib.data.image_header import decode_image

    path = tiny.path(tiny.cam_sd[0])
    plain = decode_image(path)
    path.write_bytes(_with_exif_orientation(path.read_bytes(), 6))
    assert cv2.imread(str(path)).shape[:2] == plain.shape[1::-1][:2]  # OpenCV's default turns it
    turned = decode_image(path)
    assert turned.shape == plain.shape and np.array_equal(turned, plain)
    assert _open(tiny)[0].load_image().shape == plain.shape


def test_image_size_mismatch(tiny):
    tiny.cam_sd[1]["width"] = 1600
    tiny.cam_sd[1]["height"] = 900
    tiny.rewrite_table("sample_data")
    _iterate_and_check_skip(tiny, 1, "160x90", "1600x900")


def test_bad_intrinsic(tiny):
    tiny.tables["calibrated_sensor"][0]["camera_intrinsic"] = [[0, 0, 0]]
    tiny.rewrite_table("calibrated_sensor")
    with pytest.raises(DataError, match="camera_intrinsic") as e:
        _open(tiny)[0]
    assert "cs_CAM_FRONT" in str(e.value)


def test_several_bad_frames_iteration_goes_on(tiny):
    tiny.path(tiny.radar_sd[0]).write_bytes(b"garbage")
    tiny.path(tiny.cam_sd[2]).write_bytes(b"")
    ds = _open(tiny)
    assert [f.index for f in ds] == [1, 3]
    assert [r.index for r in ds.skipped] == [0, 2]
    assert [f.index for f in ds] == [1, 3] and len(ds.skipped) == 2  # a second pass does not duplicate


# ---------------------------------------------------------------- LiDAR
def test_lidar_corrupt_and_missing_channel(tiny):
    path = tiny.path(tiny.lidar_sd[1])
    path.write_bytes(bytes(13))
    ds = _open(tiny, load_lidar=True)
    frames = list(ds)
    assert [f.index for f in frames] == [0, 2, 3]
    assert "multiple of 20" in ds.skipped[0].reason and str(path) in ds.skipped[0].reason
    assert frames[0].lidar_points.shape == (6, 4) and frames[0].lidar_points.dtype == np.float32
    with pytest.raises(DataError, match="LIDAR_TOP"):
        NuScenesRadarCamera(tiny.root, VERSION, conf={"load_lidar": True, "lidar_channel": "LIDAR_LEFT"})


# ---------------------------------------------------------------- the inspect command
def test_inspect_command_reports_skips(tiny, tmp_path, capsys):
    bad = tiny.path(tiny.radar_sd[2])
    bad.write_bytes(bad.read_bytes()[:-40])
    parser = argparse.ArgumentParser()
    inspect_cmd.add_arguments(parser)
    out = tmp_path / "out"
    args = parser.parse_args(["--data", str(tiny.root), "--version", VERSION, "--out", str(out), "--no-progress",
                              "--set", "radar_filter.ambig_states=null"])
    assert inspect_cmd.run(args) == 0
    text = capsys.readouterr().out
    assert "3/4 frames loaded, 1 skipped" in text and str(bad) in text
    summary = json.loads((out / "inspect_summary.json").read_text())
    assert summary["n_frames"] == 4 and summary["n_loaded"] == 3 and summary["skipped"][0]["index"] == 2
    group = summary["groups"][0]
    assert group["vehicle"] == "tiny" and group["radar_points_per_sweep"] == {"mean": 6.0, "min": 6, "max": 6}
    assert group["dt_radar_minus_camera_ms"]["mean"] == pytest.approx(45.0)
    conf = json.loads((out / "inspect_config.json").read_text())
    assert conf["conf"]["radar_filter"]["ambig_states"] is None
    png = cv2.imread(str(out / "overlay.png"))
    assert png is not None and png.shape[0] > 100
    # a reader that stops after the first line (`| head -1`): the files are written before the table (probe 66: none
    # were)
    import io
    import sys

    class Gone(io.StringIO):
        def write(self, text):
            raise BrokenPipeError(32, "Broken pipe")

    gone = parser.parse_args(["--data", str(tiny.root), "--version", VERSION, "--out", str(tmp_path / "gone"),
                              "--no-progress", "--set", "radar_filter.ambig_states=null"])
    real, sys.stdout = sys.stdout, Gone()
    try:
        with pytest.raises(BrokenPipeError):
            inspect_cmd.run(gone)
    finally:
        sys.stdout = real
    assert json.loads((tmp_path / "gone" / "inspect_summary.json").read_text())["n_loaded"] == 3


# ---------------------------------------------------------------- accepted silently before (issue 8)
def test_duplicate_token_is_an_error(tiny):
    tiny.tables["sample_data"].append(dict(tiny.radar_sd[1]))
    tiny.rewrite_table("sample_data")
    with pytest.raises(DataError, match="token appears twice") as e:
        _open(tiny)
    assert "sample_data.json" in str(e.value) and tiny.radar_sd[1]["token"] in str(e.value)


def test_empty_sample_table_says_so(tiny):
    tiny.tables["sample"] = []
    tiny.rewrite_table("sample")
    with pytest.raises(DataError, match="holds no samples") as e:
        _open(tiny)
    assert "sample.json" in str(e.value)


@pytest.mark.parametrize("table", ["ego_pose", "calibrated_sensor"])
def test_quaternion_renormalised_only_within_tolerance(tiny, table):
    from hybrid_calib.data.tables import QUAT_NORM_TOL

    rec = next(r for r in tiny.tables[table] if r["token"] in (tiny.radar_sd[2]["ego_pose_token"], "cs_RADAR_FRONT"))
    exact = _open(tiny)[2].T_cam_radar
    q = np.asarray(rec["rotation"])
    rec["rotation"] = (q * (1 + 0.5 * QUAT_NORM_TOL)).tolist()  # rounding in the file: renormalised
    tiny.rewrite_table(table)
    np.testing.assert_allclose(_open(tiny)[2].T_cam_radar, exact, atol=1e-12)
    rec["rotation"] = (q * 1.5).tolist()  # far from a rotation: the record is rejected
    tiny.rewrite_table(table)
    ds = _open(tiny)
    frames = list(ds)
    assert 2 not in [f.index for f in frames]
    reason = next(r.reason for r in ds.skipped if r.index == 2)
    assert "norm 1.5" in reason and f"{table}.json" in reason and rec["token"] in reason


def test_jpeg_with_corrupt_scan_data(tiny):
    path = tiny.path(tiny.cam_sd[1])
    path.write_bytes(corrupt_jpeg_scan(path.read_bytes()))
    assert image_header(path) == (160, 90)  # the header is sound: the cheap check passes
    frame = _open(tiny)[1]
    with pytest.raises(DataError, match="corrupt pixel data") as e:  # decoding checks what OpenCV reports
        frame.load_image()
    assert str(path) in str(e.value) and "OpenCV reports" in str(e.value)
    ds = _open(tiny, decode_images=True)  # eager decode (inspect): a recorded skip
    assert [f.index for f in ds] == [0, 2, 3]
    assert "corrupt pixel data" in ds.skipped[0].reason and ds.skipped[0].path == str(path)
    assert _open(tiny)[0].load_image().shape == (90, 160, 3)  # a sound image still decodes


def test_lidar_nan_points_are_counted_in_the_summary(tiny):
    from hybrid_calib.data.pcd import read_lidar_bin, write_lidar_bin
    from hybrid_calib.data.summary import summarize_dataset

    path = tiny.path(tiny.lidar_sd[0])
    pts = read_lidar_bin(path)
    pts[[1, 3], 0] = np.nan
    write_lidar_bin(path, pts)
    ds = _open(tiny, load_lidar=True)
    assert ds[0].extras["lidar_nonfinite_dropped"] == 2 and len(ds[0].lidar_points) == 4
    assert summarize_dataset(ds, progress=False).to_json()["groups"][0]["lidar_nonfinite_dropped"] == 2


def test_an_unfinished_simulation_is_named(tmp_path):
    """A simulate run interrupted before its tables were written read as "no version folder (with sample.json) found
    there" (probe 7); the rerun of simulate finishes it."""
    from hybrid_calib.data.tables import version_dir

    (tmp_path / "sim_config.json").write_text("{}")
    (tmp_path / "samples").mkdir()
    with pytest.raises(DataError, match="an unfinished simulation.*rerun the simulate command"):
        version_dir(tmp_path, "v1.0-sim")


def test_a_recording_listed_twice_is_read_once(tiny):
    """Tables that list one sensor file for two samples (a scene copied under new tokens, pointing at the same
    files) were read as twice the frames, the copies counted as independent measurements (probe 9): the later
    sample is skipped by the index, naming both samples."""
    by_token = {sd["token"]: sd for sd in tiny.tables["sample_data"]}
    by_token[tiny.radar_sd[2]["token"]]["filename"] = tiny.radar_sd[0]["filename"]
    tiny.rewrite_table("sample_data")
    ds = _open(tiny)
    assert len(ds) == 3
    (rec,) = [r for r in ds.skipped if "the same sensor file" in r.reason]
    assert tiny.radar_sd[2]["sample_token"] in rec.reason and tiny.radar_sd[0]["sample_token"] in rec.reason
    assert "the tables list one recording twice" in rec.reason
    assert ds.duplicates == {tiny.radar_sd[2]["sample_token"]: tiny.radar_sd[0]["sample_token"]}  # said by calibrate


def test_a_missing_version_folder_says_what_to_pass(tmp_path):
    """Probe 23: 'no version folder found there; ... pass one of them with --version' with none to pass."""
    from hybrid_calib.data.tables import version_dir

    with pytest.raises(DataError) as e:
        version_dir(tmp_path, "v1.0-trainval")
    assert "pass one of them" not in str(e.value) and "pass the nuScenes root" in str(e.value)
    (tmp_path / "v1.0-mini").mkdir()
    (tmp_path / "v1.0-mini" / "sample.json").write_text("[]")
    with pytest.raises(DataError, match=r"versions found there: \['v1.0-mini'\]; pass one of them with --version"):
        version_dir(tmp_path, "v1.0-trainval")


def test_a_table_that_is_a_folder_or_a_fifo_is_said_so(tmp_path):
    """A FIFO log.json, a folder named sensor.json were "table ... is missing; re-extract" (probe 27)."""
    import os

    from hybrid_calib.data.tables import load_table
    from hybrid_calib.errors import DataError

    (tmp_path / "sensor.json").mkdir()
    with pytest.raises(DataError, match="table 'sensor' is a directory, not a regular file"):
        load_table(tmp_path, "sensor")
    os.mkfifo(tmp_path / "log.json")
    with pytest.raises(DataError, match=r"table 'log' is a named pipe \(FIFO\)"):
        load_table(tmp_path, "log")


def test_a_channel_folder_missing_from_the_copy_is_named_not_the_root(tmp_path):
    """A copy of a root with the front channels only: CAM_BACK's frames read "camera image not found; check the
    dataset root (samples/ must sit next to the version folder)", where samples/ was right (probe 34)."""
    from hybrid_calib.data.image_header import image_header
    from hybrid_calib.data.pcd import read_radar_pcd

    samples = tmp_path / "samples"
    (samples / "CAM_FRONT").mkdir(parents=True)
    (samples / "RADAR_FRONT").mkdir()
    with pytest.raises(DataError, match=r"camera image not found; the folder samples/CAM_BACK does not exist under the "
                                        r"root \(channel folders there: CAM_FRONT, RADAR_FRONT\): this copy has no "
                                        r"CAM_BACK files"):
        image_header(samples / "CAM_BACK" / "a.jpg")
    with pytest.raises(DataError, match=r"radar file not found; the folder samples/RADAR_BACK_LEFT does not exist"):
        read_radar_pcd(samples / "RADAR_BACK_LEFT" / "a.pcd")
    with pytest.raises(DataError, match=r"camera image not found; check the dataset root"):  # the folder is there
        image_header(samples / "CAM_FRONT" / "a.jpg")
    # the folder holds other files: this one was not downloaded (probe 101: "check the dataset root" for 5 of 41)
    (samples / "CAM_FRONT" / "b.jpg").write_bytes(b"")
    with pytest.raises(DataError, match=r"camera image not found; its folder samples/CAM_FRONT is there, with other "
                                        r"files: this one was not downloaded or was deleted \(a partial download\)"):
        image_header(samples / "CAM_FRONT" / "a.jpg")
    (samples / "RADAR_FRONT" / "b.pcd").write_bytes(b"")
    with pytest.raises(DataError, match=r"radar file not found; its folder samples/RADAR_FRONT is there, with other"):
        read_radar_pcd(samples / "RADAR_FRONT" / "a.pcd")


def test_a_channel_written_in_another_case_is_said_so_where_no_such_file_is(tiny):
    """Probe 40: samples/radar_front/...__radar_front__... read "a radar_front file: ... its file another channel's". A
    copy whose folder really is so named still reads."""
    import shutil

    from hybrid_calib.data.nuscenes import NuScenesRadarCamera

    sd = next(r for r in tiny.tables["sample_data"] if r["is_key_frame"] and "RADAR_FRONT" in r["filename"]
              and r["sample_token"] == tiny.tables["sample"][1]["token"])
    good = sd["filename"]
    sd["filename"] = good.replace("RADAR_FRONT", "radar_front")
    tiny.rewrite_table("sample_data")
    ds = NuScenesRadarCamera(tiny.root, tiny.version)
    index = next(k for k, ref in enumerate(ds.frames) if ref.radar_sd["token"] == sd["token"])
    with pytest.raises(DataError, match="its channel is written radar_front, in another case than RADAR_FRONT"):
        ds[index]
    (tiny.root / sd["filename"]).parent.mkdir(parents=True)
    shutil.copy(tiny.root / good, tiny.root / sd["filename"])  # the file is there under that name: read
    assert NuScenesRadarCamera(tiny.root, tiny.version)[index].radar_token == sd["token"]


def _copy_scene(tiny, vehicle: str | None = None, own_files: bool = True) -> None:
    """The tiny root's scene listed a second time with fresh tokens (scene, samples, sample_data, and a log when
    ``vehicle`` names another vehicle), at the same instants; ``own_files``: each copied record reads a copy of its
    file under a new name (another recording, as far as the tables say), else the same file."""
    import shutil

    t = tiny.tables
    (scene,) = t["scene"]
    log = scene["log_token"]
    if vehicle is not None:
        t["log"].append({**t["log"][0], "token": "log-copy", "vehicle": vehicle})
        log = "log-copy"
    new = {s["token"]: s["token"] + "-copy" for s in t["sample"]}
    t["scene"].append({**scene, "token": "scene-copy", "name": scene["name"] + "-copy", "log_token": log,
                       "first_sample_token": new[scene["first_sample_token"]],
                       "last_sample_token": new[scene["last_sample_token"]]})
    t["sample"] += [{**s, "token": new[s["token"]], "scene_token": "scene-copy",
                     "prev": new.get(s["prev"], ""), "next": new.get(s["next"], "")} for s in list(t["sample"])]
    sds = {sd["token"]: sd["token"] + "-copy" for sd in t["sample_data"]}
    for sd in list(t["sample_data"]):
        fn = sd["filename"]
        if own_files:
            fn = fn.replace(".", "-copy.", 1) if "." in fn else fn + "-copy"
            shutil.copy(tiny.root / sd["filename"], tiny.root / fn)
        t["sample_data"].append({**sd, "token": sds[sd["token"]], "filename": fn,
                                 "sample_token": new.get(sd["sample_token"], sd["sample_token"]),
                                 "prev": sds.get(sd["prev"], ""), "next": sds.get(sd["next"], "")})
    for name in ("log", "scene", "sample", "sample_data"):
        tiny.rewrite_table(name)


def test_a_scene_recorded_during_another_of_its_vehicle_is_left_out(tiny):
    """Probe 94: a scene copied with its own files under one vehicle was fused with the original as one drive; the
    copies were left out as repeated views, but the hybrid paired each kept frame with the copy of the instant before,
    refused every such pair as crossing scenes, and ran without motion (the yaw 1.4 deg apart). One vehicle records
    one scene at a time: the later one is left out, each of its samples said, listed with its vehicle."""
    _copy_scene(tiny)
    ds = _open(tiny)
    assert len(ds) == 4 and {f.scene_token for f in ds.frames} == {tiny.tables["scene"][0]["token"]}
    left = [r for r in ds.skipped if "was recorded while scene" in r.reason]
    assert len(left) == 4 and "one vehicle records one scene at a time" in left[0].reason
    assert "-copy" in left[0].reason and "of the same vehicle tiny" in left[0].reason
    assert len(ds.lacking_keyframes["tiny"]) == 4  # listed in the vehicle's result
    assert ds.frameless_vehicles() == {}
    from hybrid_calib.data.summary import calibration_notes
    from hybrid_calib.fleet.jobs import _root_vehicles

    (note,) = [n for n in calibration_notes(ds) if "left out" in n]  # said by calibrate and fleet (probe 96)
    assert note.startswith("note: scene tiny-scene-copy left out: recorded while scene tiny-scene of the same vehicle")
    notes: list[str] = []
    _root_vehicles(str(tiny.root), VERSION, notes)
    assert any("scene tiny-scene-copy left out" in n for n in notes)


def _remove_copies(tiny) -> None:
    """Delete the sensor files ``_copy_scene(own_files=True)`` wrote: the copied scene is in the tables only."""
    for sd in tiny.tables["sample_data"]:
        if "-copy" in sd["filename"]:
            (tiny.root / sd["filename"]).unlink(missing_ok=True)


def test_a_scene_whose_files_are_not_on_disk_is_left_out_once(tiny):
    """Probe 101: trainval's tables with one scene's files (a partial download): the other scenes' frames were unread
    frames of their vehicle's drive, which inflated its network priors by 861 frames for 41, moved the estimate, ended
    "a radar knocked, blocked or failed there" and printed a line per absent file. A scene none of whose frames has
    its files on disk is left out at the index, said once; a vehicle with no scene on disk is a note, not a failure."""
    from hybrid_calib.data.summary import calibration_notes

    _copy_scene(tiny)
    _remove_copies(tiny)
    ds = _open(tiny)
    assert len(ds) == 4 and {f.scene_name for f in ds.frames} == {"tiny-scene"}
    (left,) = [r for r in ds.skipped if "on disk" in r.reason]  # one record for the scene, not one per frame
    assert left.reason.startswith("scene tiny-scene-copy: none of its 4 frame(s) has its camera and radar keyframe")
    assert "a partial download" in left.reason and "data.scenes" in left.reason
    assert not any("was recorded while scene" in r.reason for r in ds.skipped)
    assert ds.lacking_keyframes["tiny"] == [left]  # listed in the vehicle's result
    (note,) = [n for n in calibration_notes(ds) if "not on disk" in n]
    assert note.startswith("note: scene tiny-scene-copy left out: their sensor files are not on disk")
    assert "vehicle(s)" not in note


def test_a_vehicle_with_no_scene_on_disk_is_named_with_why(tiny):
    from hybrid_calib.data.summary import calibration_notes
    from hybrid_calib.fleet.jobs import _root_vehicles

    _copy_scene(tiny, vehicle="tiny-2")
    _remove_copies(tiny)
    ds = _open(tiny)
    assert set(ds.frames_by_vehicle()) == {"tiny"} and ds.not_on_disk_vehicles() == ["tiny-2"]
    (why,) = ds.frameless_vehicles().values()  # a failed calibration (rc 1), as any vehicle with no frame
    assert why.startswith("vehicle tiny-2: no frame: none of its 1 scene(s) has its sensor files on disk (first: "
                          "scene tiny-scene-copy: none of its 4 frame(s)")
    (note,) = [n for n in calibration_notes(ds) if "not on disk" in n]
    assert note.endswith("vehicle(s) tiny-2 have no scene on disk: they cannot be calibrated")
    assert not [n for n in calibration_notes(ds, ["tiny"]) if "not on disk" in n]  # not asked for (probe 102)
    notes: list[str] = []
    vs = _root_vehicles(str(tiny.root), VERSION, notes)
    assert set(vs) == {"tiny", "tiny-2"} and vs["tiny-2"]["tables_T"] is None  # a fleet job that fails with why
    assert any("tiny-2 have no scene on disk" in n for n in notes)


def test_frames_with_no_file_on_disk_are_no_views_of_the_drive(tiny):
    """Probe 101: the network priors carry the drive-common error once over the drive's views; frames whose files are
    absent (part of a scene downloaded) are no views, and counting them loosened every prior."""
    from hybrid_calib.hybrid.drives import open_drives
    from hybrid_calib.hybrid.loop import HybridConfig

    _, drives = open_drives(tiny.root, VERSION, HybridConfig(method="pure"), lidar=False)
    assert drives["tiny"].n_views == 4 and drives["tiny"].absent == []
    (tiny.root / tiny.tables["sample_data"][0]["filename"]).unlink()  # one keyframe's file
    ds = _open(tiny)
    assert len(ds) == 4 and not ds.not_on_disk  # the scene holds files: the frame says why when read
    _, drives = open_drives(tiny.root, VERSION, HybridConfig(method="pure"), lidar=False)
    assert drives["tiny"].n_views == 3 and len(drives["tiny"].absent) == 1


def test_a_root_with_no_sensor_file_keeps_its_per_frame_words(tiny):
    """Nothing on disk at all (samples/ elsewhere) is not a partial download: no scene is left out at the index, and
    reading a frame says where the files should be."""
    import shutil

    shutil.rmtree(tiny.root / "samples")
    ds = _open(tiny)
    assert len(ds) == 4 and not ds.not_on_disk


def test_a_copy_under_another_vehicle_name_is_calibrated_as_that_vehicle(tiny):
    """Overlapping scenes of two vehicles are no conflict (the check is per vehicle)."""
    _copy_scene(tiny, vehicle="tiny-2")
    ds = _open(tiny)
    assert len(ds) == 8 and set(ds.frames_by_vehicle()) == {"tiny", "tiny-2"}


def test_a_vehicle_whose_samples_are_all_another_ones_copies_is_named(tiny):
    """Probe 94: a scene listed a second time on the same files under a second vehicle: the index read each file
    once, and calibrate dropped that vehicle without a word (rc 0, not in result.json). It is named with why."""
    _copy_scene(tiny, vehicle="tiny-2", own_files=False)
    ds = _open(tiny)
    assert set(ds.frames_by_vehicle()) == {"tiny"} and len(ds.duplicates) == 4
    (why,) = ds.frameless_vehicles().values()
    assert why.startswith("vehicle tiny-2: no frame: none of its 4 sample(s) holds a frame the run reads")
    assert "the tables list one recording twice" in why
    assert ds.frameless_vehicles(vehicles=["tiny"]) == {}


def test_keyframes_of_a_missing_sample_are_said_by_a_calibration(tiny):
    """Probe 94: a sample record missing from sample.json: its frame vanished from calibrate's output without a word
    (inspect said it). Its keyframes belong to no scene, so to no vehicle: the calibration's warning says them."""
    from hybrid_calib.data.summary import table_warnings

    gone = tiny.tables["sample"].pop(1)
    tiny.rewrite_table("sample")
    ds = _open(tiny)
    assert len(ds) == 3
    (line,) = [w for w in table_warnings(ds) if "samples of no vehicle" in w]
    assert "2 CAM_FRONT / RADAR_FRONT keyframe sample_data record(s) reference samples not in sample.json" in line
    assert gone["token"] in line and "sample.json" in line


def test_a_fleet_makes_a_vehicle_of_no_frame_a_job(tiny):
    """A vehicle whose samples are all another's copies (probe 94) is a fleet job, which fails saying why
    (tests/test_fleet.py), not a note of a fleet that exits 0: it has no tables' extrinsic and no log of frames."""
    from hybrid_calib.fleet.jobs import _root_vehicles

    _copy_scene(tiny, vehicle="tiny-2", own_files=False)
    notes: list[str] = []
    vs = _root_vehicles(str(tiny.root), VERSION, notes)
    assert set(vs) == {"tiny", "tiny-2"} and vs["tiny"]["tables_T"] is not None
    assert vs["tiny-2"] == {"tables_T": None, "design_T": None, "logs": []}
    assert not any("no frame" in n for n in notes)


def test_a_scene_none_of_whose_frames_loads_reads_a_dash_for_its_timing(tiny):
    """Probe 94: inspect's table read "dt ms nan" for a scene whose every frame was skipped."""
    from hybrid_calib.data.summary import summarize_dataset

    for sd in tiny.cam_sd:
        tiny.path(sd).unlink()
    summary = summarize_dataset(_open(tiny), progress=False)
    row = next(line for line in summary.format().splitlines() if line.startswith("tiny-scene"))
    assert row.rstrip().endswith("-") and "nan" not in row, row
    # and inspect_summary.json is strict JSON (probe 101: bare NaN, which jq and browsers refuse)
    text = json.dumps(summary.to_json(), allow_nan=False)
    assert '"dt_radar_minus_camera_ms": {"mean": null, "min": null, "max": null}' in text
    assert '"radar_points_per_sweep": {"mean": null, "min": null, "max": null}' in text  # not 0 points (probe 102)


def test_two_roots_holding_one_recording_are_refused_by_the_learned_commands(tiny, tmp_path):
    """Probe 101: evaluate of a root and its copy (an exported calibrated_sensor.json, or v1.0-mini's scenes inside
    trainval) named both roots' frames by their shared tokens: 82 frames became 41, the later root's predictions over
    the earlier's, with no word."""
    import shutil

    from learned.dataset import open_roots

    copy = tmp_path / "copy"
    shutil.copytree(tiny.root, copy)
    with pytest.raises(DataError, match="the same recording listed twice") as e:
        open_roots([tiny.root, copy], VERSION, lidar=False)
    assert e.value.path == str(copy) and str(tiny.root) in e.value.message and "4 of its 4 frames" in e.value.message
    assert len(open_roots([tiny.root], VERSION, lidar=False)) == 4


@pytest.mark.parametrize("version", ["/abs/v1.0-mini", "../other/v1.0-mini", "..", "x\\v1.0-mini", "/", "//"])
def test_a_version_that_is_a_path_is_refused(tiny, version):
    """Probe 101: --version with the version folder's full path read that root's tables with --data's files, in
    silence (an absolute path replaces the root it is joined to). What tab completion types is the folder itself
    (probe 102: "v1.0-mini/" had been refused)."""
    from hybrid_calib.data.tables import version_dir

    with pytest.raises(DataError, match="is not a folder name: --version names the version folder under the root"):
        version_dir(tiny.root, version)
    for same in (f"{VERSION}/", f"./{VERSION}"):
        assert version_dir(tiny.root, same) == version_dir(tiny.root, VERSION)


def test_the_archive_layout_is_named_with_the_root_to_pass(tiny, tmp_path):
    """Probe 101: the official v1.0-mini archive unpacks to v1.0-mini/{samples, v1.0-mini/*.json}; --data its parent
    read "extract the metadata archive there"."""
    from hybrid_calib.data.tables import version_dir

    outer = tmp_path / "unpacked"
    (outer / VERSION).mkdir(parents=True)
    (outer / VERSION / VERSION).symlink_to(tiny.root / VERSION)
    with pytest.raises(DataError, match=f"holds the version folder {VERSION} itself .*: pass --data "):
        version_dir(outer, VERSION)


def test_a_real_root_without_lidar_files_names_the_depth_the_run_chose(tiny, tmp_path, capsys):
    """Probe 101: a real root whose tables list a LIDAR_TOP but whose LiDAR files are absent read "(the --depth
    given)" although no --depth was given: the run had chosen lidar-densified for a real root."""
    import shutil

    from tests.helpers import expect_cli_error

    shutil.rmtree(tiny.root / "samples" / "LIDAR_TOP")
    err = expect_cli_error(["calibrate", "--data", tiny.root, "--version", VERSION, "--method", "pure-avg", "--start",
                            "R1", "--out", tmp_path / "c", "--no-plots"], capsys,
                           "--depth: lidar-densified densifies each frame's LiDAR sweep",
                           "(chosen for a real root whose tables list a LIDAR_TOP, when no --depth is given)")
    assert "the --depth given" not in err


def test_which_sensors_a_root_has_is_read_from_sensor_json_alone(tiny):
    """Probe 101: a learned run loaded a trainval root's tables twice (once to learn whether it has a LIDAR_TOP):
    24 s and 1.85 GB for 420k sample_data records. The question reads sensor.json only."""
    from hybrid_calib.data.tables import sensor_channels
    from hybrid_calib.hybrid.drives import resolve_depth
    from hybrid_calib.hybrid.loop import HybridConfig

    (tiny.root / VERSION / "sample_data.json").write_text("[{")  # not read by either
    assert sensor_channels(tiny.root, VERSION) == ["CAM_FRONT", "LIDAR_TOP", "RADAR_FRONT"]
    assert resolve_depth(tiny.root, VERSION, HybridConfig())[0] == "lidar-densified"


def test_train_and_evaluate_say_timestamps_that_are_not_microseconds(tiny, caplog):
    """Probe 100: calibrate and inspect warned of millisecond timestamps; train and evaluate, which read the frames
    through ``open_roots``, said nothing and blamed the ego poses frame by frame."""
    import logging

    from learned.dataset import open_roots

    for sd in tiny.tables["sample_data"]:
        sd["timestamp"] //= 1000
    tiny.rewrite_table("sample_data")
    with caplog.at_level(logging.WARNING, logger="learned.dataset"):
        open_roots([tiny.root], VERSION, lidar=False)
    assert "the timestamps look like milliseconds or seconds" in caplog.text and str(tiny.root) in caplog.text


def test_a_dangling_link_or_a_folder_is_named_not_taken_for_a_partial_download(tiny, tmp_path):
    """Probe 102: a scene whose files were links into a store that is not mounted (or folders) was left out as "a
    partial download ... download its sensor files"; the frame's read says what each is."""
    from hybrid_calib.data.image_header import image_header

    _copy_scene(tiny)
    copies = [sd for sd in tiny.tables["sample_data"] if "-copy" in sd["filename"]]
    for sd in copies:
        path = tiny.root / sd["filename"]
        path.unlink()
        path.symlink_to(tmp_path / "unmounted" / path.name)
    ds = _open(tiny)
    assert not ds.not_on_disk and len(ds) == 4  # the copy is still a scene recorded during the other: left out so
    cam = next(sd for sd in copies if sd["filename"].endswith(".jpg"))
    with pytest.raises(DataError, match=r"it is a symbolic link to .*unmounted.*, which does not exist \(the store"):
        image_header(tiny.root / cam["filename"])
    # the channel folder itself a dangling link (probe 103: "this copy has no RADAR_FRONT files")
    from hybrid_calib.data.pcd import read_radar_pcd

    folder = tiny.root / "samples" / "RADAR_FRONT"
    folder.rename(tmp_path / "moved")
    folder.symlink_to(tmp_path / "unmounted-store")
    with pytest.raises(DataError, match=r"its folder samples/RADAR_FRONT is a symbolic link to .*unmounted-store.*, "
                                        r"which does not exist"):
        read_radar_pcd(folder / "x.pcd")


@pytest.mark.parametrize("norm, ok", [(1.0009, True), (0.9991, True), (1.002, False), (1.05, False), (0.95, False)])
def test_a_quaternion_norm_is_rounding_within_1e_3_and_corrupt_beyond(norm, ok, tmp_path):
    """Probe 149 (mutation testing): the tolerance could be raised to 0.1 with every test passing (they tried norms 0,
    0.5, 1.5 and 2): a quaternion of norm 1.05 would be renormalised into another rotation in silence."""
    from hybrid_calib.data.tables import QUAT_NORM_TOL, _pose

    assert QUAT_NORM_TOL == 1e-3
    q = np.array([0.9, 0.1, -0.3, 0.2])
    rec = {"token": "t", "rotation": (q / np.linalg.norm(q) * norm).tolist(), "translation": [1.0, 0.0, 0.5]}
    if ok:
        assert np.allclose(np.linalg.det(_pose(rec, tmp_path / "ego_pose.json")[:3, :3]), 1.0)
    else:
        with pytest.raises(DataError, match=rf"rotation quaternion has norm {norm:g}, not 1 \(tolerance 0.001\)"):
            _pose(rec, tmp_path / "ego_pose.json")


@pytest.mark.parametrize("offset_ms, ok", [(0, True), (24, True), (26, False), (40, False)])
def test_an_ego_pose_more_than_25_ms_from_its_record_is_another_instants(tiny, offset_ms, ok):
    """Probe 149 (mutation testing): the limit (25 ms: 0.75 m at 30 m/s) could be doubled unnoticed; the one test used
    a pose 2.5 s off. Pinned at both sides of it."""
    from hybrid_calib.data.nuscenes import NuScenesRadarCamera
    from hybrid_calib.data.tables import MAX_EGO_POSE_OFFSET_US

    assert MAX_EGO_POSE_OFFSET_US == 25_000
    rad = tiny.radar_sd[1]
    ep = next(e for e in tiny.tables["ego_pose"] if e["token"] == rad["ego_pose_token"])
    ep["timestamp"] = rad["timestamp"] + offset_ms * 1000
    tiny.rewrite_table("ego_pose")
    ds = NuScenesRadarCamera(tiny.root, tiny.version)
    frames = list(ds)
    reasons = " ".join(s.reason for s in ds.skipped)
    assert (f"+{offset_ms / 1e3:.3f} s from the record's own time" in reasons) is not ok, (offset_ms, reasons)
    assert len(frames) == len(ds.frames) - (0 if ok else 1)
