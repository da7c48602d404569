"""Rates from measured angles: smoothing differentiators for noisy, quantised, unevenly sampled logs.

On hardware the joint rates ``qd`` and the base angular velocity ``w0`` are not measured: they
come from differentiating encoder and motion-capture angles, and the differentiator decides much
of the final identification error (MATH.md section 6). This module turns angle samples into
smoothed angles and rates, choosing its bandwidth from the data and recording the choice.

Two families, both exact for polynomials of their degree and both working on the actual time
stamps (jitter and dropped samples need no resampling):

- ``"savgol"``: Savitzky-Golay filtering, i.e. a least-squares polynomial of degree ``order``
  fitted to the ``window`` samples around each sample, on their actual times (the window is
  shifted inwards at the ends of the record). Its bandwidth is chosen by a plug-in estimate of
  the derivative's mean squared error (see :func:`differentiate`).
- ``"spline"``: the cubic smoothing spline (natural boundary conditions, the function that
  :func:`scipy.interpolate.make_smoothing_spline` fits), computed in Reinsch form with banded
  algebra, its penalty chosen by generalised cross-validation (GCV).

A constant-acceleration Kalman smoother is not offered: with its process noise tuned by maximum
likelihood it was about 3 times less accurate than ``"savgol"`` on exciting trajectories, most
of the error at the two ends of the record.

References
----------
.. [1] A. Savitzky and M. J. E. Golay, "Smoothing and differentiation of data by simplified
   least squares procedures", Analytical Chemistry 36(8), 1964.
.. [2] J. Fan and I. Gijbels, "Local Polynomial Modelling and Its Applications", Chapman & Hall,
   1996, sections 3.7 and 4.2 (bias of local polynomial derivative estimators, plug-in
   bandwidths).
.. [3] T. Gasser, L. Sroka and C. Jennen-Steinmetz, "Residual variance and residual pattern in
   nonlinear regression", Biometrika 73(3), 1986 (noise variance from pseudo-residuals that
   annihilate polynomials on an uneven design).
.. [4] P. Craven and G. Wahba, "Smoothing noisy data with spline functions", Numerische
   Mathematik 31, 1979 (GCV).
.. [5] P. J. Green and B. W. Silverman, "Nonparametric Regression and Generalized Linear
   Models", Chapman & Hall, 1994, section 2.3 (the Reinsch algorithm).
.. [6] M. F. Hutchinson, "A stochastic estimator of the trace of the influence matrix for
   Laplacian smoothing splines", Communications in Statistics - Simulation and Computation
   18(3), 1989.
"""

from __future__ import annotations

import warnings

import numpy as np
from scipy.linalg import cho_solve_banded, cholesky_banded
from scipy.optimize import minimize_scalar

from .._errors import SpaceidError
from ._timeseries import first_unordered, quat_to_yaw, yaw_to_quat

__all__ = ["METHODS", "AUTO_METHOD", "estimate_noise", "differentiate", "differentiate_quaternion", "differentiate_log",
           "noise_gains"]

METHODS = ("auto", "savgol", "spline")
"""Values accepted by ``method``."""

AUTO_METHOD = "savgol"
"""The method ``method="auto"`` uses (the reasons are in :func:`differentiate`)."""

_AUTO_ORDERS = (3, 5, 7)  # polynomial degrees the automatic Savitzky-Golay choice compares
_PILOT_EXTRA = 3  # the bias pilot fits degree order + 3 ...
_PILOT_WIDTH = 2  # ... on a window about twice as wide
_WINDOW_RATIO = 1.25  # ratio of successive candidate windows, from the shortest to the record
_CRITERION_ROWS = 250  # evenly spaced samples on which the bandwidth criterion is averaged ...
_CRITERION_BUDGET = 125_000  # ... fewer (rows x pilot window at most this) for long windows ...
_MIN_ROWS = 64  # ... but never fewer than this
_CHUNK = 1 << 21  # local-fit elements (samples x window x coefficients) processed at a time
_NOISE_DIFFERENCE = 6  # order of the divided differences that estimate the noise
_MAD_TO_SIGMA = 1.482602218505602  # 1 / Phi^-1(3/4): median absolute deviation to std (Gaussian)
_PROBES = 16  # random sign vectors estimating the spline's hat-matrix trace for GCV
_WARN_GAP = 10.0  # steps longer than this many median steps are gaps (a warning) ...
_MAX_GAP = 100.0  # ... and beyond this many, differentiation would extrapolate (an error)
_MAX_DIFFERENCE = 1e-3  # signal-dominated sixth differences above this fraction of the range: too sparse
_QUAT_TOLERANCE = 1e-2  # |norm - 1| above which a series is not unit quaternions


