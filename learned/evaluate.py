"""Evaluation, export-then-evaluate (as in glue-factory).

1. ``export_pure`` (method ``pure``; any method in ``METHODS``): run it over a FIXED list of
   (frame, T_init) — the test split with one perturbation per sample fixed by (seed, the frame's camera token) — and
   store, per frame, ``OUT/frames/<token>.npz``: a measurement file (``factors.io``, the format
   ``hybrid-calib calibrate --correspondences OUT`` reads) with the exported correspondence rows, the
   frame's token, vehicle and timestamps, and the network block: ``T_cam_radar`` = the final estimate,
   ``cov`` its (6, 6) covariance (when the exporter gives one of that shape), ``iteration`` the
   iteration the rows came from, ``T_start`` the perturbed start; plus the evaluation's own keys:
     T_gt (4, 4), T_iters (N, 4, 4) the estimate after every iteration (float64), perturbation (6,),
     index (), and ``uncertainty`` when the exporter's per-frame uncertainty is not a (6, 6) covariance.
   ``OUT/export_config.json`` holds the evaluation config, the checkpoint and its model config.
   Frames already exported are skipped (``overwrite=False``); a frame whose files are bad (a corrupt
   radar PCD or image, ...) is listed in ``OUT/skipped.json`` (``[{"index", "token", "file",
   "reason"}]``, written on every run; first, with ``index`` null, the samples the roots' index left out) and the
   run goes on.
2. ``evaluate_predictions``: read those files and compute the paper's table with
   ``hybrid_calib.metrics`` (rotation Mean/Roll/Pitch/Yaw in degrees, translation Mean/X/Y/Z in cm,
   geodesic angle and translation norm) for the initial error, every iteration and the final
   estimate. ``write_report`` saves it as ``results.json`` + ``results.md``.

Methods: ``pure`` = the network alone (``METHODS``); a ``hybrid`` method registers an exporter with
the same signature that writes the same per-frame files (T_iters may hold one final estimate).
"""

from __future__ import annotations

import json
import shutil
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import torch

from hybrid_calib.atomic import finished, remove_temporaries
from hybrid_calib.config import (
    changed_options,
    freeze_dict_fields,
    merge,
    read_out_record,
    require_ranges,
    save_json_atomic,
    save_text_atomic,
    to_dict,
)
from hybrid_calib.data.files import read_npz, watch_roots
from hybrid_calib.data.frame import RadarCameraFrame
from hybrid_calib.errors import DataError, HybridCalibError
from hybrid_calib.metrics import (
    METRIC_KEYS,
    STD_KEYS_RADAR,
    consistency,
    extrinsic_error,
    format_table,
    summarize,
)
from hybrid_calib.metrics import nees as nees_of
from learned.dataset import EVAL_STARTS, CalibDataset, DatasetConfig, SplitConfig, camera_token, collate, split_indices
from learned.depth import DepthCache, build_depth_estimator


