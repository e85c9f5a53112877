"""The radar's sweeps between keyframes (data.sweeps, calib.ego_doppler): read from a root that has them, absent
from one that does not, a missing or corrupt sweep file said in words, the pairing rule, and the mount monitor
steadier with them."""

from __future__ import annotations

import json

import numpy as np
import pytest

from hybrid_calib.calib.ego_doppler import EgoSweep, drive_sweeps, partner, sweep_pairs


def _sweep(t_s: float | None, k: int = 0) -> EgoSweep:
    return EgoSweep(None if t_s is None else int(round(t_s * 1e6)), {}, f"s{k}", position=k)


def test_each_sweep_pairs_with_the_latest_one_far_enough_back():
    kf = [_sweep(0.5 * k, k) for k in range(5)]  # a keyframe-only drive: the previous keyframe
    got = [(a.radar_token, b.radar_token) for a, b in sweep_pairs(kf, 0.4)]
    assert got == [(f"s{k}", f"s{k + 1}") for k in range(4)]
    sw = [_sweep(0.077 * k, k) for k in range(20)]  # 13 Hz: the sweep 6 back (0.46 s), every sweep in two pairs
    pairs = sweep_pairs(sw, 0.4)
    assert len(pairs) == 14 and all(int(b.radar_token[1:]) - int(a.radar_token[1:]) == 6 for a, b in pairs)
    assert partner(sw[:3], sw[3], 0.4) is None  # the drive's first sweeps have none
    barrier = [_sweep(0.0, 0), _sweep(None, 1), _sweep(0.1, 2)]  # an unreadable frame that cannot be placed in time
    assert partner(barrier[:2], _sweep(0.6, 3), 0.4) is barrier[1]  # the pair across it is skipped, not stretched
    assert partner(barrier[:1], barrier[1], 0.4) is barrier[0]


@pytest.fixture(scope="module")
def roots(tmp_path_factory):
    """One 6-frame urban drive with the default 5 non-keyframe sweeps per interval, and the same keyframe-only."""
    from hybrid_calib.config import merge
    from hybrid_calib.sim.drive import SimConfig
    from hybrid_calib.sim.simulate import simulate

    tmp = tmp_path_factory.mktemp("sweeps")
    base = {"scenario": "urban", "vehicles": 1, "frames": 6, "seed": 5, "image_scale": 0.05}
    return (simulate(merge(SimConfig, base), tmp / "sweeps", progress=False),
            simulate(merge(SimConfig, {**base, "radar_sweeps_per_frame": 0}), tmp / "keyframes", progress=False))


def test_the_sweeps_between_keyframes_are_read_and_a_keyframe_only_root_has_none(roots):
    from learned.dataset import open_frames

    frames = open_frames(roots[0], "v1.0-sim", lidar=False)
    (idx,) = frames.frames_by_vehicle().values()
    got = frames.radar_sweeps_between(idx[2])
    t_prev, t_key = frames[idx[1]].timestamp_radar_us, frames[idx[2]].timestamp_radar_us
    assert len(got) == 5 and all(t_prev < s.timestamp_us < t_key for s in got)
    assert np.all(np.diff([s.timestamp_us for s in got]) > 60_000)  # oldest first, ~77 ms apart
    assert all(len(s.points) > 8 and "vx" in s.fields and np.isfinite(s.T_global_ego).all() and not s.why for s in got)
    assert len(frames.radar_sweeps_between(idx[0])) == 5  # the simulator starts every interval with its sweeps
    sweeps, T_ego_cam = drive_sweeps(frames, idx)
    assert T_ego_cam is not None and len(sweeps) == 6 * len(idx)
    assert [s.position for s in sweeps if s.keyframe] == list(range(len(idx)))
    assert sum(s.velocity is not None for s in sweeps) >= len(sweeps) - 2
    kf = open_frames(roots[1], "v1.0-sim", lidar=False)
    assert all(kf.radar_sweeps_between(i) == [] for i in range(len(kf)))
    assert len(drive_sweeps(kf, list(range(len(kf))))[0]) == len(kf)


