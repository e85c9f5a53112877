"""``hybrid-calib``: one command with subcommands, a thin layer over typed functions.

The error boundary is here, in one place: ``main`` turns every expected failure (a
``HybridCalibError``: bad data, a bad option, a bad checkpoint; an ``OSError`` naming a file; a full or failing
output; an option given twice) into one line ``hybrid-calib COMMAND: error: ...`` on stderr and exit status 2 (a
reader that has gone, ``| head``: quietly, 141; Ctrl-C: 130, saying what is kept). Anything else is a bug:
one line naming the exception and asking for a rerun with ``--debug`` (exit status 3). ``--debug``
(or ``HYBRID_CALIB_DEBUG=1``) lets every exception through with its traceback.
"""

from __future__ import annotations

import argparse
import errno
import importlib
import os
import re
import signal
import sys
import threading
import warnings
from pathlib import Path

from hybrid_calib.atomic import (
    LOCK_NAME,
    GuardedStdout,
    best_effort_stderr,
    finished,
    guard_stdout,
    out_dir_lock,
    record_run,
)
from hybrid_calib.errors import (
    HybridCalibError,
    check_not_being_written,
    check_out_dir,
    check_out_files,
    check_out_not_in_dataset,
    check_out_owner,
    check_runs_record,
    stop_signal_of,
)

# subcommand name -> module in hybrid_calib.commands (each has HELP, add_arguments, run).
COMMANDS: dict[str, str] = {
    "simulate": "simulate",
    "demo": "demo",
    "inspect": "inspect",
    "train": "train",
    "evaluate": "evaluate",
    "calibrate": "calibrate",
    "report": "report",
    "export": "export",
    "fleet": "fleet",
    "compare": "compare",
}

EXIT_ERROR = 2  # an expected failure, explained in one line (argparse uses 2 for usage errors too)
EXIT_BUG = 3  # an unexpected exception: rerun with --debug and report it


# what an interrupted command keeps, and how it goes on
RESUMES = {
    "calibrate": "the vehicles it finished are kept in --out/vehicles-done: rerun the same command to go on from there",
    "compare": "the trials it finished are kept in --out: rerun the same command to go on from there",
    "fleet": "the vehicles it finished are kept in --out (manifest.json): rerun the same command to go on",
    "train": "its last checkpoint is kept in --out: rerun the same command to resume training",
    "simulate": "the frames it wrote are kept: rerun the same command to go on",
    "evaluate": "the frames it exported are kept in --out: rerun the same command to go on from there",
}


class Terminated(KeyboardInterrupt):
    """SIGTERM (``kill``, ``timeout``, ``docker stop``, systemd, a batch scheduler's pre-emption): the run stops as
    Ctrl-C stops it (what it finished kept, its exit status in ``OUT/runs.json``, its lock released), exit 143. It
    had died at once, without a word, a line in runs.json or its lock released (probe 47)."""


_SIGTERM_SEEN: list[int] = [0]  # the stopping signal this run got (SIGTERM, SIGHUP: ``terminated``), or 0
# SIGHUP: the terminal or ssh session closed; it stops the run as SIGTERM does (probe 119: it died without its line, the
# lock left, runs.json later saying "killed: SIGKILL, out of memory or the machine went down")
_STOPPING = tuple(s for s in (signal.SIGTERM, getattr(signal, "SIGHUP", None)) if s is not None)


def _on_sigterm(signum, frame):
    _SIGTERM_SEEN[0] = signum
    raise Terminated


def terminated(error: BaseException | None) -> bool:
    """Whether ``error`` ends a run that got SIGTERM: ``Terminated``, or the ``KeyboardInterrupt`` a library turned it
    into (Ray's wait raises its own when a signal handler raised; probe 91: a fleet on Ray read "interrupted", 130)."""
    return isinstance(error, Terminated) or (isinstance(error, KeyboardInterrupt) and bool(_SIGTERM_SEEN[0]))


