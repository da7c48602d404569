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
Jitter and dropped samples change the weights only slightly. A spatial base's differentiated
quaternion is three series, the star tracker's small rotations, each through the four components'
filters (:func:`_attitude_series`). Spline differentiators are not covered: their covariance stays
the Newey-West one.
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


def differentiated_series(log: Log, attitude: bool = False) -> list | None:
    """The raw angle series behind the log's differentiated signals: a list of ``(record, value,
    rate)``, ``record`` as :func:`_channels` gives it, ``value`` and ``rate`` the columns of the
    signals ``x = [q, qd, w0]`` that the series' smoothed angle and derivative are (``value`` None
    for the base yaw, which planar equations do not contain). None when the log's rates cannot be
    propagated (no record, a spline, a spatial base unless ``attitude``).

    ``attitude``: a spatial base's differentiated quaternion as well, its three series the star
    tracker's small rotations about the base axes (:func:`_attitude_series`: ``value`` and ``rate``
    lists of three columns, ``record["parts"]`` the quaternion components' filters and how each
    mixes the columns); only :func:`propagated_covariance` takes those."""
    info = log.meta.get("differentiation")
    if not info:
        return None
    nj = len(log.joints)
    series = _joint_series(info.get("joints"), log.joints)
    if series is None:
        return None
    base = info.get("base")
    if base:
        records = _channels(base)
        if records is None or base.get("planar", log.planar) != log.planar or not (log.planar or attitude):
            return None
        series += [(records[0], None, 2 * nj)] if log.planar else _attitude_series(log, records, nj)
    return series or None


def at_given_levels(series, noise) -> list:
    """The differentiated ``series`` (:func:`differentiated_series`, without a spatial attitude's) with each raw
    angle level at least the one given in ``noise`` (:class:`~spaceid.estimation.Noise`: a joint's ``angle``, a
    planar base's ``attitude``), as the weights take it (:func:`differentiated_sigma`). The differentiator estimates
    the level from the angles' own scatter about its fits: about none on a noise-free log, whose differentiated
    rates then err by the filters' truncation errors, smooth over the motion (cubics over 11 samples at 50 Hz: up to
    6e-5 rad/s), which no noise level describes: random planar robot 60775 in the live engine, the levels given as
    1e-4 and the true mass 0.9 kg, published a payload of 0.9020 +- 0.0002 kg (9 standard errors off, 57 samples)
    with the level found; with the one given, 0.9009 +- 0.065 kg (112 samples, the first whose mass stands out)."""
    return [({**record, "noise": max(record["noise"], noise.attitude if value is None else noise.angle)}, value, rate)
            for record, value, rate in series]


def _joint_series(joints, names) -> list | None:
    """:func:`differentiated_series`' joint entries ``(record, value, rate)`` of the differentiation record
    ``joints`` (None or empty: none) for a log of joints ``names``, or None when they cannot be propagated."""
    nj, series = len(names), []
    if not joints:
        return series
    if "method" in joints:  # one record for every joint column (differentiate_log)
        records = _channels(joints)
        if records is None or len(records) != nj:
            return None
        return [(r, j, nj + j) for j, r in enumerate(records)]
    for name, record in joints.items():  # a record per differentiated joint (a bag; the others' rates measured)
        records = _channels(record)
        if records is None or name not in names:
            return None
        j = names.index(name)
        series.append((records[0], j, nj + j))
    return series