def estimate_noise(t, x, *, quantum=None):
    """White-noise standard deviation of each channel, from high-order divided differences.

    Sixth-order divided differences on the actual time stamps annihilate every polynomial of
    degree 5 or less, so for a smooth signal they contain the noise alone. Each is scaled to
    unit-norm weights (then its variance is the noise variance) and the robust scale
    ``1.4826 * median(|d|)`` is taken [3]_. Quantisation of ``quantum`` per count is uniform
    noise of variance ``quantum**2 / 12``; the estimate never goes below it (a slow signal
    keeps the same rounding error for many samples and the differences then miss it).

    Parameters
    ----------
    t : array_like of shape (n_samples,)
        Strictly increasing time stamps [s], at least 7.
    x : array_like of shape (n_samples,) or (n_samples, n_channels)
        Samples, e.g. angles [rad].
    quantum : float, optional
        Resolution of the sensor [units of x per count], e.g. ``2 * pi / 4096`` rad for a
        4096 counts-per-revolution encoder.

    Returns
    -------
    sigma : ndarray of shape (n_channels,)
        Noise standard deviation per channel [units of x]; ``n_channels`` is 1 for 1-D ``x``.
    source : list of str
        Per channel, ``"differences"`` or ``"quantum"`` (the quantisation floor was larger).

    Raises
    ------
    SpaceidError
        Non-increasing stamps, non-finite values, fewer than 7 samples or a bad ``quantum``.
    """
    t, x, _ = _check_series(t, x, "x")
    quantum = _check_quantum(quantum, "x")
    _require_samples(t.size, _NOISE_DIFFERENCE + 1, "x", "the noise estimate")
    return _noise(t, x, quantum)


