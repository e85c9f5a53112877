"""Reading the files a run is given or wrote before: the one home of "is this a file we can read?".

- ``check_regular_file``: a named pipe blocked a reader for ever; a directory or a device is not a data file.
- ``read_npz``: a ``.npz`` opened without pickles, with every way it can be damaged (not a zip, truncated
  archive or member, a missing key, a misshaped array read in the body) turned into one ``DataError`` naming
  the file and what to do.
- ``NPZ_ERRORS``: those ways, for the caches that recompute a damaged entry instead of failing.
- ``file_part``: a name taken from the data (a vehicle, a token) as one safe file-name component: the one
  rule for every file or folder a run names after them.
- ``data_stamp``: what changes when a root's data change (its tables, its sensor folders), so a rerun never
  reuses a result computed from other data on the strength of the path.
"""

from __future__ import annotations

import os
import stat
import zipfile
import zlib
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from pathlib import Path

import numpy as np

from hybrid_calib.errors import DataError

# np.load of a damaged .npz: not a zip (BadZipFile / ValueError), a truncated archive (BadZipFile) or member
# (EOFError, zlib.error), pickled arrays refused (ValueError), a missing key (KeyError), an unreadable file
# (OSError); IndexError / TypeError from a body that indexes a misshaped array
NPZ_ERRORS: tuple[type[BaseException], ...] = (OSError, ValueError, KeyError, IndexError, TypeError, EOFError,
                                               zipfile.BadZipFile, zlib.error)


MAX_FILE_PART = 120  # characters of a name kept in a file name (the rest: a digest)


def file_part(name: str) -> str:
    """``name`` (a vehicle name from log.json, a sample_data token, a job id) as ONE safe file-name component.

    The tables are input: a vehicle named ``../../x``, ``/abs``, ``a/b`` or ``""`` put a fleet's results outside
    ``--out`` (and replaced another run's). Percent-encoding (``urllib.parse.quote`` with nothing but letters,
    digits and ``-_.~`` kept) is injective, so two names never share a file (``a/b`` and ``a_b`` did in the
    caches, which then served one frame's data for the other); a name of dots only or starting with one (``..``,
    a hidden file) has its dots encoded too, an empty one is ``%``, and a long one keeps ``MAX_FILE_PART``
    characters and a digest of the whole. Names of letters, digits, ``-``, ``_`` and inner dots are unchanged
    (``sim-veh-000``, ``n015``, nuScenes' hex tokens)."""
    import hashlib
    from urllib.parse import quote

    name = str(name)
    part = quote(name, safe="")
    if part.startswith("."):
        part = "%2E" + part[1:]
    if part.strip(".") == "" or part.endswith("."):
        part = part.replace(".", "%2E") or "%"
    if len(part) > MAX_FILE_PART:
        part = part[:MAX_FILE_PART] + "~" + hashlib.sha1(name.encode("utf-8", "surrogatepass")).hexdigest()[:12]
    return part


def data_stamp(root: str | Path, version: str) -> dict:
    """{"digest", "newest"} of a root's data as a calibration reads it: the version folder's tables (name and
    content: a rerun of ``simulate`` rewrites them unchanged) and the file names in each folder of ``samples/`` and
    ``sweeps/`` (a file added, removed or renamed: a re-download or re-simulation of other frames). Not the folders'
    modification times: a copy of a root (``cp -r``, another machine of the fleet) is the same data, and its
    results, their reports and caches hold on it (probe 23: a ``cp -r`` of a root made ``report`` drop its
    pictures). A frame file rewritten in place under its name is not seen (hashing or stat'ing every frame file
    of a large root on each rerun is not worth it). ``newest``: the latest modification time of those tables and
    folders (ISO, UTC), for the message."""
    import datetime
    import hashlib

    root = Path(root)
    items, newest = [], 0
    for path in sorted((root / version).glob("*.json")):
        try:
            h = hashlib.sha1()
            with open(path, "rb") as f:
                for chunk in iter(lambda: f.read(1 << 20), b""):
                    h.update(chunk)
            items.append((path.name, h.hexdigest()))
            newest = max(newest, path.stat().st_mtime_ns)
        except OSError:
            continue
    for path in _sensor_folders(root):
        try:
            names = sorted(e.name for e in os.scandir(path))
            newest = max(newest, path.stat().st_mtime_ns)
        except OSError:
            continue
        items.append((str(path.relative_to(root)), hashlib.sha1("\n".join(names).encode()).hexdigest()))
    return {"digest": hashlib.sha1(repr(items).encode()).hexdigest(),
            "newest": datetime.datetime.fromtimestamp(newest / 1e9, datetime.timezone.utc).isoformat(
                timespec="seconds") if newest else None}


