"""The measurement file: one ``.npz`` per frame, the only on-disk format of correspondences.

Written by every exporter (``learned.evaluate``: ``OUT/frames/<token>.npz``; tests and tools through
``save_measurements``), read by ``hybrid-calib calibrate --correspondences DIR`` (``load_measurement_dir``).
Frames: docs/conventions.md ("Measurement file").

Keys of schema version 1 (``SCHEMA_VERSION``); arrays are float64 unless said otherwise:

=================== =========== ==========================================================================
key                 shape       meaning
=================== =========== ==========================================================================
schema_version      () int64    1
points_radar        (N, 3)      metres, radar frame, as recorded at ``timestamp_radar_us`` (z = 0 for a 2D
                                radar); the reader moves them to the camera's timestamp (below)
pixels              (N, 2)      pixels (u = column, v = row) of the image described by ``K``
sigma_px            (N,)        pixels, isotropic 1-sigma noise of each row (> 0)
confidence          (N,)        [0, 1], multiplies each row's information
K                   (3, 3)      intrinsics of the image the pixels live in (e.g. the network's input)
frame_id            () str      frame token (the camera sample_data token for nuScenes data)
timestamp_us        () int64    camera timestamp, microseconds (0 = unknown)
timestamp_radar_us  () int64    radar timestamp, microseconds (0 = unknown)
vehicle             () str      vehicle (log) the frame belongs to ("" = unknown); groups frames
=================== =========== ==========================================================================

Optional: ``ego_motion_compensated`` () bool, default false. Radar and camera are not simultaneous (nuScenes:
0-70 ms apart, up to 0.5 m of travel), so ``calibrate --correspondences`` moves each frame's points through the
ego motion between its two timestamps, ``N`` of docs/conventions.md ("Transforms"), from the root's ego poses,
and the network block's transforms by ``N^-1``, so one mount explains every frame. True: the producer did that
itself (``points_radar`` are ``N p`` and ``T_cam_radar`` estimates the mount): read as they are. Probe 85:
points as recorded, read as if moved, put a mount 18 cm off at a 2.3 cm std (4 m/s; 31-41 cm at 9 m/s).

Optional network block (a learned producer's own per-frame estimate); present when ``T_cam_radar`` is:

=================== =========== ==========================================================================
T_cam_radar         (4, 4)      the network's estimate of the frame's radar -> camera transform: of the
                                points as given (``X N`` for points as recorded, ``X`` when compensated)
cov                 (6, 6)      its covariance: right perturbation ``T Exp(xi)``, ``xi = [omega, v]``
                                (radar frame; rad^2, m^2), symmetric
iteration           () int64    0-based iteration whose assignment produced the rows (-1 = unknown); the
                                rows of iteration k > 0 were measured against the estimate of k - 1,
                                so they are correlated with ``T_cam_radar``
T_start             (4, 4)      the start the network was given (the same frame as ``T_cam_radar``)
=================== =========== ==========================================================================

Other keys are allowed (a producer's extras, e.g. ``learned.evaluate``'s ``T_gt``, ``T_iters``) and
ignored by the reader. A bad file raises ``DataError`` naming the file, the key and what is wrong.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from factors.correspondences import Correspondences
from hybrid_calib.atomic import atomic_path, finished
from hybrid_calib.data.files import read_npz
from hybrid_calib.errors import DataError

SCHEMA_VERSION = 1
ROW_KEYS = ("points_radar", "pixels", "sigma_px", "confidence")
FRAME_KEYS = ("schema_version", *ROW_KEYS, "K", "frame_id", "timestamp_us", "timestamp_radar_us", "vehicle")
NETWORK_KEYS = ("T_cam_radar", "cov", "iteration", "T_start")
COMPENSATED_KEY = "ego_motion_compensated"  # optional (module doc)
KEYS = FRAME_KEYS + NETWORK_KEYS + (COMPENSATED_KEY,)
FRAMES_SUBDIR = "frames"  # ``hybrid-calib evaluate --out E`` writes E/frames/*.npz


@dataclass(frozen=True)
class NetworkEstimate:
    """A producer's own per-frame estimate (see the module table).

    T_cam_radar: (4, 4). cov: (6, 6) right tangent, radar frame, [rad, m] or None. iteration: int
    (-1 unknown). T_start: (4, 4) or None.
    """

    T_cam_radar: np.ndarray
    cov: np.ndarray | None = None
    iteration: int = -1
    T_start: np.ndarray | None = None


@dataclass(frozen=True)
class FrameMeasurements:
    """One frame of the measurement file: its correspondence rows plus frame metadata and,
    optionally, the network's SE(3) estimate (``network``)."""

    corr: Correspondences
    vehicle: str = ""
    timestamp_radar_us: int = 0
    network: NetworkEstimate | None = None
    compensated: bool = False  # points already moved to the camera's timestamp (module doc)

    @property
    def frame_id(self) -> str:
        return self.corr.frame_id

    @property
    def timestamp_us(self) -> int:
        return self.corr.timestamp_us


