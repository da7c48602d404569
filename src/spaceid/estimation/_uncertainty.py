"""Uncertainty of the estimates: first-order sandwich covariances, the Newey-West estimate for
differentiated rates, and the Cramer-Rao bound.

Every estimator's covariance is its first-order sandwich with the equation-error covariances of
the noise model. Given noise levels are trusted and ``chi2_dof`` checks them against the
residuals; levels estimated from the log fix only the relative weights, and the residuals fix
the overall scale (the covariance is multiplied by ``chi2_dof``). Rates that come from a
differentiator have errors correlated over its window, which no white-noise model describes:
the covariance is then the Newey-West (heteroscedasticity and autocorrelation consistent)
estimate from the residuals, with the window as bandwidth.

References
----------
.. [1] K. Kanatani, "Statistical Optimization for Geometric Computation", 1996 (the KCR bound).
"""

from __future__ import annotations

import numpy as np

from .._threads import one_blas_thread
from ..data import Log
from ..dynamics import Parameterization
from ._drift import drift_vector
from ._equations import _equations, _split
from ._estimators import _column_scale, _equation_whitener, _inverse_gram, _inverse_times, _sandwich, _solve, _whitened
from ._noise import Noise, signal_sigma

__all__ = ["cramer_rao"]


def _influence(estimator, A, phi, L, info):
    """``M (n, rows, p)`` and ``bread (p, p)`` of ``estimator``'s first-order error
    ``theta - theta_0 = bread sum_n M_n^T e_n`` (see :func:`_covariance`)."""
    if estimator in ("wls", "ml"):
        return _inverse_times(L, A), _solve(*_split(_whitened(L, phi)))[1]
    if estimator == "iv":
        M = info.pop("Z").reshape(A.shape)
        scale = _column_scale(A.reshape(-1, A.shape[-1]))  # (Z^T A)^-1 = D^-1 (Z_s^T A_s)^-1 D^-1: balanced
        with one_blas_thread():
            return M, np.linalg.inv(np.einsum("nrp,nrq->pq", M / scale, A / scale)) / np.outer(scale, scale)
    return A, _inverse_gram(A.reshape(-1, A.shape[-1]))


def _covariance(eq, x, phi, sigma, theta, estimator, info, bandwidth=0):
    """First-order covariance of ``theta`` for ``estimator``, the chi-square per degree of
    freedom of the residuals under the noise model, and the RMS residual.

    Every estimator is, to first order, ``theta - theta_0 = bread sum_n M_n^T e_n`` with ``e_n``
    the equation errors: ``M_n = S_n^-1 A_n`` (wls, ml), ``Z_n`` (iv), ``A_n`` (ols, tls). With
    independent samples the covariance is ``bread (sum_n M_n^T S_n M_n) bread^T``; with errors
    correlated over ``bandwidth`` samples (rates from a differentiator's window) it is the
    Newey-West estimate from the residuals' scores ``g_n = M_n^T r_n`` with Bartlett weights.
    """
    xl = info.get("corrected", x)
    if "corrected" in info:  # ML: linearised at the corrected signals, evaluated at the measured
        phi = eq.phi(xl) + eq.dphi(xl, x - xl)
    A = phi[..., :-1]
    r = phi @ np.append(theta, 1.0)
    rms = float(np.sqrt(np.mean(r**2)))
    if estimator == "ols":  # no noise model: heteroscedasticity-consistent, from the residuals
        return _newey_west(info.pop("ginv"), A, r, bandwidth, eq.p), None, rms
    L = _equation_whitener(eq, xl, theta, sigma)
    M, bread = _influence(estimator, A, phi, L, info)
    cov = _newey_west(bread, M, r, bandwidth, eq.p) if bandwidth > 0 else _sandwich(bread, M, L)
    white = _whitened(L, r[..., None])[..., 0]
    dof = max(r.size - eq.p, 1)
    return cov, float(np.sum(white**2) / dof), rms


def _newey_west(bread, M, r, bandwidth, p):
    """``bread Omega bread^T`` with ``Omega`` the Bartlett-weighted autocovariance of the scores
    ``g_n = M_n^T r_n`` up to lag ``bandwidth`` (0: White's heteroscedasticity-consistent form),
    scaled by ``n / (n - p)``. Formed from the mapped scores ``bread g_n``, so that at lag 0 it is
    a Gram matrix: no negative variances from round-off when the residuals vanish."""
    x = np.einsum("nrp,nr->np", M, r) @ bread.T
    cov = x.T @ x
    for lag in range(1, min(bandwidth, len(x) - 1) + 1):
        c = x[lag:].T @ x[:-lag]
        cov += (1 - lag / (bandwidth + 1)) * (c + c.T)
    return cov * len(x) / max(len(x) - p, 1)


