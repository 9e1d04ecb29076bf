"""Runs of True in a boolean series: the stretches (stops, gaps, bursts, rests) that the
estimator, the re-timing and the scoring talk about."""
from __future__ import annotations

import numpy as np


def true_runs(mask) -> list[tuple[int, int]]:
    """(start, stop) index ranges of the runs of True, stop exclusive."""
    edges = np.diff(np.concatenate([[0], np.asarray(mask).astype(np.int8), [0]]))
    return list(zip(np.flatnonzero(edges == 1).tolist(), np.flatnonzero(edges == -1).tolist(), strict=False))
