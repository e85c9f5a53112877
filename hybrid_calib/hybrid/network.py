"""The network on one frame from a given start, and the on-disk cache of its outputs.

``NetworkRunner`` loads a checkpoint once, prepares each frame's inputs once (resized image,
estimated depth, padded radar: ``learned.dataset.CalibDataset``; the depth is cached on disk) and
runs the network from any start ``T_in`` (the closed loop's fused estimate, or a vehicle's start).
Its output (``NetworkOutput``) holds both row sets the measurement model chooses from (iteration 0:
measured against ``T_in`` only; the last iteration: correlated with the network's own SE(3)), the
estimate after every iteration and the RAW covariance (no ``cov_scale``, ``sigma_scale`` 1: the
hybrid's measurement model applies its own fitted scales, ``hybrid.measurement``).

``CascadeRunner`` chains two runners (a coarse network of the start range, then a refining network
trained on near-truth starts, range R0) into one runner with the same interface: the closed loop,
pure and pure-avg run the cascade as one network.

The network sees the radar points as recorded and the image at the camera's time, so what it estimates is the
frame's transform ``X N`` (docs/conventions.md "Transforms"; learned on ``frame.T_cam_radar``): points turned by
1 deg of yaw turned its output by 0.94-0.97 deg (12 frames, session 40). ``mount_pass`` runs it from a mount
estimate ``T`` as ``T N`` and reads its pass back on the mount (``on_mount``): on the real scene-0916 the radar's
keyframe is 34 ms after the camera's and ``N`` turns by 0.62 deg RMS (up to 2 deg in its turns), which every
learned method had taken for the mount's.

``OutputCache`` stores one ``.npz`` per (checkpoint, frame, start): every method that runs the
network from the same start on the same frame (pure, pure-avg, the hybrid's first frame; the fit
on validation scenes) reads the same outputs ("export once, evaluate many").
"""

from __future__ import annotations

import hashlib
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from factors.correspondences import Correspondences
from factors.io import FrameMeasurements, from_arrays, to_arrays
from hybrid_calib.data.files import NPZ_ERRORS, file_part
from hybrid_calib.errors import HybridCalibError
from hybrid_calib.geometry import nearest_rigid

SHIPPED = Path(__file__).resolve().parents[2] / "learned" / "checkpoints"


def shipped_checkpoint(start_range: str) -> Path:
    """The shipped small checkpoint trained for ``start_range`` ("R0", "R1" or "R2"; "reference" -> R1)."""
    name = {"R2": "small-sim-r2.json", "R0": "small-sim-r0.json"}.get(start_range, "small-sim-r1.json")
    path = SHIPPED / name
    if not path.is_file():
        raise HybridCalibError(f"the shipped checkpoint {path} is missing; pass --checkpoint")
    return path


def refine_checkpoint(spec: str) -> Path | None:
    """The refining network of the cascade: ``""``/``"none"`` -> None, ``"shipped"`` -> the shipped R0
    checkpoint, anything else a checkpoint path."""
    if spec in ("", "none"):
        return None
    return shipped_checkpoint("R0") if spec == "shipped" else Path(spec)


