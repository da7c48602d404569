"""Compiled kernels: Numba's ``njit`` as the project uses it."""

from __future__ import annotations

import numba

__all__ = ["kernel"]


def kernel(fn):
    """``fn`` compiled to machine code without the GIL (threads run kernels side by side) and
    without fastmath (IEEE arithmetic: a sample's result does not depend on the threads or on how
    the samples are grouped). Cached on disk in ``$NUMBA_CACHE_DIR`` when set, else beside its
    module, else in the user's cache; where none can be written it is compiled anew in each
    process."""
    try:
        return numba.njit(cache=True, nogil=True)(fn)
    except RuntimeError:  # Numba found no writable cache directory
        return numba.njit(nogil=True)(fn)