def differentiate(
    t, x, *, method="auto", window=None, order=None, smoothing=None, quantum=None, wrap=False, name="x"
):
    """Smoothed values and time derivatives of sampled signals, bandwidth chosen from the data.

    Parameters
    ----------
    t : array_like of shape (n_samples,)
        Strictly increasing time stamps [s]; uneven spacing (jitter, dropped samples) is fine.
    x : array_like of shape (n_samples,) or (n_samples, n_channels)
        Samples, typically angles [rad]; channels are treated independently.
    method : {"auto", "savgol", "spline"}
        ``"auto"`` is ``"savgol"``: its bandwidth rule targets the error of the derivative
        itself (GCV targets the values), each estimate depends only on the samples near it (a
        glitch or gap stays local), and on exciting trajectories it was 1.5 to 25 times more
        accurate than the spline, whose natural boundary conditions (f'' = 0) bias the rates
        at both ends of the record.
    window : int, optional
        Savitzky-Golay window in samples: odd, larger than ``order``, at most ``n_samples``.
        Chosen automatically when omitted.
    order : int, optional
        Savitzky-Golay polynomial degree, at least 1. When omitted, the automatic choice
        compares degrees 3, 5 and 7 (odd degrees: on a symmetric window degree 2k gives the same
        derivative as degree 2k - 1).
    smoothing : float, optional
        Spline penalty ``lam`` [s^3] of ``sum (x_i - f(t_i))^2 + lam * integral f''(t)^2 dt``,
        at least 0. Chosen by GCV when omitted.
    quantum : float, optional
        Sensor resolution [units of x per count], e.g. ``2 * pi / 4096`` rad for a 4096
        counts-per-revolution encoder: a floor of ``quantum / sqrt(12)`` on the noise level.
    wrap : bool
        Unwrap angles that jump by 2 pi at +-pi (motion-capture yaw, continuous joints) before
        smoothing; the smoothed angles are then returned unwrapped (continuous).
    name : str
        Name of the signal in error messages, e.g. ``"q_left_elbow"``.

    Returns
    -------
    x_smooth : ndarray, shape of ``x``
        Smoothed values [units of x].
    xdot : ndarray, shape of ``x``
        Time derivatives [units of x per s].
    info : dict
        What was done, JSON-ready, per-channel entries as lists (length 1 for 1-D ``x``):
        ``method``, ``requested`` (the ``method`` argument), ``window``, ``window_s`` (window
        span at the median step [s]) and ``order`` (Savitzky-Golay, else None), ``smoothing``
        (spline ``lam``, else None), ``selection`` (each tuning parameter: ``"auto"`` or
        ``"manual"``), ``rule`` (how the automatic values were chosen), ``noise`` (noise std
        per channel), ``noise_source`` (``"differences"`` or ``"quantum"``), ``quantum``,
        ``wrap`` and ``n_samples``.

    Raises
    ------
    SpaceidError
        Non-increasing or repeated stamps (the index is named), NaN or infinite values, an
        unknown method, options that do not belong to the method, a bad window, order,
        smoothing or quantum, a window longer than the record, or fewer samples than the
        differentiator needs.

    Notes
    -----
    Noise: ``sigma`` per channel from :func:`estimate_noise` (with the ``quantum`` floor).

    Savitzky-Golay bandwidth. Sample i's derivative is ``sum_j d_ij x_j`` over its window. For
    each candidate (order p, window w), the mean over the record of the squared derivative
    error is estimated as bias^2 + variance:

    - variance ``sigma^2 * mean_i sum_j d_ij^2`` (exact for white noise);
    - bias: the weights reproduce polynomials of degree p, so sample i's bias is
      ``b_i = sum_k a_ik M_ik`` over k = p+1, p+2, with the moments
      ``M_ik = sum_j d_ij (t_j - t_i)^k`` on the actual stamps and the Taylor coefficients
      ``a_ik = x^(k)(t_i) / k!`` taken from a pilot fit of degree p+3 on a window of 2w+1
      samples. The pilot is itself noisy, so its expected noise contribution
      ``sigma^2 * sum_j g_ij^2`` (``g_i`` the weights mapping the data to ``b_i``) is
      subtracted from ``mean_i b_i^2``, and the result is floored at 0 [2]_.

    Candidates are odd windows in steps of about 25 % from the shortest (p + 2) to the whole
    record, for p = 3, 5 and 7 unless ``order`` or ``window`` is given; the smallest estimate
    wins. The criterion is averaged over at most 250 evenly spaced samples (fewer for windows
    of thousands of samples), so long logs cost little.

    Spline penalty: the minimiser of ``GCV(lam) = n RSS(lam) / tr(I - A(lam))^2``, A the hat
    matrix [4]_, searched over quarter decades of ``lam`` then refined. GCV targets the
    smoothed values, not the rates: at low noise it undersmooths the rates in the middle of
    the record in exchange for less bias at its ends.

    Examples
    --------
    >>> t = np.arange(0, 5, 0.01)
    >>> rng = np.random.default_rng(0)
    >>> q = np.sin(t)[:, None] + 1e-4 * rng.standard_normal((t.size, 1))
    >>> q_s, qd, info = differentiate(t, q)
    >>> bool(np.abs(qd[:, 0] - np.cos(t)).max() < 1e-2), info["method"]
    (True, 'savgol')
    """
    t, x, shape = _check_series(t, x, name)
    quantum = _check_quantum(quantum, name)
    resolved, window, order = _check_tuning(t.size, method, window, order, smoothing, name)
    if wrap:
        x = np.unwrap(x, axis=0)
    _check_gaps(t, name)
    sigma, source = _noise(t, x, quantum)
    _check_resolution(t, x, sigma, name)
    x_smooth, xdot = np.empty_like(x), np.empty_like(x)
    windows, orders, lams = [], [], []
    for j in range(x.shape[1]):
        if resolved == "savgol":
            w, p = window, order
            if w is None or p is None:
                w, p = _select_savgol(t, x[:, j], sigma[j], window, order)
            x_smooth[:, j], xdot[:, j] = _savgol(t, x[:, j], w, p)
            windows.append(int(w))
            orders.append(int(p))
        else:
            x_smooth[:, j], xdot[:, j], lam = _spline(t, x[:, j], smoothing, name)
            lams.append(lam)

    step = float(np.median(np.diff(t)))
    if resolved == "savgol":
        selection = {"window": _how(window), "order": _how(order)}
        rule = "plug-in derivative MSE (moments on the stamps, degree p+3 pilot, noise subtracted)"
    else:
        selection = {"smoothing": _how(smoothing)}
        rule = f"generalised cross-validation (hat-matrix trace from {_PROBES} sign probes, seed 0)"
    info = {
        "method": resolved,
        "requested": method,
        "window": windows or None,
        "window_s": [(w - 1) * step for w in windows] or None,
        "order": orders or None,
        "smoothing": lams or None,
        "selection": selection,
        "rule": rule if "auto" in selection.values() else "manual",
        "noise": sigma.tolist(),
        "noise_source": source,
        "quantum": quantum,
        "wrap": bool(wrap),
        "n_samples": int(t.size),
    }
    return x_smooth.reshape(shape), xdot.reshape(shape), info