@dataclass(frozen=True)
class EvalConfig:
    method: str = "pure"  # "pure" (network only); "hybrid" is registered in METHODS by the hybrid
    perturbation: str = "R1"  # R1 (+-10 deg, +-0.25 m) or R2 (+-20 deg, +-1.5 m)
    split: str = "test"  # which split of the data ("test", "val", "train", or "all" for a held-out root)
    seed: int = 1000  # perturbation seed; differs from training's so starts are never seen in training
    max_frames: int = 0  # evaluate at most this many frames of the split (0 = all)
    batch_size: int = 4  # frames per forward pass
    threads: int = 2  # torch CPU threads
    device: str = "cpu"  # torch device
    max_radar_points: int = 512  # Nmax radar points per sample
    max_lidar_points: int = 0  # Mmax LiDAR points: none, the model uses LiDAR only for its training loss
    depth: str = "corrupted-truth"  # depth estimator: corrupted-truth | depth-anything:/local/dir
    depth_options: dict = field(default_factory=dict)  # overrides of the depth estimator's config
    depth_cache: str = ""  # depth cache folder ("" = OUT/depth-cache)
    split_options: SplitConfig = field(default_factory=SplitConfig)  # must match training's to hold out scenes
    export: dict = field(default_factory=dict)  # learned.export.ExportConfig overrides (e.g. a fitted cov_scale)
    # --fit-uncertainty: fewer frames than this fit nothing (a variance from n frames is good to sqrt(2/n): 26 %)
    fit_min_frames: int = 30

    def __post_init__(self):
        from learned.export import ExportConfig
        from learned.train import check_sizes_and_device

        freeze_dict_fields(self)  # depth_options, export: read-only as the rest
        if self.batch_size < 1 or self.max_frames < 0:
            raise ValueError(f"EvalConfig: batch_size must be >= 1 and max_frames >= 0, got {self.batch_size} and "
                             f"{self.max_frames}")
        if self.fit_min_frames < 1:
            raise ValueError(f"EvalConfig: fit_min_frames must be >= 1, got {self.fit_min_frames}")
        check_sizes_and_device(self, "EvalConfig")
        require_ranges(self, {"max_frames": "[0, 1e7]", "batch_size": "[1, 4096]", "threads": "[1, 1024]",
                              "max_radar_points": "[1, 1e6]", "max_lidar_points": "[0, 1e6]",
                              "fit_min_frames": "[1, 1e6]", "seed": "[0, 9.2e18]"})  # as --seed (probe 79)
        merge(ExportConfig, self.export, "export.")  # a bad --set export.KEY fails before the data are read


def eval_indices(frames: Sequence[RadarCameraFrame], conf: EvalConfig) -> list[int]:
    idx = split_indices(frames, conf.split, conf.split_options)
    return idx[: conf.max_frames] if conf.max_frames else idx


def checked_indices(frames: Sequence[RadarCameraFrame], conf: EvalConfig) -> list[int]:
    """``eval_indices``, or a ``HybridCalibError`` saying what to do when the split holds no frame."""
    indices = eval_indices(frames, conf)
    if not indices:
        by = merge(SplitConfig, conf.split_options).by
        how = (f"split.by={by} puts whole {by}s in one split (a hash of the name; a simulated root's scenes are "
               "named by vehicle, scene-sim-veh-NNN, so with the default salt and fractions a root of fewer than 10 "
               "vehicles has no test scene and of fewer than 8 no val scene): split each scene in time instead "
               "with --split-by time (and train with --set split.by=time), or, " if by != "time" else "")
        raise HybridCalibError(f"no frames in split {conf.split!r} ({len(frames)} frames in the data); {how}for a "
                               "separately simulated test drive the network never trained on, use --split all")
    return indices


def _frame_file(out: Path, token: str) -> Path:
    from hybrid_calib.data.files import file_part

    return out / "frames" / f"{file_part(token)}.npz"


def _measurements(corr, batch: dict, b: int, T_iters: np.ndarray, unc: np.ndarray, iteration: int):
    """(``factors.io.FrameMeasurements``, extra arrays) of sample ``b`` of an exported batch."""
    import dataclasses

    from factors.io import FrameMeasurements, NetworkEstimate

    def item(key, default):
        v = batch.get(key)
        return default if v is None else v[b]

    corr = dataclasses.replace(corr, frame_id=str(batch["token"][b]), timestamp_us=int(item("timestamp_us", 0)))
    cov = unc if unc.shape == (6, 6) else None
    T_start = batch["T_init"][b].double().cpu().numpy()
    network = NetworkEstimate(T_iters[-1], cov, iteration % len(T_iters), T_start)
    m = FrameMeasurements(corr, str(item("vehicle", "")), int(item("timestamp_radar_us", 0)), network)
    extra = {"T_gt": batch["T_gt"][b].double().cpu().numpy(), "T_iters": T_iters,
             "perturbation": batch["perturbation"][b].cpu().numpy(), "index": np.array(int(batch["index"][b]))}
    if cov is None:
        extra["uncertainty"] = unc
    return m, extra


