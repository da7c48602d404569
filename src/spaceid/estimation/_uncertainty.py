"""Uncertainty of the estimates: first-order sandwich covariances, the Newey-West estimate for
differentiated rates, and the Cramer-Rao bound.

Every estimator's covariance is its first-order sandwich. While the residuals agree with the
noise model (``chi2_dof`` within its chi-square band and no significant autocorrelation, at
``SIGNIFICANCE``) it is the sandwich of the model's equation-error covariances: given levels
are trusted, levels estimated from the log fix only the relative weights and the residuals the
overall scale (times ``chi2_dof``). When the residuals contradict the model the covariance
follows them: the sandwich of the residuals' scores (White), or the Newey-West
(heteroscedasticity and autocorrelation consistent) estimate when they are correlated; a
``chi2_dof`` far from 1 also brings a warning that says what it means (:func:`noise_model_warning`).
Rates from a Savitzky-Golay differentiator are a known linear filter of the angles: their
covariance is the angle noise propagated through it (:mod:`spaceid.estimation._differentiated`),
or the Newey-West estimate in the directions where the residuals show more (:func:`larger_of`).

References
----------
.. [1] K. Kanatani, "Statistical Optimization for Geometric Computation", 1996 (the KCR bound).
.. [2] D. W. K. Andrews, "Heteroskedasticity and autocorrelation consistent covariance matrix
   estimation", Econometrica 59(3), 1991 (the plug-in bandwidth).
.. [3] N. M. Kiefer, T. J. Vogelsang, "A new asymptotic theory for heteroskedasticity-autocorrelation
   robust tests", Econometric Theory 21(6), 2005 (the fixed-b mean of the Bartlett estimate).
.. [4] G. M. Ljung, G. E. P. Box, "On a measure of lack of fit in time series models",
   Biometrika 65(2), 1978.
"""

from __future__ import annotations

import numpy as np
from scipy.linalg import lapack

from .._distributions import chi2_cdf, chi2_ppf, chi2_sf

from .._threads import one_blas_thread
from ..data import Log
from ..dynamics import Parameterization
from ._differentiated import differentiated_series, propagated_covariance
from ._drift import drift_vector
from ._equations import _equations, _split, equation_residuals
from ._linalg import _column_scale, _equation_whitener, _inverse_gram, _inverse_times, _sandwich, _solve, _whitened
from ._noise import Noise, signal_sigma

__all__ = ["cramer_rao"]

WEIGHTED = ("wls", "ml")
"""The estimators weighted by the inverse equation-error covariances (``M_n = A_n``, ``W_n = S_n^-1``
in :func:`_covariance_terms`)."""


def _influence(estimator, A, phi, L, info):
    """``M (n, rows, p)`` and ``bread (p, p)`` of ``estimator``'s first-order error (see
    :func:`_covariance_terms`)."""
    if estimator in WEIGHTED:
        return A, _solve(*_split(_whitened(L, phi)))[1]
    if estimator == "iv":
        M = info.pop("Z").reshape(A.shape)
        scale = _column_scale(A.reshape(-1, A.shape[-1]))  # (Z^T A)^-1 = D^-1 (Z_s^T A_s)^-1 D^-1: balanced
        with one_blas_thread():
            return M, np.linalg.inv(np.einsum("nrp,nrq->pq", M / scale, A / scale)) / np.outer(scale, scale)
    return A, _inverse_gram(A.reshape(-1, A.shape[-1]))


def _covariance_terms(eq, x, phi, sigma, theta, estimator, info):
    """The pieces of ``estimator``'s first-order covariance: ``M (n, rows, p)``, ``bread (p, p)``,
    the Cholesky factors ``L`` of the equation-error covariances (None for ols: no noise model),
    the residuals ``r (n, rows)``, the residuals ``scored`` that the scores weight and, with a noise
    model, the whitened residuals.

    Every estimator is, to first order, ``theta - theta_0 = bread sum_n M_n^T W_n e_n`` with ``e_n``
    the equation errors: ``M_n = A_n`` and ``W_n = S_n^-1`` (wls, ml), ``M_n = Z_n`` (iv) or ``A_n``
    (ols, tls) and ``W_n = I``. With independent samples and the noise model right, the covariance
    is ``bread (sum_n M_n^T W_n S_n W_n M_n) bread^T`` (:func:`_model_covariance`); whatever the
    noise, it is estimated from the residuals' scores ``g_n = M_n^T W_n r_n``, ``W_n r_n`` the
    ``scored`` residuals (:func:`newey_west_covariance`). An estimator that formed the pieces at
    its estimate gives them in ``info["terms"]`` (ML: at the corrected signals)."""
    if "terms" in info:
        return info.pop("terms")
    A = phi[..., :-1]
    r = info.pop("residuals") if "residuals" in info else equation_residuals(phi, theta)  # (identify forms ols's)
    if estimator == "ols":
        return {"M": A, "bread": info.pop("ginv"), "L": None, "r": r, "scored": r, "white": None}
    L = _equation_whitener(eq, x, theta, sigma)
    M, bread = _influence(estimator, A, phi, L, info)
    scored = _inverse_times(L, r[..., None])[..., 0] if estimator in WEIGHTED else r
    return {"M": M, "bread": bread, "L": L, "r": r, "scored": scored, "white": _whitened(L, r[..., None])[..., 0]}


