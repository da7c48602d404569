"""Identification of the minimal parameters from a measured motion (the paper's Eq. 4 and Eq. 11
and beyond): :func:`identify`.

The steps: the stacked momentum equations of the log and their scale anchors
(:mod:`spaceid.estimation._equations`), checks that they determine the parameters (enough
samples, a nonzero right-hand side, every parameter excited), the noise model, the estimator
(:mod:`spaceid.estimation._estimators` describes the five), its covariance
(:mod:`spaceid.estimation._uncertainty`) and the :class:`~spaceid.estimation.Identification`
that records all of it.

References
----------
.. [1] Papadopoulos et al., Eq. 4 (stacked equations) and Eq. 11 (least squares).
"""

from __future__ import annotations

import contextlib
import functools
import warnings
from collections.abc import Callable
from dataclasses import dataclass, replace

import numpy as np
from scipy.linalg import lapack
from scipy.special import ndtri

from .._errors import SpaceidError, shown
from .._svd import svd
from .._threads import one_blas_thread, side_by_side
from ..data import Log, differentiate_log, log_fingerprint
from ..dynamics import Parameterization, full_parameter_names
from ._angles import _angle_context
from ._determined import (CORRECTED, CORRECTED_SAID, EIV_SAID, EIV_WIDENED, MODEL_SCALE, UNDETERMINED, WIDENED,
                          corrected_spread, eiv_bias, equation_noise, noise_ratios, undetermined_directions,
                          undetermined_warning, widened)
from ._diagnostics import Diagnostics, DriftTest, ResidualChecks
from ._differentiated import weighting_sigma
from ._drift import DRIFT_KINDS, check_drift_kinds, drift_names
from ._equations import _equations, _split, equation_residuals
from ._estimators import _KERNELS, ESTIMATORS, _FitContext, _ols
from ._gyro_bias import bias_test, identify_gyro_bias
from ._linalg import _column_scale, _factor_solution, _solve_factor, _triangular_factor
from ._noise import Noise, noise_from_log
from ._prior import PRIOR_STD, identify_with_prior, split_known, standard_anchor_error
from ._residuals import candidate_basis, drift_columns, drift_test
from ._result import Identification
from ._scales import log_momentum_scale
from ._stream import check_chunk, streamed_covariance, streamed_estimate, streamed_ols_factor, weighted_factor
from ._uncertainty import _reported_covariance, larger_of

__all__ = ["identify"]

IMPLAUSIBLE_LEVEL = 0.01
"""Probability that :func:`_implausible` names a parameter of a right model by chance (all tested)."""

FALLBACK_Z = 2.0
"""ML falls back on WLS when an inertia-like parameter of its estimate is below ``-FALLBACK_Z``
standard errors and none of WLS's is (:func:`_plausible_fallback`)."""

_INERTIA_LIKE = {"m", "Ixx", "Iyy", "Izz"}
"""Full parameters whose minimal combinations are masses or moments of inertia (see
:func:`_implausible`)."""


def _check_sample_count(eq, log: Log, where: str) -> None:
    """Raise unless the log gives more equations than unknowns."""
    rows = eq.param.rows
    if log.n_samples * rows < eq.p + 1:
        raise SpaceidError(
            f"{where}: {log.n_samples} samples give {log.n_samples * rows} equations for {eq.p} unknowns: "
            f"record at least {-(-(eq.p + 1) // rows)} samples"
        )


def _unexcited(r: np.ndarray, names, tol: float) -> list:
    """Names of the parameters that dominate the (near-)null space of the column-scaled
    regressor, from its triangular factor ``r (p, p)`` (same right singular vectors): the
    directions with singular values below ``tol`` of the largest."""
    with one_blas_thread():
        _, s, vt = svd(r)
    null = vt[s < tol * s[0]]
    weight = np.abs(null).max(axis=0) if len(null) else np.zeros(len(names))
    return [n for n, w in zip(names, weight) if w > 0.3]


def check_excitation(phi, names, cond_limit: float, where: str) -> tuple:
    """The orthogonal factorisation ``(scale (p,), R (p + 1, p + 1))`` of the column-scaled
    stacked equations ``phi (n, rows, p + 1)`` (see :func:`~spaceid.estimation._linalg._triangular_factor`)
    and the condition number of the column-scaled regressor; raises when the right-hand side
    vanishes or the condition number reaches ``cond_limit`` (naming the parameters not excited)."""
    A, b = _split(phi)
    _check_right_hand_side(np.any(b), where)
    # Columns scaled to unit norm: the scaled condition number decides excitation (it does not
    # depend on units). R is formed once: excitation check, singular values and the OLS solution.
    scale = _column_scale(A)
    return _check_factor((scale, _triangular_factor(A, b, scale)), names, cond_limit, where)


def excitation_condition(phi) -> float:
    """The condition number of the column-scaled regressor of ``phi (n, rows, p + 1)`` (infinite when
    singular), as :func:`check_excitation` judges it."""
    A, b = _split(phi)
    scale = _column_scale(A)
    with one_blas_thread():
        sv = svd(_triangular_factor(A, b, scale)[:-1, :-1], compute_uv=False)
    return float(sv[0] / sv[-1]) if sv[-1] > 0 else np.inf


def _check_right_hand_side(nonzero: bool, where: str) -> None:
    if not nonzero:
        raise SpaceidError(f"{where}: the right-hand side is zero (no momentum and the anchored parameters' columns "
                           "vanish, e.g. a reaction wheel at rest): spin the wheel or give the momentum")


def _check_factor(factor, names, cond_limit: float, where: str) -> tuple:
    """``factor`` and the scaled condition number of the regressor it factors, as
    :func:`check_excitation` returns them; raises when the condition number reaches ``cond_limit``."""
    scale, R = factor
    with one_blas_thread():
        sv = svd(R[:-1, :-1], compute_uv=False)  # those of A / scale, to eps * sv[0]
    cond_scaled = float(sv[0] / sv[-1]) if sv[-1] > 0 else np.inf
    if not cond_scaled < cond_limit:
        bad = _unexcited(R[:-1, :-1], names, max(1e-8, 1 / cond_limit))
        drifts = set(drift_names(DRIFT_KINDS, False)[0])
        fix = ("drop one of the drift terms the log cannot tell apart (`drift`; a constant torque and Coulomb "
               "friction are the same while the base turns one way)" if drifts & set(bad) else
               "use an exciting trajectory (design_excitation, 'spaceid design') that moves every joint")
        raise SpaceidError(f"{where}: the regressor is rank-deficient (scaled cond {cond_scaled:.3g}); not excited: "
                           f"{', '.join(bad) or 'unclear'}: {fix}")
    return factor, cond_scaled


def _instrument_context(log: Log, instruments, where: str) -> dict:
    """The joint signals ``(q, qd)`` the ``iv`` instruments are built from, and their description (the
    ``reference`` and ``instruments`` of :class:`~spaceid.estimation._estimators._FitContext`)."""
    ref = (log.q, log.qd) if instruments is None else tuple(np.asarray(a, float) for a in instruments)
    if ref[0].shape != log.q.shape or ref[1].shape != log.q.shape:
        raise SpaceidError(f"{where}: `instruments` must be joint angles and rates of shape {log.q.shape}")
    return {"reference": ref, "instruments": "measured joints, predicted base rate" if instruments is None
            else "commanded joints, predicted base rate"}  # fmt: skip


