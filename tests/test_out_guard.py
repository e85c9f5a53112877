"""No command but simulate writes into a nuScenes root, whichever root it is (probe 15): an --out that is a root, or
lies in any root's version folder, samples/ or sweeps/, is refused before anything is created there (an export into
another root's version folder replaced its calibrated_sensor.json; a report page landed among the camera images; a
refused export left an empty folder and its lock file in the version folder)."""

from __future__ import annotations

import pytest

from hybrid_calib.errors import OptionError, check_out_not_in_dataset
from tests.helpers import expect_cli_error


def _listing(root):
    return sorted((str(p.relative_to(root)), p.stat().st_mtime_ns) for p in root.rglob("*"))


@pytest.mark.parametrize("where,words", [
    ("{v}", "is the nuScenes table folder"),
    ("{v}/sub/dir", "is inside the nuScenes table folder"),
    ("samples/CAM_FRONT/x", "inside the samples/ folder of the nuScenes root"),
    ("sweeps/x", "inside the sweeps/ folder of the nuScenes root"),
    (".", "is a nuScenes root"),
])
def test_an_out_in_any_data_root_is_refused(tiny, where, words):
    (tiny.root / "sweeps").mkdir(exist_ok=True)
    out = tiny.root / where.format(v=tiny.version)
    with pytest.raises(OptionError, match=words):
        check_out_not_in_dataset(out)
    check_out_not_in_dataset(tiny.root.parent / "elsewhere")  # beside the root: fine
    check_out_not_in_dataset(tiny.root / "calib")  # the root's top level, outside its data folders: fine


def test_export_report_and_calibrate_write_nothing_into_another_root(tiny, tmp_path, capsys):
    """The result is of another root (``other``): the guard is not the run's own root's check."""
    from tests.tiny_nuscenes import make_tiny_root

    other = make_tiny_root(tmp_path / "other", n_samples=3)
    before = _listing(other.root)
    result = tmp_path / "nowhere" / "result.json"  # never read: the --out check comes first
    for argv in (["export", result, "--out", other.vdir],
                 ["export", result, "--out", other.vdir / "sub" / "dir"],
                 ["report", result, "--out", other.vdir / "r.html"],
                 ["calibrate", "--data", tiny.root, "--version", tiny.version, "--out", other.root / "samples" / "x"]):
        expect_cli_error(argv, capsys, "nuScenes")
    assert _listing(other.root) == before  # no folder, no lock file, no page, no table replaced


def test_a_cache_in_a_data_root_is_refused(tiny, tmp_path):
    from hybrid_calib.hybrid import run_calibration

    with pytest.raises(OptionError, match="--set depth_cache"):
        run_calibration(tiny.root, tiny.version, tmp_path / "out",
                        {"method": "pure", "depth_cache": str(tiny.root / "samples" / "CAM_FRONT" / "c")})


# ---------------------------------------------------------------- what the index leaves out is said (probe 15)
def test_samples_and_vehicles_the_index_leaves_out_are_in_the_result(tiny):
    """A sample without its RADAR_FRONT keyframe vanished from calibrate's accounting (inspect listed it); a second
    vehicle whose car has no RADAR_FRONT was left out of result.json with exit 0 (not in vehicles_failed)."""
    import copy

    from hybrid_calib.config import merge
    from hybrid_calib.hybrid.drives import open_drives
    from hybrid_calib.hybrid.loop import HybridConfig

    sd = tiny.tables["sample_data"]
    sd.remove(next(r for r in sd if r["sample_token"] == "sample1" and r["calibrated_sensor_token"] == "cs_RADAR_FRONT"
                   ))
    tiny.tables["log"].append({**tiny.tables["log"][0], "token": "log9", "vehicle": "n999"})
    tiny.tables["scene"].append({**tiny.tables["scene"][0], "token": "scene9", "log_token": "log9", "name": "s9",
                                 "nbr_samples": 1, "first_sample_token": "s9", "last_sample_token": "s9"})
    tiny.tables["sample"].append({**tiny.tables["sample"][0], "token": "s9", "scene_token": "scene9", "prev": "",
                                  "next": ""})
    cam = next(r for r in sd if r["sample_token"] == "sample0" and r["calibrated_sensor_token"] == "cs_CAM_FRONT")
    sd.append({**copy.deepcopy(cam), "token": "sd_s9_cam", "sample_token": "s9", "prev": "", "next": ""})
    for name in ("sample_data", "log", "scene", "sample"):
        tiny.rewrite_table(name)
    unreadable: dict = {}
    _, drives = open_drives(tiny.root, tiny.version, merge(HybridConfig, {"method": "pure"}), lidar=False,
                            unreadable=unreadable)
    assert [s["token"] for s in drives["tiny"].index_skips] == ["sample1"]
    assert drives["tiny"].index_skips[0]["index"] is None and "RADAR_FRONT" in drives["tiny"].index_skips[0]["reason"]
    assert "n999" not in drives and "no frame" in unreadable["n999"] and "RADAR_FRONT" in unreadable["n999"]


