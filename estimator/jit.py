"""Numba compilation, as the user sees it: whether numba's on-disk cache holds the fast
path's kernels, and a message before they are compiled (20-40 s, once per installation).

No numerics here: the kernel modules are passed in (:class:`estimator.backends.
NumbaBackend` passes :mod:`estimator._kernels` and :mod:`estimator._solver`), and every
function of theirs compiled with ``cache=True`` is found by its type, so there is no
list of kernels to keep up to date.
"""

from __future__ import annotations

import logging

__all__ = ["cached_kernels", "kernels_cached", "announce_compilation"]

_log = logging.getLogger("gridflow.estimator")
_announced = False


def cached_kernels(modules) -> list:
    """The numba dispatchers with an on-disk cache (``cache=True``) in ``modules``."""
    from numba.core.caching import FunctionCache
    from numba.core.registry import CPUDispatcher

    found = []
    for mod in modules:
        for obj in vars(mod).values():
            if isinstance(obj, CPUDispatcher) and isinstance(getattr(obj, "_cache", None),
                                                             FunctionCache):
                found.append(obj)
    return found


def kernels_cached(modules) -> bool:
    """Whether numba's cache holds every cached kernel of ``modules``, fresh (made from the
    current source) and for this machine's CPU: if not, their first call compiles."""
    try:
        kernels = cached_kernels(modules)
        for k in kernels:
            codegen = k.targetctx.codegen()
            # the index numba keeps beside its cached objects: empty when the cache is
            # missing or older than the source; its keys name the CPU each was built for
            index = k._cache._cache_file._load_index()
            if not any(key[1] == codegen.magic_tuple() for key in index):
                return False
        return bool(kernels)
    except Exception:        # numba's internals moved: we cannot tell, so say it may take long
        return False


def announce_compilation(modules) -> None:
    """Log (once per process, INFO on the ``gridflow`` logger) that the kernels are being
    compiled when numba's cache does not hold them yet, so a long first call is not silent."""
    global _announced
    if not _announced:
        _announced = True
        if not kernels_cached(modules):
            _log.info("compiling the estimator's numba kernels (once per installation, "
                      "20-40 s) ...")
