"""Radar PCD and LiDAR .pcd.bin I/O: round trips, the real nuScenes files, corrupt files."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from hybrid_calib.data.pcd import (
    RADAR_DTYPE,
    empty_radar_points,
    read_lidar_bin,
    read_radar_pcd,
    write_lidar_bin,
    write_radar_pcd,
)
from hybrid_calib.errors import DataError
from tests.helpers import rng

SHARED = Path(__file__).resolve().parents[1].parent / "shared" / "data" / "nuscenes-scene-0916"
needs_scene = pytest.mark.skipif(not SHARED.is_dir(), reason=f"real nuScenes scene not found at {SHARED}")


def _random_radar(n: int, seed: int = 0) -> np.ndarray:
    g = rng(seed)
    pts = empty_radar_points(n)
    pts["x"] = g.uniform(0, 100, n)
    pts["y"] = g.uniform(-30, 30, n)
    pts["rcs"] = g.normal(5, 5, n)
    pts["vx_comp"] = g.normal(0, 3, n)
    pts["dyn_prop"] = g.integers(0, 8, n)
    pts["id"] = np.arange(n)
    pts["ambig_state"] = 3
    return pts


def test_radar_round_trip(tmp_path):
    pts = _random_radar(57)
    path = write_radar_pcd(tmp_path / "a.pcd", pts)
    back = read_radar_pcd(path)
    assert back.dtype.names == RADAR_DTYPE.names
    for name in RADAR_DTYPE.names:
        np.testing.assert_array_equal(back[name], pts[name], err_msg=name)
    assert not list(tmp_path.glob("*tmp*")), "atomic write left a temp file"
    # the layout of a real nuScenes radar file: bytes after the last point (the devkit's reader asserts at least one;
    # probe 74: a writer without them passed every test, our reader not minding)
    raw = path.read_bytes()
    body = raw.index(b"DATA binary\n") + len(b"DATA binary\n") + 57 * RADAR_DTYPE.itemsize
    assert len(raw) > body and raw[body:] == b"\0" * (len(raw) - body)


def test_radar_round_trip_empty(tmp_path):
    back = read_radar_pcd(write_radar_pcd(tmp_path / "e.pcd", empty_radar_points(0)))
    assert len(back) == 0 and back.dtype.names == RADAR_DTYPE.names


def test_write_rejects_wrong_dtype(tmp_path):
    with pytest.raises(ValueError, match="RADAR_DTYPE"):
        write_radar_pcd(tmp_path / "x.pcd", np.zeros((3, 3)))


def test_lidar_round_trip(tmp_path):
    pts = rng(1).normal(size=(100, 5)).astype(np.float32)
    pts[:, 4] = rng(2).integers(0, 32, 100)  # the ring index
    back = read_lidar_bin(write_lidar_bin(tmp_path / "l.pcd.bin", pts))
    np.testing.assert_array_equal(back, pts)


def test_a_lidar_file_of_four_values_per_point_is_named(tmp_path):
    """x, y, z, intensity (KITTI's layout) in a file whose size is a multiple of 20 bytes was read as nuScenes
    points of garbage geometry, silently (probe 15): its 5th value is no ring index."""
    p = tmp_path / "kitti.pcd.bin"
    p.write_bytes(rng(3).normal(0, 10, size=(1000, 4)).astype("<f4").tobytes())  # 16000 bytes: 800 "points"
    with pytest.raises(DataError, match="no ring index.*4 values per point"):
        read_lidar_bin(p)
    # a file of NaN (probe 42: diagnosed as KITTI's layout) is said as such
    p.write_bytes(np.full((200, 5), np.nan, "<f4").tobytes())
    with pytest.raises(DataError, match="all 200 LiDAR points have NaN/inf coordinates; the file is corrupt"):
        read_lidar_bin(p)


@needs_scene
def test_real_radar_file_reads():
    files = sorted((SHARED / "samples" / "RADAR_FRONT").glob("*.pcd"))
    assert len(files) == 41
    pts = read_radar_pcd(files[0])
    assert pts.dtype.names == RADAR_DTYPE.names
    assert 0 < len(pts) <= 125  # ARS 408 front radar: at most 125 clusters a sweep
    np.testing.assert_array_equal(pts["z"], 0.0)  # 2D radar: no elevation
    assert np.all(pts["x"] > -1) and np.all(np.abs(pts["y"]) < 260)
    assert set(np.unique(pts["invalid_state"])) <= set(range(18))


@needs_scene
def test_real_lidar_file_reads():
    path = sorted((SHARED / "samples" / "LIDAR_TOP").glob("*.pcd.bin"))[0]
    pts = read_lidar_bin(path)
    assert pts.shape[1] == 5 and len(pts) > 10000
    assert set(np.unique(pts[:, 4])) <= set(range(32))  # 32-beam ring index


def test_truncated_radar_names_file(tmp_path):
    path = write_radar_pcd(tmp_path / "t.pcd", _random_radar(40))
    raw = path.read_bytes()
    path.write_bytes(raw[:-100])
    with pytest.raises(DataError, match="truncated PCD") as e:
        read_radar_pcd(path)
    assert str(path) in str(e.value) and e.value.path == str(path)


def test_header_only_truncation(tmp_path):
    path = write_radar_pcd(tmp_path / "h.pcd", _random_radar(5))
    path.write_bytes(path.read_bytes()[:150])  # cut inside the header
    with pytest.raises(DataError, match="header") as e:
        read_radar_pcd(path)
    assert str(path) in str(e.value)


@pytest.mark.parametrize("payload", [b"", b"\x00\x01garbage" * 50, b"hello\nworld\n" * 30])
def test_garbage_radar_names_file(tmp_path, payload):
    path = tmp_path / "g.pcd"
    path.write_bytes(payload)
    with pytest.raises(DataError) as e:
        read_radar_pcd(path)
    assert str(path) in str(e.value)


def test_an_ascii_pcd_reads_as_its_binary_twin_and_a_compressed_one_says_how_to_convert(tmp_path):
    """Probe 47: an ASCII PCD (what tools write when a user re-exports or edits a sweep) was refused with no way
    forward. It reads as the binary file it was written from; a body that is not text, or is short, is named;
    binary_compressed (LZF) says how to convert it."""
    pts = _random_radar(9)
    path = write_radar_pcd(tmp_path / "b.pcd", pts)
    raw = path.read_bytes()
    head, body = raw.split(b"DATA binary\n")
    lines = [" ".join(repr(float(pts[n][i])) if pts.dtype[n].kind == "f" else str(int(pts[n][i]))
                      for n in pts.dtype.names) for i in range(len(pts))]
    (tmp_path / "a.pcd").write_bytes(head + b"DATA ascii\n" + "\n".join(lines).encode() + b"\n")
    back = read_radar_pcd(tmp_path / "a.pcd")
    assert back.dtype == pts.dtype
    for name in pts.dtype.names:
        np.testing.assert_array_equal(back[name], pts[name], err_msg=name)
    (tmp_path / "short.pcd").write_bytes(head + b"DATA ascii\n" + "\n".join(lines[:4]).encode())
    with pytest.raises(DataError, match="header says 9 points of 18 values but the ASCII body has 72"):
        read_radar_pcd(tmp_path / "short.pcd")
    (tmp_path / "x.pcd").write_bytes(raw.replace(b"DATA binary", b"DATA ascii"))  # a binary body labelled ascii
    with pytest.raises(DataError, match="not a number"):
        read_radar_pcd(tmp_path / "x.pcd")
    (tmp_path / "c.pcd").write_bytes(raw.replace(b"DATA binary", b"DATA binary_compressed"))
    with pytest.raises(DataError, match="DATA mode .*binary_compressed.*pcl_convert_pcd_ascii_binary"):
        read_radar_pcd(tmp_path / "c.pcd")


def test_missing_files_name_path(tmp_path):
    with pytest.raises(DataError, match="not found") as e:
        read_radar_pcd(tmp_path / "none.pcd")
    assert "none.pcd" in str(e.value)
    with pytest.raises(DataError, match="not found"):
        read_lidar_bin(tmp_path / "none.pcd.bin")


@pytest.mark.parametrize("n_bytes", [13 * 4, 20 * 3 + 2, 7])  # whole floats but not whole points; partial floats
def test_lidar_bad_size_names_file(tmp_path, n_bytes):
    path = tmp_path / "bad.pcd.bin"
    path.write_bytes(bytes(n_bytes))
    with pytest.raises(DataError, match="not a multiple of 20") as e:
        read_lidar_bin(path)
    assert str(path) in str(e.value) and f"{n_bytes} bytes" in str(e.value)


def test_trailing_bytes_after_body_are_ignored(tmp_path):
    # Real nuScenes radar PCDs carry ~3.7 kB after the last point (and the devkit's reader needs at
    # least one trailing byte); the reader must take exactly POINTS rows and ignore the rest.
    pts = _random_radar(9, seed=4)
    path = write_radar_pcd(tmp_path / "p.pcd", pts)
    path.write_bytes(path.read_bytes() + bytes(3728))
    np.testing.assert_array_equal(read_radar_pcd(path), pts)


@pytest.mark.parametrize("head,kind", [(b"# .PCD v0.7 - Point Cloud Data file format\nVERSION 0.7\n", "a PCD file"),
                                       (b"\xff\xd8\xff\xe0" + b"\0" * 16, "a JPEG image")])
def test_a_lidar_row_pointing_at_another_sensors_file_is_named(tmp_path, head, kind):
    """A radar .pcd of 8740 bytes (a multiple of 20) was read as 437 LiDAR points of garbage (probe 7)."""
    from hybrid_calib.data.pcd import read_lidar_bin

    p = tmp_path / "x.pcd.bin"
    p.write_bytes(head.ljust(1000, b"\0"))  # 1000 bytes: a whole number of 20-byte LiDAR points
    with pytest.raises(DataError, match=f"LiDAR file is {kind}.*points at another sensor's file"):
        read_lidar_bin(p)


def test_a_radar_file_without_the_filters_fields_names_every_one_at_once(tmp_path):
    """A PCD of x y z rcs only was refused one missing filter field per try: three reruns to find the --set line
    (probe 52). Every missing field is named, with the one --set line that disables their filters."""
    from hybrid_calib.data.filters import RadarFilterConfig
    from hybrid_calib.data.sweeps import load_filtered_sweep

    head = ("VERSION 0.7\nFIELDS x y z rcs\nSIZE 4 4 4 4\nTYPE F F F F\nCOUNT 1 1 1 1\nWIDTH 2\nHEIGHT 1\n"
            "VIEWPOINT 0 0 0 1 0 0 0\nPOINTS 2\nDATA ascii\n")
    path = tmp_path / "r.pcd"
    path.write_text(head + "10.0 1.0 0.0 5.0\n20.0 -2.0 0.0 7.0\n")
    with pytest.raises(DataError) as e:
        load_filtered_sweep(path, RadarFilterConfig(), "tok")
    said = str(e.value)
    assert "lacks fields 'invalid_state', 'dyn_prop', 'ambig_state' needed by the radar filters" in said, said
    assert "--set data.radar_filter.invalid_states=null data.radar_filter.dynprop_states=null " \
           "data.radar_filter.ambig_states=null" in said
    rows, _, n_raw, _ = load_filtered_sweep(path, RadarFilterConfig(invalid_states=None, dynprop_states=None,
                                                                    ambig_states=None), "tok")
    assert n_raw == 2 and len(rows) == 2