def _attitude_series(log: Log, records: list, nj: int) -> list:
    """The three series of a spatial base whose quaternion components were differentiated by the
    filters ``records`` (four): the star tracker's small rotations ``eps_i`` about the base axes.

    A raw sample ``q_k (x) exp(eps_k / 2)`` errs by ``E(q_k) eps_k / 2`` (``E(q) u = q (x) [0, u]``,
    four by three), component ``j`` through its own filter ``W_j``. The smoothed attitude's small
    rotation is ``2 E(q_n)^T dq_n`` and the body rate's error ``2 E(q_n)^T dqdot_n`` to leading order,
    so ``eps_i`` reaches the attitude columns as ``sum_j P_j(n)[:, i] (W_j eps_i)_n`` and the base-rate
    columns through the derivative weights alike, ``P_j = E_j^T E_j`` the outer product of ``E(q_n)``'s
    row ``j`` (``sum_j P_j = I``: one filter for all components gives the joints' form). Neglected:
    the base's turn over a window (``|w0|`` times the window's span, relative) and the rate's
    dependence on the smoothed quaternion (``|w0|`` times the attitude error). Each component's
    recorded noise is ``sigma sqrt(1 - q_j^2) / 2`` on average, so ``sigma = 2 sqrt(sum_j noise_j^2 / 3)``."""
    P, sigma = _quaternion_mix(log, records)
    values, rates = [2 * nj + 3 + c for c in range(3)], [2 * nj + c for c in range(3)]
    return [({**records[0], "noise": sigma, "parts": [(r, P[:, j, :, i]) for j, r in enumerate(records)]},
             values, rates) for i in range(3)]  # fmt: skip


def _quaternion_mix(log: Log, records: list) -> tuple:
    """How the star tracker's small rotations reach the quaternion components' filters: ``P (n, 4, 3, 3)``,
    ``P_j`` the outer product of row ``j`` of ``E(q_n)`` (``E(q) u = q (x) [0, u]``), and the rotations'
    level ``sigma`` [rad] per axis from the components' recorded noise (``2 sqrt(sum_j noise_j^2 / 3)``)."""
    s, v = log.base_quat[:, :1], log.base_quat[:, 1:]
    E = np.concatenate([-v[:, None, :], s[:, :, None] * np.eye(3) + _skew(v)], axis=1)  # (n, 4, 3)
    return np.einsum("nja,njb->njab", E, E), 2 * np.sqrt(sum(r["noise"] ** 2 for r in records) / 3)


def weighting_sigma(param, log: Log, noise) -> np.ndarray:
    """The signals' noise levels ``(n_x,)`` that weight the equations and correct their errors in
    variables: those of ``noise`` (:func:`~spaceid.estimation._noise.signal_sigma`), the differentiated
    signals' raised to their filters' own (:func:`differentiated_sigma`)."""
    from ._noise import signal_sigma

    return differentiated_sigma(log, signal_sigma(param, noise))


def _skew(v):
    """``[v]x`` ``(n, 3, 3)`` of ``v (n, 3)``."""
    out = np.zeros(v.shape[:-1] + (3, 3))
    out[..., 0, 1], out[..., 0, 2], out[..., 1, 2] = -v[..., 2], v[..., 1], -v[..., 0]
    return out - np.swapaxes(out, -1, -2)


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


