"""Radar model: PCD format, sparsity, weather, determinism, and geometry against the ground truth."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from hybrid_calib.data.frame import read_depth_png
from hybrid_calib.data.pcd import RADAR_FIELDS, read_radar_pcd
from hybrid_calib.geometry import pose_from_nuscenes, se3_inverse, transform_points
from hybrid_calib.sensors.camera import PinholeCamera
from hybrid_calib.sim.drive import SimConfig, VehicleDrive
from hybrid_calib.sim.radar import (
    CLUTTER,
    REAL,
    RadarConfig,
    detection_probability,
    in_field_of_view,
    snr_db,
)
from hybrid_calib.sim.simulate import radar_truth_file, simulate

FRAMES = 5


def small_conf(**kw) -> SimConfig:
    base = dict(scenario="urban", vehicles=1, frames=FRAMES, seed=3, image_scale=0.25)
    base.update(kw)
    return SimConfig(**base)


@pytest.fixture(scope="module")
def root(tmp_path_factory) -> Path:
    return simulate(small_conf(), tmp_path_factory.mktemp("radar_sim"), progress=False)


def load_tables(root: Path) -> dict[str, dict[str, dict]]:
    return {p.stem: {r["token"]: r for r in json.loads(p.read_text())} for p in (root / "v1.0-sim").glob("*.json")
            if p.stem != "sim_vehicle"}


def pairs(root: Path):
    """Per sample: camera and radar sample_data records and the table ground truth T_cam_radar."""
    t = load_tables(root)
    sensors = {s["token"]: s["channel"] for s in t["sensor"].values()}
    by_sample: dict[str, dict[str, dict]] = {}
    for sd in t["sample_data"].values():
        ch = sensors[t["calibrated_sensor"][sd["calibrated_sensor_token"]]["sensor_token"]]
        by_sample.setdefault(sd["sample_token"], {})[ch] = sd
    out = []
    for sample in by_sample.values():
        cam, rad = sample["CAM_FRONT"], sample["RADAR_FRONT"]

        def pose(rec):
            return pose_from_nuscenes(rec["rotation"], rec["translation"])

        cs_cam = t["calibrated_sensor"][cam["calibrated_sensor_token"]]
        cs_rad = t["calibrated_sensor"][rad["calibrated_sensor_token"]]
        T = (se3_inverse(pose(cs_cam)) @ se3_inverse(pose(t["ego_pose"][cam["ego_pose_token"]]))
             @ pose(t["ego_pose"][rad["ego_pose_token"]]) @ pose(cs_rad))
        K = np.array(cs_cam["camera_intrinsic"])
        out.append((cam, rad, T, PinholeCamera.from_K(K, cam["width"], cam["height"])))
    return out


def test_pcd_fields_z_zero_and_sparsity(root):
    files = sorted((root / "samples" / "RADAR_FRONT").glob("*.pcd"))
    assert len(files) == FRAMES
    for f in files:
        p = read_radar_pcd(f)
        assert p.dtype.names == tuple(n for n, _ in RADAR_FIELDS)
        assert np.all(p["z"] == 0.0)
        assert 10 <= len(p) <= 125, f"{f.name}: {len(p)} points"
        assert np.all(p["ambig_state"] == 3) and np.all(p["invalid_state"] == 0)
        assert np.all(p["is_quality_valid"] == 1)
        assert set(np.unique(p["dyn_prop"])) <= {0, 1, 2, 3}
        # 0.2 m quantisation of the written positions
        assert np.allclose(np.round(p["x"] / 0.2) * 0.2, p["x"], atol=1e-4)
        assert np.allclose(np.round(p["y"] / 0.2) * 0.2, p["y"], atol=1e-4)
        truth = np.load(radar_truth_file(root, f"samples/RADAR_FRONT/{f.name}"))
        assert truth["true_xyz"].shape == (len(p), 3) and truth["kind"].shape == (len(p),)
        assert truth["object_id"].dtype == np.int32 and truth["kind"].dtype == np.int8
        assert np.all(truth["object_id"][truth["kind"] == CLUTTER] == -1)


def test_deterministic_for_a_seed(root, tmp_path):
    again = simulate(small_conf(frames=2), tmp_path / "a", progress=False)
    other = simulate(small_conf(frames=2, seed=4), tmp_path / "b", progress=False)
    first = sorted((root / "samples" / "RADAR_FRONT").glob("*.pcd"))[:2]
    same = sorted((again / "samples" / "RADAR_FRONT").glob("*.pcd"))
    assert [f.name for f in first] == [f.name for f in same]
    for a, b in zip(first, same):
        assert a.read_bytes() == b.read_bytes()
    diff = sorted((other / "samples" / "RADAR_FRONT").glob("*.pcd"))
    assert read_radar_pcd(diff[0]).tobytes() != read_radar_pcd(first[0]).tobytes()


def test_points_lie_on_the_surfaces_they_came_from(root):
    errs, inside_total, real_total = [], 0, 0
    for cam, rad, T, camera in pairs(root):
        stem = Path(rad["filename"]).name
        truth = np.load(radar_truth_file(root, f"samples/RADAR_FRONT/{stem}"))
        depth = read_depth_png(root / "sim_depth" / "CAM_FRONT" / (Path(cam["filename"]).stem + ".png"))
        static_real = (truth["kind"] == REAL) & (truth["object_speed"] < 0.1)
        uv, z = camera.project(transform_points(T, truth["true_xyz"][static_real]))
        inside = camera.in_image(uv, margin=1.0) & (z > 0)
        real_total += static_real.sum()
        inside_total += inside.sum()
        px = np.round(uv[inside]).astype(int)
        errs.append(np.abs(depth[px[:, 1], px[:, 0]] - z[inside]))
    errs = np.concatenate(errs)
    assert inside_total >= 20, f"only {inside_total} of {real_total} static returns inside the image"
    # the camera looks from another place, so a few reflectors are hidden behind something else
    assert np.median(errs) < 0.1, np.median(errs)
    assert np.mean(errs < 0.3) > 0.75, np.mean(errs < 0.3)


def test_recorded_point_is_on_the_reflector_arc(root):
    conf = RadarConfig()
    for f in sorted((root / "samples" / "RADAR_FRONT").glob("*.pcd")):
        p = read_radar_pcd(f)
        truth = np.load(radar_truth_file(root, f"samples/RADAR_FRONT/{f.name}"))
        real = truth["kind"] == REAL
        xyz = truth["true_xyz"][real]
        r_true = np.linalg.norm(xyz, axis=1)
        az_true = np.arctan2(xyz[:, 1], xyz[:, 0])
        # the stored elevation is that of the true point on the arc
        np.testing.assert_allclose(np.sin(truth["elevation"][real]) * r_true, xyz[:, 2], atol=1e-9)
        r_meas = np.hypot(p["x"][real], p["y"][real])
        az_meas = np.arctan2(p["y"][real], p["x"][real])
        q = conf.position_quantisation_m
        assert np.all(np.abs(r_meas - r_true) < 5 * conf.range_noise_m + q)
        cross = r_true * np.abs(np.angle(np.exp(1j * (az_meas - az_true))))
        assert np.all(cross < 5 * r_true * np.deg2rad(conf.azimuth_noise_deg) + q)


def test_elevation_is_ambiguous(root):
    truths = [np.load(f) for f in (root / "sim_truth" / "RADAR_FRONT").glob("*.npz")]
    heights = np.concatenate([t["true_xyz"][t["kind"] == REAL, 2] for t in truths])
    assert heights.std() > 0.2, heights.std()
    assert (heights > 0.1).sum() >= 5 and (heights < -0.1).sum() >= 5
    assert np.ptp(heights) > 1.0


def test_rain_fewer_detections_more_clutter():
    counts = {}
    for name in ("urban", "rain"):
        drive = VehicleDrive(small_conf(scenario=name, frames=6), 0)
        sweeps = [drive.simulate_frame(k).radar for k in range(0, 6, 2)]
        counts[name] = (sum((s.kind == REAL).sum() for s in sweeps), sum((s.kind == CLUTTER).sum() for s in sweeps))
    assert counts["rain"][0] < counts["urban"][0], counts
    assert counts["rain"][1] > counts["urban"][1], counts


def test_straight_is_straight_and_empty():
    drive = VehicleDrive(small_conf(scenario="straight", frames=4), 0)
    assert np.allclose(drive.world.path.curvature, 0.0)
    classes = {o.cls for o in drive.world.objects}
    assert not classes & {"car", "van", "truck", "bus", "pedestrian", "building"}, classes
    sweep = drive.simulate_frame(1).radar
    real = sweep.kind == REAL
    assert real.sum() > 0
    assert {drive.world.object_cls[i] for i in sweep.object_id[real]} <= {"pole", "kerb"}


def test_radar_equation_and_fields_of_view():
    c = RadarConfig()
    r = np.array([10.0, 50.0, 150.0, 240.0])
    p = detection_probability(c, snr_db(c, np.full(4, 5.0), r, np.zeros(4)))
    assert np.all(np.diff(p) < 0) and p[0] > 0.9 and p[-1] < 0.3
    p_small = detection_probability(c, snr_db(c, np.full(4, -5.0), r, np.zeros(4)))
    assert np.all(p_small <= p)
    deg = np.deg2rad
    fov = in_field_of_view(c, np.array([50.0, 50.0, 100.0, 100.0, 260.0, 0.2]),
                           deg(np.array([55.0, 65.0, 5.0, 30.0, 0.0, 0.0])))
    assert fov.tolist() == [True, False, True, False, False, False]


def test_bad_inputs_are_named():
    from hybrid_calib.sim.radar import simulate_radar_sweep
    from hybrid_calib.sim.raycast import empty_primitives

    g = np.random.default_rng(0)
    with pytest.raises(ValueError, match="T_global_radar"):
        simulate_radar_sweep(empty_primitives(), np.eye(3), np.zeros(3), RadarConfig(), g)
    with pytest.raises(ValueError, match="radar_velocity"):
        simulate_radar_sweep(empty_primitives(), np.eye(4), np.array([np.nan, 0, 0]), RadarConfig(), g)
    # an empty world: clutter only, all in the radar plane
    sweep = simulate_radar_sweep(empty_primitives(), np.eye(4), np.zeros(3), RadarConfig(clutter_per_sweep=20), g)
    assert len(sweep) > 5 and np.all(sweep.kind == CLUTTER) and np.all(sweep.true_xyz[:, 2] == 0)


def test_the_cast_skips_only_rays_whose_hits_no_scan_could_use():
    """``cast_angular(reach=...)``: every hit inside the radar's near or far scan is the one of a full cast;
    primitives are skipped (fewer rays cast) only where a hit could not be a detection."""
    from hybrid_calib.sim.radar import ray_grid
    from hybrid_calib.sim.raycast import cast_angular

    d = VehicleDrive(small_conf(scenario="urban"), 0)
    conf = d.radar_config
    el, az = ray_grid(conf)
    reach = ((conf.near_range_m, np.deg2rad(conf.near_fov_deg)), (conf.far_range_m, np.deg2rad(conf.far_fov_deg)))
    for t in (0.5, 1.5, 2.5):
        T = d.ego.T_global_ego(t) @ d.T_ego_radar(0)
        prims = d.world.primitives_at(t, T[:3, 3], conf.far_range_m)
        full, _ = cast_angular(prims, T, el, az, conf.far_range_m)
        cut, _ = cast_angular(prims, T, el, az, conf.far_range_m, reach=reach)
        AZ = np.broadcast_to(az[None, :], full.t.shape)
        usable = in_field_of_view(conf, full.t, AZ) | in_field_of_view(conf, cut.t, AZ)
        assert usable.sum() > 100
        np.testing.assert_array_equal(cut.t[usable], full.t[usable])
        np.testing.assert_array_equal(cut.prim[usable], full.prim[usable])
        assert np.all(cut.t[~usable] >= full.t[~usable])  # a skipped surface only uncovers a farther one
        assert (cut.prim != full.prim).any()  # the far field outside +-9 deg was not cast
    with pytest.raises(ValueError, match="reach limits the azimuths"):
        cast_angular(prims, T, el, az, conf.far_range_m, wrap=True, reach=reach)
