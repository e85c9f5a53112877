"""The checkpoints shipped in learned/checkpoints/ load and calibrate on held-out simulated frames."""

import json
from pathlib import Path

import numpy as np
import pytest
import torch

from hybrid_calib.data.nuscenes import NuScenesRadarCamera
from hybrid_calib.metrics import extrinsic_error
from hybrid_calib.sim.drive import SimConfig
from hybrid_calib.sim.simulate import simulate
from learned.checkpoint import load_model
from learned.dataset import CalibDataset, DatasetConfig, collate
from learned.depth import CorruptedTruthDepth, LidarDepth

CHECKPOINTS = Path(__file__).resolve().parents[1] / "learned" / "checkpoints"
SHIPPED = {"R0": CHECKPOINTS / "small-sim-r0.json", "R1": CHECKPOINTS / "small-sim-r1.json",
           "R2": CHECKPOINTS / "small-sim-r2.json"}
PAPER = CHECKPOINTS / "paper-sim-r1.json"


def test_every_range_and_the_paper_preset_are_shipped_with_provenance():
    for rng, path in [*SHIPPED.items(), ("R1", PAPER)]:
        assert path.is_file(), f"no shipped {rng} checkpoint at {path}"
        meta = json.loads(path.read_text())
        assert meta["train_config"]["perturbation"] == rng
        assert {"data", "train", "evaluate"} <= set(meta["provenance"])
        assert len(meta["export"]["cov_scale"]) == 6  # the covariance scale fitted on validation frames
        from learned.checkpoint import weights_sha256  # the fitted models are tied to these very weights

        assert meta["files"]["weights_sha256"] == weights_sha256(path.with_suffix(".safetensors"))
        assert "hybrid" in meta["export"]  # the hybrid's measurement model, fitted on validation drives
        from learned.ood import OODModel

        ood = OODModel.from_dict(meta["export"]["ood"])  # the out-of-domain model, fitted on validation drives
        assert "ood_fit.py" in ood.fitted["command"] and ood.fitted["frames"] >= 100
        assert not any(r.get("seed") in (9201, 9202, 9203) for r in ood.fitted["roots"])  # never the test drives
        assert path.with_suffix(".safetensors").stat().st_size < 25e6


@pytest.mark.parametrize("rng", ["R0", "R1", "R2"])
def test_shipped_checkpoint_reduces_rotation_error_on_unseen_frames(tmp_path, rng):
    if not SHIPPED[rng].is_file():
        pytest.fail(f"no shipped {rng} checkpoint at {SHIPPED[rng]}")
    model, ckpt = load_model(SHIPPED[rng])
    H, W = (int(v) for v in model.cfg.input_hw)
    # a drive from a seed and scene the checkpoint never saw (it was trained on seed 0)
    root = simulate(SimConfig(scenario="urban", vehicles=1, frames=6, seed=12345, image_scale=0.25), tmp_path / "sim",
                    progress=False)
    lidar = ckpt.train_config.get("depth") == LidarDepth.name  # the depth path it was trained with
    frames = list(NuScenesRadarCamera(root, "v1.0-sim", conf={"load_lidar": lidar}))
    depth = LidarDepth() if lidar else CorruptedTruthDepth()
    ds = CalibDataset(frames, DatasetConfig(height=H, width=W, perturbation=rng, seed=3), depth, train=False)
    batch = collate([ds[i] for i in range(len(ds))])
    with torch.no_grad():
        out = model(batch)
    T_gt = batch["T_gt"].double().numpy()
    init = [extrinsic_error(T0, Tg).rot_mean_deg for T0, Tg in zip(batch["T_init"].double().numpy(), T_gt)]
    final = [extrinsic_error(T, Tg).rot_mean_deg for T, Tg in zip(out["T_iters"][-1].double().numpy(), T_gt)]
    assert all(np.isfinite(final))
    # measured on 239 held-out frames (docs/benchmarks.md): R1 / R2 rotation errors drop ~4-6x, R0 (starts
    # within 2 deg) by a third
    assert np.mean(final) < (0.8 if rng == "R0" else 0.5) * np.mean(init), (np.mean(init), np.mean(final))


