"""Errors that name the file, frame or field that was wrong, and what to do about it."""

from __future__ import annotations

import errno
import os
import re
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
        self.message = message  # without the file and token
        self.path = path
        self.token = token


class CheckpointError(DataError):
    """A checkpoint file that is missing, truncated, garbage, or not in the safe format (names the file)."""


# torch's words for a DataLoader worker that a signal ended (a SIGTERM or Ctrl-C sent to the whole process group)
_WORKER_KILLED = re.compile(r"DataLoader worker \(pids?\(?s?\)? [\d, ]+\) (?:is|are) killed by signal: "
                            r"(Terminated|Interrupt)")


def unencodable_words(path: str | Path) -> str:
    """"" when ``path`` is a name this process's file-system encoding can hold, else why it cannot be opened: under an
    ASCII (or Latin-1) encoding a non-ASCII name read from a file (a result's data root, a fleet manifest) is no name
    at all (probe 119: "does not exist" and "is not there" for folders that exist, an internal error in export)."""
    import sys

    enc = sys.getfilesystemencoding()
    try:
        str(path).encode(enc, "surrogateescape")
        return ""
    except UnicodeEncodeError:
        return (f"; its name holds characters this process's file-system encoding ({enc}) cannot hold: run in a "
                "UTF-8 locale (PYTHONUTF8=1)")


def stop_signal_of(error: BaseException) -> int | None:
    """``signal.SIGTERM`` / ``SIGINT`` when ``error`` is torch's RuntimeError for a DataLoader worker that the signal
    ended, else None: the group's signal reached the worker first (``docker stop``, systemd, a scheduler's
    pre-emption), and the run is stopped by it, not failed (probe 111: an internal error, exit 3)."""
    import signal

    m = _WORKER_KILLED.search(str(error)) if isinstance(error, RuntimeError) else None
    return None if m is None else (signal.SIGTERM if m[1] == "Terminated" else signal.SIGINT)


class OptionError(HybridCalibError):
    """A command-line option whose value cannot work (e.g. ``--out`` naming an existing file)."""

    def __init__(self, option: str, message: str):
        super().__init__(f"{option}: {message}")
        self.option = option


def check_out_dir(path: str | Path | None, option: str = "--out", writable: bool = True) -> None:
    """``OptionError`` when an output directory ``path`` exists and is not a directory, lies below a file, or
    (``writable``) cannot be written (its nearest existing folder is not writable); None passes. Nothing is
    created."""
    if path is None:
        return
    path = Path(path)
    # was "a file where a folder is needed (File exists)" (probe 66); the same for a folder above it (probe 84)
    for link in (path, *path.parents):
        if not (link.is_symlink() and not link.exists()):
            continue
        what = str(link) if link == path else f"{link} (a folder above {path})"
        try:
            link.resolve(strict=True)
        except RuntimeError:  # a loop (probe 70: said to be a link to a file that is not there)
            raise OptionError(option, f"{what} is a symbolic link loop; remove it, or pass another path") from None
        except OSError:
            pass
        raise OptionError(option, f"{what} is a broken symbolic link (to {os.readlink(link)}, which is not there); "
                                  "create its target, remove the link, or pass another path")
    if path.exists() and not path.is_dir():
        raise OptionError(option, f"{path} is an existing file, but the outputs go into a directory; pass a "
                                  "directory path (it is created if missing) or move the file away")
    for parent in path.parents:
        if parent.exists() and not parent.is_dir():
            raise OptionError(option, f"{parent} (a parent of {path}) is a file, not a directory; pass another path")
    existing = next((p for p in (path, *path.parents) if p.exists()), None)
    if writable and existing is not None and not os.access(existing, os.W_OK | os.X_OK):
        what = "is not writable" if existing == path else f"(the nearest existing folder of {path}) is not writable"
        raise OptionError(option, f"{existing} {what}, so the outputs cannot be written there; pass a directory you "
                                  "can write to")


