"""What the network exports for the hybrid: correspondences and a per-frame SE(3) covariance.

Correspondences (FV view, from the assignment P of iteration ``ExportConfig.iteration``, default the
last). For each valid input point p (radar frame) that projects by that iteration's input estimate
T_in to pixel q inside radar-map cell j:

- column P[:, j] is the distribution over image cells i of where p's content is in the image;
- i* = argmax_i P_ij; over the (2r+1)^2 window W of cells around i* the weights w_i = P_ij give the
  soft-argmax centre c = sum w_i c_i / sum w_i (cell centres c_i in pixels) and its spread
  var = sum w_i |c_i - c|^2 / sum w_i / 2 (per axis);
- the image location is ``c + (q - c_j)``: the matched cell, refined below cell resolution, plus p's own
  offset inside its radar cell (the match is a displacement of cells);
- confidence = min(1, sum_W P_ij) (P already holds sigma_I sigma_R);
- sigma_px = sigma_scale * sqrt(var + stride^2 / 12) (the spread plus one cell's quantisation).

Independence: the pixel is q (a projection by T_in) plus a learned cell displacement, so at the last
iteration, where T_in is already close, a row largely restates the network's own estimate: it is
correlated with the network's SE(3) prior; do not use both at full weight. ``iteration=0`` gives rows
measured against T_init only (independent of the regression, less precise). On a toy world (64x128
input, 8 px cells, tiny model trained 600 steps; radar points projected by T_init are 13.2 px off
the truth at the median) the exported pixels were 3.9 px (iteration 0) and 2.0 px (last) off at the median.

``learned.evaluate`` stores the rows, the final estimate and this covariance per frame as a
measurement file (``factors.io``; what ``hybrid-calib calibrate --correspondences`` reads).

Rows with confidence < ``min_confidence`` are dropped. Pixels are in the model-input image (the
batch ``K``, which the Correspondences carry); points are the raw input points (radar frame, metres).
BEV matches are not exported (they live on the ground plane, not in the image).

Per-frame covariance (6, 6), right tangent of T_cam_radar ``[rot rad, trans m]`` (docs/conventions.md),
of the estimate ``T_iters[-1]``:
- ``"learned"`` (default when the config says so): diag(exp(log_var)) of the variance head, trained by
  a Gaussian NLL on the true error;
- ``"spread"``: diag(xi_last^2 + floor^2), xi_last = Log(T_deltas[-1]), the size of the last correction
  (an iteration that still moves means the estimate is not settled).
Both are multiplied by ``cov_scale`` (1 by default; a scalar or 6 per-axis factors): fit it on
held-out data so that each axis's normalised squared error averages 1 and the NEES xi^T C^-1 xi
averages 6 (``calibrate_cov_scale``; ``hybrid-calib evaluate --split val --fit-uncertainty`` stores
it in the checkpoint's ``export`` block, which every later evaluation applies). ``sigma_scale`` can be
fitted the same way on simulated validation scenes, where the true reflectors are known
(``benchmarks/correspondence_quality.py --fit-into CKPT``).
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field

import numpy as np
import torch

from factors.correspondences import Correspondences
from hybrid_calib.config import freeze_dict_fields, json_numbers, require_ranges
from hybrid_calib.metrics import nees
from learned import lie
from learned.transform import STRIDE, cell_centres, cell_index


@dataclass(frozen=True)
class ExportConfig:
    iteration: int = -1  # which iteration's assignment P to read (-1: the last, best aligned)
    window: int = 1  # soft-argmax window radius in cells (1 -> 3x3)
    min_confidence: float = 0.1  # drop rows whose confidence is below this (LightGlue's match filter threshold)
    sigma_scale: float = 1.0  # multiplies sigma_px (calibratable)
    uncertainty: str = ""  # "learned" | "spread"; "" = the model config's choice
    cov_scale: float | tuple = 1.0  # multiplies the 6x6 covariance: one factor or 6 per-axis (calibrate_cov_scale)
    cov_floor: tuple = (1e-3, 1e-2)  # "spread" floor: rad, m (no estimate is better than this)
    hybrid: dict = field(default_factory=dict)  # the hybrid's measurement model (hybrid.measurement), not used here
    ood: dict = field(default_factory=dict)  # the out-of-domain density model (learned.ood), not used here

    def __post_init__(self):
        freeze_dict_fields(self)  # hybrid, ood: read-only as the rest
        if problem := scale_problem(self.cov_scale, self.sigma_scale):
            raise ValueError(f"ExportConfig: {problem}")
        if self.uncertainty not in ("", "learned", "spread"):  # an internal error at the first frame (probe 79)
            raise ValueError(f"ExportConfig.uncertainty={self.uncertainty!r}; valid: learned, spread, or \"\" (the "
                             "model config's choice)")
        require_ranges(self, {"iteration": "[-1, 99]", "window": "[0, 100]", "min_confidence": "[0, 10]",
                              "sigma_scale": "(0, 1000]", "cov_scale": "(0, 1e6]", "cov_floor": "(0, 10]"})


def check_iteration(conf: ExportConfig, iterations: int) -> None:
    """``HybridCalibError`` naming ``export.iteration`` when it is not one of a network's ``iterations`` (0 ..
    iterations - 1, or -1 for the last): it was an IndexError at the first frame (probe 79)."""
    if not -1 <= conf.iteration < iterations:
        from hybrid_calib.errors import HybridCalibError

        raise HybridCalibError(f"export.iteration={conf.iteration}: the network runs {iterations} iteration(s); pass "
                               f"0..{iterations - 1}, or -1 for the last")


def not_finite_reason(token: str, inputs: Mapping, b: int = 0, checkpoint: str = "") -> str:
    """Why the network's output on frame ``token`` (item ``b`` of the batch ``inputs``: its model inputs,
    tensors) is not finite: the inputs, when they hold NaN/inf, else the checkpoint's weights (a probe: weights
    scaled by 1e30, finite, blamed the frame's depth map, image or radar returns)."""
    bad = [k for k, v in inputs.items() if isinstance(v, torch.Tensor) and v.is_floating_point() and v.dim() > 0
           and b < len(v) and not bool(torch.isfinite(v[b]).all())]
    if bad:
        return (f"the network's output on frame {token} is not finite (NaN/inf): its inputs hold NaN/inf "
                f"({', '.join(bad)}: the depth map, the image or the radar returns)")
    return (f"the network's output on frame {token} is not finite (NaN/inf) although its inputs are finite: the "
            f"checkpoint's weights{f' ({checkpoint})' if checkpoint else ''} overflow on it; restore or retrain the "
            "checkpoint")


