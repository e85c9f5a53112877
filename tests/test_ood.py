"""The network's out-of-domain score (learned.ood) and what the learned methods do with it
(hybrid.ood): a pure-noise frame is flagged and a clean simulated frame passes; too few in-domain
frames make a vehicle ``inconclusive`` end to end; a missing or malformed ``export.ood`` is handled."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from hybrid_calib.calib.covariance import inconclusive_status
from learned.ood import OODError, OODModel, fit_ood, frame_features, ood_model_of
from tests.test_learned_model import TINY, make_batch, tiny_model


def _features(model, batch) -> dict:
    with torch.no_grad():
        return frame_features(model(batch))


def test_density_model_flags_noise_and_passes_clean_synthetic_frames():
    model = tiny_model().eval()
    clean = [_features(model, make_batch(4, seed=s)) for s in range(8)]
    feats = {k: np.concatenate([f[k] for f in clean]) for k in ("descriptor", "signals")}
    assert feats["descriptor"].shape == (32, 2 * TINY["view_dim"]) and feats["signals"].shape == (32, 6)
    m = fit_ood(feats, "all", k=8, quantile=0.99)
    held = _features(model, make_batch(4, seed=100))
    noise = make_batch(4, seed=100)
    noise["image"] = torch.rand_like(noise["image"], generator=torch.Generator().manual_seed(0))
    assert np.all(m.score(held) < 1.0)
    assert np.all(m.score(_features(model, noise)) > 1.0)
    back = OODModel.from_dict(m.to_dict())  # the checkpoint's JSON round trip
    np.testing.assert_allclose(back.score(held), m.score(held))


@pytest.mark.parametrize("block, words", [
    ({"features": "all"}, "lacks"),
    ("garbage", "not an object"),
    ({"features": "all", "mean": [0.0], "std": [0.0], "components": [[1.0]], "variances": [1.0],
      "residual_mean": 1.0, "threshold": 1.0}, "non-positive"),
    ({"features": "pixels", "mean": [0.0], "std": [1.0], "components": [[1.0]], "variances": [1.0],
      "residual_mean": 1.0, "threshold": 1.0}, "unknown"),
    # a threshold that passes every frame, directions that are not directions: accepted without a word (probe 27)
    ({"features": "signals", "mean": [0.0], "std": [1.0], "components": [[1.0]], "variances": [1.0],
      "residual_mean": 1.0, "threshold": 1e308}, "would pass every frame"),
    ({"features": "signals", "mean": [0.0, 0.0], "std": [1.0, 1.0], "components": [[0.0, 0.0]], "variances": [1.0],
      "residual_mean": 1.0, "threshold": 1.0}, "not orthonormal"),
])
def test_malformed_ood_block_is_a_clear_error(block, words):
    with pytest.raises(OODError, match=words) as e:
        ood_model_of({"ood": block}, "ck.json")
    assert "ck.json" in str(e.value) and "ood_fit.py" in str(e.value)


def test_missing_ood_block_says_the_score_is_unavailable():
    m, note = ood_model_of({"cov_scale": 1.0}, "old.json")
    assert m is None and "unavailable" in note and "old.json" in note


def test_decision_counts_in_domain_frames():
    from hybrid_calib.hybrid.ood import OODPolicy, decide

    pol = OODPolicy(threshold=1.0, min_in_domain_fraction=0.5, min_in_domain_frames=3)
    assert decide([0.2, 0.5, 0.9, 3.0], pol)["inconclusive"] == ""
    d = decide([0.2, 5.0, 4.0, 3.0], pol)
    assert d["in_domain"] == 1 and "only 1 of 4 frames" in d["inconclusive"]
    assert "calibrate on more frames" in decide([0.1, 0.2], pol)["inconclusive"]  # fewer than 3 frames in all: said
    assert "only 1 of 2 frames" in decide([0.1, 9.0], pol)["inconclusive"]
    d = decide([float("nan")] * 3, pol, "no export.ood")
    assert not d["available"] and d["inconclusive"] == "" and d["note"] == "no export.ood"
    assert inconclusive_status("why", "ok").startswith("inconclusive: why")
    # frames that did not read count as not in domain: 4 of 5 read frames in domain is not 4 of 10 (probe 15)
    pol = OODPolicy(threshold=1.0, min_in_domain_fraction=0.8, min_in_domain_frames=3)
    assert decide([0.1, 0.2, 0.3, 0.4, 9.0], pol)["inconclusive"] == ""
    d = decide([0.1, 0.2, 0.3, 0.4, 9.0], pol, unread=5)
    assert d["unread"] == 5 and "only 4 of 10 frames" in d["inconclusive"] and "5 of them did not read" in \
        d["inconclusive"]
    assert "calibrate on more frames" not in decide([0.1, 0.2], pol, unread=3)["inconclusive"]


# ---------------------------------------------------------------------------------- on a simulated drive


@pytest.fixture(scope="module")
def sim_root(tmp_path_factory):
    """2 vehicles x 3 keyframes, 200 x 112 images."""
    from hybrid_calib.sim.drive import SimConfig
    from hybrid_calib.sim.simulate import simulate

    return simulate(SimConfig(vehicles=2, frames=3, image_scale=0.125, seed=5), tmp_path_factory.mktemp("sim"),
                    progress=False)


@pytest.fixture(scope="module")
def fitted(sim_root, tmp_path_factory):
    """A tiny untrained network as a checkpoint, its OOD model fitted on the clean frames of the drive
    (several starts per frame) and stored in its export block; returns (checkpoint, runner, drives)."""
    from hybrid_calib.config import to_dict
    from hybrid_calib.hybrid.drives import open_drives
    from hybrid_calib.hybrid.loop import HybridConfig
    from hybrid_calib.hybrid.network import NetworkRunner
    from hybrid_calib.hybrid.ood import ood_passes
    from learned.checkpoint import save_checkpoint, set_export_overrides

    model = tiny_model()
    d = tmp_path_factory.mktemp("ck")
    ck = save_checkpoint(d / "ckpt-0001", model, epoch=1, model_config=to_dict(model.cfg),
                         train_config={"perturbation": "R1", "depth": "corrupted-truth"})
    frames, drives = open_drives(sim_root, "v1.0-sim", HybridConfig(), lidar=False)
    runner = NetworkRunner(ck, frames, cache_dir=d / "cache", threads=1)
    assert runner.ood is None and "unavailable" in runner.ood_note
    recs = [r for v in drives.values() for s in range(4) for r in ood_passes(runner, v.indices, v.base, "R1", s,
                                                                             v.vehicle)]
    feats = {k: np.stack([r[k] for r in recs]) for k in ("descriptor", "signals")}
    set_export_overrides(ck, {"ood": fit_ood(feats, "all", k=8, quantile=1.0).to_dict(),
                              # stand-ins for the fitted covariance and measurement models (without them a
                              # learned result is inconclusive for that reason: test_hybrid)
                              "cov_scale": [1.0] * 6, "hybrid": {
                                  "rows": "none", "sigma_scale": 1.0, "shared_std": [0.0] * 6,
                                  "prior_cov_scale": [1.0] * 6, "drive_std": [0.0] * 6}}, "fitted by the test")
    return ck, NetworkRunner(ck, frames, cache_dir=d / "cache", threads=1), drives


def test_score_flags_a_pure_noise_frame_and_passes_a_clean_simulated_frame(fitted):
    from hybrid_calib.hybrid.ood import ood_passes

    _, runner, drives = fitted
    v = drives["sim-veh-000"]
    clean = ood_passes(runner, v.indices, v.base, "R1", 50, v.vehicle)  # new starts on the drive's frames
    noise = ood_passes(runner, v.indices, v.base, "R1", 50, v.vehicle, corruption="noise-image")
    assert max(r["score"] for r in clean) < 1.0
    assert min(r["score"] for r in noise) > 1.0


BASE = {"start": "R1", "seed": 4, "threads": 1, "progress": False, "window": {"detect_steps": False}}


@pytest.mark.parametrize("method", ["pure", "pure-avg", "hybrid"])
def test_too_few_in_domain_frames_make_the_vehicle_inconclusive(fitted, sim_root, tmp_path, method):
    from hybrid_calib.calib.result import CalibrationRun
    from hybrid_calib.hybrid import run_calibration
    from hybrid_calib.report.verdict import verdict_of

    ck = fitted[0]
    conf = {**BASE, "method": method, "checkpoint": str(ck), "vehicles": ("sim-veh-000",)}
    ok = run_calibration(sim_root, "v1.0-sim", tmp_path / "in", {**conf, "ood": {"min_in_domain_frames": 2}})
    v = ok.vehicles["sim-veh-000"]
    assert v.ood["available"] and v.ood["in_domain"] == 3 and not v.final.status.startswith("inconclusive")
    assert all(r["ood_score"] < 1.0 for r in v.frame_rows) and "out-of-domain test is off" not in v.final.status
    # the test switched off: the status says nothing checked the input (probe 23: the real scene then read "weak"
    # with a yaw 1-sigma 4 sigmas off its tables)
    off = run_calibration(sim_root, "v1.0-sim", tmp_path / "off", {**conf, "ood": {"enabled": False}})
    assert "the out-of-domain test is off (ood.enabled=false)" in off.vehicles["sim-veh-000"].final.status
    # the same drive judged against a threshold no frame meets: every frame is out of domain
    run = run_calibration(sim_root, "v1.0-sim", tmp_path / "out", {**conf, "ood": {"threshold": 1e-6}})
    v = CalibrationRun.load(tmp_path / "out" / "result.json").vehicles["sim-veh-000"]
    assert v.final.status.startswith("inconclusive: only 0 of 3 frames")
    assert v.ood["in_domain"] == 0 and v.ood["dropped"] == 0 and len(v.trajectory) == 3  # every frame, none dropped
    # the every-frame rerun's scores (frame_rows) are counted apart from the deciding pass's (ood.scores)
    assert v.ood["rerun_in_domain"] == sum(r["ood_score"] <= 1e-6 for r in v.frame_rows) == 0
    assert "on that every-frame pass 0 of 3 frames scored in domain" in v.ood["note"]
    assert v.trajectory[-1].estimate.status == v.final.status == run.vehicles["sim-veh-000"].final.status
    verdict = verdict_of(v)
    assert verdict.word == "cannot tell" and "only 0 of 3 frames" in verdict.why


@pytest.mark.parametrize("method", ["pure-avg", "hybrid"])
def test_an_inconclusive_vehicle_keeps_to_its_in_domain_frames_while_there_are_enough(fitted, sim_root, tmp_path,
                                                                                       method):
    """Probe 44: a randomised highway drive with 44 of 60 frames in domain ran on every frame; its out-of-domain
    stretch raised a false step alarm and it ended 3.2 deg off in yaw, NEES 41 (0.37 deg, NEES 6.9 on the 44)."""
    from hybrid_calib.hybrid import run_calibration

    ck = fitted[0]
    conf = {**BASE, "method": method, "checkpoint": str(ck), "vehicles": ("sim-veh-000",)}
    scores = sorted(r["ood_score"] for r in run_calibration(sim_root, "v1.0-sim", tmp_path / "all-in", {
        **conf, "ood": {"min_in_domain_frames": 2}}).vehicles["sim-veh-000"].frame_rows)
    policy = {"threshold": 0.5 * (scores[1] + scores[2]), "min_in_domain_frames": 2}  # 2 of 3 in domain (< 80 %)
    v = run_calibration(sim_root, "v1.0-sim", tmp_path / "in", {**conf, "ood": policy}).vehicles["sim-veh-000"]
    assert v.final.status.startswith("inconclusive: only 2 of 3 frames"), v.final.status
    assert v.ood["dropped"] == 1 and len(v.trajectory) == 2
    # the frames the last pass used (probe 47: "uses those 21" on a rerun pass that used 24 and dropped 17); whose
    # count is whose (probe 52: "22 of 41" of the first pass beside the last pass's "18 used, 23 dropped"): the hybrid
    # reruns its drive with the drive error counted over its 2 priors
    last = "last " if method == "hybrid" else ""
    assert f"too few frames in domain (2 of 3 on the first pass, the scores above): the estimate uses the 2 frame(s) " \
           f"its {last}pass scored in domain (1 dropped" in v.ood["note"], v.ood["note"]
    assert ("a pass that starts from another estimate scores the frames differently" in v.ood["note"]) == bool(last)
    assert [s for s in v.skipped if "ood_score" in s]
    every = run_calibration(sim_root, "v1.0-sim", tmp_path / "every", {**conf, "ood": {
        **policy, "inconclusive_frames": "all"}}).vehicles["sim-veh-000"]
    assert every.ood["dropped"] == 0 and len(every.trajectory) == 3 and every.final.status.startswith("inconclusive")
    with pytest.raises(ValueError, match="inconclusive_frames"):
        from hybrid_calib.hybrid.ood import OODPolicy

        OODPolicy(inconclusive_frames="some")


def test_out_of_domain_frames_are_dropped_with_the_reason(fitted, sim_root, tmp_path):
    from hybrid_calib.hybrid import run_vehicle

    ck, runner, _ = fitted
    conf = {**BASE, "method": "pure", "checkpoint": str(ck), "cache_dir": str(tmp_path / "c")}
    v = run_vehicle(sim_root, "v1.0-sim", "sim-veh-001", conf)
    scores = v.ood["scores"]
    thr = float(np.median(scores))  # half the frames above it: one dropped, two kept (in domain)
    policy = {"threshold": thr, "min_in_domain_frames": 1, "min_in_domain_fraction": 0.5}
    v = run_vehicle(sim_root, "v1.0-sim", "sim-veh-001", {**conf, "ood": policy})
    dropped = [s for s in v.skipped if "ood_score" in s]
    assert len(dropped) == v.ood["dropped"] == sum(s > thr for s in scores) >= 1
    assert all("out of domain" in s["reason"] for s in dropped) and len(v.trajectory) == 3 - len(dropped)
    assert not v.final.status.startswith("inconclusive")
    # the kept frames keep their drive positions: a dropped frame leaves a gap (step alarms, plots, reports)
    kept = [k for k, s in enumerate(scores) if s <= thr]
    assert [f.index for f in v.trajectory] == kept


def test_the_image_test_measures_a_scene_and_not_noise(sim_root):
    import cv2

    from learned.ood import MIN_IMAGE_STRUCTURE, image_score, image_structure, image_words

    frames = sorted((sim_root / "samples" / "CAM_FRONT").glob("*.jpg"))
    scene = [image_structure(cv2.resize(cv2.imread(str(f)), (200, 96), interpolation=cv2.INTER_AREA)) for f in frames]
    g = np.random.default_rng(0)
    noise = [image_structure(g.uniform(0, 1, (3, 96, 200))), image_structure(g.integers(0, 256, (96, 200, 3)))]
    assert min(scene) > 0.8 and max(np.abs(noise)) < 0.1
    assert image_structure(np.zeros((3, 96, 200))) == image_structure(np.full((96, 200, 3), 7)) == 0.0
    assert image_score(min(scene)) == 0.0 and image_words(min(scene)) == ""
    assert image_score(0.02) == MIN_IMAGE_STRUCTURE / 0.02 and image_score(0.0) > 100 and image_score(np.nan) == 0.0
    assert "shows no scene" in image_words(0.02) and "0.02" in image_words(0.02)
    # probe 89: 0.4952 read "0.50, under 0.5"; a checkerboard's -0.925 read "0.00"
    assert "correlate 0.495, under 0.5" in image_words(0.4952) and "correlate -0.925" in image_words(-0.925)


def test_a_noise_image_is_out_of_domain_whatever_the_density_model_says(fitted):
    """Probe 87: on the shipped network's pure-avg pass 2 of 16 pure-noise images scored 0.77 and 0.87 by the density
    model alone and were fused into a trusted result: the camera image's own test raises the score."""
    import dataclasses

    _, runner, drives = fitted
    v = drives["sim-veh-000"]
    clean = runner.run(v.indices[0], v.base)
    assert runner.ood_score(clean) < 1.0 and clean.image_structure > 0.8 and runner.ood_cause(clean)[1] == ""
    noise = dataclasses.replace(clean, image_structure=0.02)  # the same features, a noise image's structure
    assert runner.ood_score(noise) > 1.0 and "shows no scene" in runner.ood_cause(noise)[1]
    # a pass the density model scores out of domain by more than its image test: the general reason, not the image's
    # (probe 89: a dark view of a road, 4.15 by the density, 1.11 by its image, was said to show no scene)
    far = dataclasses.replace(clean, ood_descriptor=clean.ood_descriptor + 50.0, image_structure=0.45)
    assert runner.ood_score(far) > 1.2 and runner.ood_cause(far)[1] == ""


