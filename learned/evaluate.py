"""Evaluation, export-then-evaluate (as in glue-factory).

1. ``export_pure`` (method ``pure``; any method in ``METHODS``): run it over a FIXED list of
   (frame, T_init) — the test split with one perturbation per sample fixed by (seed, index) — and
   store, per frame, ``OUT/frames/<token>.npz``:
     T_init (4, 4), T_gt (4, 4), T_iters (N, 4, 4) the estimate after every iteration (float64),
     uncertainty (the model's per-frame SE(3) uncertainty, as ``export_correspondences`` gives it),
     perturbation (6,), index (), and the exported correspondences (``corr_*`` keys,
     ``factors.Correspondences.to_npz_dict``).
   ``OUT/export_config.json`` holds the evaluation config, the checkpoint and its model config.
   Frames already exported are skipped (``overwrite=False``); a frame whose files are bad (a corrupt
   radar PCD or image, ...) is listed in ``OUT/skipped.json`` (``[{"index", "token", "file",
   "reason"}]``, written on every run) and the run goes on.
2. ``evaluate_predictions``: read those files and compute the paper's table with
   ``hybrid_calib.metrics`` (rotation Mean/Roll/Pitch/Yaw in degrees, translation Mean/X/Y/Z in cm,
   geodesic angle and translation norm) for the initial error, every iteration and the final
   estimate. ``write_report`` saves it as ``results.json`` + ``results.md`` and an error-CDF plot.

Methods: ``pure`` = the network alone (``METHODS``); a ``hybrid`` method registers an exporter with
the same signature that writes the same per-frame files (T_iters may hold one final estimate).
"""

from __future__ import annotations

import json
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import torch

from hybrid_calib.config import merge, save_json_atomic, to_dict
from hybrid_calib.data.frame import RadarCameraFrame
from hybrid_calib.errors import HybridCalibError
from hybrid_calib.metrics import METRIC_KEYS, extrinsic_error, format_table, summarize
from learned.dataset import CalibDataset, DatasetConfig, SplitConfig, camera_token, collate, split_indices
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


def eval_indices(frames: Sequence[RadarCameraFrame], conf: EvalConfig) -> list[int]:
    idx = split_indices(frames, conf.split, conf.split_options)
    return idx[: conf.max_frames] if conf.max_frames else idx


def _frame_file(out: Path, token: str) -> Path:
    safe = "".join(ch if ch.isalnum() or ch in "-_." else "_" for ch in token)
    return out / "frames" / f"{safe}.npz"


def _save_npz_atomic(path: Path, arrays: dict[str, Any]) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(path.stem + ".tmp.npz")
    np.savez(tmp, **arrays)
    tmp.replace(path)


def export_pure(model, frames: Sequence[RadarCameraFrame], conf: EvalConfig, out: Path, *,
                overwrite: bool = False, progress: bool = True, exporter: Callable | None = None) -> list[Path]:
    """Run the network over the fixed evaluation list; write one ``frames/<token>.npz`` per frame.

    ``exporter(model, out, batch, export_conf) -> (list of Correspondences, (B, ...) uncertainty)``,
    default ``learned.export.export_correspondences``; ``export_conf`` is ``ExportConfig`` merged
    with ``conf.export``."""
    from tqdm import tqdm

    from learned.export import ExportConfig
    from learned.train import model_inputs, to_device

    if exporter is None:
        from learned.export import export_correspondences as exporter
    export_conf = merge(ExportConfig, conf.export)

    torch.set_num_threads(max(1, conf.threads))
    H, W = (int(v) for v in model.cfg.input_hw) if hasattr(model, "cfg") else (192, 400)
    dconf = DatasetConfig(height=H, width=W, max_radar_points=conf.max_radar_points,
                          max_lidar_points=conf.max_lidar_points, perturbation=conf.perturbation, seed=conf.seed,
                          variant=getattr(getattr(model, "cfg", None), "variant", "radar"))
    depth = build_depth_estimator(conf.depth, conf.depth_options)
    cache = DepthCache(Path(conf.depth_cache) if conf.depth_cache else out / "depth-cache")
    indices = eval_indices(frames, conf)
    if not indices:
        raise HybridCalibError(f"no frames in split {conf.split!r} ({len(frames)} frames in the data); "
                               "for a separately simulated test drive use --split all")
    dataset = CalibDataset(frames, dconf, depth, indices=indices, cache=cache, train=False)
    todo = []
    for i, fi in enumerate(indices):
        if overwrite or not _frame_file(out, camera_token(frames, fi)).is_file():
            todo.append(i)
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
            T_iters = torch.stack([T.double() for T in out_m["T_iters"]], dim=1).cpu().numpy()  # (B, N, 4, 4)
            unc_np = unc.detach().double().cpu().numpy() if isinstance(unc, torch.Tensor) else np.asarray(unc)
            for b, token in enumerate(batch["token"]):
                arrays = {
                    "T_init": batch["T_init"][b].double().cpu().numpy(),
                    "T_gt": batch["T_gt"][b].double().cpu().numpy(),
                    "T_iters": T_iters[b],
                    "uncertainty": unc_np[b],
                    "perturbation": batch["perturbation"][b].cpu().numpy(),
                    "index": np.array(int(batch["index"][b])),
                    "token": np.array(token),
                }
                arrays.update({f"corr_{k}": v for k, v in corr[b].to_npz_dict().items()})
                path = _frame_file(out, token)
                _save_npz_atomic(path, arrays)
                written.append(path)
    skipped = dataset.skip_records()  # every frame whose files were bad; the rest of the run went on
    save_json_atomic(out / "skipped.json", skipped)
    if skipped and len(skipped) == len(todo):
        raise HybridCalibError(f"every frame to export failed ({len(todo)}; reasons in {out / 'skipped.json'}); "
                               f"first: {skipped[0]['reason']}")
    return written


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


    def table(self) -> str:
        return format_table(self.rows)

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
        u = self.uncertainty
        if u:
            text += (f"\nExported 6x6 covariance of the final estimate over {u['n_frames']} frames: mean NEES "
                     f"{u['nees_mean']:.2f} (6 if honest), median {u['nees_median']:.2f}, "
                     f"{100 * u['inside_95']:.1f} % inside the 95 % ellipsoid.\n\n"
                     "| axis | RMSE | mean reported 1-sigma |\n|---|---|---|\n")
            for name, rmse, sd in zip(u["axes"], u["rmse"], u["sigma_mean"]):
                text += f"| {name} | {rmse:.3f} | {sd:.3f} |\n"
        return text