@dataclass(frozen=True)
class _Fit:
    """An estimate and how it was obtained, as the steps of :func:`identify` pass it on.

    Attributes
    ----------
    theta : ndarray of shape (p,)
        The unknowns of the equations (free parameters, estimated momentum, drift coefficients).
    info : dict
        The estimator's record (``fallback``, ``iterations``, ...; its whitener until the drift test).
    cov : ndarray of shape (p, p)
        The covariance of ``theta`` that is reported (:func:`_reported_covariance`).
    rms : float
        RMS of the equation residuals.
    uncertainty : dict
        How the covariance was obtained (the record of :func:`_reported_covariance`).
    implausible : str
        The warning of :func:`_implausible` for this estimate (``""``: none, or not checked yet).
    held : tuple or None
        ``ml`` run over the directions the data determine only (:func:`_ml_determined`): the noise-to-signal
        ratios and directions ``(mu, T)`` (:func:`~spaceid.estimation._determined.noise_to_signal`) it judged by.
    """

    theta: np.ndarray
    info: dict
    cov: np.ndarray
    rms: float
    uncertainty: dict
    implausible: str = ""
    held: tuple | None = None


def _full_covariance(eq, cov_t, k: int) -> tuple:
    """The covariance ``(k, k)`` of all minimal parameters (known ones with zero variance), the
    standard errors ``(3,)`` of the inertial momentum [N m s] (zero when it was given) and those
    ``(n_d,)`` of the drift coefficients."""
    cov = np.zeros((k, k))
    cov[np.ix_(eq.free, eq.free)] = cov_t[: len(eq.free), : len(eq.free)]
    std = np.sqrt(np.diag(cov_t))
    h_std = np.zeros(3)
    if eq.drift and np.any(eq.basis[0]):  # integrated from a history: the momentum at the log's start
        jac = np.zeros((len(eq.axes), eq.p))
        jac[:, len(eq.free) : len(eq.free) + eq.n_h] = np.eye(len(eq.axes))[:, : eq.n_h]
        jac[:, eq.p - len(eq.drift) :] = eq.basis[0][:, eq.axes].T
        h_std[eq.axes] = np.sqrt(np.diag(jac @ cov_t @ jac.T))
    elif eq.n_h:
        h_std[eq.axes] = std[len(eq.free) : len(eq.free) + eq.n_h]
    return cov, h_std, std[len(std) - len(eq.drift) :]


DRIFT_CORRELATION = 0.99
"""Drift coefficients whose estimates correlate beyond this are told apart by the log only weakly."""


def _drift_collinear(eq, cov_t, where) -> tuple:
    """The largest correlation between two drift coefficients' estimates and a warning naming the pair
    when it exceeds ``DRIFT_CORRELATION`` (``""`` otherwise): e.g. a constant torque and a Coulomb
    torque when the base never reverses, or any two while it turns one way only."""
    d = len(eq.drift)
    if d < 2:
        return None, ""
    block = cov_t[eq.p - d :, eq.p - d :]
    std = np.sqrt(np.diag(block))
    corr = block / np.outer(np.where(std > 0, std, 1), np.where(std > 0, std, 1))
    np.fill_diagonal(corr, 0)
    i, j = np.unravel_index(np.argmax(np.abs(corr)), corr.shape)
    worst = float(corr[i, j])
    if abs(worst) <= DRIFT_CORRELATION:
        return worst, ""
    return worst, (f"{where}: drift terms {eq.drift[i]} and {eq.drift[j]} are nearly indistinguishable on this log "
                   f"(correlation {worst:.4f}): noise and model errors trade one for the other, which inflates their "
                   "errors and the parameters'; keep one of them (`drift`) unless the motion can tell them apart")


def _drift_check(eq, x, phi, sigma, theta, estimator, log, drift, where, whitener=None, chunk=None,
                 noise=None, gram=None, basis=None, residuals=None) -> tuple:
    """The :class:`~spaceid.estimation.DriftTest` of the residuals for an unmodelled drift
    (:func:`spaceid.estimation._residuals.drift_test`, ``whitener`` the estimator's own, if any; streamed in chunks
    of ``chunk`` samples when given; ``noise`` the noise Gram matrix of the equations with the drift columns, or a
    function that returns it (computed beside the test), if formed; ``gram`` the Gram matrix of the columns
    whitened by ``whitener``, ``basis`` the candidates' and ``residuals`` those of ``theta``, if formed) and its
    warning (``""`` when silent); not run when drift terms are modelled."""
    if drift:
        return DriftTest.skipped(f"drift terms modelled: {', '.join(drift)}"), ""
    if estimator == "angles":  # its equations are line integrals over knot spans, not per-sample momenta
        return DriftTest.skipped("not defined for the angles estimator"), ""
    test = drift_test(eq, x, phi, sigma, theta, estimator, log, whitener, chunk, noise=noise, gram=gram, basis=basis,
                      residuals=residuals, nominal=_nominal(eq, theta))
    record = DriftTest.from_dict(test)
    if not test["drift"]:
        return record, ""
    white = "" if test["whiteness_p_value"] >= test["alpha"] else (
        f", and the residuals are correlated (lag-1 autocorrelation {test['lag1_autocorrelation']:.2f})")
    return record, (f"{where}: the equation residuals trend with time and attitude (Wald p = {test['p_value']:.2g} "
                  f"< {test['alpha']:g}, momentum drift {100 * test['relative_drift']:.2g} % of its RMS{white}): an "
                  "external torque or base friction changes the momentum: model it with `drift` (one term first, "
                  "e.g. viscous: terms that move alike are confounded; see the drift theory page)")


def _whitened_factor(factor):
    """``(scale, R, cond)``: the column-scaled factor ``(scale, R)`` of an estimator's whitened equations
    (:func:`~spaceid.estimation._linalg._triangular_factor`) with its scaled condition number, estimated
    (LAPACK ``dtrcon``, as :func:`~spaceid.estimation._determined.regressor_factor` judges it); None for None."""
    if factor is None:
        return None
    with one_blas_thread():
        rcond = lapack.dtrcon(np.ascontiguousarray(factor[1][:-1, :-1]))[0]
    return (*factor, 1 / rcond if rcond > 0 else np.inf)


def _factor_gram(factor):
    """The Gram matrix ``(p, p)`` of the regressor whose column-scaled factor is ``factor = (scale, R, ...)``
    (``R^T R`` unscaled), or None for None."""
    if factor is None:
        return None
    r = factor[1][:-1, :-1] * factor[0]
    with one_blas_thread():
        return r.T @ r


def _log_regressor(eq, phi, estimator: str):
    """The regressor ``(n, rows, k)`` at the log's signals as the equations ``phi`` hold it (their first ``k``
    columns when every parameter is free; spatial systems: the planar equations take the base rate's z
    alone), or None when they do not."""
    if phi is None or estimator == "angles" or len(eq.known) or eq.planar:
        return None
    return phi[..., : eq.param.n_params]


def _noise_gram(submit, eq, x, sigma, theta, estimator, log, whitener, basis):
    """A future, from ``submit`` (:func:`~spaceid._threads.side_by_side`), of the noise Gram matrix of the equations'
    columns with the drift test's candidates, whitened by the estimator's ``whitener``
    (:func:`~spaceid.estimation._determined.equation_noise` with ``-b`` last; ``ols``'s needs no ``theta``): formed
    once, for the undetermined directions, the drift test and least squares' bias.
    ``basis``: a future of the candidates' (:func:`~spaceid.estimation._residuals.candidate_basis`), None when drift
    terms are modelled."""
    def job():
        extra = None if basis is None else drift_columns(eq, log, basis.result())
        return equation_noise(eq, x, sigma, theta, estimator, log, whitener, extra, rhs=True)
    return submit(job)


LEAST_SQUARES = ("ols", "wls")
"""The estimators that leave the errors-in-variables bias (:func:`_eiv_widened`), as estimates and as ML's fallbacks."""


