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

The compiled code is cached on disk, and numba invalidates a cached function only when
*its own* source file changes (numba's "Notes on Caching"). Ours cross files:
`estimator_kernel.step` inlines standstill.py's tests, `smoother.run_backward` uses the
kernel's `unpack_cov` and layout. After an edit or an upgrade of one file, a cache kept
from before could run stale code of another — a full local test run once failed 7
estimator tests that way. So the cache directory is keyed by a digest of every source
of the project (`CACHE_DIR`, over gateway/ and drivers/): any change there starts a fresh
cache — the first run after an edit or an upgrade compiles again. Its base is
NUMBA_CACHE_DIR where set (the service's /var/cache/adxl-gateway), else this package's
__pycache__ (numba's own default place). Directories of older sources are left behind
(a few MB each), not pruned: another checkout or version may still use them.
"""
from __future__ import annotations

import hashlib
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


# The project's source trees: jitted code lives in gateway/core and gateway/daemon
# (sample_pipeline) and compiles in constants of drivers/ (board_protocol).
_ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
SOURCE_TREES = ("gateway", "drivers")


def sources_digest(root: str, trees: tuple[str, ...] = SOURCE_TREES) -> str:
    """A digest of every .py source under root/<tree> (relative paths and contents)."""
    h = hashlib.sha256()
    for tree in trees:
        for dirpath, dirnames, filenames in os.walk(os.path.join(root, tree)):
            dirnames[:] = sorted(d for d in dirnames if d != "__pycache__")
            for name in sorted(filenames):
                if name.endswith(".py"):
                    path = os.path.join(dirpath, name)
                    h.update(os.path.relpath(path, root).encode())
                    with open(path, "rb") as f:
                        h.update(f.read())
    return h.hexdigest()[:16]


def _keyed_cache_dir(numba) -> str:
    core = os.path.dirname(os.path.abspath(__file__))
    base = numba.config.CACHE_DIR or os.path.join(core, "__pycache__")
    # set in numba's config module, not the environment: numba keeps a value set there
    # unless a NUMBA_ variable changes, and child processes (the daemon's tests) key
    # their own from the unchanged NUMBA_CACHE_DIR
    numba.config.CACHE_DIR = os.path.join(base, f"numba-{sources_digest(_ROOT)}")
    return numba.config.CACHE_DIR


_numba = _import_numba()
JIT_ENABLED = _numba is not None
CACHE_DIR: str | None = _keyed_cache_dir(_numba) if _numba is not None else None


def jit(func):
    if _numba is None:
        return func
    # cache: compiled code is kept beside the module, so only the first run compiles
    return _numba.njit(cache=True, nogil=True)(func)
