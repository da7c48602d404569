"""The covariance of estimates from differentiated rates: the angle noise carried through the
differentiator (docs/theory/noise.md, "Standard errors").

Rates differentiated from angles are a known linear filter of the angle samples: the
Savitzky-Golay weights that :func:`spaceid.data.differentiate` recorded (window, order, and the
noise level of the raw angles, estimated from their high-order differences). Each estimator's
first-order error is ``bread sum_n M_n^T e_n``, and the equation errors ``e_n = J_n dx_n`` are,
through the filter, a linear map of the raw angle noise. So the score ``sum_n M_n^T e_n`` is
``sum_s K_s^T eps_s`` over the raw series ``s`` (a joint's encoder, the base yaw), with
``K_s = sum_c W_c^T U_c``: ``W_c (n, m_s)`` the filter of signal ``c`` (smoothed angle or rate)
from the series' ``m_s`` samples, ``U_c (n, p)`` the rows ``sum_r J_n[r, c] M_n[r]``. The covariance
is ``bread (sum_s sigma_s^2 K_s^T K_s) bread^T``: the differentiator's actual correlation structure,
positive over about half its window and negative beyond, in place of a Newey-West guess from
the residuals.

The raw stamps are not in the log: each series is rebuilt as a uniform grid at its recorded step
(the window's span over its samples), extended by half a window beyond the log when the log was
cut from a longer record (the excitation of a bag), each log sample at its nearest grid point.
Jitter and dropped samples change the weights only slightly. Spline differentiators and a spatial
base (a differentiated quaternion) are not covered: their covariance stays the Newey-West one.
"""

from __future__ import annotations

import numpy as np
from scipy import sparse

from .._threads import one_blas_thread
from ..data import Log, savgol_weights


def _channels(info) -> list:
    """The per-channel records of one ``differentiate`` record: a list of dicts with ``window``,
    ``order``, ``noise``, ``step`` [s] and ``n_samples``; None when the channels are not Savitzky-Golay."""
    if info.get("method") != "savgol" or not all(info.get(k) for k in ("window", "order", "noise", "window_s",
                                                                          "n_samples")):
        return None  # another differentiator, or a record without the filter (written by an older version)
    return [{"window": int(w), "order": int(p), "noise": float(s), "step": float(span) / (int(w) - 1),
             "n_samples": int(info["n_samples"])}
            for w, p, s, span in zip(info["window"], info["order"], info["noise"], info["window_s"])]  # fmt: skip


def differentiated_series(log: Log) -> list | None:
    """The raw angle series behind the log's differentiated signals: a list of ``(record, value,
    rate)``, ``record`` as :func:`_channels` gives it, ``value`` and ``rate`` the columns of the
    signals ``x = [q, qd, w0]`` that the series' smoothed angle and derivative are (``value`` None
    for the base yaw, which planar equations do not contain). None when the log's rates cannot be
    propagated (no record, a spline, a spatial base)."""
    info = log.meta.get("differentiation")
    if not info:
        return None
    nj = len(log.joints)
    series = []
    joints = info.get("joints")
    if joints:
        if "method" in joints:  # one record for every joint column (differentiate_log)
            records = _channels(joints)
            if records is None or len(records) != nj:
                return None
            series += [(r, j, nj + j) for j, r in enumerate(records)]
        else:  # a record per differentiated joint (a bag; the others' rates were measured)
            for name, record in joints.items():
                records = _channels(record)
                if records is None or name not in log.joints:
                    return None
                j = log.joints.index(name)
                series.append((records[0], j, nj + j))
    base = info.get("base")
    if base:
        records = _channels(base)
        if records is None or not base.get("planar", log.planar) or not log.planar:
            return None
        series.append((records[0], None, 2 * nj))
    return series or None


def whitened_series(log: Log) -> list | None:
    """The raw series behind the log's differentiated signals as the monitor's whitening takes them
    (:class:`~spaceid.estimation._monitor_filter.DifferentiatedWhitener`): those of
    :func:`differentiated_series`, each with whether it is the base attitude, and for a spatial base
    differentiated as a quaternion by Savitzky-Golay, three: the small rotations about the base
    axes, each a raw series behind its column of the attitude and of the base rate. The quaternion's
    components are filtered alike, so to first order (the base turning little within a window)
    the smoothed attitude's error is the smoothing weights times the raw rotations, the rate's the
    derivative weights times them. The raw level is twice the components' (a small rotation moves
    each by half of it). None when there are none, or they cannot be propagated."""
    info = log.meta.get("differentiation")
    if not info:
        return None
    base = info.get("base")
    if log.planar or not base or base.get("planar", log.planar):
        series = differentiated_series(log)
        return None if series is None else [(r, value, rate, value is None) for r, value, rate in series]
    records = _channels(base)
    joints = {k: v for k, v in info.items() if k != "base"}
    series = differentiated_series(Log(log.t, log.joints, log.q, log.qd, log.base_quat, log.base_w,
                                       planar=log.planar, meta={"differentiation": joints}))
    if records is None or len(records) != 4 or (series is None and joints.get("joints")):
        return None
    series = series or []
    nj = len(log.joints)
    record = dict(records[1], noise=2 * max(r["noise"] for r in records[1:]))
    return [(r, value, rate, False) for r, value, rate in series] + [
        (record, 2 * nj + 3 + k, 2 * nj + k, True) for k in range(3)]


