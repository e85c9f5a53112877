"""The network's per-frame output as honest inputs to the sliding window.

What one frame gives (``network.NetworkOutput``): correspondence rows (iteration 0: pixels measured
against the start ``T_in`` only; last iteration: pixels projected by the previous iteration's
estimate plus a learned displacement, i.e. largely a restatement of the network's own SE(3)) and
the network's SE(3) with a learned covariance. The model here (``MeasurementConfig``; every fitted
value lives in the checkpoint's ``export["hybrid"]`` block, ``hybrid.fit``):

1. No double counting. ``rows="first"`` takes the iteration-0 rows and, when ``prior`` is on,
   the network's SE(3) as a Gaussian prior; ``rows="last"`` takes the last iteration's rows and
   NEVER the prior (they restate it: ``frame_inputs`` drops it whatever ``prior`` says);
   ``rows="none"`` takes the prior alone (a filter on the network's SE(3) from the fused estimate).
2. Row noise: ``sigma_px`` times ``sigma_scale``, fitted in the loop's own regime (starts at the
   fused estimate) so the median whitened residual at the truth is the Gaussian's; the tails stay
   with the window's redescending kernel and gate (``WindowConfig.factor``).
3. Correlation within a frame: the rows and the prior of one frame share the frame's input
   estimate and the network's view of it. Modelled as a shared per-frame error ``xi_f`` with
   covariance ``S = diag(shared_std^2)`` (fitted on validation scenes): the frame's information
   ``H`` becomes ``(H^-1 + S)^-1``. The window takes rows, not a frame Gaussian, so the frame is
   down-weighted by the scalar ``1 / (1 + lambda_max(S H))`` (rows' ``sigma_px`` and the prior's
   covariance scaled by its inverse): the largest scalar with ``s H <= (H^-1 + S)^-1``, i.e. never
   more information than the shared-error model allows, in any direction. So N frames give at most
   ~N S^-1, not N K independent rows.
4. Error common to a drive: what the network gets wrong about a whole drive (the loop's fixed
   point is the network's bias near the truth) no number of frames averages out; its covariance
   ``diag(drive_std^2)`` (fitted across validation drives) is added to the fused covariance that
   the hybrid and pure-avg report (``loop``).
5. The network covariance is trusted only where it was fitted: the prior is used when the start
   lies inside the checkpoint's training range (``start_range`` vs the checkpoint's range) or the
   window's fused estimate is already tighter than ``trust_sigma_frac`` of that range; its
   covariance is multiplied by ``prior_cov_scale`` (per axis, fitted in the loop's regime).
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import numpy as np

from factors.correspondences import Correspondences
from hybrid_calib.calib.schedule import GaussianPrior, frame_information
from hybrid_calib.hybrid.network import NetworkOutput
from hybrid_calib.perturbation import RANGES

ROWS = ("first", "last", "none")


@dataclass(frozen=True)
class MeasurementConfig:
    # first (iteration 0) | last (restates the SE(3): never with the prior; a study setting, it does not pin the
    # forward offset) | none (prior only); a value other than the checkpoint's fitted one makes a result inconclusive
    rows: str = "first"
    prior: bool = True  # the network's SE(3) as a prior (only with rows=first; never with rows=last)
    sigma_scale: float = 1.0  # multiplies the exported sigma_px (fitted in the loop's regime)
    shared_std: tuple = (0.0, 0.0, 0.0, 0.0, 0.0, 0.0)  # per-frame shared error std [rad x3, m x3], radar tangent
    prior_cov_scale: tuple = (1.0, 1.0, 1.0, 1.0, 1.0, 1.0)  # per-axis factors on the raw network covariance
    drive_std: tuple = (0.0, 0.0, 0.0, 0.0, 0.0, 0.0)  # network error common to a whole drive [rad x3, m x3]
    trust_sigma_frac: float = 0.1  # prior trusted once the fused std is below this fraction of the range
    min_rows: int = 3  # a frame with fewer rows adds no rows (its prior may still enter)

    def __post_init__(self):
        if self.rows not in ROWS:
            raise ValueError(f"MeasurementConfig.rows={self.rows!r}; valid: {ROWS}")
        if len(self.shared_std) != 6 or len(self.prior_cov_scale) != 6 or len(self.drive_std) != 6:
            raise ValueError("MeasurementConfig.shared_std, drive_std and prior_cov_scale need 6 values each")
        if not self.sigma_scale > 0 or min(self.prior_cov_scale) <= 0 or min(self.shared_std) < 0:
            raise ValueError("MeasurementConfig: sigma_scale and prior_cov_scale must be > 0, shared_std >= 0")
        values = (self.sigma_scale, self.trust_sigma_frac, *self.shared_std, *self.prior_cov_scale, *self.drive_std)
        if not np.all(np.isfinite(np.asarray(values, np.float64))) or min(self.drive_std) < 0:
            raise ValueError(f"MeasurementConfig: every value must be finite and drive_std >= 0, got sigma_scale="
                             f"{self.sigma_scale}, shared_std={list(self.shared_std)}, prior_cov_scale="
                             f"{list(self.prior_cov_scale)}, drive_std={list(self.drive_std)}, trust_sigma_frac="
                             f"{self.trust_sigma_frac}")
        from hybrid_calib.config import require_ranges

        require_ranges(self, {"sigma_scale": "(0, 1000]", "shared_std": "[0, 100]", "prior_cov_scale": "(0, 1e6]",
                              "drive_std": "[0, 100]", "trust_sigma_frac": "(0, 10]", "min_rows": "[1, 1e6]"})


# what benchmarks/hybrid_fit.py writes into a checkpoint's export.hybrid: a block without one of them is not a fit (an
# empty block read as fitted, its defaults a drive error of 0: "recalibrate" by 3.1 deg on an unchanged radar,
# NEES 223; probe 109)
FITTED_KEYS = ("rows", "sigma_scale", "shared_std", "prior_cov_scale", "drive_std")


def unfitted_keys(block) -> list[str]:
    """The ``FITTED_KEYS`` an ``export.hybrid`` block lacks (all of them when it is not an object)."""
    return [k for k in FITTED_KEYS if not isinstance(block, dict) or k not in block]


@dataclass(frozen=True)
class FrameInput:
    """What one frame adds to the window: rows, an optional prior, and how they were weighted."""

    corr: Correspondences
    prior: GaussianPrior | None
    deflation: float  # the shared-error factor s in (0, 1]: the frame's information was multiplied by it
    prior_used: bool
    note: str = ""


def shared_deflation(H: np.ndarray, shared_std) -> float:
    """``1 / (1 + lambda_max(S H))`` for information ``H`` (6, 6) and ``S = diag(shared_std^2)``: the
    largest s with ``s H <= (H^-1 + S)^-1`` (eigenvalues of ``S H`` are those of ``S^1/2 H S^1/2``)."""
    s = np.sqrt(np.asarray(shared_std, np.float64) ** 2)
    if not np.any(s > 0) or not np.any(H):
        return 1.0
    M = (s[:, None] * H) * s[None, :]
    lam = float(np.max(np.linalg.eigvalsh(0.5 * (M + M.T))))
    return 1.0 / (1.0 + max(lam, 0.0))


def prior_trusted(start_range: str, network_range: str, fused_cov: np.ndarray | None, frac: float) -> bool:
    """Is the network's covariance inside the regime it was fitted for? Yes when the start range is
    no wider than the network's, or when the fused estimate's std is below ``frac`` of the network's
    range on every axis (the network then starts well inside its range)."""
    rot_n, tr_n = RANGES.get(network_range, RANGES["R1"])
    rot_s, tr_s = RANGES.get(start_range, (0.0, 0.0))
    if rot_s <= rot_n and tr_s <= tr_n:
        return True
    if fused_cov is None:
        return False
    std = np.sqrt(np.clip(np.diag(fused_cov), 0, None))
    return bool(np.all(np.degrees(std[:3]) < frac * rot_n) and np.all(std[3:] < frac * tr_n))


def frame_inputs(out: NetworkOutput, T_ref: np.ndarray, conf: MeasurementConfig, factor_conf, gate: float,
                 trusted: bool) -> FrameInput:
    """The window's inputs of one network pass (module doc). ``T_ref`` (4, 4): where the frame's
    information is evaluated for the shared-error deflation (the current fused estimate)."""
    corr = out.rows_last if conf.rows == "last" else out.rows_first
    corr = dataclasses.replace(corr, sigma_px=np.asarray(corr.sigma_px) * conf.sigma_scale)
    if len(corr) < conf.min_rows or conf.rows == "none":
        corr = Correspondences.empty(corr.K, corr.frame_id, corr.timestamp_us)
    with_prior = conf.rows != "last" and conf.prior
    use_prior = with_prior and trusted
    prior_cov = None
    H = frame_information(T_ref, corr, factor_conf, gate)[1] if len(corr) else np.zeros((6, 6))
    if use_prior:
        sc = np.sqrt(np.asarray(conf.prior_cov_scale, np.float64))
        prior_cov = (sc[:, None] * out.cov_raw) * sc[None, :]
        H = H + np.linalg.inv(prior_cov)
    s = shared_deflation(H, conf.shared_std)
    if len(corr) and s < 1.0:
        corr = dataclasses.replace(corr, sigma_px=np.asarray(corr.sigma_px) / np.sqrt(s))
    prior = GaussianPrior(out.T, prior_cov / s) if use_prior else None
    note = "network prior outside its fitted range" if with_prior and not trusted else ""
    return FrameInput(corr, prior, s, use_prior, note)
