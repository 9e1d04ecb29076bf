"""The daemon's view of the realtime estimator: one sample in, one estimate out.

The numerical core's estimator knows nothing of boards or wires; this link gives the
supervisor the few things it needs: settings from the sensor model (and a fitted
drift model when configured), a reset when continuity is lost, and the health fields
the status bits are made of.
"""
from __future__ import annotations

from dataclasses import dataclass

from gateway.core import estimator_kernel as K
from gateway.core.drift_fit import FittedDrift
from gateway.core.estimator import RealtimeEstimator
from gateway.core.estimator_settings import EstimatorSettings, from_sensor_model
from gateway.core.sensor_model import SensorParams


@dataclass(slots=True)  # not frozen: built 500 times a second, and frozen init is slow
class LinkEstimate:
    pos_m: float
    vel_mps: float
    acc_mps2: float
    standstill: bool
    bias_mps2: float
    pos_std_m: float
    # the estimator holds (no valid input, undecided window, time not advancing):
    # numbers are the last ones, not live
    holding: bool
    # before the first standstill the bias is unknown: position is held at 0
    initialising: bool
    fault: bool = False
    bias_estimating: bool = False


class EstimatorLink:
    def __init__(self, drift: FittedDrift | None = None, axis: str = "x"):
        self.settings: EstimatorSettings = from_sensor_model(SensorParams(), drift_fit=drift, axis=axis)
        self._bias_requested = False
        # The first step compiles the kernel (numba, seconds; cached on disk after): do
        # it now, before the daemon reports READY, not on the first sample of the board.
        RealtimeEstimator(self.settings).step(0.0, 0.0, 0)
        self.reset()

    def reset(self) -> None:
        self.estimator = RealtimeEstimator(self.settings)
        self._bias_requested = False

    def step(self, t_s: float, acc_mps2: float | None, lost_before: int) -> LinkEstimate:
        e = self.estimator.step(t_s, acc_mps2, lost_before)
        if e.flags & K.F_ENTRY:
            self._bias_requested = False  # the new standstill re-measures the bias
        return LinkEstimate(
            pos_m=e.pos_m, vel_mps=e.vel_mps, acc_mps2=e.acc_mps2, standstill=e.standstill,
            bias_mps2=e.bias_mps2, pos_std_m=e.pos_std_m,
            holding=bool(e.flags & (K.F_INPUT_INVALID | K.F_TIME_ERROR)),
            initialising=not e.initialised,
            bias_estimating=self._bias_requested or not e.initialised,
        )

    def request_bias_reestimate(self, at_standstill: bool) -> bool:
        """Accepted only at standstill: the bias variance widens and the rest re-measures it."""
        if not at_standstill:
            return False
        self.estimator.request_bias_reestimate()
        self._bias_requested = True
        return True
