"""Errors that name the file, frame or field that was wrong, and what to do about it."""

from __future__ import annotations

import os
from pathlib import Path


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


class CheckpointError(DataError):
    """A checkpoint file that is missing, truncated, garbage, or not in the safe format (names the file)."""


class OptionError(HybridCalibError):
    """A command-line option whose value cannot work (e.g. ``--out`` naming an existing file)."""

    def __init__(self, option: str, message: str):
        super().__init__(f"{option}: {message}")
        self.option = option


def check_out_dir(path: str | Path | None, option: str = "--out") -> None:
    """``OptionError`` when an output directory ``path`` exists and is not a directory, lies below a file, or
    cannot be written (its nearest existing folder is not writable); None passes. Nothing is created."""
    if path is None:
        return
    path = Path(path)
    if path.exists() and not path.is_dir():
        raise OptionError(option, f"{path} is an existing file, but the outputs go into a directory; pass a "
                                  "directory path (it is created if missing) or move the file away")
    for parent in path.parents:
        if parent.exists() and not parent.is_dir():
            raise OptionError(option, f"{parent} (a parent of {path}) is a file, not a directory; pass another path")
    existing = next((p for p in (path, *path.parents) if p.exists()), None)
    if existing is not None and not os.access(existing, os.W_OK | os.X_OK):
        what = "is not writable" if existing == path else f"(the nearest existing folder of {path}) is not writable"
        raise OptionError(option, f"{existing} {what}, so the outputs cannot be written there; pass a directory you "
                                  "can write to")


# the file each command writes at the top of its --out (and no other command does there)
OUT_MARKERS = {"train": "train_config.json", "evaluate": "export_config.json", "calibrate": "result.json",
               "compare": "compare_config.json", "fleet": "manifest.json", "export": "export.json",
               "demo": "demo_config.json", "inspect": "inspect_config.json"}


def check_out_owner(out: str | Path | None, command: str) -> None:
    """``OptionError`` when ``out`` holds another command's outputs (its ``OUT_MARKERS`` file): a run there mixed
    its files with them (a train run beside an evaluate run's results, sharing its depth cache)."""
    if out is None or not Path(out).is_dir():
        return
    from hybrid_calib.atomic import LOCK_NAME

    for other, marker in OUT_MARKERS.items():
        # a marker alone (with the lock file) is a run that failed before any output: nothing there to mix with
        if other != command and (Path(out) / marker).is_file() and any(
                p.name not in (marker, LOCK_NAME) for p in Path(out).iterdir()):
            raise OptionError("--out", f"{out} holds the outputs of hybrid-calib {other} ({marker}); this {command} "
                                       "run would mix its files with them: pass another --out")


def check_out_outside_data(out: str | Path | None, data, version: str | None) -> None:
    """``OptionError`` when the output folder ``out`` is (inside) a data root's version folder or sensor folders
    (``samples/``, ``sweeps/``) of ``data`` (a root or a list of roots): the outputs would lie among the dataset's
    files, and the run's own files would change the root's data stamp (its next run: "the data changed")."""
    if out is None or data is None:
        return
    out = Path(out).resolve()
    for root in data if isinstance(data, (list, tuple)) else [data]:
        root = Path(root).resolve()
        if out == root:  # its result.json, config.json and caches beside samples/ and the version folder
            raise OptionError("--out", f"{out} is the data root itself: the outputs would lie among the dataset's "
                                       "folders; pass a folder outside it (e.g. "
                                       f"{root.parent / (root.name + '-out')})")
        for part in ([version] if version else []) + ["samples", "sweeps"]:
            inside = root / part
            if out == inside or inside in out.parents:
                raise OptionError("--out", f"{out} is inside the data root's {part}/ folder ({inside}): the outputs "
                                           "would lie among the dataset's files; pass a folder outside them (e.g. "
                                           f"{root.parent / (root.name + '-out')})")
