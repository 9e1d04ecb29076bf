"""The realtime estimator over a recording chunk by chunk: memory follows the chunk.

`estimate_series(method="realtime")` runs `estimator_kernel.run_forward` over whole
arrays; the kernel keeps all its memory in the arrays of `new_state`, so running it over
consecutive chunks with the same arrays gives the same numbers, bit for bit (a test
checks it). This wrapper carries those arrays and the counts behind the notes
`estimate_series` gives, so `adxlgw estimate --method realtime` never holds a whole
12-hour recording.
"""
from __future__ import annotations

import numpy as np

from gateway.core import estimator_kernel as K
from gateway.core.estimator import EstimateTrack, RunCounts, lost_from_times
from gateway.core.estimator_settings import EstimatorSettings
from gateway.core.reference_point import NoRestError


class RealtimeChunks:
    """feed(t, acc, valid, lost) per chunk → its EstimateTrack; finish() → the notes."""

    def __init__(self, settings: EstimatorSettings):
        self.settings = settings
        self._prm = settings.kernel_params()
        self._state = K.new_state(self._prm)
        # the smoother's stores are not kept in realtime: one-row placeholders
        self._st = (np.empty((1, 3)), np.empty((1, 6)), np.empty(1, dtype=np.int8), np.empty((1, 2)),
                    np.empty(1, dtype=np.int64), np.empty((1, 5)))
        self.counts = RunCounts()
        self._last_t: float | None = None

    def feed(self, t_s, acc_mps2, valid=None, lost_before=None, standstill_hint=None) -> EstimateTrack:
        """lost_before None: from time gaps, as estimate_series does, judged on this chunk
        (with the previous chunk's last time before it). standstill_hint: the machine's word
        per sample (1 at rest, 0 moving, NaN unknown), None: unknown throughout."""
        t = np.ascontiguousarray(t_s, dtype=float)
        acc = np.ascontiguousarray(acc_mps2, dtype=float)
        n = t.size
        ok = np.isfinite(acc) if valid is None else (np.asarray(valid, dtype=bool) & np.isfinite(acc))
        if lost_before is None:
            lost = (lost_from_times(t) if self._last_t is None
                    else lost_from_times(np.concatenate([[self._last_t], t]))[1:])
        else:
            lost = np.asarray(lost_before, dtype=np.int64)
        lost = np.ascontiguousarray(lost, dtype=np.int64)
        z = np.where(ok, acc, 0.0)
        cols = {name: np.empty(n) for name in ("pos", "vel", "acc", "bias", "pos_var", "vel_var", "bias_var",
                                               "innov", "nis", "zupt")}
        flags = np.empty(n, dtype=np.int32)
        hint = (np.full(n, np.nan) if standstill_hint is None
                else np.ascontiguousarray(standstill_hint, dtype=float))
        K.run_forward(self._prm, t, z, ok, lost, hint, self._state,
                      cols["pos"], cols["vel"], cols["acc"], cols["bias"], cols["pos_var"], cols["vel_var"],
                      cols["bias_var"], cols["innov"], cols["nis"], cols["zupt"], flags, False, *self._st)
        self.counts.add_input(ok, lost)
        self.counts.add_output(t, flags)
        if n:
            self._last_t = float(t[-1])
        return EstimateTrack(
            method="realtime", t_s=t, pos_m=cols["pos"], vel_mps=cols["vel"], acc_mps2=cols["acc"],
            bias_mps2=cols["bias"], pos_std_m=np.sqrt(np.maximum(cols["pos_var"], 0.0)),
            vel_std_mps=np.sqrt(np.maximum(cols["vel_var"], 0.0)), innovation_mps2=cols["innov"],
            nis=cols["nis"], zupt_velocity_error_mps=cols["zupt"], flags=flags,
        )

    def finish(self) -> list[str]:
        """The notes estimate_series gives. Raises NoRestError as it does when the filter
        never initialised (then nothing the chunks gave is an estimate)."""
        if self.counts.samples < 2:
            raise NoRestError("fewer than two samples")
        if self.counts.first_init < 0:
            s = self.settings
            raise NoRestError(
                "no standstill found: the estimator needs a quiet stretch of "
                f"{s.window_samples} valid samples ({s.standstill_window_s:g} s) to measure the bias"
            )
        return self.counts.input_notes() + self.counts.outcome_notes()
