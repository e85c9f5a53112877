"""Dataset, training, checkpoints and evaluation of the learned model on tiny generated frames."""

from __future__ import annotations

import csv
import json
import shutil

import numpy as np
import pytest
import torch

from factors.correspondences import Correspondences
from hybrid_calib.data.frame import RadarCameraFrame, write_depth_png
from hybrid_calib.errors import HybridCalibError
from hybrid_calib.geometry import make_T, transform_points
from hybrid_calib.metrics import METRIC_KEYS, extrinsic_error
from hybrid_calib.perturbation import RANGES
from hybrid_calib.sensors.camera import PinholeCamera
from learned.dataset import (
    CalibDataset,
    DatasetConfig,
    SplitConfig,
    collate,
    group_key,
    split_indices,
)
from learned.depth import CorruptedTruthDepth, DepthCache
from tests.helpers import nominal_T_cam_radar

W0, H0 = 160, 90  # full image size on disk
# A tiny network (model input 96 x 48) so two epochs take seconds on 2 cores.
TINY_MODEL = dict(input_hw=[48, 96], bev_hw=[32, 32], bev_res_m=2.5, feat_dim=16, radar_widths=[8, 8, 16],
                  context_widths=[8, 8, 16], depth_branch_mid=8, phi_channels=8, phi_pool_fv=[2, 3],
                  phi_pool_bev=[2, 2], view_dim=32, match_dim=16, lstm_hidden=32, sk_min_dim=8)
R_CAM_LIDAR = np.array([[1.0, 0, 0], [0, 0, -1], [0, 1, 0]])  # lidar x right, y fwd, z up -> camera


def _make_frames(root, n_scenes: int = 4, per_scene: int = 3) -> list[RadarCameraFrame]:
    """Frames of a toy street: ground plane 1.5 m below the camera, a wall at 40 m, a box per frame."""
    import cv2

    g = np.random.default_rng(0)
    cam = PinholeCamera(120.0, 120.0, 79.5, 44.5, W0, H0)
    rays = cam.rays()
    T_cam_radar = nominal_T_cam_radar()
    T_cam_lidar = make_T(R_CAM_LIDAR, np.array([0.0, 0.3, -0.2]))
    frames = []
    for s in range(n_scenes):
        for k in range(per_scene):
            i = len(frames)
            with np.errstate(divide="ignore"):
                t_ground = np.where(rays[..., 1] > 1e-3, 1.5 / rays[..., 1], np.inf)
            t_wall = 40.0 / rays[..., 2]
            depth = np.minimum(t_ground, t_wall) * rays[..., 2]  # z-depth, metres
            depth[:5] = 0.0  # sky rows: no return
            box_u = 30 + 20 * k
            depth[30:60, box_u:box_u + 25] = 12.0 + 2 * s
            image = np.clip(255 * np.exp(-depth / 30.0)[..., None] * np.array([1.0, 0.8, 0.6]), 0, 255)
            image = (image + g.integers(0, 20, size=image.shape)).clip(0, 255).astype(np.uint8)
            img_path = root / f"img_{i}.png"
            cv2.imwrite(str(img_path), image[:, :, ::-1])
            depth_path = write_depth_png(root / f"depth_{i}.png", depth)
            n_r = 40 + 10 * k
            radar = np.stack([g.uniform(3, 45, n_r), g.uniform(-12, 12, n_r), np.zeros(n_r)], 1)
            lidar = np.stack([g.uniform(-15, 15, 3000), g.uniform(1, 45, 3000), g.uniform(-1.8, 1.0, 3000),
                              g.uniform(0, 1, 3000)], 1).astype(np.float32)
            frames.append(RadarCameraFrame(
                index=i, sample_token=f"sample-{i}", scene_name=f"scene-{s}", vehicle=f"veh-{s % 2}",
                log_token=f"log-{s}", camera_channel="CAM_FRONT", radar_channel="RADAR_FRONT",
                camera_token=f"cam-{i}", radar_token=f"rad-{i}", timestamp_camera_us=i * 500_000,
                timestamp_radar_us=i * 500_000, image_path=img_path, camera=cam, radar_points=radar,
                radar_fields={}, T_cam_radar=T_cam_radar, lidar_points=lidar, T_cam_lidar=T_cam_lidar,
                depth_path=depth_path))
    return frames


@pytest.fixture(scope="module")
def frames(tmp_path_factory):
    return _make_frames(tmp_path_factory.mktemp("frames"))


def _dataset(frames, tmp_path, **kw) -> CalibDataset:
    conf = DatasetConfig(**{"height": 48, "width": 96, "max_radar_points": 64, "max_lidar_points": 256, **kw})
    return CalibDataset(frames, conf, CorruptedTruthDepth(), cache=DepthCache(tmp_path / "cache"))


# ------------------------------------------------------------------------------------ dataset


def test_sample_shapes_and_collate(frames, tmp_path):
    ds = _dataset(frames, tmp_path)
    s = ds[0]
    shapes = {k: tuple(v.shape) for k, v in s.items() if isinstance(v, torch.Tensor)}
    assert shapes == {"image": (3, 48, 96), "depth": (1, 48, 96), "K": (3, 3), "radar": (64, 3), "radar_mask": (64,),
                      "T_init": (4, 4), "T_gt": (4, 4), "lidar_cam": (256, 3), "lidar_mask": (256,),
                      "lidar_fraction": (), "perturbation": (6,)}
    assert s["image"].dtype == torch.float32 and 0.0 <= s["image"].min() and s["image"].max() <= 1.0
    assert s["radar_mask"].sum() == 40 and s["lidar_mask"].sum() == 256  # 40 radar points padded, LiDAR subsampled
    assert torch.all(s["radar"][~s["radar_mask"]] == 0)
    # the share of the sweep's in-image points kept: the NR matcher's tau is the whole sweep's (probe 132)
    n_in_image = 256 / float(s["lidar_fraction"])
    assert 256 < n_in_image <= 3000 and float(_dataset(frames, tmp_path / "all", max_lidar_points=3000)[0][
        "lidar_fraction"]) == 1.0
    # LiDAR is in the camera frame: in front of the camera and inside the image
    lid = s["lidar_cam"][s["lidar_mask"]].double().numpy()
    uv, z = PinholeCamera.from_K(s["K"].double().numpy(), 96, 48).project(lid)
    assert np.all(z > 0.1) and np.all((uv[:, 0] > -0.5) & (uv[:, 0] < 95.5) & (uv[:, 1] > -0.5) & (uv[:, 1] < 47.5))
    batch = collate([ds[0], None, ds[1]])
    assert batch["image"].shape == (2, 3, 48, 96) and batch["token"] == ["cam-0", "cam-1"]
    assert batch["index"].tolist() == [0, 1]
    assert collate([None]) is None


def test_scaled_K_projects_where_the_full_size_projection_lands(frames, tmp_path):
    ds = _dataset(frames, tmp_path)
    s, f = ds[3], frames[3]
    pts = transform_points(f.T_cam_radar, f.radar_points)
    uv_full, z = f.camera.project(pts)
    K = s["K"].double().numpy()
    uv_small = (K @ (pts / pts[:, 2:]).T).T[:, :2]
    sx, sy = 96 / W0, 48 / H0
    expected = np.stack([(uv_full[:, 0] + 0.5) * sx - 0.5, (uv_full[:, 1] + 0.5) * sy - 0.5], 1)
    np.testing.assert_allclose(uv_small[z > 0], expected[z > 0], atol=1e-4)  # float32 K
    # depth map: the wall (40 m) and the box are where the full-size depth puts them, after corruption
    d = s["depth"][0].numpy()
    assert 25.0 < np.median(d[8:12][d[8:12] > 0]) < 60.0


