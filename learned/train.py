"""Training of RC-AutoCalib: presets, a deterministic resumable loop, CSV (and TensorBoard) logs.

``train(conf, frames, out)`` trains on the ``train`` split of ``frames`` (whole scenes / vehicles
per split, ``learned.dataset.split_indices``), validates on ``val`` after every epoch, and writes:
  out/train_config.json        the effective TrainConfig (+ the model config it resolves to)
  out/checkpoints/ckpt-NNNN.*  one checkpoint per epoch (``learned.checkpoint``), with its configs
  out/steps.csv                per step: epoch, step, lr, total, calib, matching, seconds
  out/epochs.csv               per epoch: train means, val losses, val rotation / translation errors
  out/history.png              losses and validation errors per epoch (drawn by ``hybrid-calib train``
                               when training ends: ``hybrid_calib.plots.training.plot_history``)
  out/depth-cache/             estimated depth per frame (``learned.depth.DepthCache``)
  out/skipped.json             frames whose files are bad, skipped so far: [{"index", "token", "file", "reason"}]
                               (index null: a sample the roots' index left out)
Re-running with ``resume=True`` continues after the last complete checkpoint; the result is the
same as an uninterrupted run (shuffling, perturbations and torch's RNG are seeded per epoch).
"""

from __future__ import annotations

import csv
import io
import json
import logging
import os
import signal
import sys
import time
from collections.abc import Callable, Iterator, Sequence
from contextlib import contextmanager
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np
import torch

from hybrid_calib.atomic import leave_bars, remove_temporaries
from hybrid_calib.config import (
    ConfigError,
    freeze_dict_fields,
    merge,
    read_out_record,
    require_ranges,
    save_json_atomic,
    to_dict,
)
from hybrid_calib.data.files import absolute_path, watch_roots
from hybrid_calib.data.frame import RadarCameraFrame
from hybrid_calib.errors import DataError, HybridCalibError, stop_signal_of
from hybrid_calib.metrics import extrinsic_error
from hybrid_calib.seeds import keyed_seed
from learned.checkpoint import checkpoint_stem, latest_checkpoint, load_checkpoint, orphaned_weights, save_checkpoint
from learned.dataset import CalibDataset, DatasetConfig, SplitConfig, collate, index_skip_records, split_indices
from learned.depth import DepthCache, build_depth_estimator

log = logging.getLogger(__name__)

# ModelConfig keys that shape only the training loss: a fine-tuning run (init_weights) may change them
LOSS_ONLY_KEYS = ("beta", "lam", "iter_gamma", "calib_rot_weight", "calib_trans_weight", "calib_point_weight",
                  "unc_weight", "use_nr", "nr_tau", "nr_delta_s_m", "nr_delta_m", "nr_chunk")

# Batch keys the model reads (the dataset adds bookkeeping keys: perturbation, index, token).
MODEL_KEYS = ("image", "depth", "K", "radar", "radar_mask", "T_init", "T_gt", "lidar_cam", "lidar_mask",
              "lidar_fraction")
# Loss terms logged when the model returns them.
LOSS_KEYS = ("total", "calib", "matching", "uncertainty")


