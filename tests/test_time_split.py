"""The time split (``SplitConfig(by="time")``): the end of each scene held out behind a guard gap,
honoured by the learned methods' drives (``calibrate`` / ``compare --split test``)."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest

from hybrid_calib.config import ConfigError
from hybrid_calib.errors import HybridCalibError
from hybrid_calib.hybrid.loop import HybridConfig, open_drives
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
