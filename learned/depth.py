"""Metric depth for the camera branch: pluggable estimators and a per-frame on-disk cache.

The network's camera front-view map is a *metric* depth image estimated from the RGB image (the
paper uses Depth Anything + ZoeDepth). Three estimators implement the same small interface:

- ``DepthAnythingEstimator``: a ``transformers`` Depth Anything model with a metric head, loaded
  only from a local directory the user gives (``local_files_only=True``; nothing is downloaded).
- ``LidarDepth`` (``lidar-densified``): the frame's LiDAR sweep projected through the dataset's
  LiDAR-camera extrinsic and hole-filled; for real roots when no local monocular model is at hand.
- ``CorruptedTruthDepth``: for the synthetic world. It takes the simulator's ground-truth depth and
  corrupts it the way monocular estimators err (global scale and shift error, smoothing across
  depth edges, range-growing noise), deterministically per frame, so the network never trains on
  perfect depth.

Every estimator has ``name``, ``config_hash()`` and
``estimate(frame, size_hw, image=None) -> (H, W) float32 metres`` (0 = unknown), where ``size_hw``
is the output (model input) size and ``image`` the (H0, W0, 3) uint8 RGB image when the caller has
already loaded it. ``DepthCache`` stores one ``.npy`` per (estimator, config hash, frame, size).
"""

from __future__ import annotations

import hashlib
import json
import os
from dataclasses import dataclass
from pathlib import Path
from typing import Protocol

import numpy as np

from hybrid_calib.atomic import atomic_path
from hybrid_calib.config import merge, require_ranges, save_json_atomic, to_dict
from hybrid_calib.data.files import NPZ_ERRORS, file_stamp
from hybrid_calib.data.frame import RadarCameraFrame
from hybrid_calib.errors import DataError, HybridCalibError
from hybrid_calib.seeds import keyed_rng


class DepthEstimator(Protocol):
    """What the dataset needs from a metric depth estimator."""

    name: str

    def config_hash(self) -> str: ...

    def estimate(self, frame: RadarCameraFrame, size_hw: tuple[int, int],
                 image: np.ndarray | None = None) -> np.ndarray: ...


def _hash_config(name: str, conf) -> str:
    blob = json.dumps({"name": name, "conf": to_dict(conf)}, sort_keys=True).encode()
    return hashlib.sha1(blob).hexdigest()[:12]


# ---------------------------------------------------------------------------------------------
# Corrupted ground truth (synthetic world)


@dataclass(frozen=True)
class CorruptedTruthConfig:
    seed: int = 0  # corruption seed; combined with the frame token so each frame is fixed
    scale_mean: float = 1.0  # mean global scale factor (1.0 = unbiased; 1.1 = 10 % too far)
    scale_std: float = 0.06  # std of the per-frame log scale error (monocular scale ambiguity)
    shift_mean_m: float = 0.0  # mean global additive depth shift, metres
    shift_std_m: float = 0.3  # std of the per-frame global shift, metres
    edge_blur_px: float = 1.5  # Gaussian sigma (output pixels) smoothing depth across object edges
    rel_noise_lowfreq: float = 0.04  # std of a smooth multiplicative error field (1 = 100 %)
    lowfreq_cells: int = 6  # the smooth field is drawn on this many cells across the width
    noise_rel: float = 0.01  # per-pixel noise std as a fraction of depth (grows linearly with range)
    noise_quad_per_m: float = 0.0005  # extra per-pixel std per metre^2 / metre: sigma += k * d^2
    min_depth_m: float = 0.5  # outputs are clipped to [min_depth_m, max_depth_m]
    max_depth_m: float = 200.0  # paper: depth range 0..200 m
    sky_depth_m: float = 0.0  # value written where the truth has no return (0 = unknown; a monocular model says ~max)

    def __post_init__(self):
        require_ranges(self, {"scale_mean": "(0, 10]", "scale_std": "[0, 2]", "shift_mean_m": "[-100, 100]",
                              "shift_std_m": "[0, 100]", "edge_blur_px": "[0, 100]", "rel_noise_lowfreq": "[0, 10]",
                              "lowfreq_cells": "[1, 1000]", "noise_rel": "[0, 10]", "noise_quad_per_m": "[0, 1]",
                              "min_depth_m": "[0, 1000]", "max_depth_m": "(0, 1000]", "sky_depth_m": "[0, 1000]"})