def export_pure(model, frames: Sequence[RadarCameraFrame], conf: EvalConfig, out: Path, *,
                overwrite: bool = False, progress: bool = True, exporter: Callable | None = None,
                ood=None) -> list[Path]:
    """Run the network over the fixed evaluation list; write one ``frames/<token>.npz`` per frame.

    ``exporter(model, out, batch, export_conf) -> (list of Correspondences, (B, ...) uncertainty)``,
    default ``learned.export.export_correspondences``; ``export_conf`` is ``ExportConfig`` merged
    with ``conf.export``. ``ood``: the checkpoint's out-of-domain model (``learned.ood.OODModel``; one network, not a
    cascade): each frame's score (``frame_score``) is written beside its prediction (``ood_score``)."""
    from tqdm import tqdm

    from factors.io import save_measurements
    from learned.export import ExportConfig, check_iteration, not_finite_reason
    from learned.train import model_inputs, to_device

    if exporter is None:
        from learned.export import export_correspondences as exporter
    export_conf = merge(ExportConfig, conf.export)
    if hasattr(model, "cfg"):
        check_iteration(export_conf, int(model.cfg.iterations))

    torch.set_num_threads(max(1, conf.threads))
    H, W = (int(v) for v in model.cfg.input_hw) if hasattr(model, "cfg") else (192, 400)
    dconf = DatasetConfig(height=H, width=W, max_radar_points=conf.max_radar_points,
                          max_lidar_points=conf.max_lidar_points, perturbation=conf.perturbation, seed=conf.seed,
                          variant=getattr(getattr(model, "cfg", None), "variant", "radar"))
    depth = build_depth_estimator(conf.depth, conf.depth_options)
    cache = DepthCache(Path(conf.depth_cache) if conf.depth_cache else out / "depth-cache")
    indices = checked_indices(frames, conf)
    dataset = CalibDataset(frames, dconf, depth, indices=indices, cache=cache, train=False)
    todo = []
    for i, fi in enumerate(indices):
        if overwrite or not _frame_file(out, camera_token(frames, fi)).is_file():
            todo.append(i)
    if progress and len(todo) < len(indices):  # a resumed run says what it kept (probe 60), as calibrate and compare
        print(f"kept {len(indices) - len(todo)} frame(s) an earlier run into {out} exported (same checkpoint, data and "
              f"options); exporting the other {len(todo)}")
    loader = torch.utils.data.DataLoader(dataset, batch_size=conf.batch_size, sampler=todo, collate_fn=collate)
    device = torch.device(conf.device)
    model = model.to(device).eval()
    written = []
    with torch.no_grad():
        for batch in tqdm(loader, desc="export", disable=not progress):
            if batch is None:
                continue
            batch = to_device(batch, device)
            inputs = model_inputs(batch)
            out_m = model(inputs)
            corr, unc = exporter(model, out_m, inputs, export_conf)
            scores = frame_scores(ood, out_m, batch["image"], batch.get("jpeg_quality")) if ood is not None else None
            T_iters = torch.stack([T.double() for T in out_m["T_iters"]], dim=1).cpu().numpy()  # (B, N, 4, 4)
            unc_np = unc.detach().double().cpu().numpy() if isinstance(unc, torch.Tensor) else np.asarray(unc)
            for b, token in enumerate(batch["token"]):
                if not (np.all(np.isfinite(T_iters[b])) and np.all(np.isfinite(unc_np[b]))):
                    # never written as a prediction (a rerun read its own NaN file as "corrupt": probe 33)
                    dataset.bad.setdefault(int(batch["index"][b]), not_finite_reason(token, inputs, b))
                    continue
                m, extra = _measurements(corr[b], batch, b, T_iters[b], unc_np[b], export_conf.iteration)
                if scores is not None:
                    extra["ood_score"] = np.array(scores[b])
                written.append(save_measurements(_frame_file(out, token), m, extra))
    # every frame whose files were bad (the rest of the run went on), after the samples the index left out
    skipped = dataset.skip_records(index=True)
    save_json_atomic(out / "skipped.json", skipped)
    failed = [rec for rec in skipped if rec["index"] is not None]
    if failed and len(failed) == len(todo):
        raise HybridCalibError(f"every frame to export failed ({len(todo)}; reasons in {out / 'skipped.json'}); "
                               f"first: {failed[0]['reason']}")
    return written