LOCK_NAME = ".hybrid-calib.lock"  # OUT/.hybrid-calib.lock: the output-folder lock of a running command (``atomic``)
RUNS_NAME = "runs.json"  # OUT/runs.json: every command that finished writing into the folder (``atomic.record_run``)

# the file each command writes at the top of its --out (and no other command does there)
OUT_MARKERS = {"train": "train_config.json", "evaluate": "export_config.json", "calibrate": "result.json",
               "compare": "compare_config.json", "fleet": "manifest.json", "export": "export.json",
               "demo": "demo_config.json", "inspect": "inspect_config.json"}


# the other files each command writes at the top of its --out (a user's file of that name there was replaced)
# (probe 117: evaluate's results.json / results.md, calibrate's data_stamp.json, train's steps.csv were missing)
OUT_FILES = {"train": ("epochs.csv", "steps.csv", "history.png", "skipped.json"),
             "evaluate": ("results.json", "results.md", "errors_cdf.png", "skipped.json"),
             "calibrate": ("config.json", "data_stamp.json"),
             "compare": ("compare.json", "compare.md", "error_vs_frames.png"),
             "fleet": ("summary.json", "summary.md", "fleet.png", "fleet_prior.json", "fleet.html"),
             "demo": ("summary.json", "projection.png"), "inspect": ("inspect_summary.json", "overlay.png")}


def check_out_files(out: str | Path | None, command: str, overwrite: bool | None = None) -> None:
    """``OptionError`` when ``out`` holds a file that ``command`` writes (``OUT_FILES``) in a folder no hybrid-calib
    run wrote (neither the command's ``OUT_MARKERS`` file nor ``runs.json``): the user's own file, which the run
    would replace (probe 40: a config.json and an overlay.png of the user's were). ``overwrite``: True replaces them;
    None: the command has no --overwrite (the message does not offer it)."""
    if out is None or overwrite or not Path(out).is_dir():
        return
    marker = OUT_MARKERS.get(command)
    if (Path(out) / RUNS_NAME).exists() or (marker and (Path(out) / marker).exists()):
        return
    if clash := [n for n in OUT_FILES.get(command, ()) if (Path(out) / n).exists()]:
        names = ", ".join(clash)
        how = "pass another --out, or --overwrite to replace them" if overwrite is not None else "pass another --out"
        record = f"{marker} or {RUNS_NAME}" if marker else RUNS_NAME
        raise OptionError("--out", f"{out} holds {names}, which hybrid-calib {command} writes there, and no record of "
                                   f"a hybrid-calib run ({record}): not its outputs, and this run would replace them; "
                                   f"{how}")


def check_runs_record(out: str | Path | None) -> None:
    """``OptionError`` when ``OUT/runs.json`` is there but is not a regular file (a FIFO hung the run at its end,
    ignoring Ctrl-C: probe 66) or cannot be read (permissions: it was replaced, the runs it recorded lost)."""
    if out is None:
        return
    path = Path(out) / RUNS_NAME
    if not os.path.lexists(path):
        return
    if not path.is_file():
        raise OptionError("--out", f"{path} is not a regular file (a folder, a named pipe or a broken link), where the "
                                   "run's record goes; move it away")
    try:
        with open(path, "rb") as f:
            f.read(1)
    except OSError as e:
        raise OptionError("--out", f"{path} cannot be read ({e.strerror or e}): the runs it records would be lost "
                                   "when this run adds its own; make it readable, or move it away") from None


def check_out_owner(out: str | Path | None, command: str, option: str = "--out") -> None:
    """``OptionError`` when ``out`` holds another command's outputs (its ``OUT_MARKERS`` file): a run there mixed
    its files with them (a train run beside an evaluate run's results, sharing its depth cache)."""
    if out is None or not Path(out).is_dir():
        return
    for other, marker in OUT_MARKERS.items():
        # a marker alone (with the lock file) is a run that failed before any output: nothing there to mix with
        if other != command and (Path(out) / marker).is_file() and any(
                p.name not in (marker, LOCK_NAME, RUNS_NAME) for p in Path(out).iterdir()):
            raise OptionError(option, f"{out} holds the outputs of hybrid-calib {other} ({marker}); this {command} "
                                      f"run would mix its files with them: pass another {option}")