class CorruptedTruthDepth:
    """Ground-truth depth corrupted like a monocular metric estimator, deterministic per frame.

    ``estimate`` reads ``frame.load_depth()`` ((H0, W0) float32 metres, 0 = no return), resizes it
    to ``size_hw`` (nearest; no-return pixels stay 0 = unknown) and applies, in order:
    1. smoothing across depth edges: a normalised Gaussian blur over valid pixels (mixes foreground
       and background near boundaries, as dense estimators do),
    2. a smooth multiplicative error field ``1 + e(u, v)`` (low frequency),
    3. a global affine error ``s * d + b`` (per-frame scale ``s`` and shift ``b``),
    4. per-pixel noise with std ``noise_rel * d + noise_quad_per_m * d^2`` (grows with range),
    then clips to ``[min_depth_m, max_depth_m]``; pixels without a return get ``sky_depth_m``.
    Returns (H, W) float32 metres.
    """

    name = "corrupted-truth"

    def __init__(self, conf: CorruptedTruthConfig | dict | None = None):
        self.conf = merge(CorruptedTruthConfig, conf)

    def config_hash(self) -> str:
        return _hash_config(self.name, self.conf)

    def estimate(self, frame: RadarCameraFrame, size_hw: tuple[int, int],
                 image: np.ndarray | None = None) -> np.ndarray:
        truth = frame.load_depth()
        if truth is None:
            raise DataError(
                "CorruptedTruthDepth needs the simulator's ground-truth depth but this frame has none "
                "(depth_path is None); for real data pass --depth lidar-densified (the root's LiDAR) or a metric "
                "depth model: --depth depth-anything:/local/model/dir (DepthAnythingEstimator)",
                token=frame.camera_token)
        return self.corrupt(truth, size_hw, frame.camera_token)

    def corrupt(self, truth: np.ndarray, size_hw: tuple[int, int], token: str) -> np.ndarray:
        """(H0, W0) metres (0 = unknown) -> corrupted (H, W) float32 metres, fixed by ``token``."""
        import cv2

        c = self.conf
        H, W = int(size_hw[0]), int(size_hw[1])
        d = cv2.resize(np.asarray(truth, np.float32), (W, H), interpolation=cv2.INTER_NEAREST)
        valid = d > 0
        g = keyed_rng(c.seed, token)  # the same frame always gets the same corruption
        # 1. smoothing across edges (normalised convolution keeps unknown pixels out of the average)
        if c.edge_blur_px > 0:
            num = cv2.GaussianBlur(d * valid, (0, 0), c.edge_blur_px, borderType=cv2.BORDER_REFLECT)
            den = cv2.GaussianBlur(valid.astype(np.float32), (0, 0), c.edge_blur_px,
                                   borderType=cv2.BORDER_REFLECT)
            d = np.where(valid, num / np.maximum(den, 1e-6), 0.0).astype(np.float32)
        # 2. smooth multiplicative field
        if c.rel_noise_lowfreq > 0:
            gw = max(2, int(c.lowfreq_cells))
            gh = max(2, int(round(gw * H / W)))
            field = g.normal(0.0, c.rel_noise_lowfreq, size=(gh, gw)).astype(np.float32)
            field = cv2.resize(field, (W, H), interpolation=cv2.INTER_CUBIC)
            d = d * (1.0 + np.clip(field, -0.5, 0.5))
        else:
            g.normal(size=1)  # keep the stream aligned whatever the options
        # 3. global scale and shift
        s = c.scale_mean * float(np.exp(g.normal(0.0, c.scale_std)))
        b = c.shift_mean_m + float(g.normal(0.0, c.shift_std_m))
        d = s * d + b
        # 4. range-growing per-pixel noise
        sigma = c.noise_rel * d + c.noise_quad_per_m * d * d
        d = d + g.standard_normal(d.shape).astype(np.float32) * sigma
        out = np.where(valid, np.clip(d, c.min_depth_m, c.max_depth_m), c.sky_depth_m)
        return out.astype(np.float32)