@dataclass(frozen=True)
class TrainConfig:
    model_preset: str = "small"  # learned.config preset the model starts from ("small" | "paper")
    model: dict = field(default_factory=dict)  # ModelConfig overrides on top of the preset
    perturbation: str = "R1"  # R1 (+-10 deg, +-0.25 m) or R2 (+-20 deg, +-1.5 m), sampled per sample
    epochs: int = 50  # paper: 50
    batch_size: int = 16  # CalibDepth-like setups train with batches of ~16 at this input size
    lr: float = 1e-4  # paper: Adam, 1e-4
    lr_halve_every: int = 8  # paper: learning rate halved every 8 epochs (0 = never halved)
    weight_decay: float = 0.0  # Adam weight decay (paper: none stated)
    grad_clip: float = 5.0  # max gradient norm; guards the LSTM against early spikes (0 = off)
    seed: int = 0  # model init, shuffling, perturbations
    samples_per_epoch: int = 0  # train samples drawn per epoch (0 = the whole train split)
    val_samples: int = 64  # validation samples per epoch (0 = the whole val split)
    num_workers: int = 0  # DataLoader worker processes (0 = in the training process)
    threads: int = 2  # torch CPU threads
    device: str = "cpu"  # torch device ("cuda" on a GPU machine)
    max_radar_points: int = 512  # Nmax radar points per sample
    max_lidar_points: int = 4096  # Mmax LiDAR points per sample (noise-resistant matcher)
    depth: str = "corrupted-truth"  # depth estimator: corrupted-truth | depth-anything:/local/dir
    depth_options: dict = field(default_factory=dict)  # overrides of the depth estimator's config
    depth_cache: str = ""  # depth cache folder ("" = OUT/depth-cache)
    split: SplitConfig = field(default_factory=SplitConfig)  # train / val / test assignment of scenes
    context_weights: str = ""  # local ResNet-18 ImageNet weights for the image context net ("" = from scratch)
    init_weights: str = ""  # checkpoint (.json) whose weights start a new run (fine-tuning, e.g. R2 from R1)

    def __post_init__(self):
        freeze_dict_fields(self)  # model, depth_options: read-only as the rest
        for name in ("epochs", "batch_size", "threads"):
            if getattr(self, name) < 1:
                raise ValueError(f"TrainConfig.{name} must be >= 1, got {getattr(self, name)}")
        for name in ("samples_per_epoch", "val_samples", "num_workers", "lr_halve_every"):
            if getattr(self, name) < 0:
                raise ValueError(f"TrainConfig.{name} must be >= 0, got {getattr(self, name)}")
        if not self.lr >= 0:  # 0 is allowed: the weights stay where they start (a fine-tuning run's check uses it)
            raise ValueError(f"TrainConfig.lr must be >= 0, got {self.lr}")
        for name in ("weight_decay", "grad_clip"):  # torch refuses a negative one; NaN disables clipping silently
            if not 0 <= getattr(self, name) < float("inf"):
                raise ValueError(f"TrainConfig.{name} must be a finite number >= 0, got {getattr(self, name)}")
        check_sizes_and_device(self, "TrainConfig")
        require_ranges(self, {"epochs": "[1, 1e4]", "batch_size": "[1, 4096]", "lr": "[0, 1]",
                              "lr_halve_every": "[0, 1e4]", "weight_decay": "[0, 1]", "grad_clip": "[0, 1e6]",
                              "samples_per_epoch": "[0, 1e8]", "val_samples": "[0, 1e8]", "num_workers": "[0, 256]",
                              "threads": "[1, 1024]", "max_radar_points": "[1, 1e6]", "max_lidar_points": "[0, 1e6]",
                              "seed": "[0, 9.2e18]"})  # as --seed (probe 79: -1 was accepted through --set)


def check_sizes_and_device(conf, owner: str) -> None:
    """``ValueError`` naming the option when ``conf.max_radar_points`` < 1, ``conf.max_lidar_points`` < 0
    or ``conf.device`` is not a torch device (each failed deep inside torch / numpy)."""
    if conf.max_radar_points < 1 or conf.max_lidar_points < 0:
        raise ValueError(f"{owner}: max_radar_points must be >= 1 and max_lidar_points >= 0, got "
                         f"{conf.max_radar_points} and {conf.max_lidar_points}")
    try:
        device = torch.device(conf.device)
    except (RuntimeError, TypeError):
        raise ValueError(f"{owner}.device={conf.device!r} is not a torch device; e.g. cpu, cuda or cuda:0") from None
    if device.type not in ("cpu", "cuda"):  # mps, meta, xpu ...: an internal error inside torch (probe 27)
        raise ValueError(f"{owner}.device={conf.device!r}: the network runs on cpu or cuda devices; use device=cpu "
                         "(or cuda on a GPU machine)")
    if device.type == "cuda" and not torch.cuda.is_available():  # the CPU build of torch: an assert deep inside
        raise ValueError(f"{owner}.device={conf.device!r}: this torch has no usable CUDA device "
                         f"(torch {torch.__version__}, torch.cuda.is_available() is False); use device=cpu")