def file_stamp(path: str | Path) -> str:
    """What a file is on disk without reading it: "resolved path/size/modification time ns", or "path/absent" when it
    cannot be stat'ed. The key of the caches of what is computed from a frame's files (``learned.depth.depth_inputs``,
    the hybrid's image matches): a file replaced at its path is another file."""
    try:
        st = Path(path).stat()
        return f"{Path(path).resolve()}/{st.st_size}/{st.st_mtime_ns}"
    except OSError:
        return f"{path}/absent"


def _sensor_folders(root: Path) -> list[Path]:
    """The folders of ``root``'s ``samples/`` and ``sweeps/`` (one per channel), sorted."""
    return sorted(d for top in ("samples", "sweeps") if (root / top).is_dir() for d in (root / top).iterdir()
                  if d.is_dir())


def root_fingerprint(root: str | Path, version: str) -> tuple:
    """What a run sees of a root's files without reading them: (name, inode, size, modification time ns) of the
    version folder's tables and of each folder of ``samples/`` and ``sweeps/`` (a file added or removed there moves
    its folder's time; a re-simulation or re-download replaces the folders). Taken at a run's start and end: a root
    that changed while it read it (probe 142: ``simulate --overwrite`` started after the calibrate) is said, not
    calibrated on a mix of old and new frames (``root_changed``)."""
    root = Path(root)
    paths = [*sorted((root / version).glob("*.json")), *_sensor_folders(root)]
    out = []
    for path in paths:
        try:
            st = path.stat()
        except OSError:
            continue
        out.append((str(path.relative_to(root)), st.st_ino, st.st_size, st.st_mtime_ns))
    return tuple(out)


def root_changed(root: str | Path, version: str, seen: tuple, digest: str) -> bool:
    """Whether the root changed since ``seen`` (its ``root_fingerprint``) and ``digest`` (its ``data_stamp`` then)
    were taken: a sensor folder replaced, or added or removed files (a re-simulation, a re-download: frames vanished
    under the reader), or tables of other content. Tables rewritten with the same bytes (``simulate`` run again on a
    complete root: probe 144) are the same data."""
    now = root_fingerprint(root, version)
    if now == seen:
        return False
    folders = [[x for x in fp if not x[0].endswith(".json")] for fp in (seen, now)]
    return folders[0] != folders[1] or data_stamp(root, version)["digest"] != digest


def root_changed_error(root: str | Path) -> DataError:
    """The ``DataError`` of a run whose root changed while it read it (``root_changed``): no result is written and its
    kept vehicles are discarded (they were read from the changing root)."""
    return DataError(f"{root} changed while this run read it (its tables or sensor folders were replaced: "
                     "re-simulated, re-downloaded or edited by another process), so its frames are a mix of the old "
                     "and the new data: no result is written, and the vehicles it finished are discarded; rerun once "
                     "the root is complete", path=str(root))