def _eiv_widened(fit, regression, reported: str, eq, x, sigma, log, chunk, noise, factor, where: str,
                 gyro_bias=None) -> tuple:
    """``(fit, warning)``: the ``reported`` estimate's ``fit`` (``ols`` or ``wls``, or ML's fallback to it) with its
    covariance widened by its first-order errors-in-variables bias (:func:`~spaceid.estimation._determined.eiv_bias`;
    its description says so from :data:`~spaceid.estimation._determined.EIV_SAID` of a standard error), and the
    warning when the bias reaches one standard error (``""`` when not). ``noise``: the noise Gram matrix of the
    equations whitened as the estimator's with ``-b`` last (the checks' own), None to form it here; ``factor``: the
    column-scaled factor ``(scale, R, ...)`` of ``[A | -b]`` whitened alike (None: WLS's at the estimate, formed
    here). ``regression`` is the data's own fit; with a ``gyro_bias`` pass, ``fit`` is it after the attitude's update
    (:meth:`~spaceid.estimation._gyro_bias.BiasPass.fused`), which carries its bias too (little of the bias
    correction's, which the attitude measures). Least squares does not correct the bias, and its first-order
    covariance holds only the spread: a random robot's differentiated encoders and 1e-3 rad/s of gyro noise put
    ``ols`` 8.6 standard errors off, of which this predicted 5.4."""
    m = len(x) * eq.param.rows
    if noise is None:
        noise = equation_noise(eq, x, sigma, fit.theta, reported, log, chunk=chunk, rhs=True)
    if factor is None:
        factor = weighted_factor(eq, x, fit.theta, sigma, chunk, refined=False)
    rss = fit.rms**2 * m if reported == "ols" else fit.uncertainty["chi2_dof"] * max(m - eq.p, 1)  # (whitened)
    bias = eiv_bias(factor[1][:-1, :-1] * factor[0], noise, regression.theta, rss, m)
    if gyro_bias:
        bias = gyro_bias.carried(eq, regression.cov, bias)
    std = np.sqrt(np.diag(fit.cov))
    ratio = np.abs(bias) / np.where(std > 0, std, np.inf)
    largest = float(ratio.max(initial=0))
    fit = replace(fit, cov=fit.cov + np.outer(bias, bias))
    if largest >= EIV_SAID:
        fit = replace(fit, uncertainty={**fit.uncertainty, "covariance": f"{fit.uncertainty['covariance']}; "
                                                                         f"{EIV_WIDENED.format(reported, largest)}"})
    if not largest >= 1:
        return fit, ""
    lead = ", ".join(str(eq.names()[i]) for i in np.argsort(-ratio)[:3] if ratio[i] >= 1)
    return fit, (f"{where}: the regressor's noise biases the {reported} estimate by up to {largest:.2g} of its "
                 f"standard errors (errors in variables, to first order; {lead} most): they are widened by the bias; "
                 "`estimator` ml corrects it")


def _singular_values(factor) -> np.ndarray:
    """Singular values of the unscaled regressor (the paper's condition number), largest first,
    from the factor ``(scale, R)`` of the scaled equations: those of ``R[:p, :p] diag(scale)``."""
    scale, R = factor
    with one_blas_thread():
        return svd(R[:-1, :-1] * scale, compute_uv=False)


def _estimate(eq, x, log: Log, sigma, ctx: _FitContext, estimator: str, estimated: bool, chunk=None,
              on_estimate=None) -> _Fit:
    """The :class:`_Fit` of ``estimator`` (not yet checked for plausibility): ``theta``, the estimator's record
    and :func:`_reported_covariance`'s covariance, RMS and record, from the OLS start, streamed over chunks of
    ``chunk`` samples when given (:mod:`spaceid.estimation._stream`); raises ``LinAlgError`` when the estimate is
    not finite (as the factorisations do on singular systems), which :func:`identify` turns into a
    ``SpaceidError``. ``on_estimate(theta, whitener)``, if given, is called with the estimate as soon as it is
    known, before the work that follows (:func:`identify` starts checks beside it): ``ols``'s (no whitener) before
    its covariance, with its residuals ``phi [theta; 1]`` ``(n, rows)`` as a third argument (formed once, for the
    covariance and the drift test), ``ml``'s in memory once it converges, with its whitener, before the factor at
    its weights."""
    residuals, requested = None, estimator
    if estimator == "ols" and on_estimate is not None and not chunk:  # before the inverse Gram matrix (p^3)
        theta = _factor_solution(*ctx.factor[::-1])
        if np.all(np.isfinite(theta)):
            residuals = equation_residuals(ctx.phi, theta)  # formed once: the covariance's and the drift test's
            on_estimate(theta, None, residuals)
    if chunk:
        theta, ginv = _solve_factor(*ctx.factor[::-1])
        info = {"ginv": ginv}
    else:
        theta, info = _ols(eq, x, sigma, None, ctx)
    if residuals is not None:
        info["residuals"] = residuals
    if estimator != "ols":
        ols_info = info
        seen = {}  # ml: the ratios that stop a stalled fit (see _undetermined_reason)
        theta, info = (streamed_estimate(eq, x, sigma, theta, estimator, ctx, chunk) if chunk else
                       _KERNELS[estimator](eq, x, sigma, theta, ctx,
                                           **({"stalled": _undetermined_reason(eq, x, log, sigma, ctx, seen),
                                               "converged": on_estimate} if estimator == "ml" else {})))
        fallback = str(info.get("fallback")).split(":")[0]  # ML failed: WLS or OLS, with their covariance
        if fallback in ("wls", "ols") and not chunk:
            theta, info = _ml_determined(eq, x, log, sigma, theta, ctx, info, seen, on_estimate)
            fallback = str(info.get("fallback")).split(":")[0]
        if fallback in ("wls", "ols"):
            estimator, info = fallback, info | (ols_info if fallback == "ols" else {})
    if not np.all(np.isfinite(theta)):
        raise np.linalg.LinAlgError("the estimate is not finite")
    if chunk:
        reported = streamed_covariance(eq, x, sigma, theta, estimator, info, ctx, log, estimated, chunk)
        info["chunk"] = chunk
    else:
        reported = _reported_covariance(eq, x, ctx.phi, sigma, theta, estimator, info, log, estimated)
    fit = _Fit(theta, info, *reported, held=info.pop("held_ratios", None))
    if requested == "ml" and estimator == "wls":  # ML's fallback: WLS's weights, at its own estimates
        return _wls_widened(eq, x, log, sigma, ctx, estimated, chunk, fit)
    own = info.pop("held_own", None)
    if own is None:
        return fit
    other, other_info = own  # the fit with the held directions at the model's own values: its weights' spread
    own_cov = _reported_covariance(eq, x, ctx.phi, sigma, other, "ml", other_info, log, estimated)[0]
    return _at_least(fit, own_cov, other - theta, HELD_WIDENED)


def _at_least(fit: _Fit, other_cov, shift, said: str) -> _Fit:
    """``fit`` with a covariance at least ``other_cov (p, p)`` (the Loewner larger of the two), widened along the
    change ``shift (p,)`` to another estimate (``+ shift shift^T``), its description ending with ``said``."""
    return replace(fit, cov=larger_of(fit.cov, other_cov)[0] + np.outer(shift, shift), uncertainty={
        **fit.uncertainty, "covariance": f"{fit.uncertainty['covariance']}; {said}"})


def _spread_along_directions(fit: _Fit, weak: list, ratios, corrects: bool, nominal) -> _Fit:
    """``fit`` with its covariance's spread along the directions of parameter space (``ratios``, :func:`~spaceid.
    estimation._determined.noise_to_signal`'s ``(mu, T)``, or None when not formed; ``weak`` the undetermined ones,
    :func:`~spaceid.estimation._determined.undetermined`'s): ML's grown with each ratio when it ``corrects`` the
    attenuation (:func:`~spaceid.estimation._determined.corrected_spread`), and widened along the undetermined to
    their values' scale, the estimate's and ``nominal``'s (:func:`~spaceid.estimation._determined.widened`); its
    description saying so."""
    uncertainty = fit.uncertainty
    if corrects and ratios is not None:
        measured = bool(uncertainty.get("covariance_from_residuals"))
        cov, largest = corrected_spread(fit.cov, *ratios, measured)
        fit = replace(fit, cov=cov)
        if largest >= CORRECTED_SAID:
            how = CORRECTED.format("1/(1 - mu)" if measured else "sqrt(1 + mu)/(1 - mu)", largest)
            uncertainty = {**uncertainty, "covariance": f"{uncertainty['covariance']}; {how}"}
    if weak:  # the standard errors say what the data do not determine
        fit = replace(fit, cov=widened(fit.cov, *ratios, fit.theta, nominal))
        how = WIDENED.format(len(weak), MODEL_SCALE)
        uncertainty = {**uncertainty, "covariance": f"{uncertainty['covariance']}; {how}"}
    return replace(fit, uncertainty=uncertainty)


