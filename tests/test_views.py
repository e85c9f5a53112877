"""Keyframes that repeat a view (the ego stood still, as at a red light: data.views) are left out of every method,
with the view they repeat named; a drive that stops is simulated (sim.trajectory.EgoStops)."""

from __future__ import annotations

import numpy as np
import pytest

from hybrid_calib.data.views import ViewConfig, repeated_views
from hybrid_calib.geometry import make_T


def _pose(x: float, yaw_deg: float = 0.0) -> np.ndarray:
    c, s = np.cos(np.radians(yaw_deg)), np.sin(np.radians(yaw_deg))
    return make_T(np.array([[c, -s, 0], [s, c, 0], [0, 0, 1.0]]), np.array([x, 0.0, 0.0]))


def test_a_frame_is_a_new_view_once_the_ego_moved_or_turned_enough_since_the_last_view():
    poses = [_pose(0.0), _pose(4.5), _pose(4.6), _pose(4.6), _pose(5.2), _pose(5.7), _pose(5.7, 4.0), None,
             _pose(5.7, 4.5), _pose(20.0)]
    rep = repeated_views(poses, ViewConfig(min_travel_m=1.0, min_turn_deg=3.0))
    # 2, 3, 4 within 1 m of frame 1 (the last view: travel is counted from it, not from the frame before); 5 is
    # 1.2 m on; 6 turned 4 deg; an unreadable pose is taken; 8 turned 0.5 deg from 6
    assert sorted(rep) == [2, 3, 4, 8] and {r.of for r in rep.values()} == {1, 6}
    assert np.isclose(rep[4].travel_m, 0.7) and np.isclose(rep[8].turn_deg, 0.5, atol=1e-6)
    assert rep[3].reason(ViewConfig()).startswith(
        "the same view as frame 1: the camera moved 0.10 m and turned 0.0 deg")
    assert repeated_views(poses, ViewConfig(min_travel_m=0.0, min_turn_deg=0.0)) == {}  # off: every frame
    assert repeated_views([_pose(0.0)] * 3, ViewConfig()).keys() == {1, 2}  # a stand-still drive: one view
    with pytest.raises(ValueError, match="min_travel_m"):
        ViewConfig(min_travel_m=-1.0)


@pytest.fixture(scope="module")
def stop_root(tmp_path_factory):
    """One vehicle, 8 keyframes (4 s), a stop from 0.5 s to 3.5 s: braking 0.5 s, 2 s at a standstill (the
    keyframes at 1.5, 2.0, 2.5 and 3.0 s repeat the one at 1.0 s), pulling away 0.5 s."""
    from hybrid_calib.config import merge
    from hybrid_calib.sim.drive import SimConfig
    from hybrid_calib.sim.simulate import simulate

    conf = merge(SimConfig, {"vehicles": 1, "frames": 8, "image_scale": 0.125, "seed": 7,
                             "stops": {"count": 1, "hold_s": 2.0, "ramp_s": 0.5}})
    return simulate(conf, tmp_path_factory.mktemp("stop"), progress=False)


REPEATS = [3, 4, 5, 6]


def _repeats(v) -> dict:
    return {s["index"]: s["reason"] for s in v.skipped if "the same view" in s["reason"]}


def test_the_oracle_leaves_the_frames_a_stop_repeats_out(stop_root, tmp_path):
    """A drive with a 10 s stop: 23 of 40 keyframes repeated one view, and the window fused them as independent
    (the true reflectors' heights, the same in each, pulled the pitch: NEES 13.0, 3.0 without them)."""
    from hybrid_calib.calib.pipeline import calibrate

    run = calibrate(stop_root, "v1.0-sim", "oracle", tmp_path / "o", {"start": "R1", "seed": 1}, progress=False)
    v = run.vehicles["sim-veh-000"]
    rep = _repeats(v)
    assert sorted(rep) == REPEATS and all(r.startswith("the same view as frame 2:") for r in rep.values())
    assert v.n_frames == 4 and [f.index for f in v.trajectory] == [0, 1, 2, 7]
    every = calibrate(stop_root, "v1.0-sim", "oracle", tmp_path / "all", {
        "start": "R1", "seed": 1, "views": {"min_travel_m": 0.0, "min_turn_deg": 0.0}}, progress=False)
    assert every.vehicles["sim-veh-000"].n_frames == 8 and not _repeats(every.vehicles["sim-veh-000"])


@pytest.mark.parametrize("method", ["hybrid", "pure-avg"])
def test_the_learned_methods_leave_the_frames_a_stop_repeats_out(stop_root, tmp_path, method):
    """The same drive on the network: a repeated view gets no pass and no place in the window or the average, and
    its record names the view it repeats; the drive-common error counts the views, not the frames."""
    from hybrid_calib.hybrid import run_calibration

    conf = {"method": method, "start": "R1", "seed": 4, "threads": 1, "progress": False,
            "window": {"detect_steps": False}, "ood": {"enabled": False}}
    v = run_calibration(stop_root, "v1.0-sim", tmp_path / method, conf).vehicles["sim-veh-000"]
    rep = _repeats(v)
    assert sorted(rep) == REPEATS and "views.min_travel_m" in rep[3]
    assert [f.index for f in v.trajectory] == [0, 1, 2, 7] and len(v.frame_rows) == 4


def test_the_motion_pairs_a_frame_with_one_a_chord_back(stop_root, tmp_path, monkeypatch):
    """The hybrid's motion pairs (``hybrid.motion.pair_partner``) on the stop drive with ``min_chord_m`` 4 m: frame 2
    (braking, 2.25 m on) is paired with frame 0 (6.75 m back), frame 7 (pulling away) with frame 6 (nothing 4 m back
    within 1.5 s); the repeated views 3-6 get none."""
    from hybrid_calib.hybrid import run_calibration
    from hybrid_calib.hybrid.motion import MotionSource

    calls = []
    real = MotionSource.measurement

    def spy(self, ia, ib, *a, **k):
        calls.append((ia, ib))
        return real(self, ia, ib, *a, **k)

    monkeypatch.setattr(MotionSource, "measurement", spy)
    conf = {"method": "hybrid", "start": "R1", "seed": 4, "threads": 1, "progress": False,
            "window": {"detect_steps": False}, "ood": {"enabled": False}, "mount": {"enabled": False},
            "motion": {"min_chord_m": 4.0}}
    run_calibration(stop_root, "v1.0-sim", tmp_path / "h", conf)
    assert calls == [(0, 1), (0, 2), (6, 7)], calls


def test_a_drive_that_ends_at_a_red_light_is_not_blamed_on_the_radar(stop_root, tmp_path, capsys):
    """Probe 49: a drive cut while the ego waited (its last 4 of 7 frames repeated views) read "inconclusive: the
    drive's last 4 of 7 frames gave nothing to fuse: a radar knocked, blocked or failed there", and calibrate's line
    counted them as "frame(s) skipped (bad files or no rows)". They are the view they repeat."""
    from hybrid_calib.cli import main

    assert main(["calibrate", "--data", str(stop_root), "--method", "oracle", "--start", "R1", "--max-frames", "7",
                 "--out", str(tmp_path / "o"), "--no-plots"]) == 0
    out = capsys.readouterr().out
    assert "4 frame(s) left out as repeats of a view (the camera moved under views.min_travel_m" in out and \
        "bad files" not in out, out
    assert "gave nothing to fuse" not in out and "inconclusive" not in out, out
