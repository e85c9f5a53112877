"""Torch dataset over radar-camera frames: resized image, estimated depth, padded radar, LiDAR in
the camera frame, and a per-sample mis-calibrated start ``T_init``.

One sample (``CalibDataset[i]``), tensors float32 unless said otherwise:
  image: (3, H, W) RGB in [0, 1], resized to the model input size (paper: W x H = 400 x 192).
  depth: (1, H, W) metres, ESTIMATED camera depth at the model size (0 = unknown).
  K: (3, 3) intrinsics of the resized image (``PinholeCamera.scaled``).
  radar: (Nmax, 3) metres, radar frame (z = 0 as recorded); radar_mask: (Nmax,) bool.
  T_init: (4, 4) the mis-calibrated T_cam_radar the model starts from.
  T_gt: (4, 4) ground-truth T_cam_radar.
  (variant "lidar", the supplement's LiDAR-camera network: radar = LiDAR points in the LiDAR frame
  that lie in front of the camera under T_init, and T_init / T_gt are T_cam_lidar.)
  lidar_cam: (Mmax, 3) metres, LiDAR points moved into the CAMERA frame (in front of the camera and
    inside the image); lidar_mask: (Mmax,) bool; lidar_fraction: () float, the share of the sweep's
    in-image points kept (1 unless subsampled to Mmax; the NR matcher scales its tau by it).
  perturbation: (6,) float64, the sampled [roll, pitch, yaw] (rad, camera axes) and [dx, dy, dz] (m).
  index: int (position in the dataset), token: str (camera sample_data token).
``collate`` stacks a list of samples into the batch dict the model takes (dropping ``None``s, which
``CalibDataset`` returns for frames whose files are bad; they are listed in ``dataset.bad``).

Perturbations (docs/conventions.md; the ranges: ``hybrid_calib.perturbation``): roll, pitch, yaw
uniform in +-rot_deg and dx, dy, dz uniform in +-trans_m (R1: 10 deg, 0.25 m; R2: 20 deg, 1.5 m),
applied with ``geometry.perturb_camera_frame``. Training draws a new one per (seed, epoch, frame index);
evaluation fixes one per (seed, frame index), whatever the epoch.
"""

from __future__ import annotations

import logging
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch

from hybrid_calib.config import ConfigError, merge, require_ranges
from hybrid_calib.data.frame import RadarCameraFrame
from hybrid_calib.data.image_header import jpeg_quality
from hybrid_calib.data.tables import SIM_VERSION
from hybrid_calib.errors import DataError, HybridCalibError
from hybrid_calib.geometry import perturb_camera_frame, transform_points
from hybrid_calib.perturbation import perturbation_bounds, sample_perturbation
from hybrid_calib.seeds import keyed_rng, keyed_seed
from learned.depth import DepthCache, DepthEstimator

log = logging.getLogger(__name__)

@dataclass(frozen=True)
class DatasetConfig:
    height: int = 192  # model input height, pixels (paper 192)
    width: int = 400  # model input width, pixels (paper 400)
    max_radar_points: int = 512  # Nmax: radar points per sample (padded / subsampled)
    max_lidar_points: int = 4096  # Mmax: LiDAR points per sample for the noise-resistant matcher
    perturbation: str = "R1"  # R1 (+-10 deg, +-0.25 m) or R2 (+-20 deg, +-1.5 m)
    seed: int = 0  # perturbation / subsampling seed
    lidar_max_depth_m: float = 200.0  # LiDAR points farther than this (camera z) are dropped
    variant: str = "radar"  # "radar": radar points / T_cam_radar; "lidar": LiDAR points / T_cam_lidar (supplement)

    def __post_init__(self):
        require_ranges(self, {"height": "[1, 10000]", "width": "[1, 10000]", "max_radar_points": "[1, 1e6]",
                              "max_lidar_points": "[0, 1e6]", "lidar_max_depth_m": "(0, 1000]"})


SPLIT_BY = ("scene", "vehicle", "log", "time")