def test_perturbations_in_range_reproducible_and_read_back_by_the_metrics(frames, tmp_path):
    for name, (rot_deg, trans_m) in RANGES.items():
        ds = _dataset(frames * 34, tmp_path, perturbation=name)  # 408 samples; nothing is loaded
        xi = np.array([ds.perturbation(i) for i in range(400)])
        assert np.all(np.abs(np.degrees(xi[:, :3])) <= rot_deg) and np.all(np.abs(xi[:, 3:]) <= trans_m)
        assert np.all(np.abs(np.degrees(xi[:, :3])).max(0) > 0.9 * rot_deg)  # the whole range is used
        np.testing.assert_allclose(np.abs(xi[:, 3:]).mean(0), trans_m / 2, rtol=0.15)  # uniform: E|x| = a/2
        np.testing.assert_array_equal(xi[7], ds.perturbation(7))
        ds.set_epoch(1)
        assert not np.allclose(xi[7], ds.perturbation(7))  # training: a new start every epoch
    ev = CalibDataset(frames, DatasetConfig(height=48, width=96), CorruptedTruthDepth(), train=False)
    first = ev.perturbation(2)
    ev.set_epoch(5)
    np.testing.assert_array_equal(first, ev.perturbation(2))  # evaluation: fixed per sample
    subset = CalibDataset(frames, DatasetConfig(height=48, width=96), CorruptedTruthDepth(), train=False,
                          indices=[5, 2])
    np.testing.assert_array_equal(first, subset.perturbation(1))  # ... whatever the split around it
    rev = CalibDataset(frames[::-1], DatasetConfig(height=48, width=96), CorruptedTruthDepth(), train=False)
    np.testing.assert_array_equal(first, rev.perturbation(len(frames) - 3))  # ... and the order of the roots read
    # (probe 114: `evaluate --data A B` and `--data B A` drew every frame another start)
    s = ev[2]
    e = extrinsic_error(s["T_init"].double().numpy(), s["T_gt"].double().numpy())
    np.testing.assert_allclose([e.roll_deg, e.pitch_deg, e.yaw_deg], np.abs(np.degrees(first[:3])), atol=1e-3)
    np.testing.assert_allclose([e.x_cm, e.y_cm, e.z_cm], np.abs(first[3:]) * 100, atol=1e-3)


def test_lidar_variant_feeds_lidar_points_and_T_cam_lidar(frames, tmp_path):
    import dataclasses

    ds = _dataset(frames, tmp_path, variant="lidar")
    s, f = ds[4], frames[4]
    np.testing.assert_allclose(s["T_gt"].double().numpy(), f.T_cam_lidar, atol=1e-6)
    pts = s["radar"][s["radar_mask"]].double().numpy()
    assert len(pts) == 64  # 3000 LiDAR points, those in front under T_init subsampled to Nmax
    assert np.all(transform_points(s["T_init"].double().numpy(), pts)[:, 2] > 0.1)
    assert np.abs(pts[:, 2]).max() > 0.1  # real LiDAR heights, not a flat radar plane
    xi = s["perturbation"].numpy()
    e = extrinsic_error(s["T_init"].double().numpy(), f.T_cam_lidar)
    np.testing.assert_allclose([e.x_cm, e.y_cm, e.z_cm], np.abs(xi[3:]) * 100, atol=1e-3)
    no_lidar = _dataset([dataclasses.replace(f, lidar_points=None)], tmp_path, variant="lidar")
    assert no_lidar[0] is None and "LiDAR" in no_lidar.bad[0]


def test_splits_keep_scenes_apart(frames):
    conf = SplitConfig(test_groups=("scene-3",), val_groups=("scene-2",))
    parts = {s: split_indices(frames, s, conf) for s in ("train", "val", "test")}
    assert sorted(sum(parts.values(), [])) == list(range(len(frames)))
    assert {frames[i].scene_name for i in parts["test"]} == {"scene-3"}
    assert {frames[i].scene_name for i in parts["train"]} == {"scene-0", "scene-1"}
    hashed = {s: split_indices(frames, s, SplitConfig(by="vehicle", test_fraction=0.5, val_fraction=0.0))
              for s in ("train", "test")}
    for a, b in [("train", "test")]:
        assert not {group_key(frames[i], "vehicle") for i in hashed[a]} & {group_key(frames[i], "vehicle")
                                                                            for i in hashed[b]}
    with pytest.raises(HybridCalibError, match="split must be"):
        split_indices(frames, "dev")


def test_bad_frame_is_recorded_and_skipped(frames, tmp_path):
    import dataclasses

    broken = dataclasses.replace(frames[0], image_path=tmp_path / "missing.png")
    ds = _dataset([broken, frames[1]], tmp_path)
    assert ds[0] is None and "not found" in ds.bad[0]
    assert collate([ds[0], ds[1]])["image"].shape[0] == 1


# ------------------------------------------------------------------------------------ training

SPLIT = {"test_groups": ["scene-3"], "val_groups": ["scene-2"]}


def _train_conf(tmp_path, epochs: int) -> dict:
    return dict(model=TINY_MODEL, epochs=epochs, batch_size=3, samples_per_epoch=6, val_samples=3, lr=1e-3,
                max_radar_points=64, max_lidar_points=256, split=SPLIT, depth_cache=str(tmp_path / "depth-cache"))


def _weights(path) -> dict:
    from safetensors.torch import load_file

    return load_file(str(path))


