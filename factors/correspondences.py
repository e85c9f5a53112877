"""Radar-point <-> image-pixel correspondences: what the network exports and the factors consume."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

SIGMA_PX_RANGE = (1e-12, 1e6)  # pixels: no 1-sigma outside this is a measurement (its information overflows)
POINT_RANGE_M = (0.0, 1e5)  # |coordinate|, metres: no radar detection lies 100 km away
PIXEL_RANGE = (0.0, 1e7)  # |coordinate|, pixels: no image is ten million pixels wide
FOCAL_MIN_PX = 1.0  # pixels: a focal length below one pixel images the whole world into one pixel
# one measurement, not two: radar points within REPEAT_RADAR_M (each coordinate) and pixels within REPEAT_SIGMA of
# their 1-sigma (an independent measurement of the same point lands that close to the first with a probability of
# ~1e-4 per row). Probe 51: a replay nudged by 1e-6 px, or rows doubled inside a frame, passed as new measurements
# and shrank the std; probe 59: so did a replay with one row added or taken away (rows are compared one by one:
# SeenRows).
REPEAT_RADAR_M = 1e-3
REPEAT_SIGMA = 0.01


@dataclass(frozen=True)
class Correspondences:
    """The correspondences of one frame.

    points_radar: (N, 3) float64, metres, radar frame, as recorded (z = 0 for a 2D radar: the
        true elevation of each reflector is unknown).
    pixels: (N, 2) float64, pixels (u = column, v = row) in the image described by ``K``.
    sigma_px: (N,) float64, pixels, isotropic 1-sigma noise of each pixel (e.g. 2 for a keypoint,
        ~8/sqrt(12)*... for a network cell; the producer decides).
    confidence: (N,) float64 in [0, 1]; multiplies the information of each row.
    K: (3, 3) float64 camera intrinsics of the image the pixels live in.
    frame_id: free-form identifier (sample token, index) used in logs and errors.
    timestamp_us: camera timestamp, microseconds (0 if unknown).
    """

    points_radar: np.ndarray
    pixels: np.ndarray
    sigma_px: np.ndarray
    confidence: np.ndarray
    K: np.ndarray
    frame_id: str = ""
    timestamp_us: int = 0

    def __post_init__(self):
        # the metadata as annotated: an int frame id is its str; a timestamp that is not an integer was refused only
        # one call later, naming neither the frame nor the field (probe 51: 'abc', 1.9 truncated to 1)
        if isinstance(self.frame_id, (int, np.integer)) and not isinstance(self.frame_id, bool):
            object.__setattr__(self, "frame_id", str(self.frame_id))
        if not isinstance(self.frame_id, str):
            raise ValueError(f"Correspondences.frame_id must be a str (a sample token or index), got "
                             f"{type(self.frame_id).__name__} {self.frame_id!r}")
        if isinstance(self.timestamp_us, bool) or not isinstance(self.timestamp_us, (int, np.integer)):
            raise ValueError(f"Correspondences[{self.frame_id}].timestamp_us must be an integer number of "
                             f"microseconds (0 if unknown), got {type(self.timestamp_us).__name__} "
                             f"{self.timestamp_us!r}")
        object.__setattr__(self, "timestamp_us", int(self.timestamp_us))
        for name in ("points_radar", "pixels", "sigma_px", "confidence", "K"):  # owned, float64, read-only: what
            value = getattr(self, name)  # was validated stays so (a caller's array changed after it was not)
            if np.iscomplexobj(value):  # float64 would keep the real part, with only a numpy warning
                raise ValueError(f"Correspondences[{self.frame_id}].{name}: complex numbers; give real ones")
            try:
                arr = np.array(value, dtype=np.float64)
            except (TypeError, ValueError) as e:
                raise ValueError(f"Correspondences[{self.frame_id}].{name}: not an array of numbers ({e})") from None
            arr.flags.writeable = False
            object.__setattr__(self, name, arr)
        n = len(self.points_radar)
        checks = {
            "points_radar": (np.shape(self.points_radar), (n, 3)),
            "pixels": (np.shape(self.pixels), (n, 2)),
            "sigma_px": (np.shape(self.sigma_px), (n,)),
            "confidence": (np.shape(self.confidence), (n,)),
            "K": (np.shape(self.K), (3, 3)),
        }
        for name, (got, want) in checks.items():
            if got != want:
                raise ValueError(f"Correspondences[{self.frame_id}].{name}: shape {got}, expected {want}")
        for name in ("points_radar", "pixels", "sigma_px", "confidence"):
            if not np.all(np.isfinite(getattr(self, name))):
                raise ValueError(f"Correspondences[{self.frame_id}].{name} has NaN/inf values; drop those rows")
        if np.any(np.asarray(self.sigma_px) <= 0):
            raise ValueError(f"Correspondences[{self.frame_id}].sigma_px must be > 0")
        # magnitudes no sensor gives, whose squares overflow the solver's information (probe 33: a file with sigma_px
        # 1e-300 or points at 1e300 m ended calibrate in "internal error")
        for name, (low, high), unit in (("sigma_px", SIGMA_PX_RANGE, "px"), ("points_radar", POINT_RANGE_M, "m"),
                                        ("pixels", PIXEL_RANGE, "px")):
            v = np.abs(getattr(self, name))
            if v.size and (v.max() > high or v.min() < low):
                worst = v.max() if v.max() > high else v.min()
                raise ValueError(f"Correspondences[{self.frame_id}].{name} holds |{worst:g}| {unit}, outside "
                                 f"[{low:g}, {high:g}] {unit}: no sensor gives it; check the producer's units")
        if np.any((self.confidence < 0) | (self.confidence > 1)):
            raise ValueError(f"Correspondences[{self.frame_id}].confidence must lie in [0, 1] (it multiplies each "
                             f"row's information), got {self.confidence.min():g} .. {self.confidence.max():g}")
        K = self.K
        # K[1, 0] is not read by the projection (probe 118: 300 px there was fused as if it were 0); the tables'
        # reader refuses it too
        if not (np.all(np.isfinite(K)) and K[0, 0] > 0 and K[1, 1] > 0 and np.allclose(K[2], [0, 0, 1])
                and abs(K[1, 0]) <= 1e-9 * K[1, 1]):
            raise ValueError(f"Correspondences[{self.frame_id}].K is not a pinhole camera matrix (finite, positive "
                             f"focal lengths fx = K[0, 0] and fy = K[1, 1], second row [0, fy, cy], last row "
                             f"[0, 0, 1]): {K.tolist()}")
        # a focal length of 1e200 px or a principal point at 1e300 px passed and failed inside the solver's
        # eigen-decomposition (probe 51): the camera's numbers live in the pixels' range, a focal length >= 1 px
        if np.abs(K[:2]).max() > PIXEL_RANGE[1] or min(K[0, 0], K[1, 1]) < FOCAL_MIN_PX:
            raise ValueError(f"Correspondences[{self.frame_id}].K {K.tolist()}: focal lengths must lie in "
                             f"[{FOCAL_MIN_PX:g}, {PIXEL_RANGE[1]:g}] px and every entry within {PIXEL_RANGE[1]:g} "
                             "px: no camera has it; check the producer's units")

    def __len__(self) -> int:
        return len(self.points_radar)

    def repeats(self, other: Correspondences) -> bool:
        """True when every row of these is a row of ``other`` again (a stalled or replayed feed, whole, reordered,
        nudged or cut short: ``SeenRows``). Fused as two frames, one measurement would shrink a covariance as if it
        were two independent ones."""
        if not len(self) or not len(other):
            return False
        seen = SeenRows()
        seen.add(other)
        return bool((seen.match(self) >= 0).all())

    def doubled_rows(self) -> list[tuple[int, int]]:
        """(row, earlier row it repeats) pairs inside this frame: radar points within ``REPEAT_RADAR_M`` and pixels
        within ``REPEAT_SIGMA`` of their sigma. Two such rows are one measurement counted twice."""
        if len(self) < 2:
            return []
        # each row against the earlier rows in its 27 cells of a REPEAT_RADAR_M grid (as SeenRows): copies with
        # another row sorted between them were missed by comparing neighbours in sorted order (probe 65)
        x = self.points_radar[:, 0]
        order = np.argsort(x, kind="stable")
        near = np.diff(x[order]) <= REPEAT_RADAR_M  # a copy has another row this close in x: the others are not
        candidate = np.zeros(len(self), bool)
        candidate[order[:-1][near]] = candidate[order[1:][near]] = True
        cells: dict[tuple[int, int, int], list[int]] = {}
        keys = np.floor(self.points_radar / REPEAT_RADAR_M).astype(np.int64)
        out = []
        for r in np.flatnonzero(candidate):
            key = keys[r]
            row = (self.points_radar[r], self.pixels[r], self.sigma_px[r])
            j = next((j for off in _NEIGHBOURS for j in cells.get(tuple((key + off).tolist()), ())
                      if _same_row(*row, self.points_radar[j], self.pixels[j], self.sigma_px[j])), None)
            if j is not None:
                out.append((int(r), int(j)))
            cells.setdefault(tuple(key.tolist()), []).append(r)
        return out

    def once(self, pairs: list[tuple[int, int]] | None = None) -> Correspondences:
        """These rows with each doubled row (``doubled_rows``) kept once; ``self`` when none is. Of a row's copies the
        one claiming the least information (``confidence / sigma_px^2``) is kept: which claim is right is unknown, and
        the weaker one cannot make the covariance over-confident. ``pairs``: the ``doubled_rows()`` a caller has."""
        if not (pairs := self.doubled_rows() if pairs is None else pairs):
            return self
        parent = list(range(len(self)))  # copies joined through their pairs (union-find)

        def root(r: int) -> int:
            while parent[r] != r:
                r = parent[r]
            return r

        for i, j in pairs:
            parent[root(i)] = root(j)
        group = np.array([root(r) for r in range(len(self))])
        info = np.asarray(self.confidence) / np.asarray(self.sigma_px) ** 2
        keep = [min(np.flatnonzero(group == g), key=lambda r: (info[r], r)) for g in np.unique(group)]
        return self.subset(np.sort(keep))

    def subset(self, mask: np.ndarray) -> Correspondences:
        """The rows selected by a boolean mask or index array."""
        return Correspondences(
            np.asarray(self.points_radar)[mask], np.asarray(self.pixels)[mask],
            np.asarray(self.sigma_px)[mask], np.asarray(self.confidence)[mask],
            self.K, self.frame_id, self.timestamp_us,
        )

    def moved(self, T: np.ndarray) -> Correspondences:
        """The rows with their radar points moved by ``T`` (4, 4), e.g. to the camera's timestamp by the frame's
        ``N`` (docs/conventions.md "Transforms"); pixels, noise and metadata kept."""
        import dataclasses

        from hybrid_calib.geometry import transform_points

        return dataclasses.replace(self, points_radar=transform_points(np.asarray(T, np.float64),
                                                                       np.asarray(self.points_radar, np.float64)))

    @classmethod
    def empty(cls, K: np.ndarray, frame_id: str = "", timestamp_us: int = 0) -> Correspondences:
        """A frame with no rows (a producer that found nothing to export)."""
        return cls(np.zeros((0, 3)), np.zeros((0, 2)), np.zeros(0), np.zeros(0), np.asarray(K, np.float64),
                   frame_id, timestamp_us)


class SeenRows:
    """The rows of the frames seen so far, to tell a new frame's rows that repeat one of theirs: the same radar point
    (each coordinate within ``REPEAT_RADAR_M``) and pixel (within ``REPEAT_SIGMA`` of the smaller of the two
    sigmas). Such a row is one measurement again, not a second one (probe 59: a replay with one row added or taken
    away passed as a new frame and shrank the std by 30 %). Rows are found through a grid of ``REPEAT_RADAR_M``
    cells on the radar point (the 27 cells around it), so a frame costs the same however many were seen. Frames are
    counted from 0 in the order added; the last ``keep`` frames are remembered."""

    def __init__(self, keep: int = 1000):
        self.keep = int(keep)
        self._cells: dict[tuple[int, int, int], list[tuple[int, np.ndarray, float]]] = {}
        self._frames: dict[int, tuple[str, list[tuple[int, int, int]]]] = {}  # counter -> (frame id, its cells)
        self._next = 0

    def __len__(self) -> int:
        return len(self._frames)

    def frame_id(self, k: int) -> str:
        """The frame id of the ``k``-th frame added."""
        return self._frames[k][0]

    def match(self, corr: Correspondences) -> np.ndarray:
        """(N,) int: for each row of ``corr``, the counter of a remembered frame holding the same row, -1 for a new
        row."""
        out = np.full(len(corr), -1, np.int64)
        if not self._cells:
            return out
        cells = np.floor(corr.points_radar / REPEAT_RADAR_M).astype(np.int64)
        keys = (cells[:, None, :] + _NEIGHBOURS[None]).reshape(-1, 3).tolist()  # (N * 27) cells
        get = self._cells.get
        for i, key in enumerate(keys):
            if (hits := get(tuple(key))) is None or out[r := i // len(_NEIGHBOURS)] >= 0:
                continue
            p, px, s = corr.points_radar[r], corr.pixels[r], corr.sigma_px[r]
            for k, row, s2 in hits:
                if _same_row(p, px, s, row[:3], row[3:], s2):
                    out[r] = k
                    break
        return out

    def add(self, corr: Correspondences) -> int:
        """Remember ``corr``'s rows; returns its counter (the oldest frame is forgotten beyond ``keep``)."""
        k, self._next = self._next, self._next + 1
        keys = [tuple(int(v) for v in c) for c in np.floor(corr.points_radar / REPEAT_RADAR_M).astype(np.int64)]
        for key, p, px, s in zip(keys, corr.points_radar, corr.pixels, corr.sigma_px):
            self._cells.setdefault(key, []).append((k, np.r_[p, px], float(s)))
        self._frames[k] = (corr.frame_id, keys)
        while len(self._frames) > self.keep:
            old = next(iter(self._frames))  # the oldest: counters are added in order
            for key in set(self._frames.pop(old)[1]):
                if kept := [e for e in self._cells[key] if e[0] != old]:
                    self._cells[key] = kept
                else:
                    del self._cells[key]
        return k