@dataclass(frozen=True)
class SplitConfig:
    """How frames are assigned to train / val / test (``split_indices``).

    by "scene" | "vehicle" | "log": whole groups go to one split (a salted hash of the group's name,
    or the explicit lists), fractions are of groups. by "time": WITHIN each scene, frames in time order
    (camera timestamp): the first ones train, then ``gap_frames`` dropped, then the val part, then
    ``gap_frames`` dropped, then the last ``round(test_fraction * n)`` frames test (val likewise
    ``round(val_fraction * n)``; no val part and no second gap when that is 0). Consecutive keyframes
    overlap in content, so the gap keeps the held-out part from being a near-copy of a trained frame;
    it is still the same scene, weather and sensors (docs/conventions.md, "Splits")."""

    by: str = "scene"  # "scene", "vehicle", "log" (whole groups per split) or "time" (within each scene)
    val_fraction: float = 0.1  # fraction of groups (by=time: of each scene's frames) for validation
    test_fraction: float = 0.2  # fraction of groups (by=time: of each scene's frames) held out for testing
    salt: str = "hybrid-calib"  # hashing salt; changing it reshuffles the split
    test_groups: tuple[str, ...] = ()  # explicit test groups (overrides the hash assignment)
    val_groups: tuple[str, ...] = ()  # explicit validation groups
    gap_frames: int = 3  # by=time: frames dropped between train and val and between val and test

    def __post_init__(self):
        if self.by not in SPLIT_BY:
            raise ConfigError(f"split.by must be one of {SPLIT_BY}, got {self.by!r}")
        if not (0 <= self.val_fraction < 1 and 0 <= self.test_fraction < 1
                and self.val_fraction + self.test_fraction < 1):
            raise ConfigError(f"split.val_fraction={self.val_fraction} and split.test_fraction={self.test_fraction} "
                              "must be in [0, 1) with a sum below 1")
        if self.gap_frames < 0:
            raise ConfigError(f"split.gap_frames must be >= 0, got {self.gap_frames}")
        require_ranges(self, {"val_fraction": "[0, 1)", "test_fraction": "[0, 1)", "gap_frames": "[0, 1e6]"})


# ---------------------------------------------------------------------------------------------
# Splits


def group_key(frame, by: str) -> str:
    """The split group of a frame (or of a ``FrameRef``): its scene, vehicle or log."""
    if by == "scene":
        return frame.scene_name
    if by == "vehicle":
        return frame.vehicle
    if by == "log":
        return frame.log_token
    raise HybridCalibError(f"split.by must be 'scene', 'vehicle' or 'log' for a group key, got {by!r}")


def assign_split(group: str, conf: SplitConfig) -> str:
    """One group name -> "train" | "val" | "test" (explicit lists first, then a salted hash)."""
    if group in conf.test_groups:
        return "test"
    if group in conf.val_groups:
        return "val"
    if conf.test_groups or conf.val_groups:
        return "train"
    u = keyed_seed(conf.salt, group) / 2.0**64
    if u < conf.test_fraction:
        return "test"
    if u < conf.test_fraction + conf.val_fraction:
        return "val"
    return "train"


def split_indices(frames: Sequence[RadarCameraFrame], split: str,
                  conf: SplitConfig | dict | None = None) -> list[int]:
    """Indices of ``frames`` in ``split`` ("train", "val", "test" or "all"). Whole groups (scenes /
    vehicles / logs) go to one split, so the test split never shares a scene with training."""
    conf = merge(SplitConfig, conf)
    if split == "all":
        return list(range(len(frames)))
    if split not in ("train", "val", "test"):
        raise HybridCalibError(f"split must be train, val, test or all, got {split!r}")
    # NuScenesRadarCamera indexes scene / vehicle / log per frame without loading it (``.frames``)
    refs = getattr(frames, "frames", None)
    items = refs if refs is not None and len(refs) == len(frames) else frames
    if conf.by == "time":
        roots = frames.root_of_each() if isinstance(frames, ConcatFrames) else None
        return [i for i, s in enumerate(time_split(items, conf, roots)) if s == split]
    keys = [group_key(items[i], conf.by) for i in range(len(frames))]
    _check_groups(set(keys), conf)
    return [i for i in range(len(frames)) if assign_split(keys[i], conf) == split]


def _check_groups(present: set[str], conf: SplitConfig) -> None:
    """``HybridCalibError`` when ``split.test_groups`` (or ``val_groups``) names none of the data's groups: every
    group not listed trains, so a misspelt held-out scene was trained on in silence (probe 79)."""
    for name, listed in (("test_groups", conf.test_groups), ("val_groups", conf.val_groups)):
        if listed and not present.intersection(listed):
            some = ", ".join(sorted(present)[:8]) + (", ..." if len(present) > 8 else "")
            raise HybridCalibError(f"split.{name} {list(listed)} names no {conf.by} of the data (its {conf.by}s: "
                                   f"{some}); every {conf.by} not listed trains, so nothing would be held out: fix "
                                   "the names")


