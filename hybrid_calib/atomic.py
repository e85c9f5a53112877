"""Atomic file writes: the one way every output file reaches disk.

A writer fills a temporary file beside the target (same folder, so the final rename is atomic on
POSIX; same suffix, so writers that choose the format by extension (OpenCV, ``np.save``,
``np.savez``, matplotlib) write the right one), and only a complete file is renamed over the target.
A crash leaves either the old file or the new one, never a half-written one; a failed writer
removes its temporary file. The temporary name carries the process id, so concurrent workers
writing the same path do not share a temporary file. An ``OSError`` of the write (a full disk too) names the
target, never the temporary file (a target that is a directory is refused before the writer runs); a writer's own
error on a full disk (safetensors', torch's) becomes the ``OSError`` of a full disk (ENOSPC), naming the target.
"""

from __future__ import annotations

import errno
import os
import re
import threading
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from pathlib import Path

from hybrid_calib.errors import LOCK_NAME, RUNS_NAME, HybridCalibError

_IS_A_DIRECTORY = ("{path} is a directory, so the output file cannot be written there; move the directory away or "
                   "write the outputs elsewhere")


_OS_ERROR = re.compile(r"os error (\d+)|\[Errno (\d+)\]")  # how Rust (safetensors) and C++ (torch) writers say one
FULL_BYTES = 1 << 20  # a file system with less than this free (bytes) is full: what failed a write there ran out


def disk_full(e: BaseException, folder: Path) -> bool:
    """Whether writer error ``e`` says the disk is full, or ``folder``'s file system is (a writer that reports it
    in its own words: torch's "unexpected pos ...")."""
    if "No space left" in str(e) or "os error 28" in str(e):
        return True
    try:
        st = os.statvfs(folder)
    except OSError:
        return False
    return st.f_bavail * st.f_frsize < FULL_BYTES


class BestEffortStream:
    """A process's stderr whose write failures (``2>/dev/full``, a reader gone) are dropped: the progress bars,
    warnings and notes written there must not stop a run whose results go to files (probe 66: calibrate exited 1
    with nothing written, its runs.json saying 2). stdout: ``GuardedStdout``, whose failure the exit status says."""

    def __init__(self, stream):
        self._stream = stream

    def write(self, text: str) -> int:
        try:
            return self._stream.write(text)
        except (OSError, ValueError) as e:
            self._failed(e)
            return len(text)

    def flush(self) -> None:
        try:
            self._stream.flush()
        except (OSError, ValueError) as e:
            self._failed(e)

    def _failed(self, e: Exception) -> None:
        """A write or flush failed with ``e``: dropped (``GuardedStdout`` says it and records it)."""

    def __getattr__(self, name: str):
        if name == "_stream":  # not set yet (copy.copy): no recursion (probe 70)
            raise AttributeError(name)
        return getattr(self._stream, name)


class GuardedStdout(BestEffortStream):
    """A process's stdout whose first write failure (a reader gone: ``| head -1``; ``> /dev/full``; a full log disk)
    is said once on stderr and recorded (``error``), its output then dropped: the run goes on to write its files, and
    its exit status says the terminal output was lost (``cli``). Probe 119: a failing stdout stopped a fleet after its
    first vehicle and train after its first epoch, a reader gone without a word on stderr; at exit Python printed
    "Exception ignored ... BrokenPipeError" and exit 120 while runs.json said 0."""

    def __init__(self, stream, command: str = "hybrid-calib"):
        super().__init__(stream)
        self.error: OSError | None = None
        self.command = command

    def _failed(self, e: Exception) -> None:
        import sys

        if self.error is not None:
            return
        self.error = e if isinstance(e, OSError) else OSError(errno.EBADF, str(e))
        try:  # what is still buffered for it must not fail again when the interpreter flushes at exit
            os.dup2(os.open(os.devnull, os.O_WRONLY), self._stream.fileno())
        except (OSError, ValueError, AttributeError):
            pass
        self._stream = open(os.devnull, "w")  # noqa: SIM115 (the process' stream, open to its end)
        gone = isinstance(e, BrokenPipeError)
        print(f"{self.command}: warning: its standard output "
              + ("was closed by its reader" if gone else f"cannot be written ({getattr(e, 'strerror', None) or e})")
              + ": the run goes on, its results are in its files; what it would have printed is lost", file=sys.stderr)