def frame_scores(ood, out_m: dict, images: torch.Tensor, jpeg: list[float] | None = None) -> np.ndarray:
    """(B,) out-of-domain scores of a forward output (``learned.ood``: the density model's, raised by the camera
    image's own tests; the rule ``hybrid.network.NetworkRunner.ood_score`` applies). images: (B, 3, H, W); jpeg: (B,)
    the files' JPEG qualities (NaN: not a JPEG; None: not measured)."""
    from learned.ood import frame_features, image_structure, raised_score

    density = np.asarray(ood.score(frame_features(out_m)), np.float64)
    quality = [float("nan")] * len(density) if jpeg is None else [float(q) for q in jpeg]
    return np.array([raised_score(d, image_structure(im), q) for d, im, q in zip(density, images, quality)])


# method name -> exporter(model, frames, conf, out, overwrite=, progress=) -> list of per-frame files
METHODS: dict[str, Callable[..., list[Path]]] = {"pure": export_pure}


@dataclass
class EvalResult:
    """The table: row name -> metric -> mean over frames (``hybrid_calib.metrics.METRIC_KEYS``)."""

    rows: dict[str, dict[str, float]]
    n_frames: int
    per_frame: dict[str, list[dict[str, float]]]  # row name -> per-frame errors (same order as tokens)
    tokens: list[str]
    uncertainty: dict[str, Any] = field(default_factory=dict)  # consistency of the exported covariance
    notes: list[str] = field(default_factory=list)  # what qualifies the figures (``annotate``)
    # the frames' out-of-domain scores ({} when none was scored): scores (same order as tokens), in_domain, threshold
    ood: dict[str, Any] = field(default_factory=dict)


    def table(self) -> str:
        return format_table(self.rows)

    def ood_words(self) -> str:
        """What the out-of-domain score says of these frames ("" when they were not scored)."""
        o = self.ood
        if not o:
            return ""
        row = (f"; the row '{o['method']} (in domain)' keeps to them" if 0 < o["in_domain"] < len(o["scores"])
               else "")
        return (f"{o['in_domain']} of {len(o['scores'])} frames inside the network's training domain (out-of-domain "
                f"score <= {o['threshold']:g}, the checkpoint's export.ood; median score "
                f"{np.median(o['scores']):.2f}){row}; calibrate's learned methods drop the others")

    def markdown(self) -> str:
        head = ("| method | R.Mean (deg) | Roll | Pitch | Yaw | Geodesic | T.Mean (cm) | X | Y | Z | Norm |\n"
                "|---|---|---|---|---|---|---|---|---|---|---|")
        lines = [head]
        for name, m in self.rows.items():
            lines.append(
                f"| {name} | {m['rot_mean_deg']:.3f} | {m['roll_deg']:.3f} | {m['pitch_deg']:.3f} | "
                f"{m['yaw_deg']:.3f} | {m['geodesic_deg']:.3f} | {m['trans_mean_cm']:.2f} | {m['x_cm']:.2f} | "
                f"{m['y_cm']:.2f} | {m['z_cm']:.2f} | {m['trans_norm_cm']:.2f} |")
        text = "\n".join(lines) + f"\n\n{self.n_frames} frames; rotation in degrees, translation in cm.\n"
        if words := self.ood_words():
            text += f"\n{words}\n"
        u = self.uncertainty
        if u:
            text += (f"\nExported 6x6 covariance of the final estimate over {u['n']} frames: mean NEES "
                     f"{u['nees_mean']:.2f} (6 if honest), median {u['nees_median']:.2f}, "
                     f"coverage {100 * u['coverage_95']:.1f} % (inside the 95 % ellipsoid).\n\n"
                     "| axis | RMSE | mean reported 1-sigma |\n|---|---|---|\n")
            for name, rmse, sd in zip(u["axes"], u["rmse"], u["sigma_mean"]):
                text += f"| {name} | {rmse:.3f} | {sd:.3f} |\n"
        if self.notes:
            text += "\n**Notes**\n\n" + "".join(f"- {n}\n" for n in self.notes)
        return text


