"""Memory a run may take: the machine's available memory, and a refusal before allocating more.

A sample count from an option (``--samples 1e9``, ``--rate 1e9``) would otherwise end, minutes
later, in MemoryError or in the machine swapping; :func:`require_memory` refuses it up front
with the number.
"""

from __future__ import annotations

import os

from ._errors import SpaceidError

__all__ = ["available_memory", "require_memory", "GiB"]

GiB = 1 << 30


def available_memory() -> float:
    """Memory a new allocation may take now [bytes]: ``MemAvailable`` of ``/proc/meminfo``
    (free memory plus reclaimable caches), else the free physical pages; inf when unknown."""
    try:
        with open("/proc/meminfo") as handle:
            for line in handle:
                if line.startswith("MemAvailable:"):
                    return float(line.split()[1]) * 1024  # the file counts kB
    except OSError:
        pass
    try:
        return float(os.sysconf("SC_AVPHYS_PAGES") * os.sysconf("SC_PAGE_SIZE"))
    except (ValueError, OSError, AttributeError):
        return float("inf")


def require_memory(needed: float, what: str, fix: str) -> None:
    """A one-line SpaceidError when ``needed`` [bytes] exceeds :func:`available_memory`.

    Parameters
    ----------
    needed : float
        Estimated peak memory of the run [bytes].
    what : str
        The option or input that sets the size, and its value (e.g. ``"--rate 1e+09: 5e+09 samples"``).
    fix : str
        What to give instead.
    """
    available = available_memory()
    if needed > available:
        raise SpaceidError(f"{what} would need about {needed / GiB:.3g} GiB of memory, more than the "
                           f"{available / GiB:.3g} GiB available: {fix}")