def _grid(record: dict, t: np.ndarray, pad: int | None = None) -> tuple:
    """Where the Savitzky-Golay filter of one series reads the raw samples for the log's stamps
    ``t (n,)``, on a uniform grid at the series' step (see the module's description): the first
    grid index of each sample's window ``(n,)`` and the sample's place in it ``(n,)`` (centred, or
    shifted inwards at the ends, as the differentiator's)."""
    step, window = record["step"], record["window"]
    if pad is None:  # the grid's extension beyond the log: none when the log is the whole record
        pad = 0 if _whole(record, t) else window // 2
    count = max(int(round((t[-1] - t[0]) / step)) + 1 + 2 * pad, window)
    rows = np.clip(np.rint((t - t[0]) / step).astype(int) + pad, 0, count - 1)
    first = np.clip(rows - window // 2, 0, count - window)
    return first, rows - first


def _whole(record: dict, t: np.ndarray) -> bool:
    """Whether the log's stamps ``t`` span the whole differentiated record."""
    return t[-1] - t[0] >= (record["n_samples"] - 1.5) * record["step"]


def _terms(entry, t: np.ndarray) -> list:
    """The filters of one series ``(record, value, rate)``: ``(record, values, rates, mix, grid)`` each,
    ``values``/``rates`` lists of signal columns, ``mix (n, columns)`` how the filtered series enters
    them (None: once each) and ``grid`` :func:`_grid`'s, the parts of an attitude series on one grid."""
    record, value, rate = entry
    if "parts" not in record:
        return [(record, [] if value is None else [value], [rate], None, _grid(record, t))]
    parts = record["parts"]
    pad = 0 if all(_whole(r, t) for r, _ in parts) else max(r["window"] // 2 for r, _ in parts)
    return [(r, value, rate, mix, _grid(r, t, pad)) for r, mix in parts]


def _summed(parts) -> tuple:
    """The sum of parts ``(first grid index, rows)`` of one ``K_s`` that may start anywhere."""
    start = min(p[0] for p in parts)
    K = np.zeros((max(p[0] + len(p[1]) for p in parts) - start, parts[0][1].shape[1]))
    for first, rows in parts:
        K[first - start : first - start + len(rows)] += rows
    return start, K


def _series_part(record, value, rate, first, place, M, J, mix=None) -> tuple:
    """The part of ``K_s`` that samples ``(k,)`` give, their windows at grid indices ``first`` and
    their places ``place`` (:func:`_grid`), ``M (k, rows, p)``, ``J (k, rows, n_x)``: the grid index
    of its first row and its rows ``W_c^T U_c`` for the smoothed angle ``value`` and rate ``rate``
    columns (lists of columns, mixed by ``mix (k, columns)`` when given). On a uniform grid a row's
    weights depend only on its place: one fit per place."""
    window = record["window"]
    places, which = np.unique(place, return_inverse=True)
    _, smooth, slope = savgol_weights(record["step"] * np.arange(window), places, window, record["order"])
    start = int(first.min())
    idx = (first - start)[:, None] + np.arange(window)
    rows = np.repeat(np.arange(len(first)), window)
    shape = (len(first), int(idx.max()) + 1)
    K = 0.0
    for weights, columns in ((smooth[which], value), (slope[which], rate)):
        if len(columns):
            W = sparse.csr_matrix((weights.ravel(), (rows, idx.ravel())), shape=shape)
            K = K + W.T @ _rows(M, J, columns, mix)
    return start, K


def _rows(M, J, column, mix=None):
    """``U_c (n, p)``: the score's derivative with respect to signal ``column`` at each sample (a list
    of columns: their sum, weighted by ``mix (n, columns)`` when given)."""
    if np.ndim(column) == 0:
        return np.einsum("nrp,nr->np", M, J[:, :, column])
    Jc = J[:, :, column] if mix is None else J[:, :, column] * mix[:, None, :]
    return np.einsum("nrp,nr->np", M, Jc.sum(-1))


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
    bread : ndarray of shape (k, p)
        ``(p, p)`` for the estimate; fewer rows for combinations of it (the drift test's coefficients).
    sigma : ndarray of shape (n_x,)
    """
    covered = {c for _, value, rate in series for c in np.ravel([value, rate]).tolist() if c is not None}
    terms = [_terms(entry, t) for entry in series]
    # the first grid row that a sample at or after each one reads: rows before it are complete
    reach = [np.append(np.minimum.accumulate(np.min([g[0] for *_, g in parts], 0)[::-1])[::-1], np.iinfo(int).max)
             for parts in terms]  # fmt: skip
    open_parts = [None] * len(series)
    cov = np.zeros((len(bread), len(bread)))  # bread (k, p): the covariance of k combinations of the estimate
    with one_blas_thread():  # one series or signal at a time: never every signal's rows at once
        for sl, M, J in chunks:
            stop = len(t) if sl.stop is None else sl.stop
            for i, ((record, _, _), parts) in enumerate(zip(series, terms)):
                start, K = _joined(open_parts[i], _summed([
                    _series_part(r, value, rate, first[sl], place[sl], M, J, None if mix is None else mix[sl])
                    for r, value, rate, mix, (first, place) in parts]))  # fmt: skip
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


def differentiated_sigma(log: Log, sigma: np.ndarray) -> np.ndarray:
    """The signal noise levels ``sigma (n_x,)`` (``x = [q, qd, w0, attitude]``) with those of the
    differentiated signals raised to their filters' own: the raw noise level the differentiator
    estimated times the noise gain of the centred filter's smoothed value or derivative, on the
    record's uniform grid (the log may be a window cut from a longer record). Levels estimated from
    differentiated rates understate them (the filter smooths the sample-to-sample differences); a
    spatial attitude's small rotation and body rate mix the quaternion components' filters
    (:func:`_attitude_levels`). Savitzky-Golay channels only; the others as given."""
    info = log.meta.get("differentiation") or {}
    nj, out = len(log.joints), np.array(sigma, float)

    def raised(record, value, rate):
        smooth, slope = _centred_weights(record)
        for column, gain in ((value, smooth), (rate, slope)):
            if column is not None and column < len(out):
                out[column] = max(out[column], record["noise"] * float(np.linalg.norm(gain)))

    for record, value, rate in _joint_series(info.get("joints"), log.joints) or ():  # one record each, or a bag's
        raised(record, value, rate)
    base = info.get("base") or {}
    records = _channels(base) if base else None
    if records and log.planar:
        raised(records[0], None, 2 * nj)
    elif records and len(records) == 4 and len(out) >= 2 * nj + 6:
        turn, rate = _attitude_levels(log, records)
        out[2 * nj : 2 * nj + 3] = np.maximum(out[2 * nj : 2 * nj + 3], rate)
        out[2 * nj + 3 : 2 * nj + 6] = np.maximum(out[2 * nj + 3 : 2 * nj + 6], turn)
    return out


def _centred_weights(record) -> tuple:
    """The smoothing ``(window,)`` [-] and derivative ``(window,)`` [1/s] weights of a channel's centred
    Savitzky-Golay fit on its record's uniform grid."""
    window = record["window"]
    _, smooth, slope = savgol_weights(record["step"] * np.arange(window), [window // 2], window, record["order"])
    return smooth[0], slope[0]


def _attitude_levels(log: Log, records: list) -> tuple:
    """The noise levels ``(3,)`` of a spatial base's smoothed small rotation and ``(3,)`` of its body
    rate [rad, rad/s] about the base axes, the quaternion's four components differentiated by the
    filters ``records``: the root mean square over the log of each sample's standard deviation.

    As in :func:`_attitude_series`, the star tracker's small rotations ``eps`` (of level ``sigma``
    per axis) reach the rate about axis ``i`` as ``sum_j sum_a P_j[i, a] (w_j eps_a)``, ``w_j`` the
    centred derivative weights of component ``j`` and ``P_j`` its outer product, so its variance is
    ``sigma^2 sum_a sum_jl P_j[i, a] P_l[i, a] w_j . w_l`` (the smoothing weights alike for the
    rotation). One filter for all four components gives ``sigma |w|`` on every axis (``sum_j P_j =
    I``); filters that differ do not: on a servicer log whose scalar component had a 7-sample window
    and the others 23 to 289, the rate's error was 2.9e-4, 8.4e-4 and 1.2e-3 rad/s about the three
    axes (the sum here: 2.7e-4, 8.6e-4, 1.2e-3), where the largest component's level put 1.4e-3 on
    every axis and the undetermined directions' check took three determined ones for noise."""
    P, sigma = _quaternion_mix(log, records)
    weights = [_centred_weights(r) for r in records]
    width = max(len(w[0]) for w in weights)

    def level(which):  # the components' weights centred on one grid: their inner products C_jl
        centred = np.zeros((len(records), width))
        for j, w in enumerate(weights):
            start = (width - len(w[which])) // 2
            centred[j, start : start + len(w[which])] = w[which]
        C = centred @ centred.T
        return sigma * np.sqrt(np.einsum("njia,nlia,jl->ni", P, P, C).mean(axis=0))

    return level(0), level(1)