HELD_WIDENED = ("at least that of the fit with the directions ML held at the model's own values (its weights), and "
                "widened along the estimate's change had they been there (the others follow them)")
"""How the covariance's description ends when :func:`_held_at_own`'s fit bounded and widened it."""


def _undetermined_reason(eq, x, log: Log, sigma, ctx: _FitContext, seen: dict):
    """``reason(theta)``: how many directions the data do not determine at ``theta`` (the noise-to-signal ratios of
    the equations weighted as WLS's, :func:`~spaceid.estimation._determined.noise_ratios`), or ``""`` when none: ML's
    fit stops on it when it has not converged after a few iterations, asked at the estimate it then reports (WLS's
    or OLS's). :func:`_ml_determined` fits the others from that estimate with these ratios, ``seen["at"] = (theta,
    (mu, T))``: the noise Gram matrix is formed once (0.27 s of the servicer's 500-sample log)."""
    def reason(theta):
        mu, T = noise_ratios(eq, x, ctx.phi, sigma, theta, "wls", log)
        seen["at"] = (theta, (mu, T))
        weak = int(np.sum(mu >= UNDETERMINED))
        return f"the data do not determine {weak} of {len(mu)} directions" if weak else ""
    return reason


def _ml_determined(eq, x, log: Log, sigma, theta, ctx: _FitContext, info: dict, seen=None,
                   on_estimate=None) -> tuple:
    """Maximum likelihood along the directions the data determine, when over all of them it did not converge:
    ``(theta, info)`` of that fit from ML's fallback ``theta`` (WLS's or OLS's estimate, whose values it keeps
    along the other directions), or of the fallback with ``info["fallback"]`` saying why when there is no such
    direction or that fit does not converge either.

    Along a direction whose regressor's noise is as large as its signal (:mod:`spaceid.estimation._determined`)
    the errors-in-variables likelihood has no maximum the data fix: the corrected signals can absorb ever more
    of the momentum as the parameters grow there (on the spatial twin's undesigned flight, 128 of 496
    directions: the objective still falling after 200 iterations). Those directions keep the fallback's values,
    and :func:`identify` widens their standard errors. ``seen["at"]``: ratios already formed, ``(estimate, (mu,
    T))``, used when ``theta`` is that estimate; ``on_estimate``: as :func:`_estimate`'s, for that fit."""
    at = (seen or {}).get("at")
    mu, T = at[1] if at is not None and at[0] is theta else noise_ratios(eq, x, ctx.phi, sigma, theta, "wls", log)
    weak = mu >= UNDETERMINED
    if not weak.any():
        return theta, info
    why = f"; the data do not determine {weak.sum()} of {len(mu)} directions, along which the likelihood has no maximum"
    if weak.all():
        return theta, info | {"fallback": info["fallback"] + why}
    held, fit = _KERNELS["ml"](eq, x, sigma, theta, ctx, subspace=T[:, ~weak], converged=on_estimate)
    kept, own = f"the {info['fallback'].split(':')[0].upper()} estimate's", None
    if fit.get("fallback"):  # the fallback's values there can leave the weights degenerate: the model's own
        held, fit = _KERNELS["ml"](eq, x, sigma, _own_coordinates(eq, theta, T, weak), ctx, subspace=T[:, ~weak],
                                   converged=on_estimate)
        kept = "the model's own"
        if fit.get("fallback"):
            return theta, info | {"fallback": info["fallback"] + why + ", nor over the others"}
    else:
        own = _held_at_own(eq, x, sigma, ctx, theta, T, weak)
    return held, fit | {"held": (f"over the {(~weak).sum()} directions the data determine; the {weak.sum()} they do "
                                 f"not keep {kept} values (along them the likelihood has no maximum)"),
                        "held_ratios": (mu, T), **({} if own is None else {"held_own": own})}


def _own_coordinates(eq, theta, T, weak) -> np.ndarray:
    """``theta (p,)`` with its coordinates ``T^-1 theta`` along the ``weak`` directions the model's own (its
    parameters', :func:`_nominal`). Held there when held at ML's fallback's values the fit did not converge: at zero
    momentum an anchored robot's OLS and WLS estimates attenuate its inertias so far that the equations' error
    covariance at them is nearly singular (spatial random robot 33485: the whiteners' smallest diagonal 9e-8 against
    1.7e-3 at the truth), and that fallback was reported 17 standard errors off; held at the model's own values the
    fit converged within 0.73 of its standard errors (0.75 with the minimal parameters 20 % off them, 0.77 with every
    body 20 % off)."""
    coords = np.linalg.solve(T, np.column_stack([theta, _nominal(eq, theta)]))
    return theta + T[:, weak] @ (coords[weak, 1] - coords[weak, 0])


def _nominal(eq, theta) -> np.ndarray:
    """The model's own values ``(p,)`` of the unknowns ``theta``'s: its parameters' (the URDF's inertias), and
    ``theta``'s for the momentum, bias and drift terms, which the model does not know (the widenings' scale)."""
    return np.concatenate([eq.param.true_values[eq.free], theta[len(eq.free):]])


HELD_OWN_TOLERANCES = {"tol": 1e-2, "ftol": 1e-7}
"""Convergence tolerances of :func:`_held_at_own`'s fit (:func:`~spaceid.estimation._estimators._ml_fit`'s: its
update in its standard errors, its objective's change relative): its estimate and weights only bound the held fit's
covariance. With ML's own (1e-4 and 1e-9) that fit took 30 and 14 iterations on two undesigned 500-sample logs of
the servicer, against 12 and 10, for standard errors that moved by at most 0.044 %."""


def _held_at_own(eq, x, sigma, ctx: _FitContext, start, T, weak):
    """:func:`_ml_determined`'s fit from ``start`` with its coordinates ``T^-1 theta`` along the ``weak`` directions
    the model's own (its parameters', the scale :func:`~spaceid.estimation._determined.widened` takes) instead of the
    fallback's: ``(theta, info)``, or None when it does not converge. :func:`_estimate` reports the held fit with at
    least this fit's covariance, widened along the change between the two:

    - the likelihood couples the coordinates, and the others follow the held ones (random robot 6089925's undesigned
      log, one direction held at WLS's values, attenuated by their errors in variables: two parameters 13 and 12
      standard errors off; held at OLS's 2.1, at the truth 1.6), which the covariance of the fit with them fixed
      does not say;
    - the weights at the held fit see the equations' noise through the attenuated values: undesigned spatial robot
      36 (15 parameters, one direction held), its pi6 3.4 off with a standard error of 0.39 at the held fit's
      weights, 1.53 at this fit's (whose own error is 3.8); the fit over every direction from the truth converges
      there too, 1.62, its errors within 2.6 of its standard errors."""
    other, fit = _KERNELS["ml"](eq, x, sigma, _own_coordinates(eq, start, T, weak), ctx, subspace=T[:, ~weak],
                                **HELD_OWN_TOLERANCES)
    return None if fit.get("fallback") else (other, fit)


@dataclass(frozen=True)
class _RateStart:
    """The spatial ``angles`` fit's start (:func:`_rate_start`): ``fit``, the ``ml`` :class:`_Fit` on rates
    differentiated from the same angles, and ``reported()``, that fit as :func:`identify` reports ML's (its spread
    along the directions of parameter space, :func:`_spread_along_directions`), formed only when reported."""

    fit: _Fit
    reported: Callable[[], _Fit]