def evaluate_predictions(out: str | Path, method: str = "pure") -> EvalResult:
    """The paper's table from the per-frame files under ``out/frames``: rows ``initial``,
    ``<method> iter k`` for every iteration k, and ``<method>`` (the final estimate)."""
    files = finished(sorted((Path(out) / "frames").glob("*.npz")))  # a killed run's temporary files: no frames
    if not files:
        raise HybridCalibError(f"no exported predictions in {Path(out) / 'frames'}; run the export first")
    per: dict[str, list] = {}
    tokens, unc, scores = [], [], []
    for path in files:
        with read_npz(path, "exported prediction", _REEXPORT) as z:
            T_gt, T_init, T_iters = z["T_gt"], z["T_start"], z["T_iters"]
            tokens.append(str(z["frame_id"]))
            scores.append(float(z["ood_score"]) if "ood_score" in z.files else float("nan"))
            if (pair := _tangent_error(z)) is not None:
                unc.append(pair)
        per.setdefault("initial", []).append(extrinsic_error(T_init, T_gt))
        if len(T_iters) > 1:
            for k, T in enumerate(T_iters, start=1):
                per.setdefault(f"{method} iter {k}", []).append(extrinsic_error(T, T_gt))
        per.setdefault(method, []).append(extrinsic_error(T_iters[-1], T_gt))
    ood = {}
    if np.isfinite(scores).all():  # every frame scored (an earlier run's frames without a score: none is said)
        keep = [k for k, x in enumerate(scores) if x <= 1.0]
        ood = {"method": method, "threshold": 1.0, "scores": scores, "in_domain": len(keep)}
        if 0 < len(keep) < len(files):
            per[f"{method} (in domain)"] = [per[method][k] for k in keep]
    rows = {name: summarize(errs) for name, errs in per.items()}
    return EvalResult(rows, len(files), {n: [e.as_dict() for e in errs] for n, errs in per.items()}, tokens,
                      uncertainty_consistency(*_stack(unc)), ood=ood)


_REEXPORT = "remove it and re-run the same hybrid-calib evaluate command (finished frames are kept)"


def _tangent_error(z) -> tuple[np.ndarray, np.ndarray] | None:
    """(xi (6,), C (6, 6)) of one exported frame (an open npz), or None when it has no (6, 6) covariance."""
    from hybrid_calib.geometry import local

    if "cov" not in z.files:
        return None
    return local(z["T_gt"], z["T_iters"][-1]), z["cov"]


def _stack(pairs: list) -> tuple[np.ndarray, np.ndarray]:
    return (np.array([p[0] for p in pairs]).reshape(-1, 6), np.array([p[1] for p in pairs]).reshape(-1, 6, 6))


def tangent_errors(out: str | Path) -> tuple[np.ndarray, np.ndarray]:
    """(F, 6) right-tangent errors Log(T_gt^-1 T_final) and (F, 6, 6) exported covariances of the
    frames under ``out/frames`` that have one (``calibrate_cov_scale`` takes both)."""
    pairs = []
    for path in finished(sorted((Path(out) / "frames").glob("*.npz"))):
        with read_npz(path, "exported prediction", _REEXPORT) as z:
            pairs.append(_tangent_error(z))
    return _stack([p for p in pairs if p is not None])