def _timestamp_us(item) -> int:
    """Camera timestamp of a ``FrameRef`` (its sample_data record) or a loaded frame."""
    sd = getattr(item, "camera_sd", None)
    return int(sd["timestamp"]) if sd is not None else int(item.timestamp_camera_us)


def time_split(items: Sequence, conf: SplitConfig, roots: Sequence[str] | None = None) -> list[str]:
    """Per frame (``FrameRef`` or frame) "train" | "val" | "test" | "gap" for ``conf.by == "time"``
    (``SplitConfig`` docstring): within each scene of each root (``roots``: the root of each item, when several
    are read as one), in camera-time order, so a drive's parts do not depend on which other roots are listed (probe
    117: simulated roots all name their scenes scene-sim-veh-NNN, and two roots' were cut as one time line: a
    shorter root's frames all trained, and evaluate on that root alone called two of them test). A scene too short
    to hold every part with its gaps is an error naming it."""
    scenes: dict[tuple[str, str], list[int]] = {}
    for i, it in enumerate(items):
        scenes.setdefault((roots[i] if roots is not None else "", it.scene_name), []).append(i)
    out = ["gap"] * len(items)
    g = conf.gap_frames
    for (root, name), idx in scenes.items():
        idx = sorted(idx, key=lambda i: (_timestamp_us(items[i]), i))
        n = len(idx)
        n_test = int(round(conf.test_fraction * n))
        n_val = int(round(conf.val_fraction * n))
        n_train = n - n_test - n_val - g * ((n_test > 0) + (n_val > 0))
        if n_train < 1 or (conf.test_fraction > 0 and n_test < 1):
            raise HybridCalibError(
                f"split.by=time: scene {name}{f' of {root}' if root else ''} has {n} frames, too few for test "
                f"{conf.test_fraction}, val "
                f"{conf.val_fraction} and gaps of {g} frames; lower split.gap_frames or the fractions")
        parts = ["train"] * n_train
        if n_val:
            parts += ["gap"] * g + ["val"] * n_val
        if n_test:
            parts += ["gap"] * g + ["test"] * n_test
        for i, part in zip(idx, parts):
            out[i] = part
    return out


def open_frames(data: str | Path, version: str = SIM_VERSION, *, lidar: bool = True,
                options: dict | None = None) -> Sequence[RadarCameraFrame]:
    """The radar-camera frames of a nuScenes root (``hybrid_calib.data.nuscenes``), with the LiDAR
    keyframe when ``lidar`` and the root has one (the noise-resistant matcher needs it in training).
    ``options``: ``DataConfig`` overrides (nsweeps, scenes, vehicles, ...)."""
    from hybrid_calib.data.nuscenes import NuScenesRadarCamera

    options = dict(options or {})
    if lidar:
        options.setdefault("load_lidar", None)  # None: when the root has the channel (DataConfig)
    return NuScenesRadarCamera(data, version, conf=options)


class ConcatFrames(Sequence):
    """Several frame sequences (e.g. nuScenes roots) read as one; keeps the per-frame ``.frames``
    references that ``split_indices`` groups by, so scenes still go to one split each."""

    def __init__(self, parts: Sequence[Sequence[RadarCameraFrame]]):
        self.parts = list(parts)
        self.offsets = np.cumsum([0] + [len(p) for p in self.parts])

    def __len__(self) -> int:
        return int(self.offsets[-1])

    def __getitem__(self, i: int) -> RadarCameraFrame:
        if not -len(self) <= i < len(self):
            raise IndexError(f"frame {i} out of range ({len(self)} frames)")
        i %= len(self)
        k = int(np.searchsorted(self.offsets, i, side="right")) - 1
        return self.parts[k][i - int(self.offsets[k])]

    def root_of_each(self) -> list[str]:
        """Per frame, the root that holds it (its ``root`` path, else its position among the parts)."""
        names = [str(getattr(p, "root", "")) or f"part {k}" for k, p in enumerate(self.parts)]
        names = [n if names.count(n) == 1 else f"{n} (part {k})" for k, n in enumerate(names)]
        return [n for n, p in zip(names, self.parts) for _ in range(len(p))]

    def radar_motion_at(self, i: int) -> np.ndarray:
        """(4, 4) ``N`` of frame ``i`` from the root that holds it (``NuScenesRadarCamera.radar_motion_at``)."""
        k = int(np.searchsorted(self.offsets, i % len(self), side="right")) - 1
        return self.parts[k].radar_motion_at(i % len(self) - int(self.offsets[k]))

    @property
    def frames(self) -> list:
        refs = []
        for p in self.parts:
            r = getattr(p, "frames", None)
            refs.extend(r if r is not None and len(r) == len(p) else [p[j] for j in range(len(p))])
        return refs