def test_a_camera_file_compressed_beyond_the_training_range_is_out_of_domain(fitted, sim_root, tmp_path):
    """Probe 116: camera images saved at JPEG quality 2 passed the density model and the image test on every frame,
    and the hybrid read 4.4-5.7 deg of yaw that was not there under a `weak` status. The file's quality (its
    quantisation table) is the third test: under 30 (trained on 55-95; nuScenes' cameras ~80) a frame is out of
    domain, said so."""
    import dataclasses

    import cv2

    from hybrid_calib.data.image_header import jpeg_quality
    from learned.ood import MIN_JPEG_QUALITY, jpeg_score, jpeg_words

    image = cv2.imread(str(sorted((sim_root / "samples" / "CAM_FRONT").glob("*.jpg"))[0]))
    for q, lo, hi in ((92, 91, 93), (55, 54, 56), (30, 29, 31), (2, 1, 15)):
        cv2.imwrite(str(tmp_path / f"q{q}.jpg"), image, [cv2.IMWRITE_JPEG_QUALITY, q])
        assert lo <= jpeg_quality(tmp_path / f"q{q}.jpg") <= hi, q
    cv2.imwrite(str(tmp_path / "p.png"), image)
    assert jpeg_quality(tmp_path / "p.png") is None and jpeg_quality(tmp_path / "none.jpg") is None
    assert jpeg_score(80.0) == jpeg_score(np.nan) == 0.0 and jpeg_words(80.0) == ""
    assert jpeg_score(11.3) == MIN_JPEG_QUALITY / 11.3 and "JPEG quality ~11, under 30" in jpeg_words(11.3)
    _, runner, drives = fitted
    v = drives["sim-veh-000"]
    clean = runner.run(v.indices[0], v.base)
    assert 85 < clean.jpeg_quality < 95 and runner.ood_score(clean) < 1.0 and runner.ood_cause(clean)[1] == ""
    squeezed = dataclasses.replace(clean, jpeg_quality=11.3)  # the same features, a quality-2 file
    assert runner.ood_score(squeezed) > 1.0 and "lost to compression" in runner.ood_cause(squeezed)[1]


