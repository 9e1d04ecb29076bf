"""Where numba keeps the compiled code: a cache directory keyed by the project's sources.

numba invalidates a cached function only when *its own* source file changes (numba's
"Notes on Caching"), and ours inline code of other files: `estimator_kernel.step` inlines
standstill.py's tests, `smoother.run_backward` the kernel's `unpack_cov` and layout, the
daemon's `sample_loop` the kernel's step and drivers/board_protocol's constants. After
an edit or an upgrade of one file a cache kept from before could run stale code of
another (a full local test run once failed 7 estimator tests that way). So NUMBA_CACHE_DIR
is set to `<base>/numba-<digest of every .py under gateway/ and drivers/>`: any change
there starts a fresh cache, and the first run after it compiles again. The base is
NUMBA_CACHE_DIR where set (the service's /var/cache/adxl-gateway), else
gateway/core/__pycache__ (numba's own place for the core's cache). Directories of older
sources are left behind (a few MB each), not pruned: another checkout or version may still
use them.

Run from gateway/__init__.py, i.e. before gateway.core.jit imports numba (which reads the
variable then). Idempotent: a child process of the same sources inherits the keyed value
and keeps it.
"""
from __future__ import annotations

import hashlib
import os

SOURCE_TREES = ("gateway", "drivers")
_ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))


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


def keyed_cache_dir(base: str | None, digest: str) -> str:
    """The cache directory for these sources under `base` (kept when already keyed so)."""
    base = base or os.path.join(_ROOT, "gateway", "core", "__pycache__")
    leaf = f"numba-{digest}"
    return base if os.path.basename(os.path.normpath(base)) == leaf else os.path.join(base, leaf)


def key_numba_cache() -> str:
    os.environ["NUMBA_CACHE_DIR"] = keyed_cache_dir(os.environ.get("NUMBA_CACHE_DIR"), sources_digest(_ROOT))
    return os.environ["NUMBA_CACHE_DIR"]