PRESETS: dict[str, dict[str, Any]] = {
    # the paper: 400x192 input, Adam 1e-4 halved every 8 epochs, 50 epochs
    "paper": dict(model_preset="paper", epochs=50, batch_size=16, lr=1e-4, lr_halve_every=8),
    # 2 CPU cores, well under two hours: the small model (200x96), a faster schedule on fewer samples
    # (2000 steps of batch 8, ~0.6 s each on 2 idle cores: ~30 min with data loading and validation)
    "small": dict(model_preset="small", epochs=20, batch_size=8, lr=3e-4, lr_halve_every=6,
                  samples_per_epoch=800, val_samples=64, max_lidar_points=2048),
}


def train_config(preset: str = "small", overrides: dict | None = None) -> TrainConfig:
    """A ``TrainConfig`` from a preset plus (nested) overrides; unknown keys raise ``ConfigError``."""
    if preset not in PRESETS:
        raise ConfigError(f"unknown training preset {preset!r}; valid: {sorted(PRESETS)}")
    base = dict(PRESETS[preset])
    overrides = dict(overrides or {})
    if "model" in overrides:  # merge model overrides instead of replacing the dict
        base["model"] = {**base.get("model", {}), **overrides.pop("model")}
    base.update(overrides)
    return merge(TrainConfig, base)


def resolve_model_config(conf: TrainConfig):
    from learned.config import model_config

    return model_config(conf.model_preset, conf.model)


def dataset_config(conf: TrainConfig, model_conf) -> DatasetConfig:
    H, W = (int(v) for v in model_conf.input_hw)
    return DatasetConfig(height=H, width=W, max_radar_points=conf.max_radar_points,
                         max_lidar_points=conf.max_lidar_points, perturbation=conf.perturbation, seed=conf.seed,
                         variant=model_conf.variant)


def to_device(batch: dict, device: str | torch.device) -> dict:
    return {k: (v.to(device) if isinstance(v, torch.Tensor) else v) for k, v in batch.items()}


def model_inputs(batch: dict) -> dict:
    return {k: batch[k] for k in MODEL_KEYS if k in batch}


class _CsvLog:
    """Append-only CSV; on resume, rows after the resumed epoch are dropped."""

    def __init__(self, path: Path, columns: Sequence[str], keep_until_epoch: int):
        self.path, self.columns = path, list(columns)
        rows = []
        if path.is_file():
            try:
                with path.open(newline="", errors="replace") as f:
                    read = list(csv.DictReader(f))
            except (OSError, csv.Error):
                read = []
            for n, r in enumerate(read, start=2):
                try:
                    if int(str(r.get("epoch"))) <= keep_until_epoch:
                        rows.append(r)
                except ValueError:  # a side record: a line that does not parse is dropped, the run goes on
                    print(f"train: {path} line {n} does not parse (epoch {str(r.get('epoch'))[:20]!r}); dropped from "
                          "the log", file=sys.stderr)
        text = io.StringIO(newline="")
        w = csv.DictWriter(text, self.columns)
        w.writeheader()
        w.writerows(rows)
        from hybrid_calib.config import save_text_atomic

        save_text_atomic(path, text.getvalue())  # a kill here keeps the old log whole (probe 28)

    def write(self, row: dict) -> None:
        with self.path.open("a", newline="") as f:
            csv.DictWriter(f, self.columns).writerow({k: row.get(k, "") for k in self.columns})


def _tensorboard(out: Path):
    try:
        from torch.utils.tensorboard import SummaryWriter
    except ImportError:
        return None
    try:
        return SummaryWriter(str(out / "tensorboard"))
    except Exception:  # noqa: BLE001 - tensorboard present but broken: CSV logs still work
        return None


RESUME_FREE = ("epochs", "threads", "num_workers", "device", "depth_cache")  # may change when a run resumes


