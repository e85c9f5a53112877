"""The benchmark scripts' cheap paths: their documented invocations stop with one line, not a traceback, where their
inputs cannot give a figure (probe 117). Benchmarks are not tests; these check only that they say so."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

ROOT = Path(__file__).resolve().parents[1]


def _script(name: str, *args: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, str(ROOT / name), *args], cwd=ROOT, capture_output=True, text=True,
                          timeout=120, env={"PYTHONPATH": str(ROOT), "PATH": "/usr/bin:/bin"})


def test_bench_timing_refuses_a_drive_shorter_than_its_window():
    """--frames 20 or fewer left no steady-state frame: an IndexError traceback."""
    r = _script("benchmarks/bench_timing.py", "--frames", "5")
    assert r.returncode == 2 and "--frames 5: the window's steady state starts after its 20 frames" in r.stderr
    assert "Traceback" not in r.stderr


def test_bench_oracle_has_no_bias_over_std_for_one_run():
    """One run's std is 0: the bias over std printed a 300-digit number."""
    from benchmarks.bench_oracle import summarise
    from hybrid_calib.metrics import METRIC_KEYS

    run = {"crb_var_report": [1e-6] * 6, "window": {"err_report": [0.001] * 6, "nees": 5.0, "crb_norm": 6.0,
                                                      "metrics": {k: 0.0 for k in METRIC_KEYS}, "status": "ok"}}
    one = summarise([run], "window")
    assert all(np.isnan(v) for v in one["bias_over_std"].values())
    two = summarise([run, {**run, "window": {**run["window"], "err_report": [0.003] * 6}}], "window")
    assert two["bias_over_std"]["rot_x"] == pytest.approx(2.0)


def test_check_with_devkit_says_it_needs_the_devkit():
    """In the project's own environment (no nuscenes-devkit) it ended in a ModuleNotFoundError traceback."""
    try:
        import nuscenes  # noqa: F401

        pytest.skip("the nuscenes-devkit is installed here")
    except ImportError:
        pass
    r = _script("examples/check_with_devkit.py", "/nonexistent", "v1.0-mini")
    assert r.returncode == 2 and "needs the nuscenes-devkit" in r.stderr and "Traceback" not in r.stderr


def test_the_ood_fit_hint_names_the_scripts_required_options():
    from learned.ood import FIT_HINT

    assert all(o in FIT_HINT for o in ("--checkpoint", "--data", "--heldout", "--out", "--fit-into"))


def test_the_step_benchmarks_summarise_every_size_they_ran(monkeypatch):
    """Probe 134 (LOW): only the default sizes (0.25 / 0.5 / 1 / 2 deg, 1 / 2 / 5 cm) were summarised: --rot 1.5 or
    --trans 10 were simulated and run, then left out of the table and summary.json without a word."""
    monkeypatch.syspath_prepend(str(ROOT / "benchmarks"))
    from bench_steps import summarise

    rows = [{"kind": "none", "false_alarms": 0, "tested": 50},
            {"kind": "rot", "size": 1.5, "delay": 3, "false_alarms": 0},
            {"kind": "rot", "size": 0.5, "delay": 4, "false_alarms": 0},
            {"kind": "trans", "size": 10.0, "delay": None, "false_alarms": 0}]
    steps = summarise(rows, 20)["steps"]
    assert list(steps) == ["rot_0.5", "rot_1.5", "trans_10"] and steps["trans_10"]["detected"] == 0.0


def test_window_slopes_reads_each_run_of_frames_own_height_slope():
    """scene_profiles --windows: the lateral slope of each run of L frames (non-overlapping), the drive's tail that
    does not fill a run left out."""
    from benchmarks.scene_profiles import window_slopes
    from factors.config import RadarPixelFactorConfig
    from factors.projection import truncated_normal_moments

    conf = RadarPixelFactorConfig()
    g = np.random.default_rng(0)
    frames = []
    for k in range(7):
        r, y = g.uniform(5.0, 80.0, 40), g.uniform(-15.0, 15.0, 40)
        beam = np.deg2rad(conf.elevation_beam_deg)
        mean_h, _ = truncated_normal_moments(conf.reflector_height_mean_m, conf.reflector_height_std_m,
                                             r * np.sin(-beam), r * np.sin(beam))
        frames.append(np.stack([r, y, mean_h + (0.02 if k < 3 else -0.01) * y], 1))
    got = window_slopes(frames, conf, [1, 3])
    assert len(got[1]) == 7 and len(got[3]) == 2
    assert got[3][0] == pytest.approx(0.02, abs=1e-6) and got[3][1] == pytest.approx(-0.01, abs=1e-6)


def test_bench_oracle_summary_only_refuses_a_root_that_is_not_there(tmp_path):
    """Probe 136: --summary-only on a deleted --data simulated a new root there and printed an empty table, rc 0."""
    r = _script("benchmarks/bench_oracle.py", "--data", str(tmp_path / "gone"), "--summary-only", "--out",
                str(tmp_path / "out"))
    assert r.returncode == 2 and "--summary-only summarises the runs on --data" in r.stderr, r.stderr
    assert not (tmp_path / "gone").exists() and "Traceback" not in r.stderr
