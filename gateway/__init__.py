# numba's cache must be keyed by the sources before gateway.core.jit imports numba
from gateway.compiled_cache import key_numba_cache as _key_numba_cache

_key_numba_cache()