def _window_spans(node):
    """Every differentiator window ``window_s`` [s] recorded in a nested record."""
    if isinstance(node, dict):
        for key, value in node.items():
            if key == "window_s" and value is not None:
                yield from np.ravel(value).tolist()
            else:
                yield from _window_spans(value)
    elif isinstance(node, list):
        for value in node:
            yield from _window_spans(value)


def _correlation_length(log: Log) -> int:
    """Samples over which the errors of differentiated rates are correlated: the longest
    differentiator window recorded in ``log.meta`` (0 when nothing was differentiated)."""
    info = log.meta.get("differentiation")
    if not info or log.n_samples < 2:
        return 0
    spans = list(_window_spans(info))
    step = float(np.median(np.diff(log.t)))
    if not spans:  # e.g. smoothing splines: the Newey-West rule of thumb
        return int(np.floor(4 * (log.n_samples / 100) ** (2 / 9)))
    return int(np.ceil(max(spans) / step))


def _reported_covariance(eq, x, phi, sigma, theta, estimator, info, log, estimated):
    """The covariance ``(p, p)`` of ``theta`` that :func:`spaceid.estimation.identify` reports,
    the RMS residual, and the record of how it was obtained (``chi2_dof``, ``variance_factor``,
    ``covariance``) for the result's settings. ``estimated``: the noise levels came from the log."""
    bandwidth = 0 if "covariance" in info else _correlation_length(log)  # the angles estimator: its own
    cov_t, chi2, rms = info.pop("covariance") if "covariance" in info else _covariance(eq, x, phi, sigma, theta,
                                                                                       estimator, info, bandwidth)
    factor = 1.0
    if bandwidth:
        how = f"Newey-West from the residuals, Bartlett weights over {bandwidth} samples (differentiated rates)"
    elif estimator == "ols":
        how = "heteroscedasticity-consistent (White) from the residuals"
    elif estimated:  # levels from the log are rough (sparse logs mix signal into them): let the
        factor = chi2  # residuals set the overall scale (a posteriori variance factor)
        cov_t = cov_t * chi2
        how = "noise model (levels estimated from the log) times the variance factor chi2_dof"
    else:
        how = "noise model (levels given)"
    return cov_t, rms, {"chi2_dof": chi2, "variance_factor": factor, "covariance": how}  # chi2_dof None for ols


def cramer_rao(param: Parameterization, log: Log, momentum, noise: Noise, *, known=None, estimate_momentum=False,
               drift=None):
    """Cramer-Rao bound of the errors-in-variables model for a motion and noise levels.

    With Gaussian noise on the signals and the momentum equations holding exactly for the true
    signals, the bound on the unknowns is ``(sum_n A_n^T S_n^{-1} A_n)^{-1}`` (Kanatani's KCR
    bound), ``A_n`` the regressor rows and ``S_n`` the equation-error covariance, both at the
    true signals and parameters.

    Parameters
    ----------
    param : Parameterization
        Its ``true_values`` are the true parameters.
    log : Log
        The noise-free motion.
    momentum : array_like of shape (3,)
        True inertial momentum [N m s].
    noise : Noise
    known : dict, optional
        Known parameters, as for :func:`spaceid.estimation.identify` (reaction wheels count as known).
    estimate_momentum : bool
        Whether the momentum is among the unknowns.
    drift : dict, optional
        True drift terms, estimated with the parameters: ``{kind: value}`` as
        :func:`spaceid.motion.simulate` takes them (each kind given is an unknown, even at 0).

    Returns
    -------
    names : list of str
        The unknowns (free parameters, then ``h_*`` if estimated, then the drift coefficients).
    cov : ndarray of shape (p, p)
    """
    momentum = np.asarray(momentum, float)
    drift = dict(drift or {})
    eq, _ = _equations(param, log, None if estimate_momentum else momentum, known, "cramer_rao", tuple(drift))
    theta = np.concatenate([param.true_values[eq.free], momentum[eq.axes] if estimate_momentum else [],
                            drift_vector(drift, tuple(drift), param.model.planar)])
    x = eq.signals(log)
    L = _equation_whitener(eq, x, theta, signal_sigma(param, noise))
    Aw, _ = _split(_whitened(L, eq.phi(x)))
    return eq.names(), _inverse_gram(Aw)
