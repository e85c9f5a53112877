"""Cheap image checks without decoding: JPEG/PNG signature, size from the header, end marker.

The data layer checks every camera image eagerly with ``image_header`` (a few small reads, no
decode): a missing file, a file that is not a JPEG/PNG, or one cut short (no end-of-image marker)
becomes a skip naming the file before any consumer sees it. Full decoding stays lazy
(``RadarCameraFrame.load_image``), which also raises ``DataError`` if the pixel data is corrupt.
OpenCV decodes a truncated JPEG into a grey-filled image with only a warning, so the end-marker
test here is what catches that case.
"""

from __future__ import annotations

import contextlib
import os
import struct
import sys
import tempfile
from collections.abc import Iterator
from pathlib import Path

from hybrid_calib.data.files import check_regular_file, missing_folder_words
from hybrid_calib.errors import DataError

_PNG_SIG = b"\x89PNG\r\n\x1a\n"
_JPEG_SOF = {0xC0, 0xC1, 0xC2, 0xC3, 0xC5, 0xC6, 0xC7, 0xC9, 0xCA, 0xCB, 0xCD, 0xCE, 0xCF}
_TAIL = 64  # bytes searched for the end marker (writers may pad a few bytes after it)


def image_header(path: str | Path, token: str | None = None) -> tuple[int, int]:
    """Check a JPEG or PNG file without decoding it and return its ``(width, height)`` in pixels.

    Raises ``DataError`` naming the file (and ``token``) when the file is missing, empty, not a
    JPEG/PNG, has no readable size, or lacks its end marker (truncated).
    """
    path = Path(path)
    try:
        check_regular_file(path, "camera image", token)
        size = path.stat().st_size
        with open(path, "rb") as f:
            head = f.read(8)
            channels = None
            if head[:3] == b"\xff\xd8\xff":
                wh, channels = _jpeg_size(f) or (None, None)
                end = b"\xff\xd9"
            elif head == _PNG_SIG:
                f.seek(8)
                chunk = f.read(24)
                if len(chunk) < 16 or chunk[4:8] != b"IHDR":
                    wh = None
                else:
                    wh = struct.unpack(">II", chunk[8:16])
                    channels = {0: 1, 4: 1}.get(chunk[17], 3) if len(chunk) >= 18 else None  # colour type 0, 4: grey
                end = b"IEND"
            else:
                what = "empty" if size == 0 else f"starts with bytes {head[:4].hex()}"
                raise DataError(f"camera image is not a JPEG or PNG ({what}); re-export or re-download it",
                                path=str(path), token=token)
            f.seek(max(0, size - _TAIL))
            tail = f.read(_TAIL)
    except FileNotFoundError:
        raise DataError(("camera image not found" + why) if (why := missing_folder_words(path)) else
                        "camera image not found; check the dataset root (samples/ must sit next to the version "
                        "folder)", path=str(path), token=token) from None
    except OSError as e:
        raise DataError(f"cannot read camera image: {e}", path=str(path), token=token) from None
    if wh is None or wh[0] <= 0 or wh[1] <= 0:
        raise DataError("camera image header has no valid size; the file is corrupt, re-export it",
                        path=str(path), token=token)
    if end not in tail:
        raise DataError("camera image is truncated (no end-of-image marker); the file is corrupt or partially "
                        "copied, re-download it", path=str(path), token=token)
    if channels == 1:  # probe 23: a grey image in a CAM_FRONT record was read and fed to the network silently
        raise DataError("camera image is grayscale (one channel); a nuScenes camera records colour and the network "
                        "reads colour images: this file is not the camera's frame (a converted copy?); restore the "
                        "original image", path=str(path), token=token)
    return int(wh[0]), int(wh[1])


def _jpeg_segments(f) -> Iterator[tuple[int, int]]:
    """(marker, payload length) of each JPEG marker segment from just after SOI to the first SOS / EOI, the file
    positioned at the segment's payload; it ends early at anything that is not a marker segment."""
    f.seek(2)
    while True:
        b = f.read(1)
        while b == b"\xff":  # fill bytes before a marker
            b = f.read(1)
        if not b:
            return
        marker = b[0]
        if marker in (0xD8, 0x01) or 0xD0 <= marker <= 0xD7:  # stand-alone markers
            continue
        if marker in (0xD9, 0xDA):  # end of image / start of scan
            return
        raw = f.read(2)
        if len(raw) < 2:
            return
        length = struct.unpack(">H", raw)[0]
        if length < 2:
            return
        start = f.tell()
        yield marker, length - 2
        f.seek(start + length - 2)
        if f.read(1) != b"\xff":  # the next byte must start a marker
            return
        f.seek(-1, 1)


def _jpeg_size(f) -> tuple[tuple[int, int], int] | None:
    """``((width, height), components)`` of the first SOF segment, or None."""
    for marker, _ in _jpeg_segments(f):
        if marker in _JPEG_SOF:
            seg = f.read(6)
            if len(seg) < 6:
                return None
            h, w = struct.unpack(">HH", seg[1:5])
            return (w, h), seg[5]
    return None


# the JPEG standard's luminance quantisation table (Annex K.1), which libjpeg scales by its quality setting
_STD_LUMINANCE_SUM = sum((16, 11, 10, 16, 24, 40, 51, 61, 12, 12, 14, 19, 26, 58, 60, 55, 14, 13, 16, 24, 40, 57, 69,
                          56, 14, 17, 22, 29, 51, 87, 80, 62, 18, 22, 37, 56, 68, 109, 103, 77, 24, 35, 55, 64, 81,
                          104, 113, 92, 49, 64, 78, 87, 103, 121, 120, 101, 72, 92, 95, 98, 112, 100, 103, 99))