def watch_roots(record: dict | None) -> Callable[[], str | None]:
    """A function giving the first root of ``record`` that changed (``root_changed``) since this call, or None: for the
    runs that read roots for long (``evaluate``'s export, ``train``'s epochs), as ``run_calibration`` checks its one
    root. ``record``: what a run records of its data, {"roots", "version", "stamps" (their ``data_stamp`` digests,
    optional)}; without roots, a watch of nothing."""
    if not record or not record.get("roots") or not record.get("version"):
        return lambda: None
    roots, version = [str(r) for r in record["roots"]], record["version"]
    digests = record.get("stamps")
    if digests is None or len(digests) != len(roots):
        digests = [data_stamp(r, version)["digest"] for r in roots]
    seen = [root_fingerprint(r, version) for r in roots]

    def first_changed() -> str | None:
        return next((r for r, fp, d in zip(roots, seen, digests) if root_changed(r, version, fp, d)), None)

    return first_changed


def absolute_path(option: str) -> str:
    """A path option (a checkpoint, a refining one, ``--init``) made absolute where it names an existing file or folder,
    so the same run typed from another folder is that run (probes 119, 121); a keyword ("", "none", "shipped") or a
    path that is not there (its reader says so, as typed) is kept."""
    return str(Path(option).resolve()) if option and option not in ("none", "shipped") and Path(option).exists() \
        else option


def missing_folder_words(path: str | Path) -> str:
    """Why a dataset file is missing when its channel's whole folder is (``samples/CAM_BACK`` absent beside other
    channels: a copy that ships some channels only), or when that folder holds other files (this one not downloaded),
    or "" when the folder is there and empty (probe 34: "check the dataset root" sent a user to a root that was
    right)."""
    # a link into a store that is not mounted, the file's or its channel folder's (probes 102 and 103 read "not
    # downloaded" and "this copy has no RADAR_FRONT files")
    for link in (Path(path), Path(path).parent, Path(path).parent.parent):
        if link.is_symlink() and not link.exists():
            try:
                target = os.readlink(link)
            except OSError:
                target = "?"
            what = "it is" if link == Path(path) else f"its folder {link.parent.name}/{link.name} is"
            return (f"; {what} a symbolic link to {target}, which does not exist (the store it points into is not "
                    "mounted, or was moved): mount it or fix the links")
    if "\\" in Path(path).name and (fixed := Path(str(path).replace("\\", "/"))).exists():  # probe 108: read as a
        # partial download
        return (f"; its name is written with backslashes (Windows separators), and {fixed.parent.name}/{fixed.name} "
                "is there: nuScenes' file names use '/'; fix the filename in sample_data.json")
    folder = Path(path).parent
    if folder.parent.name not in ("samples", "sweeps"):  # probe 146: a filename "x" read as a partial download of
        # the root's own folder
        return ("; the record's filename is not a samples/<CHANNEL>/... or sweeps/<CHANNEL>/... path (the nuScenes "
                "layout every file of a root follows): fix the filename in sample_data.json")
    if folder.is_dir():  # the channel is there, not this file (probe 101: "check the dataset root" for 5 of 41)
        try:
            others = next(folder.iterdir(), None) is not None
        except OSError:
            others = False
        return (f"; its folder {folder.parent.name}/{folder.name} is there, with other files: this one was not "
                "downloaded or was deleted (a partial download); re-download it, or leave its scene out with --set "
                "'data.scenes=[...]'") if others else ""
    if not folder.parent.is_dir():
        return ""
    there = sorted(p.name for p in folder.parent.iterdir() if p.is_dir())
    return (f"; the folder {folder.parent.name}/{folder.name} does not exist under the root (channel folders there: "
            f"{', '.join(there[:8]) or 'none'}{', ...' if len(there) > 8 else ''}): this copy has no {folder.name} "
            "files; copy them in, or pick a channel it has")