def page_target(path: str | Path, option: str = "--out") -> Path:
    """The file a page written at ``path`` lands in: a symbolic link's target (so every check is made on it: probe 70,
    a link sent the page into a root's version folder past the checks made on the link); ``OptionError`` for a link
    loop."""
    path = Path(path)
    if not path.is_symlink():
        return path
    try:
        return path.resolve()
    except (RuntimeError, OSError) as e:
        raise OptionError(option, f"{path} is a symbolic link that does not end in a file ({e}); remove it, or pass "
                                  "another path") from None


def check_api_out(out: str | Path, command: str, data=None, version: str | None = None, page: bool = False) -> None:
    """The command line's checks of an output folder, for the typed functions a library user calls directly
    (``run_calibration``, ``compare``, ``run_fleet``, the report pages): ``OptionError`` naming ``out`` when it is
    a file (``check_out_dir``; not whether it can be written: a reused result writes nothing, and a write says its
    own error), lies in any nuScenes root's tables or sensor folders (``check_out_not_in_dataset``) or holds another
    command's outputs (``check_out_owner``; probe 67: the functions wrote into a root's version folder, its samples/
    and a compare run's folder, which the commands refuse); and ``data`` when a run writes it now
    (``check_not_being_written``). ``page``: ``out`` is a page (a file): the folder of the file it lands in (a
    symbolic link's target) is checked."""
    folder = page_target(out, "out").parent if page else Path(out)
    check_out_dir(folder, "out", writable=False)  # reusing an earlier result writes nothing (a read-only archive)
    if data is not None:
        check_not_being_written(data, "data")
    check_out_not_in_dataset(folder, "out", data=data, version=version)
    if not page:
        check_out_owner(folder, command, "out")


def check_not_being_written(folders, option: str) -> None:
    """``OptionError`` naming ``option`` and the run when a folder a command reads (``--data`` roots,
    ``--correspondences``) is being written by a hybrid-calib run now: its ``LOCK_NAME`` is held (probe 140: a
    calibrate read a root ``simulate --overwrite`` was re-rendering, and blamed each vanished frame on a partial
    download; one read an evaluate export half written, calibrated 16 of 30 frames and said the export "covered other
    vehicles"). ``folders``: one path or several; a folder without a lock file, or one that cannot be opened, is not
    ours to judge."""
    import fcntl

    for folder in [folders] if isinstance(folders, (str, os.PathLike)) else list(folders or ()):
        path = Path(folder) / LOCK_NAME
        try:
            if path.is_symlink() or not path.is_file():
                continue
            f = open(path, "rb")
        except OSError:
            continue
        with f:
            try:
                fcntl.flock(f, fcntl.LOCK_SH | fcntl.LOCK_NB)
            except OSError as e:
                if e.errno not in (errno.EWOULDBLOCK, errno.EAGAIN):  # no locks there (NFS without lockd): cannot
                    continue  # tell (probe 142: a killed run's lock read as a live writer)
                holder = f.read(1 << 16).decode("utf-8", "replace").strip().split("\n")[0] or "another process"
                raise OptionError(option, f"{folder} is being written by a hybrid-calib run now ({holder}); wait for "
                                          "it to end, then rerun") from None
            fcntl.flock(f, fcntl.LOCK_UN)


TABLE_FILES = ("sample_data.json", "calibrated_sensor.json")  # a folder holding both is a nuScenes version folder


def _is_version_folder(p: Path) -> bool:
    return all((p / name).is_file() for name in TABLE_FILES)


def _holds_version_folder(p: Path) -> bool:
    try:
        return p.is_dir() and any(c.is_dir() and _is_version_folder(c) for c in p.iterdir())
    except OSError:  # unreadable: not ours to judge
        return False


