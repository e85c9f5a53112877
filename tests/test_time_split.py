"""The time split (``SplitConfig(by="time")``): the end of each scene held out behind a guard gap,
honoured by the learned methods' drives (``calibrate`` / ``compare --split test``)."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest

from hybrid_calib.config import ConfigError
from hybrid_calib.errors import HybridCalibError
from hybrid_calib.hybrid.drives import open_drives
from hybrid_calib.hybrid.loop import HybridConfig
from learned.dataset import SplitConfig, split_indices
from tests.tiny_nuscenes import VERSION, make_tiny_root


def _frames(per_scene: int = 20, scenes: int = 2) -> list:
    """Frames of ``scenes`` scenes interleaved and shuffled (the split must sort by time itself)."""
    items = [SimpleNamespace(scene_name=f"scene-{s}", timestamp_camera_us=1_000_000 * s + 500_000 * k)
             for s in range(scenes) for k in range(per_scene)]
    order = np.random.default_rng(0).permutation(len(items))
    return [items[i] for i in order]


def test_time_split_holds_out_the_end_of_each_scene_behind_a_gap():
    frames = _frames()
    conf = SplitConfig(by="time")  # test 0.2, val 0.1, gap 3: per scene of 20 -> 8 train, 2 val, 4 test
    parts = {s: split_indices(frames, s, conf) for s in ("train", "val", "test")}
    assert not set(parts["train"]) & set(parts["val"]) and not set(parts["val"]) & set(parts["test"])
    for s in range(2):
        rank = {id(f): r for r, f in enumerate(sorted((f for f in frames if f.scene_name == f"scene-{s}"),
                                                      key=lambda f: f.timestamp_camera_us))}
        got = {p: sorted(rank[id(frames[i])] for i in idx if frames[i].scene_name == f"scene-{s}")
               for p, idx in parts.items()}
        assert got == {"train": list(range(8)), "val": [11, 12], "test": [16, 17, 18, 19]}
    no_val = {s: split_indices(frames, s, SplitConfig(by="time", val_fraction=0.0, gap_frames=2))
              for s in ("train", "val", "test")}
    assert no_val["val"] == [] and len(no_val["train"]) == 2 * 14 and len(no_val["test"]) == 2 * 4


class _Root(list):
    """A root's frames as ``ConcatFrames`` reads them: items, their ``frames`` references and the root's path."""

    def __init__(self, items, root):
        super().__init__(items)
        self.frames, self.root = list(items), root


def test_the_time_split_of_several_roots_cuts_each_roots_scene_as_it_cuts_it_alone():
    """Probe 117 (HIGH): simulated roots all name their scenes scene-sim-veh-NNN; train --data A B with split.by=time
    cut the two roots' same-named scenes as one time line: every frame of the shorter root trained, and evaluate
    --data B (the checkpoint's split, B alone) called two of them test."""
    from learned.dataset import ConcatFrames

    a = _Root([SimpleNamespace(scene_name="scene-sim-veh-000", timestamp_camera_us=500_000 * k) for k in range(30)],
              "runs/A")
    b = _Root([SimpleNamespace(scene_name="scene-sim-veh-000", timestamp_camera_us=500_000 * k) for k in range(20)],
              "runs/B")
    conf = SplitConfig(by="time")
    both = ConcatFrames([a, b])
    for part in ("train", "val", "test"):
        joined = split_indices(both, part, conf)
        assert [i for i in joined if i < 30] == split_indices(a, part, conf)
        assert [i - 30 for i in joined if i >= 30] == split_indices(b, part, conf), part
    assert split_indices(b, "test", conf) == [16, 17, 18, 19]
    # a root too short alone is refused when listed with another, naming it
    short = _Root([SimpleNamespace(scene_name="scene-sim-veh-000", timestamp_camera_us=500_000 * k) for k in range(8)],
                  "runs/sim2")
    with pytest.raises(HybridCalibError, match="scene scene-sim-veh-000 of runs/sim2 has 8 frames"):
        split_indices(ConcatFrames([a, short]), "train", conf)


def test_time_split_errors_name_the_scene_and_the_option():
    with pytest.raises(HybridCalibError, match="scene-0 has 6 frames"):
        split_indices(_frames(per_scene=6, scenes=1), "test", SplitConfig(by="time"))
    with pytest.raises(ConfigError, match="split.by"):
        SplitConfig(by="week")
    with pytest.raises(ConfigError, match="gap_frames"):
        SplitConfig(by="time", gap_frames=-1)


def test_learned_drives_keep_only_the_held_out_frames(tmp_path):
    tiny = make_tiny_root(tmp_path / "root", n_samples=10)
    split = {"by": "time", "test_fraction": 0.3, "val_fraction": 0.0, "gap_frames": 2}
    frames, drives = open_drives(tiny.root, VERSION, HybridConfig(method="pure", split="test", split_options=split),
                                 lidar=False)
    assert drives["tiny"].indices == [7, 8, 9]  # time order: 5 train, 2 gap, 3 test
    _, train = open_drives(tiny.root, VERSION, HybridConfig(method="pure", split="train", split_options=split),
                           lidar=False)
    assert train["tiny"].indices == [0, 1, 2, 3, 4]
    _, every = open_drives(tiny.root, VERSION, HybridConfig(method="pure"), lidar=False)
    assert every["tiny"].indices == list(range(10))


def test_split_flags_on_oracle_are_a_clear_error(tmp_path, capsys):
    from hybrid_calib.cli import EXIT_ERROR, main

    tiny = make_tiny_root(tmp_path / "root", n_samples=4)
    rc = main(["calibrate", "--data", str(tiny.root), "--version", VERSION, "--method", "oracle", "--split", "test",
               "--split-by", "time", "--out", str(tmp_path / "out")])
    err = capsys.readouterr().err
    assert rc == EXIT_ERROR and "--split" in err and "oracle" in err and "Traceback" not in err
    rc = main(["compare", "--data", str(tiny.root), "--version", VERSION, "--methods", "pure,oracle", "--split",
               "test", "--out", str(tmp_path / "cmp")])
    err = capsys.readouterr().err
    assert rc == EXIT_ERROR and "oracle" in err and "split" in err and "Traceback" not in err


def test_real_scene_benchmark_flags_an_ok_answer_outside_its_3_sigma():
    """``benchmarks/real_scene.py``: an ``ok`` status whose error leaves its 3-sigma is flagged; a ``weak``
    one is listed, not flagged; the targets read the pooled tables."""
    import importlib.util
    from pathlib import Path

    from hybrid_calib.geometry import make_T, so3_exp

    path = Path(__file__).resolve().parents[1] / "benchmarks" / "real_scene.py"
    spec = importlib.util.spec_from_file_location("real_scene", path)
    bench = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(bench)
    truth = np.eye(4)
    est = make_T(so3_exp([0.0, 0.0, np.radians(2.0)]), [0.0, 0.0, 0.0])  # 2 deg about radar z

    def vr(status, sd_deg):
        cov = np.diag([np.radians(sd_deg) ** 2] * 3 + [0.01 ** 2] * 3)
        return SimpleNamespace(truth_T=truth, final=SimpleNamespace(T=est, cov=cov, status=status),
                               start={"seed": 3}, n_frames=8,
                               error={"rot_mean_deg": 0.67, "trans_norm_cm": 0.0, "nees": 0.0})

    bad = bench._trial_row(vr("ok", 0.5))
    assert bad["flag_ok_outside_3sigma"] and bad["outside_3sigma"] == ["rot z"] and bad["seed"] == 3
    assert not bench._trial_row(vr("ok", 1.0))["flag_ok_outside_3sigma"]
    weak = bench._trial_row(vr("weak: yaw poorly observed", 0.5))  # trusted: flagged (probe 51: only "ok" was)
    assert weak["outside_3sigma"] == ["rot z"] and weak["flag_ok_outside_3sigma"]
    lost = bench._trial_row(vr("inconclusive: 2 of 9 frames in the network's domain", 0.5))
    assert lost["outside_3sigma"] == ["rot z"] and not lost["flag_ok_outside_3sigma"]
    tab = {k: 1.0 for k in ("rot_mean_deg", "roll_deg", "pitch_deg", "yaw_deg", "trans_mean_cm", "x_cm", "y_cm",
                            "z_cm")}
    pure = {"R1": {"start": tab, "after": {**tab, "rot_mean_deg": 0.8, "yaw_deg": 1.2}, "nees_mean": 6.0,
                   "inside_95": 0.9}}
    t = bench.targets(pure, {"hybrid": {"mean": {"rot_mean_deg": 0.9}, "not_ok_fraction": 1.0,
                                        "inconclusive_fraction": 0.2, "flagged": 1}})
    assert t["R1 rotation mean <= 1.0 deg"][1] and not t["R1 yaw <= 1.0 deg"][1]
    assert not t["hybrid: no trusted status (ok or weak) with the error outside 3-sigma"][1]
    assert not t["hybrid rotation mean <= 0.3 deg (or every trial inconclusive)"][1]  # every status weak: not met
    t = bench.targets(pure, {"hybrid": {"mean": {"rot_mean_deg": 0.9}, "not_ok_fraction": 1.0,
                                        "inconclusive_fraction": 1.0, "flagged": 0}})
    assert t["hybrid rotation mean <= 0.3 deg (or every trial inconclusive)"][1]