def test_train_checkpoints_logs_and_resumes(frames, tmp_path, caplog):
    from hybrid_calib.plots.training import plot_history
    from learned.checkpoint import latest_checkpoint, load_model
    from learned.train import train, train_config

    run = tmp_path / "run"
    last = train(train_config("small", _train_conf(tmp_path, 2)), frames, run, progress=False)
    assert last.name == "ckpt-0002.json" and latest_checkpoint(run / "checkpoints") == last
    meta = json.loads(last.read_text())
    assert meta["epoch"] == 2 and meta["model_config"]["feat_dim"] == 16 and meta["train_config"]["epochs"] == 2
    for epoch in (1, 2):
        for suffix in (".safetensors", ".optim.pt", ".json"):
            assert (run / "checkpoints" / f"ckpt-000{epoch}{suffix}").is_file()
    with (run / "epochs.csv").open() as f:
        rows = list(csv.DictReader(f))
    assert [int(r["epoch"]) for r in rows] == [1, 2]
    assert all(np.isfinite(float(r["train_total"])) and float(r["val_rot_geodesic_deg"]) > 0 for r in rows)
    with (run / "steps.csv").open() as f:
        assert len(list(csv.DictReader(f))) == 4  # 2 epochs x 2 steps of 3 samples
    assert json.loads((run / "train_config.json").read_text())["model"]["input_hw"] == [48, 96]
    assert not (run / "history.png").exists()  # the command draws it (hybrid_calib.plots.training)
    assert plot_history(run / "epochs.csv", run / "history.png").stat().st_size > 1000
    w2 = _weights(run / "checkpoints" / "ckpt-0002.safetensors")
    mtime1 = (run / "checkpoints" / "ckpt-0001.safetensors").stat().st_mtime_ns

    # resume: continues with epoch 3, keeps epochs 1-2 as they were (a log line that does not parse is dropped
    # with a word: it ended the resume in an internal error)
    with (run / "epochs.csv").open("a") as f:
        f.write("zzz\n")
    # epoch 3's weights left without their JSON (a save cut short): trained again and overwritten, with a word
    shutil.copy(run / "checkpoints" / "ckpt-0002.safetensors", run / "checkpoints" / "ckpt-0003.safetensors")
    caplog.clear()
    last = train(train_config("small", _train_conf(tmp_path, 3)), frames, run, progress=False)
    assert last.name == "ckpt-0003.json"
    assert any("ckpt-0003.safetensors hold(s) no checkpoint JSON" in m and "trained again from after ckpt-0002.json"
               in m for m in caplog.messages)
    assert (run / "checkpoints" / "ckpt-0001.safetensors").stat().st_mtime_ns == mtime1
    with (run / "epochs.csv").open() as f:
        assert [int(r["epoch"]) for r in csv.DictReader(f)] == [1, 2, 3]
    with (run / "steps.csv").open() as f:
        assert [int(r["epoch"]) for r in csv.DictReader(f)] == [1, 1, 2, 2, 3, 3]
    w3 = _weights(run / "checkpoints" / "ckpt-0003.safetensors")
    assert any(not torch.equal(w2[k], w3[k]) for k in w2)

    # deterministic: an uninterrupted 3-epoch run gives the same weights as 2 + resume 1
    fresh = train(train_config("small", _train_conf(tmp_path, 3)), frames, tmp_path / "fresh", progress=False)
    wf = _weights(fresh.with_suffix(".safetensors"))
    for k in w3:
        torch.testing.assert_close(wf[k], w3[k], rtol=1e-5, atol=1e-6)

    # --epochs below what the run holds: nothing to train, and said (the later checkpoint came back silently)
    caplog.clear()
    assert train(train_config("small", _train_conf(tmp_path, 2)), frames, run, progress=False).name == "ckpt-0003.json"
    assert any("already holds 3 epochs (>= --epochs 2): nothing to train" in m and "ckpt-0002.json" in m
               for m in caplog.messages)

    model, ckpt = load_model(run)
    assert ckpt.epoch == 3 and not model.training
    state = model.state_dict()
    assert all(torch.equal(state[k], w3[k]) for k in w3)
    with pytest.raises(HybridCalibError, match="already holds checkpoints"):
        train(train_config("small", _train_conf(tmp_path, 3)), frames, run, resume=False, progress=False)
    other = _train_conf(tmp_path, 4)
    other["model"] = {**TINY_MODEL, "lstm_hidden": 16}
    with pytest.raises(HybridCalibError, match="another model config"):
        train(train_config("small", other), frames, run, progress=False)
    # other training options (or data) would continue the run with them and record them as the whole run's
    with pytest.raises(HybridCalibError, match=r"other options \(perturbation: \"R1\" -> \"R2\"; lr: 0.001 -> "):
        train(train_config("small", {**_train_conf(tmp_path, 4), "perturbation": "R2", "lr": 0.01}), frames, run,
              progress=False)
    assert latest_checkpoint(run / "checkpoints").name == "ckpt-0003.json"


def test_init_weights_starts_a_new_run_from_a_checkpoint(frames, tmp_path):
    from learned.train import train, train_config

    base = train(train_config("small", _train_conf(tmp_path, 1)), frames, tmp_path / "base", progress=False)
    conf = _train_conf(tmp_path, 1) | {"init_weights": str(base), "lr": 0.0}  # lr 0: weights stay the start
    tuned = train(train_config("small", conf), frames, tmp_path / "tuned", progress=False)
    w0, w1 = _weights(base.with_suffix(".safetensors")), _weights(tuned.with_suffix(".safetensors"))
    float_keys = [k for k in w0 if w0[k].is_floating_point() and "running" not in k]
    assert all(torch.equal(w0[k], w1[k]) for k in float_keys)
    scratch = train(train_config("small", _train_conf(tmp_path, 1) | {"lr": 0.0, "seed": 5}), frames,
                    tmp_path / "scratch", progress=False)
    ws = _weights(scratch.with_suffix(".safetensors"))
    assert any(not torch.equal(w0[k], ws[k]) for k in float_keys)  # the check above can fail
    other = _train_conf(tmp_path, 1) | {"init_weights": str(base), "model": {**TINY_MODEL, "lstm_hidden": 16}}
    with pytest.raises(HybridCalibError, match="lstm_hidden"):
        train(train_config("small", other), frames, tmp_path / "bad", progress=False)
    # loss-only settings may change when fine-tuning (e.g. a heavier translation term)
    heavier = _train_conf(tmp_path, 1) | {"init_weights": str(base), "model": {**TINY_MODEL, "calib_trans_weight": 5.0}}
    assert train(train_config("small", heavier), frames, tmp_path / "heavier", progress=False).is_file()
    # the run resumed from another folder, its --init typed relative to it: the same run (probe 119: refused as one
    # of "other options (init_weights: 'ck.json' -> '../ck.json')")
    import os

    here = os.getcwd()
    try:
        os.chdir(base.parent)
        rel = _train_conf(tmp_path, 1) | {"init_weights": base.name, "lr": 0.0}
        train(train_config("small", rel), frames, tmp_path / "resumed", progress=False)
        (tmp_path / "elsewhere").mkdir()
        os.chdir(tmp_path / "elsewhere")
        again = _train_conf(tmp_path, 2) | {"init_weights": os.path.relpath(base, tmp_path / "elsewhere"), "lr": 0.0}
        assert train(train_config("small", again), frames, tmp_path / "resumed", progress=False).name == \
            "ckpt-0002.json"
    finally:
        os.chdir(here)


def test_bad_context_weights_and_export_iteration_are_named(frames, tmp_path):
    """Probe 79: context_weights naming no file, or a file of no ResNet-18 weights, and an export.iteration the network
    does not run were internal errors (FileNotFoundError, IndexError at the first frame)."""
    from learned.export import ExportConfig, check_iteration
    from learned.train import train, train_config

    with pytest.raises(HybridCalibError, match="context_weights nope.safetensors: no such file"):
        train(train_config("small", _train_conf(tmp_path, 1) | {"context_weights": "nope.safetensors"}), frames,
              tmp_path / "a", progress=False)
    junk = tmp_path / "junk.pt"
    torch.save({"x": torch.zeros(2)}, junk)
    with pytest.raises(HybridCalibError, match="context_weights: .*pass ResNet-18 ImageNet weights"):
        train(train_config("small", _train_conf(tmp_path, 1) | {"context_weights": str(junk)}), frames,
              tmp_path / "b", progress=False)
    check_iteration(ExportConfig(iteration=2), 3)
    check_iteration(ExportConfig(iteration=-1), 3)
    with pytest.raises(HybridCalibError, match=r"export.iteration=3: the network runs 3 iteration\(s\); pass 0..2"):
        check_iteration(ExportConfig(iteration=3), 3)
    from learned.config import model_config
    from learned.evaluate import EvalConfig, export_pure
    from learned.model import RCAutoCalib

    model = RCAutoCalib(model_config("small", TINY_MODEL))
    with pytest.raises(HybridCalibError, match="export.iteration=50"):  # evaluate checks it before any frame
        export_pure(model, frames, EvalConfig(split="all", export={"iteration": 50}), tmp_path / "e", progress=False)


