"""One module per ``hybrid-calib`` subcommand; each defines ``HELP``, ``add_arguments(parser)`` and
``run(args) -> int``. The modules are thin: they parse arguments and call typed functions."""

import argparse


def positive_int(text: str) -> int:
    """argparse ``type``: an integer >= 1 (a count such as frames, vehicles, workers, sweeps)."""
    return _int_at_least(text, 1)


MAX_PROCESSES = 256  # --workers / --threads: more than any machine this runs on has cores (a pool of 1e9 forked 1e9)


def process_count(text: str) -> int:
    """argparse ``type``: processes or threads, 1..``MAX_PROCESSES`` (``--workers 999999999`` forked workers until
    the machine stopped: a process pool on Linux starts all of them at once)."""
    value = _int_at_least(text, 1)
    if value > MAX_PROCESSES:
        raise argparse.ArgumentTypeError(f"must be at most {MAX_PROCESSES}, got {value} (pass the cores to use)")
    return value


def cluster_workers(text: str) -> int:
    """argparse ``type``: parallel jobs of a fleet, 1..100000 (a Ray cluster's CPUs; on this machine the command
    allows ``MAX_PROCESSES``)."""
    value = _int_at_least(text, 1)
    if value > 100_000:
        raise argparse.ArgumentTypeError(f"must be at most 100000, got {value}")
    return value


def retry_count(text: str) -> int:
    """argparse ``type``: retries of a failed job, 0..100 (each retry reruns a job that crashed)."""
    value = _int_at_least(text, 0)
    if value > 100:
        raise argparse.ArgumentTypeError(f"must be at most 100, got {value}")
    return value


def version_name(value: str) -> str:
    """argparse ``type`` of --version: the version folder's name, "v1.0-mini/" (what tab completion types) and
    "./v1.0-mini" read as "v1.0-mini", so that runs record one name (probe 103: a rerun was refused as "another run
    (--version 'v1.0-sim' -> 'v1.0-sim/')"); anything else is left for ``data.tables.version_dir`` to refuse."""
    from hybrid_calib.data.tables import version_name as folder_name

    return folder_name(value) or value


def seed_int(text: str) -> int:
    """argparse ``type``: a seed, 0..2**63-1 (numpy's generators take no negative seed; one run's seed reads the same
    in every tool that loads its JSON)."""
    value = _int_at_least(text, 0)
    from hybrid_calib.config import MAX_SEED

    if value >= MAX_SEED:
        raise argparse.ArgumentTypeError(f"must be below 2**63, got {value}")
    return value


def nonnegative_int(text: str) -> int:
    """argparse ``type``: an integer >= 0 (a limit where 0 means "all")."""
    return _int_at_least(text, 0)


def _int_at_least(text: str, low: int) -> int:
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected an integer, got {text!r}") from None
    if value < low:
        raise argparse.ArgumentTypeError(f"must be >= {low}, got {value}")
    return value


SPLITS = ("all", "train", "val", "test")
SPLIT_BY = ("scene", "vehicle", "log", "time")


def add_split_arguments(p: argparse.ArgumentParser, default: str | None, what: str = "") -> None:
    """``--split`` (unless ``default`` is None) and the split options (``learned.dataset.SplitConfig``:
    docs/conventions.md, "Splits")."""
    if default is not None:
        p.add_argument("--split", default=default, choices=SPLITS, help=f"frames used: {what} (default: {default})")
    p.add_argument("--split-by", default=None, choices=SPLIT_BY,
                   help="how --split assigns frames: whole scenes / vehicles / logs, or time (within each scene: "
                        "first frames train, then a gap, then val, a gap, and the last frames test)")
    p.add_argument("--test-fraction", type=float, default=None, help="split.test_fraction (default 0.2)")
    p.add_argument("--val-fraction", type=float, default=None, help="split.val_fraction (default 0.1)")
    p.add_argument("--gap-frames", type=nonnegative_int, default=None,
                   help="split.gap_frames, by=time: frames dropped between the parts (default 3)")


SPLIT_FLAGS = {"by": "split_by", "test_fraction": "test_fraction", "val_fraction": "val_fraction",
               "gap_frames": "gap_frames"}  # SplitConfig key -> args attribute of its flag


def split_overrides(args: argparse.Namespace) -> dict:
    """The ``SplitConfig`` overrides the split flags give (only those passed)."""
    return given_flags(args, SPLIT_FLAGS)


def given_flags(args: argparse.Namespace, keys: dict[str, str], overrides: dict | None = None) -> dict:
    """Config key -> value of the flags passed on the command line (``keys``: config key -> ``args``
    attribute; a flag whose argparse default is None and that was not passed is left out). A flag that
    was passed wins over ``--set``; one that was not leaves ``--set`` (or the config's default) in charge.
    With ``overrides`` (the ``--set`` values), a flag that overrules a different ``--set`` value is said on stderr
    (the one rule of every command; it was silent, and inspect applied the opposite one)."""
    import sys

    given = {k: getattr(args, a) for k, a in keys.items() if getattr(args, a, None) is not None}
    for k, v in given.items():
        if overrides is not None and k in overrides and overrides[k] != v:
            flag = "--" + keys[k].replace("_", "-")
            print(f"note: {flag} {v} wins over --set {k}={overrides[k]!r} (a flag given overrules --set)",
                  file=sys.stderr)
    return given