def newey_west_covariance(bread, M, r, bandwidth, p, dof_scale=True):
    """``bread Omega bread^T`` with ``Omega`` the Bartlett-weighted autocovariance of the scores
    ``g_n = M_n^T r_n`` up to lag ``bandwidth`` (0: White's heteroscedasticity-consistent form),
    scaled by ``n / (n - p)`` and, for a bandwidth ``b n``, by ``1 / (1 - b + b^2 / 3)``: the mean of
    the Bartlett estimate from residuals is that fraction of the truth when the bandwidth is not
    small against the log (Kiefer and Vogelsang's fixed-b result; on Cepheus at 501 samples and a
    50-sample bandwidth it moved 2-sigma coverage from 0.94 to 0.95). ``dof_scale`` False: without
    the ``n / (n - p)`` (residuals already scaled by their leverage). See :func:`_hac`.

    Formed as the Gram matrix of ``bread Omega^(1/2)`` (:func:`_mapped_psd`): no negative variance
    from round-off. ``bread Omega bread^T`` as products gave 26 of 153 negative variances (NaN
    standard errors) on a noise-free satellite log, its ``bread`` at condition number 1e18."""
    # a Gram matrix, mapped after (p^3, not n p^2); the scores a block at a time (a whole log's, 40 MB of the
    # servicer's, were fresh pages to fault in at each call: 0.1 s, five times their product's time)
    blocks = (_mapped_scores(None, M[i : i + HAC_BLOCK], r[i : i + HAC_BLOCK]) for i in range(0, len(r), HAC_BLOCK))
    return _mapped_psd(bread, _hac(blocks, bandwidth, p, dof_scale))


def _mapped_psd(bread, omega):
    """``bread omega bread^T`` for a positive semi-definite ``omega (p, p)``, as the Gram matrix of
    ``bread D P L`` (``D^-1 omega D^-1 = P L L^T P^T`` by Cholesky with pivoting, LAPACK ``pstrf``, stopped at
    its rank, ``D`` the diagonal's square roots): positive semi-definite whatever the round-off, and a fifth of
    an eigendecomposition's time (0.025 s for the servicer's 496 parameters)."""
    if not np.all(np.isfinite(omega)):
        raise np.linalg.LinAlgError("the residuals' scores are not finite")
    d = np.sqrt(np.maximum(np.diag(omega), 0.0))
    d = np.where(d > 0, d, 1.0)
    with one_blas_thread():
        c, pivots, rank, _ = lapack.dpstrf(omega / np.outer(d, d), lower=1)  # (info > 0: rank deficient)
        root = np.zeros((len(d), rank))
        root[pivots - 1] = np.tril(c)[:, :rank]
        half = bread @ (d[:, None] * root)
        return half @ half.T


def _mapped_scores(bread, M, r):
    """The scores ``g_n = M_n^T r_n`` mapped by ``bread`` (None: as they are): ``(n, p)`` rows ``bread g_n``."""
    scores = np.einsum("nrp,nr->np", M, r)
    if bread is None:
        return scores
    with one_blas_thread():
        return scores @ bread.T


def _window_sums(rows, width: int, m: int) -> np.ndarray:
    """The sums ``(m, c)`` of ``width`` consecutive rows of ``rows (k, c)`` ending at each of its last ``m``
    (``k >= m + width - 1``), as differences of one cumulative sum (its rounding, ``eps`` times the
    largest partial sum, stays far below the sums: scores about a fit are centred)."""
    total = np.cumsum(rows, axis=0)
    start = len(rows) - m
    before = total[start - width : len(rows) - width] if start >= width else np.vstack(
        [np.zeros((width - start, rows.shape[1])), total[: len(rows) - width]])
    return total[start:] - before


