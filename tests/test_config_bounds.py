"""Every --set option has bounds (calibration, simulator, network): a value no computation can use is refused at start,
naming the option and its interval (each of these ran into an internal error or a silent no-op deep inside)."""

import pytest

from factors.config import RadarPixelFactorConfig
from hybrid_calib.calib.batch import BatchConfig
from hybrid_calib.calib.covariance import CovarianceConfig
from hybrid_calib.calib.degeneracy import DegeneracyConfig
from hybrid_calib.calib.drift import DriftConfig, StepConfig
from hybrid_calib.calib.lever_arm import LeverArmConfig
from hybrid_calib.calib.lidar_alignment import LidarAlignConfig
from hybrid_calib.calib.mount_monitor import MountMonitorConfig
from hybrid_calib.calib.oracle import OracleConfig
from hybrid_calib.calib.pipeline import CalibrateConfig
from hybrid_calib.calib.schedule import ScheduleConfig
from hybrid_calib.calib.window import WindowConfig
from hybrid_calib.config import ConfigError, merge, require_ranges
from hybrid_calib.data.filters import RadarFilterConfig
from hybrid_calib.data.nuscenes import DataConfig
from hybrid_calib.hybrid.average import AverageConfig
from hybrid_calib.hybrid.loop import HybridConfig
from hybrid_calib.hybrid.measurement import MeasurementConfig
from hybrid_calib.hybrid.motion import MotionConfig
from hybrid_calib.sensors.radar_velocity import RadarVelocityConfig
from hybrid_calib.sensors.visual_odometry import VisualOdometryConfig
from hybrid_calib.sim.drive import SimConfig
from hybrid_calib.sim.extrinsics import ExtrinsicChange, MountPerturbation
from hybrid_calib.sim.lidar import LidarConfig
from hybrid_calib.sim.radar import RadarConfig
from hybrid_calib.sim.randomise import Randomisation
from hybrid_calib.sim.render import ShadingConfig
from hybrid_calib.sim.scenarios import ScenarioConfig
from learned.config import ModelConfig
from learned.dataset import DatasetConfig, SplitConfig
from learned.depth import CorruptedTruthConfig, DepthAnythingConfig, LidarDepthConfig
from learned.evaluate import EvalConfig
from learned.export import ExportConfig
from learned.train import TrainConfig

CLASSES = [RadarPixelFactorConfig, BatchConfig, CovarianceConfig, DegeneracyConfig, DriftConfig, StepConfig,
           LeverArmConfig, LidarAlignConfig, MountMonitorConfig, OracleConfig, CalibrateConfig, ScheduleConfig,
           WindowConfig, DataConfig, AverageConfig, HybridConfig, MeasurementConfig, MotionConfig,
           RadarVelocityConfig, VisualOdometryConfig,
           # the simulator and the network
           SimConfig, LidarConfig, RadarConfig, ShadingConfig, ScenarioConfig, Randomisation, ExtrinsicChange,
           MountPerturbation, ModelConfig, DatasetConfig, SplitConfig, CorruptedTruthConfig, DepthAnythingConfig,
           LidarDepthConfig, EvalConfig, ExportConfig, TrainConfig]


@pytest.mark.parametrize("cls", CLASSES, ids=lambda c: c.__name__)
def test_defaults_are_inside_their_bounds(cls):
    merge(cls)