def test_concat_frames_keeps_scene_groups(frames):
    from learned.dataset import ConcatFrames

    both = ConcatFrames([frames[:6], frames[6:]])
    assert len(both) == len(frames) and both[7] is frames[7] and both[-1] is frames[-1]
    with pytest.raises(IndexError):
        both[len(frames)]
    for split in ("train", "val", "test"):
        assert split_indices(both, split, SPLIT) == split_indices(frames, split, SPLIT)


def test_checkpoint_round_trip_restores_model_and_optimizer(tmp_path):
    from learned.checkpoint import load_checkpoint, save_checkpoint

    torch.manual_seed(0)
    model = torch.nn.Sequential(torch.nn.Linear(4, 8), torch.nn.BatchNorm1d(8), torch.nn.Linear(8, 2))
    opt = torch.optim.Adam(model.parameters(), lr=1e-3)
    sched = torch.optim.lr_scheduler.StepLR(opt, 2, 0.5)
    model(torch.randn(5, 4)).sum().backward()
    opt.step()
    sched.step()
    path = save_checkpoint(tmp_path / "ckpt-0007", model, epoch=7, model_config={"a": 1}, metrics={"x": 0.5},
                           optimizer=opt, scheduler=sched)
    model2 = torch.nn.Sequential(torch.nn.Linear(4, 8), torch.nn.BatchNorm1d(8), torch.nn.Linear(8, 2))
    opt2 = torch.optim.Adam(model2.parameters(), lr=1.0)
    sched2 = torch.optim.lr_scheduler.StepLR(opt2, 2, 0.5)
    ckpt = load_checkpoint(tmp_path / "ckpt-0007.safetensors", model2, opt2, sched2)
    assert (ckpt.epoch, ckpt.model_config, ckpt.metrics) == (7, {"a": 1}, {"x": 0.5}) and ckpt.path == path
    # the weights readable as the JSON beside them (safetensors wrote them 0600: a shared run folder's were private)
    import os

    mask = os.umask(0)
    os.umask(mask)
    assert (tmp_path / "ckpt-0007.safetensors").stat().st_mode & 0o777 == 0o666 & ~mask
    for a, b in zip(model.state_dict().values(), model2.state_dict().values()):
        assert torch.equal(a, b)
    assert opt2.state_dict()["param_groups"][0]["lr"] == opt.state_dict()["param_groups"][0]["lr"]
    assert torch.equal(opt2.state_dict()["state"][0]["exp_avg"], opt.state_dict()["state"][0]["exp_avg"])
    assert sched2.last_epoch == 1
    with pytest.raises(HybridCalibError, match="do not fit"):
        load_checkpoint(path, torch.nn.Linear(4, 2))
    with pytest.raises(HybridCalibError, match="not found"):
        load_checkpoint(tmp_path / "ckpt-0099.json")


def test_a_same_seed_retrain_is_the_same_network(tmp_path):
    """Probe 72: the same weights saved twice were two files half the time (safetensors writes its metadata in
    hash-map order), and a checkpoint's identity hashed its epoch's wall time, so a same-seed retrain was "another
    network" (its caches missed, compare refused its trials). What the network computes still tells them apart."""
    import json

    from learned.checkpoint import checkpoint_digest, save_checkpoint, weights_sha256

    torch.manual_seed(0)
    model = torch.nn.Linear(3, 2)
    saved = [save_checkpoint(tmp_path / f"run{i}" / "ckpt-0001", model, epoch=1, model_config={"a": 1, "b": [2]},
                             metrics={"val_total": 0.5, "seconds": 10.0 + i}) for i in range(8)]
    assert len({weights_sha256(p.with_suffix(".safetensors")) for p in saved}) == 1
    assert len({checkpoint_digest(p) for p in saved}) == 1
    meta = json.loads(saved[0].read_text())
    saved[1].write_text(json.dumps({**meta, "metrics": {**meta["metrics"], "val_total": 0.6}}))
    saved[2].write_text(json.dumps({**meta, "export": {"hybrid": {"sigma_scale": 2.0}}}))
    with torch.no_grad():
        model.weight[0, 0] += 1e-3
    other = save_checkpoint(tmp_path / "run9" / "ckpt-0001", model, epoch=1, model_config={"a": 1, "b": [2]},
                            metrics={"val_total": 0.5, "seconds": 10.0})
    digests = [checkpoint_digest(p) for p in (saved[0], saved[1], saved[2], other)]
    assert len(set(digests)) == 4


def test_a_refit_keeps_the_value_it_replaces_and_shipped_checkpoints_are_not_rewritten(tmp_path):
    """A four-frame refit silently replaced a cov_scale fitted on 240 frames; pointed at the package's own
    checkpoint, evaluate --fit-uncertainty would have rewritten the installation in place."""
    from pathlib import Path

    import learned
    from learned.checkpoint import save_checkpoint, set_export_overrides
    from learned.uncertainty_fit import refuse_shipped

    path = save_checkpoint(tmp_path / "ckpt-0001", torch.nn.Linear(2, 2), epoch=1, model_config={"a": 1})
    set_export_overrides(path, {"cov_scale": [2.0] * 6}, "fitted on 240 frames")
    set_export_overrides(path, {"cov_scale": [2.0] * 6}, "the same value again")  # nothing replaced
    set_export_overrides(path, {"cov_scale": [0.5] * 6, "sigma_scale": 1.1}, "fitted on 4 frames")
    meta = json.loads(path.read_text())
    assert meta["export"]["cov_scale"] == [0.5] * 6 and meta["export_notes"]["cov_scale"] == "fitted on 4 frames"
    (old,) = meta["export_history"]
    assert old["key"] == "cov_scale" and old["value"] == [2.0] * 6 and old["note"] == "the same value again"
    with pytest.raises(HybridCalibError, match="shipped with the package; copy"):
        refuse_shipped(Path(learned.__file__).parent / "checkpoints" / "small-sim-r1.json")
    refuse_shipped(path)  # a checkpoint of the user's own


# ------------------------------------------------------------------------------------ evaluation


class OracleModel(torch.nn.Module):
    """Stand-in network: walks from T_init to T_gt in three steps (final = T_gt exactly)."""

    def __init__(self):
        super().__init__()
        from learned.config import model_config

        self.cfg = model_config("small", TINY_MODEL)
        self.dummy = torch.nn.Parameter(torch.zeros(()))

    def forward(self, batch):
        T0, T1 = batch["T_init"], batch["T_gt"]
        mid = T0.clone()
        mid[:, :3, 3] = 0.5 * (T0[:, :3, 3] + T1[:, :3, 3])
        return {"T_iters": [T0, mid, T1]}


def oracle_exporter(model, out, batch, export_conf=None):
    corr = []
    for b in range(len(batch["T_gt"])):
        m = batch["radar_mask"][b]
        pts = batch["radar"][b][m].double().numpy()
        pc = transform_points(batch["T_gt"][b].double().numpy(), pts)
        uv, _ = PinholeCamera.from_K(batch["K"][b].double().numpy(), 96, 48).project(pc)
        ok = np.all(np.isfinite(uv), axis=1)
        corr.append(Correspondences(pts[ok], uv[ok], np.full(ok.sum(), 2.0), np.ones(ok.sum()),
                                    batch["K"][b].double().numpy(), f"frame{b}"))
    return corr, torch.full((len(corr), 6), 1e-4)