def _rate_start(param, log: Log, momentum, known, where: str, cond_limit: float) -> _RateStart | None:
    """The start of the spatial ``angles`` fit (a :class:`_RateStart`): ML on rates differentiated from the same
    angles (:func:`~spaceid.data.differentiate_log`, their levels estimated from the differentiated log), or None
    when the log cannot give it. The integral form's least squares is biased by the noise on the attitude
    increments: on the satellite-7dof preset it starts tens of standard errors away, where Levenberg-Marquardt
    stalls; this start is a few standard errors away (docs/theory/angles.md, "Spatial models")."""
    try:
        diff = differentiate_log(log)
        eq, _ = _equations(param, diff, momentum, known, where)
        x = eq.signals(diff)
        ctx = _FitContext(eq.phi(x), check_excitation(eq.phi(x), eq.names(), cond_limit, where)[0])
        sigma = weighting_sigma(param, diff, noise_from_log(diff))
        with warnings.catch_warnings():  # the start's own warnings are not the angles fit's
            warnings.simplefilter("ignore")
            fit = _estimate(eq, x, diff, sigma, ctx, "ml", True)
    except (SpaceidError, np.linalg.LinAlgError):
        return None

    def reported():
        whitener = fit.info.get("whitener")
        weak, ratios = undetermined_directions(
            eq, x, ctx.phi, sigma, fit.theta, "ml", diff, whitener,
            equation_noise(eq, x, sigma, fit.theta, "ml", diff, whitener),
            _whitened_factor(fit.info.get("whitened_factor")), every=True)
        return _spread_along_directions(fit, weak, ratios, True, _nominal(eq, fit.theta))

    return _RateStart(fit, reported)


def _angles_estimate(eq, x, log: Log, sigma, ctx: _FitContext, estimated: bool, start) -> _Fit:
    """The ``angles`` :class:`_Fit`; when its maximum likelihood does not converge (or meets a singular system)
    and the rate start ``start`` (:func:`_rate_start`) is given, that start as ML reports it instead,
    ``info["fallback"]`` saying why (:func:`identify` warns)."""
    try:
        fit = _estimate(eq, x, log, sigma, ctx, "angles", estimated)
        if fit.info["converged"] or start is None:
            return fit
        reason = f"did not converge in {fit.info['iterations']} iterations"
    except np.linalg.LinAlgError as exc:
        if start is None:
            raise
        reason = f"met a singular system ({exc})"
    start = start.reported()
    return replace(start, info={k: v for k, v in start.info.items() if k not in ("whitener", "whitened_factor")} | {
        "fallback": f"ml on rates differentiated from the angles: maximum likelihood on the angles {reason}"})


def _leading_parameters(param: Parameterization) -> list:
    """The leading full parameter of each minimal one: the first full parameter (in
    ``full_parameter_names`` order) with a coefficient above round-off in its projection row;
    for the columns basis, the independent column that the others were absorbed into."""
    full = full_parameter_names(param.model)
    rows = np.abs(param.projection)
    return [full[int(np.argmax(row > 1e-9 * row.max()))] for row in rows]


def _implausible(param: Parameterization, pi: np.ndarray, std: np.ndarray, where: str, z: float | None = None) -> str:
    """A warning naming the inertia-like minimal parameters that came out significantly negative,
    or ``""``: below ``-z`` standard errors, ``z`` the two-sided normal quantile of
    :data:`IMPLAUSIBLE_LEVEL` shared by the ``k`` parameters tested (Bonferroni: on a robot of
    hundreds of parameters one beyond -2 is chance, not a sign of a wrong model), at least 2; or
    the ``z`` given (the choice between two estimates compares each parameter on its own).

    A parameter is inertia-like when its leading full parameter is a mass or a diagonal moment
    of inertia (``m_*``, ``Ixx_*``, ``Iyy_*``, ``Izz_*``, not a lumped product); only those positive
    for the model's own (physical) values count, as absorbed terms could make others negative.
    All of them negated at once is the signature of a momentum of the wrong sign."""
    lead = _leading_parameters(param)
    like = np.array([name.split("_")[0] in _INERTIA_LIKE and "*" not in name for name in lead])
    like &= param.true_values > 0
    z = max(2.0, -float(ndtri(IMPLAUSIBLE_LEVEL / max(1, 2 * like.sum())))) if z is None else z
    bad = like & (pi + z * std < 0)
    if not bad.any():
        return ""
    listed = ", ".join(f"{param.names[i]} = {pi[i]:.4g} {param.units[i]} (leads with {lead[i]})"
                       for i in np.flatnonzero(bad))  # fmt: skip
    every = "every one of them negative: " if bad.sum() == like.sum() > 1 else ""
    return (f"{where}: physically impossible parameters, negative though they lead with a mass or moment of inertia: "
            f"{listed}; {every}likely the wrong sign of the momentum (`momentum`) or a wrong anchor (`known`, the "
            "reaction-wheel inertia)")


def _implausible_estimate(eq, theta, cov_t, where: str, z: float | None = None) -> str:
    """:func:`_implausible` of the estimate ``theta`` of ``eq`` with its covariance ``cov_t``."""
    std = np.sqrt(np.diag(_full_covariance(eq, cov_t, eq.param.n_params)[0]))
    return _implausible(eq.param, eq.full(theta)[0], std, where, z)


FALLBACK_WIDENED = ("at least OLS's, widened along the change from OLS's estimate and along the directions the data do "
                    "not determine by OLS's equations (ML fell back on WLS, whose weights, taken at its own estimates, "
                    "can pull it away)")
"""How the covariance's description ends when :func:`_wls_widened` widened ML's WLS fallback."""


def _wls_widened(eq, x, log, sigma, ctx, estimated, chunk, wls: _Fit) -> _Fit:
    """``wls``, WLS's :class:`_Fit` reported as ML's fallback, with a covariance at least OLS's (Loewner), widened by
    the change between the two estimates and along the directions OLS's equations leave undetermined
    (``info["fallback_undetermined"]``, which :func:`identify` reports and warns of; not streamed).

    WLS's weights are taken at its own estimates, and where ML has failed (its likelihood run off, or stalled at
    zero momentum) they can be degenerate and hide what the data do not determine. Random robots released at
    rest with an anchor (``test_random_pipeline``'s): on planar robot 83 (16 parameters) ML converged to values
    1e4 times the model's, and WLS's estimate pulled an inertia from 2.66 to -0.02 with a standard error of 0.038,
    71 of them off (OLS's 1.1 of its own, a direction found undetermined); on spatial robot 729 (28) ML stalled
    at the OLS start, and WLS's pi2 was 6.9 of its standard errors off, outside the three directions found
    undetermined at its weights."""
    ols = _estimate(eq, x, log, sigma, ctx, "ols", estimated, chunk)
    fit, weak = _at_least(wls, ols.cov, wls.theta - ols.theta, FALLBACK_WIDENED), []
    if ctx.phi is not None:  # and along what the data do not determine, found unweighted (OLS's reported are)
        weak, ratios = undetermined_directions(eq, x, ctx.phi, sigma, ols.theta, "ols", log)
        fit = replace(fit, cov=widened(fit.cov, *ratios, wls.theta, _nominal(eq, wls.theta)))
    return replace(fit, info=wls.info | {"fallback_undetermined": weak})


def _plausible_fallback(eq, x, log, sigma, ctx, estimated, chunk, ml: _Fit, where) -> _Fit:
    """ML's :class:`_Fit` ``ml`` when its converged estimate is physically impossible: WLS's instead
    when WLS's is not (with a wrong noise model the likelihood can have a local minimum far from the
    truth, e.g. rates differentiated from noisy angles, levels estimated), ``info["fallback"]`` saying
    so, its covariance widened as :func:`_wls_widened` says; else ML's, whose warning then stands."""
    wls = _estimate(eq, x, log, sigma, ctx, "wls", estimated, chunk)
    if _implausible_estimate(eq, wls.theta, wls.cov, where, z=FALLBACK_Z):
        return ml
    ml_info = {k: v for k, v in ml.info.items() if k not in ("whitener", "whitened_factor")}  # ML's weights are not WLS's
    info = ml_info | {"fallback": (f"wls: the maximum-likelihood estimate converged to physically impossible "
                                   f"parameters (objective {ml_info['objective_end']:.4g}); WLS's are not")}
    return _wls_widened(eq, x, log, sigma, ctx, estimated, chunk, replace(wls, info=info))