def evaluate_predictions(out: str | Path, method: str = "pure") -> EvalResult:
    """The paper's table from the per-frame files under ``out/frames``: rows ``initial``,
    ``<method> iter k`` for every iteration k, and ``<method>`` (the final estimate)."""
    files = sorted((Path(out) / "frames").glob("*.npz"))
    if not files:
        raise HybridCalibError(f"no exported predictions in {Path(out) / 'frames'}; run the export first")
    per: dict[str, list] = {}
    tokens, unc = [], []
    for path in files:
        with np.load(path, allow_pickle=False) as z:
            T_gt, T_init, T_iters = z["T_gt"], z["T_init"], z["T_iters"]
            tokens.append(str(z["token"]))
            if (pair := _tangent_error(z)) is not None:
                unc.append(pair)
        per.setdefault("initial", []).append(extrinsic_error(T_init, T_gt))
        if len(T_iters) > 1:
            for k, T in enumerate(T_iters, start=1):
                per.setdefault(f"{method} iter {k}", []).append(extrinsic_error(T, T_gt))
        per.setdefault(method, []).append(extrinsic_error(T_iters[-1], T_gt))
    rows = {name: summarize(errs) for name, errs in per.items()}
    return EvalResult(rows, len(files), {n: [e.as_dict() for e in errs] for n, errs in per.items()}, tokens,
                      uncertainty_consistency(*_stack(unc)))


UNC_AXES = ("rot_x_deg", "rot_y_deg", "rot_z_deg", "t_x_cm", "t_y_cm", "t_z_cm")  # right tangent, radar frame
CHI2_6_95 = 12.591587243743977  # chi-square, 6 dof, 95 %


def _tangent_error(z) -> tuple[np.ndarray, np.ndarray] | None:
    """(xi (6,), C (6, 6)) of one exported frame (an open npz), or None when it has no (6, 6) covariance."""
    from hybrid_calib.geometry import local

    if "uncertainty" not in z.files or z["uncertainty"].shape != (6, 6):
        return None
    return local(z["T_iters"][-1], z["T_gt"]), z["uncertainty"]


def _stack(pairs: list) -> tuple[np.ndarray, np.ndarray]:
    return (np.array([p[0] for p in pairs]).reshape(-1, 6), np.array([p[1] for p in pairs]).reshape(-1, 6, 6))


def tangent_errors(out: str | Path) -> tuple[np.ndarray, np.ndarray]:
    """(F, 6) right-tangent errors Log(T_final^-1 T_gt) and (F, 6, 6) exported covariances of the
    frames under ``out/frames`` that have one (``calibrate_cov_scale`` takes both)."""
    pairs = []
    for path in sorted((Path(out) / "frames").glob("*.npz")):
        with np.load(path, allow_pickle=False) as z:
            pairs.append(_tangent_error(z))
    return _stack([p for p in pairs if p is not None])


