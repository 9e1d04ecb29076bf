"""Optional numba compilation for the per-sample loops of the estimators.

The offline estimate of a 12-hour recording (21.6 M samples) must take under a minute;
a Kalman step in CPython costs ~10 µs, so the loops are written in the subset of
Python that numba compiles (scalars and preallocated arrays, no allocation per step).
Without numba the very same functions run as plain Python: correct, only slower
(`JIT_ENABLED` tells which). The realtime class calls the same step function.

Set ADXLGW_NO_JIT=1 to force plain Python (e.g. to debug or to time the difference).

Any failure to import or initialise numba means plain Python, never a crash: numba's
import checks that llvmlite may map executable memory, and under systemd's
MemoryDenyWriteExecute=yes (or SELinux's execmem denial) that check raises
PermissionError, not ImportError. `JIT_UNAVAILABLE_REASON` then says why, for the
command line to log once (the core does no I/O); it stays None when numba runs or was
switched off on purpose.

The compiled code is cached on disk (numba's cache=True). Where: NUMBA_CACHE_DIR, which
`gateway/compiled_cache.py` keys by a digest of the project's sources before this module
is imported (numba re-checks a cached function only against its own file; ours inline
code of other files) — the core itself reads no files.
"""
from __future__ import annotations

import os

JIT_UNAVAILABLE_REASON: str | None = None


def _import_numba():
    global JIT_UNAVAILABLE_REASON
    if os.environ.get("ADXLGW_NO_JIT"):
        return None
    try:
        import numba
    except ImportError as err:
        JIT_UNAVAILABLE_REASON = f"numba is not installed ({err})"
        return None
    except Exception as err:  # noqa: BLE001 — whatever numba/llvmlite raise at start, we run without them
        JIT_UNAVAILABLE_REASON = f"numba cannot start: {type(err).__name__}: {err}"
        return None
    return numba


_numba = _import_numba()
JIT_ENABLED = _numba is not None


def jit(func):
    if _numba is None:
        return func
    # cache: compiled code is kept on disk (NUMBA_CACHE_DIR, gateway/compiled_cache.py), so only
    # the first run of these sources compiles
    return _numba.njit(cache=True, nogil=True)(func)


def jit_inline(func):
    """jit, inlined into its callers at numba's IR level: for a phase of a per-sample step
    that is its own function for the reader, not for the machine (a call per phase passes
    the state's arrays and their reference counts on every sample: the phased estimator
    kernel took twice the CPU time of the one-function step)."""
    if _numba is None:
        return func
    return _numba.njit(cache=True, nogil=True, inline="always")(func)



def jit_without_refcounts(func):
    """jit, compiled without numba's reference counting of arrays: for a per-sample step
    that allocates nothing and keeps no array beyond its call (its phases, inlined by
    jit_inline, take the state's arrays as arguments).

    Numba counts a reference on an array at every assignment and releases it where the
    variable dies; its pruning pass removes such pairs only within a basic block or a
    simple diamond, not across a phase's branches (numba issue #2350, its maintainers'
    example uses this same switch). Each count is an atomic operation through a function
    pointer: the phased estimator step carried 65 increfs and 176 decrefs in its compiled
    code (the one-function step before it 20 and 52; `inspect_llvm` of a fresh compile),
    and ran about 1.4× the CPU time per sample of that step offline; without the counts it
    is at least as fast (`python -m benchmarks.speed.estimator_speed --compare DIR`, with
    a worktree of the older commit). The counts are not needed: the caller (Python,
    run_forward, the daemon's run_samples) holds every array for the whole call, and the
    step allocates nothing (with the runtime off, an allocation would fail to compile, not
    leak). `_nrt=False` is numba's switch for this — underscored, so not a public promise:
    numba is pinned (constraints.txt), and a numba that dropped the switch would fail
    at its first compile (KeyError: unrecognized option), in every test."""
    if _numba is None:
        return func
    return _numba.njit(cache=True, nogil=True, _nrt=False)(func)