@dataclass(frozen=True)
class _Prepared:
    """What :func:`identify` and :func:`estimate_only` fit from (:func:`_prepared`).

    Attributes
    ----------
    eq : Equations
        The stacked momentum equations (:func:`~spaceid.estimation._equations._equations`).
    anchors : list
        Their scale anchors, as ``settings["anchors"]`` records them.
    x : ndarray of shape (n, n_x)
        The log's signals.
    phi : ndarray of shape (n, rows, p + 1) or None
        The equations at the signals (None when streamed).
    noise : Noise
        The noise model: the one given, else estimated from the log (``estimated``).
    estimated : bool
        Whether ``noise`` was estimated.
    factor : tuple
        ``(scale (p,), R (p + 1, p + 1))``: the column-scaled factor of the equations (:func:`check_excitation`).
    cond_scaled : float
        The scaled condition number of the regressor.
    ctx : _FitContext
        The estimators' context (``angles``: the angle estimator's, with its start).
    sigma : ndarray of shape (n_x,)
        The signals' noise levels that weight the equations
        (:func:`~spaceid.estimation._differentiated.weighting_sigma`).
    start : _RateStart or None
        The spatial ``angles`` fit's start (:func:`_rate_start`), else None.
    """

    eq: object
    anchors: list
    x: np.ndarray
    phi: np.ndarray | None
    noise: Noise
    estimated: bool
    factor: tuple
    cond_scaled: float
    ctx: _FitContext
    sigma: np.ndarray
    start: _RateStart | None


def _prepared(param: Parameterization, log: Log, momentum, *, estimator: str, known, noise, where: str,
              cond_limit: float, drift: tuple = (), history=None, instruments=None, knot_spacing=None,
              chunk=None, gyro_bias=False, signals_hook=None) -> _Prepared:
    """The first steps of :func:`identify` and :func:`estimate_only`: the equations, the sample
    count, the signals, the noise model, the excitation check (over chunks of ``chunk`` samples
    when given) and the estimators' context. Arguments as :func:`identify`'s, ``momentum`` an
    array or None, ``drift`` checked, ``gyro_bias`` False or a pass of :func:`identify_gyro_bias`.
    Raises as :func:`identify` on too few samples, a vanishing right-hand side or a motion that
    does not excite every parameter. ``signals_hook(eq, x, sigma)``, if given, is called once the signals and
    their weighting levels are known, before the equations are built (:func:`identify` starts work beside them)."""
    eq, anchors = _equations(param, log, momentum, known, where, drift, history)
    if gyro_bias:
        eq = replace(eq, bias=gyro_bias.columns)
    _check_sample_count(eq, log, where)
    x = eq.signals(log)
    # none given: the log's own levels, which ols weights by none but its checks and propagated covariance need
    # (at zero, a measured gyro's noise beside differentiated encoders was read as a gyro bias: the 7-DOF satellite's
    # undetermined directions went unseen, its parameters 14 standard errors off)
    estimated = noise is None
    noise = noise_from_log(log) if estimated else noise
    # differentiated signals weighted at their filters' levels: estimated from the smoothed log itself they are
    # understated, and the weights' errors-in-variables corrections fall short (docs/theory/noise.md)
    sigma = weighting_sigma(param, log, noise)
    if signals_hook is not None:
        signals_hook(eq, x, sigma)
    if chunk:
        phi, angles = None, None
        factor, nonzero = streamed_ols_factor(eq, x, chunk)
        _check_right_hand_side(nonzero, where)
        factor, cond_scaled = _check_factor(factor, eq.names(), cond_limit, where)
    else:
        phi, angles = (_angle_context(eq, log, noise, where, knot_spacing) if estimator == "angles" else
                       (eq.phi(x), None))  # fmt: skip
        factor, cond_scaled = check_excitation(phi, eq.names(), cond_limit, where)
    start = None
    if angles is not None and not eq.planar:  # the spatial fit starts from ML on differentiated rates
        start = _rate_start(param, log, momentum, known, where, cond_limit)
        angles = replace(angles, start=None if start is None else start.fit.theta)
    ctx = _FitContext(phi, factor, angles=angles,
                      **(_instrument_context(log, instruments, where) if estimator == "iv" else {}))
    return _Prepared(eq, anchors, x, phi, noise, estimated, factor, cond_scaled, ctx, sigma, start)


def estimate_only(param: Parameterization, log: Log, momentum, *, estimator: str, known: dict | None, noise: Noise,
                  drift=(), history: Log | None = None, where: str = "log", cond_limit: float = 1e10) -> np.ndarray:
    """:func:`identify`'s estimate alone, from the same arguments (an inertial ``momentum`` and
    the ``noise`` levels given; ``ols``, ``wls``, ``tls`` or ``iv`` with the measured signals as
    instruments): the free parameters, then the drift coefficients ``(p,)``, without the
    covariance nor the checks of the residuals, at a fraction of the cost (a screen: the monitor's
    of a lengthened warm-up). Raises as :func:`identify` on too few samples or a motion that does
    not excite every parameter."""
    prep = _prepared(param, log, np.asarray(momentum, float), estimator=estimator, known=known, noise=noise,
                     where=where, cond_limit=cond_limit, drift=check_drift_kinds(drift), history=history)
    theta = _ols(prep.eq, prep.x, prep.sigma, None, prep.ctx)[0]
    return theta if estimator == "ols" else _KERNELS[estimator](prep.eq, prep.x, prep.sigma, theta, prep.ctx)[0]