def check_resume(out: Path, last: Path, conf: dict, source: dict | None) -> None:
    """``HybridCalibError`` when the run in ``out`` (its ``train_config.json``; up to checkpoint ``last``) was
    trained with other options (``conf``: ``to_dict(TrainConfig)``, ``RESUME_FREE`` aside) or other data
    (``source``): resuming would continue it with these and record them as the whole run's."""
    previous = read_out_record(out / "train_config.json", "train config", "the options its checkpoints were "
                               "trained with: resume with the same options, or choose another --out")
    if previous is None:
        return
    old = previous.get("train") if isinstance(previous.get("train"), dict) else {}
    changed = [f"{k}: {json.dumps(old.get(k))} -> {json.dumps(v)}" for k, v in conf.items()
               if k not in RESUME_FREE and old.get(k) != v]
    before = previous.get("data")
    if source is not None and isinstance(before, dict) and any(before.get(k) != source.get(k) for k in before):
        # the keys the run recorded (a run from before the data stamps compares its roots, version and sweeps)
        if before.get("stamps") != source.get("stamps") and before.get("roots") == source.get("roots"):
            changed.insert(0, "data: the frames at " + ", ".join(source.get("roots") or []) + " are not the ones the "
                              "run was trained on (another data stamp: re-simulated, re-downloaded or replaced)")
        else:
            changed.insert(0, f"data: {json.dumps(before)} -> {json.dumps(source)}")
    elif source is not None and before is not None and not isinstance(before, dict):
        changed.insert(0, f"data: {json.dumps(before)} -> {json.dumps(source)}")
    if changed:
        raise HybridCalibError(f"{out} holds a run trained up to {last.name} with other options "
                               f"({'; '.join(changed)}); resume with the same options and data (only "
                               f"{', '.join(RESUME_FREE)} may change), or choose another --out")


def _resume_error(out: Path, last: Path, e: HybridCalibError) -> HybridCalibError:
    """The error for a run whose last checkpoint (the one a resume continues from) cannot be read, saying what to
    do: the checkpoint's own advice ("pick another checkpoint") did not apply, the resume takes the newest one."""
    stem = last.name.removesuffix(".json")
    files = ", ".join(sorted(p.name for p in last.parent.glob(f"{stem}.*")))
    return HybridCalibError(f"resuming {out}: its last checkpoint {stem} cannot be read ({e}); move {files} out of "
                            f"{last.parent} to resume after the epoch before it, or pass another --out to start afresh")


def check_writable(folder: Path) -> None:
    """``HybridCalibError`` naming ``folder`` (created if missing) when a file cannot be written in it: tried, since
    permissions do not say it all (a read-only mount, an immutable folder, root's writes)."""
    import os

    probe = folder / f".write-test.{os.getpid()}"
    try:
        folder.mkdir(parents=True, exist_ok=True)
        probe.write_bytes(b"")
        probe.unlink()
    except OSError as e:
        raise HybridCalibError(f"{folder} cannot be written ({e.strerror or e}): the checkpoints go there; make it "
                               "writable, or pass another --out") from None


def lr_schedule(optimizer, conf: TrainConfig):
    """The learning rate halved every ``conf.lr_halve_every`` epochs; 0 keeps it (as grad_clip 0 is off: probe 55,
    0 halved it every epoch, a 50-epoch run ending at lr / 2**49)."""
    return torch.optim.lr_scheduler.StepLR(optimizer, step_size=max(1, conf.lr_halve_every),
                                           gamma=0.5 if conf.lr_halve_every else 1.0)


# a DataLoader worker hands its batches over a Unix socket in TMPDIR/pymp-XXXXXXXX/listener-XXXXXXXX (multiprocessing's
# resource sharer); a socket's path holds at most 107 bytes
SOCKET_PATH_MAX = 107
SOCKET_NAME_BYTES = len("/pymp-12345678/listener-12345678")


def check_worker_socket_path(num_workers: int) -> None:
    """``HybridCalibError`` when DataLoader workers could not open their socket under this process's temporary folder
    (probe 119: with a 130-character TMPDIR each worker printed "OSError: AF_UNIX path too long" and the run waited
    for batches for ever)."""
    import tempfile

    tmp = tempfile.gettempdir()
    if len(os.fsencode(tmp)) + SOCKET_NAME_BYTES > SOCKET_PATH_MAX:
        n = len(os.fsencode(tmp))
        raise HybridCalibError(f"--set num_workers={num_workers}: the DataLoader workers' socket would lie under the "
                               f"temporary folder {tmp} ({n} bytes), and a socket's path holds at most "
                               f"{SOCKET_PATH_MAX}: set TMPDIR to a folder of at most "
                               f"{SOCKET_PATH_MAX - SOCKET_NAME_BYTES} bytes, or --set num_workers=0")