def _quiet_stopped_workers(unraisable) -> None:
    """``sys.unraisablehook`` of a command: a DataLoader worker that the group's signal ended is not said again, as an
    18-line traceback from the loader's ``__del__`` before the run's "terminated" line (probe 111); a Ctrl-C, SIGTERM or
    SIGHUP whose handler raised inside a ``__del__`` or weakref callback, where Python drops what is raised, is
    delivered again to the main thread, so it stops the run (probe 124: "Exception ignored in: <function WeakSet...>
    KeyboardInterrupt", and the fleet went on to write every page and exit 0); anything else as Python says it."""
    error = unraisable.exc_value
    if isinstance(error, KeyboardInterrupt):  # Terminated included: the signal its handler saw
        signum = _SIGTERM_SEEN[0] if isinstance(error, Terminated) and _SIGTERM_SEEN[0] else signal.SIGINT
        # from another thread, a moment later: delivered from this one, the handler raises inside this hook at once
        # and is dropped again; one that lands in another callback comes back here and is delivered again
        timer = threading.Timer(0.01, _interrupt_main, (signum,))
        timer.daemon = True
        timer.start()
        return
    if stop_signal_of(error) is None:
        sys.__unraisablehook__(unraisable)


def _interrupts_stop_the_run(unraisable) -> None:
    """``sys.unraisablehook`` under ``--debug``: a Ctrl-C, SIGTERM or SIGHUP raised inside a ``__del__`` delivered
    again (``_quiet_stopped_workers``), everything else as Python says it."""
    if isinstance(unraisable.exc_value, KeyboardInterrupt):
        _quiet_stopped_workers(unraisable)
    else:
        sys.__unraisablehook__(unraisable)


def _interrupt_main(signum: int) -> None:
    """``signum``'s Python handler run in the main thread at its next instruction (``_thread.interrupt_main``)."""
    import _thread

    _thread.interrupt_main(signum)


def _one_line(message, category, filename, lineno, line=None) -> str:
    """``warnings.formatwarning`` for the command line: ``warning: MESSAGE`` (``--debug``: Python's own)."""
    return f"warning: {message}\n"


def _has_vehicles_done(out: Path) -> bool:
    """Whether a calibrate run's ``out`` keeps a vehicle an interrupted run finished (``calib.result.VehicleProgress``:
    ``out/vehicles-done/<vehicle>.json`` beside its ``stamp.json``)."""
    try:
        return any(p.name != "stamp.json" for p in finished((out / "vehicles-done").glob("*.json")))
    except OSError:
        return False


def _has_checkpoint(out: Path) -> bool:
    """Whether a train run's ``out`` holds a checkpoint to resume from (``learned.train``: ``out/checkpoints``)."""
    from learned.checkpoint import latest_checkpoint

    try:
        return latest_checkpoint(out / "checkpoints") is not None
    except OSError:  # an unreadable folder: the interrupt message must not fail
        return False


CACHE_KEYS = ("cache_dir", "depth_cache")  # --set keys naming a folder the run writes (at any depth: hybrid.cache_dir)


def set_paths(args: argparse.Namespace) -> list[tuple[str, str]]:
    """[(option, path)] of the folders a command's ``--set`` names for its caches (``CACHE_KEYS``); [] when the
    ``--set`` items do not parse (the command says why)."""
    from hybrid_calib.config import parse_overrides

    try:
        overrides = parse_overrides(getattr(args, "set", None) or getattr(args, "overrides", None) or [])
    except Exception:  # noqa: BLE001 - a malformed --set is the command's own error, said by it
        return []
    found: list[tuple[str, str]] = []

    def walk(d: dict, prefix: str) -> None:
        for k, v in d.items():
            if isinstance(v, dict):
                walk(v, f"{prefix}{k}.")
            elif k in CACHE_KEYS and isinstance(v, str) and v:
                found.append((f"--set {prefix}{k}", v))

    walk(overrides, "")
    return found


PATH_OPTIONS = {"--out", "--data", "--prior", "--manifest", "--checkpoint", "--depth", "--refine", "--correspondences",
                "--ray-temp", "--depth-cache"}  # an empty one read as the current folder, or as "not given"


def gathering_options(parser: argparse.ArgumentParser) -> set[str]:
    """The options of a command's ``parser`` that may be given twice and lose nothing: those that gather every value
    (argparse ``append`` / ``extend``: ``--set``, evaluate's ``--refine``, export's ``--vehicle``) and the flags that
    take none (``--no-plots`` twice is ``--no-plots``; probe 107); any other option keeps its last value only."""
    return {name for a in parser._actions
            if isinstance(a, (argparse._AppendAction, argparse._ExtendAction, argparse._StoreConstAction))
            for name in a.option_strings}


