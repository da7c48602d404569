"""Savitzky-Golay differentiation on uneven stamps: local polynomial fits and their bandwidth.

Each sample's value and derivative come from a least-squares polynomial of degree ``order``
fitted to the ``window`` samples around it, on their actual times (the window is shifted
inwards at the ends of the record) [1]. The automatic (window, order) minimises a plug-in
estimate of the derivative's mean squared error [2] (the rule is in the Notes of
:func:`spaceid.data.differentiate`).

The numbered references are in the list of :mod:`spaceid.data._signals`.
"""

from __future__ import annotations

import numpy as np

_AUTO_ORDERS = (3, 5, 7)  # polynomial degrees the automatic Savitzky-Golay choice compares
_PILOT_EXTRA = 3  # the bias pilot fits degree order + 3 ...
_PILOT_WIDTH = 2  # ... on a window about twice as wide
_WINDOW_RATIO = 1.25  # ratio of successive candidate windows, from the shortest to the record
_CRITERION_ROWS = 250  # evenly spaced samples on which the bandwidth criterion is averaged ...
_CRITERION_BUDGET = 125_000  # ... fewer (rows x pilot window at most this) for long windows ...
_MIN_ROWS = 64  # ... but never fewer than this
_CHUNK = 1 << 21  # local-fit elements (samples x window x coefficients) processed at a time


def _windows(t, rows, window):
    """The ``window`` sample indices around each of ``rows`` (r, window), shifted inwards at the
    ends; the scaled offsets ``u_ij = (t_j - t_i) / scale_i`` (r, window); the scales (r,) [s]
    (half the window's time span)."""
    start = np.clip(rows - window // 2, 0, t.size - window)
    idx = start[:, None] + np.arange(window)
    scale = 0.5 * (t[idx[:, -1]] - t[idx[:, 0]])
    u = (t[idx] - t[rows, None]) / scale[:, None]
    return idx, u, scale


def _local_fits(t, rows, window, order):
    """Polynomial fits of degree ``order`` to the ``window`` samples around each of ``rows``.

    Returns the window indices (r, window), the scaled offsets ``u`` (r, window) of
    :func:`_windows`, the pseudo-inverses (r, order + 1, window) of the Vandermonde matrices in
    ``u`` and the scales (r,) [s]. Row k of a pseudo-inverse divided by ``scale**k`` gives the
    weights of the k-th Taylor coefficient ``x^(k)(t_i) / k!``.
    """
    idx, u, scale = _windows(t, rows, window)
    vander = np.ones(u.shape + (order + 1,))
    np.cumprod(np.broadcast_to(u[..., None], u.shape + (order,)), axis=-1, out=vander[..., 1:])
    return idx, u, np.linalg.pinv(vander), scale


def _row_chunks(n, window, order):
    """Consecutive blocks of the sample indices 0..n-1, small enough for :data:`_CHUNK`."""
    step = max(1, _CHUNK // (window * (order + 1)))
    for first in range(0, n, step):
        yield np.arange(first, min(first + step, n))


def _savgol(t, y, window, order):
    """Savitzky-Golay smoothing and derivative of one channel (n,) on the actual stamps."""
    value, rate = np.empty_like(y), np.empty_like(y)
    for rows in _row_chunks(t.size, window, order):
        idx, _, pinv, scale = _local_fits(t, rows, window, order)
        value[rows] = np.einsum("rw,rw->r", pinv[:, 0], y[idx])
        rate[rows] = np.einsum("rw,rw->r", pinv[:, 1], y[idx]) / scale
    return value, rate


def _savgol_gains(t, window, order):
    """Norms (n,) of each sample's smoothing weights [-] and derivative weights [1/s]."""
    smooth, rate = np.empty(t.size), np.empty(t.size)
    for rows in _row_chunks(t.size, window, order):
        _, _, pinv, scale = _local_fits(t, rows, window, order)
        smooth[rows] = np.linalg.norm(pinv[:, 0], axis=-1)
        rate[rows] = np.linalg.norm(pinv[:, 1], axis=-1) / scale
    return smooth, rate


def _select_savgol(t, y, sigma, window, order):
    """(window, order) minimising the plug-in derivative MSE of :func:`differentiate`'s Notes."""
    n = t.size
    orders = [p for p in (_AUTO_ORDERS if order is None else (order,)) if window is None or p < window]
    best = (np.inf, None, None)
    for p in orders:
        for w in _candidate_windows(n, p) if window is None else [window]:
            pilot = min(_PILOT_WIDTH * w + 1, n)
            if pilot <= p + _PILOT_EXTRA:  # only for the highest order on a 7- or 8-sample record
                continue
            mse = _plugin_mse(t, y, sigma, _criterion_rows(n, pilot), int(w), p, pilot)
            if mse < best[0]:
                best = (mse, int(w), p)
    return best[1], best[2]


def _candidate_windows(n, order):
    """Odd windows about :data:`_WINDOW_RATIO` apart, from the shortest fit of ``order`` to the record."""
    shortest, longest = order + 2 + (order + 1) % 2, n - 1 + n % 2
    count = int(np.ceil(np.log(longest / shortest) / np.log(_WINDOW_RATIO))) + 1
    return np.unique(np.geomspace(shortest, longest, max(count, 1)).astype(int) | 1)


def _criterion_rows(n, pilot):
    """Evenly spaced samples on which the criterion is averaged: fewer for a long ``pilot`` window."""
    count = min(n, _CRITERION_ROWS, max(_MIN_ROWS, _CRITERION_BUDGET // pilot))
    return np.unique(np.linspace(0, n - 1, count).round().astype(int))


def _power_sums(t, y, rows, window, degree):
    """Sums over each row's window of ``u**m`` (m = 0..degree) and of ``u**m * y`` (m up to
    degree / 2), ``u = (t_j - t_i) / scale_i`` as in :func:`_local_fits`; and the scales [s]."""
    idx, u, scale = _windows(t, rows, window)
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