def reject_learned_keys(overrides: dict) -> None:
    """``OptionError`` when ``--set`` for ``--method oracle`` names keys that only the learned methods' ``HybridConfig``
    has (threads, progress, measurement.*, ...): they are named as the learned methods' options, not refused as
    unknown ``CalibrateConfig`` keys with a list of valid ones that leaves the user guessing."""
    import dataclasses

    from hybrid_calib.calib.pipeline import CalibrateConfig
    from hybrid_calib.errors import OptionError
    from hybrid_calib.hybrid import HybridConfig

    own = {f.name for f in dataclasses.fields(CalibrateConfig)}
    keys = sorted(k for k in overrides if k not in own and k in {f.name for f in dataclasses.fields(HybridConfig)})
    if keys:
        one = len(keys) == 1
        raise OptionError("--set", f"{', '.join(keys)} {'is an option' if one else 'are options'} of the learned "
                                   f"methods (--method hybrid, pure or pure-avg); --method oracle runs no network: "
                                   f"drop {'it' if one else 'them'}"
                                   + ("; its progress bars are hidden by --no-progress" if "progress" in keys else ""))


def reject_unused_batch(overrides: dict, mode: str | None = None, backend: str | None = None,
                        batch_flag: str = "--mode batch") -> None:
    """``OptionError`` when the oracle's batch settings (``--backend``, ``--set batch.*``) come without the batch
    mode (``mode``: the command's --mode, or ``--set mode=batch``): the sliding window ran and they were ignored
    (probe 37). ``batch_flag``: how the command asks for the batch mode."""
    from hybrid_calib.errors import OptionError

    if (backend is not None or "batch" in overrides) and (mode or overrides.get("mode", "window")) != "batch":
        flag = "--backend" if backend is not None else "--set batch.*"
        raise OptionError(flag, f"sets the batch solve ({batch_flag}); the sliding window (the default mode) does not "
                                f"use it: add {batch_flag}, or drop {flag}")


def reject_unused_blocks(method: str, overrides: dict) -> None:
    """``OptionError`` (``--set``) naming the settings of ``overrides`` that ``method`` does not read
    (``hybrid.loop.unused_blocks``): accepted, they had no effect (probes 7 and 100). calibrate and fleet alike."""
    from hybrid_calib.errors import OptionError
    from hybrid_calib.hybrid.loop import unused_blocks

    if unused := unused_blocks(method, overrides):
        raise OptionError("--set", f"{', '.join(unused)} {'is' if len(unused) == 1 else 'are'} not used by --method "
                                   f"{method}: drop {'it' if len(unused) == 1 else 'them'}")


def reject_unused_window(overrides: dict, mode: str | None = None, window: int | None = None,
                         batch_flag: str = "--mode batch") -> None:
    """``OptionError`` when the sliding window's settings (``--window``, ``--set window.*``) come with the batch mode
    (``mode``: the command's --mode, or ``--set mode=batch``): the batch solve ran and they were ignored (probe 100),
    as ``reject_unused_batch`` for the other way round."""
    from hybrid_calib.errors import OptionError

    if (window is not None or "window" in overrides) and (mode or overrides.get("mode", "window")) == "batch":
        flag = "--window" if window is not None else "--set window.*"
        raise OptionError(flag, f"sets the sliding window; the batch solve ({batch_flag}) does not use it: drop "
                                f"{flag}, or drop {batch_flag}")


# the oracle's elevation draw: what each setting needs (calib.oracle.OracleConfig); with the default world heights
# they were accepted and changed nothing (probe 79)
ORACLE_MODEL_KEYS = {"elevation_beam_deg": "elevation=model", "elevation_mean_deg": "elevation=model",
                     "elevation_model": "elevation=model", "whole_arc_in_image": "elevation=model",
                     "reflector_height_mean_m": "elevation=model and elevation_model=height",
                     "reflector_height_std_m": "elevation=model and elevation_model=height"}


def reject_unused_oracle(overrides: dict) -> None:
    """``OptionError`` when ``--set oracle.KEY`` names a setting of the oracle's elevation draw that its
    ``oracle.elevation`` (default world: the simulator's true heights) or ``oracle.elevation_model`` does not use
    (``ORACLE_MODEL_KEYS``), as ``reject_unused_batch`` for the batch settings."""
    from hybrid_calib.calib.oracle import OracleConfig
    from hybrid_calib.errors import OptionError

    oracle = overrides.get("oracle")
    if not isinstance(oracle, dict):
        return
    model = oracle.get("elevation", OracleConfig.elevation) == "model"
    height = oracle.get("elevation_model", OracleConfig.elevation_model) == "height"
    for key, needs in ORACLE_MODEL_KEYS.items():
        if key in oracle and not (model and (height or "height" not in needs)):
            add = [f"oracle.{n}" for n, have in (("elevation=model", model), ("elevation_model=height", height))
                   if n in needs and not have]
            raise OptionError("--set", f"oracle.{key} acts only with oracle.{needs.replace(' and ', ' and oracle.')} "
                                       f"(the oracle draws reflector heights so; the default elevation=world uses the "
                                       f"simulator's own): add --set {' '.join(add)}, or drop oracle.{key}")


def reject_set_keys(overrides: dict, keys: dict[str, str]) -> None:
    """``OptionError`` when ``--set`` names a key that only its own flag sets (``keys``: config key -> flag),
    instead of ignoring it silently."""
    from hybrid_calib.errors import OptionError

    for key, flag in keys.items():
        if key in overrides:
            raise OptionError("--set", f"{key}={overrides[key]!r} is chosen with {flag} for this command; pass "
                                       f"{flag} instead (drop {key} from --set)")