def jpeg_quality(path: str | Path) -> float | None:
    """The quality (1-100, libjpeg's scale) a JPEG file was saved at, estimated from its luminance quantisation table
    (the mean step against the standard table's: ~95 for nuScenes' cameras, 55-95 for the simulator's randomised
    ones; a table clipped at 255 reads about 11 for any quality under ~10); None for a file that is not a JPEG or
    holds no such table. Reads the header only."""
    try:
        with open(path, "rb") as f:
            if f.read(2) != b"\xff\xd8":
                return None
            for marker, length in _jpeg_segments(f):
                if marker != 0xDB:
                    continue
                seg, pos = f.read(length), 0  # DQT: (precision << 4 | id, 64 steps of 1 or 2 bytes) ...
                while pos < len(seg):
                    wide, table = seg[pos] >> 4, seg[pos] & 15
                    n = 128 if wide else 64
                    steps = seg[pos + 1:pos + 1 + n]
                    if len(steps) < n:
                        return None
                    if table == 0:
                        total = sum(struct.unpack(">64H", steps)) if wide else sum(steps)
                        scale = 100.0 * total / _STD_LUMINANCE_SUM
                        return float(min(100.0, max(1.0, 5000.0 / scale if scale > 100 else (200.0 - scale) / 2)))
                    pos += 1 + n
            return None
    except OSError:
        return None


# What libjpeg (inside OpenCV) prints when it decodes a JPEG whose scan data is damaged: OpenCV
# still returns an image (grey-filled or garbled), so this text is the only sign.
_DECODER_COMPLAINTS = ("corrupt jpeg data", "premature end", "invalid", "bogus", "unsupported marker",
                       "huffman", "libpng error", "crc error")


def read_image(path: str | Path, flags: int):
    """The image file at ``path`` decoded by OpenCV with ``flags`` (an array, or None where it does not decode),
    read through its bytes: ``cv2.imread`` crashed the process (native code) on a path that is not valid UTF-8
    (probe 66). ``OSError`` when the file cannot be read."""
    import cv2
    import numpy as np

    data = np.fromfile(path, np.uint8)
    return cv2.imdecode(data, flags) if data.size else None


def write_image(path: str | Path, image, params: tuple = ()) -> Path:
    """``image`` encoded by OpenCV as the format of ``path``'s suffix (``params``: its encoder's, e.g. the JPEG
    quality) and written atomically through its bytes (as ``read_image`` reads: no path reaches OpenCV)."""
    import cv2

    from hybrid_calib.atomic import write_bytes_atomic

    ok, data = cv2.imencode(Path(path).suffix, image, list(params))
    if not ok:
        raise OSError(f"could not encode {path}")
    return write_bytes_atomic(Path(path), data.tobytes())


def decode_image(path: str | Path, token: str | None = None):
    """Decode a JPEG/PNG with OpenCV -> (H, W, 3) uint8 BGR, and check what the decoder reports.

    Raises ``DataError`` naming the file (and ``token``) when the file is missing, does not decode,
    or decodes with a warning from the JPEG/PNG library (corrupt scan data behind a valid header).
    The library writes those warnings to the process's stderr, so it is captured around the decode;
    anything else it wrote is passed on.
    """
    import cv2

    path = Path(path)
    try:
        check_regular_file(path, "camera image", token)
    except OSError:  # missing (or its folder unreadable)
        raise DataError("camera image not found", path=str(path), token=token) from None
    try:
        with _captured_stderr() as captured:  # the stored pixel grid, as the intrinsics and the nuScenes devkit (PIL)
            # read it: OpenCV otherwise turns an image with an EXIF orientation tag, and every frame was skipped as
            # "900x1600 but the calibration says 1600x900" while inspect read the header's 1600x900
            bgr = read_image(path, cv2.IMREAD_COLOR | cv2.IMREAD_IGNORE_ORIENTATION)
    except OSError as e:
        raise DataError(f"camera image cannot be read ({e.strerror or e}); check its permissions", path=str(path),
                        token=token) from None
    report = captured.text.strip()
    if bgr is None:
        raise DataError(f"camera image does not decode (corrupt or not a JPEG/PNG{': ' + report if report else ''}); "
                        "re-export it", path=str(path), token=token)
    if any(c in report.lower() for c in _DECODER_COMPLAINTS):
        raise DataError(f"camera image has corrupt pixel data (OpenCV reports: {report.splitlines()[0]}); the file is "
                        "damaged, re-download or re-export it", path=str(path), token=token)
    if report:
        sys.stderr.write(report + "\n")
    return bgr


class _Captured:
    text = ""


@contextlib.contextmanager
def _captured_stderr():
    """Capture what native code writes to file descriptor 2 while the block runs (``.text`` after)."""
    out = _Captured()
    sys.stderr.flush()
    try:
        fd = sys.__stderr__.fileno() if sys.__stderr__ is not None else 2
        saved = os.dup(fd)
    except (OSError, ValueError, AttributeError):  # no real stderr (embedded interpreter): decode uncaptured
        yield out
        return
    with tempfile.TemporaryFile() as tmp:
        os.dup2(tmp.fileno(), fd)
        try:
            yield out
        finally:
            os.dup2(saved, fd)
            os.close(saved)
            tmp.seek(0)
            out.text = tmp.read().decode("utf-8", errors="replace")