def _same_row(p, px, s, p2, px2, s2) -> bool:
    """Whether two rows (radar point (3,) m, pixel (2,), sigma px) are one measurement: the points within
    ``REPEAT_RADAR_M`` per coordinate, the pixels within ``REPEAT_SIGMA`` of the smaller sigma."""
    return bool(np.abs(p2 - p).max() <= REPEAT_RADAR_M and np.abs(px2 - px).max() <= REPEAT_SIGMA * min(s, s2))


_NEIGHBOURS = np.array([(a, b, c) for a in (0, -1, 1) for b in (0, -1, 1) for c in (0, -1, 1)], np.int64)


def repeated_rows(frames) -> dict[int, tuple[np.ndarray, int]]:
    """{index: ((N,) bool rows that repeat an earlier frame's rows, index of the frame the first of them repeats)}
    over ``Correspondences`` ``frames``, each kept once (``Correspondences.once``; the masks index those rows), for
    the frames with such a row (``SeenRows``)."""
    seen, index, out = SeenRows(keep=len(frames) + 1), {}, {}
    for i, f in enumerate(frames):
        if len(f := f.once()):
            m = seen.match(f)
            if (m >= 0).any():
                out[i] = (m >= 0, index[int(m[m >= 0][0])])
            if not (m >= 0).all():
                index[seen.add(f.subset(m < 0))] = i
    return out