def differentiate_quaternion(t, quat, *, method="auto", window=None, order=None, smoothing=None):
    """Smoothed base attitude and base angular velocity in base axes from quaternion samples.

    The series is made sign-continuous (``q`` and ``-q`` are the same rotation, and motion
    capture may flip between them), its four components are smoothed and differentiated by
    :func:`differentiate`, the smoothed quaternion is renormalised, and the body rate is

        w_body = 2 * vec(conj(q) (x) qdot) / |q|^2,

    the kinematics ``qdot = q (x) [0, w_body] / 2`` of a base-to-inertial quaternion solved for
    ``w_body`` (dividing by ``|q|^2`` removes the part of ``qdot`` that changes the norm).
    A planar log (every quaternion a pure yaw, x = y = 0 exactly, as ``base_yaw`` columns are
    read) is a special case: the unwrapped yaw is differentiated instead, giving
    ``w_body = [0, 0, d yaw / dt]`` exactly as ``differentiate(t, yaw, wrap=True)`` would.

    Parameters
    ----------
    t : array_like of shape (n_samples,)
        Strictly increasing time stamps [s].
    quat : array_like of shape (n_samples, 4)
        Base attitude, scalar-first unit quaternions ``[w, x, y, z]``, base to inertial.
    method, window, order, smoothing
        As in :func:`differentiate`, applied to each quaternion component (or to the yaw).

    Returns
    -------
    quat_smooth : ndarray of shape (n_samples, 4)
        Smoothed unit quaternions, sign-continuous (the sign may differ from the input's).
    w_body : ndarray of shape (n_samples, 3)
        Base angular velocity in base axes [rad/s].
    info : dict
        The :func:`differentiate` record for the components (or the yaw), plus ``planar`` and
        ``sign_flips`` (how many samples were negated).

    Raises
    ------
    SpaceidError
        A shape other than (n_samples, 4), quaternions whose norm departs from 1 by more than
        1e-2, and everything :func:`differentiate` rejects.
    """
    quat = np.asarray(quat, dtype=float)
    if quat.ndim != 2 or quat.shape[1] != 4:
        raise SpaceidError(
            f"quat: expected shape (n_samples, 4) scalar-first [w, x, y, z], got {quat.shape}"
        )
    t, quat, _ = _check_series(t, quat, "quat")
    norm = np.linalg.norm(quat, axis=1)
    worst = int(np.argmax(np.abs(norm - 1)))
    if abs(norm[worst] - 1) > _QUAT_TOLERANCE:
        raise SpaceidError(
            f"quat: sample {worst} has norm {norm[worst]:.6g}, expected 1: give unit quaternions, "
            "scalar first [w, x, y, z]"
        )
    options = dict(method=method, window=window, order=order, smoothing=smoothing)
    if not quat[:, 1:3].any():
        yaw, yaw_rate, info = differentiate(t, quat_to_yaw(quat), wrap=True, name="base yaw", **options)
        w_body = np.zeros((t.size, 3))
        w_body[:, 2] = yaw_rate
        return yaw_to_quat(yaw), w_body, {**info, "planar": True, "sign_flips": 0}

    flips = np.cumsum(np.einsum("ij,ij->i", quat[1:], quat[:-1]) < 0) % 2 == 1
    quat = quat.copy()
    quat[1:][flips] *= -1
    q, qdot, info = differentiate(t, quat, name="quat", **options)
    s, v = q[:, :1], q[:, 1:]
    sdot, vdot = qdot[:, :1], qdot[:, 1:]
    norm2 = np.einsum("ij,ij->i", q, q)[:, None]
    w_body = 2 * (s * vdot - sdot * v - np.cross(v, vdot)) / norm2
    return q / np.sqrt(norm2), w_body, {**info, "planar": False, "sign_flips": int(flips.sum())}


def _how(value):
    return "auto" if value is None else "manual"


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


