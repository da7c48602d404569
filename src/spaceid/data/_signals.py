"""Rates from measured angles: smoothing differentiators for noisy, quantised, unevenly sampled logs.

On hardware the joint rates ``qd`` and the base angular velocity ``w0`` are not measured: they
come from differentiating encoder and motion-capture angles, and the differentiator decides much
of the final identification error (docs/theory/noise.md). This module turns angle samples into
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

This module holds the public differentiators and their settings; the pieces are private
modules beside it: the noise estimate (``_signal_noise``), the Savitzky-Golay fits and their
bandwidth (``_signal_savgol``), the smoothing spline and GCV (``_signal_spline``) and the input
checks (``_signal_checks``).

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

import numpy as np

from .._errors import SpaceidError
from ._signal_checks import _check_gaps, _check_int, _check_quantum, _check_series, _finite_number, _require_samples
from ._signal_noise import _NOISE_DIFFERENCE, _check_resolution, _noise, _pooled_noise
from ._signal_savgol import _AUTO_ORDERS, _PILOT_EXTRA, _new_fits, _savgol, _savgol_gains, _select_savgol
from ._signal_spline import _PROBES, _spline
from ._timeseries import quat_to_yaw, yaw_to_quat

__all__ = ["METHODS", "AUTO_METHOD", "differentiate", "differentiate_quaternion", "differentiate_log", "noise_gains",
           "savgol_weights"]

METHODS = ("auto", "savgol", "spline")
"""Values accepted by ``method``."""

AUTO_METHOD = "savgol"
"""The method ``method="auto"`` uses (the reasons are in :func:`differentiate`)."""

_QUAT_TOLERANCE = 1e-2  # |norm - 1| above which a series is not unit quaternions


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
    each candidate (order p, window w), the error that the derivatives leave in an estimate fitted
    over the whole record is estimated as bias^2 + (w / n) variance, n the record's samples: the
    noise of the derivatives averages over the record's n / w independent windows, their bias,
    coherent with the motion, does not. (The derivatives' own mean squared error, bias^2 +
    variance, chose windows whose bias was as large as their noise: on a designed servicer flight
    the parameters' errors were then 1.3 to 1.4 times their standard errors, root-mean-square,
    against 1.1 with this rule, the rates' own error 2.5 times larger.) A given ``window`` fixes the
    time resolution wanted of the rates themselves (a monitor's: a change shows within the window),
    and the order is then chosen for their own error, bias^2 + variance. The terms:

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

    Bias check. The pilot sees only what a polynomial over 2w+1 samples can follow, so on a
    record with a quiet stretch and an active one it misses the active band once the window
    spans both. Without ``window``, the candidates of each order are therefore taken from the
    shortest up to, not including, the first whose derivatives differ from those of the next
    shorter candidate (nested in it) by more than noise: the difference has noise variance
    ``s_i^2 = sigma^2 (sum_j h_ij^2 - sum_j d_ij^2)`` (``h_i`` the shorter fit's weights), and
    on each eighth of the record the mean of ``diff_i^2 / s_i^2`` is tested as chi-square with
    as many degrees of freedom as shorter windows fit in it, at false-alarm probability 0.1 %.

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

    References
    ----------
    .. [2] J. Fan and I. Gijbels, "Local Polynomial Modelling and Its Applications", Chapman &
       Hall, 1996, sections 3.7 and 4.2.
    .. [4] P. Craven and G. Wahba, "Smoothing noisy data with spline functions", Numerische
       Mathematik 31, 1979.
    """
    return _differentiated(t, x, method=method, window=window, order=order, smoothing=smoothing, quantum=quantum,
                           wrap=wrap, name=name)