def check_regular_file(path: str | Path, what: str, token: str | None = None) -> None:
    """``DataError`` naming ``path`` when it exists but is not a regular file (after following links): reading a
    named pipe (FIFO) blocked the job for ever, a directory or a device is not a data file either. A missing
    path raises ``FileNotFoundError`` (each reader says what to do about it)."""
    try:
        mode = os.stat(path).st_mode
    except ValueError as e:  # "embedded null byte": a name no file has (probe 108: an internal error)
        raise DataError(f"{what} has a path no file can have ({e}): {str(path)!r}; fix the record that names it",
                        path=repr(str(path)), token=token) from None
    if stat.S_ISREG(mode):
        return
    kind = ("a named pipe (FIFO)" if stat.S_ISFIFO(mode) else "a directory" if stat.S_ISDIR(mode)
            else "a socket" if stat.S_ISSOCK(mode) else "a device" if stat.S_ISCHR(mode) or stat.S_ISBLK(mode)
            else "a special file")
    raise DataError(f"{what} is {kind}, not a regular file, so it cannot be read; replace it with the dataset's "
                    "file (re-extract or re-download it)", path=str(path), token=token)


@contextmanager
def read_npz(path: str | Path, what: str, fix: str, token: str | None = None) -> Iterator[np.lib.npyio.NpzFile]:
    """``with read_npz(path, "measurement file", "re-run the export") as z: ...``: the open archive (no pickles).

    Any of ``NPZ_ERRORS`` raised while opening it or in the body (a missing key, a misshaped array) becomes
    ``DataError("<what> unreadable (<error>); the file is corrupt or truncated: <fix>")`` naming ``path`` and
    ``token``; a path that is not a regular file is named as such first (a FIFO would block ``np.load``)."""
    try:
        check_regular_file(path, what, token)
        z = np.load(path, allow_pickle=False)
        if not isinstance(z, np.lib.npyio.NpzFile):  # a bare array (.npy) under the name (probe 103: a TypeError)
            raise DataError(f"{what} unreadable: it is not a .npz archive (a single array, .npy, under its name); the "
                            f"file is another file under its name: {fix}", path=str(path), token=token)
        with z:
            yield z
    except NPZ_ERRORS as e:
        if isinstance(e, ValueError) and "pickle" in str(e):  # not a zip: numpy took it for a pickle (probe 100 read
            # its advice to "load it unsafely")
            raise DataError(f"{what} unreadable: it is not a .npz archive (neither a zip of arrays nor an array); the "
                            f"file is corrupt or another file under its name: {fix}", path=str(path),
                            token=token) from None
        raise DataError(f"{what} unreadable ({type(e).__name__}: {e}); the file is corrupt or truncated: {fix}",
                        path=str(path), token=token) from None


def stamps_changed(was: dict, now: dict) -> str:
    """Words for a record of the data a run read (``{"roots", "stamps"}``: ``data_stamp`` digests per root) whose
    roots' data changed since ``was`` was recorded; "" when they did not, or when ``was`` holds no stamps (an older
    record)."""
    if "stamps" not in was or was.get("stamps") == now.get("stamps"):
        return ""
    changed = [r for r, a, b in zip(now.get("roots", []), was["stamps"], now.get("stamps", [])) if a != b]
    return (f"the data in {', '.join(changed or now.get('roots', []))} as it was before (its tables or sensor folders "
            "changed since: re-simulated or re-downloaded)")


def root_labels(roots: list[str], sep: str = "-") -> dict[str, str]:
    """root (as given) -> a short label that tells the roots apart: the folder name, with as many parent folders as
    it takes to tell roots of one folder name apart, joined by ``sep`` (``2024-05-sim``, ``2024-06-sim``; the fleet's
    job ids, compare's per-root rows). Spellings of one folder get one label."""
    given = {}  # resolved -> the path as given (its parts name it)
    for r in roots:
        given.setdefault(str(Path(r).resolve()), Path(r).absolute())
    depth, most = 1, max((len(p.parts) for p in given.values()), default=1)
    while True:
        labels = {k: sep.join(p.parts[-depth:]).lstrip("/") for k, p in given.items()}
        if len(set(labels.values())) == len(labels) or depth >= most:
            return {r: labels[str(Path(r).resolve())] for r in roots}
        depth += 1