def to_arrays(m: FrameMeasurements) -> dict[str, np.ndarray]:
    """The file's arrays (module table) of one frame."""
    c = m.corr
    d = {
        "schema_version": np.array(SCHEMA_VERSION, np.int64),
        **{k: np.array(getattr(c, k), np.float64) for k in ROW_KEYS},  # copies: the frame's own are read-only
        "K": np.array(c.K, np.float64), "frame_id": np.array(str(c.frame_id)),
        "timestamp_us": np.array(int(c.timestamp_us), np.int64),
        "timestamp_radar_us": np.array(int(m.timestamp_radar_us), np.int64), "vehicle": np.array(str(m.vehicle)),
        COMPENSATED_KEY: np.array(bool(m.compensated)),
    }
    n = m.network
    if n is not None:
        d["T_cam_radar"] = np.asarray(n.T_cam_radar, np.float64)
        d["iteration"] = np.array(int(n.iteration), np.int64)
        if n.cov is not None:
            d["cov"] = np.asarray(n.cov, np.float64)
        if n.T_start is not None:
            d["T_start"] = np.asarray(n.T_start, np.float64)
    return d


def _bad(source: str, msg: str) -> DataError:
    return DataError(f"not a measurement file (factors.io schema {SCHEMA_VERSION}): {msg}; write it with "
                     "factors.io.save_measurements (or re-run the export)", path=source or None)


MAX_ROWS = 100_000  # correspondence rows of one frame file


def _array(d: Mapping, key: str, shape: tuple, source: str) -> np.ndarray:
    """``d[key]`` as float64 with ``shape`` (-1 = any length), finite."""
    a = np.asarray(d[key])
    if a.ndim != len(shape) or any(w not in (-1, g) for g, w in zip(a.shape, shape)):
        want = "(" + ", ".join("N" if w == -1 else str(w) for w in shape) + (",)" if len(shape) == 1 else ")")
        raise _bad(source, f"key {key!r} has shape {a.shape}, expected {want}")
    try:
        a = a.astype(np.float64)
    except (TypeError, ValueError):
        raise _bad(source, f"key {key!r} has dtype {a.dtype}, expected numbers") from None
    if not np.all(np.isfinite(a)):
        raise _bad(source, f"key {key!r} has NaN/inf values")
    return a


def _integer(d: Mapping, key: str, source: str) -> int:
    """``d[key]`` as an int: a scalar integer, or a whole float (numpy stores what it is given); a string read
    "unreadable (ValueError: invalid literal for int() ...)" without the key (probe 51)."""
    a = np.asarray(d[key])
    v = a.item() if a.shape == () else None
    if isinstance(v, bool) or not isinstance(v, (int, float)) or not np.isfinite(v) or v != int(v):
        raise _bad(source, f"key {key!r} is {a!r}, expected an integer")
    return int(v)


def _transform(d: Mapping, key: str, source: str) -> np.ndarray:
    from hybrid_calib.geometry import is_rigid

    T = _array(d, key, (4, 4), source)
    if not np.allclose(T[3], [0, 0, 0, 1]):
        raise _bad(source, f"key {key!r} is not a rigid transform (last row {T[3].tolist()})")
    # float32 network outputs are orthonormal to ~1e-7; a scaled rotation was read as an exact one (probe 31)
    if not is_rigid(T, atol=1e-4):
        raise _bad(source, f"key {key!r} is not a rigid transform (its rotation block is not a rotation: "
                           f"R^T R - I up to {np.abs(T[:3, :3].T @ T[:3, :3] - np.eye(3)).max():.2g}, det "
                           f"{np.linalg.det(T[:3, :3]):.3g})")
    return T