def _differentiated(t, x, *, method, window, order, smoothing, quantum, wrap, name, shared=None):
    """:func:`differentiate`; ``shared``: the channels take one automatic Savitzky-Golay setting, their
    criteria summed and their noise spanning ``shared`` independent directions (:func:`_select_savgol`);
    None: each channel its own."""
    t, x, shape = _check_series(t, x, name)
    quantum = _check_quantum(quantum, name)
    resolved, window, order = _check_tuning(t.size, method, window, order, smoothing, name)
    if wrap:
        x = np.unwrap(x, axis=0)
    _check_gaps(t, name)
    sigma, source = _noise(t, x, quantum)
    _check_resolution(t, x, sigma, name)
    given = window, order
    if shared:  # the channels' levels scaled to their total (the window check and the record take it)
        sigma = sigma * np.sqrt(_pooled_noise(t, x, shared) / max(np.sum(sigma**2), 1e-300))
    if shared and resolved == "savgol" and (window is None or order is None):
        window, order = _select_savgol(t, x, sigma, window, order, shared)
    x_smooth, xdot, windows, orders, lams = _fit_channels(t, x, sigma, resolved, window, order, smoothing, name)
    step = float(np.median(np.diff(t)))
    selection, rule = _selection(resolved, *given, smoothing)
    if shared and rule != "manual" and resolved == "savgol":
        rule += f"; one setting for the {x.shape[1]} channels, their criteria summed"
    info = {
        "method": resolved,
        "requested": method,
        "window": windows or None,
        "window_s": [(w - 1) * step for w in windows] or None,
        "order": orders or None,
        "smoothing": lams or None,
        "selection": selection,
        "rule": rule,
        "noise": sigma.tolist(),
        "noise_source": source,
        "quantum": quantum,
        "wrap": bool(wrap),
        "n_samples": int(t.size),
    }
    return x_smooth.reshape(shape), xdot.reshape(shape), info


def _fit_channels(t, x, sigma, method, window, order, smoothing, name):
    """Smoothed values and derivatives (n, m) of each channel of ``x`` by the resolved ``method``,
    and the settings used: per channel window and order (Savitzky-Golay) or penalty (spline)."""
    x_smooth, xdot = np.empty_like(x), np.empty_like(x)
    windows, orders, lams = [], [], []
    for j in range(x.shape[1]):
        if method == "savgol":
            w, p = window, order
            if w is None or p is None:
                w, p = _select_savgol(t, x[:, j], sigma[j], window, order)
            x_smooth[:, j], xdot[:, j] = _savgol(t, x[:, j], w, p)
            windows.append(int(w))
            orders.append(int(p))
        else:
            x_smooth[:, j], xdot[:, j], lam = _spline(t, x[:, j], smoothing, name)
            lams.append(lam)
    return x_smooth, xdot, windows, orders, lams


def _selection(method, window, order, smoothing):
    """How each tuning parameter of ``method`` was set (``"auto"`` or ``"manual"``), and the rule
    that chose the automatic ones (``"manual"`` when none was)."""
    if method == "savgol":
        selection = {"window": _how(window), "order": _how(order)}
        rule = (
            "plug-in bias^2 + variance of the derivative (the window given: the rates' own error; moments on the "
            "stamps, degree p+3 pilot, noise subtracted)" if window is not None else
            "plug-in bias^2 + (w / n) variance of the derivative (moments on the stamps, degree p+3 pilot, noise "
            "subtracted), windows up to the first with bias shown on an eighth of the record"
        )
    else:
        selection = {"smoothing": _how(smoothing)}
        rule = f"generalised cross-validation (hat-matrix trace from {_PROBES} sign probes, seed 0)"
    return selection, rule if "auto" in selection.values() else "manual"


def _how(value):
    return "auto" if value is None else "manual"


def _check_tuning(n, method, window, order, smoothing, name):
    """The resolved method and the validated window and order, or a SpaceidError."""
    if method not in METHODS:
        raise SpaceidError(f"{name}: `method` {method!r} is not one of {', '.join(METHODS)}")
    resolved = AUTO_METHOD if method == "auto" else method
    if resolved == "spline":
        _check_spline_tuning(n, window, order, smoothing, name)
        return resolved, None, None
    window, order = _check_savgol_tuning(n, method, window, order, smoothing, name)
    return resolved, window, order