# ---------------------------------------------------------------------------------------------
# LiDAR-densified depth (real nuScenes roots without a local monocular model)


# lidar-densified depth known at fewer pixels than this: the sweep does not see what the camera sees (60-90 % on
# the real scene-0916 and simulated highway and straight drives at the small preset's 200x96)
MIN_KNOWN_FRACTION = 0.05


@dataclass(frozen=True)
class LidarDepthConfig:
    min_depth_m: float = 1.0  # LiDAR returns nearer than this (ego body) are dropped
    max_depth_m: float = 200.0  # and farther than this
    occlusion_kernel_px: int = 5  # a return with a much nearer one in this window is background seen through
    occlusion_ratio: float = 0.8  # a gap between beams: it takes the nearer depth (nearer = < ratio x own)
    fill_kernels_px: tuple = (3, 5, 9, 17)  # hole filling: nearest-depth fill with growing square windows
    blur_px: float = 0.0  # optional smoothing (Gaussian sigma, output pixels) of the filled map

    def __post_init__(self):
        require_ranges(self, {"min_depth_m": "[0, 1000]", "max_depth_m": "(0, 1000]",
                              "occlusion_kernel_px": "[0, 1000]", "occlusion_ratio": "[0, 1]",
                              "fill_kernels_px": "[1, 1000]", "blur_px": "[0, 100]"})


