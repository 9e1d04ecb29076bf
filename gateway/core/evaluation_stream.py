"""`evaluation.summarise_errors` over chunks, so a streamed estimate is judged without
keeping its whole track: the same definitions (a stop is a run of reference rest of at
least min_s, judged at its last sample, the initial rest is not one), carried across chunk
boundaries. A test checks it against summarise_errors on the same data in many chunks.
"""
from __future__ import annotations

import math

import numpy as np

from gateway.core.evaluation import ErrorSummary, StopError, tol_moving_mps


class StreamedErrors:
    def __init__(self, min_s: float = 0.2, tol_mps: float = 1e-6):
        self.min_s = min_s
        self.tol_mps = tol_mps
        self.n = 0
        self._sum_sq = 0.0
        self._travelled = 0.0
        self._moving_max = -math.inf
        self._stops: list[StopError] = []
        self._last = None  # (t, err, ref_pos) of the last sample seen
        self._run_start: tuple[int, float] | None = None  # (index, t) of the open rest run

    def feed(self, t_s, pos_m, ref_pos_m, ref_vel_mps, ref_acc_mps2=None) -> None:
        t = np.asarray(t_s, dtype=float)
        if t.size == 0:
            return
        ref_pos = np.asarray(ref_pos_m, dtype=float)
        ref_vel = np.asarray(ref_vel_mps, dtype=float)
        err = np.asarray(pos_m, dtype=float) - ref_pos
        still = np.abs(ref_vel) <= self.tol_mps
        if ref_acc_mps2 is not None:
            still &= np.abs(np.asarray(ref_acc_mps2, dtype=float)) <= 1e-9
        prev = 1 if self._run_start is not None else 0
        edges = np.diff(np.concatenate([[prev], still.astype(np.int8)]))
        for k in np.flatnonzero(edges):  # starts (+1) and ends (−1) alternate
            if edges[k] > 0:
                self._run_start = (self.n + int(k), float(t[k]))
            else:
                end_t, end_err = (float(t[k - 1]), float(err[k - 1])) if k > 0 else self._last[:2]
                self._close(self.n + int(k) - 1, end_t, end_err)
        self._sum_sq += float(np.sum(err ** 2))
        steps = np.abs(np.diff(ref_pos))
        self._travelled += float(np.sum(steps))
        if self._last is not None:
            self._travelled += abs(float(ref_pos[0]) - self._last[2])
        moving = np.abs(ref_vel) > tol_moving_mps
        if moving.any():
            self._moving_max = max(self._moving_max, float(np.max(np.abs(err[moving]))))
        self._last = (float(t[-1]), float(err[-1]), float(ref_pos[-1]))
        self.n += t.size

    def _close(self, last_index: int, last_t: float, last_err: float) -> None:
        start_index, start_t = self._run_start
        self._run_start = None
        if start_index > 0 and last_t - start_t >= self.min_s:
            self._stops.append(StopError(last_index, last_t, last_err))

    def result(self) -> ErrorSummary:
        if self.n == 0:
            raise ValueError("no samples")
        stops = list(self._stops)
        if self._run_start is not None:  # a rest running to the end ends at the last sample
            start_index, start_t = self._run_start
            if start_index > 0 and self._last[0] - start_t >= self.min_s:
                stops.append(StopError(self.n - 1, self._last[0], self._last[1]))
        return ErrorSummary(stops=tuple(stops), final_m=self._last[1], rms_m=math.sqrt(self._sum_sq / self.n),
                            travelled_m=self._travelled,
                            moving_max_m=self._moving_max if self._moving_max > -math.inf else float("nan"))
