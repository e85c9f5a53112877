"""Errors that name the file, frame or field that was wrong, and what to do about it."""

from __future__ import annotations


class HybridCalibError(Exception):
    """Base class of every error this package raises on purpose."""


class DataError(HybridCalibError):
    """Bad input data: a corrupt file, a missing table, an unresolved token, NaN points...

    The message always names the offending file / token / field and says what to do.
    """

    def __init__(self, message: str, *, path: str | None = None, token: str | None = None):
        where = []
        if path:
            where.append(f"file {path}")
        if token:
            where.append(f"token {token}")
        super().__init__(f"{message}" + (f" [{', '.join(where)}]" if where else ""))
        self.path = path
        self.token = token