@dataclass(frozen=True)
class NetworkOutput:
    """One pass of the network on one frame.

    T_in: (4, 4) the start it was given. T_iters: (N, 4, 4) the estimate after each iteration.
    cov_raw: (6, 6) covariance of ``T_iters[-1]`` (right tangent, radar frame, [rad, m]) without
    the checkpoint's ``cov_scale``. rows_first / rows_last: the exported rows of iteration 0 / the
    last iteration, ``sigma_px`` unscaled (pixels of the model-input image, ``K`` of that image).
    seconds: wall time of the pass (forward + export), CPU.
    ood_descriptor / ood_signals: the out-of-domain features of the pass (``learned.ood.frame_features``;
    empty for outputs made without them); ``NetworkRunner.ood_score`` reads them.
    image_structure: the camera image's own test (``learned.ood.image_structure`` of the model-input image; NaN
    for outputs made without it). jpeg_quality: the camera file's (``data.image_header.jpeg_quality``; NaN when it
    is not a JPEG), the other test of the image before any feature (``learned.ood.jpeg_score``). image_luminance: the
    model-input image's mean grey level, 0..1 (``learned.ood.image_luminance``; words only:
    ``NetworkRunner.ood_cause``).
    """

    T_in: np.ndarray
    T_iters: np.ndarray
    cov_raw: np.ndarray
    rows_first: Correspondences
    rows_last: Correspondences
    seconds: float
    ood_descriptor: np.ndarray = field(default_factory=lambda: np.zeros(0))
    ood_signals: np.ndarray = field(default_factory=lambda: np.zeros(0))
    image_structure: float = float("nan")
    jpeg_quality: float = float("nan")
    image_luminance: float = float("nan")

    @property
    def T(self) -> np.ndarray:
        return self.T_iters[-1]

    @property
    def finite(self) -> bool:
        """Whether the estimates, the covariance and the rows are all finite (a depth map of NaN made them NaN)."""
        arrays = (self.T_in, self.T_iters, self.cov_raw, *(a for c in (self.rows_first, self.rows_last)
                                                          for a in (c.points_radar, c.pixels, c.sigma_px)))
        return all(np.isfinite(np.asarray(a, np.float64)).all() for a in arrays)

    def to_arrays(self) -> dict[str, np.ndarray]:
        d = {"T_in": self.T_in, "T_iters": self.T_iters, "cov_raw": self.cov_raw,
             "seconds": np.array(self.seconds), "ood_descriptor": self.ood_descriptor, "ood_signals": self.ood_signals,
             "image_structure": np.array(self.image_structure), "jpeg_quality": np.array(self.jpeg_quality),
             "image_luminance": np.array(self.image_luminance)}
        for prefix, c in (("first_", self.rows_first), ("last_", self.rows_last)):
            d.update({prefix + k: v for k, v in to_arrays(FrameMeasurements(c)).items()})
        return d

    @classmethod
    def from_arrays(cls, z) -> NetworkOutput:
        rows = [from_arrays({k[len(p):]: z[k] for k in z.files if k.startswith(p)}).corr
                for p in ("first_", "last_")]
        T_in, T_iters, cov = (np.asarray(z[k], np.float64) for k in ("T_in", "T_iters", "cov_raw"))
        if T_in.shape != (4, 4) or T_iters.ndim != 3 or T_iters.shape[1:] != (4, 4) or not len(T_iters) \
                or cov.shape != (6, 6):  # probe 63: a damaged entry failed the trial instead of being recomputed
            raise ValueError(f"network output of shapes T_in {T_in.shape}, T_iters {T_iters.shape}, cov_raw "
                             f"{cov.shape}")
        # an entry without the ood arrays or the image's test (an older cache) is a miss (KeyError)
        return cls(T_in, T_iters, cov, rows[0], rows[1], float(z["seconds"]),
                   np.asarray(z["ood_descriptor"], np.float64), np.asarray(z["ood_signals"], np.float64),
                   float(z["image_structure"]), float(z["jpeg_quality"]), float(z["image_luminance"]))


def _start_key(T: np.ndarray) -> str:
    return hashlib.sha1(np.round(np.asarray(T, np.float64), 9).tobytes()).hexdigest()[:16]


class OutputCache:
    """``root/<token>-<hash of T_in>.npz`` per network pass (atomic writes; a corrupt entry is a miss).

    ``network``: the identity of the network and its data that make the outputs (``NetworkRunner.key``: the
    checkpoint's files, the depth estimator and ``NuScenesRadarCamera.identity``), stored in each entry; an entry of
    another network (the same ``--out`` rerun with another ``--checkpoint``, ``--refine`` or ``--depth``) or of other
    data (another root whose tokens coincide, a root changed since) is a miss and is overwritten. ""
    (a reader that does not know the network) accepts any entry."""

    def __init__(self, root: str | Path, network: str = ""):
        self.root = Path(root)
        self.network = network
        self._warned = False

    def path(self, token: str, T_in: np.ndarray) -> Path:
        return self.root / f"{file_part(token)}-{_start_key(T_in)}.npz"

    def get(self, token: str, T_in: np.ndarray) -> NetworkOutput | None:
        p = self.path(token, T_in)
        if not p.is_file():
            return None
        try:
            with np.load(p, allow_pickle=False) as z:
                if self.network and ("network" not in z.files or str(z["network"]) != self.network):
                    return None  # another network's output (or an entry older than the key): recomputed
                out = NetworkOutput.from_arrays(z)
                # and its out-of-domain features and time (probe 65: NaN features turned the domain test off)
                ok = out.finite and all(np.isfinite(a).all() for a in (out.ood_descriptor, out.ood_signals)) \
                    and np.isfinite(out.seconds) and out.seconds >= 0 and np.isfinite(out.image_structure)
                # and it is this frame's pass from this start (probe 109: another frame's entry under this one's name
                # was used in silence, its out-of-domain score too)
                mine = out.rows_first.frame_id == str(token) and np.allclose(out.T_in, T_in, rtol=0.0, atol=1e-8)
                return out if ok and mine else None
        except (*NPZ_ERRORS, HybridCalibError):  # a row array the measurement format refuses (DataError), too
            return None  # a damaged entry (truncated, not a zip, a missing key, misshapen, not numbers) is recomputed

    def put(self, token: str, out: NetworkOutput) -> None:
        """Keep one pass (atomically). A cache is recomputable: an entry that cannot be written (a directory in
        its place, a full disk) is warned about once and the run goes on."""
        import sys

        from hybrid_calib.atomic import atomic_path

        p = self.path(token, out.T_in)
        try:
            p.parent.mkdir(parents=True, exist_ok=True)
            with atomic_path(p) as tmp:
                np.savez(tmp, **out.to_arrays(), network=np.array(self.network))
        except (OSError, HybridCalibError) as e:
            if not self._warned:
                self._warned = True
                print(f"network cache: {p} could not be written ({e}); going on without caching this pass (and "
                      "saying so once)", file=sys.stderr)


