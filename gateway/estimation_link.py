"""The daemon's view of the realtime estimator: one sample in, one estimate out.

The numerical core's estimator knows nothing of boards or wires; this link gives the
supervisor the few things it needs: settings from the sensor model (and a fitted
drift model when configured), a reset when continuity is lost, and the health fields
the status bits are made of.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

from gateway.core import estimator_kernel as K
from gateway.core.drift_fit import FittedDrift
from gateway.core.estimator import RealtimeEstimator
from gateway.core.estimator_settings import EstimatorSettings, from_sensor_model
from gateway.core.sensor_model import SensorParams

# the kernel's output layout and flags, looked up once (the step runs 500 times a second)
_O_POS, _O_VEL, _O_ACC, _O_BIAS, _O_POS_VAR, _O_FLAGS = K.O_POS, K.O_VEL, K.O_ACC, K.O_BIAS, K.O_POS_VAR, K.O_FLAGS
_F_ENTRY, _F_STANDSTILL, _F_INITIALISED = K.F_ENTRY, K.F_STANDSTILL, K.F_INITIALISED
_F_HOLDING = K.F_INPUT_INVALID | K.F_TIME_ERROR


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
        est = self.estimator
        try:  # the kernel's state, for the per-sample fast path (see step)
            self._kernel_args = (est._x, est._P, est._m, est._ring_z, est._ring_ok, est._snap, est._prm, est._gain)
            self._out = est._out
        except AttributeError:  # the core changed its internals: use its public step
            self._kernel_args = None

    def step(self, t_s: float, acc_mps2: float | None, lost_before: int) -> LinkEstimate:
        """RealtimeEstimator.step, then the health the daemon publishes.

        The kernel is called exactly as RealtimeEstimator.step calls it, on the
        estimator's own state, but without building its full Estimate (twelve numpy
        scalars turned into floats, a frozen dataclass): that wrapper cost four times
        the kernel, 500 times a second. tests/test_service_parts.py checks that both
        paths give the same numbers, bit for bit.
        """
        if self._kernel_args is None:
            e = self.estimator.step(t_s, acc_mps2, lost_before)
            pos, vel, acc, bias, pos_std, flags = e.pos_m, e.vel_mps, e.acc_mps2, e.bias_mps2, e.pos_std_m, e.flags
        else:
            valid = acc_mps2 is not None
            K.step(*self._kernel_args, float(t_s), float(acc_mps2) if valid else 0.0, valid, int(lost_before),
                   self._out)
            o = self._out.tolist()
            pos, vel, acc, bias, var = o[_O_POS], o[_O_VEL], o[_O_ACC], o[_O_BIAS], o[_O_POS_VAR]
            pos_std = math.sqrt(var) if var >= 0.0 else math.nan  # as np.sqrt
            flags = int(o[_O_FLAGS])
        if flags & _F_ENTRY:
            self._bias_requested = False  # the new standstill re-measures the bias
        initialised = bool(flags & _F_INITIALISED)
        # positional, in field order: pos, vel, acc, standstill, bias, pos_std, holding,
        # initialising, fault, bias_estimating
        return LinkEstimate(pos, vel, acc, bool(flags & _F_STANDSTILL), bias, pos_std, bool(flags & _F_HOLDING),
                            not initialised, False, self._bias_requested or not initialised)

    def request_bias_reestimate(self, at_standstill: bool) -> bool:
        """Accepted only at standstill: the bias variance widens and the rest re-measures it."""
        if not at_standstill:
            return False
        self.estimator.request_bias_reestimate()
        self._bias_requested = True
        return True