# (class, option, value): the fuzz of session 21 (calibrate --method oracle, 2 frames) found each accepted
BAD = [
    (RadarPixelFactorConfig, "reflector_height_std_m", 1e300),  # internal error
    (RadarPixelFactorConfig, "scene_height_std_m", 1e300),  # internal error
    (RadarPixelFactorConfig, "elevation_mean_deg", 1e300),
    (RadarPixelFactorConfig, "min_depth_m", -1),
    (ScheduleConfig, "convex_kernel", "zzz"),  # internal error
    (ScheduleConfig, "convex_scale", 0),  # internal error
    (ScheduleConfig, "max_iterations", 10**12),  # internal error (an int overflow in GTSAM)
    (ScheduleConfig, "max_iterations", 0),
    (CovarianceConfig, "rot_tol_deg", 0),  # internal error
    (CovarianceConfig, "trans_tol_cm", 1e300),  # internal error
    (CovarianceConfig, "rot_tol_deg", -1),
    (DegeneracyConfig, "along_road_lateral_m", 1e300),  # internal error
    (DegeneracyConfig, "trade_off_correlation", -1),
    (DriftConfig, "ref_rot_std_deg", 1e300),  # internal error
    (DriftConfig, "ref_trans_std_cm", 1e300),  # internal error
    (StepConfig, "p_alarm", 0),
    (DriftConfig, "alpha", 2**70),  # probe 79: numpy's isfinite on an int beyond 2**64 named no option
    (WindowConfig, "default_dt_s", 2**70),
    (StepConfig, "consecutive", -1),
    (StepConfig, "long_frames", (10, -20)),
    (WindowConfig, "window", 10**12),
    (BatchConfig, "backend", "zzz"),
    (OracleConfig, "sigma_px", 1e300),
    (OracleConfig, "kinds", (5, 3, 1)),  # probe 79: accepted, said as "no real reflector"
    (LeverArmConfig, "noise_scale", 1e300),
    (LidarAlignConfig, "beam_deg", 1e300),
    (MountMonitorConfig, "threshold", 1e300),
    (AverageConfig, "iterations", 0),
    (MeasurementConfig, "trust_sigma_frac", -1),
    (MotionConfig, "gate", 0),
    (RadarVelocityConfig, "min_inliers", -1),
    (VisualOdometryConfig, "ratio", 0),
    (VisualOdometryConfig, "ransac_px", 20),  # probe 79: 5.9 deg off in yaw at 0.49 deg 1-sigma, "recalibrate"
    (RadarPixelFactorConfig, "reflector_height_std_m", 1e-9),  # probe 79: the oracle 111 cm off at NEES 26
    (DataConfig, "nsweeps", 0),
    (RadarFilterConfig, "invalid_states", (-5,)),  # probe 79: a code the radar never writes kept nothing, in silence
    (RadarFilterConfig, "dynprop_states", (8,)),
    (HybridConfig, "threads", 10**12),
    # the simulator and the network
    (SimConfig, "radar_sweep_period_ms", 0),
    (SimConfig, "lidar_offset_ms", 1e300),
    (SimConfig, "camera_max_range_m", -1),
    (SimConfig, "frames", 10**12),
    (SimConfig, "vehicles", 10**12),
    (LidarConfig, "max_range_m", 1e300),
    (LidarConfig, "n_beams", 10**12),
    (RadarConfig, "range_noise_m", 1e300),
    (RadarConfig, "max_points", 10**12),
    (RadarConfig, "clutter_rcs_db", (2**70, 1.0)),
    (RadarConfig, "near_fov_deg", 1e300),
    (RadarConfig, "position_quantisation_m", 0),  # divides: NaN points
    (ShadingConfig, "gamma", -1),
    (ScenarioConfig, "ego_speed", -1),
    (ScenarioConfig, "pole_spacing", 1e-300),  # a pole every 1e-300 m: endless
    (Randomisation, "gamma", (-1.0, 1.0)),
    (Randomisation, "range_noise_m", (0.1, 1e300)),
    (ExtrinsicChange, "frame", -2),
    (MountPerturbation, "radar_rotation_deg", -1),
    (ModelConfig, "beta", -1),
    (ModelConfig, "nr_tau", 0),
    (ModelConfig, "feat_dim", 10**12),
    (DatasetConfig, "height", -1),
    (SplitConfig, "gap_frames", 10**12),
    (CorruptedTruthConfig, "max_depth_m", -1),
    (DepthAnythingConfig, "max_depth_m", -1),
    (LidarDepthConfig, "max_depth_m", -1),
    (EvalConfig, "threads", 0),
    (EvalConfig, "threads", -1),
    (ExportConfig, "window", -1),
    (ExportConfig, "uncertainty", "abc"),  # probe 79: an internal error at the first frame
    (SimConfig, "radar_offset_ms", (50.0, 30.0)),  # probe 79: an internal error in the draw
    (ExportConfig, "min_confidence", 1e300),
    (TrainConfig, "lr", 1e300),
    (TrainConfig, "seed", -1),  # probe 79: the --seed flags refuse it, --set took it
    (EvalConfig, "seed", -1),
    (TrainConfig, "epochs", 10**12),
    (TrainConfig, "threads", 10**12),
]


@pytest.mark.parametrize("cls,key,value", BAD, ids=[f"{c.__name__}.{k}={v}" for c, k, v in BAD])
def test_a_value_no_computation_can_use_is_refused_naming_the_option(cls, key, value):
    with pytest.raises(ConfigError, match=key):
        merge(cls, {key: value})


def test_nested_option_is_refused_with_its_path():
    with pytest.raises(ConfigError, match=r"window\.factor.*kernel_scale in \(0, 100\]"):
        merge(CalibrateConfig, {"window": {"factor": {"kernel_scale": 1e300}}})


def test_require_ranges_reads_intervals_as_written():
    from dataclasses import dataclass

    @dataclass(frozen=True)
    class _Conf:
        a: float = 1.0
        b: tuple = (1, 2)

    for a, ok in ((0.0, False), (1e-9, True), (100.0, True), (100.1, False), (float("nan"), False)):
        conf = _Conf(a=a)
        if ok:
            require_ranges(conf, {"a": "(0, 100]"})
        else:
            with pytest.raises(ValueError, match=r"need a in \(0, 100\]"):
                require_ranges(conf, {"a": "(0, 100]"})
    with pytest.raises(ValueError, match=r"b in \[1, 2\)"):
        require_ranges(_Conf(), {"b": "[1, 2)"})
    with pytest.raises(TypeError, match="not an interval"):
        require_ranges(_Conf(), {"a": "0..1"})