def open_roots(roots: Sequence[str | Path], version: str = SIM_VERSION, *, lidar: bool = True,
               options: dict | None = None) -> Sequence[RadarCameraFrame]:
    """``open_frames`` over one or several roots (same version folder), concatenated in order."""
    parts = [open_frames(r, version, lidar=lidar, options=options) for r in roots]
    if not parts:
        raise HybridCalibError("no data root given")
    _shared_frames(roots, parts)
    from hybrid_calib.data.summary import timestamp_unit_warning

    for root, part in zip(roots, parts):  # calibrate and inspect said it; train and evaluate did not (probe 100)
        if line := timestamp_unit_warning(part):
            log.warning("%s: %s: the poses' checks and the radar's motion compensation read time from them; fix the "
                        "tables", root, line.removeprefix("warning: "))
    return parts[0] if len(parts) == 1 else ConcatFrames(parts)


def _shared_frames(roots: Sequence[str | Path], parts: Sequence) -> None:
    """``DataError`` when two roots hold frames of one camera keyframe token: the same recording listed twice (a
    copy of a root, a root and its exported copy, v1.0-mini's scenes inside v1.0-trainval). Frames are named by that
    token (evaluate's frames/, the depth and network caches): probe 101 read 82 frames as 41, the later root's
    predictions over the earlier's, with no word."""
    seen: dict[str, str] = {}  # token -> the root that holds it first
    for root, part in zip(roots, parts):
        refs = getattr(part, "frames", None) or []
        tokens = {ref.camera_sd["token"] for ref in refs if hasattr(ref, "camera_sd")}
        shared = sorted(t for t in tokens if t in seen)
        if shared:
            raise DataError(f"{len(shared)} of its {len(tokens)} frames are also frames of {seen[shared[0]]} (camera "
                            f"keyframe {shared[0]}, the same sample_data token): the same recording listed twice (a "
                            "copy of a root, or a scene in two releases); frames are named by that token, so pass "
                            "each root on its own (its own --out), or only one of them", path=str(root))
        seen.update({t: str(root) for t in tokens})


def index_skip_records(frames: Sequence[RadarCameraFrame]) -> list[dict]:
    """What the index of ``frames``' roots left out (a sample with no camera or radar keyframe, a record left out for
    its schema, a scene with no file on disk: ``NuScenesRadarCamera.skipped`` with index None), as skipped.json
    entries with ``index`` None: evaluate read "15 of 15 frames" and train said nothing where calibrate listed the
    sample with why (probe 100)."""
    out = []
    for part in getattr(frames, "parts", None) or [frames]:
        out += [{"index": None, "token": s.token, "file": s.path, "reason": s.reason}
                for s in getattr(part, "skipped", None) or () if getattr(s, "index", 0) is None]
    return out


def camera_token(frames: Sequence[RadarCameraFrame], fi: int) -> str:
    """The camera sample_data token of frame ``fi``, from the index when there is one (``.frames`` of
    ``NuScenesRadarCamera`` / ``ConcatFrames``), so that a frame with a corrupt file is not loaded for it."""
    refs = getattr(frames, "frames", None)
    if refs is not None and len(refs) == len(frames):
        ref = refs[fi]
        return ref.camera_sd["token"] if hasattr(ref, "camera_sd") else ref.camera_token
    return frames[fi].camera_token


# How evaluation draws a frame's start (``CalibDataset.perturbation``), recorded with evaluate's predictions: an --out
# whose predictions another rule drew is not tabled with this one's
EVAL_STARTS = "seed and camera token"


# ---------------------------------------------------------------------------------------------
# Dataset