def _check_spline_tuning(n, window, order, smoothing, name):
    """The spline takes ``smoothing`` (a number >= 0) only, and needs 7 samples."""
    for key, value in (("window", window), ("order", order)):
        if value is not None:
            raise SpaceidError(
                f"{name}: `{key}` {value!r} applies to `method` 'savgol', not 'spline': drop it or "
                "set `method` to 'savgol' (the spline takes `smoothing`)"
            )
    if smoothing is not None and not _finite_number(smoothing, 0.0):
        raise SpaceidError(f"{name}: `smoothing` {smoothing!r}: expected a finite number >= 0 [s^3]")
    _require_samples(n, _NOISE_DIFFERENCE + 1, name, "method 'spline'")


def _check_savgol_tuning(n, method, window, order, smoothing, name):
    """The validated Savitzky-Golay (window, order), each None when automatic, or a SpaceidError."""
    if smoothing is not None:
        raise SpaceidError(
            f"{name}: `smoothing` {smoothing!r} applies to `method` 'spline', not {method!r}: "
            "drop it or set `method` to 'spline' (Savitzky-Golay takes `window` and `order`)"
        )
    order = _check_int(order, "order", name, minimum=1)
    window = _check_int(window, "window", name, minimum=(order or 0) + 1)
    if window is None:  # the bias pilot of the lowest order needs order + 4 samples
        needed = (order or min(_AUTO_ORDERS)) + _PILOT_EXTRA + 1
    elif window % 2 == 0:
        raise SpaceidError(f"{name}: `window` {window} is even: give an odd number of samples")
    elif order is None and window <= min(_AUTO_ORDERS):
        raise SpaceidError(
            f"{name}: `window` {window} is too short for the automatic orders {_AUTO_ORDERS}: "
            f"give an `order` below {window} or a longer `window`"
        )
    elif window > n:
        raise SpaceidError(
            f"{name}: `window` {window} is longer than the record ({n} samples): "
            f"choose an odd window of at most {n - 1 + n % 2} samples"
        )
    else:
        needed = window
    _require_samples(n, max(needed, _NOISE_DIFFERENCE + 1), name, "method 'savgol'")
    return window, order


def differentiate_quaternion(t, quat, *, method="auto", window=None, order=None, smoothing=None):
    """Smoothed base attitude and base angular velocity in base axes from quaternion samples.

    The series is made sign-continuous (``q`` and ``-q`` are the same rotation, and motion
    capture may flip between them), its four components are smoothed and differentiated by
    :func:`differentiate` with one Savitzky-Golay window and order (chosen automatically for the
    four together: the rate then does not depend on the inertial frame, and a component's own
    noise, which varies with the attitude, does not set its window), the smoothed quaternion is
    renormalised, and the body rate is::

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
        ``sign_flips`` (how many samples were negated); the components' ``noise`` scaled to
        their pooled total (a star tracker's small rotations, three directions: its level is
        ``2 sqrt(sum noise^2 / 3)``).

    Raises
    ------
    SpaceidError
        A shape other than (n_samples, 4), quaternions whose norm departs from 1 by more than
        1e-2, and everything :func:`differentiate` rejects.
    """
    t, quat = _check_quaternions(t, quat)
    options = dict(method=method, window=window, order=order, smoothing=smoothing)
    if not quat[:, 1:3].any():  # a pure yaw: differentiate the unwrapped angle
        yaw, yaw_rate, info = differentiate(t, quat_to_yaw(quat), wrap=True, name="base yaw", **options)
        w_body = np.zeros((t.size, 3))
        w_body[:, 2] = yaw_rate
        return yaw_to_quat(yaw), w_body, {**info, "planar": True, "sign_flips": 0}
    quat, flips = _sign_continuous(quat)
    # one setting for the four components: a linear filter then commutes with a change of inertial
    # frame (the rate does not depend on it), and each component's noise varies with the attitude
    # while their sum does not (_bias_shown)
    q, qdot, info = _differentiated(t, quat, name="quat", quantum=None, wrap=False, shared=3, **options)
    quat_smooth, w_body = _body_rate(q, qdot)
    return quat_smooth, w_body, {**info, "planar": False, "sign_flips": flips}


def _check_quaternions(t, quat):
    """``t`` (n,) and ``quat`` (n, 4) as float arrays, checked to be unit quaternions on valid stamps."""
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
    return t, quat