def from_arrays(d: Mapping, source: str = "") -> FrameMeasurements:
    """One frame from the file's arrays (an open ``np.load`` or a dict); ``source`` names the file in
    errors. Raises ``DataError`` for a missing key, a wrong shape or version, NaN/inf."""
    keys = set(d.keys())
    if "schema_version" not in keys:
        raise _bad(source, "no 'schema_version' key (a file from before the format, e.g. evaluate's old "
                           "corr_* keys)")
    version = int(np.asarray(d["schema_version"]))
    if version != SCHEMA_VERSION:
        raise _bad(source, f"schema_version {version}, this reader knows {SCHEMA_VERSION}")
    missing = [k for k in FRAME_KEYS if k not in keys]
    if missing:
        raise _bad(source, f"missing key(s) {missing}")
    pts = _array(d, "points_radar", (-1, 3), source)
    n = len(pts)
    if n > MAX_ROWS:  # a radar sweep has 50-125 detections: such a file stalled the run (probe 27: 2 million rows)
        raise _bad(source, f"{n} rows, more than a frame holds (at most {MAX_ROWS})")
    rows = {"points_radar": pts}
    for key, shape in (("pixels", (n, 2)), ("sigma_px", (n,)), ("confidence", (n,))):
        rows[key] = _array(d, key, shape, source)
    if np.any(rows["sigma_px"] <= 0):
        raise _bad(source, "key 'sigma_px' has values <= 0")
    K = _array(d, "K", (3, 3), source)
    if not (K[0, 0] > 0 and K[1, 1] > 0 and np.allclose(K[2], [0.0, 0.0, 1.0])):  # a zero K passed (probe 27)
        raise _bad(source, "key 'K' is not a camera intrinsic matrix (focal lengths > 0, last row [0, 0, 1])")
    try:
        corr = Correspondences(rows["points_radar"], rows["pixels"], rows["sigma_px"], rows["confidence"],
                               K, str(d["frame_id"]), _integer(d, "timestamp_us", source))
    except ValueError as e:
        raise _bad(source, str(e)) from None
    network = None
    present = [k for k in NETWORK_KEYS if k in keys]
    if present and "T_cam_radar" not in keys:
        raise _bad(source, f"network key(s) {present} without 'T_cam_radar'")
    if "T_cam_radar" in keys:
        cov = _array(d, "cov", (6, 6), source) if "cov" in keys else None
        if cov is not None and (not np.allclose(cov, cov.T, rtol=1e-6, atol=1e-12) or np.any(np.diag(cov) < 0)):
            raise _bad(source, "key 'cov' is not symmetric with a non-negative diagonal")
        # a symmetric matrix of a negative eigenvalue was read as the network's covariance, its stds reported as
        # ordinary ones (probe 51); float32 rounding of a semidefinite one passes
        if cov is not None and (low := float(np.linalg.eigvalsh(0.5 * (cov + cov.T))[0])) < -1e-6 * max(
                float(np.abs(cov).max()), 1e-300):
            raise _bad(source, f"key 'cov' is not a covariance (an eigenvalue {low:.3g} < 0)")
        if cov is not None and not np.any(cov):
            raise _bad(source, "key 'cov' is all zeros (no network is certain); leave the key out when the covariance "
                               "is unknown")
        network = NetworkEstimate(_transform(d, "T_cam_radar", source), cov,
                                  _integer(d, "iteration", source) if "iteration" in keys else -1,
                                  _transform(d, "T_start", source) if "T_start" in keys else None)
    return FrameMeasurements(corr, str(d["vehicle"]), _integer(d, "timestamp_radar_us", source), network,
                             _flag(d, COMPENSATED_KEY, source) if COMPENSATED_KEY in keys else False)


def _flag(d: Mapping, key: str, source: str) -> bool:
    """``d[key]`` as a bool: a scalar bool, or the integer 0 / 1."""
    a = np.asarray(d[key])
    v = a.item() if a.shape == () else None
    if isinstance(v, (bool, np.bool_)) or (isinstance(v, (int, float)) and v in (0, 1)):
        return bool(v)
    raise _bad(source, f"key {key!r} is {a!r}, expected true or false")


def at_camera_time(m: FrameMeasurements, N: np.ndarray) -> FrameMeasurements:
    """``m`` with its points moved to the camera's timestamp (``N p``; ``N`` (4, 4) the radar's motion between the
    two timestamps, docs/conventions.md) and its network block of the mount (``T N^-1``; the right-perturbation
    covariance by ``Ad_N``: ``T Exp(xi) N^-1 = T N^-1 Exp(Ad_N xi)``); ``m`` itself when already compensated."""
    import dataclasses

    from hybrid_calib.geometry import without_motion

    if m.compensated:
        return m
    net = m.network
    if net is not None:
        T, cov = without_motion(net.T_cam_radar, N, net.cov)
        net = NetworkEstimate(T, cov, net.iteration, None if net.T_start is None else without_motion(net.T_start, N)[0])
    return dataclasses.replace(m, corr=m.corr.moved(N), network=net, compensated=True)


def save_measurements(path: str | Path, m: FrameMeasurements, extra: Mapping[str, np.ndarray] | None = None) -> Path:
    """Write one frame atomically (temp file + rename). ``extra``: a producer's own arrays, stored
    beside the format's keys (their names must not be format keys)."""
    path = Path(path)
    extra = dict(extra or {})
    clash = sorted(set(extra) & set(KEYS))
    if clash:
        raise ValueError(f"save_measurements: extra keys {clash} are format keys; pass them through the frame")
    with atomic_path(path) as tmp:
        np.savez(tmp, **extra, **to_arrays(m))
    return path