def _option_name(name: str, parser: argparse.ArgumentParser | None) -> str:
    """The option ``name`` stands for in ``parser`` (argparse takes an unambiguous prefix: ``--vehic`` is
    ``--vehicle``), its longest spelling; ``name`` itself where the parser has no one option it begins."""
    if parser is None:
        return name
    actions = parser._option_string_actions
    found = {id(a): a for o, a in actions.items() if o == name} or \
        {id(a): a for o, a in actions.items() if o.startswith(name) and o.startswith("--")}
    return max(next(iter(found.values())).option_strings, key=len) if len(found) == 1 else name


def _repeated_or_empty(argv: list[str], parser: argparse.ArgumentParser | None = None) -> str:
    """Why the command line cannot mean what it says ("" when it can): an option given twice keeps only its last
    value in argparse (``simulate --out a --out b`` wrote b alone; ``--data A --data B`` read B; probe 105:
    ``calibrate --refine A --refine B`` ran B alone, ``report --vehicle A --vehicle B`` reported B) unless the
    command's option gathers them (``gathering_options`` of its ``parser``; without one, ``--set`` alone), and an
    empty path reads as the current folder ("--out '': . is not empty"; probe 27). With the command's ``parser`` an
    abbreviation counts as the option it stands for (probe 106: ``--vehicle A --vehic B`` reported B, ``--veh A --veh
    B`` of export was refused)."""
    repeatable = gathering_options(parser) if parser is not None else {"--set"}
    seen: set[str] = set()
    for k, token in enumerate(argv):
        if token == "--":
            break
        if token == "":  # an option's value or a positional path: "" read as the current folder or the default
            before = argv[k - 1] if k else ""
            if before.startswith("--") and "=" not in before:
                return f"{before} is empty; pass a {'path' if before in PATH_OPTIONS else 'value'}"
            return "an argument is empty (''); pass the path or value it stands for"
        if not token.startswith("--") or len(token) < 3:
            continue
        typed, eq, value = token.partition("=")
        name = _option_name(typed, parser)
        if name in seen and name not in repeatable:
            return (f"{name} is given twice{'' if typed == name else f' (as {typed})'}; give it once (argparse would "
                    "keep only the last value" + ("; several roots go after one --data" if name == "--data" else "")
                    + ")")
        seen.add(name)
        if name in PATH_OPTIONS and eq and value == "":  # --out='' (the spaced form is the empty token's above)
            return f"{name} is empty; pass a path"
    return ""


_DASHED: list[str] = []  # the command line's values that read as options: a path starting with "-" (``_Parser``)


class _Parser(argparse.ArgumentParser):
    """argparse's parser, whose errors name a path that starts with "-" where there is one (probe 119: `export
    -x/result.json` read "the following arguments are required: RESULT", one being given)."""

    def error(self, message: str):
        if _DASHED:
            message += (f" ({_DASHED[0]} starts with '-', so it was read as an option: write ./{_DASHED[0]}, or give "
                        "it after --)")
        super().error(message)


def build_parser() -> argparse.ArgumentParser:
    parser = _Parser(
        prog="hybrid-calib", description="Target-free radar-camera extrinsic calibration.")
    sub = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")
    for name, module in COMMANDS.items():
        mod = importlib.import_module(f"hybrid_calib.commands.{module}")
        p = sub.add_parser(name, help=mod.HELP, description=mod.HELP)
        mod.add_arguments(p)
        p.add_argument("--debug", action="store_true", help="show the full traceback of any error")
        p.set_defaults(_run=mod.run, _parser=p)
    return parser


def _parse(argv: list[str] | None) -> argparse.Namespace:
    """The command line, an option the command does not have said by that command's parser (its usage, "hybrid-calib
    evaluate: error: unrecognized arguments: --no-plots"), not the top level's (probe 100)."""
    words = sys.argv[1:] if argv is None else [str(a) for a in argv]
    _DASHED[:] = [w for w in words if w.startswith("-") and not w.startswith("--") and ("/" in w or re.search(
        r"\.(json|html?|npz)$", w))]
    args, extra = build_parser().parse_known_args(argv)
    if extra:
        args._parser.error(f"unrecognized arguments: {' '.join(extra)}")
    return args