class LidarDepth:
    """Metric depth from the frame's LiDAR sweep, projected through the dataset's (known) LiDAR-camera
    extrinsic and densified: for users without a local Depth Anything model, and for real nuScenes
    roots, where the LiDAR is calibrated to the camera and only the radar is in question.

    ``estimate``: points ``T_cam_lidar @ p`` in front of the camera are projected with K scaled to
    ``size_hw``; each pixel keeps its nearest return; a return with a much nearer one within
    ``occlusion_kernel_px`` is background seen between the beams of a foreground object and takes that
    depth; empty pixels then take the nearest depth within growing windows (``fill_kernels_px``, a
    min-filter over valid pixels), so foreground wins at edges.
    Pixels still empty (above the LiDAR's top beam: sky, tall structures) stay 0 = unknown.
    Returns (H, W) float32 metres. Needs ``frame.lidar_points`` and ``frame.T_cam_lidar``.
    """

    name = "lidar-densified"

    def __init__(self, conf: LidarDepthConfig | dict | None = None):
        self.conf = merge(LidarDepthConfig, conf)

    def config_hash(self) -> str:
        return _hash_config(self.name, self.conf)

    def estimate(self, frame: RadarCameraFrame, size_hw: tuple[int, int],
                 image: np.ndarray | None = None) -> np.ndarray:
        if frame.lidar_points is None or frame.T_cam_lidar is None:
            raise DataError("lidar-densified depth needs the frame's LiDAR sweep and the tables' LiDAR mount, and "
                            "this frame was read without them (the root has no LIDAR_TOP channel, or the LiDAR was not "
                            "loaded: --set data.load_lidar=false); pass another --depth: corrupted-truth on a "
                            "simulated root, depth-anything:/local/model/dir on any", token=frame.camera_token)
        cam = frame.camera.scaled(size_hw[1] / frame.camera.width, size_hw[0] / frame.camera.height)
        K = cam.K  # the same resized intrinsics the dataset gives the network
        pts = np.asarray(frame.lidar_points, np.float64)[:, :3]
        T = np.asarray(frame.T_cam_lidar, np.float64)
        depth = self.densify(pts @ T[:3, :3].T + T[:3, 3], K, size_hw)
        known = float(np.mean(depth > 0))
        if known < MIN_KNOWN_FRACTION:
            raise DataError(f"the LiDAR sweep gives a depth at only {100 * known:.1f} % of the image (a LiDAR that "
                            "sees what the camera sees: 60-90 %): its points lie behind or beside the camera, or the "
                            "file is not this frame's LiDAR; the frame is skipped (replace the file, or pass another "
                            "--depth)", token=frame.camera_token)
        return depth

    def densify(self, points_cam: np.ndarray, K: np.ndarray, size_hw: tuple[int, int]) -> np.ndarray:
        """(M, 3) camera-frame points (metres), K (3, 3) at ``size_hw`` -> (H, W) float32 metres (0 = unknown)."""
        import cv2

        c = self.conf
        H, W = int(size_hw[0]), int(size_hw[1])
        z = points_cam[:, 2]
        keep = (z > c.min_depth_m) & (z < c.max_depth_m)
        p, z = points_cam[keep], z[keep]
        u = np.floor(K[0, 0] * p[:, 0] / z + K[0, 2] + 0.5).astype(np.int64)
        v = np.floor(K[1, 1] * p[:, 1] / z + K[1, 2] + 0.5).astype(np.int64)
        inside = (u >= 0) & (u < W) & (v >= 0) & (v < H)
        depth = np.full(H * W, np.inf, np.float32)
        np.minimum.at(depth, v[inside] * W + u[inside], z[inside].astype(np.float32))
        depth = depth.reshape(H, W)
        if c.occlusion_kernel_px > 1:
            k = int(c.occlusion_kernel_px)
            near = cv2.erode(depth, np.ones((k, k), np.uint8), borderType=cv2.BORDER_REPLICATE)
            hidden = np.isfinite(depth) & (near < c.occlusion_ratio * depth)
            depth = np.where(hidden, near, depth)
        for k in c.fill_kernels_px:
            empty = ~np.isfinite(depth)
            if not empty.any():
                break
            near = cv2.erode(depth, np.ones((int(k), int(k)), np.uint8), borderType=cv2.BORDER_REPLICATE)
            depth = np.where(empty, near, depth)
        known = np.isfinite(depth)
        depth = np.where(known, depth, 0.0).astype(np.float32)
        if c.blur_px > 0 and known.any():
            num = cv2.GaussianBlur(depth, (0, 0), c.blur_px)
            den = cv2.GaussianBlur(known.astype(np.float32), (0, 0), c.blur_px)
            depth = np.where(known, num / np.maximum(den, 1e-6), 0.0).astype(np.float32)
        return depth


# ---------------------------------------------------------------------------------------------
# Depth Anything (transformers), local directory only


@dataclass(frozen=True)
class DepthAnythingConfig:
    device: str = "cpu"  # torch device the depth model runs on
    max_depth_m: float = 200.0  # predictions are clipped to (0, max_depth_m]
    dtype: str = "float32"  # float32 | float16 | bfloat16 (half precision on GPU only)

    def __post_init__(self):
        require_ranges(self, {"max_depth_m": "(0, 1000]"})