def scale_problem(cov_scale, sigma_scale) -> str:
    """What is wrong with an export block's ``cov_scale`` (a number in (0, 1e6], or 6 of them) and
    ``sigma_scale`` (a number in (0, 1000]); "" when both can work (the intervals of ``ExportConfig``: a checkpoint's
    block is refused at load naming its file, not later as if an option were wrong; probe 27)."""
    try:  # JSON numbers, not text that reads as one (probe 109: "1" was taken)
        cov = np.asarray(cov_scale, np.float64) if json_numbers(cov_scale) else np.full(1, np.nan)
    except (TypeError, ValueError):
        cov = np.full(1, np.nan)
    if cov.shape not in ((), (6,)) or not np.all(np.isfinite(cov)) or not np.all((cov > 0) & (cov <= 1e6)):
        return f"cov_scale={cov_scale!r}: need one factor in (0, 1e6] or 6 of them (per axis: rot x3, trans x3)"
    try:
        sigma = float(sigma_scale) if json_numbers(sigma_scale) else float("nan")
    except (TypeError, ValueError):
        sigma = float("nan")
    if not (np.isfinite(sigma) and 0 < sigma <= 1000):
        return f"sigma_scale={sigma_scale!r}: need a factor in (0, 1000]"
    return ""


def _np(x: torch.Tensor) -> np.ndarray:
    return x.detach().cpu().double().numpy()


@torch.no_grad()
def refine_matches(log_P: torch.Tensor, grid: tuple, cell_R: torch.Tensor, window: int = 1,
                   stride: int = STRIDE) -> dict[str, torch.Tensor]:
    """Soft-argmax of P's columns around their mode.

    log_P: (B, m_I, m_R); grid: (h, w) image-cell grid (m_I = h w); cell_R: (B, N) radar cell of each
    point (-1 = none). Returns ``centre`` (B, N, 2) pixels, ``var`` (B, N) px^2 per axis, ``mass``
    (B, N) sum of P in the window, ``best`` (B, N) argmax image cell.
    """
    B, m_I, _ = log_P.shape
    h, w = grid
    P = log_P.exp()
    j = cell_R.clamp_min(0)
    cols = torch.gather(P, 2, j[:, None, :].expand(B, m_I, j.shape[1])).transpose(1, 2)  # (B, N, m_I)
    best = cols.argmax(-1)
    r0, c0 = best // w, best % w
    d = torch.arange(-window, window + 1, device=log_P.device)
    dr, dc = torch.meshgrid(d, d, indexing="ij")
    rr = r0[..., None] + dr.reshape(-1)  # (B, N, k)
    cc = c0[..., None] + dc.reshape(-1)
    ok = (rr >= 0) & (rr < h) & (cc >= 0) & (cc < w)
    idx = (rr.clamp(0, h - 1) * w + cc.clamp(0, w - 1))
    wts = torch.gather(cols, 2, idx) * ok
    centres = cell_centres((h * stride, w * stride), stride, log_P.dtype, log_P.device)  # (m_I, 2)
    pos = centres[idx]  # (B, N, k, 2)
    mass = wts.sum(-1)
    wn = wts / mass.clamp_min(1e-12)[..., None]
    centre = (wn[..., None] * pos).sum(-2)
    var = (wn * ((pos - centre[..., None, :]) ** 2).sum(-1)).sum(-1) / 2
    return dict(centre=centre, var=var, mass=mass, best=best)


