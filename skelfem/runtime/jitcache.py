"""Compiled forms, elements and expressions looked up once per process.

Every new mesh (each edit of a live Session) builds its function spaces,
forms and expressions anew. FFCx finds their compiled modules in its disk
cache, but each look-up lists the cache folder and loads the module again:
about 1 ms each, ten of them per model, on every edit. A module in that
cache never changes once it is complete, so :func:`install` keeps the ones
found in a dictionary keyed by the module's name (FFCx's signature of the
UFL object, so a changed form still gets its own module). FFCx's merged
parameters are likewise read from its JSON files and pretty-printed for its
log on every call; they are kept per set of priority parameters.
"""
from __future__ import annotations

_MODULES: dict = {}
MIN_WAIT = 300          # s: how long a look-up waits for another process's compile of the same module
_INSTALLED = False


def _memoised(lookup):
    def get_cached_module(module_name, object_names, cache_dir, timeout):
        key = (module_name, tuple(object_names), str(cache_dir))
        hit = _MODULES.get(key)
        if hit is None:
            # another process compiling the same module (parallel tests, sweeps): wait for it
            # as long as a 3D P2 compile takes on a loaded machine, not FFCx's 10 s
            hit = lookup(module_name, object_names, cache_dir, max(timeout, MIN_WAIT))
            if hit[0] is not None:          # (None, None): this process compiles it now
                _MODULES[key] = hit
        return hit
    get_cached_module.lookup = lookup
    return get_cached_module


def _memoised_parameters(get):
    memo: dict = {}

    def get_parameters(priority_parameters=None):
        key = repr(sorted((priority_parameters or {}).items()))
        if key not in memo:
            memo[key] = get(priority_parameters)
        return dict(memo[key])
    return get_parameters


def install() -> None:
    """Make FFCx's cache look-ups hit memory after the first one of each module (idempotent)."""
    global _INSTALLED
    if _INSTALLED:
        return
    import ffcx
    import ffcx.parameters
    from ffcx.codegeneration import jit
    jit.get_cached_module = _memoised(jit.get_cached_module)
    ffcx.get_parameters = ffcx.parameters.get_parameters = _memoised_parameters(ffcx.parameters.get_parameters)
    _INSTALLED = True