def clear_own_caches(out: str | Path, cache_dir: str = "", depth_cache: str = "") -> None:
    """``--overwrite``: empty the network-output and depth caches a run keeps in its own ``out`` (``network-cache``,
    ``depth-cache``; a folder the config names, ``cache_dir`` / ``depth_cache``, is the user's and kept), so that the
    run recomputes from the data as they are now: their entries are keyed by frame token (and start), which a root
    re-made at the same path keeps (measured: the old answer came back after the data changed)."""
    import shutil

    for given, name in ((cache_dir, "network-cache"), (depth_cache, "depth-cache")):
        if not given:
            shutil.rmtree(Path(out) / name, ignore_errors=True)


def network_key(checkpoint: str | Path, depth_name: str, depth_hash: str) -> str:
    """The identity of a network's outputs (``OutputCache``): the checkpoint (``learned.checkpoint.checkpoint_digest``)
    and its depth input."""
    from learned.checkpoint import checkpoint_digest

    return hashlib.sha1(f"{depth_name}/{depth_hash}/{checkpoint_digest(checkpoint)}".encode()).hexdigest()[:16]


def on_mount(out: NetworkOutput, N: np.ndarray) -> NetworkOutput:
    """``out``, a pass on a frame's transform ``X N`` (``N`` (4, 4): the radar's motion between its and the camera's
    timestamps, radar frame), as a pass on the mount ``X``: its transforms by ``N^-1``, its right-perturbation
    covariance by ``Ad_N`` (``T Exp(xi) N^-1 = T N^-1 Exp(Ad_N xi)``), its rows' points moved by ``N``."""
    import dataclasses

    from hybrid_calib.geometry import without_motion

    T_iters, cov = without_motion(out.T_iters, N, out.cov_raw)
    return dataclasses.replace(out, T_in=without_motion(out.T_in, N)[0], T_iters=T_iters, cov_raw=cov,
                               rows_first=out.rows_first.moved(N), rows_last=out.rows_last.moved(N))


def mount_pass(runner, index: int, T: np.ndarray) -> NetworkOutput | None:
    """The network (``NetworkRunner`` or ``CascadeRunner``) on frame ``index`` from the mount estimate ``T`` (4, 4):
    run from the frame's transform ``T N`` and read back on the mount (``on_mount``; module doc); None for a bad
    frame (``runner.bad_reason``)."""
    N = runner.radar_motion(index)
    out = runner.run(index, np.asarray(T, np.float64) @ N)
    return None if out is None else on_mount(out, N)


def frames_motion(frames, index: int) -> np.ndarray:
    """(4, 4) ``N`` of frame ``index`` of ``frames`` from its tables (``radar_motion_at`` of ``NuScenesRadarCamera``
    and ``learned.dataset.ConcatFrames``); the identity for frames that do not say (in-memory test frames) or whose
    poses do not read (the frame's own reading then refuses it, naming why)."""
    from hybrid_calib.errors import DataError

    motion = getattr(frames, "radar_motion_at", None)
    if motion is None:
        return np.eye(4)
    try:
        return np.asarray(motion(index), np.float64)
    except (DataError, KeyError, IndexError, AttributeError):
        return np.eye(4)