def _grid(record: dict, t: np.ndarray) -> tuple:
    """Where the Savitzky-Golay filter of one series reads the raw samples for the log's stamps
    ``t (n,)``, on a uniform grid at the series' step (see the module's description): the first
    grid index of each sample's window ``(n,)`` and the sample's place in it ``(n,)`` (centred, or
    shifted inwards at the ends, as the differentiator's)."""
    step, window = record["step"], record["window"]
    whole = t[-1] - t[0] >= (record["n_samples"] - 1.5) * step  # the log is the whole record
    pad = 0 if whole else window // 2
    count = max(int(round((t[-1] - t[0]) / step)) + 1 + 2 * pad, window)
    rows = np.clip(np.rint((t - t[0]) / step).astype(int) + pad, 0, count - 1)
    first = np.clip(rows - window // 2, 0, count - window)
    return first, rows - first


def _series_part(record, value, rate, first, place, M, J) -> tuple:
    """The part of ``K_s`` that samples ``(k,)`` give, their windows at grid indices ``first`` and
    their places ``place`` (:func:`_grid`), ``M (k, rows, p)``, ``J (k, rows, n_x)``: the grid index
    of its first row and its rows ``W_c^T U_c`` for the smoothed angle ``value`` and rate ``rate``
    columns. On a uniform grid a row's weights depend only on its place: one fit per place."""
    window = record["window"]
    places, which = np.unique(place, return_inverse=True)
    _, smooth, slope = savgol_weights(record["step"] * np.arange(window), places, window, record["order"])
    start = int(first.min())
    idx = (first - start)[:, None] + np.arange(window)
    rows = np.repeat(np.arange(len(first)), window)
    shape = (len(first), int(idx.max()) + 1)
    K = 0.0
    for weights, column in ((smooth[which], value), (slope[which], rate)):
        if column is not None:
            W = sparse.csr_matrix((weights.ravel(), (rows, idx.ravel())), shape=shape)
            K = K + W.T @ _rows(M, J, column)
    return start, K


def _rows(M, J, column):
    """``U_c (n, p)``: the score's derivative with respect to signal ``column`` at each sample."""
    return np.einsum("nrp,nr->np", M, J[:, :, column])


def _joined(open_part, part) -> tuple:
    """The rows of ``K_s`` still open before a chunk (``(first grid index, rows)``, or None) plus
    that chunk's part (:func:`_series_part`), which starts no earlier."""
    if open_part is None:
        return part
    (start, K), (start_new, K_new) = open_part, part
    joined = np.zeros((max(len(K), start_new - start + len(K_new)), K_new.shape[1]))
    joined[: len(K)] += K
    joined[start_new - start : start_new - start + len(K_new)] += K_new
    return start, joined


def propagated_covariance(series, t, chunks, bread, sigma) -> np.ndarray:
    """``bread (sum_s sigma_s^2 K_s^T K_s + sum_c sigma_c^2 U_c^T U_c) bread^T`` ``(p, p)``: the
    first-order covariance of an estimate whose score is ``sum_n M_n^T e_n``, the differentiated
    series ``series`` (:func:`differentiated_series`) carried through their filters, every other
    signal ``c`` white with the noise model's ``sigma (n_x,)``.

    The samples come in consecutive chunks (one, or a stream: :mod:`spaceid.estimation._stream`).
    A row of ``K_s`` (a raw sample) sums the samples whose windows hold it; it is complete, and its
    term added, once no later sample's window reaches it: only the rows under the windows that
    straddle a chunk's end are carried to the next, ``(chunk + window) x p`` values.

    Parameters
    ----------
    series : list
        From :func:`differentiated_series`.
    t : ndarray of shape (n,)
        The log's stamps [s].
    chunks : iterable
        ``(rows, M_c, J_c)`` in time order: the slice of samples, the estimator's weights
        ``M_c (k, rows, p)`` (:func:`spaceid.estimation._uncertainty._covariance_terms`) and the equation
        errors' derivatives ``J_c (k, rows, n_x)`` with respect to the signals.
    bread : ndarray of shape (p, p)
    sigma : ndarray of shape (n_x,)
    """
    covered = {c for _, value, rate in series for c in (value, rate) if c is not None}
    grids = [_grid(record, t) for record, _, _ in series]
    # the first grid row that a sample at or after each one reads: rows before it are complete
    reach = [np.append(np.minimum.accumulate(first[::-1])[::-1], np.iinfo(int).max) for first, _ in grids]
    open_parts = [None] * len(series)
    cov = np.zeros(bread.shape)
    with one_blas_thread():  # one series or signal at a time: never every signal's rows at once
        for sl, M, J in chunks:
            stop = len(t) if sl.stop is None else sl.stop
            for i, ((record, value, rate), (first, place)) in enumerate(zip(series, grids)):
                start, K = _joined(open_parts[i], _series_part(record, value, rate, first[sl], place[sl], M, J))
                done = min(max(reach[i][stop] - start, 0), len(K))
                cov += _mapped_gram(record["noise"] * K[:done], bread)
                open_parts[i] = (start + done, K[done:]) if done < len(K) else None
            for c in range(J.shape[-1]):
                if c not in covered and sigma[c] > 0:
                    cov += _mapped_gram(sigma[c] * _rows(M, J, c), bread)
    return cov


def _mapped_gram(K, bread):
    """``bread K^T K bread^T``, as the Gram matrix of ``K bread^T``: positive semi-definite whatever the round-off."""
    x = K @ bread.T
    return x.T @ x