def uncertainty_consistency(xi: np.ndarray, C: np.ndarray) -> dict[str, Any]:
    """Is the exported per-frame covariance honest? ``xi`` (F, 6) = Log(T_gt^-1 T_final) (right
    tangent, [rot rad, trans m], ``metrics.nees``'s error) and ``C`` (F, 6, 6) as ``tangent_errors`` gives them.
    Returns {} when F = 0, else ``metrics.consistency`` (n, nees_mean, nees_median, coverage_95: the summary compare
    and calibrate report) with axes, rmse and sigma_mean per tangent axis (degrees / cm; the axes are the radar
    frame's: ``axes`` are ``hybrid_calib.metrics.std_keys("radar")``)."""
    if not len(xi):
        return {}
    scale = np.array([np.degrees(1.0)] * 3 + [100.0] * 3)
    return {
        **consistency(nees_of(xi, C)), "axes": list(STD_KEYS_RADAR),
        "rmse": (np.sqrt((xi ** 2).mean(0)) * scale).tolist(),
        "sigma_mean": (np.sqrt(np.diagonal(C, axis1=1, axis2=2)).mean(0) * scale).tolist(),
    }


def write_report(result: EvalResult, out: str | Path, config: dict | None = None) -> Path:
    """``results.json`` (schema below) and ``results.md`` in ``out`` (``hybrid-calib evaluate`` adds
    ``errors_cdf.png``: ``hybrid_calib.plots.evaluation.plot_error_cdf``).

    results.json: {"n_frames": int, "metrics": list of metric names, "rows": {row: {metric: mean}},
    "per_frame": {row: [{metric: value}, ...]}, "tokens": [...], "uncertainty": {...}
    (``uncertainty_consistency``), "ood": {"scores": [per token], "in_domain", "threshold", "method"} or {} (frames
    not scored), "notes": [str] (``annotate``), "config": {...}}."""
    out = Path(out)
    path = save_json_atomic(out / "results.json", {
        "n_frames": result.n_frames, "metrics": list(METRIC_KEYS), "rows": result.rows,
        "per_frame": result.per_frame, "tokens": result.tokens, "uncertainty": result.uncertainty,
        "ood": result.ood, "notes": list(result.notes), "config": config or {}})
    save_text_atomic(out / "results.md", result.markdown())
    return path


def annotate(out: str | Path, result: EvalResult, notes: list[str]) -> Path:
    """``results.json`` and ``results.md`` in ``out`` written again with ``notes`` (what qualifies the figures: no
    held-out measure, errors against a real root's tables, frames skipped), their config as it was."""
    out = Path(out)
    result.notes = list(notes)
    config = json.loads((out / "results.json").read_text()).get("config") or {}
    return write_report(result, out, config)


def _what_differs(old: dict, new: dict) -> str:
    """Words for what differs between the record of the kept predictions and this run's (``evaluate``)."""
    from hybrid_calib.data.files import stamps_changed

    was, now = old.get("data") or {}, new.get("data") or {}
    words = []
    if [was.get(k) for k in ("roots", "version", "nsweeps")] != [now.get(k) for k in ("roots", "version", "nsweeps")]:
        words.append("frames of other roots, --version or --nsweeps")
    elif changed := stamps_changed(was, now):
        words.append(changed)
    if old.get("starts") != new.get("starts"):
        words.append(f"starts drawn by another rule (this version: {new.get('starts')}; the predictions kept: "
                     f"{old.get('starts') or 'by the frame position among the roots read, before 2026-12-07'})")
    if old.get("network") != new.get("network"):
        words.append("another checkpoint's files (retrained or edited at the same path, e.g. by the fit an "
                     "--fit-uncertainty run writes into it, or another file)")
    options = changed_options(old, new, skip=("data", "network", "starts"), whole=("data", "network"))
    if options:
        words.append(f"another config ({'; '.join(options[:4])}{'; ...' if len(options) > 4 else ''})")
    return "; ".join(words) or "another config"


