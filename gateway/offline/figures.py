"""Writing matplotlib figures for the offline commands (Agg backend, no display)."""
from __future__ import annotations

from gateway.errors import InputError


def save_figure(fig, path, dpi: int = 100) -> None:
    """Save and close; a path that cannot be written is bad input (exit 2), not a crash."""
    import matplotlib.pyplot as plt

    try:
        fig.savefig(path, dpi=dpi)
    except OSError as err:
        raise InputError(f"{path}: cannot write the plot: {err.strerror or err}") from err
    finally:
        plt.close(fig)
