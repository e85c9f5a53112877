"""Metric depth for the network: the corrupted-truth estimator, Depth Anything local loading, the cache."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from hybrid_calib.data.frame import RadarCameraFrame, write_depth_png
from hybrid_calib.errors import DataError, HybridCalibError
from hybrid_calib.sensors.camera import PinholeCamera
from learned.depth import CorruptedTruthDepth, DepthCache, LidarDepth, build_depth_estimator, depth_inputs

H, W = 60, 120
QUIET = dict(scale_std=0.0, shift_std_m=0.0, edge_blur_px=0.0, rel_noise_lowfreq=0.0, noise_rel=0.0,
             noise_quad_per_m=0.0)  # every corruption off: the estimator must return the truth


def ramp_depth() -> np.ndarray:
    """(H, W) metres: a ground-plane-like ramp from 5 m (bottom) to 100 m (top), no unknown pixels."""
    return np.repeat(np.linspace(100.0, 5.0, H, dtype=np.float32)[:, None], W, axis=1)


def make_frame(tmp_path, depth: np.ndarray | None, token: str = "cam-0") -> RadarCameraFrame:
    import cv2

    img_path = tmp_path / f"{token}.jpg"
    cv2.imwrite(str(img_path), np.full((H, W, 3), 128, np.uint8))
    depth_path = write_depth_png(tmp_path / f"{token}_depth.png", depth) if depth is not None else None
    return RadarCameraFrame(
        index=0, sample_token="s", scene_name="scene", vehicle="v", log_token="l", camera_channel="CAM_FRONT",
        radar_channel="RADAR_FRONT", camera_token=token, radar_token="r", timestamp_camera_us=0,
        timestamp_radar_us=0, image_path=img_path, camera=PinholeCamera(100.0, 100.0, 59.5, 29.5, W, H),
        radar_points=np.zeros((0, 3)), radar_fields={}, T_cam_radar=np.eye(4), depth_path=depth_path)


def test_corrupted_truth_is_deterministic_per_frame_and_never_the_truth():
    truth = ramp_depth()
    est = CorruptedTruthDepth()
    a = est.corrupt(truth, (H, W), "tok-a")
    b = est.corrupt(truth, (H, W), "tok-a")
    c = est.corrupt(truth, (H, W), "tok-b")
    np.testing.assert_array_equal(a, b)
    assert not np.allclose(a, c, atol=1e-3)
    assert a.dtype == np.float32 and a.shape == (H, W)
    rel = np.abs(a - truth) / truth
    assert np.all(rel > 0) and rel.mean() > 0.005  # never the truth
    assert np.median(rel) < 0.3  # but still a usable metric estimate
    other_seed = CorruptedTruthDepth({"seed": 7}).corrupt(truth, (H, W), "tok-a")
    assert not np.allclose(a, other_seed, atol=1e-3)


def test_corrupted_truth_with_every_error_off_returns_the_truth():
    truth = ramp_depth()
    np.testing.assert_allclose(CorruptedTruthDepth(QUIET).corrupt(truth, (H, W), "t"), truth, rtol=1e-6)


def test_global_scale_and_shift_bias_as_configured():
    truth = ramp_depth()
    exact = CorruptedTruthDepth({**QUIET, "scale_mean": 1.2, "shift_mean_m": 0.5}).corrupt(truth, (H, W), "t")
    np.testing.assert_allclose(exact, 1.2 * truth + 0.5, rtol=1e-5)
    # with the default noise on, the configured bias is still what a robust fit reads back
    noisy = CorruptedTruthDepth({"scale_mean": 1.2}).corrupt(truth, (H, W), "t")
    assert 1.1 < np.median(noisy / truth) < 1.3
    unbiased = [np.median(CorruptedTruthDepth().corrupt(truth, (H, W), f"t{i}") / truth) for i in range(20)]
    assert 0.95 < np.mean(unbiased) < 1.05 and np.std(unbiased) > 0.02  # per-frame scale error, no bias


def test_noise_grows_with_range():
    truth = ramp_depth()
    est = CorruptedTruthDepth({**QUIET, "noise_rel": 0.01, "noise_quad_per_m": 0.0005})
    res = est.corrupt(truth, (H, W), "t") - truth
    near = res[-10:].std()  # bottom rows: 5..20 m
    far = res[:10].std()  # top rows: 85..100 m
    assert far > 5 * near
    # the measured std matches the configured model sigma = 0.01 d + 0.0005 d^2 within 25 %
    d_far = truth[:10]
    assert far == pytest.approx(np.sqrt(np.mean((0.01 * d_far + 0.0005 * d_far**2) ** 2)), rel=0.25)


def test_edges_are_smoothed_and_unknown_stays_unknown():
    truth = np.full((H, W), 10.0, np.float32)
    truth[:, W // 2:] = 40.0  # a vertical depth edge at column 60
    truth[:5, :10] = 0.0  # no return (sky)
    out = CorruptedTruthDepth({**QUIET, "edge_blur_px": 2.0}).corrupt(truth, (H, W), "t")
    assert np.all(out[:5, :10] == 0.0)
    row = out[30]
    assert 11.0 < row[W // 2 - 1] < 39.0 and 11.0 < row[W // 2] < 39.0  # mixed across the edge
    assert row[5] == pytest.approx(10.0, abs=1e-3) and row[-5] == pytest.approx(40.0, abs=1e-3)  # flat parts kept
    assert np.abs(np.diff(row)).max() < 0.5 * 30.0  # the 30 m step is spread over several pixels
    sky = CorruptedTruthDepth({**QUIET, "sky_depth_m": 200.0}).corrupt(truth, (H, W), "t")
    assert np.all(sky[:5, :10] == 200.0) and sky[30, 5] == pytest.approx(10.0)


def test_estimate_reads_the_frame_depth_and_resizes(tmp_path):
    frame = make_frame(tmp_path, ramp_depth())
    out = CorruptedTruthDepth().estimate(frame, (30, 60))
    assert out.shape == (30, 60) and np.all(out > 0)
    with pytest.raises(DataError, match="ground-truth depth"):
        CorruptedTruthDepth().estimate(make_frame(tmp_path, None, "nodepth"), (30, 60))


def test_cache_hit_is_identical_and_changed_config_misses(tmp_path):
    frame = make_frame(tmp_path, ramp_depth())
    cache = DepthCache(tmp_path / "cache")
    est = CorruptedTruthDepth()
    first = cache.get(est, frame, (30, 60))
    second = cache.get(CorruptedTruthDepth(), frame, (30, 60))  # a new instance with the same config
    np.testing.assert_array_equal(first, second)
    assert (cache.hits, cache.misses) == (1, 1)
    path = cache.path(est, frame.camera_token, (30, 60), depth_inputs(frame))
    assert path.is_file() and (path.parent / "estimator.json").is_file()
    assert not list(path.parent.glob("*tmp*"))  # atomic: no temp files left
    changed = CorruptedTruthDepth({"seed": 3})
    third = cache.get(changed, frame, (30, 60))
    assert cache.misses == 2 and cache.path(changed, frame.camera_token, (30, 60), depth_inputs(frame)) != path
    assert not np.array_equal(first, third)
    cache.get(est, frame, (15, 30))  # another size is another entry
    assert cache.misses == 3
    path.write_bytes(b"garbage")  # a corrupt entry is recomputed, not returned
    np.testing.assert_array_equal(cache.get(est, frame, (30, 60)), first)
    np.save(path, np.full((30, 60), np.nan, np.float32))  # no estimator gives a map without one finite depth
    np.testing.assert_array_equal(cache.get(est, frame, (30, 60)), first)
    for scaled in (first * 1000, -first):  # nor one beyond every estimator's range (probe 45: x1000 was read)
        np.save(path, scaled.astype(np.float32))
        np.testing.assert_array_equal(cache.get(est, frame, (30, 60)), first)
    # another frame of the same token (a copy of the root, edited: probe 23 read one root's depth for the other's)
    other = dataclasses.replace(frame, depth_path=make_frame(tmp_path / "b", ramp_depth() * 2).depth_path)
    assert other.camera_token == frame.camera_token
    misses = cache.misses
    np.testing.assert_array_equal(cache.get(est, other, (30, 60)), est.estimate(other, (30, 60)))
    assert cache.misses == misses + 1 and not np.array_equal(cache.get(est, other, (30, 60)), first)


def test_build_depth_estimator_rejects_unknown_names():
    assert isinstance(build_depth_estimator("corrupted-truth", {"seed": 2}), CorruptedTruthDepth)
    with pytest.raises(HybridCalibError, match="unknown depth estimator"):
        build_depth_estimator("midas")


def test_lidar_depth_projects_fills_and_keeps_the_foreground(tmp_path):
    import dataclasses

    # LiDAR frame = camera frame rotated (x fwd, y left, z up); a dense wall at 30 m, a post at 8 m
    R = np.array([[0.0, -1, 0], [0, 0, -1], [1, 0, 0]])  # camera <- lidar
    T_cam_lidar = np.eye(4)
    T_cam_lidar[:3, :3] = R
    ys, zs = np.meshgrid(np.linspace(-12, 12, 90), np.linspace(-4, 2, 25))
    wall = np.stack([np.full(ys.size, 30.0), ys.ravel(), zs.ravel()], 1)
    py, pz = np.meshgrid(np.linspace(-0.1, 0.1, 3), np.linspace(-1.2, 0.4, 12))
    post = np.stack([np.full(py.size, 8.0), py.ravel(), pz.ravel()], 1)
    pts = np.concatenate([wall, post, [[0.3, 0.0, 0.0]]])  # and one return inside the ego body
    lidar = np.c_[pts, np.zeros(len(pts))].astype(np.float32)
    frame = dataclasses.replace(make_frame(tmp_path, None), lidar_points=lidar, T_cam_lidar=T_cam_lidar)
    d = LidarDepth().estimate(frame, (H, W))
    assert d.shape == (H, W) and d.dtype == np.float32
    known = d > 0
    assert 0.5 < known.mean() < 1.0 and not known[0].any()  # rows above the top beam stay unknown
    np.testing.assert_allclose(d[known & (d > 20)], 30.0, atol=1e-4)  # z-depth of the wall
    post_px = np.floor(100.0 * np.array([0.0, 0.5]) / 8.0 + np.array([59.5, 29.5]) + 0.5).astype(int)
    assert d[post_px[1], post_px[0]] == pytest.approx(8.0)  # nearest return wins (the post, not the wall)
    assert d.min() >= 0 and (d[known] >= 8.0 - 1e-5).all()  # the 0.3 m return was dropped
    half = LidarDepth().estimate(frame, (H // 2, W // 2))
    assert half.shape == (H // 2, W // 2) and np.isclose(half[half > 20], 30.0).all()
    assert isinstance(build_depth_estimator("lidar-densified"), LidarDepth)
    with pytest.raises(DataError, match="LiDAR sweep"):
        LidarDepth().estimate(make_frame(tmp_path, None, "nolidar"), (H, W))
    # a sweep that reads but does not see what the camera sees (behind the car, all zeros): the frame is skipped
    for bad in (np.c_[-pts[:, :1], pts[:, 1:]], np.zeros_like(pts)):
        blind = dataclasses.replace(frame, lidar_points=np.c_[bad, np.zeros(len(bad))].astype(np.float32))
        with pytest.raises(DataError, match=r"gives a depth at only 0.0 % of the image .*the frame is skipped"):
            LidarDepth().estimate(blind, (H, W))


def _tiny_depth_anything(directory, metric: bool = True):
    """A randomly initialised, tiny Depth Anything (metric head) saved with save_pretrained."""
    transformers = pytest.importorskip("transformers", reason="transformers is not installed in this venv")
    import torch

    backbone = transformers.Dinov2Config(
        hidden_size=32, num_hidden_layers=4, num_attention_heads=2, intermediate_size=64, image_size=56,
        patch_size=14, out_features=["stage1", "stage2", "stage3", "stage4"], reshape_hidden_states=False)
    conf = transformers.DepthAnythingConfig(
        backbone_config=backbone, reassemble_hidden_size=32, neck_hidden_sizes=[16, 16, 16, 16],
        fusion_hidden_size=16, head_hidden_size=8, patch_size=14,
        depth_estimation_type="metric" if metric else "relative", max_depth=80)
    torch.manual_seed(0)
    model = transformers.DepthAnythingForDepthEstimation(conf).eval()
    model.save_pretrained(directory)
    from transformers.models.dpt.image_processing_pil_dpt import DPTImageProcessorPil

    DPTImageProcessorPil(size={"height": 56, "width": 56}, keep_aspect_ratio=True, ensure_multiple_of=14
                         ).save_pretrained(directory)
    return model


def test_depth_anything_loads_from_a_local_directory_only(tmp_path, monkeypatch):
    import torch

    from learned.depth import DepthAnythingEstimator

    monkeypatch.setenv("HF_HUB_OFFLINE", "1")
    reference = _tiny_depth_anything(tmp_path / "da")
    est = build_depth_estimator(f"depth-anything:{tmp_path / 'da'}")
    assert isinstance(est, DepthAnythingEstimator)
    frame = make_frame(tmp_path, None)
    image = frame.load_image()
    depth = est.estimate(frame, (24, 48))
    assert depth.shape == (24, 48) and depth.dtype == np.float32
    assert np.all(np.isfinite(depth)) and np.all(depth > 0) and depth.max() <= 80.0 + 1e-3
    # the reloaded weights are the saved ones: same output as the in-memory model
    inputs = est.processor(images=image, return_tensors="pt")
    with torch.no_grad():
        ref = reference(pixel_values=inputs["pixel_values"]).predicted_depth
    ref = torch.nn.functional.interpolate(ref[:, None], size=(24, 48), mode="bicubic", align_corners=False)[0, 0]
    np.testing.assert_allclose(depth, ref.clamp(1e-3, 200.0).numpy(), rtol=1e-4, atol=1e-4)
    # the cache keys it by the weights too
    cache = DepthCache(tmp_path / "cache")
    np.testing.assert_array_equal(cache.get(est, frame, (24, 48)), cache.get(est, frame, (24, 48)))
    assert cache.hits == 1


def test_depth_anything_errors_name_the_directory(tmp_path):
    from learned.depth import DepthAnythingEstimator

    with pytest.raises(HybridCalibError, match="no config.json"):
        DepthAnythingEstimator(tmp_path / "missing")
    _tiny_depth_anything(tmp_path / "rel", metric=False)
    with pytest.raises(HybridCalibError, match="relative"):
        DepthAnythingEstimator(tmp_path / "rel")


def test_lidar_depth_on_simulated_frames_matches_the_rendered_truth(tmp_path):
    """The depth path real roots use (the frame's LiDAR through T_cam_lidar), run on the simulator's
    own LiDAR: dense enough and metrically right against the rendered depth of the same frame, which
    is what lets the networks train on the depth they are tested with."""
    from hybrid_calib.data.nuscenes import NuScenesRadarCamera
    from hybrid_calib.sim.drive import SimConfig
    from hybrid_calib.sim.simulate import simulate

    root = simulate(SimConfig(scenario="urban", vehicles=1, frames=2, seed=31, image_scale=0.125), tmp_path / "sim",
                    progress=False)
    frames = list(NuScenesRadarCamera(root, "v1.0-sim", conf={"load_lidar": True}))
    size = (48, 96)
    for f in frames:
        lidar = LidarDepth().estimate(f, size, None)
        truth = CorruptedTruthDepth(QUIET).estimate(f, size, None)
        both = (lidar > 0) & (truth > 0) & (truth < 60.0)
        assert lidar.shape == size and lidar.dtype == np.float32
        assert (lidar > 0).mean() > 0.4  # the densified map covers most of the image below the horizon
        rel = np.abs(lidar[both] - truth[both]) / truth[both]
        assert both.sum() > 500 and np.median(rel) < 0.05, (both.sum(), np.median(rel))
    # a root read without its LiDAR says what to do instead of guessing a depth
    bare = next(iter(NuScenesRadarCamera(root, "v1.0-sim", conf={"load_lidar": False})))
    with pytest.raises(DataError, match="LIDAR_TOP"):
        LidarDepth().estimate(bare, size, None)


def test_a_lidar_folder_that_cannot_be_read_is_said_with_the_depth_advice(tmp_path, monkeypatch):
    """Probe 80: an unreadable samples/LIDAR_TOP stopped calibrate with a bare 'Permission denied' (from listing it);
    an empty or missing one names the --depth choices. (Run as root, the test stands the permissions in.)"""
    import os
    from pathlib import Path

    from hybrid_calib.errors import OptionError
    from learned.depth import check_depth_source

    folder = tmp_path / "samples" / "LIDAR_TOP"
    folder.mkdir(parents=True)
    with pytest.raises(OptionError, match="LIDAR_TOP is missing or empty"):
        check_depth_source("lidar-densified", tmp_path, given=True)
    (folder / "x.pcd.bin").write_bytes(b"")
    check_depth_source("lidar-densified", tmp_path, given=True)

    def denied(self):
        raise PermissionError(13, "Permission denied", str(self))

    monkeypatch.setattr(Path, "iterdir", denied)
    monkeypatch.setattr(os, "access", lambda path, mode: Path(path) != folder)
    with pytest.raises(OptionError, match=r"--depth: lidar-densified densifies .*LIDAR_TOP cannot be read \(its "
                                          r"permissions\): make it readable"):
        check_depth_source("lidar-densified", tmp_path, given=True)


@pytest.mark.parametrize("damage", ["garbage", "empty", "pickle-only"])
def test_a_damaged_depth_model_is_an_error_naming_its_directory(damage, tmp_path):
    """A depth model whose weights file was damaged ended in an internal error (SafetensorError "header too large"),
    and one with only a pickled pytorch_model.bin was unpickled (probe 109). Each is one error naming the folder and
    the weights files there; only safetensors load."""
    from learned.depth import DepthAnythingEstimator

    _tiny_depth_anything(tmp_path / "da")
    weights = tmp_path / "da" / "model.safetensors"
    if damage == "garbage":
        weights.write_bytes(np.random.default_rng(0).bytes(1000))
    elif damage == "empty":
        weights.write_bytes(b"")
    else:
        weights.rename(weights.with_name("pytorch_model.bin"))
    with pytest.raises(HybridCalibError, match=r"could not load a depth model from .*da \(weights files there: "):
        DepthAnythingEstimator(tmp_path / "da")