def test_a_missing_or_corrupt_sweep_file_is_counted_or_said_not_a_crash(roots, tmp_path):
    import shutil

    from learned.dataset import open_frames

    root = tmp_path / "root"
    shutil.copytree(roots[0], root)
    frames = open_frames(root, "v1.0-sim", lidar=False)
    (idx,) = frames.frames_by_vehicle().values()
    names = [frames.tables.get("sample_data", s.token)["filename"] for s in frames.radar_sweeps_between(idx[3])]
    (root / names[0]).unlink()
    (root / names[1]).write_bytes(b"not a pcd")
    frames = open_frames(root, "v1.0-sim", lidar=False)
    got = frames.radar_sweeps_between(idx[3])
    assert len(got) == 4 and frames.radar_sweeps_missing == 1
    bad = [s for s in got if s.why]
    assert len(bad) == 1 and "sweep unreadable" in bad[0].why and len(bad[0].points) == 0
    sweeps, _ = drive_sweeps(frames, idx)
    assert any("sweep unreadable" in s.why and s.velocity is None for s in sweeps)
    # one file of many missing is said as such, not as "keyframes only: no sweep files"
    from hybrid_calib.calib.mount_monitor import tested_words
    from hybrid_calib.hybrid.drives import sweep_files_record

    record = sweep_files_record(frames, idx)
    assert record["sweeps_absent"] is False and record["sweeps_missing"]["n"] == 1
    assert record["sweeps_missing"]["first"] == str(root / names[0])
    words = tested_words({"pairs_tested": 3, "frames_tested": 3, **record})
    assert "1 of the " in words and "radar sweep files between keyframes are missing" in words
    assert "keyframes only" not in words
    # a file there that does not read is named with why (probe 42: all zero-byte left only a count of skipped pairs)
    assert record["sweeps_unreadable"]["n"] == 1 and names[1] in record["sweeps_unreadable"]["first"]
    assert f"1 of the {record['sweeps_unreadable']['of']} radar sweep files between keyframes do not read (first: " \
           f"sweep unreadable: " in words and "replace the files" in words
    # a prev pointer to a record not older than its own ends the walk, and is counted among the records listed
    # (probe 45: every radar timestamp equal read "5 of the 0 radar sweep files ... do not read")
    path = root / "v1.0-sim" / "sample_data.json"
    rows = json.loads(path.read_text())
    kf = frames.frames[idx[4]].radar_sd
    for r in rows:
        if r["token"] == kf["prev"]:
            r["timestamp"] = kf["timestamp"]
    path.write_text(json.dumps(rows))
    frames = open_frames(root, "v1.0-sim", lidar=False)
    got = frames.radar_sweeps_between(idx[4])
    assert len(got) == 1 and "not older than it" in got[0].why
    record = sweep_files_record(frames, [idx[4]])
    assert record["sweeps_unreadable"] == {"n": 1, "of": 1, "first": got[0].why}
    # a directory in a sweep file's place is said as such (it was counted as a missing file)
    (root / names[2]).unlink()
    (root / names[2]).mkdir()
    got = open_frames(root, "v1.0-sim", lidar=False).radar_sweeps_between(idx[3])
    assert any("radar sweep file is a directory, not a regular file" in s.why for s in got)


def test_a_broken_sweep_record_is_said_and_the_drive_goes_on(roots, tmp_path):
    """A ``prev`` pointer that resolves to nothing and a file name that leaves the root: each sweep is named with
    why, the walk keeps what it read, and the drive's other sweeps (and frames) still pair."""
    import json
    import shutil

    from hybrid_calib.calib.ego_doppler import pair_skip
    from learned.dataset import open_frames

    root = tmp_path / "root"
    shutil.copytree(roots[0], root)
    frames = open_frames(root, "v1.0-sim", lidar=False)
    (idx,) = frames.frames_by_vehicle().values()
    broken, escapes = frames.radar_sweeps_between(idx[2])[2].token, frames.radar_sweeps_between(idx[4])[1].token
    table = root / "v1.0-sim" / "sample_data.json"
    records = json.loads(table.read_text())
    for r in records:
        if r["token"] == broken:
            r["prev"] = "no-such-token"
        if r["token"] == escapes:
            r["filename"] = "sweeps/RADAR_FRONT/../../../etc/passwd"
    table.write_text(json.dumps(records))
    frames = open_frames(root, "v1.0-sim", lidar=False)
    got = frames.radar_sweeps_between(idx[2])
    assert len(got) == 4 and got[0].timestamp_us is None and "no-such-token" in got[0].why  # the 3 after the break
    assert all(not s.why for s in got[1:])
    got = frames.radar_sweeps_between(idx[4])
    assert len(got) == 5 and "leaves the root" in got[1].why and got[1].timestamp_us is not None
    sweeps, _ = drive_sweeps(frames, idx)
    skips = [pair_skip(a, b) for a, b in sweep_pairs(sweeps, 0.4)]
    assert sum("no-such-token" in s for s in skips) >= 1 and sum("leaves the root" in s for s in skips) >= 1
    assert sum(s == "" for s in skips) >= len(skips) - 12  # one bad record costs the pairs that touch it


