"""Optional numba compilation for the per-sample loops of the estimators.

The offline estimate of a 12-hour recording (21.6 M samples) must take under a minute;
a Kalman step in CPython costs ~10 µs, so the loops are written in the subset of
Python that numba compiles (scalars and preallocated arrays, no allocation per step).
Without numba the very same functions run as plain Python: correct, only slower
(`JIT_ENABLED` tells which). The realtime class calls the same step function.

Set ADXLGW_NO_JIT=1 to force plain Python (e.g. to debug or to time the difference).
"""
from __future__ import annotations

import os

try:
    if os.environ.get("ADXLGW_NO_JIT"):
        raise ImportError("disabled by ADXLGW_NO_JIT")
    import numba

    JIT_ENABLED = True

    def jit(func):
        # cache: compiled code is kept beside the module, so only the first run compiles
        return numba.njit(cache=True, nogil=True)(func)

except ImportError:
    JIT_ENABLED = False

    def jit(func):
        return func