def test_evaluate_table_columns_and_zero_error_for_an_oracle(frames, tmp_path):
    from hybrid_calib.plots.evaluation import plot_error_cdf
    from learned.evaluate import EvalConfig, evaluate, evaluate_predictions

    conf = EvalConfig(perturbation="R2", split="test", split_options=SplitConfig(test_groups=("scene-3",)),
                      max_radar_points=64, max_lidar_points=64, batch_size=2)
    out = tmp_path / "eval"
    res = evaluate(OracleModel(), frames, conf, out, exporter=oracle_exporter, progress=False)
    assert res.n_frames == 3 and list(res.rows) == ["initial", "pure iter 1", "pure iter 2", "pure iter 3", "pure"]
    for row in res.rows.values():
        assert set(row) == set(METRIC_KEYS)
    assert all(v < 1e-4 for v in res.rows["pure"].values())  # T_gt -> zero error
    init = res.rows["initial"]
    assert 0 < init["rot_mean_deg"] <= 20 and 0 < init["trans_mean_cm"] <= 150  # R2 starts
    assert res.rows["pure iter 2"]["trans_mean_cm"] == pytest.approx(init["trans_mean_cm"] / 2, rel=1e-6)
    saved = json.loads((out / "results.json").read_text())
    assert saved["rows"]["pure"]["geodesic_deg"] < 1e-4 and saved["n_frames"] == 3
    assert "| pure |" in (out / "results.md").read_text()
    assert plot_error_cdf(res, out / "errors_cdf.png").stat().st_size > 1000  # as hybrid-calib evaluate does
    with np.load(next((out / "frames").glob("*.npz"))) as z:
        assert z["T_iters"].shape == (3, 4, 4) and z["pixels"].shape[1] == 2 and z["uncertainty"].shape == (6,)
        assert "cov" not in z.files and z["schema_version"] == 1 and z["vehicle"] == "veh-1"
    # idempotent: a second run exports nothing new and reads the same table
    mtimes = {p: p.stat().st_mtime_ns for p in (out / "frames").glob("*.npz")}
    again = evaluate(OracleModel(), frames, conf, out, exporter=oracle_exporter, progress=False)
    assert {p: p.stat().st_mtime_ns for p in (out / "frames").glob("*.npz")} == mtimes
    assert again.rows == evaluate_predictions(out).rows
    # a killed run's temporary file (SIGKILL between its write and its rename) is no frame: the resume removes it
    # (probe 90: a complete one was tabled as a 4th frame, a truncated one stopped the run)
    first = sorted((out / "frames").glob("*.npz"))[0]
    (out / "frames" / f"{first.stem}.4242.hybrid-calib-tmp.npz").write_bytes(first.read_bytes())
    (out / "frames" / f"{first.stem}.4243.hybrid-calib-tmp.npz").write_bytes(first.read_bytes()[:100])
    assert evaluate_predictions(out).n_frames == 3
    assert evaluate(OracleModel(), frames, conf, out, exporter=oracle_exporter, progress=False).n_frames == 3
    assert not list((out / "frames").glob("*tmp*"))
    with pytest.raises(HybridCalibError, match=r"another config \(eval.perturbation: \"R2\" -> \"R1\""):
        evaluate(OracleModel(), frames, EvalConfig(perturbation="R1", split_options=conf.split_options), out,
                 exporter=oracle_exporter, progress=False)
    # the same root re-made at the same path, or the checkpoint retrained there: other predictions, said
    data = {"roots": ["/r"], "version": "v1.0-sim", "nsweeps": 1, "stamps": ["a"]}
    evaluate(OracleModel(), frames, conf, tmp_path / "e2", exporter=oracle_exporter, progress=False, data=data,
             network=["n1"])
    for other, words in (({"data": {**data, "stamps": ["b"]}}, "the data in /r as it was before"),
                         ({"network": ["n2"]}, "another checkpoint's files")):
        with pytest.raises(HybridCalibError, match=words):
            evaluate(OracleModel(), frames, conf, tmp_path / "e2", exporter=oracle_exporter, progress=False,
                     **{"data": data, "network": ["n1"], **other})
    stale = tmp_path / "e2" / "depth-cache" / "stale"
    stale.parent.mkdir(exist_ok=True)
    stale.write_text("x")  # --overwrite recomputes from the data as they are now: its own depth cache goes too
    evaluate(OracleModel(), frames, conf, tmp_path / "e2", exporter=oracle_exporter, progress=False, data=data,
             network=["n2"], overwrite=True)
    assert not stale.exists()


# ------------------------------------------------------------------------------------ command line


@pytest.fixture(scope="module")
def sim_root(tmp_path_factory):
    """A tiny simulated drive: 3 vehicles (one scene each) x 3 keyframes, 200 x 112 images."""
    from hybrid_calib.sim.drive import SimConfig
    from hybrid_calib.sim.simulate import simulate

    return simulate(SimConfig(vehicles=3, frames=3, image_scale=0.125, seed=0),
                    tmp_path_factory.mktemp("sim"), progress=False)


def _run_command(name: str, argv: list[str]) -> int:
    """``hybrid-calib NAME ARGV`` in-process."""
    from hybrid_calib.cli import main

    return main([name, *argv])


def test_fine_tuning_goes_on_with_the_depth_its_weights_learned(sim_root, tmp_path, capsys):
    """Probe 56: train --init with a shipped (lidar-densified) checkpoint on a simulated root trained on corrupted-truth
    depth, with no word: the weights met another input than the one they learned."""
    model_sets = [f"model.{k}={json.dumps(v)}" for k, v in TINY_MODEL.items()]
    sets = ["batch_size=3", "samples_per_epoch=3", "val_samples=3", "max_lidar_points=256",
            'split.test_groups=["scene-sim-veh-002"]', 'split.val_groups=["scene-sim-veh-001"]', *model_sets]
    common = ["--data", str(sim_root), "--preset", "small", "--epochs", "1", "--no-progress",
              *[a for s in sets for a in ("--set", s)]]
    assert _run_command("train", [*common, "--out", str(tmp_path / "a"), "--depth", "lidar-densified"]) == 0
    init = tmp_path / "a" / "checkpoints" / "ckpt-0001.json"
    capsys.readouterr()
    assert _run_command("train", [*common, "--out", str(tmp_path / "b"), "--init", str(init)]) == 0
    assert "was trained on lidar-densified depth: the run goes on with it, not corrupted-truth" in \
        capsys.readouterr().err
    meta = json.loads((tmp_path / "b" / "checkpoints" / "ckpt-0001.json").read_text())
    assert meta["train_config"]["depth"] == "lidar-densified"
    assert _run_command("train", [*common, "--out", str(tmp_path / "c"), "--init", str(init), "--depth",
                                  "corrupted-truth"]) == 0  # asked for: kept, no note
    assert "the run goes on with it" not in capsys.readouterr().err
    assert json.loads((tmp_path / "c" / "checkpoints" / "ckpt-0001.json").read_text())["train_config"]["depth"] == \
        "corrupted-truth"