def main(argv: list[str] | None = None) -> int:
    for name in ("stdout", "stderr"):  # a closed stream (`2>&-`): Python sets it to None, every print and bar failed
        if getattr(sys, name) is None:
            setattr(sys, name, open(os.devnull, "w"))  # noqa: SIM115 (the process' stream, open to its end)
    if argv is None:  # the process's own stderr (a caller of main(argv) keeps its own)
        best_effort_stderr()
    args = _parse(argv)
    if argv is None:  # its stdout failing loses only what it prints (atomic.GuardedStdout)
        for stream in (sys.stdout, sys.stderr):  # a name the terminal's encoding cannot show is shown escaped
            try:  # (probe 119: PYTHONIOENCODING=ascii made "wrote 数据/result.json" an internal error)
                stream.reconfigure(errors="backslashreplace")
            except (AttributeError, ValueError, OSError):
                pass
        guard_stdout(args.command)
    if problem := _repeated_or_empty(sys.argv[1:] if argv is None else [str(a) for a in argv], args._parser):
        print(f"hybrid-calib {args.command}: error: {problem}", file=sys.stderr)
        return EXIT_ERROR
    debug = args.debug or os.environ.get("HYBRID_CALIB_DEBUG", "") not in ("", "0")
    before, unraisable = warnings.formatwarning, sys.unraisablehook
    if not debug:  # a warning is one line, as every other message: not our source file and line after it
        warnings.formatwarning = _one_line
    # --debug too: an interrupt raised inside a __del__ stops the run (probe 127); the rest as Python says it there
    sys.unraisablehook = _quiet_stopped_workers if not debug else _interrupts_stop_the_run
    term, _SIGTERM_SEEN[0] = None, 0
    if threading.current_thread() is threading.main_thread():  # signal handlers live in the main thread only
        # a SIGHUP that is ignored stays so: nohup's run outlives its terminal
        term = {s: signal.signal(s, _on_sigterm) for s in _STOPPING
                if s == signal.SIGTERM or signal.getsignal(s) != signal.SIG_IGN}
    args._process = argv is None and term is not None  # the process's own command line (not a caller's main(argv))
    try:
        return _run(args, debug, sys.argv[1:] if argv is None else [str(a) for a in argv])
    finally:
        warnings.formatwarning, sys.unraisablehook = before, unraisable
        if term is not None and not args._process:
            for s, handler in term.items():
                signal.signal(s, handler)


POSITIONAL = {"out_html": "--out", "result": "RESULT", "results": "RESULT"}  # dest -> the name the user typed
# the options that name files or folders (those typed as ``Path`` too): where '~' and '-' are said as paths
PATH_DESTS = ("out", "out_html", "data", "checkpoint", "refine", "correspondences", "reference", "manifest", "prior",
              "result", "results", "init", "ray_temp")


