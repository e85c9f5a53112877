"""The network's out-of-domain score: is this frame like the frames it learned from?

Per frame, from what the network produces (``frame_features``; B samples):

- ``descriptor`` (B, 2 D'): the fused global descriptor the regression head reads (``out["fused"]``)
  at iteration 0 and at the last iteration, concatenated;
- ``signals`` (B, 6): named in ``SIGNALS``:
  ``match_mass``: mean over the valid radar points of the FV assignment mass ``sum_i P_ij`` of the
  point's radar cell at iteration 0 (how much the network finds anything to match);
  ``match_entropy``: mean entropy of the column ``P_:j`` normalised over image cells, divided by
  ``log m_I`` (0: one sharp match, 1: uniform);
  ``last_step_rot`` / ``last_step_trans``: size of the last cascade correction ``Log(T_deltas[-1])``
  (rad, m): an estimate that still moves at the last iteration has not settled;
  ``log_var_mean``: mean of the last iteration's predicted log-variances (the network's own doubt);
  ``fusion_fv``: mean selective-fusion weight of the FV view (0.5 without selective fusion).

The score (``OODModel``) is a Gaussian density model of one feature set (``FEATURE_SETS``) fitted on
in-domain frames (simulated validation drives; ``benchmarks/ood_fit.py``): each feature standardised
by its fit mean and std, projected on the top ``k`` principal directions (variance ``lam_k``) with the
remaining squared norm ``r`` as one more term:

    d2 = sum_k p_k^2 / lam_k + r / r_mean            (expected value k + 1 on in-domain frames)
    score = d2 / threshold

``threshold`` is the ``quantile`` (default 0.99) of ``d2`` over calibration frames that were NOT used to
fit the mean, std and directions (the fit frames are split in two), so ``score > 1`` marks a frame less
typical than 99 % of held-out in-domain frames. A frame whose camera image shows no scene
(``image_structure`` below ``MIN_IMAGE_STRUCTURE``: noise, a blank frame) scores at least ``image_score`` whatever
the network made of it (``hybrid.network.NetworkRunner.ood_score``). The model lives in the checkpoint's export block
(``export["ood"]``, ``OODModel.to_dict``) with the command and frames that fitted it.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field

import numpy as np
import torch

from hybrid_calib.config import json_numbers
from hybrid_calib.errors import HybridCalibError
from learned import lie
from learned.transform import cell_index

SIGNALS = ("match_mass", "match_entropy", "last_step_rot", "last_step_trans", "log_var_mean", "fusion_fv")
FEATURE_SETS = ("descriptor", "signals", "all")
FIT_HINT = ("fit it with: PYTHONPATH=. python benchmarks/ood_fit.py --checkpoint CKPT --data VALIDATION_ROOT ... "
            "--heldout OTHER_ROOT ... --out OUT --fit-into (docs/benchmarks.md, 'Out-of-domain score')")


class OODError(HybridCalibError):
    """A malformed ``export["ood"]`` block (the message names what is wrong)."""


@torch.no_grad()
def frame_features(out: dict) -> dict[str, np.ndarray]:
    """``{"descriptor": (B, 2 D') , "signals": (B, len(SIGNALS))}`` float64 from a forward output."""
    fused = out["fused"]
    B = fused[0].shape[0]
    desc = torch.cat([fused[0], fused[-1]], 1).double()
    mass = torch.full((B,), float("nan"), dtype=torch.float64, device=desc.device)
    ent = mass.clone()
    fv = out["match"][0].get("fv")
    if fv is not None:
        log_P = fv["log_P"].double()  # (B, m_I, m_R)
        r = out["render"][0]
        cell = cell_index(r["fv_pix"], r["fv_valid"], out["image_hw"])  # (B, N)
        col_mass = torch.logsumexp(log_P, 1)  # (B, m_R) log sum_i P_ij
        p = (log_P - col_mass[:, None, :]).exp()
        col_ent = -(p * p.clamp_min(1e-30).log()).sum(1) / np.log(log_P.shape[1])  # (B, m_R)
        valid = cell >= 0
        idx = cell.clamp_min(0)
        n = valid.sum(1).clamp_min(1).double()
        mass = (col_mass.exp().gather(1, idx) * valid).sum(1) / n
        ent = (col_ent.gather(1, idx) * valid).sum(1) / n
        none = ~valid.any(1)
        mass[none] = 0.0
        ent[none] = 1.0
    xi = lie.se3_log(out["T_deltas"][-1].detach().double())
    w = out["fusion_weights"][-1]
    fusion = (w[:, 0].double().mean(-1) if w is not None
              else torch.full((B,), 0.5, dtype=torch.float64, device=desc.device))
    sig = torch.stack([mass, ent, xi[:, :3].norm(dim=1), xi[:, 3:].norm(dim=1),
                       out["log_var"][-1].double().mean(1), fusion], 1)
    sig = torch.nan_to_num(sig, nan=0.0)  # no FV matching head (ablations): constant signals
    return {"descriptor": desc.cpu().numpy(), "signals": sig.cpu().numpy()}


# The camera image's own test, before any network feature: a view of a scene has neighbouring pixels that correlate
# (lag-1 correlation of grey levels at the network's input, 96 x 200: min 0.95 on 80 images of randomised simulated
# drives of the four presets, min 0.86 / median 0.94 on scene-0916's 41 CAM_FRONT keyframes), uniform noise does not
# (0.00-0.01 saved as a 1600 x 900 JPEG, ~0.1 as a 200 x 112 one), a constant image has none (0);
# benchmarks/image_structure.py. Probe 87: on the shipped network's pure-avg pass 2 of 16 pure-noise images scored
# 0.77 and 0.87 by the density model alone (in domain) and were fused into a trusted result.
MIN_IMAGE_STRUCTURE = 0.5


def image_structure(image) -> float:
    """Lag-1 correlation (mean of horizontal and vertical neighbours) of the grey levels of ``image``, (3, H, W)
    (or (H, W, 3) uint8) in any scale: ~1 on a camera's view of a scene, ~0 on noise; 0 for a constant image."""
    g = np.asarray(image.cpu().numpy() if hasattr(image, "cpu") else image, np.float64)
    g = g.mean(0) if g.ndim == 3 and g.shape[0] in (1, 3) else g.mean(-1) if g.ndim == 3 else g
    cs = []
    for a, b in ((g[:, 1:], g[:, :-1]), (g[1:, :], g[:-1, :])):
        a, b = a - a.mean(), b - b.mean()
        d = float(np.sqrt((a * a).sum() * (b * b).sum()))
        cs.append(float((a * b).sum()) / d if d > 1e-12 * a.size else 0.0)
    return float(np.mean(cs)) if np.isfinite(cs).all() else 0.0


def image_score(structure: float) -> float:
    """The out-of-domain score the image test alone gives (``MIN_IMAGE_STRUCTURE / structure``, > 1 below the
    minimum; 0 at or above it, where the density model decides alone; 0 when not measured: NaN)."""
    if not np.isfinite(structure) or structure >= MIN_IMAGE_STRUCTURE:
        return 0.0
    return MIN_IMAGE_STRUCTURE / max(float(structure), 1e-3)


def image_words(structure: float) -> str:
    """Why a frame is out of domain by its image alone ("" when the image passes)."""
    if not image_score(structure):
        return ""
    return (f"the camera image shows no scene: its neighbouring pixels correlate {structure:.3f}, under "
            f"{MIN_IMAGE_STRUCTURE:g}; noise, a blank frame or a broken camera")


# The camera file's compression: the simulator's randomised training images are saved at JPEG quality 55-95, nuScenes'
# cameras at ~80 (``data.image_header.jpeg_quality``); under this the image has lost the detail the network matches on
# (probe 116: quality 2 passed every other test, and the hybrid read 4.4-5.7 deg of yaw that was not there).
MIN_JPEG_QUALITY = 30.0


def jpeg_score(quality: float) -> float:
    """The out-of-domain score the file's JPEG quality alone gives (``MIN_JPEG_QUALITY / quality``, > 1 below the
    minimum; 0 at or above it, and when not measured: NaN, a file that is not a JPEG)."""
    if not np.isfinite(quality) or quality >= MIN_JPEG_QUALITY:
        return 0.0
    return MIN_JPEG_QUALITY / max(float(quality), 1.0)


def jpeg_words(quality: float) -> str:
    """Why a frame is out of domain by its file's compression ("" when it passes)."""
    if not jpeg_score(quality):
        return ""
    return (f"the camera image is saved at JPEG quality ~{quality:.0f}, under {MIN_JPEG_QUALITY:g}: its detail is lost "
            "to compression (the networks were trained on 55-95; nuScenes' cameras save at ~80)")


# The camera image's brightness (mean grey level of the model-input image, 0..1): the randomised training images span
# ~0.28-0.62 (simulated with randomise.enabled=true, urban and rain, and the plain presets), scene-0916's 0.37-0.44.
# Outside these bounds a frame the density model scores out of domain is said to be dark or washed out: words only,
# the score stays the density model's (probe 89 and session 47: night-like images were "inconclusive" without a cause).
DARK_LUMINANCE = 0.2
BRIGHT_LUMINANCE = 0.8
TRAINED_LUMINANCE = "~0.28-0.62"

# A short phrase per cause, for a drive's count of its out-of-domain frames (``hybrid.ood.decide``)
CAUSES = {"no scene": "show no scene (noise, a blank frame or a broken camera)",
          "compression": f"are compressed beyond the training range (JPEG quality under {MIN_JPEG_QUALITY:g})",
          "dark": "are dark (night, a tunnel or an under-exposed camera)",
          "bright": "are washed out (glare, or an over-exposed camera)"}


def image_luminance(image) -> float:
    """Mean grey level, 0..1, of ``image``: (3, H, W) float in [0, 1] (the model input) or (H, W, 3) uint8."""
    a = np.asarray(image.cpu().numpy() if hasattr(image, "cpu") else image)
    g = a.astype(np.float64) / (255.0 if a.dtype == np.uint8 else 1.0)
    m = float(g.mean()) if g.size else float("nan")
    return m if np.isfinite(m) else float("nan")


def luminance_words(luminance: float) -> tuple[str, str]:
    """(cause, words) of an image darker or brighter than the training images' (``CAUSES``' key); ("", "") within
    them, and when not measured (NaN)."""
    if not np.isfinite(luminance) or DARK_LUMINANCE <= luminance <= BRIGHT_LUMINANCE:
        return "", ""
    dark = luminance < DARK_LUMINANCE
    cause = "night, a tunnel or an under-exposed camera" if dark else "glare, or an over-exposed camera"
    return ("dark" if dark else "bright",
            f"the camera image is {'dark' if dark else 'washed out'}: its mean grey level {luminance:.2f} is "
            f"{'under' if dark else 'over'} {DARK_LUMINANCE if dark else BRIGHT_LUMINANCE:g} (the networks were "
            f"trained on {TRAINED_LUMINANCE}): {cause}")


def raised_score(density: float, structure: float, quality: float) -> float:
    """A frame's out-of-domain score: the density model's ``density``, raised by the camera image's own tests (its
    structure, ``image_score``; its file's JPEG quality, ``jpeg_score``). Calibrate's and evaluate's one rule."""
    return max(float(density), image_score(structure), jpeg_score(quality))


def image_cause(density: float, structure: float, quality: float, luminance: float) -> tuple[str, str]:
    """(cause, words): why a pass whose density-model score is ``density`` is out of domain, by its camera image: the
    image test's or the file's own test where one scores at or above the density model (``image_words``,
    ``jpeg_words``), else its brightness where it lies outside the training images' (``luminance_words``);
    ("", "") where the image shows no cause (the general reason holds)."""
    image, jpeg = image_score(structure), jpeg_score(quality)
    if max(image, jpeg) and max(image, jpeg) >= density:
        return ("no scene", image_words(structure)) if image >= jpeg else ("compression", jpeg_words(quality))
    return luminance_words(luminance)


def select(feats: Mapping[str, np.ndarray], features: str) -> np.ndarray:
    """(F, D) rows of one feature set from ``{"descriptor": (F, Dd), "signals": (F, Ds)}``."""
    if features == "all":
        return np.concatenate([np.atleast_2d(feats["descriptor"]), np.atleast_2d(feats["signals"])], 1)
    if features not in FEATURE_SETS:
        raise OODError(f"unknown feature set {features!r}; valid: {FEATURE_SETS}")
    return np.atleast_2d(np.asarray(feats[features], np.float64))


QUANTILE = 0.99  # the calibration half's d2 quantile a fit sets the threshold at (and a model that records none)


@dataclass(frozen=True)
class OODModel:
    """Gaussian (PCA + residual) density of in-domain features; see the module docstring.

    features: one of ``FEATURE_SETS``. mean, std: (D,). components: (k, D) orthonormal rows.
    variances: (k,) lam. residual_mean: mean residual squared norm on the fit half. threshold: d2 at
    ``quantile`` of the calibration half. fitted: provenance (command, roots, frames, counts).
    """

    features: str
    mean: np.ndarray
    std: np.ndarray
    components: np.ndarray
    variances: np.ndarray
    residual_mean: float
    threshold: float
    quantile: float = QUANTILE
    fitted: dict = field(default_factory=dict)

    def distance(self, X: np.ndarray) -> np.ndarray:
        """(F, D) features of ``self.features`` -> (F,) d2."""
        X = np.atleast_2d(np.asarray(X, np.float64))
        if X.shape[1] != len(self.mean):
            raise OODError(f"features have {X.shape[1]} dimensions, the fitted model {len(self.mean)}: the "
                           f"export.ood block belongs to another network; {FIT_HINT}")
        z = (X - self.mean) / self.std
        p = z @ self.components.T
        r = np.maximum((z * z).sum(1) - (p * p).sum(1), 0.0)
        return (p * p / self.variances).sum(1) + r / max(self.residual_mean, 1e-12)

    def score(self, feats: Mapping[str, np.ndarray]) -> np.ndarray:
        """(F,) score = d2 / threshold (> 1: out of domain) of ``frame_features``-like rows."""
        return self.distance(select(feats, self.features)) / self.threshold

    def to_dict(self) -> dict:
        return {"features": self.features, "mean": self.mean.tolist(), "std": self.std.tolist(),
                "components": self.components.tolist(), "variances": self.variances.tolist(),
                "residual_mean": float(self.residual_mean), "threshold": float(self.threshold),
                "quantile": float(self.quantile), "fitted": self.fitted}

    @classmethod
    def from_dict(cls, d) -> OODModel:
        """``OODError`` saying what is wrong with a malformed block."""
        if not isinstance(d, Mapping):
            raise OODError(f"export.ood is a {type(d).__name__}, not an object; {FIT_HINT}")
        missing = [k for k in ("features", "mean", "std", "components", "variances", "residual_mean", "threshold")
                   if k not in d]
        if missing:
            raise OODError(f"export.ood lacks {missing}; {FIT_HINT}")
        text = [k for k in ("mean", "std", "components", "variances", "residual_mean", "threshold", "quantile")
                if k in d and not json_numbers(d[k])]
        if text:  # "12.2" read as the number before (probe 110): a block hand-edited or written by another tool
            raise OODError(f"export.ood holds a non-numeric value in {', '.join(text)} (JSON numbers are needed, not "
                           f"text); {FIT_HINT}")
        try:
            mean, std = np.asarray(d["mean"], np.float64), np.asarray(d["std"], np.float64)
            comp, var = np.atleast_2d(np.asarray(d["components"], np.float64)), np.asarray(d["variances"], np.float64)
            res, thr, quantile = float(d["residual_mean"]), float(d["threshold"]), float(d.get("quantile", QUANTILE))
        except (TypeError, ValueError) as e:
            raise OODError(f"export.ood holds a non-numeric value ({e}); {FIT_HINT}") from None
        D = len(mean)
        if mean.ndim != 1 or not D or std.shape != (D,) or comp.shape[1:] != (D,) or var.shape != (len(comp),):
            raise OODError(f"export.ood arrays disagree in shape (mean {mean.shape}, std {std.shape}, components "
                           f"{comp.shape}, variances {var.shape}); {FIT_HINT}")
        arrays_ok = all(np.all(np.isfinite(a)) for a in (mean, std, comp, var))
        if not arrays_ok or np.any(std <= 0) or np.any(var <= 0) or not (thr > 0 and np.isfinite(thr)) \
                or not (res >= 0 and np.isfinite(res)) or not 0 < quantile <= 1:
            raise OODError(f"export.ood holds non-finite or non-positive statistics (or a quantile outside (0, 1]: "
                           f"{quantile}); {FIT_HINT}")
        if np.abs(comp @ comp.T - np.eye(len(comp))).max() > 1e-6:
            raise OODError(f"export.ood components are not orthonormal rows (principal directions); {FIT_HINT}")
        if thr > 100 * (len(comp) + 1):  # in-domain frames' d2 is about k + 1: such a test flags nothing (probe 27)
            raise OODError(f"export.ood threshold {thr:g} is more than 100 times the distance of an in-domain frame "
                           f"(about {len(comp) + 1}), so the test would pass every frame; {FIT_HINT}")
        if not isinstance(d.get("fitted", {}), Mapping):
            raise OODError(f"export.ood fitted is a {type(d['fitted']).__name__}, not an object; {FIT_HINT}")
        features = str(d["features"])
        if features not in FEATURE_SETS:
            raise OODError(f"export.ood features {features!r} unknown; valid: {FEATURE_SETS}; {FIT_HINT}")
        return cls(features, mean, std, comp, var, res, thr, quantile, dict(d.get("fitted", {})))


def fit_ood(feats: Mapping[str, np.ndarray], features: str = "all", k: int = 16, quantile: float = QUANTILE,
            seed: int = 0, fitted: dict | None = None) -> OODModel:
    """Fit on in-domain rows (``{"descriptor": (F, .), "signals": (F, .)}``, F >= 4): a random half fits
    the mean, std and directions, the other half the threshold (module docstring)."""
    X = select(feats, features)
    F = len(X)
    if F < 4:
        raise OODError(f"fitting the out-of-domain model needs at least 4 in-domain frames, got {F}")
    perm = np.random.default_rng(seed).permutation(F)
    A, C = X[perm[: F // 2]], X[perm[F // 2:]]
    mean = A.mean(0)
    std = A.std(0)
    std = np.where(std > 1e-8 * max(float(std.max()), 1e-30), std, max(float(std.max()), 1.0))  # constant features
    Z = (A - mean) / std
    k = int(max(1, min(k, len(A) - 1, X.shape[1] - 1)))
    _, s, Vt = np.linalg.svd(Z, full_matrices=False)
    comps = Vt[:k]
    var = np.maximum(s[:k] ** 2 / max(len(A) - 1, 1), 1e-12)
    p = Z @ comps.T
    res = float(np.mean(np.maximum((Z * Z).sum(1) - (p * p).sum(1), 0.0)))
    model = OODModel(features, mean, std, comps, var, max(res, 1e-12), 1.0, quantile, dict(fitted or {}))
    thr = float(np.quantile(model.distance(C), quantile))
    return OODModel(features, mean, std, comps, var, max(res, 1e-12), thr, quantile,
                    {**(fitted or {}), "fit_frames": int(len(A)), "threshold_frames": int(len(C)), "k": k})


def ood_model_of(export: Mapping, source: str = "") -> tuple[OODModel | None, str]:
    """(model, note) from a checkpoint's export block: (None, why the score is unavailable) without
    ``export["ood"]``; ``OODError`` naming ``source`` for a malformed one."""
    block = export.get("ood") if isinstance(export, Mapping) else None
    if block is None:
        return None, f"out-of-domain score unavailable: checkpoint {source or '?'} has no export.ood; {FIT_HINT}"
    try:
        return OODModel.from_dict(block), ""
    except OODError as e:
        raise OODError(f"checkpoint {source}: {e}") from None