def test_train_and_evaluate_list_the_samples_the_index_left_out(sim_root, tmp_path, capsys):
    """Probe 100: a sample whose radar keyframe record is broken (no frame) vanished from evaluate ("15 of 15 frames",
    skipped.json []) and train (no skipped.json), where calibrate and inspect list it with why."""
    import shutil

    root = tmp_path / "root"
    shutil.copytree(sim_root, root)
    sd_path = root / "v1.0-sim" / "sample_data.json"
    sds = json.loads(sd_path.read_text())
    radar = next(sd for sd in sds if sd["is_key_frame"] and "RADAR_FRONT" in sd["filename"])
    radar.pop("filename")  # the record is left out for its schema: its sample has no RADAR_FRONT keyframe
    sd_path.write_text(json.dumps(sds))
    model_sets = [f"model.{k}={json.dumps(v)}" for k, v in TINY_MODEL.items()]
    sets = ["batch_size=3", "samples_per_epoch=3", "val_samples=3", "max_lidar_points=256", *model_sets]
    run = tmp_path / "run"
    assert _run_command("train", ["--data", str(root), "--preset", "small", "--out", str(run), "--epochs", "1",
                                  "--no-progress"] + [a for s in sets for a in ("--set", s)]) == 0
    left = [r for r in json.loads((run / "skipped.json").read_text()) if r["index"] is None]
    assert len(left) == 2 and "lacks field(s) ['filename']" in left[0]["reason"]  # the record, then its sample
    assert radar["sample_token"] in left[1]["reason"] and "has no keyframe for ['RADAR_FRONT']" in left[1]["reason"]
    capsys.readouterr()
    out = tmp_path / "eval"
    assert _run_command("evaluate", ["--data", str(root), "--split", "all", "--checkpoint", str(run), "--out",
                                     str(out), "--no-progress"]) == 0
    said = capsys.readouterr().out
    left = json.loads((out / "skipped.json").read_text())
    assert [r["index"] for r in left] == [None, None] and radar["sample_token"] in left[1]["reason"]
    assert "0 frame(s) skipped, 2 sample(s) or record(s) of the tables hold no frame" in said
    assert json.loads((out / "results.json").read_text())["n_frames"] == 8