def network_depth(train_config: dict | None, checkpoint_path, depth: str = ""):
    """(spec, ``learned.depth`` estimator) the network of a checkpoint reads: ``depth`` ("" = the checkpoint's training
    depth, ``learned.depth.trained_with``), with the training run's depth options when it is that same spec. The one
    rule of ``NetworkRunner`` and of the report's attention figure (probe 141: the figure chose its own)."""
    from learned.depth import build_depth_estimator, trained_with

    trained = train_config or {}
    name = depth or trained_with(trained, checkpoint_path)
    opts = trained.get("depth_options", {}) if name == trained.get("depth") else {}
    return name, build_depth_estimator(name, opts)


class NetworkRunner:
    """The network of a checkpoint over the frames of one dataset (see the module doc).

    frames: the indexable frames (``learned.dataset.open_frames``); depth: estimator spec ("" = the
    checkpoint's training depth); cache_dir: network-output cache ("" = none); depth_cache: folder;
    device: torch device of the network ("cpu", "cuda"); outputs are always numpy on the CPU.
    """

    def __init__(self, checkpoint: str | Path, frames, depth: str = "", cache_dir: str | Path = "",
                 depth_cache: str | Path = "", threads: int = 2, min_confidence: float = 0.1,
                 model_factory=None, device: str = "cpu"):
        import torch

        from learned.checkpoint import load_model
        from learned.dataset import CalibDataset, DatasetConfig
        from learned.depth import DepthCache
        from learned.ood import ood_model_of

        torch.set_num_threads(max(1, threads))
        self.device = torch.device(device)
        self.model, self.ckpt = load_model(checkpoint, device=self.device, model_factory=model_factory)
        self.ood, self.ood_note = ood_model_of(self.ckpt.export, str(self.ckpt.path))
        trained = self.ckpt.train_config or {}
        self.depth_name, estimator = network_depth(trained, self.ckpt.path, depth)
        H, W = (int(v) for v in self.model.cfg.input_hw)
        self.range = str(trained.get("perturbation", "R1"))
        dconf = DatasetConfig(height=H, width=W, max_radar_points=512, max_lidar_points=0,
                              perturbation=self.range, seed=0, variant=self.model.cfg.variant)
        self.dataset = CalibDataset(frames, dconf, estimator,
                                    cache=DepthCache(depth_cache) if depth_cache else None, train=False)
        # the outputs are of this network on these data: a cache shared by roots whose tokens coincide (a copy of a
        # scene, edited; compare's one cache for all its roots) returned one root's passes for the other's frames,
        # bit-identical (probe 23)
        self.key = hashlib.sha1(f"{network_key(self.ckpt.path, self.depth_name, self.dataset.depth.config_hash())}/"
                                f"{getattr(frames, 'identity', '')}".encode()).hexdigest()[:16]
        self.cache = OutputCache(cache_dir, self.key) if cache_dir else None
        self.min_confidence = float(min_confidence)
        self._samples: dict[int, dict | None] = {}
        self._not_finite: dict[int, str] = {}  # frames whose pass came out non-finite: why (bad_reason)

    @property
    def checkpoint(self) -> str:
        """The checkpoint's path, absolute: a result records it, and a relative one was read from another folder by
        report, which drew another network's attention under this name (probe 109)."""
        return str(Path(self.ckpt.path).resolve())

    def sample(self, index: int) -> dict | None:
        """The prepared inputs of frame ``index`` (None when its files are bad: ``bad_reason``)."""
        if index not in self._samples:
            self.dataset.indices = [index]
            self._samples = {index: self.dataset[0]}  # keep one: a drive is visited once per frame
        return self._samples[index]

    def bad_reason(self, index: int) -> str:
        return self.dataset.bad.get(index, "") or self._not_finite.get(index, "")

    def token(self, index: int) -> str:
        from learned.dataset import camera_token

        return camera_token(self.dataset.frames, index)

    def radar_motion(self, index: int) -> np.ndarray:
        """(4, 4) ``N`` of frame ``index`` (``frames_motion``)."""
        return frames_motion(self.dataset.frames, index)

    def run(self, index: int, T_in: np.ndarray) -> NetworkOutput | None:
        """The network on frame ``index`` from ``T_in`` (4, 4); cached; None for a bad frame."""
        token = self.token(index)
        if self.cache is not None and (hit := self.cache.get(token, T_in)) is not None and self._fits(hit):
            return hit
        s = self.sample(index)
        if s is None:
            return None
        out = self.forward(s, T_in)
        if not out.finite:  # a frame, not the run: skipped with why (its inputs, or the checkpoint's weights)
            from learned.dataset import collate
            from learned.export import not_finite_reason
            from learned.train import model_inputs

            self._not_finite[index] = not_finite_reason(token, model_inputs(collate([s])), 0, str(self.checkpoint))
            return None
        if self.cache is not None:
            self.cache.put(token, out)
        return out

    def _fits(self, hit: NetworkOutput) -> bool:
        """Whether a cached pass is one this runner can use: its out-of-domain features fit the checkpoint's fitted
        model (probe 63: an entry whose features had another length was a hit, and the run failed blaming the
        checkpoint); a damaged one is recomputed."""
        from learned.ood import OODError

        try:
            self.ood_score(hit)
        except (OODError, ValueError, IndexError, TypeError):
            return False
        return True

    def network_cov(self, out: NetworkOutput) -> np.ndarray:
        """(6, 6) the network's own covariance of ``out.T`` with the checkpoint's evaluate-fitted
        ``cov_scale`` (what the pure methods report)."""
        s = np.broadcast_to(np.asarray(self.ckpt.export.get("cov_scale", 1.0), np.float64), (6,))
        return (np.sqrt(s)[:, None] * out.cov_raw) * np.sqrt(s)[None, :]

    def ood_score(self, out: NetworkOutput) -> float:
        """The pass's out-of-domain score (``learned.ood``: > 1 out of domain): the density model's, raised to the
        camera image's own test where the image shows no scene (``learned.ood.image_score``); NaN when the
        checkpoint has no ``export.ood`` (``ood_note`` says so) or the output carries no features."""
        from learned.ood import raised_score

        density = self._density(out)
        return float("nan") if density is None else raised_score(density, out.image_structure, out.jpeg_quality)

    def ood_cause(self, out: NetworkOutput) -> tuple[str, str]:
        """(cause, words) for an out-of-domain pass whose camera image shows a cause (``learned.ood.image_cause``: the
        image's or the file's test scoring it at or above the density model, else an image darker or brighter than
        the training images'; the cause a key of ``learned.ood.CAUSES``); ("", "") otherwise, where the general reason
        holds (probe 89: a dark view of a road the density model scored 4.15 was said to show no scene, its image
        test giving 1.11)."""
        from learned.ood import image_cause

        density = self._density(out)
        if density is None:
            return "", ""
        return image_cause(density, out.image_structure, out.jpeg_quality, out.image_luminance)

    def _density(self, out: NetworkOutput) -> float | None:
        """The density model's score of the pass's features; None without a model or features."""
        if self.ood is None or not out.ood_descriptor.size:
            return None
        from learned.ood import OODError

        try:
            return float(self.ood.score({"descriptor": out.ood_descriptor, "signals": out.ood_signals})[0])
        except OODError as e:  # fitted on another network's features
            raise OODError(f"checkpoint {self.checkpoint}: {e}") from None

    def forward(self, s: dict, T_in: np.ndarray) -> NetworkOutput:
        """The network on a prepared sample ``s`` (``sample``, possibly altered) from ``T_in``; not cached."""
        import dataclasses

        import torch

        from learned.dataset import collate
        from learned.export import ExportConfig, export_correspondences
        from learned.ood import frame_features, image_luminance, image_structure
        from learned.train import model_inputs, to_device

        t0 = time.perf_counter()
        batch = collate([{**s, "T_init": torch.from_numpy(np.asarray(T_in, np.float32))}])
        inputs = to_device(model_inputs(batch), self.device)
        inputs["token"] = batch["token"]
        inputs["timestamp_us"] = batch["timestamp_us"]
        with torch.no_grad():
            out = self.model(inputs)
            rows = []
            for it in (0, -1):
                conf = ExportConfig(iteration=it, sigma_scale=1.0, cov_scale=1.0, min_confidence=self.min_confidence)
                corr, cov = export_correspondences(self.model, out, inputs, conf)
                rows.append(dataclasses.replace(corr[0], frame_id=str(batch["token"][0])))
            feats = frame_features(out)
        # float32 in the network: orthonormal to ~1e-7 only; the estimate a result reports is an exact rigid transform
        # (a non-finite pass is kept as it is: ``run`` skips its frame and says why; an SVD of NaN raised, probe 33)
        raw = [T[0].double().cpu().numpy() for T in out["T_iters"]]
        T_iters = np.stack([nearest_rigid(T) if np.all(np.isfinite(T)) else T for T in raw])
        return NetworkOutput(np.asarray(T_in, np.float64), T_iters, np.asarray(cov[0], np.float64), rows[0], rows[1],
                             time.perf_counter() - t0, feats["descriptor"][0], feats["signals"][0],
                             image_structure(s["image"]), float(s.get("jpeg_quality", float("nan"))),
                             image_luminance(s["image"]))