def check_text_arguments(args: argparse.Namespace) -> None:
    """``OptionError`` naming the option whose value (any text, ``--set`` items too) is not valid UTF-8, or
    ``HybridCalibError`` naming the working folder when that is what is not (a relative path, a checkpoint's name, a
    cache named by ``--set`` all lie below it; the run's record names it): a folder named in another encoding (Latin-1
    bytes from an old archive) or any non-ASCII name under an ASCII (C) locale reaches Python as lone surrogates,
    which OpenCV's native code crashed on (probe 66: exit 139, no word, a half-written root and a lock left) and which
    no JSON record can hold as typed. The advice follows the cause: bytes that are UTF-8 read under another locale
    (``PYTHONUTF8=1`` reads them), or bytes that are not (rename; probe 69: the locale was advised for both). A
    working folder that is gone is not checked (probe 70: an internal error even with absolute paths)."""
    from hybrid_calib.errors import OptionError

    def bad(text: str) -> bool:
        try:
            text.encode("utf-8")
            return False
        except UnicodeEncodeError:
            return True

    def advice(text: str) -> str:
        raw = text.encode("utf-8", "surrogateescape")
        try:
            raw.decode("utf-8")
            return "run in a UTF-8 locale (PYTHONUTF8=1): the name is UTF-8, read in another encoding"
        except UnicodeDecodeError:
            return "rename it to UTF-8 (its name is in another encoding, shown with its bytes as \\xNN)"

    def shown(text: str) -> str:
        return text.encode("utf-8", "surrogateescape").decode("utf-8", "backslashreplace")

    try:
        cwd = os.getcwd()
    except OSError:  # deleted under the shell: every command records where it ran (the lock, runs.json), and torch
        # cannot load from there (probe 111: internal errors, an MKL fatal error and no word of ours)
        raise HybridCalibError("the working folder no longer exists (it was deleted after this shell entered it): cd "
                               "to an existing folder and rerun") from None
    if bad(cwd):
        raise HybridCalibError(f"the working folder {shown(cwd)} is not valid UTF-8: {advice(cwd)}, or run from "
                               "another folder")
    for dest, value in vars(args).items():
        if dest.startswith("_") or dest == "argv":
            continue
        for v in value if isinstance(value, (list, tuple)) else (value,):
            if not isinstance(v, (str, Path)):
                continue
            option = POSITIONAL.get(dest, "--" + dest.replace("_", "-"))
            if bad(str(v)):
                raise OptionError(option, f"{shown(str(v))} is not valid UTF-8: {advice(str(v))}")
            if not (isinstance(v, Path) or dest in PATH_DESTS):  # a name (a vehicle, a channel) may hold them
                continue
            if str(v) == "-":  # the usual "standard output": a folder or file named "-" was made
                raise OptionError(option, "'-' (standard output or input) is not a path this command takes: pass a "
                                          "file or folder name (./- for one named '-')")
            first = str(v).split("/")[0]
            if re.match(r"~[\w.-]*$", first) and not Path(first).exists():
                # the shell expands ~ only at a word's start (not in --out=~/x) and unquoted: a folder named "~" was
                # made in the working folder, and "wrote ~/x/result.json" read as the home folder (probe 119)
                home = os.path.expanduser(str(v))
                raise OptionError(option, f"{v} starts with '~', which the shell did not expand (it does not in "
                                          f"{option}=~/... nor in quotes): pass {option} {v} with a space"
                                          + (f", or the full path ({home})" if home != str(v) else
                                             f" ({first} names no user here)")
                                          + f"; a folder named {first!r} here is ./{v}")


def _ran(args: argparse.Namespace) -> int:
    """The command's exit status, after its output is flushed: 141 (a reader gone, as a shell reports a command a pipe
    ended) or ``EXIT_ERROR`` (a full or failing device) where its standard output failed and it would have returned 0
    (``atomic.GuardedStdout``: the run went on, its files are complete; runs.json records this status too)."""
    status = int(args._run(args) or 0)
    out = sys.stdout
    if isinstance(out, GuardedStdout):
        out.flush()
        if out.error is not None and status == 0:
            return 141 if isinstance(out.error, BrokenPipeError) else EXIT_ERROR
    return status


def _finished(args: argparse.Namespace) -> None:
    """The run's work is done and its exit status recorded: Ctrl-C or SIGTERM from here to the process's end must not
    turn it into "interrupted" (probe 60: export exited 130, with no word, while its runs.json said 0). Only for the
    process's own command line: a caller of ``main(argv)`` keeps its signals."""
    if getattr(args, "_process", False):
        for s in (signal.SIGINT, *_STOPPING):
            signal.signal(s, signal.SIG_IGN)  # (SIGHUP's end is nohup's, where it was ignored already)


