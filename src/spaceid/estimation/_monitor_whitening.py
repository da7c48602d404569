"""The monitor's whitening (docs/theory/monitor.md): each sample's equations whitened by the
equation-error covariance ``S_n`` at the segment's linearisation point, the recursive least
squares that predicts each from the samples before, and the prewhitening of innovations that
differentiated rates correlate: the differentiator's Kalman whitening
(:class:`~spaceid.estimation._monitor_filter.DifferentiatedWhitener`) when the warm-up agrees
with its model, else an autoregressive filter fitted to the warm-up's residuals.
"""

from __future__ import annotations

import collections
import dataclasses
import math
from dataclasses import dataclass

import numpy as np
from scipy.linalg import lapack, solve_triangular
from .._distributions import chi2_cdf, chi2_sf

from ..data import quat_to_matrix
from ._linalg import _accumulate_factor, _whiten, lower_inverse
from ._noise import equation_covariance
from ._uncertainty import SIGNIFICANCE, residual_checks

AR_ORDER = 3
"""Order of the autoregressive filter that prewhitens correlated innovations (rates differentiated otherwise)."""
NEGLIGIBLE = 0.01
"""Residuals' chi2/dof below which they are negligible against the noise model (an error below a tenth
of its std): no prewhitening is fitted to them."""
PRIOR = 1e4
"""The differentiator's whitening starts each segment with the estimate's error this many times
the warm-up's weighted least-squares covariance: diffuse against the warm-up itself, which it then
takes in (a change within the warm-up puts its batch estimate, the linearisation point, between
the two systems: many of its standard errors from either)."""
PRIOR_CEILING = 1e10
"""Largest variance of that prior in any direction of the scaled parameters (a unit there moves the
warm-up's whitened residuals by at most one noise standard deviation in all): a direction the
warm-up leaves this undetermined is unknown to the test either way, and larger variances leave the
filter's covariance update to round-off (on the twin, 1e13 against the raw noise's 1 turned it
indefinite and the innovations' Cholesky factorisation failed)."""


def whitened_equations(eq, log, basis, momentum, theta_ref, sigma, derivatives: bool = False, known=None) -> tuple:
    """``log``'s equations ``[A | b]`` whitened by ``S_n`` at the linearisation point.

    Parameters
    ----------
    eq : _Equations
        The monitor's equations (its model, anchors and drift kinds).
    log : Log
        The samples, ``n`` of them.
    basis : numpy.ndarray of shape (n, n_d, 3) or None
        Their drift basis since the segment's origin; None without drift terms.
    momentum : numpy.ndarray of shape (3,)
        The momentum at the segment's origin [N m s].
    theta_ref : numpy.ndarray of shape (p,)
        The linearisation point (free parameters, then drift coefficients).
    sigma : numpy.ndarray of shape (n_x,)
        Signal noise levels (:func:`~spaceid.estimation.signal_sigma`).
    derivatives : bool
        Also return the derivatives of the equations in each signal.
    known : numpy.ndarray, optional
        Those derivatives, when known (:func:`equation_derivatives`: they do not depend on ``theta_ref``).

    Returns
    -------
    white : numpy.ndarray of shape (n, rows, p + 1)
        The whitened equations.
    L : numpy.ndarray of shape (n, rows, rows)
        Cholesky factors of ``S_n``.
    J : numpy.ndarray of shape (n, rows, n_x)
        The equation errors' Jacobians at the linearisation point.
    D : numpy.ndarray of shape (n, rows, p + 1, n_x) or None
        If ``derivatives``, those of the equations ``[A | -b]`` (the equation error's Jacobian at
        any estimate is their product with ``[theta; 1]``).
    """
    eq = _at(eq, log, basis, momentum)
    x = eq.signals(log)
    J = eq.jacobian(x, theta_ref)
    L = _whiten(equation_covariance(J, sigma))
    white = np.linalg.solve(L, eq.phi(x))
    white[..., -1] *= -1
    if not derivatives:
        return white, L, J, None
    return white, L, J, _derivatives(eq, x) if known is None else known