def test_a_frame_whose_image_is_noise_is_dropped_naming_the_image(fitted, sim_root, tmp_path):
    import shutil

    import cv2

    from hybrid_calib.hybrid import run_vehicle

    root = tmp_path / "root"
    shutil.copytree(sim_root, root)
    images = sorted((root / "samples" / "CAM_FRONT").glob("*sim-veh-001*.jpg")) or \
        sorted((root / "samples" / "CAM_FRONT").glob("*.jpg"))
    im = cv2.imread(str(images[0]))
    cv2.imwrite(str(images[0]), np.random.default_rng(1).integers(0, 256, im.shape, dtype=np.uint8))
    conf = {**BASE, "method": "pure-avg", "checkpoint": str(fitted[0]), "ood": {"min_in_domain_frames": 1,
                                                                                "min_in_domain_fraction": 0.5}}
    runs = [run_vehicle(root, "v1.0-sim", name, conf) for name in ("sim-veh-000", "sim-veh-001")]
    dropped = [s for v in runs for s in v.skipped if "ood_score" in s]
    assert len(dropped) == 1 and "the camera image shows no scene" in dropped[0]["reason"], dropped
    assert dropped[0]["ood_score"] > 2  # 0.5 / structure: a JPEG of noise at 200 x 112 keeps ~0.1