def leave_bars() -> bool:
    """Whether an inner progress bar (an epoch's, a vehicle's frames) is left when done: off a terminal, so that each
    ends its line in a log (probe 119: train's log was one line, its bars ended by carriage returns only); on one, it
    is cleared."""
    import sys

    try:
        return not sys.stderr.isatty()
    except (AttributeError, ValueError, OSError):
        return True


def guard_stdout(command: str) -> None:
    """Make this process's ``sys.stdout`` a ``GuardedStdout`` (once)."""
    import sys

    if sys.stdout is not None and not isinstance(sys.stdout, GuardedStdout):
        sys.stdout = GuardedStdout(sys.stdout, f"hybrid-calib {command}")


def exit_with_parent(period_s: float = 2.0) -> None:
    """In a process-pool worker (a pool's ``initializer``): exit when the process that started it is gone. A driver
    killed with -9 left its workers asleep on the pool's queue for ever (a fleet's ~460 MB each, the output log held
    open; simulate's held its output folder's lock, probe 111); what they had finished is in the result files, and
    the next run redoes the job they were on."""
    import threading
    import time

    parent = os.getppid()

    def watch() -> None:
        while os.getppid() == parent:
            time.sleep(period_s)
        os._exit(1)

    threading.Thread(target=watch, name="exit-with-parent", daemon=True).start()


def best_effort_stderr() -> None:
    """Make this process's ``sys.stderr`` a ``BestEffortStream`` (once): the command line's process, and the fleet's
    spawned workers, whose notes to stderr failed their jobs under ``2>/dev/full`` (probe 70)."""
    import sys

    if sys.stderr is not None and not isinstance(sys.stderr, BestEffortStream):
        sys.stderr = BestEffortStream(sys.stderr)


NAME_MAX = 255  # bytes of one file name (Linux, macOS)


def fit_name(name: str, most: int = NAME_MAX) -> str:
    """``name``, or where it is longer than ``most`` bytes (a file name may have ``NAME_MAX``), its first characters, a
    hash of the whole and its last 16: for the names derived from a user's (a temporary file, a page's lock), which a
    legal 250-character page name made too long (probe 66: "File name too long", naming the lock, not the page)."""
    import hashlib

    raw = os.fsencode(name)
    if len(raw) <= most:
        return name
    head = name[:most - 128]  # characters are 1 byte or more: at most these (linear in a long name: probe 70)
    while len(os.fsencode(head)) > most - 128:  # whole characters (a cut multi-byte one is not a name)
        head = head[:-1]
    return f"{head}~{hashlib.sha1(raw).hexdigest()[:12]}~{name[-16:]}"


TEMP_MARK = "hybrid-calib-tmp"  # in every ``atomic_path`` temporary name: "<stem>.<pid>.hybrid-calib-tmp<suffix>"
# what no file of a user's or a frame token of a dataset ends in (probe 93: ".<digits>.tmp" matched a user's
# scene-0001.2.tmp.npz, which evaluate deleted, and a frame whose token ended so, which it left out)
_TEMPORARY = re.compile(r"\.\d+\." + re.escape(TEMP_MARK) + r"(\.[^.]*)?$")


def is_temporary(path: str | Path) -> bool:
    """Whether ``path`` names an ``atomic_path`` temporary file (a write in progress, or one a SIGKILL left, which no
    ``finally`` removed): never a finished file of ours nor a user's (probe 90: a left temporary in ``frames/`` was
    read as one more frame; ``TEMP_MARK``)."""
    return bool(_TEMPORARY.search(Path(path).name))


def finished(paths) -> list[Path]:
    """``paths`` without ``atomic_path``'s temporary files (``is_temporary``), in their order."""
    return [Path(p) for p in paths if not is_temporary(p)]


def remove_temporaries(folder: str | Path) -> list[Path]:
    """Delete the ``atomic_path`` temporary files in ``folder`` (not below it) and return them: for a run that holds
    the folder's lock (``out_dir_lock``), any there is a killed run's, never a writer's at work."""
    folder = Path(folder)
    gone = [p for p in (sorted(folder.iterdir()) if folder.is_dir() else []) if p.is_file() and is_temporary(p)]
    for p in gone:
        p.unlink(missing_ok=True)
    return gone