HAC_BLOCK = 1024
"""Scores taken at a time by :func:`_hac` (its copies and sums stay in cache)."""


def _hac(chunks, bandwidth, p, dof_scale=True):
    """:func:`newey_west_covariance` from the mapped scores ``bread g_n`` given as consecutive chunks
    ``(n_c, p)`` in time order (one, or a stream of them: the windows reach back across chunks).

    The Bartlett-weighted sum of the lagged products is the Gram matrix of the scores' sums over windows
    of ``bandwidth + 1`` samples, divided by ``bandwidth + 1``: with the log padded by ``bandwidth`` zeros
    at both ends, two samples ``lag`` apart share ``bandwidth + 1 - lag`` windows. One product whatever
    the bandwidth (a lag at a time cost a product per lag: 12 on a 10,000-sample log), and a Gram
    matrix: no negative variances from round-off when the residuals vanish. BLAS on one thread: on busy
    cores threaded BLAS took these products (10,000 scores of 496 parameters) from 0.15 s to 0.5 s
    (measured)."""
    cov, n, tail = 0.0, 0, np.zeros((bandwidth, p))  # tail: the last `bandwidth` scores, zeros before the log
    with one_blas_thread():
        for x in (chunk[i : i + HAC_BLOCK] for chunk in chunks for i in range(0, len(chunk), HAC_BLOCK)):
            both = np.vstack([tail, x]) if bandwidth else x
            sums = _window_sums(both, bandwidth + 1, len(x)) if bandwidth else x  # White's: the scores themselves
            cov, tail, n = cov + sums.T @ sums, both[len(both) - bandwidth :], n + len(x)
        if bandwidth:  # the windows that reach past the log's end
            sums = _window_sums(np.vstack([tail, np.zeros((bandwidth, p))]), bandwidth + 1, bandwidth)
            cov = cov + sums.T @ sums
    b = min(bandwidth / max(n, 1), 1.0)
    return cov / (bandwidth + 1) * (n / max(n - p, 1) if dof_scale else 1.0) / (1 - b + b * b / 3)


def window_spans(node):
    """Every differentiator window ``window_s`` [s] recorded in a nested record."""
    if isinstance(node, dict):
        for key, value in node.items():
            if key == "window_s" and value is not None:
                yield from np.ravel(value).tolist()
            else:
                yield from window_spans(value)
    elif isinstance(node, list):
        for value in node:
            yield from window_spans(value)


def correlation_length(log: Log) -> int:
    """Samples over which the errors of differentiated rates are correlated: the longest
    differentiator window recorded in ``log.meta`` (0 when nothing was differentiated)."""
    info = log.meta.get("differentiation")
    if not info or not any(info.values()) or log.n_samples < 2:  # (a bag's record of no series: every rate measured)
        return 0
    spans = list(window_spans(info))
    step = float(np.median(np.diff(log.t)))
    if not spans:  # e.g. smoothing splines: the Newey-West rule of thumb
        return int(np.floor(4 * (log.n_samples / 100) ** (2 / 9)))
    return int(np.ceil(max(spans) / step))


SIGNIFICANCE = 1e-3
"""Significance level at which the residuals are taken to contradict the noise model (the
chi-square test of ``chi2_dof`` and the Ljung-Box test of their autocorrelation)."""

LAGS = 10
"""Lags of the Ljung-Box test (fewer on short logs: a tenth of the samples)."""

LEVERAGE_LIMIT = 0.1
"""Largest ratio of unknowns to equations for which the Ljung-Box test decides the covariance: a
fit's residuals share its projection, so with many unknowns per equation (a 496-parameter
servicer from 1,500 equations) they are correlated though the noise is white, and the test
would inflate honest standard errors (measured: 8-fold)."""


def _ljung_box_p(rho, m: int) -> float:
    """Ljung-Box p-value of the autocorrelations ``rho (lags,)`` at lags 1, 2, ... of ``m`` samples."""
    lags = len(rho)
    q = m * (m + 2) * np.sum(rho**2 / (m - np.arange(1, lags + 1)))
    return float(chi2_sf(q, lags))


