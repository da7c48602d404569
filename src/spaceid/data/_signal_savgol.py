"""Savitzky-Golay differentiation on uneven stamps: local polynomial fits and their bandwidth.

Each sample's value and derivative come from a least-squares polynomial of degree ``order``
fitted to the ``window`` samples around it, on their actual times (the window is shifted
inwards at the ends of the record) [1]. The automatic (window, order) minimises a plug-in
estimate of the error the derivatives leave in an estimate fitted over the record (their bias
squared plus their variance over the record's independent windows) [2] (the rule is in the Notes of
:func:`spaceid.data.differentiate`), among windows whose bias the data do not show.

The plug-in's bias comes from a polynomial pilot over twice the window, which sees only what
that polynomial can follow: on a record that is quiet for most of its length and active for a
few seconds (a base attitude during wheel spin-up, then the arm's excitation), the pilot of a
window spanning both stretches misses the active band, the estimated MSE keeps falling with the
window, and the band was smoothed away (2 to 4 s windows for 0.3 to 2 Hz base-rate variations).
Hence a direct check that needs no model of the signal: for each order the candidates are
walked from the shortest, and the walk stops at the first window whose derivatives differ from
those of the next shorter candidate by more than noise on some eighth of the record (a
chi-square test, :func:`_bias_shown`). The check is local, so the active stretch counts however
long the quiet one is; where the signal is smooth at every scale the plug-in's optimum, whose
bias is well below that noise, comes first and is unchanged.

The numbered references are in the list of :mod:`spaceid.data._signals`.
"""

from __future__ import annotations

import functools

import numpy as np
from .._distributions import chi2_isf