def uncertainty_consistency(xi: np.ndarray, C: np.ndarray) -> dict[str, Any]:
    """Is the exported per-frame covariance honest? ``xi`` (F, 6) = Log(T_final^-1 T_gt) (right
    tangent, [rot rad, trans m]) and ``C`` (F, 6, 6) as ``tangent_errors`` gives them; NEES =
    xi^T C^-1 xi. Returns {} when F = 0, else n_frames, nees_mean (6 if honest), nees_median,
    inside_95 (fraction with NEES below the chi-square 95 % bound; 0.95 if honest), axes, rmse and
    sigma_mean per tangent axis (degrees / cm; the axes are the radar frame's)."""
    if not len(xi):
        return {}
    nees = np.einsum("fi,fij,fj->f", xi, np.linalg.inv(C), xi)
    scale = np.array([np.degrees(1.0)] * 3 + [100.0] * 3)
    return {
        "n_frames": len(xi), "nees_mean": float(nees.mean()), "nees_median": float(np.median(nees)),
        "inside_95": float(np.mean(nees < CHI2_6_95)), "axes": list(UNC_AXES),
        "rmse": (np.sqrt((xi ** 2).mean(0)) * scale).tolist(),
        "sigma_mean": (np.sqrt(np.diagonal(C, axis1=1, axis2=2)).mean(0) * scale).tolist(),
    }


def write_report(result: EvalResult, out: str | Path, config: dict | None = None, plot: bool = True) -> Path:
    """``results.json`` (schema below), ``results.md`` and ``errors_cdf.png`` in ``out``.

    results.json: {"n_frames": int, "metrics": list of metric names, "rows": {row: {metric: mean}},
    "per_frame": {row: [{metric: value}, ...]}, "tokens": [...], "uncertainty": {...}
    (``uncertainty_consistency``), "config": {...}}."""
    out = Path(out)
    path = save_json_atomic(out / "results.json", {
        "n_frames": result.n_frames, "metrics": list(METRIC_KEYS), "rows": result.rows,
        "per_frame": result.per_frame, "tokens": result.tokens, "uncertainty": result.uncertainty,
        "config": config or {}})
    md = out / "results.md"
    tmp = md.with_name(md.name + ".tmp")
    tmp.write_text(result.markdown())
    tmp.replace(md)
    if plot:
        _plot_cdf(result, out / "errors_cdf.png")
    return path


def _plot_cdf(result: EvalResult, path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 2, figsize=(10, 4))
    for name, errs in result.per_frame.items():
        for ax, key in zip(axes, ("geodesic_deg", "trans_norm_cm")):
            v = np.sort([e[key] for e in errs])
            style = dict(color="k", ls="--", lw=1.2) if " iter " not in name and name != "initial" else {}
            ax.plot(v, np.arange(1, len(v) + 1) / len(v), label=name, **style)
    axes[0].set_xlabel("rotation error, geodesic (deg)")
    axes[1].set_xlabel("translation error, norm (cm)")
    for ax in axes:
        ax.set_ylabel("fraction of frames")
        ax.grid(alpha=0.3)
    axes[1].legend(fontsize=8)
    fig.suptitle(f"extrinsic error CDF ({result.n_frames} frames)")
    fig.tight_layout()
    tmp = path.with_name(path.stem + ".tmp.png")
    fig.savefig(tmp, dpi=100)
    plt.close(fig)
    tmp.replace(path)


def evaluate(model, frames: Sequence[RadarCameraFrame], conf: EvalConfig | dict, out: str | Path, *,
             checkpoint: str | Path | None = None, overwrite: bool = False, progress: bool = True,
             **method_options) -> EvalResult:
    """Export with ``conf.method`` into ``out`` (skipping frames already there unless ``overwrite``),
    then compute and write the table. A changed config in an existing ``out`` is an error.
    ``method_options`` go to the method's exporter (``export_pure``: ``exporter``)."""
    conf = merge(EvalConfig, conf)
    if conf.method not in METHODS:
        raise HybridCalibError(f"unknown method {conf.method!r}; available: {sorted(METHODS)}")
    out = Path(out)
    record = {"eval": to_dict(conf), "checkpoint": str(checkpoint) if checkpoint else None,
              "model_config": to_dict(model.cfg) if hasattr(model, "cfg") else None}
    cfg_path = out / "export_config.json"
    if cfg_path.is_file() and not overwrite:
        old = json.loads(cfg_path.read_text())
        if old != json.loads(json.dumps(record)):
            raise HybridCalibError(f"{out} holds predictions made with another config ({cfg_path}); "
                                   "use --overwrite or another --out")
    if overwrite:
        for old_file in (out / "frames").glob("*.npz"):
            old_file.unlink()
    save_json_atomic(cfg_path, record)
    METHODS[conf.method](model, frames, conf, out, overwrite=overwrite, progress=progress, **method_options)
    result = evaluate_predictions(out, conf.method)
    write_report(result, out, record)
    return result