def test_an_image_darker_or_brighter_than_the_training_images_is_named_as_the_cause():
    """Words only: the density model's score decides; the image test's and the file's own test keep their words where
    they score at or above it, and an image outside the training images' brightness names itself otherwise."""
    from learned.ood import BRIGHT_LUMINANCE, DARK_LUMINANCE, image_cause, image_luminance, luminance_words

    assert image_luminance(np.full((96, 200, 3), 51, np.uint8)) == pytest.approx(0.2)
    assert image_luminance(np.full((3, 96, 200), 0.5)) == 0.5 and np.isnan(image_luminance(np.zeros((3, 0, 0))))
    assert luminance_words(0.45) == luminance_words(np.nan) == ("", "")
    assert luminance_words(DARK_LUMINANCE) == luminance_words(BRIGHT_LUMINANCE) == ("", "")
    cause, words = luminance_words(0.06)
    assert cause == "dark" and "mean grey level 0.06 is under 0.2" in words and "night" in words
    cause, words = luminance_words(0.93)
    assert cause == "bright" and "washed out" in words and "over 0.8" in words
    # the density model decides (score 3): the dark image's words; the image test above it (0.5 / 0.1 = 5): its own
    assert image_cause(3.0, 0.9, 80.0, 0.06)[0] == "dark" and image_cause(3.0, 0.9, 80.0, 0.45) == ("", "")
    assert image_cause(3.0, 0.1, 80.0, 0.06)[0] == "no scene" and image_cause(3.0, 0.9, 5.0, 0.06)[0] == "compression"