def repeated_frames(frames) -> dict[int, int]:
    """{index: index of the earlier frame it repeats} over ``Correspondences`` ``frames`` whose rows all repeat
    earlier frames' rows (``repeated_rows``: a replay, whole, reordered, nudged or cut short); frames without rows
    repeat nothing."""
    return {i: j for i, (m, j) in repeated_rows(frames).items() if m.all()}


def fresh_rows(frames, rep: dict | None = None) -> list[Correspondences]:
    """``frames``, each kept once, without the rows that repeat an earlier frame's rows (``rep``: their
    ``repeated_rows`` when the caller has it)."""
    rep = repeated_rows(frames) if rep is None else rep
    return [f.once().subset(~rep[i][0]) if i in rep else f.once() for i, f in enumerate(frames)]


def repeat_message(frame_id: str, earlier_id: str) -> str:
    """The words for a frame whose rows repeat an earlier frame's (``repeated_frames``)."""
    return (f"frame {frame_id or '?'} repeats the rows of frame {earlier_id or '?'} (the same radar points, the "
            f"pixels within {REPEAT_SIGMA:.0%} of their sigma: a stalled or replayed feed?): one measurement, not two "
            "independent ones, so it is left out")


def replayed_message(c: Correspondences, repeated: np.ndarray, earlier_id: str) -> str:
    """The words for a frame some of whose rows (``repeated``, (N,) bool) repeat an earlier frame's, left out."""
    return (f"{int(repeated.sum())} of the frame's {len(c)} rows repeat rows of frame {earlier_id or '?'} (the same "
            f"radar points, the pixels within {REPEAT_SIGMA:.0%} of their sigma: a replayed feed?): left out (one "
            "measurement counted twice shrinks the covariance as if it were two)")


def doubled_message(c: Correspondences, pairs: list[tuple[int, int]] | None = None) -> str:
    """The words for a frame holding rows twice (``Correspondences.doubled_rows``, or the ``pairs`` a caller has),
    kept once; "" when it holds none."""
    if not (pairs := c.doubled_rows() if pairs is None else pairs):
        return ""
    i, j = pairs[0]
    return (f"{len(pairs)} of the frame's {len(c)} rows repeat another row of it (first: row {i} = row {j}: the same "
            "radar point and pixel): kept once (one measurement counted twice shrinks the covariance as if it were "
            "two)")