def test_nested_sim_option_and_the_scenario_weather_are_checked():
    with pytest.raises(ConfigError, match="radar.*range_noise_m"):
        merge(SimConfig, {"radar": {"range_noise_m": 1e300}})
    merge(SimConfig, {"scenario": "urban", "radar": {"extra_loss_db": 200}})
    with pytest.raises(ConfigError, match="rain scenario's weather.*extra_loss_db"):  # rain adds 7 dB
        merge(SimConfig, {"scenario": "rain", "radar": {"extra_loss_db": 200}})
    with pytest.raises(ConfigError, match="randomise.clutter_scale.*clutter_per_sweep"):  # 6000 x 2: a draw too many
        merge(SimConfig, {"radar": {"clutter_per_sweep": 6000}, "randomise": {"enabled": True}})


@pytest.mark.parametrize("argv", [
    ["simulate", "--workers", "999999999", "--out", "{tmp}/s"],
    ["fleet", "--data", "{tmp}", "--engine", "process", "--workers", "1000", "--out", "{tmp}/f"],
    ["fleet", "--data", "{tmp}", "--engine", "ray", "--address", "h:1", "--workers", "999999", "--out", "{tmp}/f"],
    ["fleet", "--data", "{tmp}", "--threads", "1000", "--out", "{tmp}/f"],
    ["fleet", "--data", "{tmp}", "--retries", "999999999", "--out", "{tmp}/f"],
])
def test_process_counts_are_bounded(argv, tmp_path, capsys):
    """``simulate --workers 999999999`` forked workers until the machine stopped (a process pool on Linux starts all
    of them at once; the fuzz of session 21 met it): refused by argparse (exit 2), nothing started."""
    from tests.helpers import run_cli

    rc, err = run_cli([a.format(tmp=tmp_path) for a in argv], capsys)
    assert rc == 2 and "at most" in err, err


def test_fleet_options_are_bounded():
    from hybrid_calib.fleet.driver import FleetOptions

    with pytest.raises(ValueError, match="workers in"):
        FleetOptions(engine="process", workers=10**9)
    FleetOptions(engine="ray", workers=512, address="head:6379")  # a cluster's CPUs


def test_a_learning_rate_halved_every_0_epochs_is_never_halved():
    """Probe 55: lr_halve_every=0 was accepted and halved the rate every epoch (0 is "off", as for grad_clip)."""
    import torch

    from hybrid_calib.config import merge
    from learned.train import lr_schedule

    def rates(every):
        opt = torch.optim.SGD([torch.nn.Parameter(torch.zeros(1))], lr=1.0)
        sched = lr_schedule(opt, merge(TrainConfig, {"lr_halve_every": every}))
        out = []
        for _ in range(4):
            out.append(opt.param_groups[0]["lr"])
            opt.step()
            sched.step()
        return out

    assert rates(0) == [1.0] * 4
    assert rates(1) == [1.0, 0.5, 0.25, 0.125]
    assert rates(2) == [1.0, 1.0, 0.5, 0.5]


def test_a_frozen_configs_dict_options_are_frozen_too():
    """A frozen dataclass left its dict-valued options open (``conf.data["nsweeps"] = 5`` changed a run's config after
    it was recorded). Every config with such a field holds a ``FrozenDict``, nested ones too, that reads, serialises
    and pickles (worker processes, Ray) as a dict."""
    import dataclasses
    import json
    import pickle

    from hybrid_calib.config import FrozenDict, to_dict

    cases = [(HybridConfig, {"data": {"nsweeps": 2}, "measurement": {}, "split_options": {"by": "time"}}),
             (SimConfig, {"world": {"pole_spacing": 30.0}}), (ExportConfig, {"hybrid": {}, "ood": {"a": {"b": 1}}}),
             (EvalConfig, {"depth_options": {}, "export": {}}), (TrainConfig, {"model": {"feat_dim": 16}})]
    for cls, options in cases:
        conf = merge(cls, options)
        dict_fields = [f.name for f in dataclasses.fields(conf) if isinstance(getattr(conf, f.name), dict)]
        assert dict_fields and all(type(getattr(conf, n)) is FrozenDict for n in dict_fields), (cls, dict_fields)
        for name in dict_fields:
            d = getattr(conf, name)
            for method, args in (("__setitem__", ("x", 1)), ("update", ({"x": 1},)), ("pop", ("x", None)),
                                 ("setdefault", ("x", 1)), ("clear", ())):
                with pytest.raises(TypeError, match="frozen"):
                    getattr(d, method)(*args)
        assert pickle.loads(pickle.dumps(conf)) == conf and json.loads(json.dumps(to_dict(conf))) == to_dict(conf)
    nested = merge(ExportConfig, {"ood": {"a": {"b": 1}}}).ood["a"]
    with pytest.raises(TypeError, match="frozen"):
        nested["b"] = 2
