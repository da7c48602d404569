"""Input checks of the differentiators (sample series, stamps, gaps, numbers and integers), and
the plausibility checks of a log as read (:func:`plausibility_warnings`: stamps, rates and angle
columns that read but disagree with each other).

Each check turns a defect into a one-line :class:`~spaceid.SpaceidError` that names the signal
(``name``, e.g. ``"q_left_elbow"``) and the fix, or a warning that names the columns and the
likely cause.
"""

from __future__ import annotations

import warnings

import numpy as np

from .._errors import SpaceidError
from ._timeseries import first_unordered, quat_to_matrix

__all__ = ["check_time_units", "plausibility_warnings"]

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
            f"{name}: `quantum` {quantum!r}: expected the sensor resolution per count, a number > 0 "
            "(e.g. 0.00153 rad for 4096 counts per revolution)"
        )
    return float(quantum)


def _check_int(value, key, name, *, minimum):
    """``value`` as an int of at least ``minimum`` (None stays None), or a SpaceidError."""
    if value is None:
        return None
    if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or value < minimum:
        raise SpaceidError(f"{name}: `{key}` {value!r}: expected an integer >= {minimum}")
    return int(value)


def _require_samples(n, needed, name, what):
    """A SpaceidError when ``n`` samples are fewer than ``what`` (a differentiator) needs."""
    if n < needed:
        raise SpaceidError(
            f"{name}: {n} samples are too few for {what}, which needs at least {needed}: a sample "
            "rate too low for the chosen differentiator; record longer or faster, or give a "
            "smaller `window` or `order`"
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


# --- plausibility of a readable log (issue 12): units, orders and labels that read but are wrong ------

_SLOW_STEP = 1.0  # [s] a median step above this is slower than any robot's log: stamps in ms? (a warning)
_NS_STEP = 1e5  # [s] above this (a day between samples) the stamps cannot be seconds (an error)
_MIN_TRAVEL = 0.05  # [rad] columns that move less than this are not compared (noise would dominate)
_MISMATCH = 0.5  # relative misfit of the angle increments against the rate's integral beyond which they disagree
_SCALE_TOL = 1.25  # a ratio of the rate's integral to the angle change within [1/tol, tol] is consistent
_KNOWN_RATIOS = {  # ratio of the rate's integral to the angle's change: its likely cause
    180 / np.pi: "the rate in deg/s (or the angle in rad where the rate is right)",
    np.pi / 180: "the angle in degrees",
    1e3: "time stamps in milliseconds",
    1e6: "time stamps in microseconds",
    1e9: "time stamps in nanoseconds",
}
_CHECK_POINTS = 200  # increments compared per column (longer logs are compared over strides)


def _rotation_increments(quat):
    """Body-axes rotation vectors [rad] from each attitude to the next, shape (n - 1, 3), of
    scalar-first quaternions ``quat (n, 4)``."""
    rot = quat_to_matrix(quat)
    rel = np.einsum("nji,njk->nik", rot[:-1], rot[1:])  # R_k^T R_k+1
    v = 0.5 * np.stack([rel[:, 2, 1] - rel[:, 1, 2], rel[:, 0, 2] - rel[:, 2, 0], rel[:, 1, 0] - rel[:, 0, 1]], -1)
    sin = np.linalg.norm(v, axis=1)
    angle = np.arctan2(sin, 0.5 * (np.trace(rel, axis1=1, axis2=2) - 1))
    return v * np.where(sin > 1e-12, angle / np.where(sin > 1e-12, sin, 1), 1.0)[:, None]


def _strided(increments, stride):
    """Sums of ``increments (n - 1, m)`` over consecutive strides of ``stride`` samples."""
    m = increments.shape[0] // stride * stride
    return increments[:m].reshape(-1, stride, increments.shape[1]).sum(axis=1)


def _agreement(angle_steps, rate_steps):
    """``(ratio, misfit)`` of angle increments against the rate's integral over the same steps
    (both (k, m)): ``ratio`` the integral's size over the increments' (least squares), ``misfit``
    the relative residual of the increments after that scaling; None when either barely moves."""
    a, b = angle_steps.ravel(), rate_steps.ravel()
    if not np.all(np.isfinite(b)) or np.sum(np.abs(a)) < _MIN_TRAVEL or np.sum(np.abs(b)) < _MIN_TRAVEL:
        return None
    with np.errstate(all="ignore"):  # huge values are refused elsewhere: no overflow warnings from a check
        k = float(a @ b / (b @ b))  # a ~ k b
        misfit = float(np.linalg.norm(a - k * b) / np.linalg.norm(a))
    if not np.isfinite(misfit):
        return None
    return (1 / k if k else np.inf), misfit


def _likely_cause(ratio):
    """The cause of a rate integral ``ratio`` times the angle change, or None."""
    for known, cause in _KNOWN_RATIOS.items():
        if abs(np.log(abs(ratio) / known)) < np.log(_SCALE_TOL):
            return cause
    return None


def _pairs(log, wheels):
    """``{label: (angle increments, rate increments, angle column, rate column)}`` per stride,
    for the base attitude and every joint but the reaction wheels."""
    n = log.n_samples
    stride = max(1, (n - 1) // _CHECK_POINTS)
    dt = np.diff(log.t)[:, None]
    trapezoid = lambda x: 0.5 * (x[1:] + x[:-1]) * dt  # noqa: E731
    base = (("base_yaw", "base_wz") if log.planar else
            ("base_qw, base_qx, base_qy, base_qz", "base_wx, base_wy, base_wz"))
    w = log.base_w[:, 2:] if log.planar else log.base_w
    pairs = {"base": (_strided(_rotation_increments(log.base_quat)[:, 2:] if log.planar else
                               _rotation_increments(log.base_quat), stride), _strided(trapezoid(w), stride), *base)}
    for j, joint in enumerate(log.joints):
        if joint not in wheels:
            pairs[joint] = (_strided(np.diff(log.q[:, j:j + 1], axis=0), stride),
                            _strided(trapezoid(log.qd[:, j:j + 1]), stride), f"q_{joint}", f"qd_{joint}")
    return pairs, stride


def plausibility_warnings(log, where, wheels=()) -> list:
    """Warnings about a log that reads but is likely wrong: each names the column and the
    likely cause (docs/formats/log-csv.md, "Plausibility checks").

    - time stamps far slower than a robot's log (a median step above 1 s: milliseconds?);
    - an angle column whose increments disagree with the integral of its rate column (columns
      swapped or mislabelled, a quaternion stored x, y, z, w), or agree only after scaling by
      a telling factor (a rate in deg/s, an angle in degrees, stamps in ms, us or ns).

    Parameters
    ----------
    log : Log
        The log as read (rates NaN where missing: those columns are not compared).
    where : str
        The log's name, for messages.
    wheels : sequence of str
        Reaction-wheel joints, not compared (their angle wraps at their speed).

    Returns
    -------
    list of str
        The warnings, empty for a plausible log.

    Raises
    ------
    SpaceidError
        A median time step above a day: the stamps cannot be in seconds.
    """
    if log.n_samples < 3:
        return []
    median = float(np.median(np.diff(log.t)))
    if median > _NS_STEP:
        raise SpaceidError(f"{where}: column t: the median time step is {median:.3g} s (more than a day): the stamps "
                           "look like nanoseconds or microseconds: convert t to seconds")
    found = []
    if median > _SLOW_STEP:
        found.append(f"{where}: column t: the median time step is {median:.3g} s ({1 / median:.3g} Hz), far slower "
                     "than a robot's log: if the stamps are in milliseconds, divide t by 1000 (rates differentiated "
                     "from them would be 1000 times too small, every parameter 1000 times too large)")
    pairs, stride = _pairs(log, wheels)
    agreement = {label: _agreement(a, b) for label, (a, b, _, _) in pairs.items()}
    stamps = _stamps_in_other_units(agreement, where)
    if stamps:
        return [stamps]
    for label, result in agreement.items():
        if result is None:
            continue
        ratio, misfit = result
        _, _, angle, rate = pairs[label]
        if misfit >= _MISMATCH:
            found.append(_disagreement(log, label, pairs, where, misfit, stride))
        elif abs(np.log(abs(ratio))) > np.log(_SCALE_TOL):
            cause = _likely_cause(ratio) or "a unit or scale error in one of them"
            found.append(f"{where}: columns {angle} and {rate}: the rate integrates to {ratio:.3g} times the "
                         f"angle's change: likely {cause}")
    return found


def _stamps_in_other_units(agreement, where) -> str | None:
    """The warning that every rate integrates to one telling factor (1e3, 1e6, 1e9) times its
    angle's change: stamps in ms, us or ns; None otherwise."""
    ratios = [r for r, misfit in filter(None, agreement.values()) if misfit < _MISMATCH]
    cause = _likely_cause(np.median(ratios)) if len(ratios) > 1 else None
    if not (cause and cause.startswith("time stamps") and all(_likely_cause(r) == cause for r in ratios)):
        return None
    return (f"{where}: column t: every rate integrates to {np.median(ratios):.3g} times its angle's change: "
            f"{cause}? Convert t to seconds (rates differentiated from these stamps, and validation, would be off "
            "by that factor)")


def check_time_units(log, where: str, wheels=()) -> None:
    """A SpaceidError naming the log's column t when its stamps are not seconds (every rate
    integrates to 1e3, 1e6 or 1e9 times its angle's change): for what re-simulates the log in
    time (validation, prediction), where such stamps give meaningless figures."""
    if log.n_samples >= 3:
        pairs, _ = _pairs(log, wheels)
        stamps = _stamps_in_other_units({k: _agreement(a, b) for k, (a, b, _, _) in pairs.items()}, where)
        if stamps:
            raise SpaceidError(stamps)


def _disagreement(log, label, pairs, where, misfit, stride):
    """The warning for angle column(s) ``label`` whose increments do not follow their rate:
    naming the other joint's angle that does (swapped columns) or the quaternion order that does."""
    a, b, angle, rate = pairs[label]
    text = (f"{where}: columns {angle} and {rate} disagree: the angle's increments depart from the rate's integral "
            f"by {100 * misfit:.0f} %")
    if label == "base" and not log.planar:
        xyzw = _rotation_increments(log.base_quat[:, [3, 0, 1, 2]])
        fit = _agreement(_strided(xyzw, stride), b)
        if fit and fit[1] < _MISMATCH:
            return text + ": the quaternion looks stored x, y, z, w: reorder the columns to w, x, y, z (scalar first)"
    for other, (a2, _, angle2, _) in pairs.items():
        fit = _agreement(a2, b) if other not in ("base", label) and a2.shape == b.shape else None
        if fit and fit[1] < _MISMATCH:
            return text + f", while {angle2} follows {rate}: columns swapped or mislabelled? Check the header"
    return text + ": the columns are mislabelled, swapped or hold other signals (a rate of another joint, a filtered " \
                  "or delayed signal): check the header and units"