class CascadeRunner:
    """Two runners as one (module doc): the coarse network from ``T_in``, then the refining network
    from the coarse estimate. Its ``NetworkOutput``: ``T_in`` the loop's start, ``T_iters`` every
    iteration of both stages, ``cov_raw``, ``rows_last`` and the out-of-domain features the refining
    network's, ``rows_first`` the coarse network's iteration 0 (measured against ``T_in`` only),
    ``seconds`` both passes.
    ``ckpt`` (whose export block the measurement model reads) is the refining network's; ``range``
    (the starts the cascade accepts) the coarse one's. Composite outputs are cached in ``cache_dir``,
    each stage's in ``cache_dir/coarse`` and ``cache_dir/refine``."""

    def __init__(self, coarse: NetworkRunner, refine: NetworkRunner, cache_dir: str | Path = ""):
        self.coarse, self.refine = coarse, refine
        self.key = hashlib.sha1(f"cascade/{coarse.key}/{refine.key}".encode()).hexdigest()[:16]
        self.cache = OutputCache(cache_dir, self.key) if cache_dir else None
        self.ckpt, self.range = refine.ckpt, coarse.range
        self.depth_name = coarse.depth_name
        self.ood, self.ood_note = refine.ood, refine.ood_note  # the features are the refining pass's

    def ood_score(self, out: NetworkOutput) -> float:
        return self.refine.ood_score(out)

    def ood_cause(self, out: NetworkOutput) -> tuple[str, str]:
        return self.refine.ood_cause(out)

    @property
    def checkpoint(self) -> str:
        return f"{self.coarse.checkpoint} -> {self.refine.checkpoint}"

    def bad_reason(self, index: int) -> str:
        return self.coarse.bad_reason(index) or self.refine.bad_reason(index)

    def network_cov(self, out: NetworkOutput) -> np.ndarray:
        """(6, 6) the covariance the cascade reports: its last (refining) stage's, with that checkpoint's scale."""
        return self.refine.network_cov(out)

    def token(self, index: int) -> str:
        return self.coarse.token(index)

    def radar_motion(self, index: int) -> np.ndarray:
        return self.coarse.radar_motion(index)

    def run(self, index: int, T_in: np.ndarray) -> NetworkOutput | None:
        token = self.token(index)
        if self.cache is not None and (hit := self.cache.get(token, T_in)) is not None:
            return hit
        first = self.coarse.run(index, T_in)
        if first is None:
            return None
        second = self.refine.run(index, first.T)
        if second is None:
            return None
        out = NetworkOutput(np.asarray(T_in, np.float64), np.concatenate([first.T_iters, second.T_iters]),
                            second.cov_raw, first.rows_first, second.rows_last, first.seconds + second.seconds,
                            second.ood_descriptor, second.ood_signals, second.image_structure,
                            second.jpeg_quality, second.image_luminance)
        if self.cache is not None:
            self.cache.put(token, out)
        return out


def build_runner(checkpoint: str | Path, refine: str | Path | None, frames, depth: str = "",
                 cache_dir: str | Path = "", depth_cache: str | Path = "", threads: int = 1):
    """A ``NetworkRunner`` of ``checkpoint``, or, with ``refine``, the ``CascadeRunner`` of the two (the
    refining network uses the coarse one's depth estimator and the same depth cache)."""
    sub = (lambda name: str(Path(cache_dir) / name)) if (cache_dir and refine) else (lambda name: cache_dir)
    coarse = NetworkRunner(checkpoint, frames, depth, sub("coarse"), depth_cache, threads)
    if not refine:
        return coarse
    fine = NetworkRunner(refine, frames, coarse.depth_name, sub("refine"), depth_cache, threads)
    if tuple(fine.model.cfg.input_hw) != tuple(coarse.model.cfg.input_hw):
        raise HybridCalibError(f"the refining checkpoint {refine} takes {tuple(fine.model.cfg.input_hw)} inputs, the "
                               f"coarse one {checkpoint} {tuple(coarse.model.cfg.input_hw)}: use a pair of one preset")
    return CascadeRunner(coarse, fine, cache_dir)
