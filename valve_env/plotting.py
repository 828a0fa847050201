"""The one place that chooses matplotlib's backend for the figures the package writes.

Figures are written to files, so a script, the CLI or a worker needs no display: :func:`headless`
selects Agg there. In a notebook (an ``inline`` backend, or any ``module://`` backend a front end
installed) the user's backend is kept, so that the figures a tutorial makes still show inline after
a command has written its own.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any


def headless() -> None:
    """Select the Agg backend unless a notebook's inline (``module://...``) backend is active."""
    import matplotlib

    backend = str(matplotlib.get_backend())
    if not backend.startswith("module://") and "inline" not in backend.lower():
        matplotlib.use("Agg")


def save_figure(fig: Any, path: str | Path, dpi: int = 110, format: str | None = None) -> Path:  # noqa: A002
    """Write ``fig`` to ``path`` at ``dpi`` (in ``format``; default: from the path's suffix, so a staged file
    without one names it) and close it; returns the path."""
    import matplotlib.pyplot as plt

    path = Path(path)
    fig.savefig(path, dpi=dpi, format=format)
    plt.close(fig)
    return path


__all__ = ["headless", "save_figure"]
