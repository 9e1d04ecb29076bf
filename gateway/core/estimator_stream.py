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
from gateway.core.estimator import EstimateTrack, lost_from_times
from gateway.core.estimator_settings import EstimatorSettings
from gateway.core.reference_point import NoRestError


class RealtimeChunks:
    """feed(t, acc, valid, lost) per chunk → its EstimateTrack; finish() → the notes."""

    def __init__(self, settings: EstimatorSettings):
        self.settings = settings
        self._prm = settings.kernel_params()
        (self._x, self._P, self._m, self._ring_z, self._ring_ok, self._snap, self._gain,
         self._out) = K.new_state(self._prm)
        # the smoother's stores are not kept in realtime: one-row placeholders
        self._st = (np.empty((1, 3)), np.empty((1, 6)), np.empty(1, dtype=np.int8), np.empty((1, 2)),
                    np.empty(1, dtype=np.int64), np.empty((1, 5)))
        self.samples = 0
        self._invalid = 0
        self._gaps = 0
        self._lost = 0
        self._first_init = -1
        self._t0 = None
        self._t_first_init = None
        self._last_t: float | None = None

    def feed(self, t_s, acc_mps2, valid=None, lost_before=None) -> EstimateTrack:
        """lost_before None: from time gaps, as estimate_series does, judged on this chunk
        (with the previous chunk's last time before it)."""
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
        K.run_forward(self._prm, t, z, ok, lost, self._x, self._P, self._m, self._ring_z, self._ring_ok,
                      self._snap, self._gain, self._out,
                      cols["pos"], cols["vel"], cols["acc"], cols["bias"], cols["pos_var"], cols["vel_var"],
                      cols["bias_var"], cols["innov"], cols["nis"], cols["zupt"], flags, False, *self._st)
        if n:
            if self._t0 is None:
                self._t0 = float(t[0])
            init = (flags & K.F_INITIALISED) != 0
            if self._first_init < 0 and init.any():
                k = int(np.argmax(init))
                self._first_init = self.samples + k
                self._t_first_init = float(t[k])
            self._invalid += int(np.count_nonzero(~ok))
            self._gaps += int(np.count_nonzero(lost))
            self._lost += int(lost.sum())
            self._last_t = float(t[-1])
        self.samples += n
        return EstimateTrack(
            method="realtime", t_s=t, pos_m=cols["pos"], vel_mps=cols["vel"], acc_mps2=cols["acc"],
            bias_mps2=cols["bias"], pos_std_m=np.sqrt(np.maximum(cols["pos_var"], 0.0)),
            vel_std_mps=np.sqrt(np.maximum(cols["vel_var"], 0.0)), innovation_mps2=cols["innov"],
            nis=cols["nis"], zupt_velocity_error_mps=cols["zupt"], flags=flags,
        )

    def finish(self) -> list[str]:
        """The notes estimate_series gives. Raises NoRestError as it does when the filter
        never initialised (then nothing the chunks gave is an estimate)."""
        if self.samples < 2:
            raise NoRestError("fewer than two samples")
        if self._first_init < 0:
            s = self.settings
            raise NoRestError(
                "no standstill found: the estimator needs a quiet stretch of "
                f"{s.window_samples} valid samples ({s.standstill_window_s:g} s) to measure the bias"
            )
        notes = []
        if self._invalid:
            notes.append(f"{self._invalid} samples invalid (NaN/inf/flagged): the estimate holds over them")
        if self._lost:
            notes.append(f"{self._gaps} gaps, {self._lost} samples lost: "
                         "propagated with the last acceleration and a wider variance")
        if self._first_init > 0:
            notes.append(f"the first {self._first_init} samples ({self._t_first_init - self._t0:.3f} s) came "
                         "before the first standstill: held at position 0")
        return notes
