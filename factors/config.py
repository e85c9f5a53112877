"""Configuration of the radar-to-pixel factor (shared by the GTSAM and Ceres back ends)."""

from __future__ import annotations

from dataclasses import dataclass

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
    """

    kernel: str = "cauchy"  # none | huber | cauchy | tukey | geman_mcclure (per correspondence row)
    kernel_scale: float = 2.5  # kernel threshold in whitened units (multiples of the row's sigma)
    elevation_model: str = "height"  # zero | mean_arc | anisotropic | height (chosen by the elevation study)
    elevation_beam_deg: float = 7.0  # half-width of the vertical beam (ARS 408-like far range: +-7 deg)
    elevation_mean_deg: float = 0.0  # centre of the elevation distribution of reflectors, degrees
    reflector_height_mean_m: float = 0.5  # "height": mean reflector height above the radar plane, m (sim ML fit)
    reflector_height_std_m: float = 2.0  # "height": reflector height std before truncation to the beam, m (sim ML fit)
    reflector_height_mean_std_m: float = 0.3  # "height": uncertainty of the mean height = radar-z translation std, m
    reflector_tilt_std_deg: float = 1.0  # "height": tilt of the height reference plane ~ radar pitch std, degrees
    min_depth_m: float = 0.1  # points closer than this to the camera plane get a large constant residual

    def __post_init__(self):
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
        if not 0 <= self.elevation_beam_deg < 45:
            raise ValueError(
                f"RadarPixelFactorConfig.elevation_beam_deg must be in [0, 45), got {self.elevation_beam_deg}")