class CalibDataset(torch.utils.data.Dataset):
    """Samples for RC-AutoCalib (see the module docstring for the fields).

    frames: any indexable sequence of ``RadarCameraFrame`` (``open_frames`` or a list).
    indices: which frames to use (``split_indices``); all when None.
    depth: a ``DepthEstimator`` (``CorruptedTruthDepth`` for the simulator); ``cache`` stores its
      output per frame.
    train: True draws a new perturbation every epoch (``set_epoch``); False fixes one per sample.
    """

    def __init__(self, frames: Sequence[RadarCameraFrame], conf: DatasetConfig | dict | None,
                 depth: DepthEstimator, *, indices: Sequence[int] | None = None,
                 cache: DepthCache | None = None, train: bool = True):
        self.frames = frames
        self.conf = merge(DatasetConfig, conf)
        perturbation_bounds(self.conf.perturbation)
        if self.conf.variant not in ("radar", "lidar"):
            raise HybridCalibError(f"DatasetConfig.variant must be 'radar' or 'lidar', got {self.conf.variant!r}")
        self.indices = list(range(len(frames))) if indices is None else list(indices)
        self.depth = depth
        self.cache = cache
        self.train = train
        self.epoch = 0
        self.bad: dict[int, str] = {}  # frame index -> reason, for frames that could not be loaded
        self.bad_files: dict[int, str | None] = {}  # frame index -> the file that was wrong (None if unknown)

    def __len__(self) -> int:
        return len(self.indices)

    def skip_records(self, index: bool = False) -> list[dict]:
        """The frames that could not be loaded so far: ``[{"index", "token", "file", "reason"}]`` sorted by
        frame index (``token``: the camera sample_data token; ``file``: the bad file, or None); with ``index``, first
        the samples the roots' index left out (``index_skip_records``)."""
        return (index_skip_records(self.frames) if index else []) + [
            {"index": int(fi), "token": camera_token(self.frames, fi), "file": self.bad_files.get(fi), "reason": reason}
            for fi, reason in sorted(self.bad.items())]

    def set_epoch(self, epoch: int) -> None:
        """Training draws new perturbations per epoch; evaluation ignores this."""
        self.epoch = int(epoch)

    def perturbation(self, i: int) -> np.ndarray:
        """The (6,) perturbation of sample ``i``: deterministic given the seed and, in training, the epoch and the
        frame's index in ``frames``; in evaluation the frame's camera token (so a frame keeps its start whatever the
        split, and whatever the order or company of the roots it was read with: by its index, ``evaluate --data A B``
        and ``--data B A`` gave every frame another start, and the table other figures: probe 114)."""
        c = self.conf
        fi = self.indices[i]
        g = (keyed_rng("train", c.seed, self.epoch, fi) if self.train else
             keyed_rng("eval", c.seed, camera_token(self.frames, fi)))
        return sample_perturbation(g, c.perturbation)

    def __getitem__(self, i: int) -> dict | None:
        fi = self.indices[i]
        try:
            frame = self.frames[fi]
            return self._sample(i, frame)
        except DataError as e:
            if fi not in self.bad:  # said once: a frame read again (a second pass, a rerun) was said twice
                log.warning("skipping frame %d: %s", fi, e)
            self.bad[fi] = str(e)
            self.bad_files[fi] = e.path
            return None

    def _sample(self, i: int, frame: RadarCameraFrame) -> dict:
        import cv2

        c = self.conf
        H, W = c.height, c.width
        image = frame.load_image()
        h0, w0 = image.shape[:2]
        if (w0, h0) != (frame.camera.width, frame.camera.height):
            raise DataError(f"image is {w0}x{h0} but the calibration says "
                            f"{frame.camera.width}x{frame.camera.height}", path=str(frame.image_path),
                            token=frame.camera_token)
        camera = frame.camera.scaled(W / w0, H / h0)
        resized = cv2.resize(image, (W, H), interpolation=cv2.INTER_AREA)
        if self.cache is not None:
            depth = self.cache.get(self.depth, frame, (H, W), image)
        else:
            depth = self.depth.estimate(frame, (H, W), image)
        if depth.shape != (H, W):
            raise DataError(f"depth estimator returned {depth.shape}, expected {(H, W)}", token=frame.camera_token)

        xi = self.perturbation(i)
        if c.variant == "lidar":  # the supplement's LiDAR-camera variant: calibrate T_cam_lidar
            if frame.lidar_points is None or frame.T_cam_lidar is None:
                raise DataError("the lidar variant needs the LiDAR sweep and T_cam_lidar; open the data with "
                                "load_lidar", token=frame.camera_token)
            T_gt = np.asarray(frame.T_cam_lidar, np.float64)
            T_init = perturb_camera_frame(T_gt, xi[:3], xi[3:])
            radar = np.asarray(frame.lidar_points, np.float64)[:, :3]
            radar = radar[np.all(np.isfinite(radar), axis=1)]
            # keep points in front of the camera under the (known) initial estimate, never the truth
            radar = radar[transform_points(T_init, radar)[:, 2] > 0.1]
        else:
            T_gt = np.asarray(frame.T_cam_radar, np.float64)
            T_init = perturb_camera_frame(T_gt, xi[:3], xi[3:])
            radar = np.asarray(frame.radar_points, np.float64).reshape(-1, 3)
            radar = radar[np.all(np.isfinite(radar), axis=1)]
        g = keyed_rng("subsample", c.seed, frame.camera_token)
        radar_pad, radar_mask = _pad(radar, c.max_radar_points, g)

        lidar_cam = np.zeros((0, 3))
        if frame.lidar_points is not None and frame.T_cam_lidar is not None:
            pts = transform_points(np.asarray(frame.T_cam_lidar, np.float64),
                                   np.asarray(frame.lidar_points, np.float64)[:, :3])
            uv, z = camera.project(pts)
            keep = (z > 0.1) & (z < c.lidar_max_depth_m) & camera.in_image(uv)
            lidar_cam = pts[keep]
        lidar_pad, lidar_mask = _pad(lidar_cam, c.max_lidar_points, g)
        # the share of the sweep's in-image points kept (the NR matcher's tau is the whole sweep's)
        lidar_fraction = min(1.0, c.max_lidar_points / len(lidar_cam)) if len(lidar_cam) else 1.0

        return {
            "image": torch.from_numpy(np.ascontiguousarray(resized.transpose(2, 0, 1))).float() / 255.0,
            "depth": torch.from_numpy(depth[None].astype(np.float32)),
            "K": torch.from_numpy(camera.K.astype(np.float32)),
            "radar": torch.from_numpy(radar_pad.astype(np.float32)),
            "radar_mask": torch.from_numpy(radar_mask),
            "T_init": torch.from_numpy(T_init.astype(np.float32)),
            "T_gt": torch.from_numpy(T_gt.astype(np.float32)),
            "lidar_cam": torch.from_numpy(lidar_pad.astype(np.float32)),
            "lidar_mask": torch.from_numpy(lidar_mask),
            "lidar_fraction": torch.tensor(lidar_fraction, dtype=torch.float32),
            "perturbation": torch.from_numpy(xi),
            "index": self.indices[i],
            "token": frame.camera_token,
            "vehicle": frame.vehicle,
            "timestamp_us": int(frame.timestamp_camera_us),
            "timestamp_radar_us": int(frame.timestamp_radar_us),
            # the file's compression (``learned.ood.jpeg_score``: the out-of-domain test); NaN when not a JPEG
            "jpeg_quality": float(q) if (q := jpeg_quality(frame.image_path)) is not None else float("nan"),
        }


def _pad(points: np.ndarray, n_max: int, g: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """(N, 3) -> (n_max, 3) zero-padded and an (n_max,) bool mask; a random subset when N > n_max."""
    if len(points) > n_max:
        points = points[np.sort(g.choice(len(points), n_max, replace=False))]
    out = np.zeros((n_max, 3), np.float64)
    mask = np.zeros(n_max, bool)
    out[: len(points)] = points
    mask[: len(points)] = True
    return out, mask


def collate(samples: list[dict | None]) -> dict | None:
    """Stack samples into a batch; ``None`` (bad frames) are dropped; None if nothing is left."""
    samples = [s for s in samples if s is not None]
    if not samples:
        return None
    out = {}
    for key, value in samples[0].items():
        if isinstance(value, torch.Tensor):
            out[key] = torch.stack([s[key] for s in samples])
        elif isinstance(value, int):
            out[key] = torch.tensor([s[key] for s in samples], dtype=torch.long)
        else:
            out[key] = [s[key] for s in samples]
    return out