def _check_tuning(n, method, window, order, smoothing, name):
    """The resolved method and the validated window and order, or a SpaceidError."""
    if method not in METHODS:
        raise SpaceidError(f"{name}: unknown method {method!r}: choose one of {', '.join(METHODS)}")
    resolved = AUTO_METHOD if method == "auto" else method
    if resolved == "spline":
        for key, value in (("window", window), ("order", order)):
            if value is not None:
                raise SpaceidError(
                    f"{name}: {key}={value!r} applies to method='savgol', not 'spline': drop it or "
                    "set method='savgol' (the spline takes smoothing)"
                )
        if smoothing is not None and not _finite_number(smoothing, 0.0):
            raise SpaceidError(f"{name}: smoothing={smoothing!r}: expected a finite number >= 0 [s^3]")
        _require_samples(n, _NOISE_DIFFERENCE + 1, name, "method 'spline'")
        return resolved, None, None
    if smoothing is not None:
        raise SpaceidError(
            f"{name}: smoothing={smoothing!r} applies to method='spline', not {method!r}: "
            "drop it or set method='spline' (Savitzky-Golay takes window and order)"
        )
    order = _check_int(order, "order", name, minimum=1)
    window = _check_int(window, "window", name, minimum=(order or 0) + 1)
    if window is None:  # the bias pilot of the lowest order needs order + 4 samples
        needed = (order or min(_AUTO_ORDERS)) + _PILOT_EXTRA + 1
    elif window % 2 == 0:
        raise SpaceidError(f"{name}: window={window} is even: give an odd number of samples")
    elif order is None and window <= min(_AUTO_ORDERS):
        raise SpaceidError(
            f"{name}: window={window} is too short for the automatic orders {_AUTO_ORDERS}: "
            f"give an order below {window} or a longer window"
        )
    elif window > n:
        raise SpaceidError(
            f"{name}: window={window} is longer than the record ({n} samples): "
            f"choose an odd window of at most {n - 1 + n % 2} samples"
        )
    else:
        needed = window
    _require_samples(n, max(needed, _NOISE_DIFFERENCE + 1), name, "method 'savgol'")
    return resolved, window, order


def _finite_number(value, minimum):
    """Whether ``value`` is a real number, finite and at least ``minimum``."""
    number = isinstance(value, (int, float, np.integer, np.floating)) and not isinstance(value, bool)
    return number and np.isfinite(value) and value >= minimum


def _check_quantum(quantum, name):
    if quantum is None:
        return None
    if not (_finite_number(quantum, 0.0) and quantum > 0):
        raise SpaceidError(
            f"{name}: quantum={quantum!r}: expected the sensor resolution per count, a number > 0 "
            "(e.g. 2*pi/4096 rad for 4096 counts per revolution)"
        )
    return float(quantum)


def _check_int(value, key, name, *, minimum):
    if value is None:
        return None
    if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or value < minimum:
        raise SpaceidError(f"{name}: {key}={value!r}: expected an integer >= {minimum}")
    return int(value)


def _require_samples(n, needed, name, what):
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


def _check_resolution(t, x, sigma, name):
    """Refuse samples too sparse for local polynomial fits.

    For white noise the normalised sixth differences keep their size when every other sample is
    dropped; when they measure the signal instead they grow ~2^6 times. Signal-dominated
    differences above ``_MAX_DIFFERENCE`` of the channel's range mean the signal is not nearly
    polynomial over seven samples: the rates would be wrong, not noisy.
    """
    if t.size < 4 * (_NOISE_DIFFERENCE + 1):
        return
    coarse, _ = _noise(t[::2], x[::2], None)
    span = np.ptp(x, axis=0)
    bad = (((coarse > 4 * sigma) & (sigma > _MAX_DIFFERENCE * span)) | (sigma > 0.1 * span)) & (span > 0)  # or aliased
    if bad.any():
        j = int(np.argmax(bad))
        raise SpaceidError(
            f"{name}: channel {j} is sampled too sparsely to differentiate ({1 / np.median(np.diff(t)):.3g} Hz: its "
            f"sixth differences are signal, {sigma[j] / span[j]:.1%} of its range, not noise): record faster or log "
            "the rates"
        )


def _noise(t, x, quantum):
    """Per-channel noise std and its source, for validated (n, m) samples (see estimate_noise)."""
    k = _NOISE_DIFFERENCE
    idx = np.arange(t.size - k)[:, None] + np.arange(k + 1)
    gaps = t[idx][:, :, None] - t[idx][:, None, :]
    gaps[:, np.arange(k + 1), np.arange(k + 1)] = 1.0
    weights = 1.0 / np.prod(gaps, axis=2)
    weights /= np.linalg.norm(weights, axis=1, keepdims=True)
    differences = np.einsum("ik,ikm->im", weights, x[idx])
    sigma = _MAD_TO_SIGMA * np.median(np.abs(differences), axis=0)
    floor = 0.0 if quantum is None else quantum / np.sqrt(12.0)
    source = ["quantum" if s < floor else "differences" for s in sigma]
    return np.maximum(sigma, floor), source


_GAINS: dict = {}  # (stamps, method, setting) -> per-sample (smoothing, derivative) gains