def test_cli_train_then_evaluate(sim_root, tmp_path, capsys):
    model_sets = [f"model.{k}={json.dumps(v)}" for k, v in TINY_MODEL.items()]
    sets = ["batch_size=3", "samples_per_epoch=3", "val_samples=3", "max_lidar_points=256",
            'split.test_groups=["scene-sim-veh-002"]', 'split.val_groups=["scene-sim-veh-001"]', *model_sets]
    run = tmp_path / "run"
    argv = ["--data", str(sim_root), "--preset", "small", "--out", str(run), "--range", "R2", "--epochs", "1",
            "--no-progress"] + [a for s in sets for a in ("--set", s)]
    assert _run_command("train", argv) == 0
    meta = json.loads((run / "checkpoints" / "ckpt-0001.json").read_text())
    assert meta["train_config"]["perturbation"] == "R2" and meta["model_config"]["input_hw"] == [48, 96]
    assert "last checkpoint" in capsys.readouterr().out and (run / "history.png").stat().st_size > 1000

    out = tmp_path / "eval"
    assert _run_command("evaluate", ["--data", str(sim_root), "--range", "R1", "--method", "pure", "--checkpoint",
                                     str(run), "--out", str(out), "--no-progress"]) == 0
    printed = capsys.readouterr().out
    assert "R.Mean" in printed and "pure" in printed
    res = json.loads((out / "results.json").read_text())
    assert res["n_frames"] == 3  # the held-out scene only (split taken from the checkpoint)
    assert res["config"]["eval"]["split_options"]["test_groups"] == ["scene-sim-veh-002"]
    assert set(res["rows"]["pure"]) == set(METRIC_KEYS) and (out / "results.md").is_file()
    assert (out / "errors_cdf.png").stat().st_size > 1000
    assert res["uncertainty"]["n"] == 3 and len(res["uncertainty"]["rmse"]) == 6

    # the evaluate output feeds calibrate directly (factors.io files; the network block is carried). The
    # one-epoch model is confident about nothing: export every row, and a frame without rows is skipped
    from hybrid_calib.calib.result import CalibrationRun

    cal_argv = ["--data", str(sim_root), "--window", "3", "--no-plots", "--out"]
    assert _run_command("calibrate", ["--correspondences", str(out), *cal_argv, str(tmp_path / "c0")]) == 2
    assert "no usable frame" in capsys.readouterr().err
    assert _run_command("evaluate", ["--data", str(sim_root), "--checkpoint", str(run), "--out", str(tmp_path / "e0"),
                                     "--set", "export.min_confidence=0", "--no-progress"]) == 0
    assert _run_command("calibrate", ["--correspondences", str(tmp_path / "e0"), *cal_argv, str(tmp_path / "c1")]) == 0
    said = capsys.readouterr()
    assert "sim-veh-002" in said.out  # the test split's vehicle; the others are said to have no file in the export
    assert "2 vehicle(s) of the root have no measurement file" in said.err and "sim-veh-000" in said.err
    (veh,) = CalibrationRun.load(tmp_path / "c1" / "result.json").vehicles.values()
    assert veh.vehicle == "sim-veh-002" and veh.n_frames == 3 and len(veh.trajectory) == 3
    assert veh.network["n_frames"] == 3 and veh.network["std_cam"] is not None and veh.error is not None
    exported = json.loads((tmp_path / "e0" / "export_config.json").read_text())["eval"]["depth"]  # probe 142: the
    assert isinstance(exported, str) and veh.network["depth"] == exported  # report's attention figure reads it

    # fit the covariance scale on the val scene; it lands in the checkpoint and the next export uses it
    R2 = ("--range", "R2")  # the starts the run was trained on
    ckpt_json = run / "checkpoints" / "ckpt-0001.json"
    before = ckpt_json.read_bytes()
    assert _run_command("evaluate", [*R2, "--data", str(sim_root), "--checkpoint", str(run), "--split", "val",
                                     "--fit-uncertainty", "--out", str(tmp_path / "fit0"), "--no-progress"]) == 2
    assert "fewer than 30" in capsys.readouterr().err and ckpt_json.read_bytes() == before  # nothing written
    assert not (tmp_path / "fit0" / "results.json").exists()  # said before the frames ran (probe 117: after 74 s)
    # a scale for the starts it is used on (probe 55: R0 starts on an R1 network stored a scale 5-80x too small)
    assert _run_command("evaluate", ["--data", str(sim_root), "--checkpoint", str(run), "--split", "val",
                                     "--fit-uncertainty", "--out", str(tmp_path / "fitr"), "--no-progress"]) == 2
    assert "--range R1 on a checkpoint trained on R2 starts" in capsys.readouterr().err
    assert _run_command("evaluate", [*R2, "--data", str(sim_root), "--checkpoint", str(run), "--split", "all",
                                     "--fit-uncertainty", "--out", str(tmp_path / "fit1"), "--no-progress"]) == 2
    assert "a root the checkpoint was trained on" in capsys.readouterr().err
    # the checkpoint copied out of its run folder, or the root copied to another path: the same frames, refused as
    # well (probe 55: both fitted the scale on the training frames, with no note)
    import shutil

    flat, copy = tmp_path / "flat", tmp_path / "root-copy"
    flat.mkdir()
    for f in (run / "checkpoints").glob("ckpt-0001.*"):
        shutil.copy(f, flat / f.name)
    shutil.copytree(sim_root, copy)
    for data, ck in ((sim_root, flat / "ckpt-0001.json"), (copy, run)):
        assert _run_command("evaluate", [*R2, "--data", str(data), "--checkpoint", str(ck), "--split", "all",
                                         "--fit-uncertainty", "--out", str(tmp_path / "fitc"), "--no-progress"]) == 2
        assert "a root the checkpoint was trained on" in capsys.readouterr().err
    assert _run_command("evaluate", [*R2, "--data", str(sim_root), "--version", "v1.0-mini", "--checkpoint", str(run),
                                     "--split", "val", "--fit-uncertainty", "--out", str(tmp_path / "fit2")]) == 2
    assert "has no ground truth, only its tables" in capsys.readouterr().err  # a real root: the tables' errors
    from unittest import mock

    with mock.patch("hybrid_calib.commands.evaluate.os.access", lambda path, mode: False):  # a read-only checkpoint
        assert _run_command("evaluate", [*R2, "--data", str(sim_root), "--checkpoint", str(run), "--split", "val",
                                         "--fit-uncertainty", "--out", str(tmp_path / "fit3"), "--no-progress",
                                         "--set", "fit_min_frames=1"]) == 2
    assert "cannot be written" in capsys.readouterr().err and not (tmp_path / "fit3" / "results.json").exists()
    assert _run_command("evaluate", [*R2, "--data", str(sim_root), "--checkpoint", str(run), "--split", "val",
                                     "--fit-uncertainty", "--out", str(tmp_path / "fit"), "--no-progress",
                                     "--set", "fit_min_frames=1"]) == 0  # the tiny test drive: accepted when asked
    assert "fitted cov_scale" in capsys.readouterr().out
    fitted = json.loads(ckpt_json.read_text())["export"]["cov_scale"]
    assert len(fitted) == 6 and all(v > 0 for v in fitted)
    from learned.evaluate import tangent_errors

    xi, C = tangent_errors(tmp_path / "fit")
    np.testing.assert_allclose(fitted, np.mean(xi ** 2 / np.diagonal(C, axis1=1, axis2=2), axis=0))
    assert _run_command("evaluate", ["--data", str(sim_root), "--checkpoint", str(run), "--out",
                                     str(tmp_path / "scaled"), "--no-progress"]) == 0
    assert "no held-out measure" not in capsys.readouterr().err  # the test split: held out
    raw = {p.name: np.load(p)["cov"] for p in (out / "frames").glob("*.npz")}
    for p in (tmp_path / "scaled" / "frames").glob("*.npz"):
        np.testing.assert_allclose(np.diag(np.load(p)["cov"]), np.diag(raw[p.name]) * fitted, rtol=1e-6)
    assert _run_command("evaluate", [*R2, "--data", str(sim_root), "--checkpoint", str(run), "--fit-uncertainty",
                                     "--out", str(tmp_path / "e3")]) == 2
    assert "nothing held out" in capsys.readouterr().err
    # the frames it was trained on, evaluated: said, since the table then measures no held-out error
    assert _run_command("evaluate", ["--data", str(sim_root), "--checkpoint", str(run), "--split", "all",
                                     "--max-frames", "2", "--out", str(tmp_path / "e4"), "--no-progress"]) == 0
    assert "these frames include its training frames, so the table is no held-out measure" in capsys.readouterr().err
    for name in ("results.md", "results.json"):  # beside the figures too, not on the screen alone (probe 55)
        assert "these frames include its training frames" in (tmp_path / "e4" / name).read_text()
    # split flags other than the checkpoint's: its training frames in the "held-out" split (probe 55)
    assert _run_command("evaluate", [*R2, "--data", str(sim_root), "--checkpoint", str(run), "--split", "val",
                                     "--split-by", "time", "--gap-frames", "0", "--val-fraction", "0.34",
                                     "--test-fraction", "0.34", "--fit-uncertainty", "--set", "fit_min_frames=1",
                                     "--out", str(tmp_path / "fitt"), "--no-progress"]) == 2
    err = capsys.readouterr().err
    assert "--fit-uncertainty: " in err and "of the --split val frames the checkpoint was trained on" in err
    assert _run_command("evaluate", ["--data", str(sim_root), "--checkpoint", str(run), "--split", "val",
                                     "--split-by", "time", "--gap-frames", "0", "--val-fraction", "0.34",
                                     "--test-fraction", "0.34", "--max-frames", "2", "--out", str(tmp_path / "e5"),
                                     "--no-progress"]) == 0
    assert "the checkpoint was trained on (the split flags differ" in capsys.readouterr().err
    # a two-stage cascade (the same checkpoint twice): every stage's iterations are in the table
    assert _run_command("evaluate", ["--data", str(sim_root), "--checkpoint", str(run), "--refine", str(run),
                                     "--out", str(tmp_path / "cascade"), "--no-progress"]) == 0
    capsys.readouterr()
    rows = json.loads((tmp_path / "cascade" / "results.json").read_text())["rows"]
    assert [r for r in rows if "iter" in r] == [f"pure iter {k}" for k in range(1, 7)]
    assert _run_command("evaluate", [*R2, "--data", str(sim_root), "--checkpoint", str(run), "--refine", str(run),
                                     "--split", "val", "--fit-uncertainty", "--out", str(tmp_path / "e4")]) == 2
    assert "without --refine" in capsys.readouterr().err
    assert _run_command("evaluate", ["--data", str(sim_root), "--method", "hybrid-typo", "--checkpoint", str(run),
                                     "--out", str(tmp_path / "e2")]) == 2
    assert "unknown method 'hybrid-typo'" in capsys.readouterr().err


def test_evaluate_names_the_reason_when_every_frame_fails(frames, tmp_path):
    import dataclasses

    from learned.evaluate import EvalConfig, evaluate

    no_depth = [dataclasses.replace(f, depth_path=None) for f in frames[:2]]  # real data without an estimator
    with pytest.raises(HybridCalibError, match="ground-truth depth"):
        evaluate(OracleModel(), no_depth, EvalConfig(split="all"), tmp_path / "e", exporter=oracle_exporter,
                 progress=False)
    assert len(json.loads((tmp_path / "e" / "skipped.json").read_text())) == 2