def train(conf: TrainConfig | dict, frames: Sequence[RadarCameraFrame], out: str | Path, *, resume: bool = True,
          progress: bool = True, model_factory: Callable[[Any], torch.nn.Module] | None = None,
          source: dict | None = None) -> Path:
    """Train RC-AutoCalib on the ``train`` split of ``frames``; returns the last checkpoint's JSON.

    ``conf``: a ``TrainConfig`` (or overrides of the defaults). ``out``: the run folder (module
    docstring). With ``resume`` an existing run continues after its last checkpoint, when it was trained
    with the same options (``RESUME_FREE`` aside) and ``source``; without it an existing run folder with
    checkpoints is an error (pick a new ``out``). ``model_factory`` builds the network from its
    ``ModelConfig`` (default ``learned.model.RCAutoCalib``). ``source``: where ``frames`` came from (the
    command's roots, version, sweeps), recorded in ``train_config.json`` as "data"."""
    from tqdm import tqdm

    if model_factory is None:
        from learned.model import RCAutoCalib as model_factory

    conf = merge(TrainConfig, conf)
    # absolute: the same run resumed from another folder is this run (probe 119: "other options (init_weights:
    # 'ck.json' -> '../ck.json')")
    conf = replace(conf, init_weights=absolute_path(conf.init_weights))
    out = Path(out)
    ckpt_dir = out / "checkpoints"
    model_conf = resolve_model_config(conf)
    model_conf_dict = to_dict(model_conf)
    torch.set_num_threads(max(1, conf.threads))
    device = torch.device(conf.device)

    if conf.num_workers:
        check_worker_socket_path(conf.num_workers)
    last = latest_checkpoint(ckpt_dir)
    if last is not None and not resume:
        raise HybridCalibError(f"{out} already holds checkpoints ({last.name}); resume, or choose another --out")
    try:
        last_meta = None if last is None else load_checkpoint(last)
    except HybridCalibError as e:
        raise _resume_error(out, last, e) from None
    if last_meta is not None and last_meta.model_config != model_conf_dict:
        raise HybridCalibError(f"{last} was trained with another model config; resume with the same "
                               "preset and --set options, or choose another --out")
    if last is not None:
        check_resume(out, last, to_dict(conf), source)
    if orphans := orphaned_weights(ckpt_dir, last):  # trained again and overwritten: said (probe 33), not refused
        log.warning("%s hold(s) no checkpoint JSON beside (a save cut short, or the JSON deleted): %s trained again "
                    "from %s and overwritten when it ends; to keep them, stop this run (Ctrl-C) and move them away",
                    ", ".join(p.name for p in orphans),
                    "those epochs are" if len(orphans) > 1 else "that epoch is",
                    f"after {last.name}" if last is not None else "the start")
    # what refuses the run is checked before its folder is written (probe 71: an --init of another model, a --depth
    # that does not exist and an empty train split left a train_config.json and a runs.json line behind)
    if conf.context_weights and last is None and not Path(conf.context_weights).is_file():  # probe 79: internal
        raise HybridCalibError(f"context_weights {conf.context_weights}: no such file; pass a local ResNet-18 "
                               "ImageNet weights file (.safetensors or a torch state dict), or drop it to train the "
                               "image context network from scratch")
    if conf.init_weights and last is None:
        init = load_checkpoint(conf.init_weights)
        diff = sorted(k for k in set(init.model_config) | set(model_conf_dict)
                      if init.model_config.get(k) != model_conf_dict.get(k) and k not in LOSS_ONLY_KEYS)
        if diff:
            raise HybridCalibError(f"init_weights {conf.init_weights} has another model config (differs in "
                                   f"{', '.join(diff)}); train with its preset and --set model.* options "
                                   f"(only the loss settings {', '.join(LOSS_ONLY_KEYS)} may change)")
    train_idx = split_indices(frames, "train", conf.split)
    val_idx = split_indices(frames, "val", conf.split)
    if not train_idx:
        raise HybridCalibError(f"the train split is empty ({len(frames)} frames, split by {conf.split.by}); "
                               "give more scenes or set split.test_fraction / split.val_fraction lower")
    depth = build_depth_estimator(conf.depth, conf.depth_options)
    out.mkdir(parents=True, exist_ok=True)
    check_writable(ckpt_dir)  # before an epoch's work, not after it (probe 33: a read-only checkpoints/ was exit 3)
    remove_temporaries(ckpt_dir)  # a killed save's (probe 90: a 12 MB partial optim file stayed for good)
    save_json_atomic(out / "train_config.json", {"train": to_dict(conf), "model": model_conf_dict,
                                                 **({"data": source} if source is not None else {})})

    if not val_idx and (conf.split.test_groups or conf.split.val_groups):  # the fractions are not used then
        log.warning("no validation frames: split.val_groups names none (the groups listed decide the split, not "
                    "val_fraction); add --set split.val_groups=[...] to validate")
    elif not val_idx:  # epochs.csv's val_* columns stayed empty and history.png had no validation curve, no word
        log.warning("no validation frames: split.by=%s with val_fraction %s leaves none of the %d frames for "
                    "validation (no val_* columns, no validation curve); add roots or scenes, or pass --set %s",
                    conf.split.by, conf.split.val_fraction, len(frames),
                    "split.val_fraction=0.2 (or more frames)" if conf.split.by == "time" else "split.by=time")
    if conf.samples_per_epoch > len(train_idx):  # probe 87: cut to the split without a word
        log.warning("samples_per_epoch %d is more than the %d frames of the train split: each epoch draws each of "
                    "them once (%d samples)", conf.samples_per_epoch, len(train_idx), len(train_idx))
    cache = DepthCache(Path(conf.depth_cache) if conf.depth_cache else out / "depth-cache")
    dconf = dataset_config(conf, model_conf)
    train_set = CalibDataset(frames, dconf, depth, indices=train_idx, cache=cache, train=True)
    val_set = CalibDataset(frames, dconf, depth, indices=val_idx, cache=cache, train=False)
    if unindexed := index_skip_records(frames):  # listed before the first epoch (probe 100: train said nothing)
        save_json_atomic(out / "skipped.json", train_set.skip_records(index=True) + val_set.skip_records())
        log.warning("%d sample(s) or record(s) of the tables hold no frame (listed in %s); first: %s", len(unindexed),
                    out / "skipped.json", unindexed[0]["reason"])

    torch.manual_seed(keyed_seed("init", conf.seed, nbytes=4))
    model = model_factory(model_conf).to(device)
    optimizer = torch.optim.Adam(model.parameters(), lr=conf.lr, weight_decay=conf.weight_decay)
    scheduler = lr_schedule(optimizer, conf)
    start = 1
    if conf.context_weights and last is None:
        try:
            loaded = model.load_context_weights(conf.context_weights)
        except (ValueError, KeyError, RuntimeError, OSError) as e:  # not ResNet-18 weights, or not readable
            raise DataError(f"context_weights: {e}; pass ResNet-18 ImageNet weights (torchvision key names)",
                            path=str(conf.context_weights)) from e
        log.info("image context network: %d tensors from %s", len(loaded), conf.context_weights)
    if conf.init_weights and last is None:
        load_checkpoint(conf.init_weights, model, map_location=device)
        log.info("weights initialised from %s (epoch %d)", conf.init_weights, init.epoch)
    if last is not None:
        try:
            ckpt = load_checkpoint(last, model, optimizer, scheduler, map_location=device)
        except HybridCalibError as e:
            raise _resume_error(out, last, e) from None
        start = ckpt.epoch + 1
        log.info("resuming %s after epoch %d", out, ckpt.epoch)
        if ckpt.epoch >= conf.epochs:  # a run already past --epochs returned its later checkpoint without a word
            earlier = ckpt_dir / f"ckpt-{conf.epochs:04d}.json"
            log.warning("%s already holds %d epochs (>= --epochs %d): nothing to train; its last checkpoint is "
                        "epoch %d%s", out, ckpt.epoch, conf.epochs, ckpt.epoch,
                        f" (the {conf.epochs}-epoch one: {earlier})" if earlier.is_file() else "")
    steps_log = _CsvLog(out / "steps.csv", ["epoch", "step", "lr", *LOSS_KEYS, "seconds"], start - 1)
    epochs_log = _CsvLog(out / "epochs.csv", ["epoch", "lr", *(f"train_{k}" for k in LOSS_KEYS),
                                              *(f"val_{k}" for k in LOSS_KEYS), "val_rot_geodesic_deg",
                                              "val_trans_norm_cm", "val_rot_mean_deg", "val_trans_mean_cm",
                                              "skipped_frames", "nonfinite_steps", "seconds"], start - 1)
    tb = _tensorboard(out)
    last_path = last
    changed = watch_roots(source)  # a root rewritten under the run (as calibrate's: probe 142)
    with _stopped_workers_stop_the_run():  # a worker the group's signal ended: that signal (probe 111)
        for epoch in range(start, conf.epochs + 1):
            t0 = time.time()
            torch.manual_seed(keyed_seed("epoch", conf.seed, epoch, nbytes=4))
            train_set.set_epoch(epoch)
            g = np.random.default_rng(keyed_seed("shuffle", conf.seed, epoch, nbytes=4))
            order = g.permutation(len(train_set))
            if conf.samples_per_epoch:
                order = order[: conf.samples_per_epoch]
            loader = torch.utils.data.DataLoader(train_set, batch_size=conf.batch_size, sampler=order.tolist(),
                                                 num_workers=conf.num_workers, collate_fn=collate)
            model.train()
            lr = optimizer.param_groups[0]["lr"]
            sums: dict[str, float] = {}
            n_steps = nonfinite = 0
            bar = tqdm(loader, desc=f"epoch {epoch}/{conf.epochs}", disable=not progress, leave=leave_bars())
            for step, batch in enumerate(bar):
                if batch is None:
                    continue
                ts = time.time()
                batch = to_device(batch, device)
                out_m = model(model_inputs(batch))
                losses = model.loss(out_m, model_inputs(batch))
                if not torch.isfinite(losses["total"]):  # a degenerate batch must not poison the weights
                    nonfinite += 1
                    log.warning("epoch %d step %d: non-finite loss %s; step skipped", epoch, step,
                                {k: float(v.detach()) for k, v in losses.items()})
                    continue
                optimizer.zero_grad(set_to_none=True)
                losses["total"].backward()
                if conf.grad_clip > 0:
                    torch.nn.utils.clip_grad_norm_(model.parameters(), conf.grad_clip)
                optimizer.step()
                vals = {k: float(v.detach()) for k, v in losses.items() if k in LOSS_KEYS}
                for k, v in vals.items():
                    sums[k] = sums.get(k, 0.0) + v
                n_steps += 1
                steps_log.write({"epoch": epoch, "step": step, "lr": lr, **vals, "seconds": round(time.time() - ts, 3)})
                bar.set_postfix(loss=f"{vals['total']:.4f}")
                if tb is not None:
                    for k, v in vals.items():
                        tb.add_scalar(f"train/{k}", v, (epoch - 1) * len(loader) + step)
            if n_steps == 0 and not nonfinite and train_set.bad:
                save_json_atomic(out / "skipped.json", train_set.skip_records(index=True) + val_set.skip_records())
                raise HybridCalibError(f"epoch {epoch}: no training step ran, every frame drawn failed to load "
                                       f"({len(train_set.bad)} bad; listed in {out / 'skipped.json'}); first: "
                                       f"{next(iter(train_set.bad.values()))}")
            scheduler.step()
            train_means = {f"train_{k}": v / max(n_steps, 1) for k, v in sums.items()}
            val = validate(model, val_set, conf, device) if len(val_set) else {}
            metrics = {"epoch": epoch, "lr": lr, **train_means, **val,
                       "skipped_frames": len(train_set.bad) + len(val_set.bad), "nonfinite_steps": nonfinite,
                       "seconds": round(time.time() - t0, 1)}
            epochs_log.write(metrics)
            if train_set.bad or val_set.bad:  # which frames were skipped, and why (the count is in epochs.csv)
                save_json_atomic(out / "skipped.json", train_set.skip_records(index=True) + val_set.skip_records())
            if tb is not None:
                for k, v in metrics.items():
                    if k.startswith("val_"):
                        tb.add_scalar(f"val/{k[4:]}", v, epoch)
            if (root := changed()) is not None:  # the epoch read old and new frames: not saved as one of these
                raise DataError(f"{root} changed while epoch {epoch} read it (its tables or sensor folders were "
                                "replaced: re-simulated, re-downloaded or edited by another process), so the epoch "
                                "trained on a mix of the old and the new data and its checkpoint is not written"
                                + (f"; {last_path.name}, of the data the run began with, is kept" if last_path else "")
                                + ": train again into another --out once the root is complete"
                                + (" (--init that checkpoint to go on from it)" if last_path else ""), path=str(root))
            last_path = save_checkpoint(checkpoint_stem(ckpt_dir, epoch), model, epoch=epoch,
                                        model_config=model_conf_dict, train_config=to_dict(conf), metrics=metrics,
                                        optimizer=optimizer, scheduler=scheduler, data=source)
            if progress:
                print(json.dumps({k: (round(v, 4) if isinstance(v, float) else v) for k, v in metrics.items()}))
    if tb is not None:
        tb.close()
    if last_path is None:
        raise HybridCalibError(f"no epoch was trained (epochs={conf.epochs})")
    return last_path


