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
        # the kernel's state, for the per-sample fast path (see step) and the daemon's
        # compiled per-chunk path (gateway/sample_fast_path.py)
        *self.kernel_args, self.kernel_out = self.estimator.kernel_state
        self.kernel_args = tuple(self.kernel_args)

    def step(self, t_s: float, acc_mps2: float | None, lost_before: int) -> LinkEstimate:
        """RealtimeEstimator.step, then the health the daemon publishes.

        The kernel is called exactly as RealtimeEstimator.step calls it, on the
        estimator's own state, but without building its full Estimate (twelve numpy
        scalars turned into floats, a frozen dataclass): that wrapper cost four times
        the kernel, 500 times a second. tests/test_service_parts.py checks that both
        paths give the same numbers, bit for bit.
        """
        valid = acc_mps2 is not None
        K.step(*self.kernel_args, float(t_s), float(acc_mps2) if valid else 0.0, valid, int(lost_before),
               self.kernel_out)
        return self.latest(entered_standstill=None)

    def latest(self, entered_standstill: bool | None) -> LinkEstimate:
        """The estimate in the kernel's output array (its newest step).

        `entered_standstill`: whether any step since the last call began a standstill
        (the daemon's compiled path steps a whole chunk); None: look at the newest step.
        """
        o = self.kernel_out.tolist()
        pos, vel, acc, bias, var = o[_O_POS], o[_O_VEL], o[_O_ACC], o[_O_BIAS], o[_O_POS_VAR]
        pos_std = math.sqrt(var) if var >= 0.0 else math.nan  # as np.sqrt
        flags = int(o[_O_FLAGS])
        if entered_standstill is None:
            entered_standstill = bool(flags & _F_ENTRY)
        if entered_standstill:
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