def _run(args: argparse.Namespace, debug: bool, argv: list[str]) -> int:
    """The command, inside the error boundary (module doc). A command that returns, or fails after writing into its
    output folder, appends its command line and exit status to ``OUT/runs.json`` (``atomic.record_run``; not
    simulate's root, not report's page). ``args.argv``: the arguments as typed (``main(argv)``'s, not the Python
    process's: compare.md named pytest's arguments as its command)."""
    import time

    args.argv = argv

    out = getattr(args, "out", None)
    try:
        check_text_arguments(args)
        if args.command == "report":  # --out is the page (a file), written atomically
            check_out_dir(None if out is None else Path(out).parent)
            status = _ran(args)
            _finished(args)
            return status
        check_out_dir(out)
        data, version = getattr(args, "data", None), getattr(args, "version", None)
        # simulate's --out is the root it writes
        check_out_not_in_dataset(out, root_ok=args.command == "simulate", data=data, version=version)
        if args.command != "simulate":  # what it reads: not while another run writes it (probe 140)
            check_not_being_written(data, "--data")
            check_not_being_written(getattr(args, "correspondences", None), "--correspondences")
        for option, path in set_paths(args):  # caches named by --set: the same rule as --out, before anything runs
            check_out_dir(path, option)  # an existing file there: no cache was written, without a word (probe 27)
            check_out_not_in_dataset(path, option, data=data, version=version)
        check_out_owner(out, args.command)
        check_out_files(out, args.command, getattr(args, "overwrite", None))
        if args.command != "simulate":  # simulate's root has no runs.json
            check_runs_record(out)
        if out is None:
            status = _ran(args)
            _finished(args)
            return status
        # the lock holds the command line, for runs.json when the run is killed (not simulate's root: no runs.json)
        started = time.time()
        with out_dir_lock(out, args.command, argv=None if args.command == "simulate" else argv,
                          started=started) as recorded:
            status, before = None, _listing(Path(out))
            try:
                status = _ran(args)
                return status
            finally:  # also a run that failed or was interrupted after writing something (not one refused before
                # it wrote: its folder is as it was): its line says how it ended
                if status is not None:
                    _finished(args)
                after = _listing(Path(out))
                if args.command != "simulate" and after and (status is not None or after != before):
                    error = sys.exc_info()[1]
                    try:
                        record_run(out, args.command, argv, _exit_status(status, error), started)
                        recorded()
                    except OSError as e:
                        if error is None:  # what the run wrote is complete: said, not failed (probe 86: export's
                            # "a rerun resumes", and the rerun refused the complete export it found)
                            print(f"hybrid-calib {args.command}: warning: it finished (exit status {status}) and what "
                                  f"it wrote is complete, but its line in {Path(out) / 'runs.json'} could not be "
                                  f"written ({e.strerror or e})", file=sys.stderr)
                            try:
                                recorded()  # the lock no longer names it as a run killed before its line
                            except OSError:
                                pass
    except BrokenPipeError:  # `| head -1`: the reader has gone; nothing more to say, and nowhere to say it
        _stdout_to_devnull()
        return 141  # 128 + SIGPIPE, as a shell reports a command a pipe ended
    except KeyboardInterrupt as e:
        if debug:
            raise
        kept = RESUMES.get(args.command)
        if args.command == "train" and out is not None and not _has_checkpoint(Path(out)):
            kept = "it stopped before its first checkpoint, so nothing is kept: rerun the same command to start again"
        if args.command == "calibrate" and out is not None and not _has_vehicles_done(Path(out)):
            # the network's and the depth's caches in --out are kept and a rerun reads them (probe 47)
            # only the network's methods cache (probe 124: "what it cached is reused" after an oracle run)
            learned = getattr(args, "method", None) in ("hybrid", "pure", "pure-avg")
            kept = ("it stopped before a vehicle finished, so no vehicle's result is kept: rerun the same command to "
                    "start again (an earlier run's result, if any, is as it was"
                    + ("; the network passes and depth it cached in --out are reused)" if learned else ")"))
        how = ("interrupted" if not terminated(e) else "terminated (SIGHUP: its terminal closed; run it under nohup, "
               "tmux or screen to outlive the session)" if _SIGTERM_SEEN[0] == getattr(signal, "SIGHUP", -1) else
               "terminated (SIGTERM)")
        _close_bars()
        print(f"hybrid-calib {args.command}: {how}" + (f"; {kept}" if kept else ""), file=sys.stderr)
        return _exit_status(None, e)
    except Exception as e:
        if debug:
            raise
        return report_error(args.command, e)


def _close_bars() -> None:
    """Close the progress bars still open, so that the interrupt's line is the last the user sees (probe 60: fleet's
    and simulate's bars were drawn once more after it, when the interrupted run's objects were collected)."""
    try:
        from tqdm import tqdm
    except ImportError:
        return
    for bar in list(getattr(tqdm, "_instances", ())):
        try:
            bar.close()
        except Exception:  # noqa: BLE001 (a bar that cannot draw any more: nothing to close)
            pass


