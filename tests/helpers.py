"""Shared test helpers: seeded generators and dtype-aware tolerances."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from hybrid_calib.geometry import make_T, so3_exp

TOL = {np.dtype(np.float64): dict(rtol=1e-7, atol=1e-9), np.dtype(np.float32): dict(rtol=1e-4, atol=1e-5)}


def rng(seed: int = 0) -> np.random.Generator:
    """A seeded generator; every test uses its own seed so failures reproduce."""
    return np.random.default_rng(seed)


def assert_close(a, b, dtype=np.float64, scale: float = 1.0, err_msg: str = ""):
    """``np.testing.assert_allclose`` with tolerances chosen by dtype (multiplied by ``scale``)."""
    t = TOL[np.dtype(dtype)]
    np.testing.assert_allclose(a, b, rtol=t["rtol"] * scale, atol=t["atol"] * scale, err_msg=err_msg)


def random_pose(g: np.random.Generator, rot_scale: float = 1.0, trans_scale: float = 2.0) -> np.ndarray:
    """A random (4, 4) rigid transform."""
    return make_T(so3_exp(g.normal(size=3) * rot_scale), g.normal(size=3) * trans_scale)


# A nuScenes-like nominal extrinsic: RADAR_FRONT at the bumper, CAM_FRONT behind the windscreen.
def nominal_T_cam_radar() -> np.ndarray:
    from hybrid_calib.geometry import R_AXES_CAM_FROM_RADAR

    # radar 1.7 m ahead of and 1.0 m below the camera, centred: in camera axes (x right, y down, z fwd).
    return make_T(R_AXES_CAM_FROM_RADAR, np.array([0.0, 1.0, 1.7]))


# factor overrides for data drawn from the factor's own fixed elevation model (no per-drive scene
# structure): the scene nuisance (factors.scene) off, so covariances can be compared with the bound
NO_SCENE = {"scene_height_std_m": 0.0, "scene_lateral_slope_std": 0.0, "scene_height_sq_std_m2": 0.0}


def run_cli(argv: list, capsys) -> tuple[int, str]:
    """``hybrid-calib ARGV`` in-process -> (exit status, stderr); argparse errors exit via SystemExit.
    Asserts that no traceback reached stderr."""
    from hybrid_calib.cli import main

    try:
        rc = main([str(a) for a in argv])
    except SystemExit as e:
        rc = e.code
    err = capsys.readouterr().err
    assert "Traceback" not in err, err
    return rc, err


def expect_cli_error(argv: list, capsys, *needles, rc: int = 2) -> str:
    """Run ``argv`` (``run_cli``); assert the exit status ``rc`` and that stderr holds every needle."""
    got, err = run_cli(argv, capsys)
    assert got == rc, err
    for needle in needles:
        assert str(needle) in err, (needle, err)
    return err


def skips_of(tiny) -> list:
    """Every frame of a tiny root (the ``tiny`` fixture) loaded in turn: the skip records (any other exception
    fails the test)."""
    from hybrid_calib.data.nuscenes import NuScenesRadarCamera

    ds = NuScenesRadarCamera(tiny.root, tiny.version)
    list(ds)
    return ds.skipped


def network_start(root, version: str, camera_token: str, T: np.ndarray) -> np.ndarray:
    """(4, 4) the start the network is given for the mount estimate ``T`` on the frame of ``camera_token``: ``T N``
    (``hybrid.network.mount_pass``), the key of its pass in an ``OutputCache``."""
    from hybrid_calib.data.nuscenes import NuScenesRadarCamera

    ds = NuScenesRadarCamera(root, version)
    ref = next(r for r in ds.frames if r.camera_sd["token"] == camera_token)
    return np.asarray(T, np.float64) @ ds.radar_motion(ref)


def list_again_as_vehicle(tables: Path, vehicle: str) -> None:
    """Rewrite a root's tables (its version folder ``tables``) so that its first log's drive is listed again under
    ``vehicle``: a copied log, scenes, samples and sample_data ("-copy" tokens) on the same sensor files."""
    import json

    t = {n: json.loads((tables / f"{n}.json").read_text()) for n in ("log", "scene", "sample", "sample_data")}
    t["log"].append({**t["log"][0], "token": "log-copy", "vehicle": vehicle})
    t["scene"] += [{**s, "token": s["token"] + "-copy", "name": s["name"] + "-copy", "log_token": "log-copy",
                    "first_sample_token": s["first_sample_token"] + "-copy",
                    "last_sample_token": s["last_sample_token"] + "-copy"} for s in list(t["scene"])]
    t["sample"] += [{**s, "token": s["token"] + "-copy", "scene_token": s["scene_token"] + "-copy",
                     "prev": s["prev"] and s["prev"] + "-copy", "next": s["next"] and s["next"] + "-copy"}
                    for s in list(t["sample"])]
    t["sample_data"] += [{**sd, "token": sd["token"] + "-copy", "sample_token": sd["sample_token"] + "-copy",
                          "prev": sd["prev"] and sd["prev"] + "-copy", "next": sd["next"] and sd["next"] + "-copy"}
                         for sd in list(t["sample_data"])]
    for n, recs in t.items():
        (tables / f"{n}.json").write_text(json.dumps(recs))