class DepthAnythingEstimator:
    """A ``transformers`` depth model with a metric head (Depth Anything V1/V2 metric, or any
    ``AutoModelForDepthEstimation`` with ``depth_estimation_type == "metric"``), loaded ONLY from
    ``local_dir`` (a directory written by ``save_pretrained``: ``config.json``, weights and
    ``preprocessor_config.json``). Nothing is fetched from a hub.

    ``estimate`` returns (H, W) float32 metres at ``size_hw`` (bicubic from the model's output).
    """

    def __init__(self, local_dir: str | Path, conf: DepthAnythingConfig | dict | None = None):
        self.conf = merge(DepthAnythingConfig, conf)
        self.local_dir = Path(local_dir)
        if not (self.local_dir / "config.json").is_file():
            raise HybridCalibError(
                f"depth model directory {self.local_dir} has no config.json: give a local directory "
                "written by save_pretrained() (config.json, model weights, preprocessor_config.json); "
                "models are never downloaded")
        try:
            import transformers
            from transformers import AutoImageProcessor, AutoModelForDepthEstimation
        except ImportError as e:  # pragma: no cover - depends on the environment
            raise HybridCalibError("DepthAnythingEstimator needs `pip install transformers`") from e
        import torch

        transformers.logging.set_verbosity_error()
        transformers.logging.disable_progress_bar()
        try:  # safetensors only: a pickled pytorch_model.bin is never loaded (it can run code)
            self.model = AutoModelForDepthEstimation.from_pretrained(self.local_dir, local_files_only=True,
                                                                     use_safetensors=True)
            self.processor = AutoImageProcessor.from_pretrained(self.local_dir, local_files_only=True)
        except Exception as e:  # noqa: BLE001 - the user's files, read by transformers: a damaged weights file was
            # an internal error (SafetensorError "header too large", an UnpicklingError: probe 109)
            files = sorted(p.name for p in self.local_dir.iterdir() if p.suffix in (".safetensors", ".bin"))
            raise HybridCalibError(f"could not load a depth model from {self.local_dir} (weights files there: "
                                   f"{files or 'none'}): {type(e).__name__}: {str(e)[:300]}; save it again with "
                                   "save_pretrained(..., safe_serialization=True)") from None
        kind = getattr(self.model.config, "depth_estimation_type", "relative")
        if kind != "metric":
            raise HybridCalibError(
                f"depth model in {self.local_dir} predicts {kind!r} depth; the network needs metric depth "
                "(a checkpoint with depth_estimation_type='metric', e.g. a Depth Anything metric model)")
        self.dtype = getattr(torch, self.conf.dtype)
        self.model.to(self.conf.device, dtype=self.dtype).eval()
        self.name = "depth-anything"
        self._weights_id = _directory_fingerprint(self.local_dir)

    def config_hash(self) -> str:
        blob = json.dumps({"conf": to_dict(self.conf), "weights": self._weights_id}, sort_keys=True)
        return hashlib.sha1(blob.encode()).hexdigest()[:12]

    def estimate(self, frame: RadarCameraFrame | None, size_hw: tuple[int, int],
                 image: np.ndarray | None = None) -> np.ndarray:
        if image is None:
            if frame is None:
                raise ValueError("DepthAnythingEstimator.estimate needs a frame or an image")
            image = frame.load_image()
        return self.predict(image, size_hw)

    def predict(self, image: np.ndarray, size_hw: tuple[int, int]) -> np.ndarray:
        """(H0, W0, 3) uint8 RGB -> (H, W) float32 metres at ``size_hw``."""
        import torch

        image = np.asarray(image)
        if image.ndim != 3 or image.shape[2] != 3 or image.dtype != np.uint8:
            raise ValueError(f"expected an (H, W, 3) uint8 RGB image, got {image.shape} {image.dtype}")
        inputs = self.processor(images=image, return_tensors="pt")
        pixel_values = inputs["pixel_values"].to(self.conf.device, dtype=self.dtype)
        with torch.inference_mode():
            pred = self.model(pixel_values=pixel_values).predicted_depth  # (1, h, w) metres
        pred = torch.nn.functional.interpolate(pred[:, None].float(), size=tuple(int(s) for s in size_hw),
                                               mode="bicubic", align_corners=False)[0, 0]
        return pred.clamp(1e-3, self.conf.max_depth_m).cpu().numpy().astype(np.float32)


def _directory_fingerprint(path: Path) -> str:
    """Names, sizes and mtimes of the files in a model directory: changes when the weights do."""
    items = sorted((p.name, p.stat().st_size, int(p.stat().st_mtime)) for p in path.iterdir() if p.is_file())
    return hashlib.sha1(json.dumps(items).encode()).hexdigest()[:12]


# ---------------------------------------------------------------------------------------------
# Cache


MAX_DEPTH_M = 1000.0  # no estimator's depth goes beyond (their max_depth_m are bounded by it)


