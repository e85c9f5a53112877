"""Two-view visual odometry: the camera's rotation and direction of travel between two images.

SIFT features (OpenCV), Lowe's ratio test, the essential matrix by RANSAC and ``recoverPose``
(cheirality). Returns the motion of camera b in the frame of camera a: rotation ``R_ab`` (3, 3)
(``x_a = R_ab x_b + c``) and the unit direction ``c`` (3,) of camera b's centre in camera a's
frame; the scale is not observable from two views. Images wider than ``max_width`` are
downscaled first (the intrinsics with them). Lens distortion is undone on the matched points
when the camera has one.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from hybrid_calib.sensors.camera import PinholeCamera


@dataclass(frozen=True)
class VisualOdometryConfig:
    max_width: int = 960  # images are downscaled to at most this width (pixels) before matching
    features: int = 4000  # SIFT features per image
    ratio: float = 0.8  # Lowe's ratio test
    # essential-matrix RANSAC threshold, pixels of the (downscaled) image. At most 5 px: the VO's std (the hybrid's
    # motion model, docs/benchmarks.md "The visual odometry's std by its inlier count") is fitted at 1 px, and a
    # threshold wider than the matches' spread keeps every match as an inlier (probe 79: 20 px left a 40-frame drive
    # 5.9 deg off in yaw at 0.49 deg 1-sigma, "recalibrate" on an untouched radar; 5 px: 0.06 deg)
    ransac_px: float = 1.0
    ransac_confidence: float = 0.9999
    min_inliers: int = 10  # fewer inliers: no motion
    min_parallax_px: float = 2.0  # median flow of the inliers after removing the rotation; below: no translation
    # a homography explaining this fraction of the essential matrix's inliers means a planar scene or
    # too little parallax: the motion is not unique (rotation and translation trade off), no motion
    max_homography_ratio: float = 0.8

    def __post_init__(self):
        from hybrid_calib.config import require_ranges

        require_ranges(self, {"max_width": "[32, 100000]", "features": "[8, 1e6]", "ratio": "(0, 1]",
                              "ransac_px": "(0, 5]", "ransac_confidence": "(0, 1)", "min_inliers": "[5, 1e6]",
                              "min_parallax_px": "[0, 10000]", "max_homography_ratio": "(0, 1]"})


@dataclass(frozen=True)
class CameraMotion:
    """R_ab: (3, 3) rotation of camera b in camera a. c: (3,) unit direction of b's centre in a's
    frame. n_inliers: essential-matrix inliers. parallax_px: their median translational flow."""

    R_ab: np.ndarray
    c: np.ndarray
    n_inliers: int
    parallax_px: float


def _gray(img: np.ndarray, scale: float) -> np.ndarray:
    import cv2

    g = cv2.cvtColor(img, cv2.COLOR_RGB2GRAY) if img.ndim == 3 else img
    if scale != 1.0:
        g = cv2.resize(g, None, fx=scale, fy=scale, interpolation=cv2.INTER_AREA)
    return g


def match_features(img_a: np.ndarray, img_b: np.ndarray, camera: PinholeCamera,
                   conf: VisualOdometryConfig = VisualOdometryConfig()) -> tuple[tuple | None, str]:
    """((pa (M, 2), pb (M, 2), K (3, 3)), "") or (None, why not): SIFT matches passing the ratio test,
    undistorted, in the pixels of the images downscaled to ``conf.max_width`` (K scaled with them)."""
    import cv2

    if img_a.shape[:2] != img_b.shape[:2]:
        return None, f"the two images differ in size ({img_a.shape[:2]} vs {img_b.shape[:2]})"
    scale = min(1.0, conf.max_width / img_a.shape[1])
    K = camera.K.copy()
    K[:2] *= scale
    sift = cv2.SIFT_create(conf.features)
    ka, da = sift.detectAndCompute(_gray(img_a, scale), None)
    kb, db = sift.detectAndCompute(_gray(img_b, scale), None)
    if da is None or db is None or len(ka) < conf.min_inliers or len(kb) < conf.min_inliers:
        return None, "too few image features (a blank, dark or blurred image?)"
    pairs = cv2.BFMatcher(cv2.NORM_L2).knnMatch(da, db, k=2)
    good = [m[0] for m in pairs if len(m) == 2 and m[0].distance < conf.ratio * m[1].distance]
    if len(good) < conf.min_inliers:
        return None, f"{len(good)} feature matches between the frames (need {conf.min_inliers})"
    pa = np.float64([ka[m.queryIdx].pt for m in good])
    pb = np.float64([kb[m.trainIdx].pt for m in good])
    if any(camera.dist):
        d = np.asarray(camera.dist, np.float64)
        pa = cv2.undistortPoints(pa[:, None], K, d, P=K)[:, 0]
        pb = cv2.undistortPoints(pb[:, None], K, d, P=K)[:, 0]
    return (pa, pb, K), ""


def _parallax(pa: np.ndarray, pb: np.ndarray, K: np.ndarray, R: np.ndarray) -> float:
    """Median flow (px) left after rotating a's rays into b by R (x_b = R x_a + t)."""
    rb = K @ (R @ (np.linalg.inv(K) @ np.c_[pa, np.ones(len(pa))].T))
    return float(np.median(np.linalg.norm(pb - (rb[:2] / rb[2]).T, axis=1)))