def equation_derivatives(eq, log, basis, momentum) -> np.ndarray:
    """The derivatives ``(n, rows, p + 1, n_x)`` of ``log``'s equations ``[A | -b]`` in each signal
    (as :func:`whitened_equations` computes them, from the same arguments; they do not depend on
    the linearisation point), a view of an array laid out ``(n_x, n, rows, p + 1)``: each sample's
    are the same whatever samples they are computed with (those of the equations themselves are
    not: the regressor's vectorised loops round a sample differently in batches of other sizes)."""
    eq = _at(eq, log, basis, momentum)
    return _derivatives(eq, eq.signals(log))


def _at(eq, log, basis, momentum):
    """The equations of ``log``'s samples: their base rotations, drift basis and momentum."""
    return dataclasses.replace(eq, rot=quat_to_matrix(log.base_quat), basis=basis, momentum=momentum)


def _derivatives(eq, x) -> np.ndarray:
    """:func:`equation_derivatives` at the signals ``x (n, n_x)`` of ``eq``'s samples."""
    n, n_x = x.shape  # every signal direction in one call: the regressor's cost is mostly per call
    tiled = dataclasses.replace(eq, rot=np.tile(eq.rot, (n_x, 1, 1)),
                                basis=None if eq.basis is None else np.tile(eq.basis, (n_x, 1, 1)))
    D = tiled.dphi(np.tile(x, (n_x, 1)), np.repeat(np.eye(n_x), n, axis=0))
    return np.moveaxis(D.reshape((n_x, n) + D.shape[1:]), 0, -1)


def _prediction(R: np.ndarray, a: np.ndarray) -> tuple:
    """The estimate ``(p,)`` of the square-root information factor ``R (p + 1, p + 1)`` (scaled
    unknowns, data column last) and ``u = R_p^-T a^T (p, rows)`` for the rows ``a (rows, p)``: ``u^T
    u`` is the estimate's share of the covariance of their residual."""
    r = R[:-1, :-1]
    return lapack.dtrtrs(r, R[:-1, -1])[0], lapack.dtrtrs(r, a.T, trans=1)[0]