def frame_covariance(out: dict, kind: str, cov_scale: float | tuple = 1.0, floor: tuple = (1e-3, 1e-2)
                     ) -> np.ndarray:
    """(B, 6, 6) float64 covariance of T_iters[-1] (right tangent, [rot rad, trans m]); the diagonal
    is multiplied by ``cov_scale`` (a scalar or 6 per-axis factors)."""
    if kind == "learned":
        var = out["log_var"][-1].detach().exp()
    elif kind == "spread":
        xi = lie.se3_log(out["T_deltas"][-1].detach())
        fl = torch.tensor([floor[0]] * 3 + [floor[1]] * 3, dtype=xi.dtype, device=xi.device)
        var = xi * xi + fl * fl
    else:
        raise ValueError(f"uncertainty kind must be 'learned' or 'spread', got {kind!r}")
    scale = np.broadcast_to(np.asarray(cov_scale, dtype=np.float64), (6,))
    return np.stack([np.diag(v * scale) for v in _np(var)])


def export_correspondences(model, out: dict, batch: Mapping, conf: ExportConfig | None = None
                           ) -> tuple[list[Correspondences], np.ndarray]:
    """Per sample: ``Correspondences`` (FV matches) and a (B, 6, 6) covariance of the final estimate.

    model: the ``RCAutoCalib`` that produced ``out``. Without the FV matching head (``use_ems=False``
    or ``views='bev'``, ablations) every frame gets empty ``Correspondences`` and only the covariance.
    batch: the forward batch (``radar``, ``K``; optional ``frame_id`` (or ``token``) list of str and
    ``timestamp_us``).
    """
    conf = conf or ExportConfig()
    cfg = model.cfg
    cov = frame_covariance(out, conf.uncertainty or cfg.uncertainty, conf.cov_scale, conf.cov_floor)
    ids = batch.get("frame_id", batch.get("token"))
    stamps = batch.get("timestamp_us")
    K = _np(batch["K"])
    if not (cfg.use_ems and cfg.views in ("both", "fv")):
        # ablated models (no EMS, or BEV only) have no FV assignment: the SE(3) and covariance only
        return [Correspondences.empty(K[b], str(ids[b]) if ids is not None else str(b),
                                      int(stamps[b]) if stamps is not None else 0) for b in range(len(K))], cov
    n = conf.iteration
    match = out["match"][n]["fv"]
    render = out["render"][n]
    H, W = out["image_hw"]
    gh, gw = match["grid_I"]
    cell_R = cell_index(render["fv_pix"], render["fv_valid"], (H, W))
    ref = refine_matches(match["log_P"], (gh, gw), cell_R, conf.window)
    centres = cell_centres((H, W), STRIDE, ref["centre"].dtype, ref["centre"].device)
    own_offset = render["fv_pix"] - centres[cell_R.clamp_min(0)]
    pixels = ref["centre"] + own_offset
    sigma = conf.sigma_scale * torch.sqrt(ref["var"] + STRIDE ** 2 / 12.0)
    confidence = ref["mass"].clamp(0.0, 1.0)
    keep = (cell_R >= 0) & (confidence >= conf.min_confidence) & torch.isfinite(pixels).all(-1)
    pts, pix, sig, cf, kp = (_np(batch["radar"]), _np(pixels), _np(sigma), _np(confidence),
                             keep.detach().cpu().numpy())
    corr = []
    for b in range(len(K)):
        k = kp[b]
        corr.append(Correspondences(
            pts[b][k], pix[b][k], sig[b][k], cf[b][k], K[b],
            frame_id=str(ids[b]) if ids is not None else str(b),
            timestamp_us=int(stamps[b]) if stamps is not None else 0,
        ))
    return corr, cov


def extrinsics_per_iteration(out: dict) -> np.ndarray:
    """(B, N, 4, 4) float64: the estimate after each iteration."""
    return np.stack([_np(T) for T in out["T_iters"]], 1)


def calibrate_cov_scale(errors: np.ndarray, covs: np.ndarray, per_axis: bool = False) -> float | list[float]:
    """Scale(s) that make the exported covariance honest on held-out frames.

    errors: (F, 6) right-tangent errors Log(T_est^-1 T_gt); covs: (F, 6, 6) as exported.
    ``per_axis=False``: scalar s with mean NEES xi^T (s C)^-1 xi = 6. ``per_axis=True``: 6 factors
    s_k = mean(xi_k^2 / C_kk), so every axis's normalised squared error averages 1 (for the diagonal
    covariances the network exports this also gives mean NEES 6).
    """
    errors, covs = np.asarray(errors, np.float64), np.asarray(covs, np.float64)
    if per_axis:
        return [float(v) for v in np.mean(errors ** 2 / np.diagonal(covs, axis1=1, axis2=2), axis=0)]
    return float(np.mean(nees(errors, covs)) / 6.0)