@pytest.mark.parametrize("damage", ["cycle", "forward"])
def test_a_prev_pointer_cycle_or_one_forward_in_time_ends_the_walk_in_words(damage, roots, tmp_path):
    """A cycle of prev pointers was walked round to the limit (57 sweep pairs instead of 42, the same sweeps used
    several times, no word); a pointer to a later record is no earlier sweep either."""
    import json
    import shutil

    from learned.dataset import open_frames

    root = tmp_path / "root"
    shutil.copytree(roots[0], root)
    frames = open_frames(root, "v1.0-sim", lidar=False)
    (idx,) = frames.frames_by_vehicle().values()
    sweeps = frames.radar_sweeps_between(idx[3])  # oldest first
    table = root / "v1.0-sim" / "sample_data.json"
    records = json.loads(table.read_text())
    target = sweeps[-1].token if damage == "cycle" else frames.radar_sweeps_between(idx[4])[0].token
    for r in records:
        if r["token"] == sweeps[1].token:
            r["prev"] = target  # the second sweep points back at the newest one of its interval / the next interval
    table.write_text(json.dumps(records))
    got = open_frames(root, "v1.0-sim", lidar=False).radar_sweeps_between(idx[3])
    read = [s.token for s in got[1:]]  # the broken pointer's entry, then the sweeps after it, each once
    assert read == [s.token for s in sweeps[1:]]
    assert got[0].timestamp_us is None and ("a cycle" if damage == "cycle" else "not older") in got[0].why
    assert "prev pointer" in got[0].why and all(not s.why for s in got[1:])


def test_inspect_says_whether_the_sweeps_between_keyframes_are_there(roots, tmp_path):
    import shutil

    from hybrid_calib.data.summary import summarize_dataset
    from learned.dataset import open_frames

    def line(root):
        s = summarize_dataset(open_frames(root, "v1.0-sim", lidar=False), progress=False)
        return s.format().splitlines()[-1], s.to_json()["groups"][0]["radar_sweeps_between"]

    text, rec = line(roots[0])
    assert rec == {"records": 30, "on_disk": 30, "broken": 0, "unreadable": 0} and "30 (5.0 per frame), all on disk" \
        in text
    text, rec = line(roots[1])
    assert rec["records"] == 0 and "none in the tables" in text and "keyframes only" in text
    copy = tmp_path / "keyframe-only"  # the tables keep the sweep records, the files are gone (a mini copy)
    shutil.copytree(roots[0], copy)
    shutil.rmtree(copy / "sweeps")
    text, rec = line(copy)
    assert rec == {"records": 30, "on_disk": 0, "broken": 0, "unreadable": 0}
    assert "none on disk (a keyframe-only copy)" in text and "add the sweeps/ folder for about 6 times" in text
    # a sweep file there but truncated is said (probe 23: a truncated and an empty one counted "on disk", ready)
    shutil.copytree(roots[0] / "sweeps", copy / "sweeps")
    bad = sorted((copy / "sweeps").rglob("*.pcd"))[0]
    bad.write_bytes(bad.read_bytes()[:100])
    text, rec = line(copy)
    assert rec == {"records": 30, "on_disk": 30, "broken": 0, "unreadable": 1}
    assert "; 1 of the files on disk do not read (first: " in text and bad.name in text