def _recursive_innovations(block: np.ndarray, rows: int, scale: np.ndarray) -> np.ndarray:
    """Innovations ``(n, rows)`` of recursive least squares over whitened equations ``block (n rows,
    p + 1)`` (unknowns divided by ``scale (p,)``): each sample's residual at the estimate from the
    samples before it, normalised by its covariance ``I + u^T u``; NaN (untested) until those
    samples give four equations per unknown, the least warm-up (from fewer, the innovations'
    variance ran 12 to 26 % above one on Cepheus logs with measured rates), and while they leave
    the estimate undetermined (a joint still at rest)."""
    p = len(scale)
    eqs = np.asfortranarray(block / np.r_[scale, 1.0])
    out, R = np.full((len(block) // rows, rows), np.nan), None
    for k in range(len(out)):
        a, b = eqs[k * rows : (k + 1) * rows, :p], eqs[k * rows : (k + 1) * rows, p]
        if k * rows >= 4 * (p + 1):
            diag = np.abs(np.diag(R)[:p])
            if diag.min() > 1e-8 * diag.max():
                theta, u = _prediction(R, a)
                out[k] = solve_triangular(np.linalg.cholesky(np.eye(rows) + u.T @ u), b - a @ theta, lower=True)
        R = _accumulate_factor(R, eqs[k * rows : (k + 1) * rows])
    return out


def _ar_fit(res: np.ndarray, order: int, p: int) -> tuple:
    """Autoregressive coefficients ``(order,)`` of the whitened residuals ``res (n, rows)`` (the rows
    as separate series with common coefficients, least squares) and the std of what the filter leaves, its variance
    scaled by ``m / (m - p)`` for the ``p`` unknowns fitted to the ``m`` equations (the residuals
    are smaller than the innovations by the fit's share)."""
    n = len(res)
    lags = np.stack([res[order - k : n - k] for k in range(1, order + 1)], axis=-1).reshape(-1, order)
    now = res[order:].reshape(-1)
    coef = np.linalg.lstsq(lags, now, rcond=None)[0]
    left = now - lags @ coef
    m = res.size
    scale = math.sqrt(np.sum(left**2) / max(left.size - order, 1) * m / max(m - p, 1))
    return coef, scale


def _ar_filtered(nu: np.ndarray, coef, scale: float) -> np.ndarray:
    """What the AR filter ``coef (order,)`` of the past does not predict of each of the innovations
    ``nu (n, rows)``, divided by ``scale`` (the first ``order`` with the lags they have)."""
    out = np.array(nu, float)
    for k, c in enumerate(coef, start=1):
        out[k:] -= c * nu[:-k]
    return out / scale


def whitener_prior(R: np.ndarray, p: int) -> np.ndarray:
    """The covariance ``(p, p)`` the differentiator's whitening starts a segment with: the
    estimate's error ``PRIOR`` times as uncertain as the weighted least-squares factor ``R`` (scaled
    unknowns first) says, no direction's variance above ``PRIOR_CEILING`` or below zero."""
    r_inv = solve_triangular(R[:p, :p], np.eye(p))
    variances, axes = np.linalg.eigh(PRIOR * r_inv @ r_inv.T)
    # negative variances are rounding: a factor of scaled condition 1e8 gave -4e3 beside 1e10, and the
    # filter's covariance, started indefinite, turned the innovations' variances negative
    return (axes * np.clip(variances, 0.0, PRIOR_CEILING)) @ axes.T


def differentiator_innovations(whitener, t, a, res, L, J, sigma, p: int, start: int = 0) -> tuple:
    """Run the differentiator's whitening (started) over a warm-up's residuals; its state then
    predicts the first tested sample.

    Parameters
    ----------
    whitener : DifferentiatedWhitener
        The whitening, started for the segment.
    t : sequence of float
        The warm-up's sample times [s], ``n`` of them.
    a : numpy.ndarray of shape (n, rows, p)
        Their whitened regressors in the scaled unknowns.
    res : numpy.ndarray of shape (n, rows)
        Their whitened residuals at the warm-up's batch estimate.
    L, J : numpy.ndarray
        Their whiteners ``(n, rows, rows)`` and Jacobians ``(n, rows, n_x)`` (:func:`whitened_equations`).
    sigma : numpy.ndarray of shape (n_x,)
        Signal noise levels.
    p : int
        Unknowns fitted to the warm-up.
    start : int
        The first sample whose innovation the check takes (:func:`kalman_check`; before, the samples
        before each did not determine the estimate, and the regressor's noise biased its
        predictions: on a 33-parameter robot the innovations of a 16 s warm-up failed the Ljung-Box
        test by their first 4 s). All are returned.

    Returns
    -------
    nu : numpy.ndarray of shape (n, rows)
        The innovations.
    chi2_dof : float
        Their chi-square per degree of freedom (``p`` unknowns fitted).
    scale : float
        What the test divides them by: 1, or ``sqrt(chi2_dof)`` when they are larger than the
        noise model predicts (its upper tail below ``SIGNIFICANCE``: effects it does not have).
    small : bool
        Whether they are smaller than it predicts (the lower tail).
    start : int
        The first of them that the check took.
    """
    Li = lower_inverse(L)
    R = Li @ equation_covariance(J, whitener.uncovered(sigma)) @ np.swapaxes(Li, -1, -2)
    nu = [whitener.innovation(r, whitener.design(tk, ak, li @ j), c)
          for tk, r, ak, li, j, c in zip(t, res, a, Li, J, R)]  # fmt: skip
    nu = np.array(nu)
    _, chi2_dof, scale, small = kalman_check(nu[start:], p if start == 0 else 0)
    return nu, chi2_dof, scale, small, start


def kalman_check(nu: np.ndarray, p: int) -> tuple:
    """The differentiator's innovations ``nu (n, rows)`` over a warm-up with ``p`` unknowns fitted
    (0 for a part of it after the estimate is determined), their chi2/dof, the scale the test
    divides them by and whether they are smaller than predicted (:func:`differentiator_innovations`)."""
    dof = max(nu.size - p, 1)
    chi2_dof = float(np.sum(np.square(nu)) / dof)
    scale = math.sqrt(chi2_dof) if chi2_sf(chi2_dof * dof, dof) < SIGNIFICANCE else 1.0
    return nu, chi2_dof, scale, bool(chi2_cdf(chi2_dof * dof, dof) < SIGNIFICANCE)


@dataclass
class Prewhitening:
    """How a segment whitens its innovations beyond ``S_n``, chosen on its warm-up (:func:`prewhitening`).

    Attributes
    ----------
    kalman : bool
        The differentiator's Kalman whitening; turned off within the segment when a new part of
        the log comes without a differentiation record.
    kalman_scale : float
        What that whitening's innovations are divided by (1, or ``sqrt(chi2_dof)`` of the warm-up).
    coefficients : numpy.ndarray of shape (order,)
        The AR filter (empty without one).
    scale : float
        The std the AR filter leaves (1 without one).
    lags : collections.deque of numpy.ndarray of shape (rows,)
        The last ``order`` innovations, the filter's lags.
    record : dict
        The JSON record (``prewhitening`` of a segment, docs/formats/events-json.md).
    """

    kalman: bool
    kalman_scale: float
    coefficients: np.ndarray
    scale: float
    lags: collections.deque
    record: dict

    def filtered(self, nu: np.ndarray) -> np.ndarray:
        """A tested sample's innovation ``nu (rows,)`` through the AR filter of the ones before it
        (none: ``nu`` itself)."""
        if not len(self.coefficients):
            return nu
        recent = np.array([*self.lags, nu])  # the order lags, then this sample
        self.lags.append(nu)
        return _ar_filtered(recent, self.coefficients, self.scale)[-1]


def prewhitening(res: np.ndarray, p: int, window: int, kalman: tuple | None,
                 noise: float | None = None) -> Prewhitening:
    """The segment's prewhitening from the warm-up's whitened residuals at its batch estimate.

    The differentiator's Kalman whitening when the log records Savitzky-Golay rates and the
    warm-up agrees with its model: its innovations independent (Ljung-Box) and not smaller than
    predicted (the lower tail of chi2/dof), both at ``SIGNIFICANCE``. Otherwise an
    AR(``AR_ORDER``) filter and the std it leaves, fitted to the residuals, when the rates were
    differentiated or the residuals are autocorrelated (Ljung-Box, as the identification's
    covariance choice); else none (the innovations are independent). None either when the
    residuals are negligible against the noise model (chi2/dof below ``NEGLIGIBLE``: a noise-free
    log, whose residuals are rounding, integration or differentiator errors, smooth): the model's
    levels bound the errors, and the test runs at them; a filter fitted to such residuals would
    normalise the innovations by them, which the estimate's own error (it absorbs part of a smooth
    error, and extrapolates it) exceeds, and raise alarms on it.

    Parameters
    ----------
    res : numpy.ndarray of shape (n, rows)
        The warm-up's whitened residuals.
    p : int
        Unknowns fitted to them.
    window : int
        The differentiator's window [samples]; 0 for measured rates.
    kalman : tuple or None
        The warm-up under the differentiator's whitening (:func:`differentiator_innovations`);
        None without a differentiation record.
    noise : float, optional
        The sum of the residuals' error variances under the noise model (with differentiated
        rates, their smoothed noise's); the number of residuals when omitted.
    """
    checks = residual_checks(res, res.size, None)
    expected = (res.size if noise is None else noise) * max(res.size - p, 1) / res.size  # p unknowns fitted
    residual_chi2_dof = float(np.sum(res**2) / expected) if expected > 0 else math.inf
    negligible = residual_chi2_dof < NEGLIGIBLE
    use, chi2_dof, kalman_scale, kalman_p = False, None, 1.0, None
    if kalman is not None:
        nu, chi2_dof, kalman_scale, small, start = kalman
        kalman_p = residual_checks(nu[start:], nu[start:].size, None)["ljung_box_p"]
        use = kalman_p >= SIGNIFICANCE and not small and not negligible
    correlated = window or checks["ljung_box_p"] < SIGNIFICANCE
    order = AR_ORDER if not use and not negligible and correlated and len(res) > 4 * AR_ORDER else 0
    coef, scale = _ar_fit(res, order, p) if order else (np.zeros(0), 1.0)
    record = {"filter": "differentiator" if use else "autoregressive" if order else None,
              "order": order, "coefficients": coef.tolist(), "scale": scale, "chi2_dof": chi2_dof,
              "differentiator_scale": None if kalman is None else kalman_scale,
              "innovations_ljung_box_p": kalman_p,
              "lag1_autocorrelation": checks["lag1_autocorrelation"],
              "ljung_box_p": checks["ljung_box_p"], "residual_chi2_dof": residual_chi2_dof,
              "differentiator_window": window}  # fmt: skip
    lags = collections.deque(list(res[len(res) - order :]), maxlen=order)  # the lags of the first test
    return Prewhitening(use, kalman_scale, coef, scale, lags, record)


def warm_up_innovations(last: dict | None, block: np.ndarray, kalman, rows: int, scale: np.ndarray, nf: int,
                        carried: np.ndarray | None, inflation=None):
    """The innovations ``(n, rows)`` of a warm-up after an alarm, each predicted from the warm-up's
    samples before it, under the whitening of the segment before (its recording's noise), divided
    by the square root of ``inflation (n,)``: how much the regressor noise makes the prediction's
    variance larger than the recursion says (:mod:`~spaceid.estimation._monitor_determinacy`;
    NaN: untested). The first warm-up is tested under its own whitening (``last`` its record).

    The differentiator's (``kalman``, :func:`differentiator_innovations`), divided by the square
    root of that segment's chi2/dof when above 1 (this warm-up's own would grow with a change
    within it); else those of recursive least squares from the warm-up's start (its whitened
    equations ``block (n rows, p + 1)``, unknowns divided by ``scale (p,)``, the ``nf`` free
    parameters first), through that segment's AR filter if it had one. None when ``last`` is None.

    With drift terms, recursive least squares takes the drift coefficients ``carried (n_d,)`` the
    change's momentum was carried with as known: estimated from the warm-up's first samples,
    whose drift basis has barely grown, they leave the parameters' estimate so loose along a
    direction that the regressor's own noise (not in ``I + u^T u``) inflated the innovations (on
    Cepheus logs their variance ran 0.6 to 1.6 over a warm-up at the exact weights).
    """
    if last is None:
        return None
    if last["filter"] == "differentiator":
        nu = kalman / math.sqrt(max(last["chi2_dof"], 1.0))  # its excess as measured, significant or not
    else:
        if carried is not None:  # [A_free | b - A_drift d]
            block = np.column_stack([block[:, :nf], block[:, -1] - block[:, nf:-1] @ carried])
        else:
            nf = len(scale)
        nu = _recursive_innovations(block, rows, scale[:nf])
        nu = _ar_filtered(nu, last["coefficients"], last["scale"]) if last["order"] else nu
    return nu if inflation is None else nu / np.sqrt(inflation)[:, None]