def identify(
    param: Parameterization,
    log: Log,
    momentum,
    *,
    estimator: str = "ml",
    known: dict | None = None,
    noise: Noise | None = None,
    instruments=None,
    where: str = "log",
    cond_limit: float = 1e10,
    knot_spacing: float | None = None,
    drift=(),
    history: Log | None = None,
    chunk: int | None = None,
    prior=None,
    prior_std: float = PRIOR_STD,
    gyro_bias: bool = False,
) -> Identification:
    """Estimate the minimal parameters from a measured motion.

    Parameters
    ----------
    param : Parameterization
        Minimal parameter set of the model (geometry only is used, and the rotor inertias of
        reaction wheels).
    log : Log
        Measured motion; joint columns in ``param.model.joints`` order.
    momentum : array_like of shape (3,) or None
        Inertial angular momentum of the whole system [N m s] (at the first sample when
        ``drift`` is given); None: unknown, estimated with the parameters.
    estimator : {"ml", "wls", "iv", "tls", "ols", "angles"}
        Maximum likelihood (efficient, the default), weighted, instrumental-variables, total or
        ordinary least squares; ``angles``: maximum likelihood on the joint angles and base attitude
        alone (the log's rates unused; spatial: started from ``ml`` on rates differentiated from the
        angles, which is reported, with a warning, when the likelihood does not converge);
        ``spaceid.estimation._estimators`` describes each one's assumptions and cost.
    known : dict, optional
        Known parameter values ``{name: value}``, by minimal-parameter name or by the physical
        parameter a minimal one equals alone (e.g. ``{"Iczz_wheel": 0.00197}``): they move to
        the right-hand side and anchor the scale (see :func:`spaceid.estimation.resolve_anchors`).
    noise : Noise, optional
        Measurement noise levels; estimated from the log when omitted.
    instruments : tuple of ndarray (n_samples, n_joints), optional
        Commanded joint angles and rates at the log's stamps, for ``iv`` (default: the
        measured ones, with the base rate the model predicts).
    where : str
        Name of the data source, for error messages.
    cond_limit : float
        Condition numbers of the column-scaled regressor above this mean some parameters are
        not excited: an error names them.
    knot_spacing : float, optional
        ``angles`` only: knot spacing of the joint-path splines [s] (at least two samples per
        span). Default: :data:`spaceid.estimation.KNOT_SPACING` for planar models; for spatial ones the
        coarsest of 1, 2, 4, ... 32 times it at which splines fit the joint samples to ``noise.angle``
        (docs/theory/angles.md, "Knots"), recorded in ``estimator_info["knot_spacing"]``.
    drift : iterable of {"torque", "viscous", "coulomb"}
        External torques that change the momentum, their coefficients estimated with the
        parameters (:mod:`spaceid.estimation._drift`; docs/theory/drift.md). Without them, a
        residual test warns when the data show a drift.
    history : Log, optional
        With ``drift``: a longer record (same stamps where they overlap) from whose first sample
        the drift is integrated, ``momentum`` being the momentum there (e.g. a rest before the
        log: friction acted in between). The result's ``momentum`` is still the one at the
        log's first sample.
    chunk : int, optional
        Stream the identification (``ols``, ``wls``, ``iv``, ``ml``): the equations are built a chunk of
        this many samples at a time and never held whole, so memory does not grow with the
        regressor (:mod:`spaceid.estimation._stream`); the result agrees with the in-memory one
        to round-off, the residual test for an unmodelled drift and the covariance of
        differentiated rates included. Default: in memory.
    prior : Model or str or Path, optional
        A CAD model of the robot (same joints and geometry): the estimate is then the maximum a
        posteriori over physically consistent models, with an independent Gaussian prior on every
        body's mass, first moments and inertia about the CAD values (:mod:`spaceid.estimation._prior`,
        docs/theory/prior.md); ``known`` may then also name a body's mass (``m_base``) or the total
        mass (``m_total``), held to a relative std of 1e-6. Works on any motion, even one that does
        not determine the parameters.
    prior_std : float
        The prior's relative standard deviation of masses and principal moments (default 0.2); the
        CoMs' is ``prior_std`` times each body's radius of gyration.
    gyro_bias : bool
        Estimate a constant gyro bias ``b`` (base axes [rad/s]; z only for planar systems) with the
        parameters: the base rate is taken as ``w_meas - b`` (``ml``, ``wls``, ``ols``, in memory;
        :mod:`spaceid.estimation._gyro_bias`, docs/theory/sensors.md). The result's ``gyro_bias``
        holds it with its standard errors, and ``cov`` includes its coupling with the parameters.

    Returns
    -------
    Identification
        ``values``/``std``/``cov`` over all minimal parameters (known ones with zero
        variance); ``drift``: the drift coefficients; ``momentum_std``: the standard errors of
        an estimated momentum; the anchors, the noise model and the log's provenance in
        ``settings``; in ``diagnostics`` (:class:`~spaceid.estimation.Diagnostics`) ``chi2_dof``
        and how the covariance was obtained (``covariance_method``, ``covariance``,
        ``residual_checks``, ``noise_model_warning``: what a ``chi2_dof`` far from 1 means), the
        estimator's record (``estimator_info``: for ``ml`` its convergence and ``fallback``, the
        estimate reported when it failed), ``plausibility`` (the warning about inertia-like
        parameters that came out negative) and ``drift_test`` (the residual test for an
        unmodelled drift); the warnings are also issued as ``UserWarning``.

    Raises
    ------
    SpaceidError
        Too few samples, no scale anchor, a scaled condition number at or above ``cond_limit``
        (naming the parameters not excited), or a singular or non-finite system in any
        estimator: one line naming the log and the fix.
    """
    if estimator not in ESTIMATORS:
        raise SpaceidError(f"`estimator`: {shown(estimator)} is not one of {', '.join(ESTIMATORS)}")
    if prior is not None:
        if gyro_bias:
            raise SpaceidError("`gyro_bias`: not estimated with a `prior` yet: estimate the bias without the "
                               "prior, correct the log's base rate by it, then identify with the prior")
        return identify_with_prior(identify, param, log, momentum, prior=prior, prior_std=prior_std, known=known,
                                   estimator=estimator, noise=noise, where=where, cond_limit=cond_limit, drift=drift,
                                   history=history, instruments=instruments, knot_spacing=knot_spacing, chunk=chunk)
    standard = split_known(param, known, where)[1]
    if standard:
        raise standard_anchor_error(next(iter(standard)), param, where)
    if gyro_bias is True:  # Gauss-Newton passes, each an identification with the bias columns (a BiasPass)
        def run(lg, step):
            return identify(param, lg, momentum, estimator=estimator, known=known, noise=noise, instruments=instruments,
                            where=where, cond_limit=cond_limit, knot_spacing=knot_spacing, drift=drift,
                            history=history, gyro_bias=step)

        return identify_gyro_bias(run, param, log, estimator=estimator, noise=noise, chunk=chunk, where=where)
    momentum = None if momentum is None else np.asarray(momentum, float)
    drift = check_drift_kinds(drift)
    if drift and estimator == "angles":
        raise SpaceidError("`drift`: not available with `estimator` angles (its equations do not carry drift "
                           "columns): use another estimator, or no drift terms")
    chunk = None if chunk is None else check_chunk(chunk, estimator)
    # the checks beside the work before them. ols's need no estimate: its noise Gram matrix starts beside the equations
    # and, on a second worker, its drift test beside the covariance. ml's noise Gram matrix starts once it converges,
    # beside the factor at its weights (again after it, should a fallback change them), its drift test on the second
    # worker once the factor is formed. The others' checks start after the estimate, beside the drift test.
    early, converging = estimator == "ols" and not chunk and not gyro_bias, estimator == "ml" and not chunk
    try:
        with contextlib.ExitStack() as beside:
            submit = beside.enter_context(side_by_side(2)) if early or converging else None
            jobs = {}

            def basis_beside():  # the drift test's candidates (a quadrature of the base rate), once
                if "basis" not in jobs:
                    jobs["basis"] = None if drift else submit(candidate_basis, log)

            def noise_beside(eq, x, sigma, theta=None, whitener=None):
                basis_beside()
                jobs["gram"], jobs["weights"] = _noise_gram(submit, eq, x, sigma, theta, estimator, log, whitener,
                                                            jobs["basis"]), whitener

            def basis():  # the candidates' basis, if formed beside
                return jobs["basis"].result() if jobs.get("basis") is not None else None

            prep = _prepared(param, log, momentum, estimator=estimator, known=known, noise=noise, where=where,
                             cond_limit=cond_limit, drift=drift, history=history, instruments=instruments,
                             knot_spacing=knot_spacing, chunk=chunk, gyro_bias=gyro_bias,
                             signals_hook=noise_beside if early else None)
            eq, x, phi, noise, estimated, factor, cond_scaled, ctx, sigma, start = (
                prep.eq, prep.x, prep.phi, prep.noise, prep.estimated, prep.factor, prep.cond_scaled, prep.ctx,
                prep.sigma, prep.start)
            angles = ctx.angles
            if submit is not None:  # formed while the estimator runs (ols's are already, beside the equations)
                basis_beside()

            def on_estimate(theta, whitener, residuals=None):
                if early:  # (ols: no whitener, the excitation check's factor, its residuals)
                    jobs["drift"] = submit(_drift_check, eq, x, phi, sigma, theta, estimator, log, drift, where, None,
                                           None, jobs["gram"].result, _factor_gram(factor), basis(), residuals)
                else:
                    noise_beside(eq, x, sigma, theta, whitener)

            fit = (_angles_estimate(eq, x, log, sigma, ctx, estimated, start) if angles is not None else
                   _estimate(eq, x, log, sigma, ctx, estimator, estimated, chunk,
                             on_estimate if early or converging else None))
            # the data's fit, and the one reported: updated by the attitude's measurement of the gyro bias, if estimated
            regression, fit, fused_by = fit, gyro_bias.fused(eq, fit) if gyro_bias else fit, gyro_bias or None
            nominal = _nominal(eq, fit.theta)
            if estimator == "ml" and not fit.info.get("fallback"):  # held directions judged with their widened errors
                judged = fit.cov if fit.held is None else widened(fit.cov, *fit.held, fit.theta, nominal)
                if _implausible_estimate(eq, fit.theta, judged, where, z=FALLBACK_Z):
                    fit = regression = _plausible_fallback(eq, x, log, sigma, ctx, estimated, chunk, fit, where)
                    fused_by = None
            theta, info, uncertainty = fit.theta, fit.info, fit.uncertainty  # the warnings below name them
            whitener = info.pop("whitener", None)
            # the factor of the columns whitened as the checks take them (ols: the excitation check's; ml: its bread's)
            white_factor = ((*factor, cond_scaled) if estimator == "ols" else
                            _whitened_factor(info.pop("whitened_factor", None)))
            if estimator == "wls" and not chunk:  # its weights' at the estimate: for the checks and its bias
                white_factor = _whitened_factor(weighted_factor(eq, x, theta, sigma, refined=False, phi=phi))
            submit = submit or beside.enter_context(side_by_side())
            if not chunk and estimator != "angles" and not ("gram" in jobs and jobs["weights"] is whitener):
                noise_beside(eq, x, sigma, theta, whitener)
            check = functools.partial(_drift_check, eq, x, phi, sigma, theta, estimator, log, drift, where, whitener,
                                      chunk, jobs["gram"].result if "gram" in jobs else None)
            # ols's on a worker since its estimate; ml's on the second worker now, before the directions (which wait
            # for the noise Gram matrix)
            drift_job = jobs.get("drift") or (submit(check, _factor_gram(white_factor), basis()) if converging
                                              else None)
            corrects = estimator == "ml" and not info.get("fallback")  # ML's spread grows with the noise it removes
            if "gram" in jobs:
                jobs["directions"] = submit(lambda: undetermined_directions(
                    eq, x, phi, sigma, theta, estimator, log, whitener, jobs["gram"].result()[: eq.p, : eq.p],
                    white_factor, every=corrects))
            s = _singular_values(factor)
            scale = log_momentum_scale(param, log, regressor=_log_regressor(eq, phi, estimator))  # (while ols waits)
            # the others' drift test here while the directions are found beside (ols's and ml's on a worker: taken last)
            checked = None if drift_job else check(_factor_gram(white_factor), basis())
            if chunk and corrects:  # streamed: from the noise a chunk at a time and the factor ML brings
                weak, ratios = undetermined_directions(
                    eq, x, None, sigma, theta, estimator, log, whitener,
                    equation_noise(eq, x, sigma, theta, estimator, log, whitener, chunk=chunk), white_factor, True)
            else:
                weak, ratios = jobs["directions"].result() if "directions" in jobs else ([], None)
            fit = _spread_along_directions(replace(fit, uncertainty=uncertainty), weak, ratios, corrects, nominal)
            uncertainty = fit.uncertainty
            # ML's WLS fallback: found by OLS's equations where WLS's weights hid them (its covariance widened there)
            hidden = info.pop("fallback_undetermined", [])
            weak = weak or hidden
            reported, biased = (info.get("fallback") or estimator).split(":")[0], ""
            if reported in LEAST_SQUARES:  # and the bias least squares leaves
                own = jobs["gram"].result() if reported == estimator and "gram" in jobs else None
                own_factor = (*factor, cond_scaled) if reported == "ols" else white_factor
                fit, biased = _eiv_widened(replace(fit, uncertainty=uncertainty), regression, reported, eq, x, sigma,
                                           log, chunk, own, own_factor, where, fused_by)
                uncertainty = fit.uncertainty
            # judged with the widened errors: an undetermined direction's value, pulled towards zero, is no sign of a
            # wrong momentum or anchor
            fit = replace(fit, implausible=_implausible_estimate(eq, theta, fit.cov, where))
            drift_record, drift_warning = drift_job.result() if drift_job else checked
        if drift_record.drift and not gyro_bias:  # an unestimated gyro bias trends too: named if it fits better
            bias, warning = bias_test(eq, x, phi, sigma, theta, estimator, log, whitener, chunk,
                                      drift_record.to_dict(), where)
            drift_record, drift_warning = replace(drift_record, gyro_bias=bias), warning or drift_warning
        pi, h = eq.full(theta)
        if history is not None and drift:  # the momentum at the log's first sample
            h = np.einsum("ij,i->j", eq.rot[0], eq.base_momentum(theta)[0])
        cov, h_std, d_std = _full_covariance(eq, fit.cov, param.n_params)
        correlation, collinear = _drift_collinear(eq, fit.cov, where)
    except np.linalg.LinAlgError as exc:  # singular or non-finite systems, at any step: one line, not a traceback
        raise SpaceidError(
            f"{where}: estimator '{estimator}' met a singular or non-finite linear system ({exc}): check the log for "
            "NaN or frozen signals and use an exciting trajectory (spaceid design)"
            + ("" if estimator == "ols" else ", or try `estimator` ols")
        ) from None
    if info.get("fallback"):
        warnings.warn(f"{where}: maximum likelihood failed, the estimate reported is {info['fallback']}", stacklevel=2)
    elif estimator == "angles" and not info.get("converged", True):
        warnings.warn(f"{where}: maximum likelihood on the angles did not converge in {info['iterations']} iterations: "
                      "the estimate and its standard errors are the last iterate's; use a designed motion "
                      "(spaceid design) or `estimator` ml on differentiated rates", stacklevel=2)
    if uncertainty["noise_model_warning"]:
        warnings.warn(f"{where}: {uncertainty['noise_model_warning']}", stacklevel=2)
    for warning in (fit.implausible, drift_warning, collinear, undetermined_warning(weak, eq.p, where), biased):
        if warning:
            warnings.warn(warning, stacklevel=2)
    units = drift_names(drift, param.model.planar)[1]
    terms = tuple({"name": n, "value": float(v), "std": float(e), "unit": u}
                  for n, v, e, u in zip(eq.drift, eq.drift_values(theta), d_std, units))  # fmt: skip
    settings = {
        "parameterization": param.to_dict(),
        "log": dict(log.meta),
        "log_fingerprint": log_fingerprint(log),  # validation warns when given this same log
        "anchors": prep.anchors,
        "momentum_estimated": momentum is None,
        **({"history": {"source": str(history.meta.get("source", "log")), "start": float(history.t[0]),
                        "momentum": eq.full(theta)[1].tolist()}} if history is not None and drift else {}),
        "noise": noise.to_dict(),
    }
    diagnostics = Diagnostics(
        chi2_dof=uncertainty["chi2_dof"], variance_factor=uncertainty["variance_factor"],
        covariance_method=uncertainty["covariance_method"], covariance=uncertainty["covariance"],
        covariance_from_residuals=uncertainty["covariance_from_residuals"],
        residual_checks=ResidualChecks.from_dict(uncertainty["residual_checks"]),
        noise_model_warning=uncertainty["noise_model_warning"],
        plausibility=fit.implausible or "no inertia-like parameter negative", drift_test=drift_record,
        drift_correlation=correlation, condition_number_scaled=cond_scaled,
        estimator_info={k: v for k, v in info.items() if v is None or np.isscalar(v) or isinstance(v, (str, list))},
        undetermined=tuple(weak),
    )
    return Identification(
        names=param.names, definitions=param.definitions, values=pi, std=np.sqrt(np.diag(cov)), cov=cov,
        condition_number=float(s[0] / s[-1]) if s[-1] > 0 else np.inf, singular_values=s, residual_rms=fit.rms,
        n_samples=log.n_samples, estimator=estimator, momentum=h, model=param.model.source or param.model.name,
        planar=param.model.planar, settings=settings, units=param.units, drift=terms, momentum_std=h_std,
        diagnostics=diagnostics, scale=scale,
        gyro_bias=gyro_bias.terms(eq, theta, fit.cov) if gyro_bias else (),
    )