def check_out_not_in_dataset(out: str | Path | None, option: str = "--out", root_ok: bool = False, data=None,
                             version: str | None = None) -> None:
    """``OptionError`` when the output folder ``out`` is a nuScenes root, or lies inside any root's version folder
    (a folder holding ``TABLE_FILES``) or its ``samples/`` / ``sweeps/``: whichever root, not only the one the run
    reads (an export into another root's version folder replaced its calibrated_sensor.json; a report page or a
    cache landed among a dataset's files); first, with ``data`` / ``version``, the run's own roots
    (``check_out_outside_data``: their folders also when their tables are incomplete). Checked before the run takes
    its lock or creates the folder. ``root_ok``: ``out`` may itself be a root (simulate's --out), but not lie inside
    one's data folders."""
    if out is None or str(out) == "":
        return
    check_out_outside_data(out, data, version, option)
    for form in _path_forms(out):
        _check_not_in_dataset(form, option, root_ok)


def _path_forms(path: str | Path) -> list[Path]:
    """``path`` absolute as written and with its symlinks resolved (one or two paths): a root whose samples/ is a
    symlink into a store holds ``ROOT/samples/x`` only as written, a symlinked output folder only resolved."""
    written, resolved = Path(os.path.abspath(path)), Path(path).resolve()
    return [written] if written == resolved else [written, resolved]


def _check_not_in_dataset(out: Path, option: str, root_ok: bool) -> None:
    for p in (out, *out.parents):
        if _is_version_folder(p):
            raise OptionError(option, f"{out} is {'' if p == out else 'inside '}the nuScenes table folder {p} (it "
                                      "holds sample_data.json and calibrated_sensor.json): the outputs would lie "
                                      "among a dataset's tables and could replace them; pass a folder outside any "
                                      "data root")
        if p.name in ("samples", "sweeps") and _holds_version_folder(p.parent):
            raise OptionError(option, f"{out} is inside the {p.name}/ folder of the nuScenes root {p.parent}: the "
                                      "outputs would lie among the dataset's sensor files; pass a folder outside it")
    if not root_ok and _holds_version_folder(out):  # simulate writes a root: its own, resumed or --overwrite
        raise OptionError(option, f"{out} is a nuScenes root (it holds a version folder with sample_data.json): the "
                                  "outputs would lie among the dataset's folders; pass a folder outside it (e.g. "
                                  f"{out.parent / (out.name + '-out')})")


def check_out_outside_data(out: str | Path | None, data, version: str | None, option: str = "--out") -> None:
    """``OptionError`` when the output folder ``out`` is (inside) a data root's version folder or sensor folders
    (``samples/``, ``sweeps/``) of ``data`` (a root or a list of roots): the outputs would lie among the dataset's
    files, and the run's own files would change the root's data stamp (its next run: "the data changed")."""
    if out is None or data is None:
        return
    pairs = [(o, r) for d in (data if isinstance(data, (list, tuple)) else [data])
             for o in _path_forms(out) for r in _path_forms(d)]
    for out, root in pairs:  # each written / resolved form of the output against each of the root
        if out == root:  # its result.json, config.json and caches beside samples/ and the version folder
            raise OptionError(option, f"{out} is the data root itself: the outputs would lie among the dataset's "
                                      "folders; pass a folder outside it (e.g. "
                                      f"{root.parent / (root.name + '-out')})")
        for part in ([version] if version else []) + ["samples", "sweeps"]:
            # the folder as written and resolved: a samples/ that is a symlink to a store on another disk holds the
            # sensor files under its target too (probe 40: an --out given by that target's path was written into)
            for inside in dict.fromkeys((root / part, (root / part).resolve())):
                if out == inside or inside in out.parents:
                    where = "" if out == inside else "inside "
                    raise OptionError(option, f"{out} is {where}the data root's {part}/ folder ({inside}): the "
                                              "outputs would lie among the dataset's files; pass a folder outside "
                                              f"them (e.g. {root.parent / (root.name + '-out')})")