@contextmanager
def atomic_path(path: str | Path) -> Iterator[Path]:
    """Yield a temporary path for ``path`` (parent folder created); rename it over ``path`` when
    the block exits normally and the writer produced it, delete it when the block raises."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    if path.is_dir():
        raise IsADirectoryError(errno.EISDIR, _IS_A_DIRECTORY.format(path=path), str(path))
    tail = f".{os.getpid()}.{TEMP_MARK}{path.suffix}"  # kept whole, however long the name: ``is_temporary``
    tmp = path.with_name(fit_name(path.stem, NAME_MAX - len(os.fsencode(tail))) + tail)
    try:
        yield tmp
        if not tmp.exists():
            raise OSError(f"writing {path}: the writer produced no file")
        tmp.replace(path)
    except OSError as e:
        if e.filename is not None and str(e.filename) not in (str(tmp), str(path)):
            raise  # about another path (a file the writer read, a parent folder): it names that one
        # no filename: a write into the open temporary file (a full disk: ENOSPC, or numpy's "N requested and M
        # written", which has no errno): about this file too (probe 27: "internal error", naming no file)
        code = e.errno or (errno.EIO if "requested and" not in str(e) else  # cut short: a full disk, or a file-size
                           errno.ENOSPC if disk_full(e, tmp.parent) else errno.EFBIG)  # limit (probe 111: said full)
        what = (_IS_A_DIRECTORY.format(path=path) if path.is_dir() else
                f"{path} cannot be written ({e.strerror or e})")
        raise OSError(code, what, str(path)) from None  # the errno's subclass
    except Exception as e:  # a writer's own error type (safetensors, torch) on a full disk: probe 55's "internal error"
        if disk_full(e, tmp.parent):
            raise OSError(errno.ENOSPC, f"{path} cannot be written: no space left on the device "
                                        f"({type(e).__name__}: {e})", str(path)) from None
        # another system error in the writer's own words: a file-size limit (EFBIG: "os error 27"), a quota, an I/O
        # error (probe 111: internal errors naming no file)
        if (m := _OS_ERROR.search(str(e))) and (code := int(m[1] or m[2])) > 0:
            raise OSError(code, f"{path} cannot be written ({os.strerror(code)}; {type(e).__name__}: "
                                f"{str(e)[:160]})", str(path)) from None
        raise
    finally:
        if tmp.exists():
            tmp.unlink()


def write_bytes_atomic(path: str | Path, data: bytes) -> Path:
    """Write ``data`` to ``path`` atomically; returns the path."""
    with atomic_path(path) as tmp:
        tmp.write_bytes(data)
    return Path(path)


_HELD_LOCKS: set[int] = set()  # the descriptors of the output-folder locks this process holds
_HELD_PATHS: dict[str, int] = {}  # and their paths -> the holding thread: a typed function called by the command that
# holds its lock already (in that thread: probe 142, two threads of one process wrote one folder)


def _drop_held_locks_in_child() -> None:
    """After a fork, in the child: its copies of the parent's lock descriptors point at /dev/null. A ``flock`` lives
    as long as any copy of its descriptor, so a forked worker left alive by a killed run held that run's folder
    locked for ever ("being written by another hybrid-calib run (pid <the dead one>)", probe 111); the number stays
    valid, so nothing else is closed if the child's copy of the file object is ever closed."""
    if not _HELD_LOCKS:
        return
    null = os.open(os.devnull, os.O_RDONLY)
    for fd in _HELD_LOCKS:
        try:
            os.dup2(null, fd)
        except OSError:
            pass
    os.close(null)
    _HELD_LOCKS.clear()
    _HELD_PATHS.clear()


os.register_at_fork(after_in_child=_drop_held_locks_in_child)
_RUN_RECORD = re.compile(r"pid \d+, hybrid-calib \S+, since ")  # what a run writes into its lock file


