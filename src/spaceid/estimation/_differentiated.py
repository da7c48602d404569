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


def _filter(record: dict, t: np.ndarray):
    """The Savitzky-Golay filter of one series at the log's stamps ``t (n,)``: the grid indices
    ``(n, window)`` and the value and rate weights ``(n, window)``, on a uniform grid at the
    series' step (see the module's description). On a uniform grid a row's weights depend only on
    its place in its window (centred, or shifted inwards at the ends): one fit per place."""
    step, window = record["step"], record["window"]
    whole = t[-1] - t[0] >= (record["n_samples"] - 1.5) * step  # the log is the whole record
    pad = 0 if whole else window // 2
    count = max(int(round((t[-1] - t[0]) / step)) + 1 + 2 * pad, window)
    rows = np.clip(np.rint((t - t[0]) / step).astype(int) + pad, 0, count - 1)
    first = np.clip(rows - window // 2, 0, count - window)  # each row's window, as the differentiator's
    places, which = np.unique(rows - first, return_inverse=True)
    _, smooth, rate = savgol_weights(step * np.arange(window), places, window, record["order"])
    return first[:, None] + np.arange(window), smooth[which], rate[which]


def _series_scores(record, value, rate, t, M, J):
    """``K_s (m_s, p)`` of one series: its filters transposed onto the rows ``U_c = sum_r J[:, r, c] M[:, r]``
    of its smoothed angle ``value`` and rate ``rate`` columns."""
    idx, smooth, slope = _filter(record, t)
    n, width = idx.shape
    rows = np.repeat(np.arange(n), width)
    size = int(idx.max()) + 1
    K = 0.0
    for weights, column in ((smooth, value), (slope, rate)):
        if column is not None:
            W = sparse.csr_matrix((weights.ravel(), (rows, idx.ravel())), shape=(n, size))
            K = K + W.T @ _rows(M, J, column)
    return K


def _rows(M, J, column):
    """``U_c (n, p)``: the score's derivative with respect to signal ``column`` at each sample."""
    return np.einsum("nrp,nr->np", M, J[:, :, column])


def propagated_covariance(series, t, M, J, bread, sigma) -> np.ndarray:
    """``bread (sum_s sigma_s^2 K_s^T K_s + sum_c sigma_c^2 U_c^T U_c) bread^T`` ``(p, p)``: the
    first-order covariance of an estimate whose score is ``sum_n M_n^T e_n``, the differentiated
    series ``series`` (:func:`differentiated_series`) carried through their filters, every other
    signal ``c`` white with the noise model's ``sigma (n_x,)``.

    Parameters
    ----------
    series : list
        From :func:`differentiated_series`.
    t : ndarray of shape (n,)
        The log's stamps [s].
    M : ndarray of shape (n, rows, p)
        The estimator's weights (:func:`spaceid.estimation._uncertainty._covariance_terms`).
    J : ndarray of shape (n, rows, n_x)
        The equation errors' derivatives with respect to the signals.
    bread : ndarray of shape (p, p)
    sigma : ndarray of shape (n_x,)
    """
    covered = {c for _, value, rate in series for c in (value, rate) if c is not None}
    cov = np.zeros(bread.shape)
    with one_blas_thread():  # one series or signal at a time: never every signal's rows at once
        for record, value, rate in series:
            cov += _mapped_gram(record["noise"] * _series_scores(record, value, rate, t, M, J), bread)
        for c in range(J.shape[-1]):
            if c not in covered and sigma[c] > 0:
                cov += _mapped_gram(sigma[c] * _rows(M, J, c), bread)
    return cov


def _mapped_gram(K, bread):
    """``bread K^T K bread^T``, as the Gram matrix of ``K bread^T``: positive semi-definite whatever the round-off."""
    x = K @ bread.T
    return x.T @ x
