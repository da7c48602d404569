"""A constant gyro bias estimated jointly with the parameters (docs/theory/sensors.md).

The gyros measure ``w_meas = w + b + noise`` with ``b`` constant in base axes. The momentum is
linear in the base rate, ``Y(q, qd, w) pi = Y(q, qd, w_meas) pi - A(q; pi) b``, ``A`` the locked
inertia (base rate to momentum, the base-rate columns of the signal Jacobian), so the equations
are bilinear in ``(pi, b)``. They are solved by Gauss-Newton on ``b`` around the linear
estimators: pass ``k`` subtracts the current ``b_k`` from the measured rates and adds the
columns ``-A(q; pi_k)`` of a correction ``db`` to the equations
(:class:`~spaceid.estimation._equations.Equations` ``bias``), which ``ols``, ``wls`` or ``ml``
then estimate with the parameters; ``b_{k+1} = b_k + db`` until ``db`` is below
``TOLERANCE`` of its standard error. At the fixed point ``db = 0``, the columns of ``pi`` are the
regressor at ``w_meas - b`` and those of ``b`` are ``-A(q; pi)``: the Jacobian of the bilinear
equations, so the covariance of the last pass is that of ``(pi, b)`` jointly, the parameters'
standard errors grown by their coupling with ``b``.

The attitude samples observe ``b`` too: the gyro integrated over a sample interval minus the
attitude increment that the star tracker measured is ``b dt`` plus noise
(:func:`attitude_information`). That estimate is independent of the parameters; it is fused
with each pass's (a Kalman update of ``theta`` by the measurement of ``db``), which fixes ``b``
where the momentum equations alone determine it poorly (a motion that barely changes the locked
inertia, an unknown momentum, which absorbs ``A b`` where ``A`` is constant).
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass, replace

import numpy as np

from .._errors import SpaceidError
from ..data import Log, log_fingerprint, quat_to_yaw
from ._noise import Noise, noise_from_log, signal_jacobian

__all__ = ["GYRO_BIAS_ESTIMATORS"]

GYRO_BIAS_ESTIMATORS = ("ml", "wls", "ols")
"""The estimators that ``identify(..., gyro_bias=True)`` runs: their equations take the bias
columns. ``iv`` builds its instruments from a predicted base rate, ``tls`` scales columns by a noise
the bias columns do not carry, ``angles`` uses no gyro."""

MAX_PASSES = 10
"""Gauss-Newton passes on the bias before giving up (2 to 4 suffice from the attitude's estimate)."""

TOLERANCE = 1e-3
"""Converged when every component of the bias correction is below this fraction of its standard
error (or of round-off on noise-free logs)."""


def _axes(planar: bool) -> list:
    return [2] if planar else [0, 1, 2]


def check_gyro_bias(log: Log, estimator: str, chunk, where: str) -> None:
    """Raise unless ``log`` has a measured base rate and ``estimator`` takes the bias columns."""
    if estimator not in GYRO_BIAS_ESTIMATORS:
        raise SpaceidError(f"`gyro_bias`: not available with `estimator` {estimator} (it is estimated with "
                           f"{', '.join(GYRO_BIAS_ESTIMATORS)}): use one of those, or no `gyro_bias`")
    if chunk:
        raise SpaceidError("`gyro_bias`: the bias is estimated in memory only: drop `chunk`")
    if "base" in log.meta.get("differentiation", {}) or np.isnan(log.base_w[:, _axes(log.planar)]).any():
        raise SpaceidError(f"{where}: `gyro_bias`: the log's base rate is not a gyro's (it was differentiated from "
                           "the attitude, or is missing), so it has no gyro bias: keep the measured base rate "
                           "(differentiate the joint angles only), or drop `gyro_bias`")


def bias_columns(param, pi, log: Log) -> np.ndarray:
    """``-A(q; pi)`` at the log's samples, ``(n, rows, n_b)``: the change of the equations per unit
    gyro bias (base axes; z only for planar systems), from the base-rate columns of the analytic
    signal Jacobian (:func:`~spaceid.estimation.signal_jacobian`)."""
    nj = len(param.model.joints)
    axes = _axes(param.model.planar)
    qd = np.nan_to_num(log.qd)  # the columns do not depend on the rates (the momentum is linear in them)
    jac = signal_jacobian(param, pi, log.q, qd, log.base_w)
    return -jac[..., 2 * nj : 2 * nj + len(axes)]


def _rotation_increments(log: Log) -> np.ndarray:
    """The attitude increments between successive samples, as rotation vectors in the base axes of
    the earlier sample, ``(n - 1, n_b)`` [rad] (the yaw increments for planar logs)."""
    from scipy.spatial.transform import Rotation
    if log.planar:
        return np.diff(np.unwrap(quat_to_yaw(log.base_quat)))[:, None]
    r = Rotation.from_quat(log.base_quat[:, [1, 2, 3, 0]])  # SciPy's quaternions are scalar-last
    return (r[:-1].inv() * r[1:]).as_rotvec()


def _increments(log: Log) -> np.ndarray:
    """The gyro integrated over each sample interval, ``(n - 1, n_b)`` [rad]: trapezoid rule, its
    error ``-dt^3 w'' / 12`` corrected (``w''`` from second differences), and for spatial logs the
    coning term of the rotation vector, ``(dt^2 / 12) w_n x w_(n+1)`` for a rate linear in time."""
    w, dt = log.base_w[:, _axes(log.planar)], np.diff(log.t)
    inc = (w[1:] + w[:-1]) / 2 * dt[:, None] + _derivative_term(w, dt, 2, -1 / 12)
    return inc if log.planar else inc + dt[:, None] ** 2 / 12 * np.cross(w[:-1], w[1:])


def _body_estimate(log: Log, inc) -> np.ndarray:
    """A first estimate of the bias, ``(n_b,)``: the gyro's increments minus the attitude's over the log,
    per unit time (first order in the rotation per interval; the start of :func:`attitude_information`)."""
    return (inc - _rotation_increments(log)).sum(0) / (log.t[-1] - log.t[0])


def _nominal_attitude(log: Log, steps) -> np.ndarray:
    """The attitude integrated from the first measured one by the increments ``steps (n - 1, n_b)``:
    yaws ``(n, 1)`` (planar) or rotation matrices ``(n, 3, 3)``."""
    from scipy.spatial.transform import Rotation
    if log.planar:
        return np.unwrap(quat_to_yaw(log.base_quat))[0] + np.concatenate([[0.0], np.cumsum(steps[:, 0])])[:, None]
    out = np.empty((len(steps) + 1, 3, 3))
    out[0] = Rotation.from_quat(log.base_quat[0, [1, 2, 3, 0]]).as_matrix()
    for k, e in enumerate(Rotation.from_rotvec(steps).as_matrix()):
        out[k + 1] = out[k] @ e
    return out


def attitude_information(log: Log, noise: Noise) -> dict:
    """The gyro bias that the attitude samples alone give: ``b (n_b,)`` and its covariance ``(n_b, n_b)``.

    The attitude is integrated from the gyro (:func:`_increments`) with a first estimate of the bias
    subtracted (:func:`_body_estimate`); its error ``phi`` (a rotation in base axes) and the
    bias's correction ``db`` are then a linear Gaussian state: ``phi_(k+1) = E_k^T phi_k - dt_k db -
    g_k``, ``E_k`` the interval's rotation and ``g_k`` the integrated gyro noise (variance
    ``dt_k^2 noise.base_rate^2`` per axis), observed by the star tracker as ``phi_k + delta_k``
    (variance ``noise.attitude^2``). A Kalman filter over the log gives ``db`` from every attitude
    sample (the filtered estimate of a constant at the last sample is the smoothed one), in O(n).
    The quadrature's remaining error, the Euler-Maclaurin term ``dt^5 w^(4) / 720`` per interval
    (fourth differences), is systematic: its sum over the log per unit time, the largest over the
    axes, is added to the standard error of every axis. When the filter's innovations are larger
    than its model predicts (chi-square per degree of freedom above 1, e.g. a noise-free log whose
    quadrature errors are not noise), the covariance is scaled up by that factor.

    Returns
    -------
    dict
        ``value (n_b,)`` [rad/s], ``cov (n_b, n_b)`` and, for the record, ``std`` (the largest
        over the axes), ``quadrature`` (its systematic part) and ``noise`` (the levels used).
    """
    from scipy.spatial.transform import Rotation
    m, t, dt = len(_axes(log.planar)), log.t, np.diff(log.t)
    inc = _increments(log)
    start = _body_estimate(log, inc)
    steps = inc - np.outer(dt, start)
    nominal = _nominal_attitude(log, steps)
    if log.planar:
        turns, y = np.ones((len(dt), 1, 1)), np.unwrap(quat_to_yaw(log.base_quat))[:, None] - nominal
    else:
        turns = Rotation.from_rotvec(steps).as_matrix()
        measured = Rotation.from_quat(log.base_quat[:, [1, 2, 3, 0]]).as_matrix()
        y = Rotation.from_matrix(np.swapaxes(nominal, -1, -2) @ measured).as_rotvec()
    r = max(noise.attitude**2, (64 * np.finfo(float).eps) ** 2)  # noise-free: round-off of the attitude
    w = log.base_w[:, _axes(log.planar)]
    # the increments' own error per interval: the order after the coning term, dt^4 |w|^2 |w'| / 12
    # (floored by its mean: where the base is at rest the bound vanishes, the error does not)
    model = (dt**3 * np.linalg.norm(w[:-1], axis=1) ** 2 * np.linalg.norm(np.diff(w, axis=0), axis=1) / 12) ** 2
    model += model.mean()
    eye = np.eye(m)
    x, P = np.zeros(2 * m), np.diag(np.r_[np.full(m, r), np.full(m, 1e-4)])  # db: diffuse against its std
    F, chi2 = np.eye(2 * m), 0.0
    for k in range(len(t)):
        if k:
            F[:m, :m], F[:m, m:] = turns[k - 1].T, -dt[k - 1] * eye
            x, P = F @ x, F @ P @ F.T
            P[:m, :m] += ((dt[k - 1] * noise.base_rate) ** 2 + model[k - 1]) * eye
        innovation, S = y[k] - x[:m], P[:m, :m] + r * eye
        gain = np.linalg.solve(S, P[:m, :]).T
        x, P = x + gain @ innovation, P - gain @ P[:m, :]
        chi2 += innovation @ np.linalg.solve(S, innovation)
        P = (P + P.T) / 2
    quadrature = float(np.abs(_derivative_term(w, dt, 4, 1 / 720).sum(0)).max() / (t[-1] - t[0])
                       + 16 * np.finfo(float).eps * np.abs(w).max())
    factor = max(1.0, chi2 / (m * len(t)))  # innovations larger than the model says (e.g. noise-free): scaled up
    cov = P[m:, m:] * factor + quadrature**2 * eye
    return {"value": start + x[m:], "cov": cov, "std": float(np.sqrt(np.diag(cov)).max()),
            "quadrature": quadrature, "variance_factor": factor,
            "noise": {"attitude": noise.attitude, "base_rate": noise.base_rate}}


def _derivative_term(w, dt, order: int, factor: float) -> np.ndarray:
    """``factor dt^(order + 1) w^(order)`` per sample interval, ``(n - 1, axes)``: the derivative
    from differences of ``order`` of the rate ``w (n, axes)`` on the median step, averaged to the
    intervals' midpoints and held at the ends."""
    step = float(np.median(dt))
    d = np.diff(w, order, axis=0) / step**order  # at the samples 1 .. n - 2 (centred, even order)
    d = np.concatenate([np.repeat(d[:1], order // 2, 0), (d[1:] + d[:-1]) / 2, np.repeat(d[-1:], order // 2, 0)])
    return factor * dt[:, None] ** (order + 1) * d


@dataclass(frozen=True)
class BiasPass:
    """One Gauss-Newton pass of the bias (what :func:`spaceid.estimation.identify` takes as ``gyro_bias``
    from :func:`identify_gyro_bias`): the bias ``b`` already subtracted from the log's base rate
    ``(3,)``, the columns of the correction ``(n, rows, n_b)`` and the attitude's estimate of ``b``."""

    bias: np.ndarray
    columns: np.ndarray
    attitude: dict

    def fused(self, eq, fit):
        """``fit`` (theta and its covariance ``cov``) updated by the attitude's measurement of the
        correction ``db``, ``b_attitude - bias`` (a Kalman update: the two are independent to first
        order; docs/theory/sensors.md)."""
        s, gain = self._gain(eq, fit.cov)
        innovation = self.attitude["value"] - self.bias[_axes(eq.planar)] - fit.theta[s]
        cov = fit.cov - gain @ fit.cov[s, :]
        return replace(fit, theta=fit.theta + gain @ innovation, cov=(cov + cov.T) / 2)

    def carried(self, eq, cov, error):
        """``error (p,)`` of the regression's estimate (of covariance ``cov``) as it carries into the
        :meth:`fused` one, whose update is linear in it."""
        s, gain = self._gain(eq, cov)
        return error - gain @ error[s]

    def _gain(self, eq, cov) -> tuple:
        """The correction's columns (a slice) and the Kalman gain ``(p, n_b)`` of :meth:`fused`."""
        s = slice(len(eq.free) + eq.n_h, len(eq.free) + eq.n_h + eq.n_b)
        return s, np.linalg.solve(cov[s, s] + self.attitude["cov"], cov[s, :]).T

    def terms(self, eq, theta, cov) -> tuple:
        """The bias estimated, ``{name, value, std, unit}`` per axis: ``bias + db``."""
        s = slice(len(eq.free) + eq.n_h, len(eq.free) + eq.n_h + eq.n_b)
        std = np.sqrt(np.diag(cov)[s])
        values = self.bias[_axes(eq.planar)] + theta[s]
        return tuple({"name": f"gyro_bias_{'xyz'[a]}", "value": float(v), "std": float(e), "unit": "rad/s"}
                     for a, v, e in zip(_axes(eq.planar), values, std))


def identify_gyro_bias(run, param, log: Log, *, estimator: str, noise, chunk, where: str):
    """:func:`spaceid.estimation.identify` with the gyro bias estimated (see the module), ``run(log,
    gyro_bias)`` being identify with every other argument bound."""
    check_gyro_bias(log, estimator, chunk, where)
    attitude = attitude_information(log, noise if noise is not None else noise_from_log(log))
    bias = np.zeros(3)
    bias[_axes(log.planar)] = attitude["value"]  # the start: the attitude's estimate
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        pi = run(replace(log, base_w=log.base_w - bias), False).values
    history = []
    for passes in range(1, MAX_PASSES + 1):
        step = BiasPass(bias, bias_columns(param, pi, replace(log, base_w=log.base_w - bias)), attitude)
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            result = run(replace(log, base_w=log.base_w - bias), step)
        values = np.array([d["value"] for d in result.gyro_bias])
        std = np.array([d["std"] for d in result.gyro_bias])
        correction = np.abs(values - bias[_axes(log.planar)])
        history.append(float(np.max(correction / std)))
        bias[_axes(log.planar)] = values
        pi = result.values
        # converged, or at round-off: within the noise and no longer shrinking (noise-free logs)
        if history[-1] <= TOLERANCE or passes > 1 and history[-1] <= 1 and history[-1] > history[-2] / 4:
            break
    else:
        caught.append(warnings.WarningMessage(
            f"{where}: the gyro bias did not converge in {MAX_PASSES} passes (last corrections "
            f"{', '.join(f'{c:.2g}' for c in history[-3:])} standard errors): the bias and the parameters are "
            "poorly determined "
            "together; record a longer log or a richer motion", UserWarning, "", 0))
    for w in caught:
        warnings.warn(w.message, w.category, stacklevel=3)
    record = {"passes": passes, "corrections": history, "attitude": {
        "value": attitude["value"].tolist(), "std": attitude["std"], "quadrature": attitude["quadrature"],
        "variance_factor": attitude["variance_factor"],
        "noise": attitude["noise"]}}
    settings = dict(result.settings, gyro_bias=record, log_fingerprint=log_fingerprint(log))
    return replace(result, settings=settings)


COLLINEAR = 1e-3
"""The bias test is not run when a bias column is this close to the span of the regressor's
(relative residual of its least-squares fit by them, whitened): the log hardly tells a bias from
the parameters there (a base turning at a nearly constant rate; 7.5e-4 on Cepheus's paper motion,
where the test, run on every log, named a 'bias' of minus the base rate; 2e-3 to 8e-2 on random
robots)."""


def bias_test(eq, x, phi, sigma, theta, estimator, log: Log, whitener, chunk, drift: dict,
              where: str) -> tuple:
    """Whether a constant gyro bias, not estimated, explains the residuals that the drift test
    (``drift``, its record, which rejected) took for a momentum drift: the same Wald test
    (:func:`spaceid.estimation._residuals.drift_test`, its level and its covariance of correlated
    residuals) with the bias columns ``-A(q; pi)`` as the candidates. When it rejects and the bias
    explains the residuals better than the drift terms (a larger Wald statistic per coefficient),
    returns the fitted bias ``(n_b,)`` [rad/s] and the warning naming it; else ``((), "")``. Not run
    on a base rate differentiated from the attitude (no gyro); silent when a bias column is within
    ``COLLINEAR`` of the span of the equations' columns (whitened; streamed alike)."""
    from ._residuals import drift_test

    if "base" in log.meta.get("differentiation", {}):
        return (), ""
    pi, axes = eq.full(theta)[0], _axes(eq.planar)
    columns = bias_columns(eq.param, pi, log)
    test = drift_test(eq, x, phi, sigma, theta, estimator, log, whitener, chunk,
                      ([f"gyro_bias_{'xyz'[a]}" for a in axes], lambda sl: columns[sl]))
    if not test["drift"] or test["span_residual"] < COLLINEAR or test["wald"] / test["dof"] < drift["wald"] / drift[
            "dof"]:
        return (), ""
    bias = tuple(test["trend"].values())
    shown = ", ".join(f"{v:.2g}" for v in bias)
    return bias, (f"{where}: the equation residuals trend (drift test p = {drift['p_value']:.2g}), but a gyro bias of "
                  f"about [{shown}] rad/s (base axes) explains them better than a momentum drift (Wald p = "
                  f"{test['p_value']:.2g}, statistic per term {test['wald'] / test['dof']:.3g} against "
                  f"{drift['wald'] / drift['dof']:.3g} for the drift terms): identify with `gyro_bias`")
