"""Seeded random streams: the one home of how the project turns keys into a generator.

Two derivations, each kept where it is (changing either changes every figure and root drawn with it):

- ``keyed_seed`` / ``keyed_rng``: keys (ints or strings) joined by ":" and hashed (SHA-1, its first ``nbytes``
  little-endian). The keys may be tokens and names, and a stream does not depend on what else a run holds (a
  vehicle's start, a frame's depth corruption, a training epoch's shuffle, a scene's split).
- ``sequence_rng``: integer keys through numpy's ``SeedSequence`` (the simulator's streams: per vehicle, per frame,
  per purpose).
"""

from __future__ import annotations

import hashlib

import numpy as np


def keyed_seed(*keys: int | str, nbytes: int = 8) -> int:
    """An integer in [0, 2**(8*nbytes)) fixed by ``keys`` alone: SHA-1 of the keys joined by ":", its first
    ``nbytes`` bytes little-endian."""
    return int.from_bytes(hashlib.sha1(":".join(str(k) for k in keys).encode()).digest()[:nbytes], "little")


def keyed_rng(*keys: int | str) -> np.random.Generator:
    """A generator fixed by ``keys`` alone (``keyed_seed``)."""
    return np.random.default_rng(keyed_seed(*keys))


def sequence_rng(*keys: int) -> np.random.Generator:
    """A generator of integer ``keys`` through ``np.random.SeedSequence`` (the simulator's streams)."""
    return np.random.default_rng(np.random.SeedSequence([int(k) for k in keys]))