def _sign_continuous(quat):
    """``quat`` (n, 4) with samples negated where needed so that neighbours have a positive dot
    product (q and -q are one rotation), and how many were negated."""
    flips = np.cumsum(np.einsum("ij,ij->i", quat[1:], quat[:-1]) < 0) % 2 == 1
    quat = quat.copy()
    quat[1:][flips] *= -1
    return quat, int(flips.sum())


def _body_rate(q, qdot):
    """Unit quaternions (n, 4) and body rates ``2 vec(conj(q) (x) qdot) / |q|^2`` (n, 3) [rad/s]
    from smoothed quaternions ``q`` and their derivatives ``qdot`` (n, 4) [1/s]."""
    s, v = q[:, :1], q[:, 1:]
    sdot, vdot = qdot[:, :1], qdot[:, 1:]
    norm2 = np.einsum("ij,ij->i", q, q)[:, None]
    w_body = 2 * (s * vdot - sdot * v - np.cross(v, vdot)) / norm2
    return q / np.sqrt(norm2), w_body


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
    if method == "savgol":
        smooth, rate = _savgol_gains(t, window, order)
    else:
        values, rates, _ = differentiate(t, np.eye(t.size), method="spline", smoothing=smoothing)
        smooth, rate = np.linalg.norm(values, axis=1), np.linalg.norm(rates, axis=1)
    if len(_GAINS) > 64:
        _GAINS.clear()
    _GAINS[key] = (smooth, rate)
    return smooth, rate


def savgol_weights(t, rows, window: int, order: int):
    """The Savitzky-Golay weights that give the smoothed values and derivatives at ``rows``.

    Parameters
    ----------
    t : ndarray of shape (n,)
        The stamps of the samples differentiated [s].
    rows : ndarray of shape (r,)
        The samples (indices into ``t``) whose weights are wanted.
    window, order : int
        The setting :func:`differentiate` recorded for the channel.

    Returns
    -------
    idx : ndarray of shape (r, window)
        The samples in each row's window (shifted inwards at the ends, as :func:`differentiate` does).
    smooth, rate : ndarray of shape (r, window)
        Weights [-] and [1/s]: the smoothed value at ``rows[i]`` is ``smooth[i] @ x[idx[i]]``, its
        derivative ``rate[i] @ x[idx[i]]``; with white noise of std ``sigma`` on ``x``, the errors of
        two rows' derivatives have covariance ``sigma^2`` times the overlap of their weights.
    """
    idx, _, pinv, scale = _new_fits(np.asarray(t, float), np.asarray(rows), int(window), int(order))
    return idx, pinv[:, 0], pinv[:, 1] / scale[:, None]


def differentiate_log(log, *, method: str = "auto", window=None, order=None, smoothing=None, quantum=None,
                      base: bool = True):
    """A log whose joint rates and base angular velocity come from its angles and attitude.

    Joint angles are differentiated channel by channel (``quantum`` [rad per count] for
    encoders), the base attitude with :func:`differentiate_quaternion`; the angles are replaced
    by their smoothed values. What was used is recorded in ``meta["differentiation"]``.

    Parameters
    ----------
    log : spaceid.Log
    method, window, order, smoothing, quantum
        As in :func:`differentiate` (``quantum`` applies to the joints only).
    base : bool
        Also the base attitude; False: the base rate stays as measured (a gyro's, whose bias
        ``identify(..., gyro_bias=True)`` estimates), the attitude as sampled.

    Returns
    -------
    spaceid.Log
    """
    from dataclasses import replace

    q, qd, info_q = differentiate(log.t, log.q, method=method, window=window, order=order, smoothing=smoothing,
                                  quantum=quantum, name="joint angles")
    if not base:
        meta = dict(log.meta, differentiation={"joints": info_q})
        return replace(log, q=q.reshape(log.q.shape), qd=qd.reshape(log.q.shape), meta=meta)
    quat, w, info_b = differentiate_quaternion(log.t, log.base_quat, method=method, window=window, order=order,
                                               smoothing=smoothing)
    meta = dict(log.meta, differentiation={"joints": info_q, "base": info_b})
    return replace(log, q=q.reshape(log.q.shape), qd=qd.reshape(log.q.shape), base_quat=quat, base_w=w, meta=meta)