def test_a_drive_of_dark_images_is_inconclusive_and_says_they_are_dark(fitted, sim_root, tmp_path):
    """Session 47's known item (and probe 89): a drive whose camera saw night was `inconclusive` naming only its
    scores ("only 0 of 4 frames are inside the network's training domain"), with no word of its darkness; each dropped
    frame read "the input is unlike the frames the network was fitted on"."""
    import shutil

    import cv2

    from hybrid_calib.hybrid import run_vehicle
    from hybrid_calib.hybrid.ood import OODPolicy, decide

    root = tmp_path / "root"
    shutil.copytree(sim_root, root)
    images = sorted((root / "samples" / "CAM_FRONT").glob("*sim-veh-001*.jpg"))
    assert images
    for f in images:
        cv2.imwrite(str(f), (cv2.imread(str(f)) * 0.08).astype(np.uint8))
    conf = {**BASE, "method": "pure-avg", "checkpoint": str(fitted[0])}
    v = run_vehicle(root, "v1.0-sim", "sim-veh-001", conf)
    dark = v.ood["causes"].get("dark", 0)
    assert dark >= 0.75 * len(images) and v.ood["in_domain"] < len(images) / 2, v.ood
    assert v.final.status.startswith("inconclusive:") and f"{dark} are dark (night" in v.final.status, v.final.status
    # one dark frame among clean ones: dropped, naming its darkness
    for f in images[1:]:
        shutil.copy(sim_root / "samples" / "CAM_FRONT" / f.name, f)
    v = run_vehicle(root, "v1.0-sim", "sim-veh-001", {**conf, "ood": {"min_in_domain_frames": 1,
                                                                      "min_in_domain_fraction": 0.5}})
    said = [s["reason"] for s in v.skipped if "ood_score" in s]
    assert len(said) == 1 and "the camera image is dark: its mean grey level 0.0" in said[0], said
    # the words name the causes they count, most frequent first; none named where none is seen
    block = decide([3.0, 4.0, 0.5, 2.0], OODPolicy(min_in_domain_frames=3), causes={"bright": 1, "dark": 2})
    assert "of the 3 frames out of domain, 2 are dark" in block["inconclusive"]
    assert block["inconclusive"].endswith("1 are washed out (glare, or an over-exposed camera)")
    assert "frames out of domain," not in decide([3.0, 4.0], OODPolicy(min_in_domain_frames=3))["inconclusive"]