def _listing(out: Path) -> dict[str, int]:
    """The top of an output folder, its lock aside: entry -> modification time (ns); a folder written into changes."""
    try:
        return {p.name: p.stat().st_mtime_ns for p in out.iterdir() if p.name != LOCK_NAME}
    except OSError:
        return {}


def _exit_status(status: int | None, error: BaseException | None) -> int:
    """The exit status a run ends with: ``status`` when it returned, else the one its exception gets below."""
    if status is not None or error is None:
        return int(status or 0)
    if terminated(error):  # 128 + the signal, as a shell reports a command it ended (143 SIGTERM, 129 SIGHUP)
        return 128 + int(_SIGTERM_SEEN[0] or signal.SIGTERM)
    if isinstance(error, KeyboardInterrupt):
        return 130
    if isinstance(error, BrokenPipeError):
        return 141
    return EXIT_ERROR if isinstance(error, (HybridCalibError, OSError)) else EXIT_BUG


def _stdout_to_devnull() -> None:
    """Point the process' standard output at /dev/null: what is still buffered for a reader that has gone (or a full
    disk) must not fail again, as a traceback, when the interpreter flushes it at exit."""
    try:
        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
    except (OSError, ValueError, AttributeError):
        pass


def report_error(command: str, e: Exception) -> int:
    """Print one line for ``e`` (no traceback) and return the exit status (``EXIT_ERROR`` or ``EXIT_BUG``)."""
    if isinstance(e, HybridCalibError):  # one paragraph: a message quoting a library's may span lines
        message = re.sub(r"\s*\n\s*", " ", str(e))
        print(f"hybrid-calib {command}: error: {message}", file=sys.stderr)
        return EXIT_ERROR
    if isinstance(e, (FileExistsError, NotADirectoryError)) and e.filename:  # mkdir where a file lies (probe 27)
        print(f"hybrid-calib {command}: error: {e.filename} (or a folder above it) is a file where a folder is "
              f"needed ({e.strerror or e}); move the file away, or pass another path", file=sys.stderr)
        return EXIT_ERROR
    if isinstance(e, OSError) and e.filename and e.errno in (errno.ENOSPC, errno.EDQUOT):
        print(f"hybrid-calib {command}: error: no space left on the device while writing {e.filename}; free space "
              "there or pass another output path (what was written before is kept: every file is replaced whole or "
              "not at all, and a rerun resumes)", file=sys.stderr)
        return EXIT_ERROR
    if isinstance(e, OSError) and e.filename and e.errno == errno.EFBIG:  # probe 111: "check ... permissions"
        print(f"hybrid-calib {command}: error: {e.strerror or e} [file {e.filename}]; a file-size limit was hit "
              "(`ulimit -f`, or the file system's largest file): raise it or pass another output path (what was "
              "written before is kept, and a rerun resumes)", file=sys.stderr)
        return EXIT_ERROR
    if isinstance(e, OSError) and e.filename:
        print(f"hybrid-calib {command}: error: {e.strerror or e} [file {e.filename}]; check the path and its "
              "permissions", file=sys.stderr)
        return EXIT_ERROR
    if isinstance(e, OSError) and e.errno in (errno.ENOSPC, errno.EIO, errno.EPIPE, errno.EBADF):  # `> /dev/full`
        _stdout_to_devnull()
        print(f"hybrid-calib {command}: error: cannot write to its output ({e.strerror or e}): the disk or device "
              "its files or its standard output go to is full or failing; free space there, or write elsewhere",
              file=sys.stderr)
        return EXIT_ERROR
    if isinstance(e, UnicodeEncodeError) and sys.getfilesystemencoding().lower() not in ("utf-8", "utf8"):
        print(f"hybrid-calib {command}: error: a name holds characters this process's file-system encoding "
              f"({sys.getfilesystemencoding()}) cannot hold ({e.object[e.start:e.end]!r}, in a path read from a "
              "file or a table): run in a UTF-8 locale (PYTHONUTF8=1)", file=sys.stderr)
        return EXIT_ERROR
    print(f"hybrid-calib {command}: internal error: {type(e).__name__}: {e}\n"
          f"  this looks like a bug (or an input not checked yet); rerun with --debug for the traceback and "
          "report it", file=sys.stderr)
    return EXIT_BUG


if __name__ == "__main__":
    sys.exit(main())