def residual_checks(res, dof, chi2):
    """The tests of the residuals ``res (n, rows)`` (whitened when there is a noise model) against
    white noise of the model's levels: the two-sided chi-square p-value of ``chi2_dof`` for ``dof``
    degrees of freedom (None without a noise model), the band of ``chi2_dof`` that passes, and the
    Ljung-Box p-value of the autocorrelations pooled over the rows (each row standardised), with the
    lag-1 autocorrelation."""
    n = len(res)
    lags = max(1, min(LAGS, n // 10))
    e = res - res.mean(axis=0)
    e = e / np.where(e.std(axis=0) > 0, e.std(axis=0), 1.0)
    rho = np.array([np.sum(e[k:] * e[:-k]) for k in range(1, lags + 1)]) / max(np.sum(e**2), 1e-300)
    m = n * res.shape[1]  # pooled: the rows as independent series under the model
    record = {"significance": SIGNIFICANCE, "ljung_box_p": _ljung_box_p(rho, m), "ljung_box_lags": lags,
              "lag1_autocorrelation": float(rho[0]), "chi2_p": None, "chi2_band": None}  # fmt: skip
    if chi2 is not None:
        cdf = chi2_cdf(chi2 * dof, dof)
        record["chi2_p"] = float(2 * min(cdf, 1 - cdf))
        record["chi2_band"] = [float(chi2_ppf(q, dof) / dof) for q in (SIGNIFICANCE / 2, 1 - SIGNIFICANCE / 2)]
    return record


def _hac_bandwidth(rho1, n):
    """Newey-West bandwidth [samples] for residuals of lag-1 autocorrelation ``rho1``: Andrews'
    plug-in rule for the Bartlett kernel and an AR(1) error, ``1.1447 (alpha n)^(1/3)``."""
    rho1 = min(abs(rho1), 0.99)
    return int(np.ceil(1.1447 * (4 * rho1**2 / (1 - rho1**2) ** 2 * n) ** (1 / 3)))


POOR_FIT_CHI2 = 100.0
"""A ``chi2_dof`` above this (residuals 10 times the noise) with noise levels estimated from the
log and measured rates is a poor fit, not a noise-level error (given levels may be wrong; rates
differentiated from the angles reach it on clean logs, their estimated levels understated)."""


FOLLOWED = "the standard errors follow the residuals instead"
"""How :func:`noise_model_warning` ends by default: what the covariance then is (:data:`CONTRADICTED`)."""


def noise_model_warning(chi2, checks, log: Log, estimated: bool, standard_errors: str = FOLLOWED) -> str:
    """What a ``chi2_dof`` far from 1 means, or ``""``: the test rejects the noise model and the
    standard errors it implies would be off by more than ~40 % (``chi2_dof`` outside [0.5, 2]).
    Levels estimated from the log are not blamed for being too large (on smooth or noise-free
    logs the sixth-order differences hold some of the motion: the residuals set the scale).
    ``standard_errors``: what the caller's standard errors then are, the warning's last words."""
    if chi2 is None or checks["chi2_p"] >= SIGNIFICANCE or 0.5 <= chi2 <= 2 or (estimated and chi2 < 1):
        return ""
    lo, hi = checks["chi2_band"]
    if chi2 < 1:
        cause = "the noise levels are larger than the residuals show (check `noise` or let them be estimated)"
    else:
        cause = ("the noise levels are too small for the residuals, or the equations miss something: unmodelled "
                 "drift or disturbances (gas jets, cables, air-bearing tilt), rates from one-tick differences or a "
                 "differentiator, a wrong momentum or model")  # fmt: skip
        if "differentiation" in log.meta:
            cause += " (here the rates were differentiated: levels estimated from them understate their error)"
        elif estimated and chi2 > POOR_FIT_CHI2:  # levels from the log itself: the data or equations are wrong
            cause = (f"the residuals are {np.sqrt(chi2):.0f} times the noise: the fit is poor, likely wrong data "
                     "(swapped or mislabelled columns, units: see the log's warnings), a wrong momentum or model; else "
                     + cause)
    return (f"chi2_dof = {chi2:.3g}, outside [{lo:.3g}, {hi:.3g}] at significance {SIGNIFICANCE:g}: the residuals "
            f"contradict the noise model: {cause}; {standard_errors}")


def _own_covariance(cov_t, chi2, rms, estimated) -> tuple:
    """An estimator's own covariance (the angles estimator: the inverse Fisher matrix of its
    likelihood, nuisance eliminated) as :func:`_reported_covariance` returns it; scaled by
    ``chi2`` when the noise levels were estimated from the log."""
    factor = chi2 if estimated else 1.0
    how = "inverse Fisher information of the angle likelihood" + (
        ", times the variance factor chi2_dof (levels estimated from the log)" if estimated else " (levels given)")
    return cov_t * factor, rms, {"chi2_dof": chi2, "variance_factor": factor, "covariance_method": "fisher",
                                 "covariance": how, "covariance_from_residuals": False, "residual_checks": {},
                                 "noise_model_warning": ""}  # fmt: skip


def _reported_covariance(eq, x, phi, sigma, theta, estimator, info, log, estimated):
    """The covariance ``(p, p)`` of ``theta`` that :func:`spaceid.estimation.identify` reports,
    the RMS residual, and the record of how it was obtained for the result's diagnostics
    (``chi2_dof``, ``variance_factor``, ``covariance_method``, ``covariance``, ``covariance_from_residuals``,
    ``residual_checks`` and ``noise_model_warning``). ``estimated``: the noise levels came from the log.

    The noise model's covariance is reported only while the residuals agree with it; otherwise
    the covariance follows the residuals: for rates differentiated by Savitzky-Golay, the angle
    noise propagated through the filters, or Newey-West over half the differentiator's window in
    the directions where that is larger (Newey-West alone for other differentiators), Newey-West
    with Andrews' bandwidth when the residuals are autocorrelated
    (Ljung-Box), the sandwich of the residuals' scores (White) when ``chi2_dof`` is off at
    ``SIGNIFICANCE``; ols, which has no noise model, always follows the residuals. The angles
    estimator brings its own covariance (:func:`_own_covariance`)."""
    if "covariance" in info:
        return _own_covariance(*info.pop("covariance"), estimated)
    t = _covariance_terms(eq, x, phi, sigma, theta, estimator, info)
    r, white = t["r"], t["white"]
    chi2, checks, choice = _covariance_choice(eq, r, white, estimator, log, estimated)
    bandwidth, follows, factor = choice["bandwidth"], choice["covariance_from_residuals"], choice["variance_factor"]
    if follows:
        cov_t = newey_west_covariance(t["bread"], t["M"], t["scored"], bandwidth, eq.p)
        cov_t = _with_propagated(cov_t, choice, log, estimator, t["bread"], sigma,
                                 lambda: [(slice(None), t["M"], t["L"], eq.jacobian(x, theta))])
    else:
        cov_t = _model_covariance(estimator, t["bread"], t["M"], t["L"]) * factor
    return cov_t, float(np.sqrt(np.mean(r**2))), _covariance_record(chi2, checks, choice, log, estimated)


def _with_propagated(cov_t, choice, log, estimator, bread, sigma, chunks):
    """The Newey-West ``cov_t (p, p)``, or for rates differentiated by Savitzky-Golay the larger
    (:func:`larger_of`) of it and the angle noise propagated through the filters, ``choice["covariance"]``
    then saying so. ``chunks()`` gives ``(rows, M_c, L_c, J_c)`` in time order (the whole log, or a
    stream: :func:`~spaceid.estimation._differentiated.propagated_covariance`), not called otherwise."""
    series = differentiated_series(log, attitude=True)
    if series is None:
        return cov_t
    scores = ((sl, _inverse_times(L, M) if estimator in WEIGHTED else M, J) for sl, M, L, J in chunks())  # M^T e
    cov_t, larger = larger_of(propagated_covariance(series, log.t, scores, bread, sigma), cov_t)
    choice["covariance"] = _propagated_how(series, larger, len(cov_t), choice["bandwidth"])
    choice["method"] = "propagated"
    return cov_t


def larger_of(base, other) -> tuple:
    """The covariance ``(p, p)`` that is ``base`` in every direction of parameter space where
    ``other`` is not larger, and ``other`` where it is, and how many of the ``p`` directions that is.

    In the frame where ``base`` is the identity (``base = L L^T``, columns scaled to unit
    variance first), ``L^-1 other L^-T = V diag(lam) V^T``; the result is ``L V diag(max(lam, 1))
    V^T L^T``: at least ``base`` and ``other`` (Loewner order), and equal to the larger where one
    dominates."""
    scale = np.sqrt(np.diag(base))
    if not np.all(scale > 0):  # a parameter without angle noise (noise-free channels): the residuals decide
        return other, len(scale)
    try:
        with one_blas_thread():
            L = np.linalg.cholesky(base / np.outer(scale, scale))
    except np.linalg.LinAlgError:
        return other, len(scale)
    with one_blas_thread():
        Li = np.linalg.inv(L)
        lam, V = np.linalg.eigh(Li @ (other / np.outer(scale, scale)) @ Li.T)
        half = (L @ V) * np.sqrt(np.maximum(lam, 1.0))
        return half @ half.T * np.outer(scale, scale), int(np.sum(lam > 1.0))


def _propagated_how(series, larger: int, p: int, bandwidth: int) -> str:
    """``diagnostics.covariance`` for the covariance of :func:`larger_of` with the propagated one."""
    how = (f"the angle noise of {len(series)} differentiated series propagated through their Savitzky-Golay "
           "filters (its correlation over the windows)")
    if larger:
        how += (f"; in {larger} of {p} directions the Newey-West estimate from the residuals (Bartlett weights over "
                f"{bandwidth} samples) is larger and is taken there")
    return how


def _model_covariance(estimator, bread, M, L):
    """The sandwich of the noise model, ``bread (sum_n M_n^T S_n M_n) bread^T`` (:func:`_sandwich`);
    for ``wls`` and ``ml`` (weights ``S_n^-1``, ``bread`` the inverse of ``sum_n A_n^T S_n^-1 A_n``)
    that is ``bread`` itself, taken as it is: exact, and two products of the regressor's size fewer
    (1.6 s of 10,000 servicer samples, measured)."""
    return bread if estimator in WEIGHTED else _sandwich(bread, M, L)


def _covariance_record(chi2, checks, choice, log, estimated):
    """The record of :func:`_reported_covariance` for the result's diagnostics."""
    return {"chi2_dof": chi2, "variance_factor": choice["variance_factor"], "covariance_method": choice["method"],
            "covariance": choice["covariance"],
            "covariance_from_residuals": choice["covariance_from_residuals"], "residual_checks": checks,
            "noise_model_warning": noise_model_warning(chi2, checks, log, estimated)}  # fmt: skip


CONTRADICTED = "sandwich of the residuals' scores (White): chi2_dof = {:.3g} contradicts the noise model (p = {:.2g})"
"""How a covariance is described when the residuals' chi-square test rejects the noise model (``chi2_dof``, its
p-value): ``identify``'s and the payload's."""


def _covariance_choice(eq, r, white, estimator, log, estimated):
    """``chi2_dof`` (None without a noise model), the residual checks and the covariance chosen
    from the residuals ``r (n, rows)`` and, with a noise model, their whitened form: a dict of
    ``bandwidth`` (Newey-West lags, 0 for White), ``covariance_from_residuals``, ``variance_factor``
    and ``covariance`` (how, in words); see :func:`_reported_covariance`."""
    dof = max(r.size - eq.p, 1)
    chi2 = None if white is None else float(np.sum(white**2) / dof)
    checks = residual_checks(r if white is None else white, dof, chi2)
    window = correlation_length(log)
    factor, follows, method = 1.0, True, "newey-west"
    if window:  # a differentiator's errors are positively correlated over about half its window, negatively
        bandwidth = max(1, window // 2)  # beyond (they sum to zero): the whole window understated the std by ~16 %
        how = f"Newey-West from the residuals, Bartlett weights over {bandwidth} samples (differentiated rates)"
    elif checks["ljung_box_p"] < SIGNIFICANCE and eq.p <= LEVERAGE_LIMIT * r.size:
        bandwidth = _hac_bandwidth(checks["lag1_autocorrelation"], len(r))
        how = (f"Newey-West from the residuals, Bartlett weights over {bandwidth} samples (residuals autocorrelated: "
               f"Ljung-Box p = {checks['ljung_box_p']:.2g}, "
               f"lag-1 autocorrelation {checks['lag1_autocorrelation']:.2f})")
    else:
        bandwidth, method = 0, "sandwich"
        if estimator == "ols":
            how = "heteroscedasticity-consistent (White) from the residuals"
        elif checks["chi2_p"] < SIGNIFICANCE:
            how = CONTRADICTED.format(chi2, checks["chi2_p"])
        else:
            follows, method = False, "noise-model"
            how = "noise model (levels given)"
            if estimated:  # levels from the log are rough (sparse logs mix signal into them): let the
                factor = chi2  # residuals set the overall scale (a posteriori variance factor)
                how = "noise model (levels estimated from the log) times the variance factor chi2_dof"
    return chi2, checks, {"bandwidth": bandwidth, "covariance_from_residuals": follows, "variance_factor": factor,
                          "covariance": how, "method": method}  # fmt: skip


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
