"""What every figure shares: a headless matplotlib, names short enough to draw, and an atomic PNG write."""

from __future__ import annotations

import warnings
from pathlib import Path

from hybrid_calib.atomic import atomic_path


def pyplot():
    """``matplotlib.pyplot`` on the non-interactive Agg back end (no display needed). ``MPLBACKEND`` is set to Agg
    before matplotlib's first import: matplotlib refuses, while importing, a value it does not know, and a
    notebook's kernel sets one (``module://matplotlib_inline.backend_inline``; probe 84: every command with plots
    ended in "internal error" run from a notebook cell)."""
    import os
    import sys

    if "matplotlib" not in sys.modules:
        os.environ["MPLBACKEND"] = "Agg"
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    # and while a figure is laid out (tight_layout, text extents), before any save (probe 88: every run with a
    # vehicle named in another script printed the warning)
    warnings.filterwarnings("ignore", message=r"Glyph \d+ .*missing from", category=UserWarning)
    return plt


NAME_CHARS = 40  # a vehicle's name drawn on a figure: at most this many characters (``short_name``)


def short_name(name, most: int = NAME_CHARS) -> str:
    """``name`` as a figure draws it: itself when it has at most ``most`` characters (one line), else its first and
    last characters around an ellipsis (a vehicle's number is at its end). Probe 88: one 226-character vehicle name as
    a tick label squeezed the fleet figure's six panels into a 15 px strip, and cut a report picture's title."""
    name = " ".join(str(name).split())
    if len(name) <= most:
        return name
    head = (most - 1) * 2 // 3
    return name[:head] + "\u2026" + name[len(name) - (most - 1 - head):]


def save_figure(fig, path: str | Path, dpi: float | None = None) -> Path:
    """Write ``fig`` to ``path`` (PNG) through a temporary file, close it, return the path.
    ``dpi`` None keeps the figure's own dpi. The parent folder is created. A character the font lacks (a
    vehicle or scene named in another script) is drawn as a box, without matplotlib's warning per glyph."""
    path = Path(path)
    try:
        with atomic_path(path) as tmp, warnings.catch_warnings():
            warnings.filterwarnings("ignore", message=r"Glyph \d+ .*missing from", category=UserWarning)
            fig.savefig(tmp, dpi=dpi if dpi is not None else "figure")
    finally:
        pyplot().close(fig)
    return path