@contextmanager
def _stopped_workers_stop_the_run() -> Iterator[None]:
    """A DataLoader worker ended by a signal sent to the process group (SIGTERM, Ctrl-C) stops the run as the signal
    does: it is raised in this process (the command's handler says what is kept, exit 143 / 130), not torch's
    RuntimeError (probe 111: "internal error", exit 3, when a worker got the group's SIGTERM first)."""
    try:
        yield
    except RuntimeError as e:
        if (sig := stop_signal_of(e)) is not None:
            signal.raise_signal(sig)
        raise


@torch.no_grad()
def validate(model, dataset: CalibDataset, conf: TrainConfig, device) -> dict[str, float]:
    """Mean losses and final-iteration errors over (up to ``conf.val_samples``) validation samples."""
    model.eval()
    n = len(dataset) if not conf.val_samples else min(conf.val_samples, len(dataset))
    loader = torch.utils.data.DataLoader(dataset, batch_size=conf.batch_size, sampler=list(range(n)),
                                         num_workers=conf.num_workers, collate_fn=collate)
    sums: dict[str, float] = {}
    errs = []
    batches = 0
    for batch in loader:
        if batch is None:
            continue
        batch = to_device(batch, device)
        out = model(model_inputs(batch))
        losses = model.loss(out, model_inputs(batch))
        if torch.isfinite(losses["total"]):  # a degenerate batch is left out of the loss means
            for k in LOSS_KEYS:
                if k in losses:
                    sums[k] = sums.get(k, 0.0) + float(losses[k])
            batches += 1
        T_final = out["T_iters"][-1].double().cpu().numpy()
        T_gt = batch["T_gt"].double().cpu().numpy()
        errs += [extrinsic_error(a, b) for a, b in zip(T_final, T_gt)]
    model.train()
    if not errs:
        return {}
    res = {f"val_{k}": v / max(batches, 1) for k, v in sums.items()}
    res.update({
        "val_rot_geodesic_deg": float(np.mean([e.geodesic_deg for e in errs])),
        "val_trans_norm_cm": float(np.mean([e.trans_norm_cm for e in errs])),
        "val_rot_mean_deg": float(np.mean([e.rot_mean_deg for e in errs])),
        "val_trans_mean_cm": float(np.mean([e.trans_mean_cm for e in errs])),
    })
    return res
