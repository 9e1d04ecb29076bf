"""Errors of an estimate against a reference motion: at each stop, at the end, RMS."""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from gateway.core.runs import true_runs


@dataclass(frozen=True)
class StopError:
    index: int  # the sample the error is taken at: the last one of the stop
    t_s: float
    error_m: float


@dataclass(frozen=True)
class ErrorSummary:
    stops: tuple[StopError, ...]  # the stops after motion, in order (the initial rest is not one)
    final_m: float
    rms_m: float
    travelled_m: float
    vel_rms_mps: float = float("nan")  # when the estimate's velocity is given
    moving_max_m: float = float("nan")  # largest |position error| while the reference moves

    @property
    def last_stop_percent_of_travel(self) -> float:
        if not self.stops or self.travelled_m == 0:
            return float("nan")
        return 100.0 * abs(self.stops[-1].error_m) / self.travelled_m


tol_moving_mps = 1e-6


def rest_intervals(t_s, ref_vel_mps, ref_acc_mps2=None, min_s: float = 0.2, tol_mps: float = 1e-6):
    """(start, stop) index ranges (stop exclusive) where the reference is at rest for ≥ min_s."""
    t = np.asarray(t_s, dtype=float)
    still = np.abs(np.asarray(ref_vel_mps, dtype=float)) <= tol_mps
    if ref_acc_mps2 is not None:
        still &= np.abs(np.asarray(ref_acc_mps2, dtype=float)) <= 1e-9
    return [(a, b) for a, b in true_runs(still) if t[b - 1] - t[a] >= min_s]


def summarise_errors(t_s, pos_m, ref_pos_m, ref_vel_mps, ref_acc_mps2=None, vel_mps=None) -> ErrorSummary:
    """Errors at the last sample of each stop after the first motion, at the end, RMS, and
    (with vel_mps) the velocity RMS."""
    t = np.asarray(t_s, dtype=float)
    err = np.asarray(pos_m, dtype=float) - np.asarray(ref_pos_m, dtype=float)
    rests = rest_intervals(t, ref_vel_mps, ref_acc_mps2)
    stops = tuple(StopError(b - 1, float(t[b - 1]), float(err[b - 1])) for a, b in rests if a > 0)
    travelled = float(np.sum(np.abs(np.diff(np.asarray(ref_pos_m, dtype=float)))))
    vel_rms = float("nan")
    if vel_mps is not None:
        vel_err = np.asarray(vel_mps, dtype=float) - np.asarray(ref_vel_mps, dtype=float)
        vel_rms = float(np.sqrt(np.mean(vel_err**2)))
    moving = np.abs(np.asarray(ref_vel_mps, dtype=float)) > tol_moving_mps
    return ErrorSummary(stops=stops, final_m=float(err[-1]), rms_m=float(np.sqrt(np.mean(err**2))),
                        travelled_m=travelled, vel_rms_mps=vel_rms,
                        moving_max_m=float(np.max(np.abs(err[moving]))) if moving.any() else float("nan"))


@dataclass(frozen=True)
class MoveError:
    """One move between two rests: the displacement from the end of one rest to the end of the next."""

    start: int  # last sample of the rest before
    end: int  # last sample of the rest after
    ref_m: float
    estimate_m: float

    @property
    def error_m(self) -> float:
        return self.estimate_m - self.ref_m

    @property
    def percent(self) -> float:
        return 100.0 * abs(self.error_m) / abs(self.ref_m)


def move_errors(pos_m, ref_pos_m, at_rest, min_move_m: float = 0.01) -> list[MoveError]:
    """Per move between two rests (runs of at_rest ≠ 0, e.g. a robot's "in position"): the
    estimated displacement against the reference's, both taken at the last sample of each
    rest. Moves of less than min_move_m (the axis stood while another one moved) are left out."""
    rest = np.asarray(at_rest, dtype=float) > 0.5
    edges = np.diff(np.concatenate([[0], rest.astype(np.int8), [0]]))
    ends = np.flatnonzero(edges == -1) - 1  # last sample of each rest
    pos = np.asarray(pos_m, dtype=float)
    ref = np.asarray(ref_pos_m, dtype=float)
    moves = []
    for a, b in zip(ends[:-1], ends[1:], strict=False):
        d_ref = float(ref[b] - ref[a])
        if abs(d_ref) >= min_move_m:
            moves.append(MoveError(int(a), int(b), d_ref, float(pos[b] - pos[a])))
    return moves