@contextmanager
def out_dir_lock(out: str | Path, command: str, name: str = LOCK_NAME, what: str | None = None,
                 argv: list[str] | None = None, started: float | None = None, reentrant: bool = False
                 ) -> Iterator[Callable[[], None]]:
    """Hold ``out``'s lock (``OUT/.hybrid-calib.lock``, or ``OUT/name``: an advisory ``flock``, released when the
    process ends, however it ends) while a command writes there, so that two runs into one folder (or onto one file,
    ``what``: report's page) do not overwrite each other's results: the second gets ``OutDirBusy`` naming the first
    (its pid, command and start). ``out`` is created if missing and, when the block leaves nothing in it, removed
    again; the lock file is removed at the end (while still held) when this run created it or a killed run left it
    (it holds a run's record); another file of that name is left as it was. With ``argv`` (the command line as typed)
    the lock also holds the run's start, and a run that finds a killed run's lock (SIGKILL, the OOM killer, a machine
    that went down: nothing of that run could say so) adds that run to ``OUT/runs.json`` with exit status null
    (``record_run``; probe 60: such runs were missing from it); ``started``: the run's start as its own line in
    runs.json will say (a run killed after writing that line is not added twice). Yields a function to call once the
    run's own line is in runs.json: the lock then no longer holds the command line.

    The typed functions that write a folder (``hybrid.run_calibration``, ``compare.compare``, ``fleet.run_fleet``,
    ``sim.simulate.simulate``) hold it too (probe 140: a library run and a command wrote one
    folder, and the command's result was replaced in silence), with ``reentrant``: a lock this process holds already
    is the command's that called them, and they go on under it."""
    import json
    import time

    out = Path(out)
    created = not out.exists()
    out.mkdir(parents=True, exist_ok=True)
    path = out / name
    if path.is_symlink() or (path.exists() and not path.is_file()):  # a link's target would be overwritten
        kind = "a symbolic link" if path.is_symlink() else "a directory" if path.is_dir() else "a special file"
        raise HybridCalibError(f"{path} is {kind}, not the lock file hybrid-calib keeps in its output folder; "
                               "remove it and rerun")
    key = str(out.resolve() / name)
    if reentrant and _HELD_PATHS.get(key) == threading.get_ident():  # the command around the typed function
        yield lambda: None
        return
    existed = path.exists()
    f = _locked_file(path, what or out)
    _HELD_LOCKS.add(f.fileno())
    _HELD_PATHS[key] = threading.get_ident()
    first = f"pid {os.getpid()}, hybrid-calib {command}, since {time.strftime('%Y-%m-%d %H:%M:%S')}"
    was = None  # what the file held before (restored at the end when it is not a run's lock)
    try:
        f.seek(0)
        was = f.read()
        text = was[: 1 << 16].decode("utf-8", "replace")
        stale = _RUN_RECORD.match(text)  # a killed run's (probe 60: left behind by every later run)
        existed = existed and not stale
        if stale and name == LOCK_NAME:
            _record_killed(out, text)
        _rewrite(f, path, first + ("" if argv is None else "\n" + json.dumps(
            {"command": command, "argv": [str(a) for a in argv], "cwd": os.getcwd(),
             "started": time.time() if started is None else started})))
        # the run's own line in runs.json is written: the lock no longer names it as a run to record if killed now
        # (probe 65: killed between the two, it was listed twice)
        yield lambda: _rewrite(f, path, first)
    finally:
        try:  # unlinked while still held: a run that opened it meanwhile finds it locked and stops (no two holders)
            if not existed:  # a refused run left it in the user's data root ("refusing to write anything there")
                path.unlink()
            elif was is not None:  # not ours: as it was (with this run's record in it, the next run took this one
                f.seek(0)  # for killed)
                f.truncate()
                f.write(was)
                f.flush()
            if created and not any(out.iterdir()):
                out.rmdir()
        except OSError:
            pass
        _HELD_LOCKS.discard(f.fileno())
        _HELD_PATHS.pop(key, None)
        try:
            f.close()
        except OSError:  # the record it could not write (a full disk) was said where it was written (_rewrite)
            pass