def test_ego_poses_that_contradict_the_doppler_speed_are_not_used():
    """Frozen ego poses (the vehicle 'standing still' while the radar sees the world pass at 9 m/s) gave the motion
    constraint the rotation 0 in turns and the hybrid a confident 3.6 deg error with a 'recalibrate' verdict."""
    from types import SimpleNamespace

    from hybrid_calib.calib.ego_doppler import ego_measurement, pose_doppler_conflict
    from hybrid_calib.geometry import make_T
    from hybrid_calib.hybrid.motion import ego_conflict

    assert pose_doppler_conflict(4.5, 0.5, 9.0) == "" and pose_doppler_conflict(4.6, 0.5, 8.7) == ""
    assert pose_doppler_conflict(4.0, 0.5, 8.7) == ""  # 0.7 m/s off at 8.7 m/s: inside 1 m/s
    assert pose_doppler_conflict(0.0, 0.5, 8.7).startswith("the ego poses moved 0.00 m in 0.50 s (0.0 m/s) while "
                                                           "the radar's Doppler measured 8.7 m/s")
    assert pose_doppler_conflict(30.0, 0.5, 30.0)  # 60 m/s against 30
    assert pose_doppler_conflict(13.0, 0.5, 30.0) == ""  # 26 against 30 m/s: within 25 %

    still = make_T(np.eye(3), [10.0, 0.0, 0.0])
    a = SimpleNamespace(extras={"T_global_ego_cam": still, "T_global_ego_radar": still}, timestamp_camera_us=0,
                        timestamp_radar_us=0, radar_token="a")
    b = SimpleNamespace(extras={"T_global_ego_cam": still, "T_global_ego_radar": still}, timestamp_camera_us=500_000,
                        timestamp_radar_us=500_000, radar_token="b")
    assert "ego_pose.json" in ego_conflict(a, b, 8.7)
    v = SimpleNamespace(v=np.array([-8.7, 0.0]), cov=np.eye(2) * 1e-4, speed=8.7, n_inliers=30)
    m, why = ego_measurement(a, v, b, v, np.eye(4), 2.0, 1.5, 40.0)
    assert m is None and "while the radar's Doppler measured 8.7 m/s" in why
    assert "(vx, vy: the raw Doppler velocity" in why  # the fields the Doppler fit reads (not vx_comp, vy_comp)
    b.extras = {k: make_T(np.eye(3), [14.4, 0.0, 0.0]) for k in b.extras}  # 8.8 m/s: agrees
    assert ego_conflict(a, b, 8.7) == ""
    m, why = ego_measurement(a, v, b, v, np.eye(4), 2.0, 1.5, 40.0)
    assert m is not None, why
    # a heading flipped in the tables is no turn (it read "turning at 329 deg/s (at most 15)", probe 7)
    from scipy.spatial.transform import Rotation

    b.extras = {k: make_T(Rotation.from_euler("z", 180, degrees=True).as_matrix(), [14.4, 0.0, 0.0]) for k in b.extras}
    m, why = ego_measurement(a, v, b, v, np.eye(4), 2.0, 1.5, 40.0)
    assert m is None and "which no vehicle does: the ego poses (ego_pose.json) are wrong here" in why
    # a radar whose velocity fields say 0 m/s while the poses move is not a parked car
    v0 = SimpleNamespace(v=np.zeros(2), cov=np.eye(2) * 1e-4, speed=0.0, n_inliers=30)
    m, why = ego_measurement(a, v0, b, v0, np.eye(4), 2.0, 1.5, 40.0)
    assert m is None and "the radar's Doppler measured 0.0 m/s" in why, why


def test_the_poses_are_checked_against_the_doppler_by_the_radars_travel_not_the_ego_origins():
    """Where a root puts its ego origin is its own choice (nuScenes: the rear axle). Scene-0916 with its origin put
    3 m beside the sensors had 11 pairs of its turns (21 deg/s: 1.1 m/s between the origin's speed and the radar's)
    refused as "the ego poses moved ... while the radar's Doppler measured ...", and the hybrid's motion constraint
    dropped the poses' rotation there: the same drive ended 0.6 deg elsewhere."""
    from types import SimpleNamespace

    from scipy.spatial.transform import Rotation

    from hybrid_calib.calib.ego_doppler import ego_measurement, sensor_travel
    from hybrid_calib.geometry import make_T
    from hybrid_calib.hybrid.motion import ego_conflict

    w, dt, r = np.radians(21.0), 0.5, 4.0  # a 4 m radius turn about the ego origin's centre: 1.47 m/s
    def pose(t):  # the ego origin on a circle of radius r, heading along it
        th = w * t
        return make_T(Rotation.from_euler("z", th).as_matrix(), [r * np.sin(th), r * (1 - np.cos(th)), 0.0])
    radar = make_T(np.eye(3), [0.0, -3.0, 0.0])  # 3 m to the right of the origin: radius 7 m, 2.57 m/s
    travel = sensor_travel(pose(0.0), pose(dt), radar)
    assert np.isclose(travel, 2 * 7.0 * np.sin(w * dt / 2), rtol=1e-9)  # the radar's chord
    assert np.isclose(sensor_travel(pose(0.0), pose(dt), None), 2 * r * np.sin(w * dt / 2), rtol=1e-9)
    a = SimpleNamespace(extras={"T_global_ego_cam": pose(0.0), "T_global_ego_radar": pose(0.0), "T_ego_radar": radar},
                        timestamp_camera_us=0, timestamp_radar_us=0, radar_token="a")
    b = SimpleNamespace(extras={"T_global_ego_cam": pose(dt), "T_global_ego_radar": pose(dt), "T_ego_radar": radar},
                        timestamp_camera_us=500_000, timestamp_radar_us=500_000, radar_token="b")
    speed = 7.0 * w  # the radar's Doppler speed: 2.57 m/s, the origin's 1.47 (1.1 m/s off: refused before)
    v = SimpleNamespace(v=np.array([-speed, 0.0]), cov=np.eye(2) * 1e-4, speed=speed, n_inliers=30)
    assert ego_conflict(a, b, speed) == ""
    m, why = ego_measurement(a, v, b, v, radar, 1.0, 1.5, 40.0)
    assert m is not None, why
    assert ego_conflict(a, b, 1.47)  # a Doppler at the origin's speed: the radar's poses disagree with it