def test_checkpoint_without_ood_block_keeps_working_and_says_so(sim_root, tmp_path):
    from hybrid_calib.config import to_dict
    from hybrid_calib.hybrid import run_vehicle
    from learned.checkpoint import save_checkpoint, set_export_overrides

    model = tiny_model()
    ck = save_checkpoint(tmp_path / "ckpt-0001", model, epoch=1, model_config=to_dict(model.cfg),
                         train_config={"perturbation": "R1", "depth": "corrupted-truth"})
    set_export_overrides(ck, {"cov_scale": [1.0] * 6}, "a stand-in for the fitted covariance scale")
    v = run_vehicle(sim_root, "v1.0-sim", "sim-veh-000", {**BASE, "method": "pure", "max_frames": 2,
                                                          "checkpoint": str(ck)})
    assert not v.ood["available"] and "unavailable" in v.ood["note"] and "no export.ood" in v.ood["note"]
    assert v.ood["dropped"] == 0 and len(v.trajectory) == 2 and all(r["ood_score"] is None for r in v.frame_rows)
    # every frame used, and the status says why the covariance is not to be trusted (probe 105: it read 'weak')
    assert v.final.status.startswith("inconclusive:") and "export.ood" in v.final.status, v.final.status


def test_malformed_ood_block_in_a_checkpoint_stops_with_the_file_named(fitted, sim_root, tmp_path, capsys):
    import shutil

    from hybrid_calib.cli import main
    from learned.checkpoint import set_export_overrides

    ck = fitted[0]
    bad = tmp_path / "ckpt-0001.json"
    shutil.copy(ck, bad)
    shutil.copy(ck.with_suffix(".safetensors"), tmp_path / "ckpt-0001.safetensors")
    set_export_overrides(bad, {"ood": {"features": "all", "mean": "x"}})
    rc = main(["calibrate", "--data", str(sim_root), "--version", "v1.0-sim", "--method", "pure", "--checkpoint",
               str(bad), "--start", "R1", "--out", str(tmp_path / "o"), "--set", "threads=1", "max_frames=1"])
    err = capsys.readouterr().err
    assert rc != 0 and str(bad) in err and "export.ood" in err and "Traceback" not in err


