"""The fleet prior: a random-effects model of the vehicles' mounts, robust to outlier vehicles.

Vehicles of one model share a design mount and scatter around it. On the right tangent space
around a reference ``T_ref`` (the design mount; docs/conventions.md: ``xi = local(T_ref, T)``,
[rotation rad, translation m], radar frame, the convention of every ``cov_right_radar``), vehicle
``i``'s estimate ``x_i = local(T_ref, T_i)`` with covariance ``C_i`` (6, 6) is modelled as

    x_i = mu + b_i + e_i,   b_i ~ N(0, S) (the fleet's spread),   e_i ~ N(0, C_i) (its own noise),

so ``x_i ~ N(mu, S + C_i)``. ``S`` is diagonal (six per-axis variances: a few dozen vehicles do not
support 21 covariance entries). ``mu`` and ``S`` are the maximum-likelihood estimate by EM,
started at the per-axis DerSimonian-Laird estimate (``_em``: the E-step is each vehicle's
posterior ``b_i``, the M-step the weighted mean and the per-axis mean of ``b_i^2`` + posterior
variance), which handles unequal ``C_i`` (a 10-frame vehicle with a weak direction weighs little
in it), unlike a plain sample variance.

Common-mode error: in the directions that only the elevation prior pins (``calib.covariance.
prior_pinned_std``: radar pitch and radar z; camera pitch and vertical translation) every vehicle's
estimate carries the SAME assumption about the world's reflector heights, so their errors are
correlated across the fleet, not independent (measured, docs/benchmarks.md: 20 ten-frame vehicles
all off by +32 cm in camera y, scatter 18 cm; a model without this term "learned" the fleet mean
there to 7 cm and tightened every vehicle's vertical translation to a confident wrong value, NEES
45). With ``common_cov`` = P (6, 6) the model is ``x_i = mu + c + b_i + e_i``, ``c ~ N(0, P)`` shared by
all vehicles: the EM uses each vehicle's own part ``C_i - common_part(C_i, P)`` (``P`` itself where only the
elevation prior pins the direction, less where the network or the LiDAR measure it too), the outlier test is
unaffected by ``c`` (it cancels in ``x_i - mu``). Measured on hybrid fleets (docs/benchmarks.md, "The common-mode
part"): the mean stays inside the vehicles and is more accurate than with all of P taken out, but the spread in the
pinned directions is not resolved and a knocked radar is named less often by this test (its own tests name it).
The prior handed to a vehicle must not pin those directions at
all: the vehicle's own covariance already holds ``c`` (``marginalise_prior_pinned``), and a window
combines an external prior as independent information, so a prior holding ``P`` once still
tightened them falsely (measured: camera-y std 31 -> 23 cm at an unchanged 36 cm RMS error).
Priors therefore carry ``PINNED_INFLATION x P`` (10x the std: uninformative there).

Robustness: each vehicle is tested against the fleet fitted WITHOUT it (leave-one-out):
``d_i^2 = (x_i - mu_-i)^T (S_-i + C_i + Cov(mu_-i))^-1 (x_i - mu_-i)``, referred to the sum of six
squared Student-t(m - 1) with m the other vehicles (``outlier_p_value``: S is estimated from them, not
known; chi-square(6) only for large fleets); a vehicle with p < ``alpha`` is an outlier (a knocked
radar), named, and left out of the fit; repeated until the inlier set is stable. The prior for an
inlier vehicle is its leave-one-out predictive distribution ``N(T_ref exp(mu_-i), f(m) S_-i + Cov(mu_-i) +
PINNED_INFLATION P)`` (its own data is not counted twice; ``f(m) = (m - 1) / (m - 3)``, ``predictive_factor``: the
Student-t's variance, for S itself is estimated from the m other vehicles), given only when it rests on at least
``MIN_PRIOR_VEHICLES`` (4) other vehicles (a fleet of 4: none, "no_prior" in the file); for a new vehicle the
full fit's (m = all inliers); an outlier gets none (the crowd must not pull it back). The caller leaves out vehicles
whose own status says their estimate is not trusted (``fleet.summary``).

Applying a saved prior (``load_priors``, ``match_prior``): the file records where each vehicle came from
(``sources``: root, version, vehicle, frames); a named prior goes only to that vehicle of that root (another
fleet's vehicle of the same name is a new vehicle to it), and a prior tighter than ``MIN_PRIOR_STD`` on any axis
is refused on load. A vehicle's verdict names the axes where its estimate still restates the prior
(``calib.drift.prior_note``).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from functools import lru_cache
from pathlib import Path

import numpy as np

from hybrid_calib.config import save_json_atomic
from hybrid_calib.errors import DataError
from hybrid_calib.geometry import check_covariance, check_transform, is_rigid, local, retract

MIN_VEHICLES = 3  # fewer inliers say nothing about a spread
# a prior rests on at least this many vehicles: the spread ``S`` is estimated from them, so the predictive distribution
# of a vehicle's mount is a Student-t with m - 1 degrees of freedom, whose variance ``(m - 1) / (m - 3) S`` is finite
# from m = 4 on (``predictive_factor``); a Gaussian with ``S`` itself handed out by a 4-vehicle fleet missed its own
# vehicles by d2 = 19.7 on average against 4 (probe 21; 24 vehicles: 4.90)
MIN_PRIOR_VEHICLES = 4
PINNED_INFLATION = 100.0  # priors carry this x the common-mode covariance P (module doc): no pull there
VAR_FLOOR = (np.radians(1e-3) ** 2,) * 3 + ((1e-5) ** 2,) * 3  # (6,) [rad^2, m^2]: keeps S positive
# a prior tighter than this on any axis (std, [rad x3, m x3]) is refused on load: no target-free calibration of a
# fleet knows a mount to better than a hundredth of a degree or a millimetre (a 1e-14 covariance pinned every
# vehicle to the prior's mean and called each "recalibrate" with micro-degree stds)
MIN_PRIOR_STD = (np.radians(0.01),) * 3 + (1e-3,) * 3


@dataclass(frozen=True)
class Fit:
    """One EM fit: fleet mean offset ``mu`` (6,), spread ``S`` (6, 6) diagonal, ``cov_mu`` (6, 6)."""

    mu: np.ndarray
    S: np.ndarray
    cov_mu: np.ndarray
    iterations: int


def _sym(C: np.ndarray) -> np.ndarray:
    C = 0.5 * (np.asarray(C, np.float64) + np.asarray(C, np.float64).T)
    return C + np.eye(6) * 1e-12 * max(np.trace(C), 1e-12)


def _dersimonian_laird(x: np.ndarray, C: np.ndarray) -> np.ndarray:
    """(6,) per-axis DerSimonian-Laird moment estimate of the spread variance (EM's starting point:
    EM alone creeps for many iterations from a spread far below the vehicles' own noise)."""
    w = 1.0 / np.diagonal(C, axis1=1, axis2=2)  # (n, 6)
    m = (w * x).sum(0) / w.sum(0)
    Q = (w * (x - m) ** 2).sum(0)
    return np.maximum(0.0, (Q - (len(x) - 1)) / (w.sum(0) - (w ** 2).sum(0) / w.sum(0)))


def common_part(C: np.ndarray, P: np.ndarray) -> np.ndarray:
    """(6, 6) the part of a vehicle's covariance ``C`` that the fleet's common-mode error (``P``, diagonal: the
    prior-pinned directions) puts there: ``L P L^T`` with loading column ``L[:, k] = C[:, k] / max(P_kk, C_kk)``.

    Where the vehicle's information holds the elevation prior ``P^-1`` and nothing else along k (the oracle:
    ``C e_k = P_kk e_k``) this is ``P`` itself. Where something else measures k too (the hybrid: the network's prior
    of the mount, the LiDAR), the shared error enters the estimate scaled by ``C P^-1`` (``C_kk < P_kk``), so only
    ``C_kk^2 / P_kk`` of it is common; subtracting all of ``P`` there left each vehicle a near-exact "own" variance
    (0.2 cm in radar z) and the fleet mean was extrapolated beyond every vehicle (session 36, probe 67: the demo's
    3 hybrid vehicles at -0.2..7.1 cm forward, mean -5.8 cm; on 300 synthetic hybrid-like fleets the mean's NEES
    1569, 4.4 with this). A covariance widened beyond ``P`` (``C_kk > P_kk``) holds all of ``P``."""
    d = np.diag(P)
    K = np.flatnonzero(d > 1e-9 * max(float(d.max()), 1e-300))  # the pinned axes (_sym adds a trace-sized epsilon)
    if not len(K):
        return np.zeros((6, 6))
    # L = C[:, K] A, A = diag(1 / max(P_kk, C_kk)): common = C[:, K] M C[K, :] with M = A P_KK A. It is at most C when
    # M <= C_KK^-1 (then it is at most the Schur part C[:, K] C_KK^-1 C[K, :]): true per axis, not always for
    # correlated pinned axes (probe 70: pitch and height correlated 0.9 gave an own variance < 0, clipped to ~0).
    # Scaled down to that bound where it is passed.
    A = np.diag(1.0 / np.maximum(d[K], np.diag(C)[K]))
    M = A @ P[np.ix_(K, K)] @ A
    R = np.linalg.cholesky(C[np.ix_(K, K)])
    over = float(np.linalg.eigvalsh(R.T @ M @ R).max())  # M <= C_KK^-1  <=>  R^T M R <= I
    return C[:, K] @ (M / max(over, 1.0)) @ C[K, :]


def _own(C: np.ndarray, P: np.ndarray) -> np.ndarray:
    """A vehicle's own covariance ``C - common_part(C, P)``, kept positive definite: its eigenvalues are clipped at
    1e-4 of C's own along each eigenvector."""
    C = _sym(C)
    w, V = np.linalg.eigh(C - common_part(C, P))
    floor = 1e-4 * np.einsum("ij,ik,kj->j", V, C, V)
    return _sym((V * np.maximum(w, floor)) @ V.T)


def _em(x: np.ndarray, C: np.ndarray, iters: int = 300, tol: float = 1e-6, init: Fit | None = None) -> Fit:
    """ML (mu, S) of ``x`` (n, 6) with per-item covariances ``C`` (n, 6, 6) (module doc); ``init``
    warm-starts the spread (the leave-one-out fits start at the full fit)."""
    floor = np.asarray(VAR_FLOOR)
    s = np.maximum(_dersimonian_laird(x, C), floor) if init is None else np.diag(init.S).copy()
    iterations = 0
    while iterations < iters:
        iterations += 1
        S = np.diag(s)
        W = np.linalg.inv(S[None] + C)  # (n, 6, 6)
        cov_mu = np.linalg.inv(W.sum(0))
        mu = cov_mu @ np.einsum("nij,nj->i", W, x)
        K = S[None] @ W  # (n, 6, 6): posterior gain of b_i
        r = x - mu
        b = np.einsum("nij,nj->ni", K, r)
        P = S[None] - K @ S[None]
        s_new = np.maximum(np.mean(b ** 2 + np.diagonal(P, axis1=1, axis2=2), axis=0), floor)
        done = np.max(np.abs(s_new - s) / s) < tol
        s = s_new
        if done:
            break
    S = np.diag(s)
    W = np.linalg.inv(S[None] + C)
    cov_mu = np.linalg.inv(W.sum(0))
    mu = cov_mu @ np.einsum("nij,nj->i", W, x)
    return Fit(mu, S, cov_mu, iterations)


def _d2(x: np.ndarray, C: np.ndarray, f: Fit) -> float:
    r = x - f.mu
    return float(r @ np.linalg.solve(f.S + C + f.cov_mu, r))


@lru_cache(maxsize=64)
def _sum_t2_sample(dof: int) -> np.ndarray:
    """Sorted Monte Carlo sample (200 000, fixed seed) of the sum of six squared Student-t(``dof``) variables."""
    g = np.random.default_rng(20261202)
    return np.sort((g.standard_t(dof, size=(200_000, 6)) ** 2).sum(axis=1))


def outlier_p_value(d2: float, m: int) -> float:
    """p-value of a vehicle's ``d2`` against a fleet fitted on ``m`` other vehicles. The spread S is estimated
    from those m vehicles, not known: each standardised axis is then Student-t with m - 1 degrees of freedom, not
    normal, and ``d2`` is referred to the sum of six squared t(m - 1) (Monte Carlo) rather than chi-square(6) (as
    if S were known: measured, 2 of 5 healthy simulated vehicles named outliers at alpha 1e-3, d2 47 and 37).
    Conservative where the vehicles' own covariances dominate S; chi-square(6) from 100 degrees of freedom on."""
    from scipy.stats import chi2

    dof = max(int(m) - 1, 1)
    if dof >= 100:
        return float(chi2.sf(d2, 6))
    sample = _sum_t2_sample(dof)
    above = len(sample) - int(np.searchsorted(sample, d2, side="left"))
    return (above + 1) / (len(sample) + 1)


def predictive_factor(m: int) -> float:
    """Variance factor of a vehicle's predictive distribution when the fleet spread was estimated from ``m`` vehicles:
    the Student-t's ``nu / (nu - 2)`` with ``nu = m - 1`` (3 for m = 4, 1.5 for 7, 1.1 for 23); infinite below m = 4."""
    nu = int(m) - 1
    return float("inf") if nu <= 2 else nu / (nu - 2)


@dataclass
class FleetPrior:
    """The fitted fleet model (module doc). Vectors are right-tangent offsets from ``T_ref``."""

    T_ref: np.ndarray  # (4, 4) the reference (design mount)
    names: list[str]  # every vehicle used (inliers + outliers)
    fit: Fit  # on the inliers
    inliers: list[str]
    outliers: dict[str, dict] = field(default_factory=dict)  # name -> {"d2", "p_value"}
    tests: dict[str, dict] = field(default_factory=dict)  # name -> {"d2", "p_value"} for every vehicle
    loo: dict[str, Fit] = field(default_factory=dict)  # inlier name -> fit without it
    alpha: float = 1e-3
    common_cov: np.ndarray = field(default_factory=lambda: np.zeros((6, 6)))  # P (module doc)
    # name -> {"data": root (resolved), "version", "vehicle", "frames"}: where each vehicle came from, so that a
    # later fleet applies a named prior only to the same vehicle of the same root (``match_prior``)
    sources: dict[str, dict] = field(default_factory=dict)
    # (6, 6) the variances along directions the fleet's method does not measure (a learned method's roll, pitch and
    # height: ``fleet.summary.unmeasured_cov``): its priors carry ``PINNED_INFLATION`` x them, no information there
    unmeasured_cov: np.ndarray = field(default_factory=lambda: np.zeros((6, 6)))

    @property
    def T_mean(self) -> np.ndarray:
        """(4, 4) the fleet's mean mount."""
        return retract(self.T_ref, self.fit.mu)

    def prior(self, name: str | None = None) -> dict | None:
        """The prior for vehicle ``name`` (leave-one-out for an inlier, the full fit for a new
        vehicle, None for an outlier) as plain data {"T_cam_radar", "cov_right_radar"}: the predictive distribution
        of its mount, ``predictive_factor(m) S + Cov(mu) + PINNED_INFLATION P`` with m the vehicles it rests on;
        None below ``MIN_PRIOR_VEHICLES`` of them."""
        rests_on = len(self.inliers) - (name in self.inliers)  # its own estimate is not counted twice
        if name in self.outliers or rests_on < MIN_PRIOR_VEHICLES:
            return None  # an outlier; or too few other vehicles to know the spread
        f = self.loo.get(name, self.fit) if name is not None else self.fit
        T = retract(self.T_ref, f.mu)
        cov = predictive_factor(rests_on) * f.S + f.cov_mu + PINNED_INFLATION * (self.common_cov + self.unmeasured_cov)
        return {"T_cam_radar": T.tolist(), "cov_right_radar": _sym(cov).tolist()}

    def priors(self) -> dict[str, dict]:
        """Job id -> prior for every vehicle (None for an outlier: no prior), "*" (a new vehicle) -> the
        full fit's."""
        return {"*": self.prior(None), **{n: self.prior(n) for n in self.names}}

    def spread_std_cam(self) -> np.ndarray:
        """(6,) the fleet's 1-sigma spread in camera axes [deg x3, cm x3] (docs/conventions.md)."""
        from hybrid_calib.calib.covariance import report_std

        return report_std(self.T_mean, self.fit.S)

    def to_dict(self) -> dict:
        from hybrid_calib.calib.covariance import report_std
        from hybrid_calib.calib.result import STD_FRAME, extrinsic_report
        from hybrid_calib.metrics import std_dict

        return {
            "schema": PRIOR_SCHEMA,
            "model": "x_i = local(T_ref, T_i) ~ N(mu, S + C_i), S diagonal; EM; leave-one-out outlier test, d2 "
                     "referred to the sum of six squared Student-t(m - 1), m the other vehicles (chi2(6) from m = 101)",
            "no_prior": sorted(n for n in self.inliers if len(self.inliers) - 1 < MIN_PRIOR_VEHICLES),
            "T_ref": self.T_ref.tolist(), "T_mean": self.T_mean.tolist(), "mean_report": extrinsic_report(self.T_mean),
            "mu_right_radar": self.fit.mu.tolist(), "spread_cov_right_radar": self.fit.S.tolist(),
            "mean_cov_right_radar": self.fit.cov_mu.tolist(),
            "spread_std_cam": std_dict(self.spread_std_cam(), STD_FRAME),
            "mean_std_cam": std_dict(report_std(self.T_mean, self.fit.cov_mu + self.common_cov), STD_FRAME),
            "common_cov_right_radar": self.common_cov.tolist(),
            **({"unmeasured_cov_right_radar": self.unmeasured_cov.tolist()} if np.any(self.unmeasured_cov) else {}),
            "fitted_on": "each vehicle's drive alone (a vehicle given a fleet prior enters with its calibration "
                         "without it: fleet.summary._own_estimate)",
            "alpha": self.alpha, "iterations": self.fit.iterations,
            "vehicles": self.names, "inliers": self.inliers, "outliers": self.outliers, "tests": self.tests,
            "priors": self.priors(), "sources": self.sources,
            "basis": {"vehicles": len(self.names), "inliers": len(self.inliers),
                      "frames": sum(int(v.get("frames") or 0) for v in self.sources.values()) or None},
        }

    def save(self, path: str | Path) -> Path:
        return save_json_atomic(Path(path), self.to_dict())


def fit_fleet_prior(names: list[str], Ts: list[np.ndarray], covs: list[np.ndarray], T_ref: np.ndarray,
                    alpha: float = 1e-3, rounds: int = 10, common_cov: np.ndarray | None = None,
                    sources: dict[str, dict] | None = None, unmeasured_cov: np.ndarray | None = None) -> FleetPrior:
    """Fit the fleet model (module doc) to vehicles ``names`` with estimates ``Ts`` (each (4, 4)) and
    covariances ``covs`` (each (6, 6), right tangent, radar frame, [rad, m]) around ``T_ref`` (4, 4).
    ``common_cov`` (6, 6): the part of every ``covs[i]`` shared by all vehicles (P; default none).
    ``sources``: name -> {"data", "version", "vehicle", "frames"} (``FleetPrior.sources``). ``unmeasured_cov`` (6, 6):
    ``FleetPrior.unmeasured_cov`` (default none).
    ``DataError`` with fewer than ``MIN_VEHICLES`` vehicles."""
    if not len(names) == len(Ts) == len(covs):  # zip-like truncation dropped vehicles without a word
        raise ValueError(f"fit_fleet_prior: {len(names)} names, {len(Ts)} transforms and {len(covs)} covariances; "
                         "give one of each per vehicle")
    if len(set(names)) != len(names):
        raise ValueError(f"fit_fleet_prior: a vehicle named twice ({sorted({n for n in names if names.count(n) > 1})})")
    T_ref = check_transform(T_ref, "fit_fleet_prior T_ref")
    Ts = [check_transform(T, f"fit_fleet_prior Ts[{k}] ({names[k]})") for k, T in enumerate(Ts)]
    covs = [check_covariance(c, f"fit_fleet_prior covs[{k}] ({names[k]})") for k, c in enumerate(covs)]
    if len(names) < MIN_VEHICLES:
        raise DataError(f"a fleet prior needs >= {MIN_VEHICLES} calibrated vehicles, got {len(names)}")
    x = np.array([local(T_ref, T) for T in Ts])
    P = np.zeros((6, 6)) if common_cov is None else _sym(common_cov)
    C = np.array([_own(c, P) for c in covs])
    inl = list(range(len(names)))
    loo: dict[int, Fit] = {}
    tests: dict[int, tuple[float, float]] = {}
    for _ in range(rounds):
        fit = _em(x[inl], C[inl])
        # every inlier against the fleet WITHOUT it (a fit that includes it would test it against itself)
        loo = {i: _em(x[[j for j in inl if j != i]], C[[j for j in inl if j != i]], init=fit) for i in inl}
        for i in range(len(names)):
            d2 = _d2(x[i], C[i], loo.get(i, fit))
            tests[i] = (d2, outlier_p_value(d2, len(inl) - 1 if i in loo else len(inl)))
        new = [i for i in range(len(names)) if tests[i][1] >= alpha]
        if len(new) < MIN_VEHICLES:  # no crowd to speak of: keep the largest-p vehicles
            new = sorted(sorted(range(len(names)), key=lambda i: -tests[i][1])[:MIN_VEHICLES])
        if new == inl:
            break
        inl = new
    return FleetPrior(
        np.asarray(T_ref, np.float64), list(names), fit, [names[i] for i in inl],
        {names[i]: {"d2": tests[i][0], "p_value": tests[i][1]} for i in range(len(names)) if i not in inl},
        {names[i]: {"d2": tests[i][0], "p_value": tests[i][1]} for i in range(len(names))},
        {names[i]: f for i, f in loo.items()}, alpha, P, dict(sources or {}),
        _sym(unmeasured_cov) if unmeasured_cov is not None and np.any(unmeasured_cov) else np.zeros((6, 6)))


def _check_prior(k: str, p: dict) -> None:
    """``ValueError`` naming prior ``k`` when its transform is not a finite rigid 4x4 or its covariance not a finite
    symmetric positive-definite 6x6 (a NaN prior failed every vehicle as an "internal error")."""
    T = np.asarray(p["T_cam_radar"], np.float64)
    C = np.asarray(p["cov_right_radar"], np.float64)
    if T.shape != (4, 4) or C.shape != (6, 6):
        raise ValueError(f"prior {k!r} needs T_cam_radar 4x4 and cov_right_radar 6x6")
    if not (np.isfinite(T).all() and np.isfinite(C).all()):
        raise ValueError(f"prior {k!r} holds non-finite values")
    if not is_rigid(T):
        raise ValueError(f"prior {k!r}: T_cam_radar is not a rigid transform")
    if not np.allclose(C, C.T, atol=1e-12 + 1e-9 * np.abs(C).max()) or np.linalg.eigvalsh(0.5 * (C + C.T)).min() <= 0:
        raise ValueError(f"prior {k!r}: cov_right_radar is not symmetric positive definite")
    std = np.sqrt(np.diag(C))
    if (low := np.flatnonzero(std < np.asarray(MIN_PRIOR_STD))).size:
        axes = ", ".join(("rot x", "rot y", "rot z", "t x", "t y", "t z")[i] for i in low)
        raise ValueError(f"prior {k!r}: cov_right_radar is tighter than any fleet can know a mount ({axes}: std "
                         f"{', '.join(f'{std[i]:.2g}' for i in low)} [rad | m], floor 0.01 deg / 1 mm)")


PRIOR_SCHEMA = "hybrid-calib/fleet-prior/v1"  # fleet_prior.json's "schema" (a file without one is read as it)


def load_priors(path: str | Path) -> dict[str, dict]:
    """``fleet_prior.json`` (``FleetPrior.save``) -> its "priors" (job id -> {"T_cam_radar",
    "cov_right_radar", "file", and "source" where the file records it}, or None for a named outlier; "*" for a new
    vehicle); ``DataError`` naming the file (also for a prior tighter than ``MIN_PRIOR_STD``)."""
    import json

    path = Path(path)
    if not path.is_file():
        # beside a fleet run's summary.json that wrote none: its summary says why (probe 71: the advice to pass
        # the file that run wrote could not be followed)
        why = (f"; the fleet run in {path.parent} fitted none (its summary.md says why: fewer than "
               f"{MIN_VEHICLES} vehicles with a trusted estimate, say)" if (path.parent / "summary.json").is_file()
               else "")
        raise DataError(f"fleet prior {'is a directory' if path.is_dir() else 'does not exist'}{why}; pass the "
                        "fleet_prior.json a hybrid-calib fleet run wrote beside its summary.json, or run without "
                        "--prior", path=str(path))
    try:
        doc = json.loads(path.read_text(encoding="utf-8"))
        if not isinstance(doc, dict) or "priors" not in doc:
            raise KeyError("no 'priors': not a fleet_prior.json")
        if doc.get("schema", PRIOR_SCHEMA) != PRIOR_SCHEMA:  # probe 45: another schema's file was read as this one
            raise ValueError(f"its schema is {str(doc.get('schema'))[:60]!r}, not {PRIOR_SCHEMA!r} (a file of another "
                             "version of hybrid-calib, or edited): rerun that fleet with this version")
        priors = doc["priors"]
        sources = doc.get("sources") or {}
        if not isinstance(priors, dict):
            raise TypeError(f"'priors' is a JSON {type(priors).__name__}, not an object of job id -> prior")
        if not isinstance(sources, dict) or not all(isinstance(v, dict) for v in sources.values()):
            raise TypeError("'sources' is not an object of vehicle -> {data, version, vehicle, frames}")
        for k, p in priors.items():
            if p is not None:
                _check_prior(k, p)
    except (OSError, ValueError, KeyError, TypeError, AttributeError, np.linalg.LinAlgError, RecursionError) as e:
        why = "nested too deeply" if isinstance(e, RecursionError) else f"{type(e).__name__}: {str(e)[:300]}"
        raise DataError(f"fleet prior unreadable ({why}); pass the fleet_prior.json of a "
                        "hybrid-calib fleet run", path=str(path)) from None
    out = {}
    for k, p in priors.items():
        # a named outlier (no prior) keeps its source too: another root's outlier verdict must not pass by name
        p = {"outlier": True, "file": str(path)} if p is None else \
            {"T_cam_radar": p["T_cam_radar"], "cov_right_radar": p["cov_right_radar"], "file": str(path)}
        if isinstance(sources.get(k), dict):
            p["source"] = {f: sources[k].get(f) for f in ("data", "version", "vehicle", "digest")}
        out[k] = p
    return out


def same_source(source: dict, data: str, version: str, vehicle: str,
                digest: Callable[[], str | None] | None = None) -> bool:
    """Whether a prior's recorded ``source`` ({"data", "version", "vehicle", "digest"}) is vehicle ``vehicle`` of
    root ``data`` and ``version``: the root at the recorded path (compared resolved), or a root whose data are the
    recorded ones (``data.files.data_stamp``'s digest; ``digest()`` gives this root's, asked only when the paths
    differ): a root copied or moved to another path is the same data (probe 114: its vehicles were given the full
    fit, which holds their own estimates, without a word)."""
    if source.get("version") != version or source.get("vehicle") != vehicle:
        return False
    try:
        if Path(str(source.get("data"))).resolve() == Path(data).resolve():
            return True
    except (OSError, RuntimeError):
        pass
    want = source.get("digest")
    return bool(isinstance(want, str) and want and digest is not None and digest() == want)


def match_prior(priors: dict, job_id: str, data: str, version: str, vehicle: str,
                digest: Callable[[], str | None] | None = None) -> tuple[dict | None, str | None]:
    """The prior for a job (``load_priors``' dict): the one named ``job_id`` when it was fitted on this very
    vehicle of this root, else the one fitted on this vehicle of this root under another job id (a root run alone
    names its vehicles without the root's prefix a fleet of several roots gave them), else the new-vehicle prior "*";
    with a note (str) when a named prior was passed over, found by its source, or could not be checked (a file without
    "sources"), else None. A named outlier's None stays None."""
    if job_id not in priors:
        for name, p in priors.items():  # the vehicle was in the fit under another id: its own leave-one-out prior
            if name != "*" and isinstance(p, dict) and isinstance(p.get("source"), dict) and \
                    same_source(p["source"], data, version, vehicle, digest):
                own = _usable(p)  # a named outlier, or a fit of too few others, holds none (probe 115: "applied")
                return own, (f"{job_id}: the fleet prior's entry {name!r} was fitted on this vehicle of this root: "
                             + ("its leave-one-out prior is applied (the full fit's would hold its own estimate)"
                                if own is not None else "it holds no prior for it (an outlier of that fleet, or too "
                                "few other vehicles), so none is applied (the full fit's would hold its own "
                                "estimate)"))
        return _usable(priors.get("*")), None
    p = priors[job_id]
    if p is None:
        return None, None
    src = p.get("source")
    if not isinstance(src, dict):
        return _usable(p), ("the fleet prior's file records no source for its vehicles (written by an older "
                            "version): its named priors are applied by vehicle name only; refit it to have them "
                            "checked")
    if same_source(src, data, version, vehicle, digest):
        return _usable(p), None
    return _usable(priors.get("*")), (f"{job_id}: the fleet prior's entry {job_id!r} was fitted on vehicle "
                                      f"{src.get('vehicle')!r} of {src.get('data')!r} ({src.get('version')!r}), not "
                                      "on this root's; it gets the new-vehicle prior instead")


def _usable(p: dict | None) -> dict | None:
    """A prior as a job takes it: None for a named outlier (``load_priors``' {"outlier": True})."""
    return None if p is None or p.get("outlier") else p
