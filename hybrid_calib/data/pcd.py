"""Radar PCD (nuScenes / Continental ARS 408-21, binary PCD v0.7, 18 fields) and LiDAR .pcd.bin I/O.

Every reader error is a ``DataError`` naming the file and what is wrong.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from hybrid_calib.atomic import write_bytes_atomic
from hybrid_calib.data.files import check_regular_file, missing_folder_words
from hybrid_calib.errors import DataError

# The 18 fields of a nuScenes radar PCD, in file order, with their numpy types.
RADAR_FIELDS: tuple[tuple[str, str], ...] = (
    ("x", "<f4"), ("y", "<f4"), ("z", "<f4"),
    ("dyn_prop", "i1"), ("id", "<i2"), ("rcs", "<f4"),
    ("vx", "<f4"), ("vy", "<f4"), ("vx_comp", "<f4"), ("vy_comp", "<f4"),
    ("is_quality_valid", "i1"), ("ambig_state", "i1"), ("x_rms", "i1"), ("y_rms", "i1"),
    ("invalid_state", "i1"), ("pdh0", "i1"), ("vx_rms", "i1"), ("vy_rms", "i1"),
)
RADAR_DTYPE = np.dtype(list(RADAR_FIELDS))
_TYPE_CHAR = {"f": "F", "i": "I", "u": "U"}
_TRAILING_PAD = 16  # bytes of zero padding after the body (see write_radar_pcd)


def _header_text(n_points: int) -> bytes:
    names = " ".join(n for n, _ in RADAR_FIELDS)
    sizes = " ".join(str(np.dtype(t).itemsize) for _, t in RADAR_FIELDS)
    types = " ".join(_TYPE_CHAR[np.dtype(t).kind] for _, t in RADAR_FIELDS)
    counts = " ".join("1" for _ in RADAR_FIELDS)
    return (
        "# .PCD v0.7 - Point Cloud Data file format\nVERSION 0.7\n"
        f"FIELDS {names}\nSIZE {sizes}\nTYPE {types}\nCOUNT {counts}\n"
        f"WIDTH {n_points}\nHEIGHT 1\nVIEWPOINT 0 0 0 1 0 0 0\nPOINTS {n_points}\nDATA binary\n"
    ).encode("ascii")


def write_radar_pcd(path: str | Path, points: np.ndarray) -> Path:
    """Write a structured array of dtype ``RADAR_DTYPE`` (N,) as a nuScenes radar PCD, atomically."""
    path = Path(path)
    points = np.asarray(points)
    if points.dtype != RADAR_DTYPE:
        raise ValueError(f"radar points must have dtype RADAR_DTYPE, got {points.dtype}")
    # Real nuScenes radar files carry trailing padding, and nuscenes-devkit's reader asserts at
    # least one byte after the last point: keep that layout.
    write_bytes_atomic(path, _header_text(len(points)) + points.tobytes() + b"\0" * _TRAILING_PAD)
    return path


def empty_radar_points(n: int) -> np.ndarray:
    """(n,) structured array of ``RADAR_DTYPE`` filled with zeros."""
    return np.zeros(n, dtype=RADAR_DTYPE)


def read_radar_pcd(path: str | Path) -> np.ndarray:
    """Read a binary radar PCD -> structured array (N,) with the fields named in its header.

    Raises ``DataError`` for a missing file, a malformed header, an unsupported DATA mode or a
    truncated body.
    """
    path = Path(path)
    try:
        check_regular_file(path, "radar file")
        raw = path.read_bytes()
    except FileNotFoundError:
        raise DataError(("radar file not found" + why) if (why := missing_folder_words(path)) else
                        "radar file not found; check the dataset root and version", path=str(path)) from None
    except OSError as e:
        raise DataError(f"cannot read radar file: {e}", path=str(path)) from None
    if not raw:
        raise DataError("radar file is empty (0 bytes); it was not copied or extracted completely, re-download it",
                        path=str(path))
    header: dict[str, list[str]] = {}
    pos = 0
    while True:
        end = raw.find(b"\n", pos)
        if end < 0:
            raise DataError("truncated PCD header (no DATA line); the file is corrupt, re-download it",
                            path=str(path))
        line = raw[pos:end].decode("ascii", errors="replace").strip()
        pos = end + 1
        if not line or line.startswith("#"):
            continue
        key, *vals = line.split()
        header[key.upper()] = vals
        if key.upper() == "DATA":
            break
        if len(header) > 20:
            raise DataError("not a PCD file (no DATA line in the header)", path=str(path))
    for key in ("FIELDS", "SIZE", "TYPE", "POINTS"):
        if key not in header:
            raise DataError(f"PCD header lacks {key}; the file is corrupt", path=str(path))
    if header["DATA"] not in (["binary"], ["ascii"]):  # binary_compressed (LZF): a library this reader does not use
        raise DataError(f"unsupported PCD DATA mode {header['DATA']}; radar PCDs are read as 'binary' (as nuScenes "
                        "ships them) or 'ascii': convert the file, e.g. with PCL's "
                        "pcl_convert_pcd_ascii_binary IN OUT 1", path=str(path))
    names, sizes, types = header["FIELDS"], header["SIZE"], header["TYPE"]
    counts = header.get("COUNT", ["1"] * len(names))
    if not (len(names) == len(sizes) == len(types) == len(counts)):
        raise DataError("PCD header FIELDS/SIZE/TYPE/COUNT lengths differ; the file is corrupt", path=str(path))
    try:
        dtype = np.dtype([
            (n, f"<{ {'F': 'f', 'I': 'i', 'U': 'u'}[t] }{s}") if int(c) == 1
            else (n, f"<{ {'F': 'f', 'I': 'i', 'U': 'u'}[t] }{s}", (int(c),))
            for n, s, t, c in zip(names, sizes, types, counts)
        ])
        if len(header["POINTS"]) != 1:
            raise ValueError(f"POINTS needs one number, got {header['POINTS']}")
        n_points = int(header["POINTS"][0])
        if n_points < 0 or any(int(c) < 1 for c in counts):
            raise ValueError("POINTS must be >= 0 and every COUNT >= 1")
        if "WIDTH" in header and "HEIGHT" in header and \
                int(header["WIDTH"][0]) * int(header["HEIGHT"][0]) != n_points:  # half a sweep read silently
            raise ValueError(f"POINTS {n_points} but WIDTH x HEIGHT = {header['WIDTH'][0]} x {header['HEIGHT'][0]}; "
                             "they must agree")
    except (KeyError, ValueError, TypeError) as e:
        raise DataError(f"PCD header has an invalid field description ({e})", path=str(path)) from None
    body = raw[pos:]
    if header["DATA"] == ["ascii"]:  # what tools write when a user re-exports or edits a sweep (probe 47)
        return _ascii_points(body, dtype, n_points, path)
    need = n_points * dtype.itemsize
    if len(body) < need:
        raise DataError(
            f"truncated PCD: header says {n_points} points ({need} bytes) but the body has {len(body)} bytes; "
            "the file is corrupt or partially copied", path=str(path))
    blank = ~np.frombuffer(body[:need], np.uint8).reshape(n_points, dtype.itemsize).any(axis=1)
    if blank.any():  # every field 0, a return at the sensor itself: the zero padding real radar files end with,
        # read as points because POINTS / WIDTH were raised above the data (probe 108, LOW)
        first = int(np.argmax(blank))
        raise DataError(f"PCD header says {n_points} points but {int(blank.sum())} of them (the first at index "
                        f"{first}) are zero bytes, the file's padding rather than detections: POINTS / WIDTH were "
                        f"raised above the data; the file is corrupt, re-download it", path=str(path))
    return np.frombuffer(body[:need], dtype=dtype).copy()


def _ascii_points(body: bytes, dtype: np.dtype, n_points: int, path: Path) -> np.ndarray:
    """The points of an ASCII PCD's body (one point a line, its values in the header's field order) as ``dtype``."""
    width = sum(int(np.prod(dtype[n].shape or (1,))) for n in dtype.names)
    try:
        values = np.array(body.decode("ascii").split(), dtype=np.float64)
    except (UnicodeDecodeError, ValueError) as e:
        raise DataError(f"ASCII PCD body holds something that is not a number ({str(e)[:80]}); the file is corrupt",
                        path=str(path)) from None
    if len(values) < n_points * width:
        raise DataError(f"truncated PCD: header says {n_points} points of {width} values but the ASCII body has "
                        f"{len(values)} values; the file is corrupt or partially copied", path=str(path))
    rows = values[: n_points * width].reshape(n_points, width)
    out = np.zeros(n_points, dtype=dtype)
    col = 0
    for name in dtype.names:
        k = int(np.prod(dtype[name].shape or (1,)))
        with np.errstate(invalid="ignore"):
            out[name] = rows[:, col:col + k].reshape(out[name].shape)
        col += k
    return out


# the first bytes of files a LiDAR row must not point at: a radar PCD (text header), an image
_OTHER_FILES = ((b"# .PCD", "a PCD file with a text header (a radar's)"), (b"VERSION", "a PCD file (a radar's)"),
                (b"\xff\xd8\xff", "a JPEG image"), (b"\x89PNG", "a PNG image"))


def read_lidar_bin(path: str | Path, n_fields: int = 5) -> np.ndarray:
    """nuScenes LIDAR_TOP ``.pcd.bin`` (float32 x 5: x, y, z, intensity, ring) -> (N, 5) float32."""
    path = Path(path)
    try:
        check_regular_file(path, "LiDAR file")
        data = path.read_bytes()
    except FileNotFoundError:
        raise DataError("LiDAR file not found; the LiDAR is read for lidar-densified depth (the depth the shipped "
                        "checkpoints were trained with, chosen by default) and the hybrid's LiDAR alignment: restore "
                        "the LiDAR folder of samples/ next to the version folder, or read the root without it: "
                        "another --depth for calibrate, train and evaluate (corrupted-truth on a simulated root, "
                        "depth-anything:/local/model/dir on any), --set load_lidar=false for inspect",
                        path=str(path)) from None
    except OSError as e:
        raise DataError(f"cannot read LiDAR file: {e}", path=str(path)) from None
    if not data:  # a real sweep always has points (the ground, the car's own body): a failed copy
        raise DataError("LiDAR file is empty (0 bytes); it was not copied or extracted completely, re-download it",
                        path=str(path))
    kind = next((k for magic, k in _OTHER_FILES if data.startswith(magic)), "")
    if kind:  # a row pointed at another sensor's file: decoded as floats it was silently a cloud of garbage
        raise DataError(f"LiDAR file is {kind}, not a LiDAR .pcd.bin (raw float32 points): the sample_data row points "
                        "at another sensor's file; fix its filename in sample_data.json", path=str(path))
    point_bytes = 4 * n_fields
    if len(data) % point_bytes:
        raise DataError(f"LiDAR file size {len(data)} bytes is not a multiple of {point_bytes} ({n_fields} float32 "
                        "values per point); the file is truncated or corrupt, re-download it", path=str(path))
    points = np.frombuffer(data, dtype="<f4").reshape(-1, n_fields).copy()
    if len(points) and not np.isfinite(points[:, :3]).any():  # said as such, not as another layout (probe 42)
        raise DataError(f"all {len(points)} LiDAR points have NaN/inf coordinates; the file is corrupt, re-download it",
                        path=str(path))
    if n_fields == 5 and len(points):
        ring = points[:, 4]
        with np.errstate(invalid="ignore"):
            bad = ~(np.isfinite(ring) & (ring == np.round(ring)) & (ring >= 0) & (ring <= MAX_RING))
        if np.mean(bad) > 0.01:  # a 4-float file (x, y, z, intensity: KITTI) whose size is a multiple of 20 bytes
            raise DataError(f"LiDAR file does not hold nuScenes points (x, y, z, intensity, ring as float32): the 5th "
                            f"value of {np.mean(bad):.0%} of its points is no ring index (an integer 0..{MAX_RING}; "
                            "e.g. a file of 4 values per point, as KITTI writes); convert it to nuScenes' layout",
                            path=str(path))
    return points


MAX_RING = 1023  # the largest laser index a LiDAR's ring column holds (nuScenes' LIDAR_TOP: 0..31)


def write_lidar_bin(path: str | Path, points: np.ndarray) -> Path:
    """(N, 5) float -> nuScenes ``.pcd.bin`` (float32), atomically."""
    path = Path(path)
    points = np.asarray(points, dtype=np.float32)
    if points.ndim != 2 or points.shape[1] != 5:
        raise ValueError(f"LiDAR points must be (N, 5) [x, y, z, intensity, ring], got {points.shape}")
    write_bytes_atomic(path, points.tobytes())
    return path