def test_an_empty_split_says_how_to_split_in_time(frames, tmp_path):
    """The README's evaluate on a 3-vehicle simulated root always failed: its scenes (named by vehicle) hash into
    train; the error offered only --split all, which on a trained root evaluates training frames (probe 32)."""
    from learned.evaluate import EvalConfig, evaluate

    conf = EvalConfig(split="test", split_options=SplitConfig(test_fraction=0.0))
    with pytest.raises(HybridCalibError, match="no frames in split 'test'.*split.by=scene puts whole scenes .*"
                                               "--split-by time .*--set split.by=time"):
        evaluate(OracleModel(), frames, conf, tmp_path / "e", exporter=oracle_exporter, progress=False)
    assert not (tmp_path / "e").exists()  # refused before anything is written (probe 87: export_config.json stayed)
    # a held-out scene misspelt: every scene not listed trains, so nothing would be held out (probe 79)
    typo = EvalConfig(split="test", split_options=SplitConfig(test_groups=("no-such-scene",)))
    with pytest.raises(HybridCalibError, match=r"split.test_groups \['no-such-scene'\] names no scene of the data "
                                               r"\(its scenes: scene-0, scene-1, scene-2, scene-3\)"):
        evaluate(OracleModel(), frames, typo, tmp_path / "e", exporter=oracle_exporter, progress=False)
    with pytest.raises(HybridCalibError, match="names no scene"):  # train's split alike
        split_indices(frames, "train", SplitConfig(val_groups=("scene-9",)))
    with pytest.raises(HybridCalibError, match="no frames in split 'val'") as e:  # by time: nothing to add
        evaluate(OracleModel(), frames, EvalConfig(split="val", split_options=SplitConfig(by="time", val_fraction=0,
                                                                                         gap_frames=0)),
                 tmp_path / "e2", exporter=oracle_exporter, progress=False)
    assert "--split-by time" not in str(e.value)


def test_a_checkpoints_folder_that_cannot_be_written_is_said_before_any_epoch(frames, tmp_path, monkeypatch):
    """A read-only (immutable, as root) checkpoints/ trained the whole epoch, then ended in exit 3 (probe 33)."""
    from pathlib import Path

    from learned.train import train, train_config

    real = Path.write_bytes

    def refuse(self, data):
        if self.name.startswith(".write-test"):
            raise PermissionError(1, "Operation not permitted", str(self))
        return real(self, data)

    monkeypatch.setattr(Path, "write_bytes", refuse)
    with pytest.raises(HybridCalibError, match="checkpoints cannot be written \\(Operation not permitted\\): the "
                                               "checkpoints go there"):
        train(train_config("small", _train_conf(tmp_path, 1)), frames, tmp_path / "run", progress=False)
    assert not (tmp_path / "run" / "epochs.csv").exists()


def test_a_checkpoint_s_optimizer_file_is_the_same_bytes_for_the_same_state(tmp_path, monkeypatch):
    """Probe 90: torch.save named the zip's folder after the temporary file, whose name holds the writer's pid."""
    import hybrid_calib.atomic
    from learned.checkpoint import save_checkpoint

    torch.manual_seed(0)
    model = torch.nn.Linear(3, 2)
    optimizer = torch.optim.Adam(model.parameters())
    paths = []
    for pid, d in ((101, "a"), (202, "b")):  # two runs: two writers' pids
        monkeypatch.setattr(hybrid_calib.atomic.os, "getpid", lambda pid=pid: pid)
        paths.append(save_checkpoint(tmp_path / d / "ckpt-0001", model, epoch=1, model_config={"k": 1},
                                     optimizer=optimizer))
    a, b = (p.with_suffix(".optim.pt").read_bytes() for p in paths)
    assert a == b


def test_a_temporary_folder_too_long_for_the_workers_socket_is_said(frames, tmp_path, monkeypatch):
    """Probe 119: train --set num_workers=2 under a 130-character TMPDIR hung for ever, each worker printing "OSError:
    AF_UNIX path too long"; said before the run now, with what to do."""
    import tempfile

    from learned.train import train, train_config

    long = tmp_path / ("t" * 120)
    long.mkdir()
    monkeypatch.setattr(tempfile, "tempdir", str(long))
    conf = _train_conf(tmp_path, 1) | {"num_workers": 2}
    with pytest.raises(HybridCalibError, match=r"num_workers=2: the DataLoader workers' socket .* set TMPDIR to a "
                                               r"folder of at most 75 bytes, or --set num_workers=0"):
        train(train_config("small", conf), frames, tmp_path / "run", progress=False)
    assert not (tmp_path / "run" / "checkpoints").exists()


def test_an_evaluation_resumed_from_another_folder_is_the_same_run(sim_root, tmp_path, monkeypatch, capsys):
    """Probe 121: evaluate recorded --checkpoint as typed, so `--checkpoint ck.json`, then `../ck.json` from a
    sub-folder (the same file), was refused as "predictions made with another config"."""
    import shutil
    from pathlib import Path

    import learned

    work = tmp_path / "work"
    (work / "sub").mkdir(parents=True)
    for f in (Path(learned.__file__).parent / "checkpoints").glob("small-sim-r1.*"):
        shutil.copy(f, work / f.name)
    argv = ["--data", str(sim_root), "--split", "all", "--range", "R1", "--max-frames", "1", "--out",
            str(tmp_path / "ev"), "--no-progress"]
    monkeypatch.chdir(work)
    assert _run_command("evaluate", [*argv, "--checkpoint", "small-sim-r1.json"]) == 0
    monkeypatch.chdir(work / "sub")
    assert _run_command("evaluate", [*argv, "--checkpoint", "../small-sim-r1.json"]) == 0, capsys.readouterr().err


def test_a_root_rewritten_during_an_evaluation_or_a_training_epoch_is_said(frames, tmp_path, monkeypatch):
    """Calibrate refused a root another process rewrote under it (probe 142); evaluate tabled frames exported from the
    old and the new data, and train saved a checkpoint of an epoch that read both. Now the evaluation writes no
    table and the epoch no checkpoint (the earlier epochs' are kept), each naming the root."""
    import learned.train as train_mod
    from hybrid_calib.errors import DataError
    from learned.checkpoint import latest_checkpoint
    from learned.evaluate import EvalConfig, evaluate
    from learned.train import train, train_config

    root = tmp_path / "root"
    (root / "v1.0-sim").mkdir(parents=True)
    table = root / "v1.0-sim" / "sample_data.json"
    table.write_text("[]")
    data = {"roots": [str(root)], "version": "v1.0-sim"}

    def rewritten(*args, **kwargs):  # another process re-simulates the root while the frames are read
        table.write_text(table.read_text() + "\n")
        return oracle_exporter(*args, **kwargs)

    conf = EvalConfig(perturbation="R1", split="test", split_options=SplitConfig(test_groups=("scene-3",)),
                      max_radar_points=64, max_lidar_points=64, batch_size=2)
    assert evaluate(OracleModel(), frames, conf, tmp_path / "e0", exporter=oracle_exporter, progress=False,
                    data=data).n_frames == 3  # unchanged: as before
    with pytest.raises(DataError, match="changed while this run read it") as e:
        evaluate(OracleModel(), frames, conf, tmp_path / "e1", exporter=rewritten, progress=False, data=data)
    assert str(root) in str(e.value) and "--overwrite" in str(e.value)
    assert not (tmp_path / "e1" / "results.json").exists()

    validate, calls = train_mod.validate, []

    def validate_then_rewrite(*args, **kwargs):
        calls.append(1)
        if len(calls) == 2:  # during epoch 2
            table.write_text(table.read_text() + "\n")
        return validate(*args, **kwargs)

    monkeypatch.setattr(train_mod, "validate", validate_then_rewrite)
    run = tmp_path / "run"
    with pytest.raises(DataError, match="changed while epoch 2 read it") as e:
        train(train_config("small", _train_conf(tmp_path, 2)), frames, run, progress=False, source=data)
    assert "ckpt-0001.json, of the data the run began with, is kept" in str(e.value) and str(root) in str(e.value)
    assert latest_checkpoint(run / "checkpoints").name == "ckpt-0001.json"