def evaluate(model, frames: Sequence[RadarCameraFrame], conf: EvalConfig | dict, out: str | Path, *,
             checkpoint: str | Path | None = None, overwrite: bool = False, progress: bool = True,
             data: dict | None = None, network: list[str] | None = None, **method_options) -> EvalResult:
    """Export with ``conf.method`` into ``out`` (skipping frames already there unless ``overwrite``),
    then compute and write the table. A changed config in an existing ``out`` is an error; ``data`` (what
    the frames were read from, e.g. {"roots", "version", "nsweeps"}) is part of it: frames of other roots
    would be tabled with the ones already there (with ``"stamps"``, ``hybrid_calib.data.files.data_stamp`` per root:
    a root re-made at the same path is other data); ``network``: the checkpoints' digests
    (``learned.checkpoint.checkpoint_digest``: one retrained at the same path is another network). ``overwrite``
    also empties ``out``'s own depth cache (keyed by frame token, which a re-made root keeps). ``method_options`` go
    to the method's exporter (``export_pure``: ``exporter``)."""
    conf = merge(EvalConfig, conf)
    if conf.method not in METHODS:
        raise HybridCalibError(f"unknown method {conf.method!r}; available: {sorted(METHODS)}")
    out = Path(out)
    record = {"eval": to_dict(conf), "checkpoint": str(checkpoint) if checkpoint else None,
              "model_config": to_dict(model.cfg) if hasattr(model, "cfg") else None}
    if data is not None:
        record["data"] = data
    if network is not None:
        record["network"] = network
    record["starts"] = EVAL_STARTS  # an --out of the rule before is not mixed with this one's (probe 115)
    checked_indices(frames, conf)  # an empty split is refused before anything is written (probe 87: it left
    # export_config.json and a runs.json line behind)
    cfg_path = out / "export_config.json"
    old = None if overwrite else read_out_record(cfg_path, "export config", "what its predictions were made "
                                                 "with: use --overwrite or another --out")
    if old is not None and not any((out / "frames").glob("*.npz")):  # an earlier run that exported nothing (it
        old = None  # failed before its first frame): nothing of it to mix with this run's predictions
    if old is not None:
        for key in ("data", "network"):  # written before it was recorded
            if key not in old and key in record:
                old = {**old, key: record[key]}
        if old != json.loads(json.dumps(record)):
            raise HybridCalibError(f"{out} holds predictions made with {_what_differs(old, record)} ({cfg_path}), "
                                   "which this run would table with its own; use --overwrite or another --out")
    remove_temporaries(out / "frames")  # a killed run's (probe 90): this run holds the folder's lock
    if overwrite:
        for old_file in (out / "frames").glob("*.npz"):
            old_file.unlink()
        if not conf.depth_cache:  # its own: recomputed from the data as they are now
            shutil.rmtree(out / "depth-cache", ignore_errors=True)
    save_json_atomic(cfg_path, record)
    changed = watch_roots(data)  # a root rewritten under the run (as calibrate's: probe 142)
    METHODS[conf.method](model, frames, conf, out, overwrite=overwrite, progress=progress, **method_options)
    if (root := changed()) is not None:  # as calibrate (probe 142): the frames exported are of the old and the new
        raise DataError(f"{root} changed while this run read it (its tables or sensor folders were replaced: "
                        "re-simulated, re-downloaded or edited by another process), so the frames exported are a "
                        f"mix of the old and the new data: no table is written; rerun with --overwrite once the "
                        f"root is complete (the frames in {out} were read from data the root no longer holds)",
                        path=str(root))
    result = evaluate_predictions(out, conf.method)
    write_report(result, out, record)
    return result