def test_simulate_writes_no_root_inside_another_and_caches_are_checked_in_every_command(tiny, tmp_path, capsys):
    """Probe 18: simulate --out ROOT/v1.0-mini/simroot wrote a whole root among another's tables (and one under
    samples/ changed that root's data stamp: its results read "computed from other data"); evaluate, train and
    compare wrote --set depth_cache / cache_dir into data roots (only calibrate checked them); fleet failed every job
    on them (exit 1) instead of refusing the option."""
    before = _listing(tiny.root)
    ck = "learned/checkpoints/small-sim-r1.json"
    for argv in (["simulate", "--vehicles", "1", "--frames", "2", "--out", tiny.vdir / "simroot"],
                 ["simulate", "--vehicles", "1", "--frames", "2", "--out", tiny.root / "samples" / "simroot"],
                 ["evaluate", "--data", tiny.root, "--version", tiny.version, "--checkpoint", ck, "--out",
                  tmp_path / "e", "--set", f"depth_cache={tiny.vdir / 'dc'}"],
                 ["train", "--data", tiny.root, "--version", tiny.version, "--out", tmp_path / "t", "--set",
                  f"depth_cache={tiny.root / 'sweeps' / 'dc'}"],
                 ["compare", "--data", tiny.root, "--version", tiny.version, "--out", tmp_path / "c", "--set",
                  f"hybrid.cache_dir={tiny.root / 'samples' / 'nc'}"],
                 ["fleet", "--data", tiny.root, "--version", tiny.version, "--out", tmp_path / "f", "--set",
                  f"depth_cache={tiny.vdir / 'dc'}"]):
        expect_cli_error(argv, capsys, "--set " if "--set" in argv else "--out", "folder")
    assert _listing(tiny.root) == before and not any((tmp_path / d).exists() for d in "etcf")


def test_a_root_whose_samples_folder_is_a_symlink_is_guarded_too(tiny, tmp_path):
    """Probe 18: with ROOT/samples -> ../store/samples, --out ROOT/samples wrote result.json among the sensor files:
    both checks resolved the symlink first, and the resolved path no longer lay under the root."""
    from hybrid_calib.errors import check_out_outside_data

    store = tmp_path / "store"
    store.mkdir()
    (tiny.root / "samples").rename(store / "samples")
    (tiny.root / "samples").symlink_to(store / "samples")
    for out in (tiny.root / "samples", tiny.root / "samples" / "x"):
        with pytest.raises(OptionError, match="samples/ folder"):
            check_out_not_in_dataset(out)
        with pytest.raises(OptionError, match="samples/ folder"):
            check_out_outside_data(out, tiny.root, tiny.version)
    # probe 40: the same folder by its target's path (the store) wrote result.json and caches among the sensor files
    for out in (store / "samples", store / "samples" / "CAM_FRONT"):
        with pytest.raises(OptionError, match="the data root's samples/ folder"):
            check_out_outside_data(out, tiny.root, tiny.version)
    check_out_outside_data(store / "elsewhere", tiny.root, tiny.version)  # beside it in the store: fine


def test_a_cache_folder_that_is_a_file_is_refused_before_anything_runs(tiny, tmp_path, capsys):
    """`--set cache_dir=afile` ran with no cache written or read, and said nothing (probe 27)."""
    afile = tmp_path / "afile"
    afile.write_text("x")
    expect_cli_error(["calibrate", "--data", tiny.root, "--version", tiny.version, "--method", "pure", "--out",
                      tmp_path / "out", "--set", f"cache_dir={afile}"], capsys, "--set cache_dir", "existing file")
    assert not (tmp_path / "out").exists()
