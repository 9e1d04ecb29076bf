"""Writing matplotlib figures for the offline commands (Agg backend, no display)."""
from __future__ import annotations

from pathlib import Path

from gateway.errors import InputError

#: what matplotlib's Agg backend writes (savefig picks the format by the extension)
PLOT_SUFFIXES = (".png", ".pdf", ".svg", ".jpg", ".jpeg", ".eps", ".ps", ".tif", ".tiff", ".webp")


def check_plot_path(path: str, option: str = "--plot") -> None:
    """InputError (exit 2) unless a plot can be written at `path`: an extension matplotlib
    writes and a directory that exists — said before the work, not after it (a long
    estimate or fit that then fails to save its figure loses the run)."""
    if not path.lower().endswith(PLOT_SUFFIXES):
        raise InputError(f"{option} {path}: not a figure's extension: {', '.join(PLOT_SUFFIXES)}")
    parent = Path(path).parent
    if not parent.is_dir():
        raise InputError(f"{option} {path}: no directory {parent}")


def save_figure(fig, path, dpi: int = 100) -> None:
    """Save and close; a path that cannot be written is bad input (exit 2), not a crash."""
    import matplotlib.pyplot as plt

    try:
        fig.savefig(path, dpi=dpi)
    except OSError as err:
        raise InputError(f"{path}: cannot write the plot: {err.strerror or err}") from err
    finally:
        plt.close(fig)