def camera_motion(img_a: np.ndarray, img_b: np.ndarray, camera: PinholeCamera,
                  conf: VisualOdometryConfig = VisualOdometryConfig()) -> tuple[CameraMotion | None, str]:
    """(motion of camera b in camera a, "") or (None, why not) by the five-point essential matrix.
    img_*: (H, W[, 3]) uint8 RGB."""
    m, why = match_features(img_a, img_b, camera, conf)
    return (None, why) if m is None else motion_from_matches(*m, conf)


def motion_from_matches(pa: np.ndarray, pb: np.ndarray, K: np.ndarray,
                        conf: VisualOdometryConfig = VisualOdometryConfig()) -> tuple[CameraMotion | None, str]:
    """The five-point essential matrix on matches (``match_features``)."""
    import cv2

    E, mask = cv2.findEssentialMat(pa, pb, K, cv2.RANSAC, conf.ransac_confidence, conf.ransac_px)
    if E is None or E.shape != (3, 3):
        return None, "no essential matrix (degenerate matches)"
    n_e = int((mask.ravel() > 0).sum())
    n, R, t, mask = cv2.recoverPose(E, pa, pb, K, mask=mask)
    inl = mask.ravel() > 0
    if n < conf.min_inliers:
        return None, f"{n} matches agree on one camera motion (need {conf.min_inliers})"
    H, hmask = cv2.findHomography(pa, pb, cv2.RANSAC, conf.ransac_px)
    n_h = 0 if H is None else int(hmask.sum())
    if n_h > conf.max_homography_ratio * n_e:
        return None, (f"a homography explains {n_h} of the {n_e} matches: planar scene or pure rotation, the "
                      "direction of travel is not determined")
    parallax = _parallax(pa[inl], pb[inl], K, R)
    if parallax < conf.min_parallax_px:
        return None, f"median parallax {parallax:.1f} px (need {conf.min_parallax_px:g}): the camera hardly moved"
    c = (-R.T @ t).ravel()
    return CameraMotion(R.T, c / np.linalg.norm(c), int(n), parallax), ""


def travel_given_rotation(pa: np.ndarray, pb: np.ndarray, K: np.ndarray, R_ab: np.ndarray,
                          conf: VisualOdometryConfig = VisualOdometryConfig(), seed: int = 0
                          ) -> tuple[CameraMotion | None, str]:
    """The direction of travel when the rotation ``R_ab`` (3, 3, camera b in camera a) is known: the
    epipolar constraint ``x_b . (t x R x_a) = t . (R x_a x x_b) = 0`` is linear in t, two matches
    fix it (RANSAC on the epipolar distance in pixels, then least squares on the inliers), and
    cheirality picks its sign. Two unknowns instead of five: no rotation-translation trade-off.
    pa, pb: (M, 2) matched pixels, K: (3, 3) (``match_features``)."""
    R = R_ab.T  # x_b = R x_a + t
    Kinv = np.linalg.inv(K)
    xa = (Kinv @ np.c_[pa, np.ones(len(pa))].T).T
    xb = (Kinv @ np.c_[pb, np.ones(len(pb))].T).T
    Rxa = xa @ R.T
    A = np.cross(Rxa, xb)  # rows a_i: a_i . t = 0
    f = float(K[0, 0])

    def dist(t):
        lines = np.cross(t, Rxa)  # epipolar lines in b (normalised coordinates)
        return f * np.abs(A @ t) / np.maximum(np.linalg.norm(lines[:, :2], axis=1), 1e-12)

    rng = np.random.default_rng(seed)
    best = None
    for _ in range(300):
        i, j = rng.choice(len(A), 2, replace=False)
        t = np.cross(A[i], A[j])
        if np.linalg.norm(t) < 1e-12:
            continue
        inl = dist(t / np.linalg.norm(t)) < conf.ransac_px
        if best is None or inl.sum() > best.sum():
            best = inl
    if best is None or best.sum() < conf.min_inliers:
        return None, f"{0 if best is None else int(best.sum())} matches agree on one direction of travel " \
                     f"(need {conf.min_inliers})"
    for _ in range(2):
        t = np.linalg.svd(A[best])[2][-1]
        best = dist(t) < conf.ransac_px
    if best.sum() < conf.min_inliers:
        return None, f"{int(best.sum())} matches agree on one direction of travel (need {conf.min_inliers})"
    # cheirality: lam_a R x_a - lam_b x_b = -t, both depths positive for the right sign
    M = np.stack([Rxa[best], -xb[best]], 2)  # (n, 3, 2)
    lam = np.array([np.linalg.lstsq(Mi, -t, rcond=None)[0] for Mi in M])
    front = np.sum((lam[:, 0] > 0) & (lam[:, 1] > 0))
    if front < 0.5 * len(lam):
        t = -t
    parallax = _parallax(pa[best], pb[best], K, R)
    if parallax < conf.min_parallax_px:
        return None, f"median parallax {parallax:.1f} px (need {conf.min_parallax_px:g}): the camera hardly moved"
    c = -R.T @ t
    return CameraMotion(R_ab, c / np.linalg.norm(c), int(best.sum()), parallax), ""