class DepthCache:
    """Per-frame on-disk depth cache.

    Layout: ``root/<estimator name>-<config hash>/<frame token>_<W>x<H>.npy`` ((H, W) float32
    metres), with ``estimator.json`` (the estimator's name and hash) beside them. Files are written
    atomically (temp + rename), so a killed run never leaves a half-written entry. A different
    estimator config gets a different folder, so a changed config always misses.
    """

    def __init__(self, root: str | Path):
        self.root = Path(root)
        self.hits = 0
        self.misses = 0

    def path(self, estimator: DepthEstimator, token: str, size_hw: tuple[int, int], inputs: str = "") -> Path:
        from hybrid_calib.data.files import file_part

        name = f"{file_part(token)}{'-' + inputs if inputs else ''}_{size_hw[1]}x{size_hw[0]}.npy"
        return self.root / f"{estimator.name}-{estimator.config_hash()}" / name

    def get(self, estimator: DepthEstimator, frame: RadarCameraFrame, size_hw: tuple[int, int],
            image: np.ndarray | None = None) -> np.ndarray:
        """The cached depth of ``frame`` at ``size_hw``, computing and storing it on a miss. An entry is of the
        frame's token and its inputs (``depth_inputs``): two roots whose tokens coincide (a copy of a scene, edited)
        share a cache without reading each other's depth (probe 23)."""
        path = self.path(estimator, frame.camera_token, size_hw, depth_inputs(frame))
        if path.is_file():
            try:
                depth = np.load(path, allow_pickle=False)
                finite = depth[np.isfinite(depth)] if depth.shape == tuple(size_hw) else np.empty(0)
                if depth.dtype == np.float32 and finite.size and finite.min() >= 0 and finite.max() <= MAX_DEPTH_M:
                    self.hits += 1
                    return depth
            except NPZ_ERRORS:
                pass  # a corrupt entry (truncated, a pickle, not an array) is recomputed below
            # (so is one of another shape or type, without one finite depth, or beyond every estimator's range: an
            # entry scaled by 1000 was read as it was, probe 45: the hybrid 3.1 deg off instead of 0.3)
        self.misses += 1
        depth = np.asarray(estimator.estimate(frame, size_hw, image), dtype=np.float32)
        path.parent.mkdir(parents=True, exist_ok=True)
        meta = path.parent / "estimator.json"
        if not meta.is_file():
            save_json_atomic(meta, {"name": estimator.name, "config_hash": estimator.config_hash()})
        with atomic_path(path) as tmp:
            np.save(tmp, depth, allow_pickle=False)
        return depth


def depth_inputs(frame: RadarCameraFrame) -> str:
    """A short hash of what any depth estimator reads from ``frame``: its image and ground-truth depth files (resolved
    path, size, modification time), the intrinsics, and the LiDAR points with their extrinsic."""
    h = hashlib.sha1()
    for p in (frame.image_path, frame.depth_path):
        if p is not None:
            h.update(file_stamp(p).encode())
    for a in (frame.K, frame.T_cam_lidar, frame.lidar_points):
        if a is not None:
            h.update(np.ascontiguousarray(a).tobytes())
    return h.hexdigest()[:12]


def trained_with(train_config: dict | None, source: str | Path | None = None) -> str:
    """The depth spec a checkpoint (its JSON: ``source``) was trained with (its ``train_config["depth"]``;
    corrupted-truth, the training default, when it does not say). ``CheckpointError`` naming the file and the field
    when it names no estimator (probe 27: a damaged field read as if the user had passed a wrong ``--depth``)."""
    from hybrid_calib.errors import CheckpointError

    config = {} if train_config is None else train_config
    spec = config.get("depth", CorruptedTruthDepth.name) if isinstance(config, dict) else None
    known = spec in (CorruptedTruthDepth.name, LidarDepth.name) or (
        isinstance(spec, str) and spec.startswith("depth-anything:") and spec.split(":", 1)[1].strip())
    if not known:
        raise CheckpointError(f"the checkpoint's train_config.depth is {spec!r}, which names no depth estimator "
                              f"('{CorruptedTruthDepth.name}', '{LidarDepth.name}' or 'depth-anything:DIR'): the "
                              "checkpoint is damaged; fix the field, or pass --depth to say which depth to use",
                              path=None if source is None else str(source))
    return spec