_AUTO_ORDERS = (3, 5, 7)  # polynomial degrees the automatic Savitzky-Golay choice compares
_PILOT_EXTRA = 3  # the bias pilot fits degree order + 3 ...
_PILOT_WIDTH = 2  # ... on a window about twice as wide
_WINDOW_RATIO = 1.25  # ratio of successive candidate windows, from the shortest to the record
_CRITERION_ROWS = 250  # evenly spaced samples on which the bandwidth criterion is averaged ...
_CRITERION_BUDGET = 125_000  # ... fewer (rows x pilot window at most this) for long windows ...
_MIN_ROWS = 64  # ... but never fewer than this
_BLOCKS = 8  # the bias check tests this many consecutive stretches of the record ...
_BIAS_LEVEL = 1e-3  # ... each at this false-alarm probability
_CHUNK = 1 << 21  # local-fit elements (samples x window x coefficients) processed at a time
_REMEMBERED = 1 << 16  # local-fit elements of the largest fits remembered (eight of them: 4 MB)
_ROW_FITS_ROWS = 1024  # fits of at most this many rows take each row's remembered pseudo-inverse ...
_ROW_FITS_MAX = 8192  # ... of this many remembered (8 MB with 25-sample cubic windows)
_ROW_FITS = {}  # (order, the row's offsets' bytes) -> its pseudo-inverse (order + 1, window)


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
    weights of the k-th Taylor coefficient ``x^(k)(t_i) / k!``. The last few small ones (at most
    :data:`_REMEMBERED` elements, consecutive rows) are remembered, read only: the channels of one
    record share their stamps (a robot's joints, a quaternion's components), the smoothing and
    its gains take the same fits, and the live monitor's short records come one after another.
    """
    rows = np.asarray(rows)
    if 0 < rows.size * window * (order + 1) <= _REMEMBERED and np.array_equal(rows, rows[0] + np.arange(rows.size)):
        return _remembered_fits(np.asarray(t, float).tobytes(), int(rows[0]), rows.size, window, order)
    return _new_fits(t, rows, window, order)


@functools.lru_cache(maxsize=8)
def _remembered_fits(stamps: bytes, first: int, count: int, window: int, order: int):
    """:func:`_new_fits` of the consecutive rows from ``first`` on the stamps ``stamps``
    (their bytes), its arrays read only."""
    fits = _new_fits(np.frombuffer(stamps), np.arange(first, first + count), window, order)
    for a in fits:
        a.flags.writeable = False
    return fits


def _new_fits(t, rows, window, order):
    """:func:`_local_fits`, computed (the pseudo-inverses of a few rows from :func:`_row_pinv`)."""
    idx, u, scale = _windows(t, rows, window)
    return idx, u, (_row_pinv(u, order) if u.shape[0] <= _ROW_FITS_ROWS else _pinv(u, order)), scale


def _pinv(u, order):
    """Pseudo-inverses (r, order + 1, window) of the Vandermonde matrices of degree ``order`` in the
    offsets ``u`` (r, window)."""
    vander = np.ones(u.shape + (order + 1,))
    np.cumprod(np.broadcast_to(u[..., None], u.shape + (order,)), axis=-1, out=vander[..., 1:])
    return np.linalg.pinv(vander)


def _row_pinv(u, order):
    """:func:`_pinv`, each row's remembered by its offsets (the last :data:`_ROW_FITS_MAX` or
    fewer; copies in and out): the live monitor aligns each sample in some 20 records one after
    another (its parts' context), whose windows are those of the record before but at the record's
    new end. Each row's is the one computed with any others (NumPy's stacked SVD and products go
    matrix by matrix)."""
    keys = [(order, row.tobytes()) for row in u]
    out = np.empty(u.shape[:1] + (order + 1, u.shape[1]))
    missing = []
    for k, key in enumerate(keys):
        found = _ROW_FITS.get(key)
        if found is None:
            missing.append(k)
        else:
            out[k] = found
    if missing:
        out[missing] = _pinv(u[missing], order)
        if len(_ROW_FITS) + len(missing) > _ROW_FITS_MAX:
            _ROW_FITS.clear()
        for k in missing:
            _ROW_FITS[keys[k]] = out[k].copy()
    return out


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


def _select_savgol(t, y, sigma, window, order, dimensions=1):
    """(window, order) minimising the plug-in criterion of :func:`differentiate`'s Notes (bias^2 +
    (w / n) variance: the error the derivatives leave in an estimate fitted over the record), among
    the windows shorter than the first whose bias the data show (:func:`_bias_shown`). A given
    ``window`` fixes the time resolution the caller wants of the rates themselves (a monitor's: a
    change shows within it), so the order is then chosen for their own error, bias^2 + variance (for
    the estimate's, quintics over 11 samples doubled the rates' noise and random robots' grasps went
    unseen for 1.8 to 3 s).

    ``y`` (n,) with noise level ``sigma``, or (n, m) channels that take one setting, of levels ``sigma
    (m,)``: their criteria summed, their noise spanning ``dimensions`` independent directions (a unit
    quaternion's four components: three, :func:`spaceid.data.differentiate_quaternion`)."""
    n = t.size
    y, sigma = np.reshape(y, (n, -1)), np.reshape(sigma, -1)
    orders = [p for p in (_AUTO_ORDERS if order is None else (order,)) if window is None or p < window]
    best = (np.inf, None, None)
    for p in orders:
        for w in _candidate_windows(n, p) if window is None else [window]:
            pilot = min(_PILOT_WIDTH * w + 1, n)
            if pilot <= p + _PILOT_EXTRA:  # only for the highest order on a 7- or 8-sample record
                continue
            if window is None and _bias_shown(t, y, sigma, _criterion_rows(n, w), int(w), p, dimensions):
                break
            share = w / n if window is None else 1.0
            mse = sum(_plugin_mse(t, y[:, j], sigma[j], _criterion_rows(n, pilot), int(w), p, pilot, share)
                      for j in range(y.shape[1]))  # fmt: skip
            if mse < best[0]:
                best = (mse, int(w), p)
    return best[1], best[2]


def _bias_shown(t, y, sigma, rows, window, order, dimensions=1):
    """Whether the derivatives of the (window, order) fit at ``rows`` differ from those of the next
    shorter candidate's fit by more than noise, on any of :data:`_BLOCKS` consecutive stretches;
    ``y`` (n, m) channels of noise levels ``sigma (m,)``, their squared differences summed.

    The shorter window is nested in the longer one, so the difference of the two derivatives is
    the difference of their biases plus noise of variance ``s_i^2 = sigma^2 (|h_i|^2 - |d_i|^2)``
    (``h_i . d_i = |d_i|^2``: the shorter fit's weights ``h_i`` differentiate exactly the
    polynomial of degree ``order`` that ``d_i`` is on their window). Without bias, the mean of
    ``diff_i^2 / s_i^2`` over a stretch is taken as chi-square over as many degrees of freedom as
    rows tested in it, or as shorter windows fit in it where they are fewer (neighbouring rows share
    their noise), times ``dimensions``, tested at :data:`_BIAS_LEVEL`. Summed over channels, only
    the total noise ``sum sigma^2`` need be the same along the record: a unit quaternion's
    components each have noise that varies with the attitude (``sigma sqrt(1 - q_j^2) / 2`` for a
    small rotation of ``sigma`` per axis: on a servicer's star tracker log the scalar component's,
    five times larger on one stretch than its average, cut its window to 5 to 7 samples and made
    the base rate 50 times noisier), their sum does not (``3 sigma^2 / 4``).
    """
    shorter = max(int(window / _WINDOW_RATIO) | 1, _shortest_window(order))
    if shorter >= window:
        return False
    squares, gains = 0.0, None
    for j in range(y.shape[1]):
        rate, gain = _local_rates(t, y[:, j], rows, window, order)
        rate_short, gain_short = _local_rates(t, y[:, j], rows, shorter, order)
        squares, gains = squares + (rate - rate_short) ** 2, gain_short - gain
    ratio = squares / (np.sum(sigma**2) * gains)
    for block in np.array_split(np.arange(rows.size), min(_BLOCKS, rows.size)):
        # independent terms: the rows tested, fewer where their windows overlap (counted as the stretch
        # over the shorter window); the stretch alone overcounted sparse rows (31 rows of a 6,000-sample
        # servicer log taken as 150 terms: a 3.9-sigma encoder sample cut a joint's window to 5 samples)
        dof = max(1, min(block.size, (rows[block[-1]] - rows[block[0]] + 1) // shorter))
        if np.mean(ratio[block]) > _bias_threshold(dof * dimensions):
            return True
    return False


@functools.lru_cache(maxsize=4096)
def _bias_threshold(dof):
    """The mean of ``dof`` unit chi-square terms exceeded with probability :data:`_BIAS_LEVEL`. Cached: the
    quantile took a fifth of the window choice (scipy's ``isf`` costs ~0.3 ms a call; the same few ``dof`` recur)."""
    return float(chi2_isf(_BIAS_LEVEL, dof) / dof)


def _shortest_window(order):
    """The shortest odd window that a fit of degree ``order`` smooths: order + 2 or order + 3 samples."""
    return order + 2 + (order + 1) % 2


def _candidate_windows(n, order):
    """Odd windows about :data:`_WINDOW_RATIO` apart, from the shortest fit of ``order`` to the record."""
    shortest, longest = _shortest_window(order), n - 1 + n % 2
    count = int(np.ceil(np.log(longest / shortest) / np.log(_WINDOW_RATIO))) + 1
    return np.unique(np.geomspace(shortest, longest, max(count, 1)).astype(int) | 1)


def _criterion_rows(n, pilot):
    """Evenly spaced samples on which the criterion is averaged: fewer for a long ``pilot`` window."""
    count = min(n, _CRITERION_ROWS, max(_MIN_ROWS, _CRITERION_BUDGET // pilot))
    return np.unique(np.linspace(0, n - 1, count).round().astype(int))


def _local_rates(t, y, rows, window, order):
    """Derivatives (r,) [1/s x units of y] of the degree-``order`` fits to the ``window`` samples
    around ``rows``, and the squared norms (r,) [1/s^2] of their weights: with ``c_i = G_i^-1 e_1``
    (``G`` the Gram matrix of the scaled offsets' Vandermonde matrix ``V``), the derivative is
    ``c_i . (V_i^T y) / scale_i`` and the squared norm ``c_i1 / scale_i^2``."""
    sums, weighted, scale = _power_sums(t, y, rows, window, 2 * order)
    c = _inverse_gram_columns(sums, order + 1, [1])[:, :, 0]
    return np.einsum("ra,ra->r", c, weighted) / scale, c[:, 1] / scale**2


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


def _inverse_gram_columns(sums, size, columns):
    """Columns ``columns`` (r, size, len(columns)) of the inverses of the Gram matrices
    ``G_ab = sums[:, a + b]`` (Jacobi-scaled), by a solve: the window choice needs no whole inverse,
    and solving for two columns costs about half an inversion."""
    gram = sums[:, np.add.outer(np.arange(size), np.arange(size))]
    d = 1.0 / np.sqrt(np.einsum("rii->ri", gram))
    units = np.broadcast_to(d[:, columns, None] * np.eye(size)[columns][None], (len(d), len(columns), size))
    return d[:, :, None] * np.linalg.solve(d[:, :, None] * gram * d[:, None, :], np.swapaxes(units, 1, 2))


def _plugin_mse(t, y, sigma, rows, window, order, pilot, share=1.0):
    """Estimated squared derivative bias of a (window, order) fit plus ``share`` times its variance,
    averaged over ``rows`` (``share`` 1: the mean squared error).

    The fit's derivative weights are ``d_i = V_i c_i / scale_i`` with ``c_i = G_i^-1 e_1``, so
    ``|d_i|^2 = c_i1 / scale_i^2`` and the moments ``M_ik = scale_i^(k-1) sum_a c_ia S_i(a+k)``
    follow from the power sums ``S`` alone; likewise the pilot's Taylor coefficients and their
    noise covariance ``sigma^2 H_kl / scale^(k+l)`` (``H`` the inverse pilot Gram matrix).
    """
    sums, _, scale = _power_sums(t, y, rows, window, 2 * order + 2)
    c = _inverse_gram_columns(sums, order + 1, [1])[:, :, 0]
    variance = sigma**2 * np.mean(c[:, 1] / scale**2)
    powers = np.arange(order + 1, order + 3)
    moments = np.stack(
        [np.einsum("ra,ra->r", c, sums[:, k : k + order + 1]) * scale ** (k - 1) for k in powers], axis=1
    )
    degree = order + _PILOT_EXTRA
    sums, weighted, scale = _power_sums(t, y, rows, pilot, 2 * degree)
    inverse = np.swapaxes(_inverse_gram_columns(sums, degree + 1, powers), 1, 2)  # rows ``powers`` (symmetric)
    taylor = np.einsum("rkb,rb->rk", inverse, weighted) / scale[:, None] ** powers
    scaled = moments / scale[:, None] ** powers
    bias = np.einsum("rk,rk->r", moments, taylor)
    pilot_noise = sigma**2 * np.einsum("rk,rkl,rl->r", scaled, inverse[:, :, powers], scaled)
    return max(np.mean(bias**2 - pilot_noise), 0.0) + share * variance