def test_a_frame_off_the_fitted_subspace_is_out_of_domain():
    """The density has two terms: the principal directions and the residual off them. A frame whose features leave
    the subspace the in-domain frames span (not far along any principal direction) is out of domain; one 1 sigma
    along a principal direction is not (a mutation probe found the residual term unpinned)."""
    g = np.random.default_rng(0)
    X = g.normal(size=(400, 2)) @ g.normal(size=(2, 8)) + 1e-3 * g.normal(size=(400, 8))
    m = fit_ood({"descriptor": X, "signals": np.zeros((400, 1))}, features="descriptor", k=2)
    u = np.linalg.svd(m.components)[2][-1]  # a unit direction orthogonal to both components (standardised units)
    off = m.mean + m.std * 10 * u
    along = m.mean + m.std * m.components[0] * np.sqrt(m.variances[0])
    s = m.score({"descriptor": np.stack([off, along]), "signals": np.zeros((2, 1))})
    assert s[0] > 1 and s[1] < 1, s
    # the residual is measured in units of the in-domain frames' own (probe 73: the raw residual, small beside the
    # principal terms, survived): 30 times their residual's rms off the subspace is out of domain, however small
    slightly_off = m.mean + m.std * 30 * np.sqrt(m.residual_mean) * u
    assert m.score({"descriptor": slightly_off[None], "signals": np.zeros((1, 1))})[0] > 1


def test_the_in_domain_count_needed_rounds_up():
    """``min_in_domain_fraction`` of the frames, rounded up: 4 of 6 in domain is 67 %, short of 80 % (5 needed)."""
    from hybrid_calib.hybrid.ood import OODPolicy, decide

    block = decide([0.1] * 4 + [9.0] * 2, OODPolicy(min_in_domain_fraction=0.8, min_in_domain_frames=3))
    assert block["in_domain"] == 4 and block["inconclusive"].startswith("only 4 of 6 frames"), block
    assert "fewer than the 5 required" in block["inconclusive"]
    assert decide([0.1] * 5 + [9.0], OODPolicy(min_in_domain_fraction=0.8, min_in_domain_frames=3))["inconclusive"] \
        == ""


# ---- tests the mutation probe (probe 25) found missing: each fails under its mutant

def test_unread_frames_count_against_the_domain_not_the_drive():
    from hybrid_calib.hybrid.ood import OODPolicy, decide
    why = decide([0.1, 0.1], OODPolicy(threshold=1.0, min_in_domain_frames=5), unread=1)["inconclusive"]
    assert why.startswith("only 2 of 3 frames") and "1 of them did not read" in why


def test_an_unreadable_frame_is_counted_and_recorded_by_its_drive_position():
    from types import SimpleNamespace

    from hybrid_calib.hybrid.loop import _Trace
    tr = _Trace()
    tr.unreadable(SimpleNamespace(token=lambda i: "t", bad_reason=lambda i: "bad"), 7, 1)
    assert tr.unread == 1 and tr.skipped == [{"index": 1, "token": "t", "reason": "bad"}]


def test_a_frozen_camera_frame_is_left_out_and_counted_against_the_domain(fitted, sim_root, tmp_path):
    """Probe 89: a frame whose image was the previous frame's, byte for byte, scored in domain and was fused as a view
    of its own moment."""
    import shutil

    from hybrid_calib.data.nuscenes import NuScenesRadarCamera
    from hybrid_calib.hybrid import run_vehicle
    from hybrid_calib.hybrid.drives import frozen_images

    root = tmp_path / "root"
    shutil.copytree(sim_root, root)
    ds = NuScenesRadarCamera(root, "v1.0-sim", conf={"check_images": False, "vehicles": ("sim-veh-000",)})
    idx = ds.frames_by_vehicle()["sim-veh-000"]
    files = ds.camera_files(idx)
    assert frozen_images(ds, idx, {}) == {}  # a drive's own images all differ
    shutil.copy(files[0], files[2])  # frame 2's camera repeats frame 0's image
    frozen = frozen_images(ds, idx, {})
    assert list(frozen) == [idx[2]] and frozen[idx[2]]["frozen"] == 0 and frozen[idx[2]]["index"] == 2
    assert "byte for byte frame 0's" in frozen[idx[2]]["reason"]
    assert frozen_images(ds, idx, {idx[2]: {}}) == {}  # a repeated view (the ego stood still) is not compared
    conf = {**BASE, "method": "pure-avg", "checkpoint": str(fitted[0]), "ood": {"min_in_domain_frames": 1,
                                                                                "min_in_domain_fraction": 0.5}}
    v = run_vehicle(root, "v1.0-sim", "sim-veh-000", conf)
    assert [s["index"] for s in v.skipped if "frozen" in s] == [2] and v.ood["frozen"] == 1
    assert [f.index for f in v.trajectory] == [0, 1]
    strict = run_vehicle(root, "v1.0-sim", "sim-veh-000", {**conf, "ood": {"min_in_domain_fraction": 1.0,
                                                                          "min_in_domain_frames": 1}})
    assert "1 of them repeat an earlier frame's camera image (a frozen camera)" in strict.final.status