def noise_gains(t, method: str, *, window=None, order=None, smoothing=None):
    """Noise gains of a differentiator at every sample: how white noise of unit variance on a
    channel reaches its smoothed values and its derivative.

    Parameters
    ----------
    t : ndarray of shape (n,)
        Time stamps [s].
    method : {"savgol", "spline"}
        With the setting :func:`differentiate` recorded for the channel: ``window`` and
        ``order`` (Savitzky-Golay) or ``smoothing`` (spline).

    Returns
    -------
    smooth, rate : ndarray of shape (n,)
        Norms of the smoothing weights ``|s_i|`` [-] and of the derivative weights ``|d_i|``
        [1/s]: the smoothed value's noise std is ``sigma |s_i|``, the rate's ``sigma |d_i|``.
        Savitzky-Golay weights are the rows of the local fits' pseudo-inverses; the spline's (a
        linear smoother for a fixed penalty) its responses to unit impulses. Cached by stamps
        and setting (Monte Carlo studies ask for the same ones many times).
    """
    t = np.asarray(t, float)
    key = (t.tobytes(), method, window, order, smoothing)
    if key in _GAINS:
        return _GAINS[key]
    n = t.size
    if method == "savgol":
        smooth, rate = np.empty(n), np.empty(n)
        step = max(1, _CHUNK // (window * (order + 1)))
        for first in range(0, n, step):
            rows = np.arange(first, min(first + step, n))
            _, _, pinv, scale = _local_fits(t, rows, window, order)
            smooth[rows] = np.linalg.norm(pinv[:, 0], axis=-1)
            rate[rows] = np.linalg.norm(pinv[:, 1], axis=-1) / scale
    else:
        values, rates, _ = differentiate(t, np.eye(n), method="spline", smoothing=smoothing)
        smooth, rate = np.linalg.norm(values, axis=1), np.linalg.norm(rates, axis=1)
    if len(_GAINS) > 64:
        _GAINS.clear()
    _GAINS[key] = (smooth, rate)
    return smooth, rate


def _local_fits(t, rows, window, order):
    """Polynomial fits of degree ``order`` to the ``window`` samples around each of ``rows``.

    Returns the window indices (r, window), the scaled offsets ``u_ij = (t_j - t_i) / scale_i``
    (r, window), the pseudo-inverses (r, order + 1, window) of the Vandermonde matrices in ``u``
    and the scales (r,) [s] (half the window's time span). Row k of a pseudo-inverse divided by
    ``scale**k`` gives the weights of the k-th Taylor coefficient ``x^(k)(t_i) / k!``.
    """
    start = np.clip(rows - window // 2, 0, t.size - window)
    idx = start[:, None] + np.arange(window)
    scale = 0.5 * (t[idx[:, -1]] - t[idx[:, 0]])
    u = (t[idx] - t[rows, None]) / scale[:, None]
    vander = np.ones(u.shape + (order + 1,))
    np.cumprod(np.broadcast_to(u[..., None], u.shape + (order,)), axis=-1, out=vander[..., 1:])
    return idx, u, np.linalg.pinv(vander), scale


def _savgol(t, y, window, order):
    """Savitzky-Golay smoothing and derivative of one channel (n,) on the actual stamps."""
    value, rate = np.empty_like(y), np.empty_like(y)
    step = max(1, _CHUNK // (window * (order + 1)))
    for first in range(0, t.size, step):
        rows = np.arange(first, min(first + step, t.size))
        idx, _, pinv, scale = _local_fits(t, rows, window, order)
        value[rows] = np.einsum("rw,rw->r", pinv[:, 0], y[idx])
        rate[rows] = np.einsum("rw,rw->r", pinv[:, 1], y[idx]) / scale
    return value, rate


def _select_savgol(t, y, sigma, window, order):
    """(window, order) minimising the plug-in derivative MSE of :func:`differentiate`'s Notes."""
    n = t.size
    orders = [p for p in (_AUTO_ORDERS if order is None else (order,)) if window is None or p < window]
    best = (np.inf, None, None)
    for p in orders:
        if window is not None:
            candidates = [window]
        else:
            shortest, longest = p + 2 + (p + 1) % 2, n - 1 + n % 2
            count = int(np.ceil(np.log(longest / shortest) / np.log(_WINDOW_RATIO))) + 1
            candidates = np.unique(np.geomspace(shortest, longest, max(count, 1)).astype(int) | 1)
        for w in candidates:
            pilot = min(_PILOT_WIDTH * w + 1, n)
            if pilot <= p + _PILOT_EXTRA:  # only for the highest order on a 7- or 8-sample record
                continue
            count = min(n, _CRITERION_ROWS, max(_MIN_ROWS, _CRITERION_BUDGET // pilot))
            rows = np.unique(np.linspace(0, n - 1, count).round().astype(int))
            mse = _plugin_mse(t, y, sigma, rows, int(w), p, pilot)
            if mse < best[0]:
                best = (mse, int(w), p)
    return best[1], best[2]


def _power_sums(t, y, rows, window, degree):
    """Sums over each row's window of ``u**m`` (m = 0..degree) and of ``u**m * y`` (m up to
    degree / 2), ``u = (t_j - t_i) / scale_i`` as in :func:`_local_fits`; and the scales [s]."""
    start = np.clip(rows - window // 2, 0, t.size - window)
    idx = start[:, None] + np.arange(window)
    scale = 0.5 * (t[idx[:, -1]] - t[idx[:, 0]])
    u = (t[idx] - t[rows, None]) / scale[:, None]
    power, values = np.ones_like(u), y[idx]
    sums, weighted = np.empty((rows.size, degree + 1)), np.empty((rows.size, degree // 2 + 1))
    for m in range(degree + 1):
        sums[:, m] = power.sum(axis=1)
        if m <= degree // 2:
            weighted[:, m] = np.einsum("rw,rw->r", power, values)
        power *= u
    return sums, weighted, scale


def _inverse_gram(sums, size):
    """Inverses (r, size, size) of the Gram matrices ``G_ab = sums[:, a + b]`` (Jacobi-scaled)."""
    gram = sums[:, np.add.outer(np.arange(size), np.arange(size))]
    d = 1.0 / np.sqrt(np.einsum("rii->ri", gram))
    return d[:, :, None] * np.linalg.inv(d[:, :, None] * gram * d[:, None, :]) * d[:, None, :]


def _plugin_mse(t, y, sigma, rows, window, order, pilot):
    """Estimated mean squared derivative error of a (window, order) fit, averaged over ``rows``.

    The fit's derivative weights are ``d_i = V_i c_i / scale_i`` with ``c_i = G_i^-1 e_1``, so
    ``|d_i|^2 = c_i1 / scale_i^2`` and the moments ``M_ik = scale_i^(k-1) sum_a c_ia S_i(a+k)``
    follow from the power sums ``S`` alone; likewise the pilot's Taylor coefficients and their
    noise covariance ``sigma^2 H_kl / scale^(k+l)`` (``H`` the inverse pilot Gram matrix).
    """
    sums, _, scale = _power_sums(t, y, rows, window, 2 * order + 2)
    c = _inverse_gram(sums, order + 1)[:, :, 1]
    variance = sigma**2 * np.mean(c[:, 1] / scale**2)
    powers = np.arange(order + 1, order + 3)
    moments = np.stack(
        [np.einsum("ra,ra->r", c, sums[:, k : k + order + 1]) * scale ** (k - 1) for k in powers], axis=1
    )
    degree = order + _PILOT_EXTRA
    sums, weighted, scale = _power_sums(t, y, rows, pilot, 2 * degree)
    inverse = _inverse_gram(sums, degree + 1)[:, powers]
    taylor = np.einsum("rkb,rb->rk", inverse, weighted) / scale[:, None] ** powers
    scaled = moments / scale[:, None] ** powers
    bias = np.einsum("rk,rk->r", moments, taylor)
    pilot_noise = sigma**2 * np.einsum("rk,rkl,rl->r", scaled, inverse[:, :, powers], scaled)
    return max(np.mean(bias**2 - pilot_noise), 0.0) + variance


def _spline(t, y, lam, name):
    """Cubic smoothing spline of one channel in Reinsch form: values, derivative, penalty.

    With steps ``h``, the tridiagonal ``Q`` (n, n-2) of second divided differences and ``R``
    (n-2, n-2), the spline's second derivatives at the inner stamps solve
    ``(R + lam Q^T Q) gamma = Q^T y`` and its values are ``g = y - lam Q gamma`` [5]_.
    """
    n, h = t.size, np.diff(t)
    a, c = 1.0 / h[:-1], 1.0 / h[1:]  # column j of Q holds (a_j, b_j, c_j) at rows j, j+1, j+2
    b = -a - c
    bands = np.zeros((2, 3, n - 2))  # upper banded storage of R and of Q^T Q
    bands[0, 2], bands[0, 1, 1:] = (h[:-1] + h[1:]) / 3, h[1:-1] / 6
    bands[1, 2] = a**2 + b**2 + c**2
    bands[1, 1, 1:] = b[:-1] * a[1:] + c[:-1] * b[1:]
    bands[1, 0, 2:] = c[:-2] * a[2:]

    def q_t(v):  # Q^T v for v of shape (n, k)
        return a[:, None] * v[:-2] + b[:, None] * v[1:-1] + c[:, None] * v[2:]

    def q(gamma):  # Q gamma for gamma of shape (n - 2, k)
        out = np.zeros((n, gamma.shape[1]))
        out[:-2] += a[:, None] * gamma
        out[1:-1] += b[:, None] * gamma
        out[2:] += c[:, None] * gamma
        return out

    def solve(lam, rhs):
        return cho_solve_banded((cholesky_banded(bands[0] + lam * bands[1]), False), rhs)

    if lam is None:
        lam = _gcv_penalty(t, y, q_t, q, solve)
    try:
        gamma = solve(lam, q_t(y[:, None]))
    except np.linalg.LinAlgError:
        raise SpaceidError(
            f"{name}: smoothing={lam:.3g} makes the spline system numerically singular for this "
            "record: give a smaller value"
        ) from None
    value = y - lam * q(gamma)[:, 0]
    second = np.r_[0.0, gamma[:, 0], 0.0]  # natural spline: f'' = 0 at both ends
    slope = np.diff(value) / h
    last = slope[-1] + h[-1] * (second[-2] + 2 * second[-1]) / 6  # the end of the last interval
    rate = np.r_[slope - h * (2 * second[:-1] + second[1:]) / 6, last]
    return value, rate, float(lam)


def _gcv_penalty(t, y, q_t, q, solve):
    """Spline penalty minimising GCV(lam) = n RSS / tr(I - A)^2 (A the hat matrix) [4]_.

    ``RSS = lam^2 |Q gamma|^2`` and ``tr(I - A) = lam tr(Q M^-1 Q^T)`` with
    ``M = R + lam Q^T Q``; the trace is estimated with fixed random sign probes ``z``
    (``mean z^T Q M^-1 Q^T z``, the same probes for every ``lam``, so the choice is
    reproducible) [6]_. ``lam`` is searched on a grid of quarter decades between equivalent
    bandwidths ``(lam h)^(1/4)`` of a quarter step and a quarter of the record, then refined.
    """
    n, step, span = t.size, np.median(np.diff(t)), t[-1] - t[0]
    probes = np.random.default_rng(0).choice([-1.0, 1.0], size=(n, _PROBES))
    rhs = q_t(np.column_stack([y, probes]))

    def gcv(log_lam):
        lam = 10.0**log_lam
        try:
            solution = solve(lam, rhs)
        except np.linalg.LinAlgError:
            return np.inf
        residual = lam**2 * np.sum(q(solution[:, :1]) ** 2)
        trace = lam * np.mean(np.sum(rhs[:, 1:] * solution[:, 1:], axis=0))
        return n * residual / trace**2

    bounds = np.log10([(step / 4) ** 4 / step, (span / 4) ** 4 / step])
    grid = np.arange(bounds[0], bounds[1] + 0.25, 0.25)
    values = [gcv(g) for g in grid]
    best = int(np.argmin(values))
    refined = minimize_scalar(
        gcv, bounds=(grid[max(best - 1, 0)], grid[min(best + 1, grid.size - 1)]), method="bounded",
        options={"xatol": 1e-3},
    )
    return 10.0 ** (refined.x if refined.fun <= values[best] else grid[best])


def differentiate_log(log, *, method: str = "auto", window=None, order=None, smoothing=None, quantum=None):
    """A log whose joint rates and base angular velocity come from its angles and attitude.

    Joint angles are differentiated channel by channel (``quantum`` [rad per count] for
    encoders), the base attitude with :func:`differentiate_quaternion`; the angles are replaced
    by their smoothed values. What was used is recorded in ``meta["differentiation"]``.

    Parameters
    ----------
    log : spaceid.Log
    method, window, order, smoothing, quantum
        As in :func:`differentiate` (``quantum`` applies to the joints only).

    Returns
    -------
    spaceid.Log
    """
    from dataclasses import replace

    q, qd, info_q = differentiate(log.t, log.q, method=method, window=window, order=order, smoothing=smoothing,
                                  quantum=quantum, name="joint angles")
    quat, w, info_b = differentiate_quaternion(log.t, log.base_quat, method=method, window=window, order=order,
                                               smoothing=smoothing)
    meta = dict(log.meta, differentiation={"joints": info_q, "base": info_b})
    return replace(log, q=q.reshape(log.q.shape), qd=qd.reshape(log.q.shape), base_quat=quat, base_w=w, meta=meta)