# what --depth may be, in words (a message's advice)
DEPTH_CHOICES = ("corrupted-truth (a simulated root), lidar-densified (a root with its LiDAR) or "
                 "depth-anything:/local/model/dir (any)")


def check_depth_source(spec: str, root: str | Path, given: bool | str, option: str = "--depth") -> None:
    """``OptionError`` (``--depth``) when depth ``spec`` cannot be computed on the nuScenes ``root``: the simulator's
    truth for ``corrupted-truth``, the LiDAR's files for ``lidar-densified``. ``given``: ``spec`` is the --depth the
    user passed (else the checkpoint's; a string: the words for where the run chose it); ``option``: how the command
    takes it (``--depth``; fleet's ``--set depth``). Said once before the frames
    are read, by every command that runs a network (probe 23, probe 71: every frame was skipped in turn, a line
    each)."""
    from hybrid_calib.errors import OptionError

    root = Path(root)
    name = str(spec).split(":", 1)[0]
    folder = root / "samples" / "LIDAR_TOP"
    if name == CorruptedTruthDepth.name and not (root / "sim_truth").is_dir():
        why = (f"{spec} corrupts the simulator's ground-truth depth, and {root} has none (no sim_truth/ folder: a "
               "real root)")
    elif name == LidarDepth.name and not _has_files(folder):
        why = (f"{spec} densifies each frame's LiDAR sweep, and {root} has no LiDAR files ({folder} is missing or "
               "empty: no LiDAR, or a partial download)")
    elif name == LidarDepth.name and not os.access(folder, os.R_OK | os.X_OK):
        why = (f"{spec} densifies each frame's LiDAR sweep, and {folder} cannot be read (its permissions): make it "
               "readable")  # probe 80: a bare 'Permission denied' with no --depth advice
    else:
        return
    source = given if isinstance(given, str) else f"the {option} given" if given else "the checkpoint depth"
    # ``option``: how the command takes a depth (fleet: --set depth=...; probe 127: "pass another --depth" to a
    # command that has none)
    raise OptionError(option, f"{why} ({source}); pass another {option}: {DEPTH_CHOICES}")


def _has_files(folder: Path) -> bool:
    """Whether ``folder`` is a directory with an entry; a directory that cannot be listed counts as having files
    (``check_depth_source`` says its permissions)."""
    try:
        return folder.is_dir() and any(folder.iterdir())
    except OSError:
        return folder.is_dir()


def needs_lidar(spec: str) -> bool:
    """Does this depth spec read the frame's LiDAR sweep (so the root must be opened with it)?"""
    return spec == LidarDepth.name


def build_depth_estimator(spec: str, overrides: dict | None = None) -> DepthEstimator:
    """``"corrupted-truth"`` -> ``CorruptedTruthDepth``; ``"depth-anything:/path/to/dir"`` ->
    ``DepthAnythingEstimator`` from that local directory. ``overrides`` go to the estimator config."""
    if spec == CorruptedTruthDepth.name:
        return CorruptedTruthDepth(overrides)
    if spec == LidarDepth.name:
        return LidarDepth(overrides)
    if spec.startswith("depth-anything:"):
        if not spec.split(":", 1)[1].strip():
            raise HybridCalibError("--depth depth-anything: names no model directory; pass the local folder of a "
                                   "Depth Anything model (its config.json and weights), e.g. "
                                   "--depth depth-anything:/models/depth-anything-v2-small")
        return DepthAnythingEstimator(spec.split(":", 1)[1], overrides)
    raise HybridCalibError(
        f"unknown depth estimator {spec!r}: use 'corrupted-truth' (synthetic data with ground-truth "
        "depth), 'lidar-densified' (the frame's LiDAR through the known LiDAR-camera extrinsic) or "
        "'depth-anything:/local/model/dir'")
