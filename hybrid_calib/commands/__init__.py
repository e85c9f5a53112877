"""One module per ``hybrid-calib`` subcommand; each defines ``HELP``, ``add_arguments(parser)`` and
``run(args) -> int``. The modules are thin: they parse arguments and call typed functions."""

import argparse


def positive_int(text: str) -> int:
    """argparse ``type``: an integer >= 1 (a count such as frames, vehicles, workers, sweeps)."""
    return _int_at_least(text, 1)


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
