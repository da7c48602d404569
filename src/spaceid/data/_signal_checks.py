"""Input checks of the differentiators: sample series, stamps, gaps, numbers and integers.

Each check turns a defect into a one-line :class:`~spaceid.SpaceidError` that names the signal
(``name``, e.g. ``"q_left_elbow"``) and the fix.
"""

from __future__ import annotations

import warnings

import numpy as np

from .._errors import SpaceidError
from ._timeseries import first_unordered

_WARN_GAP = 10.0  # steps longer than this many median steps are gaps (a warning) ...
_MAX_GAP = 100.0  # ... and beyond this many, differentiation would extrapolate (an error)


def _check_series(t, x, name):
    """``t`` as (n,) and ``x`` as (n, m) float arrays plus ``x``'s shape, or a SpaceidError."""
    t = np.asarray(t, dtype=float)
    x = np.asarray(x, dtype=float)
    if t.ndim != 1:
        raise SpaceidError(f"{name}: time stamps must be 1-D (n_samples,), got shape {t.shape}")
    if x.ndim not in (1, 2) or x.shape[0] != t.size:
        raise SpaceidError(
            f"{name}: expected shape ({t.size},) or ({t.size}, n_channels) to match the "
            f"{t.size} time stamps, got {x.shape}"
        )
    bad = np.flatnonzero(~np.isfinite(t))
    if bad.size:
        raise SpaceidError(f"{name}: time stamp t[{bad[0]}] is {t[bad[0]]}: drop or repair that sample")
    unordered = first_unordered(t)
    if unordered:
        i, count, kind = unordered
        raise SpaceidError(
            f"{name}: time stamp t[{i}] = {float(t[i])!r} {kind} t[{i - 1}] = {float(t[i - 1])!r} "
            f"({count} such step(s)): stamps must be strictly increasing; sort the log and "
            "drop repeated samples"
        )
    x2 = x.reshape(t.size, -1)
    bad = np.argwhere(~np.isfinite(x2))
    if bad.size:
        i, j = bad[0]
        where = f"{name}[{i}]" if x.ndim == 1 else f"{name}[{i}, {j}]"
        raise SpaceidError(
            f"{name}: {where} is {x2[i, j]} ({len(bad)} non-finite value(s)): fill or drop those "
            "samples before differentiating"
        )
    return t, x2, x.shape


def _finite_number(value, minimum):
    """Whether ``value`` is a real number, finite and at least ``minimum``."""
    number = isinstance(value, (int, float, np.integer, np.floating)) and not isinstance(value, bool)
    return number and np.isfinite(value) and value >= minimum


def _check_quantum(quantum, name):
    """The sensor resolution as a float (None stays None), or a SpaceidError."""
    if quantum is None:
        return None
    if not (_finite_number(quantum, 0.0) and quantum > 0):
        raise SpaceidError(
            f"{name}: quantum={quantum!r}: expected the sensor resolution per count, a number > 0 "
            "(e.g. 2*pi/4096 rad for 4096 counts per revolution)"
        )
    return float(quantum)


def _check_int(value, key, name, *, minimum):
    """``value`` as an int of at least ``minimum`` (None stays None), or a SpaceidError."""
    if value is None:
        return None
    if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or value < minimum:
        raise SpaceidError(f"{name}: {key}={value!r}: expected an integer >= {minimum}")
    return int(value)


def _require_samples(n, needed, name, what):
    """A SpaceidError when ``n`` samples are fewer than ``what`` (a differentiator) needs."""
    if n < needed:
        raise SpaceidError(
            f"{name}: {n} samples are too few for {what}, which needs at least {needed}: a sample "
            "rate too low for the chosen differentiator; record longer or faster, or give a "
            "smaller window or order"
        )


def _check_gaps(t, name):
    """Gaps (dropped samples): local fits on the actual stamps bridge short ones (a warning);
    one over ``_MAX_GAP`` median steps would be extrapolation (an error)."""
    steps = np.diff(t)
    i = int(np.argmax(steps))
    median = float(np.median(steps))
    if steps[i] <= _WARN_GAP * median:
        return
    text = (f"{name}: a gap of {steps[i]:.3g} s after t = {t[i]:.6g} ({steps[i] / median:.0f} times the median step "
            f"{median:.3g} s)")
    if steps[i] > _MAX_GAP * median:
        raise SpaceidError(f"{text}: too long to differentiate across; split the log at the gap or log the rates")
    warnings.warn(f"{text}: the rates near it are bridged by the local fits", stacklevel=3)
