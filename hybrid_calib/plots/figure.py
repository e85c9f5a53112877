"""What every figure shares: a headless matplotlib and an atomic PNG write."""

from __future__ import annotations

from pathlib import Path

from hybrid_calib.atomic import atomic_path


def pyplot():
    """``matplotlib.pyplot`` on the non-interactive Agg back end (no display needed)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def save_figure(fig, path: str | Path, dpi: float | None = None) -> Path:
    """Write ``fig`` to ``path`` (PNG) through a temporary file, close it, return the path.
    ``dpi`` None keeps the figure's own dpi. The parent folder is created."""
    path = Path(path)
    try:
        with atomic_path(path) as tmp:
            fig.savefig(tmp, dpi=dpi if dpi is not None else "figure")
    finally:
        pyplot().close(fig)
    return path