def load_measurements(path: str | Path) -> FrameMeasurements:
    """One frame file; ``DataError`` naming it when it is unreadable or not in the format."""
    with read_npz(path, "measurement file", "re-run the export, or move it out of the directory") as z:
        return from_arrays(z, str(path))


def measurement_files(directory: str | Path) -> dict[str, list[Path]]:
    """The frame files of a directory, by sub-directory name ("" for files directly in it).

    Layouts, tried in order: ``DIR/frames/*.npz`` (``hybrid-calib evaluate --out DIR``), ``DIR/*.npz``
    (flat), ``DIR/<name>/*.npz`` (one sub-directory per vehicle)."""
    d = Path(directory)
    if not d.is_dir():
        raise DataError("measurement directory not found (expected *.npz frame files, an evaluate output with "
                        "frames/, or one sub-directory of *.npz per vehicle)", path=str(d))
    # a killed writer's temporary files are no frames (probe 90: one was read as a frame of its own)
    if files := finished(sorted((d / FRAMES_SUBDIR).glob("*.npz"))):
        return {"": files}
    if files := finished(sorted(d.glob("*.npz"))):
        return {"": files}
    groups = {s.name: finished(sorted(s.glob("*.npz"))) for s in sorted(d.iterdir()) if s.is_dir()}
    groups = {k: v for k, v in groups.items() if v}
    if not groups:
        raise DataError("no *.npz measurement files (factors.io) in the directory, its frames/ or its "
                        "sub-directories", path=str(d))
    return groups


def measurement_stamp(directory: str | Path) -> str:
    """A digest of the frame files a calibration reads from ``directory`` (``measurement_files``: their paths relative
    to it and their contents): the rows re-exported in place, or another folder typed under the same relative name,
    are other rows (probe 119: a result of the earlier rows was reused as this run's). Contents, not modification
    times: a copied folder holds the same rows. "" when the directory holds none (its reader says why)."""
    import hashlib

    try:
        groups = measurement_files(directory)
    except DataError:
        return ""
    h = hashlib.sha1()
    for files in groups.values():
        for f in files:
            h.update(str(Path(f).relative_to(directory)).encode() + b"\0")
            try:
                h.update(Path(f).read_bytes())
            except OSError:
                h.update(b"unreadable")
    return h.hexdigest()


def load_measurement_dir(directory: str | Path, skipped: list | None = None) -> dict[str, list[FrameMeasurements]]:
    """Every frame under ``directory`` (``measurement_files``), grouped by the file's ``vehicle``
    (a file without one takes its sub-directory's name, "" when flat); each group sorted by camera
    timestamp, then frame id. A bad file raises its ``DataError``, or, when ``skipped`` is a list, is
    appended to it as ``(sub-directory name, path, DataError)`` and left out."""
    out: dict[str, list[FrameMeasurements]] = {}
    seen: dict[tuple, Path] = {}  # (vehicle, frame id) -> its first file: a copy would be fused twice (probe 27)
    for sub, files in measurement_files(directory).items():
        for f in files:
            try:
                m = load_measurements(f)
                if (key := (m.vehicle or sub, m.frame_id)) in seen:
                    raise DataError(f"frame {m.frame_id!r} of vehicle {key[0]!r} is also in {seen[key]}: one frame's "
                                    "rows fused twice would count its information twice; used once, remove the copy",
                                    path=str(f))
                seen[key] = f
            except DataError as e:
                if skipped is None:
                    raise
                skipped.append((_vehicle_of(f) or sub, f, e))
                continue
            out.setdefault(m.vehicle or sub, []).append(m)
    for frames in out.values():
        frames.sort(key=lambda m: (m.timestamp_us, m.frame_id))
    return dict(sorted(out.items()))


def _vehicle_of(path: Path) -> str:
    """The ``vehicle`` a frame file that failed its checks still names ("" when even that does not read): its skip is
    then the vehicle's alone, not listed under every vehicle of a flat directory (probe 27)."""
    try:
        with np.load(path, allow_pickle=False) as z:
            v = z["vehicle"] if "vehicle" in z.files else None
            return str(v) if v is not None and v.ndim == 0 and v.dtype.kind == "U" else ""
    except Exception:  # noqa: BLE001 (a damaged file: any reader error means "does not say")
        return ""


def load_correspondence_dir(directory: str | Path) -> list[Correspondences]:
    """The correspondences of every frame under ``directory``, all vehicles together, sorted by
    camera timestamp then frame id."""
    frames = [m for group in load_measurement_dir(directory).values() for m in group]
    return [m.corr for m in sorted(frames, key=lambda m: (m.timestamp_us, m.frame_id))]