@pytest.mark.parametrize("edit", [{"input_hw": [48, 96]}, {"iterations": 1}, {"input_hw": None}, {"feat_dim": None}])
def test_a_checkpoint_json_whose_model_config_was_edited_is_refused(edit, tmp_path):
    """input_hw, iterations or variant change no tensor shape: an edited JSON loaded silently and its fitted models
    were applied to another network (probe 33: NEES 3.7 -> 32.8, coverage 12.5 %, exit 0). A deleted feat_dim (a
    model of the default width) blamed the weights file: the JSON is what was edited."""
    import shutil

    from learned.checkpoint import CheckpointError

    for suffix in (".json", ".safetensors"):
        shutil.copy(SHIPPED["R1"].with_suffix(suffix), tmp_path / f"small-sim-r1{suffix}")
    load_model(tmp_path / "small-sim-r1.json")  # as shipped: loads
    meta = json.loads((tmp_path / "small-sim-r1.json").read_text())
    key, value = next(iter(edit.items()))
    if value is None:
        del meta["model_config"][key]  # a key deleted: the dataclass default would have been used
    else:
        meta["model_config"][key] = value
    (tmp_path / "small-sim-r1.json").write_text(json.dumps(meta))
    with pytest.raises(CheckpointError, match=f"model_config differs from the one its weights small-sim-r1.safetensors "
                                              f"were saved with, in 1 key\\(s\\): {key} .*the JSON was edited"):
        load_model(tmp_path / "small-sim-r1.json")


@pytest.mark.parametrize("edit, where", [(("ood", "mean", 2), "ood.mean\\[2\\]"),
                                         (("hybrid", "drive_std", 0), "hybrid.drive_std\\[0\\]")])
def test_a_non_finite_number_in_a_checkpoints_fitted_blocks_is_refused_on_load(edit, where, tmp_path):
    """evaluate took a NaN export.ood block and copied it into its records as bare NaN tokens (probe 33)."""
    import shutil

    from learned.checkpoint import CheckpointError, load_checkpoint

    for suffix in (".json", ".safetensors"):
        shutil.copy(SHIPPED["R1"].with_suffix(suffix), tmp_path / f"small-sim-r1{suffix}")
    meta = json.loads((tmp_path / "small-sim-r1.json").read_text())
    block, key, i = edit
    meta["export"][block][key][i] = float("nan")
    (tmp_path / "small-sim-r1.json").write_text(json.dumps(meta))  # json writes NaN, as a hand edit would
    with pytest.raises(CheckpointError, match=f"export block: {where} is not a finite number"):
        load_checkpoint(tmp_path / "small-sim-r1.json")


def test_a_checkpoint_json_saved_with_a_byte_order_mark_loads_and_a_folder_of_named_ones_is_said(tmp_path):
    """A Windows editor's BOM read as "truncated or corrupt"; the folder message said --checkpoint to train --init."""
    import shutil

    from learned.checkpoint import load_checkpoint

    for suffix in (".json", ".safetensors"):
        shutil.copy(SHIPPED["R1"].with_suffix(suffix), tmp_path / f"small-sim-r1{suffix}")
    (tmp_path / "small-sim-r1.json").write_bytes(b"\xef\xbb\xbf" + (tmp_path / "small-sim-r1.json").read_bytes())
    assert load_checkpoint(tmp_path / "small-sim-r1.json").epoch >= 1
    with pytest.raises(Exception, match="holds named checkpoints \\(small-sim-r1.json\\): pass one of them, e.g. "
                                        f"{tmp_path / 'small-sim-r1.json'}$"):
        load_checkpoint(tmp_path)