def _locked_file(path: Path, what):
    """The lock file at ``path`` opened (binary) and ``flock``ed exclusively, or ``OutDirBusy`` naming its holder.
    A holder unlinks the file at its end while still holding it: a run that opened it just before and locks it just
    after would hold a file no longer at the path while the next run locks a new one (probe 140: two holders), so
    the file locked must be the one at the path (else it is opened again)."""
    import fcntl

    for _ in range(100):
        # bytes: a lock file is anyone's (probe 65: one of non-UTF-8 bytes was an internal error)
        f = os.fdopen(os.open(path, os.O_RDWR | os.O_CREAT | os.O_NOFOLLOW, 0o644), "r+b")
        try:
            fcntl.flock(f, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except OSError:
            f.seek(0)
            holder = f.read(1 << 16).decode("utf-8", "replace").strip().split("\n")[0] or "another process"
            f.close()  # its first line (the second: the command line)
            raise OutDirBusy(f"{what} is being written by another hybrid-calib run ({holder}); wait for it to "
                             "end, or write elsewhere (another --out)") from None
        held = os.fstat(f.fileno())
        try:
            now = os.stat(path, follow_symlinks=False)
        except FileNotFoundError:
            now = None
        if now is not None and (now.st_ino, now.st_dev) == (held.st_ino, held.st_dev):
            return f
        f.close()  # the file its last holder unlinked: open the one at the path now
    raise OutDirBusy(f"{what}: its lock file {path} keeps being replaced; wait for the other hybrid-calib runs "
                     "there to end, or write elsewhere (another --out)")


def _rewrite(f, path: Path, text: str) -> None:
    """Replace the content of the open lock file ``f`` (binary) at ``path`` with ``text``; an ``OSError`` names
    ``path`` (probe 84: on a full disk every command said "cannot write to its output", naming no file)."""
    try:
        f.seek(0)
        f.truncate()
        f.write(text.encode("utf-8"))
        f.flush()
    except OSError as e:
        raise OSError(e.errno, e.strerror, str(path)) from None


def _record_killed(out: Path, lock_text: str) -> None:
    """Add the run whose lock ``lock_text`` a killed run left (its second line: its command, argv, working folder and
    start, as ``out_dir_lock`` writes them) to ``OUT/runs.json`` with exit status null; nothing when the lock does not
    say (an older run's) or runs.json cannot be written (it is a log)."""
    import json

    try:
        run = json.loads(lock_text.split("\n", 1)[1])
        record_run(out, str(run["command"]), [str(a) for a in run["argv"]], None, float(run["started"]),
                   cwd=str(run["cwd"]))
    except (IndexError, ValueError, KeyError, TypeError, OSError, OverflowError):  # a lock edited by hand
        pass


RUNS_KEPT = 200  # the newest records kept


def record_run(out: str | Path, command: str, argv: list[str], status: int | None, started: float,
               cwd: str | None = None) -> Path | None:
    """Append what ran into ``out`` to ``OUT/runs.json`` (a JSON list, oldest first, the newest ``RUNS_KEPT``): the
    command line as typed, the working folder it was typed in, the start and end (UTC, ISO 8601), its exit status,
    the hybrid-calib and Python versions and the host. A folder's results then say which command made them, when,
    and which runs resumed them. Not a configuration: nothing compares it (each command's own record does that).
    ``status`` None: a run that was killed without a word (``out_dir_lock`` found its lock): its end and exit status
    are null and ``ended`` says so. A record that cannot be read is kept aside as ``runs.damaged.json`` and a new one
    started (said nowhere: it is a log; probe 109 found the history lost); returns its path, None when ``out`` is
    not a folder."""
    import json
    import platform
    import shlex
    import time

    import hybrid_calib

    out = Path(out)
    if not out.is_dir():
        return None
    path = out / RUNS_NAME
    try:
        runs = json.loads(path.read_text())
        if not isinstance(runs, list):
            raise ValueError("not a list")
    except (OSError, ValueError, RecursionError):
        runs = []
        if path.is_file():  # the history kept, not overwritten
            try:
                os.replace(path, path.with_name("runs.damaged.json"))
            except OSError:
                pass

    def utc(t: float) -> str:
        return time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime(t))

    killed = {} if status is not None else {
        "ended": f"without a word (killed: SIGKILL, out of memory or the machine went down); the run started at "
                 f"{utc(time.time())} found its lock"}
    line = " ".join(["hybrid-calib", *map(shlex.quote, argv)])
    if killed and any(isinstance(r, dict) and (r.get("command"), r.get("cwd"), r.get("started_utc")) ==
                      (line, cwd or os.getcwd(), utc(started)) for r in runs):
        return path  # its own line is there: it was killed after writing it (probe 65: it was listed twice)
    runs.append({"command": line, "cwd": cwd or os.getcwd(),
                 "started_utc": utc(started), "finished_utc": None if killed else utc(time.time()),
                 "exit_status": None if killed else int(status), **killed,
                 "hybrid_calib": hybrid_calib.__version__, "python": platform.python_version(),
                 "host": platform.node()})
    return write_bytes_atomic(path, (json.dumps(runs[-RUNS_KEPT:], indent=2) + "\n").encode("utf-8"))


class OutDirBusy(HybridCalibError):
    """Another run holds the output folder's lock (``out_dir_lock``); the command line turns it into an error."""
