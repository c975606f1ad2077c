"""The C allocator's settings for a ``gridflow`` process (glibc only).

A step of a recording allocates and frees a few hundred arrays of a few MB to a few
hundred MB (the structure tensor's planes, the FFTs' work arrays, the signals) on each of
the threads that run steps at once.  Under glibc's defaults every such thread gets its
own arena, whose free memory is handed back to the system after each array and faulted
in (zeroed by the kernel) for the next, and arrays above a threshold that grows only up
to 32 MiB are mapped afresh every time.  Measured on 512^2, 5 x 5 affine recording steps (two at once on 2 cores,
``bench/README.md``, *The allocator*): the kernel's share of the process's CPU time (page
faults) was 16-26 %.

:func:`tune_allocator` sets, with ``mallopt``, before any thread of the process starts:

* one arena for all threads (``M_ARENA_MAX``): the threads reuse each other's freed
  memory, instead of each arena holding its own (the peak memory fell as well);
* every array from the heap (``M_MMAP_MAX = 0``), none mapped on its own;
* freed memory kept for the next step instead of being handed back after every array
  (``M_TRIM_THRESHOLD``, up to 2 GiB free at the heap's top): the process keeps the
  memory of its largest step until it exits, which is its peak anyway.

Nothing is set where the C library is not glibc, or where the user set glibc's malloc
variables (any ``MALLOC_*`` variable, or ``glibc.malloc.*`` in ``GLIBC_TUNABLES``):
theirs hold.  ``GRIDFLOW_MALLOC=system`` leaves the allocator as it is.  The estimates
do not depend on any of this (the same arrays, the same arithmetic).  Only the
command-line process is tuned: the library, imported into someone else's process, does
not change that process's allocator, and worker processes (``gridflow sweep
--workers``'s pool, a ``dask.distributed`` cluster's workers, ``--connect``) run under
their own settings.

What it costs: the process keeps the memory of its largest step until it exits; free
memory inside the heap (not at its top) is not handed back either, so a long run's
memory could grow by fragmentation (44 affine steps at 512^2 measured flat); a large
``numpy.zeros`` taken from memory the heap kept is zeroed by glibc's ``calloc`` instead
of arriving as fresh zero pages.
"""

from __future__ import annotations

import os
import sys

__all__ = ["tune_allocator", "SETTINGS"]

# mallopt's parameter numbers (glibc's malloc.h)
_M_TRIM_THRESHOLD, _M_MMAP_MAX, _M_ARENA_MAX = -1, -4, -8

#: (name, mallopt parameter, value): what :func:`tune_allocator` sets, in this order
SETTINGS = (
    ("M_ARENA_MAX", _M_ARENA_MAX, 1),
    # no array mapped on its own: the large ones (the tensor's planes, 300 MB for an
    # affine step at 512^2) come from the heap as the small ones do, instead of being
    # mapped and faulted in anew each step
    ("M_MMAP_MAX", _M_MMAP_MAX, 0),
    # mallopt takes an int: the largest it takes, 2 GiB of free memory at the heap's top
    # (setting it stops glibc's own adjustment of it)
    ("M_TRIM_THRESHOLD", _M_TRIM_THRESHOLD, 2**31 - 1),
)


def _users_own(env) -> bool:
    """Whether the environment gives glibc malloc settings of the user's own."""
    return (any(name.startswith("MALLOC_") for name in env)
            or "glibc.malloc." in env.get("GLIBC_TUNABLES", ""))


def tune_allocator(environ=None) -> tuple[str, ...]:
    """Set glibc's allocator for a process of steps at once (module docstring).

    Call before the process starts its threads: an arena already given to a thread stays
    its own.

    Parameters
    ----------
    environ : mapping, optional
        The environment to read the opt-outs from (default ``os.environ``).

    Returns
    -------
    tuple of str
        The names of the settings made (empty where none: not glibc, the user's own
        settings, ``GRIDFLOW_MALLOC=system``, or a setting glibc refused, after which
        the rest are not tried).
    """
    env = os.environ if environ is None else environ
    if env.get("GRIDFLOW_MALLOC", "").strip().lower() == "system":
        return ()
    if _users_own(env):
        return ()
    if not sys.platform.startswith("linux"):
        return ()
    try:
        libc_name = os.confstr("CS_GNU_LIBC_VERSION") or ""
    except (ValueError, OSError):
        libc_name = ""
    if not libc_name.startswith("glibc"):
        return ()
    try:
        import ctypes

        libc = ctypes.CDLL(None)
        mallopt = libc.mallopt
    except (ImportError, OSError, AttributeError):
        return ()
    mallopt.argtypes = (ctypes.c_int, ctypes.c_int)
    mallopt.restype = ctypes.c_int
    made = []
    for name, param, value in SETTINGS:
        if mallopt(param, value) != 1:
            break
        made.append(name)
    return tuple(made)
