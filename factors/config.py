"""Configuration of the radar-to-pixel factor (shared by the GTSAM and Ceres back ends)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

ELEVATION_MODELS = ("zero", "mean_arc", "anisotropic", "height")
KERNELS = ("none", "huber", "cauchy", "tukey", "geman_mcclure")


@dataclass(frozen=True)
class RadarPixelFactorConfig:
    """How a radar point (recorded with z = 0) is compared with its pixel.

    Elevation models (see docs/benchmarks.md, "Elevation model study"):
    - ``zero``: the recorded point itself (elevation 0), isotropic pixel noise (the naive baseline).
    - ``mean_arc``: the mean of the reflector's elevation arc (cos-foreshortened), isotropic noise.
    - ``anisotropic``: a nuisance elevation per correspondence with a Gaussian prior matching the
      beam, eliminated in closed form after linearising the arc: the mean-arc point with pixel
      covariance ``sigma_px^2 I + sigma_elev^2 j j^T`` (``j``: image of the arc's tangent).
    - ``height``: like ``anisotropic``, but the prior is on the reflector's HEIGHT above the radar
      plane, ``h ~ N(mu_h, sigma_h^2)`` truncated to the beam, so the elevation prior depends on the
      row's range ``r``: mean ``asin(E[h] / r)``, std ``min(std(h) / (r cos phi), beam / sqrt(3))``.
      A common offset of all heights is a radar translation along its own z, a tilt of the plane
      they are measured from (about) a rotation about radar y; the data cannot see either, so the
      calibrator adds ``reflector_height_mean_std_m`` and ``reflector_tilt_std_deg`` to those
      directions' covariance (``hybrid_calib.calib.covariance.prior_pinned_std``).

    Scene nuisance (``factors.scene``, issue 10): the heights of one drive's reflectors are not the
    fixed distribution above (ground near, kerbs, vehicles, facades far, more on one side of the
    road). Three per-drive deviations, each a Gaussian nuisance with the std below (0 = off), held at
    their prior mean (0) by the estimate and added to its covariance ("consider" covariance,
    ``hybrid_calib.calib.covariance.marginalise_scene_nuisance``): a height-profile offset per range
    knot ``scene_height_std_m``; a left/right height slope ``scene_lateral_slope_std``; and an offset
    of the mean squared height per range knot ``scene_height_sq_std_m2``, which moves the expected
    point radially by ``-delta / (2 r)`` (the foreshortening ``r - sqrt(r^2 - h^2)`` of tall or low
    reflectors, centimetres at 10 m: it looks like a forward translation).
    """

    # none | huber | cauchy | tukey | geman_mcclure (per correspondence row); none and huber only for rows without gross
    # outliers (their cost can be lowest at a collapsed pose: calib.schedule's module doc)
    kernel: str = "cauchy"
    kernel_scale: float = 2.5  # kernel threshold in whitened units (multiples of the row's sigma)
    elevation_model: str = "height"  # zero | mean_arc | anisotropic | height (chosen by the elevation study)
    elevation_beam_deg: float = 7.0  # half-width of the vertical beam (ARS 408-like far range: +-7 deg)
    elevation_mean_deg: float = 0.0  # centre of the elevation distribution of reflectors, degrees
    reflector_height_mean_m: float = 0.5  # "height": mean reflector height above the radar plane, m (sim ML fit)
    reflector_height_std_m: float = 2.0  # "height": reflector height std before truncation to the beam, m (sim ML fit)
    reflector_height_mean_std_m: float = 0.3  # "height": uncertainty of the mean height = radar-z translation std, m
    reflector_tilt_std_deg: float = 1.0  # "height": tilt of the height reference plane ~ radar pitch std, degrees
    # "height": the normal of the plane the heights are measured from (the road's), in the radar frame (normalised);
    # None: the radar's own plane (0, 0, 1). calibrate sets it per vehicle from its reference radar mount (the
    # tables' or an export's; not for the oracle's model draw), so a radar mounted off level is not taken for level
    height_plane_normal: tuple[float, float, float] | None = None
    scene_knots_m: tuple[float, ...] = (0.0, 10.0, 20.0, 35.0, 60.0, 100.0)  # range knots of the scene profiles, m
    scene_height_std_m: float = 0.25  # per-knot std of the drive's mean-height offset, m (0 = off)
    scene_height_sq_std_m2: float = 0.35  # per-knot std of the drive's mean-squared-height offset, m^2 (0 = off)
    scene_lateral_slope_std: float = 0.005  # std of the drive's left/right height slope dh/dy, m per m (0 = off)
    # a short stretch of road sees one roadside: the slope of n keyframes' rows has the variance
    # scene_lateral_slope_std^2 + scene_lateral_slope_frame_std^2 / n (calib.covariance.scene_config_for; fitted on
    # validation drives: docs/benchmarks.md); widens a slope that is on (scene_lateral_slope_std > 0), 0 = not
    scene_lateral_slope_frame_std: float = 0.0
    # the three scene stds x this when the rows lie along the road (calib.degeneracy.along_road): a
    # straight road shows the same roadside all drive long, its height profile does not average out
    # (chosen on 5 straight drives, validated on 5 others: docs/benchmarks.md)
    scene_along_road_factor: float = 2.5
    min_depth_m: float = 0.1  # points closer than this to the camera plane get a large constant residual

    def __post_init__(self):
        from hybrid_calib.config import check_fields

        check_fields(self)  # the types first: kernel_scale="2" was a bare TypeError below (probe 51)
        if self.kernel not in KERNELS:
            raise ValueError(f"RadarPixelFactorConfig.kernel={self.kernel!r}; valid: {KERNELS}")
        if self.elevation_model not in ELEVATION_MODELS:
            raise ValueError(
                f"RadarPixelFactorConfig.elevation_model={self.elevation_model!r}; valid: {ELEVATION_MODELS}")
        if not self.kernel_scale > 0:
            raise ValueError(f"RadarPixelFactorConfig.kernel_scale must be > 0, got {self.kernel_scale}")
        if not (self.reflector_height_std_m > 0 and self.reflector_height_mean_std_m >= 0
                and self.reflector_tilt_std_deg >= 0):
            raise ValueError(f"RadarPixelFactorConfig: reflector_height_std_m must be > 0, reflector_height_mean_std_m "
                             f"and reflector_tilt_std_deg >= 0; got {self.reflector_height_std_m}, "
                             f"{self.reflector_height_mean_std_m}, {self.reflector_tilt_std_deg}")
        n = self.height_plane_normal
        if n is not None:
            v = np.asarray(n, np.float64)
            norm = float(np.linalg.norm(v)) if v.shape == (3,) and np.all(np.isfinite(v)) else 0.0
            if not (norm > 0 and v[2] >= 0.5 * norm):
                raise ValueError(f"RadarPixelFactorConfig.height_plane_normal must be 3 finite numbers, a direction "
                                 f"within 60 deg of the radar's z axis (the road's normal in the radar frame, e.g. "
                                 f"[0, 0, 1]; it is normalised), got {n}")
            object.__setattr__(self, "height_plane_normal", tuple(float(x) for x in v / norm))
        knots = self.scene_knots_m
        if len(knots) < 2 or any(not b > a for a, b in zip(knots, knots[1:])) or knots[0] < 0:
            raise ValueError(f"RadarPixelFactorConfig.scene_knots_m must be >= 2 increasing ranges >= 0 (m), "
                             f"got {knots}")
        if not self.scene_along_road_factor >= 1:
            raise ValueError(f"RadarPixelFactorConfig.scene_along_road_factor must be >= 1, got "
                             f"{self.scene_along_road_factor}")
        if min(self.scene_height_std_m, self.scene_height_sq_std_m2, self.scene_lateral_slope_std,
               self.scene_lateral_slope_frame_std) < 0:
            raise ValueError("RadarPixelFactorConfig: scene_height_std_m, scene_height_sq_std_m2, "
                             "scene_lateral_slope_std and scene_lateral_slope_frame_std must be >= 0 (0 = off)")
        if not 0 <= self.elevation_beam_deg < 45:
            raise ValueError(
                f"RadarPixelFactorConfig.elevation_beam_deg must be in [0, 45), got {self.elevation_beam_deg}")
        from hybrid_calib.config import require_ranges

        require_ranges(self, {"kernel_scale": "(0, 100]", "elevation_mean_deg": "[-45, 45]",
                              "reflector_height_mean_m": "[-10, 10]", "reflector_height_std_m": "[0.05, 20]",
                              "reflector_height_mean_std_m": "[0, 10]", "reflector_tilt_std_deg": "[0, 45]",
                              "scene_knots_m": "[0, 1000]", "scene_height_std_m": "[0, 10]",
                              "scene_height_sq_std_m2": "[0, 100]", "scene_lateral_slope_std": "[0, 1]",
                              "scene_lateral_slope_frame_std": "[0, 1]",
                              "scene_along_road_factor": "[1, 100]", "min_depth_m": "(0, 100]"})