def test_the_dropped_count_names_its_pass_where_the_status_counts_another():
    """Probe 92: "only 21 of 41 frames are inside" beside "21 frame(s) dropped" (21 + 21 of 41): the estimate's last
    pass, from other starts, dropped 21."""
    from types import SimpleNamespace

    from hybrid_calib.commands.calibrate import _pass_words

    assert _pass_words(SimpleNamespace(ood={"in_domain": 21, "frames": 41, "unread": 0}), 20) == ""
    assert "by the pass the estimate used" in _pass_words(SimpleNamespace(ood={"in_domain": 21, "frames": 41}), 21)
    assert _pass_words(SimpleNamespace(ood={"in_domain": 3, "frames": 4, "unread": 2}), 1) == ""
    assert _pass_words(SimpleNamespace(ood=None), 2) == ""


def test_hybrid_rows_other_than_the_fitted_ones_are_not_trusted(fitted, sim_root):
    """Probe 117: --set measurement.rows=last (calibrate's --help example) put the forward offset 6-27 m off with a
    0.2-0.6 m std, and only the 2 m guard said a word, blaming the tables first. The checkpoint's measurement model is
    fitted for its rows; other rows are named and the result is not trusted."""
    from hybrid_calib.hybrid import run_vehicle

    conf = {**BASE, "method": "hybrid", "checkpoint": str(fitted[0]), "max_frames": 3, "motion": {"enabled": False},
            "ood": {"min_in_domain_frames": 1}}
    from hybrid_calib.hybrid.loop import HybridConfig, other_rows_reason

    v = run_vehicle(sim_root, "v1.0-sim", "sim-veh-000", {**conf, "measurement": {"rows": "first"}})
    assert v.final.status.startswith("inconclusive:") and "--set measurement.rows=first overrides the rows the " \
        "checkpoint's export.hybrid was fitted with (none)" in v.final.status, v.final.status
    runner = fitted[1]
    assert "measurement.rows=last overrides" in other_rows_reason(runner, HybridConfig(measurement={"rows": "last"}))
    assert other_rows_reason(runner, HybridConfig(method="pure-avg", measurement={"rows": "last"})) == ""
    same = run_vehicle(sim_root, "v1.0-sim", "sim-veh-000", {**conf, "measurement": {"rows": "none"}})
    assert "overrides the rows" not in same.final.status


def test_the_same_learned_run_typed_from_another_folder_is_this_run(fitted, sim_root, tmp_path, monkeypatch):
    """Probe 119: --checkpoint ck.json, then ../ck.json from a sub-folder (the same file), was refused as "another
    run", and an interrupted run could not be resumed from there without --overwrite."""
    import shutil
    from pathlib import Path

    from hybrid_calib.hybrid import run_calibration

    work = tmp_path / "work"
    (work / "sub").mkdir(parents=True)
    for f in Path(fitted[0]).parent.glob(Path(fitted[0]).stem + ".*"):
        shutil.copy(f, work / f.name)
    name = Path(fitted[0]).name
    conf = {**BASE, "method": "pure", "max_frames": 2, "vehicles": ["sim-veh-000"]}
    monkeypatch.chdir(work)
    first = run_calibration(sim_root, "v1.0-sim", tmp_path / "run", {**conf, "checkpoint": name})
    assert first.vehicles["sim-veh-000"].checkpoint == str(work / name)
    monkeypatch.chdir(work / "sub")
    again = run_calibration(sim_root, "v1.0-sim", tmp_path / "run", {**conf, "checkpoint": f"../{name}"})
    assert again.to_dict() == first.to_dict()
