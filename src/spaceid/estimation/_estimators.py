"""The five estimators of the minimal parameters (the paper's Eq. 11 and beyond), and the linear
algebra they share.

Each kernel solves the stacked equations ``Phi_n(x) [theta; 1] = 0`` of
:class:`~spaceid.estimation._equations.Equations` for ``theta``, starting from the OLS
solution; ``ESTIMATORS`` names them and ``_KERNELS`` dispatches on the name:

``ols``
    Ordinary least squares (the paper's Eq. 11). Biased by O(sigma^2) as the regressor is
    noisy, and not efficient: every equation counts the same however noisy it is. Needs no noise
    model: its covariance is the heteroscedasticity-consistent one from the residuals, and it is
    the fast choice for long logs of large systems (10,000 samples of a 496-parameter servicer
    in about a second).
``wls``
    Weighted least squares, each sample weighted by the inverse first-order covariance of its
    equation error, ``S_n = J_n Sigma J_n^T`` (:mod:`spaceid.estimation`), iterated twice. Efficient
    to first order; keeps an O(sigma^2) bias.
``tls``
    Total least squares on the column-scaled system (errors in every column, of the size the
    noise model predicts). Consistent only when the regressor's entry errors are independent
    and alike after scaling, which they are not here (columns share the same noisy signals):
    offered for comparison with the literature.
``iv``
    Instrumental variables: instruments are the regressor rebuilt from signals that do not
    share the measurement noise: the commanded joint trajectory (``instruments=``) with the
    base rate the current estimate predicts, or, without one, the measured joint signals with
    the predicted base rate (removes the base-rate noise, the largest on a motion-capture
    table, but not the joint noise). Iterated twice.
``ml`` (default)
    Maximum likelihood for Gaussian signal noise of known levels: alternates the projection of
    the signals onto the momentum constraint and the fundamental-numerical-scheme update of pi
    (the stationarity condition of the Sampson cost, derivative of the weights included), so
    that at convergence the corrected signals satisfy the equations exactly and pi minimises
    the whitened signal corrections. Unbiased to first order and efficient: its covariance is
    the Cramer-Rao bound of the errors-in-variables model (:func:`spaceid.estimation.cramer_rao`).
    The whole call costs about three ``ols`` calls (10,000 servicer samples): the equations are
    built and the whitened ones factorised once, each iteration needs only the analytic signal
    Jacobian at the corrected signals and a contracted derivative (:func:`_ml_fit`), and it
    streams (:mod:`spaceid.estimation._stream`).
``angles``
    Maximum likelihood on the joint angles and base attitude alone, the joint paths a spline nuisance;
    no rates (:mod:`spaceid.estimation._angles`, spatial models :mod:`spaceid.estimation._angles_spatial`; at
    least 40 Hz). Its covariance
    is the Cramer-Rao bound for angle measurements, which it reaches where the rate-based
    estimators on differentiated angles stay 1.3 to 2.2 times above (Cepheus, 100 Hz). Planar fits start
    from the integral form's least squares, spatial ones from ``ml`` on rates differentiated from the angles,
    which ``identify`` reports (``info["fallback"]``) when the spatial likelihood does not converge.

The linear algebra the kernels share with the covariances and the streamed passes (whitening, the
triangular factor of the column-scaled equations) is :mod:`spaceid.estimation._linalg`.

References
----------
.. [1] The Cepheus paper (NTUA Control Systems Lab; see docs/citing.md), Eq. 11 (least squares).
.. [2] W. Chojnacki, M. J. Brooks, A. van den Hengel, D. Gawley, "On the fitting of surfaces to
   data with covariances", IEEE TPAMI 22(11), 2000 (the fundamental numerical scheme).
"""

from __future__ import annotations

import functools
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np
from scipy.linalg import solve_triangular

from .._constants import ESTIMATORS
from .._svd import svd
from .._threads import one_blas_thread
from ..dynamics import base_rate
from ._angles import _angles_ml
from ._equations import _split, equation_residuals
from ._linalg import (SINGLE_COLUMNS, SINGLE_COND, _column_scale, _equation_whitener, _gram_matrix_factor,
                      _inverse_times, _parts, _solve, _solve_factor, _triangular_factor, _whiten, _whitened,
                      _whitened_gram, lower_inverse)  # fmt: skip
from ._noise import FD_STEP, equation_covariance

if TYPE_CHECKING:
    from ._angles import _AngleData

__all__ = ["ESTIMATORS"]


# --- the kernels: (eq, x, sigma, theta, ctx) -> (theta, info) -----------------------------------


@dataclass(frozen=True)
class _FitContext:
    """What a kernel takes besides the equations, signals, noise levels and start (``ctx``).

    Attributes
    ----------
    phi : ndarray of shape (n, rows, p + 1) or None
        The stacked equations ``[A | -b]`` (the ``angles`` estimator: its integral form); None when
        streamed (:mod:`spaceid.estimation._stream`: built a chunk at a time).
    factor : tuple or None
        ``(scale, R)``, the orthogonal factor of the column-scaled equations (:func:`_triangular_factor`).
    reference : tuple of 2 ndarray or None
        ``iv``: the joint signals ``(q, qd)`` the instruments are built from.
    instruments : str or None
        ``iv``: which signals those are, in words (recorded in the estimator's info).
    angles : _AngleData or None
        ``angles``: the spline path, the measured angles and the noise levels
        (:func:`spaceid.estimation._angles._angle_context`).
    """

    phi: np.ndarray | None
    factor: tuple | None = None
    reference: tuple | None = None
    instruments: str | None = None
    angles: _AngleData | None = None


def _ols(eq, x, sigma, theta, ctx):
    A, b = _split(ctx.phi)
    theta, ginv = _solve(A, b, factor=ctx.factor)
    return theta, {"ginv": ginv}  # reused by the covariance


def _wls(eq, x, sigma, theta, ctx, iterations=2):
    phi = ctx.phi
    for _ in range(iterations):
        L = _equation_whitener(eq, x, theta, sigma)
        theta, _ = _solve(*_split(_whitened(L, phi)))
    return theta, {"iterations": iterations}


def _column_noise(eq, x, sigma):
    """RMS noise of each column of ``[A | -b]`` [per entry], propagated from the signal noise."""
    total = np.zeros(eq.p + 1)
    for i in np.flatnonzero(sigma):
        e = np.zeros(x.shape[1])
        e[i] = FD_STEP
        d = (eq.phi(x + e) - eq.phi(x - e)) / (2 * FD_STEP)
        total += sigma[i] ** 2 * np.sum(d**2, axis=(0, 1))
    return np.sqrt(total / (len(x) * eq.param.rows))


def _tls(eq, x, sigma, theta, ctx):
    from scipy.optimize import brentq
    A, b = _split(ctx.phi)
    noise = _column_noise(eq, x, sigma)
    d_a = np.where(noise[:-1] > 0, noise[:-1], np.linalg.norm(A, axis=0) * 1e-12 + 1e-300)
    As = A / d_a
    # minimise |As y - b|^2 / (|y|^2 + d_b^2): (As^T As - lam I) y = As^T b, lam the root of the
    # secular equation sum c_i^2 / (mu_i - lam) + lam d_b^2 - |b|^2 = 0 below the smallest mu
    with one_blas_thread():  # threaded, on busy cores, the SVD of 600 x 496 took 2.3 s (measured)
        U, sv, Vt = svd(As, full_matrices=False)  # not the Gram matrix: keeps cond(A), not its square
    mu, c = sv**2, sv * (U.T @ b)
    secular = lambda lam: np.sum(c**2 / (mu - lam)) + lam * noise[-1] ** 2 - b @ b  # noqa: E731
    lam = 0.0
    if secular(0.0) < 0:
        hi = mu[-1] * (1 - 1e-12)
        lam = brentq(secular, 0.0, hi, xtol=1e-14 * mu[-1], rtol=1e-14) if secular(hi) > 0 else hi
    return Vt.T @ (c / (mu - lam)) / d_a, {"lambda": float(lam), "column_noise": noise.tolist()}


def _instrument_rows(eq, x, theta, reference):
    """Instruments ``Z (n rows, p)``: the regressor columns at the joint signals ``reference``
    ``(q, qd)`` and the base rate that ``theta`` predicts for them."""
    nj = len(eq.param.model.joints)
    xz = x.copy()
    xz[:, : 2 * nj] = np.hstack(reference)
    w = base_rate(eq.param, eq.full(theta)[0], reference[0], reference[1], eq.base_momentum(theta))
    xz[:, 2 * nj : 2 * nj + len(eq.axes)] = w[:, eq.axes]
    return _split(eq.phi(xz))[0]


def _iv(eq, x, sigma, theta, ctx, iterations=2):
    A, b = _split(ctx.phi)
    for _ in range(iterations):
        Z = _instrument_rows(eq, x, theta, ctx.reference)
        # (Z^T A) theta = Z^T b, solved as least squares in the instruments' orthonormal basis:
        # conditioned like A, not like A^T Z
        scale = np.linalg.norm(A, axis=0)
        scale[scale == 0] = 1.0
        with one_blas_thread():  # threaded, on busy cores, the QR of 600 x 496 took 0.7 s instead of 0.1 (measured)
            basis = np.linalg.qr(Z / scale)[0]
            theta = np.linalg.lstsq(basis.T @ (A / scale), basis.T @ b, rcond=None)[0] / scale
    return theta, {"iterations": iterations, "instruments": ctx.instruments, "Z": Z}


ML_PART = 1024
"""Samples per part of a maximum-likelihood evaluation (:func:`_ml_evaluate`): the parts run on
threads and their sums are added in order, so the result does not depend on the thread count."""

ANDERSON = 3
"""Earlier updates that the maximum-likelihood iteration combines with the last (Anderson
acceleration, :func:`_anderson`)."""


def _ml_part(eq, x, theta, sigma, equations, previous=None, gradient=True) -> dict:
    """One part's share of a maximum-likelihood evaluation at ``theta``, the constraint linearised
    at the corrected signals ``xh`` and evaluated at the measured ``x (n, n_x)``.

    ``xh`` is ``x`` without ``previous``; with it, the corrected signals of ``theta`` by the last
    accepted evaluation's linearisation, ``previous = (theta_0, xh_0, r_0, L_0, J_0)`` (its signal
    Jacobian ``J_0`` recomputed when None): ``x - Sigma J_0^T S_0^-1 (r_0 + A (theta - theta_0))``, the
    projection onto that linearised constraint (:func:`_ml_fit` compares objectives of evaluations
    linearised alike). ``equations()`` gives the equations ``[A | -b] (n, rows, p + 1)`` at ``x``.

    Returns the objective ``f = sum_n r_n^T S_n^-1 r_n`` (the whitened signal corrections that
    satisfy the linearised constraint), the linearisation point ``xh``, the residuals
    ``r (n, rows)`` of the linearised equations ``Phi(xh) theta_bar + J (x - xh)``, the Cholesky
    factors ``L (n, rows, rows)`` of their covariances ``S = J Sigma J^T``, ``J`` itself (all from the
    signal Jacobian at ``xh``: no regressor) and, with ``gradient``, the half-gradient of ``f``:
    ``A^T u - sum_n u_n^T dA_n[v_n]``, ``u = S^-1 r``, ``v = Sigma J^T u`` (the second term is the
    weights' derivative, formed without the derivative of ``A``)."""
    phi = equations() if gradient or previous is not None else None
    xh = x
    if previous is not None:
        theta_0, xh_0, r_0, L_0, J_0 = previous
        J_0 = eq.jacobian(xh_0, theta_0) if J_0 is None else J_0
        u_0 = _inverse_times(L_0, (r_0 + equation_residuals(phi, theta - theta_0, 0.0))[..., None])[..., 0]
        xh = x - sigma**2 * np.einsum("nrx,nr->nx", J_0, u_0)
    J = eq.jacobian(xh, theta)
    r = eq.error(xh, theta, J) + np.einsum("nrx,nx->nr", J, x - xh)
    L = _whiten(equation_covariance(J, sigma))
    inverse = lower_inverse(L)
    white = np.einsum("nrs,ns->nr", inverse, r)
    part = {"f": float(np.sum(white**2)), "xh": xh, "L": L, "r": r, "J": J}
    if gradient:
        u = np.einsum("nsr,ns->nr", inverse, white)
        v = sigma**2 * np.einsum("nrx,nr->nx", J, u)
        part["grad"] = (u.ravel() @ phi.reshape(len(u.ravel()), -1))[:-1] - (eq.contracted_dphi((x + xh) / 2, v, u)
                                                                             if np.any(v) else 0.0)  # fmt: skip
    return part


def _ml_evaluate(eq, x, theta, sigma, size, equations, previous=None, gradient=True, keep_jacobian=True) -> dict:
    """:func:`_ml_part` over the parts of ``size`` samples, joined: the sums added in order, the
    per-sample arrays stacked (``J`` only with ``keep_jacobian``; ``previous`` too holds whole-log
    arrays, its ``J_0`` None when not kept). ``equations(rows, eq_part, x_part)`` gives the equations
    of those samples."""
    n, rows = len(x), eq.param.rows
    out = {"f": 0.0, "grad": 0.0, "xh": np.empty_like(x), "L": np.empty((n, rows, rows)), "r": np.empty((n, rows)),
           "J": np.empty((n, rows, x.shape[1])) if keep_jacobian else None}  # fmt: skip

    def part(sl):
        e = eq.select(sl)
        before = None if previous is None else [None if a is None else a[sl] for a in previous[1:]]
        return _ml_part(e, x[sl], theta, sigma, lambda: equations(sl, e, x[sl]),
                        None if previous is None else (previous[0], *before), gradient)  # fmt: skip

    for sl, one in _parts(part, n, size):
        out["f"], out["grad"] = out["f"] + one["f"], out["grad"] + one.get("grad", 0.0)
        for key in ("xh", "L", "r", "J"):
            if out[key] is not None:
                out[key][sl] = one[key]
    return out


def _gram_solver(factor, subspace=None) -> tuple:
    """``(solve, std)``: ``solve(g) = (A^T A)^-1 g`` for the factor ``(scale, R)`` of :func:`_triangular_factor`
    (two triangular solves) and ``std (p,)`` the square roots of that inverse's diagonal; with ``subspace (p, k)``
    of full column rank, both within its span: ``B (B^T A^T A B)^-1 B^T`` (``B = subspace``, by a QR factor)."""
    scale, R = factor
    r = R[:-1, :-1]
    with one_blas_thread():
        if subspace is None:
            def solve(g):
                with one_blas_thread():
                    return solve_triangular(r, solve_triangular(r, g / scale, trans="T")) / scale
            # the inverse's diagonal: the row norms of R^-1 (its product with itself, p^3, is not needed)
            return solve, np.maximum(np.linalg.norm(solve_triangular(r, np.eye(len(r))), axis=1) / scale, 1e-150)
        m = np.linalg.qr(r @ (subspace * scale[:, None]), mode="r")
        spread = solve_triangular(m, subspace.T, trans="T")  # B m^-1, transposed

    def solve_within(g):
        with one_blas_thread():
            return subspace @ solve_triangular(m, solve_triangular(m, subspace.T @ g, trans="T"))
    return solve_within, np.sqrt(np.maximum(np.sum(spread**2, axis=0), 1e-300))


def _anderson(history):
    """The next estimate from the last updates, ``history`` a list of (scaled update ``g_k``,
    proposal ``theta_k + update_k``): the combination of the proposals whose updates' combination
    is least (type-II Anderson acceleration), or the last proposal when there is one."""
    g, proposals = np.array([h[0] for h in history]), np.array([h[1] for h in history])
    if len(history) < 2:
        return proposals[-1]
    with one_blas_thread():
        gamma = np.linalg.lstsq(np.diff(g, axis=0).T, g[-1], rcond=None)[0]
    return proposals[-1] - gamma @ np.diff(proposals, axis=0)


EARLY_CHECK = 5
EARLY_FALL = 1e-2
"""A fit whose objective still fell by more than ``EARLY_FALL`` of itself in its ``EARLY_CHECK``-th iteration asks
then, once, what it would ask after :data:`STALL_CHECK`. Over 2,400 fits over every direction on 300 random robots
(8 noise draws each, undesigned and designed motions), the 146 that converged after more than 5 iterations fell by
at most 9.3e-4 in their fifth; 66 fits that did not converge asked 5 iterations earlier, the same fits were held,
and no robot's largest error moved. The servicer's held 500-sample log (194 of 496 directions held) fell by 3.3 %."""
STALL_CHECK = 10
"""Iterations after which a maximum-likelihood fit that has not converged asks whether the data leave
directions undetermined (``stalled`` of :func:`_ml_fit`): along them the likelihood has no maximum, and
the iteration would creep on to ``max_iter`` (the converged fits of the test suite take 2 to 9
iterations, one 36; on the presets' short undesigned logs the objective still fell by 0.1 % an
iteration at the 50th)."""


def _ml_fit(x, theta, evaluate, factor, wls, max_iter=50, tol=1e-4, ftol=1e-9, halvings=6, subspace=None,
            stalled=None, converged=None):
    """The maximum-likelihood iteration on the signals ``x (n, n_x)`` from the OLS ``theta``, given

    - ``evaluate(theta, previous, gradient)``: :func:`_ml_evaluate` (``previous`` the last accepted
      evaluation: its ``(theta, xh, r, L, J)``);
    - ``factor(L, single=False)``: the factor ``(scale, R)`` of the equations whitened by ``L``
      (:func:`_triangular_factor`); ``single``: from their Gram matrix formed in single precision, or None when their
      condition does not allow it (:data:`~spaceid.estimation._linalg.SINGLE_COND`). The preconditioners of
      :data:`~spaceid.estimation._linalg.SINGLE_COLUMNS` unknowns or more are asked for so (the fixed point is the
      scheme's whatever the preconditioner); the covariance's factor is formed in double;
    - ``wls()``: the WLS estimate, the fallback.

    The first update is that of the fundamental numerical scheme from ``theta``: ``-G^-1 grad``
    (:func:`_ml_part`), ``G`` the Gram matrix of the equations whitened at the measured signals
    and ``theta``. ``G`` is factorised once more, at the weights of the first update's estimate,
    and then preconditions every update: the fixed point is the scheme's (``grad = 0``) whatever
    the preconditioner. The updates are combined by Anderson acceleration (:func:`_anderson`),
    which makes up for the fixed preconditioner: on 10,000 servicer samples at 1e-3 noise the
    plain updates contract by 0.33 a step with the start's ``G`` (0.11 with it refactorised at
    each estimate); refactorised once and accelerated, the iteration reaches ``tol`` in 4 steps
    (5 without the second factorisation).

    A step is taken when it does not raise the objective (by more than ``ftol`` relative, the
    jitter of the finite differences); otherwise it is halved, back towards the last accepted
    estimate (the acceleration restarted there), up to ``halvings`` times. Converged when the
    update proposed at an accepted estimate moves no parameter by more than ``tol`` of its
    standard error (or 1e-9 relative: the finite differences leave a jitter of ~1e-10) and the
    objective changed by less than ``ftol`` relative: the estimate is then within about ``tol``
    standard errors of the fixed point. Not converged after :data:`STALL_CHECK` iterations (:data:`EARLY_CHECK` while
    its objective still falls by more than :data:`EARLY_FALL` an iteration), it asks once and stops when
    ``stalled(theta)`` (optional) gives a reason at the estimate it would report on failing (below; directions
    the data do not determine, which the iterate itself runs off along), as when it does not converge.

    When it does not converge (``max_iter`` reached, or the line search stalls) the iterates are
    not reported, whatever their objective: with a wrong noise model the objective can keep
    falling while the parameters run off to infinity (its infimum lies there; measured on Cepheus
    with rates differentiated at 3e-2 rad noise, levels estimated: the unaccelerated scheme's
    error grew to 100 times the parameters; accelerated, it converges there to a local minimum, 9
    times the parameters, one negative: :func:`spaceid.estimation.identify` then reports WLS's
    estimate when that one is physically possible). The estimate is then WLS when its objective is below
    the OLS start's, else OLS: ``info["fallback"]`` says which and why, and the objective is never
    worse than the start's. Converged, ``info`` holds the factor of the equations whitened at the estimate, the
    whitener and the residuals (``factor``, ``whitener``, ``residuals``: the covariance's terms); ``converged(theta,
    L)`` (optional) is called first, with the estimate and the whitener (:func:`spaceid.estimation.identify` starts
    its checks beside the factor)."""
    start_theta = theta

    @functools.cache
    def fallback():  # the estimate reported on failing, WLS's or the OLS start's, and WLS's objective
        estimate = wls()
        f_wls = evaluate(estimate, None, False)["f"]
        return (estimate if f_wls < start else start_theta), f_wls

    now = evaluate(theta, None, True)
    single = len(theta) >= SINGLE_COLUMNS  # the preconditioners' Gram matrices in single precision, where that pays

    def preconditioner(L):  # once single precision is refused, so would the second be: the weights move little
        nonlocal single
        scaled = factor(L, True) if single else None
        single = scaled is not None
        return scaled or factor(L)

    f, start, scaled = now["f"], now["f"], preconditioner(now["L"])
    solve = _gram_solver(scaled, subspace)[0]
    target = theta - solve(now["grad"])  # the fundamental numerical scheme's first update
    history, small, reason, damping, falling = [], False, None, 1.0, 0.0
    for it in range(1, max_iter + 1):
        if stalled is not None and (it == STALL_CHECK + 1 or it == EARLY_CHECK + 1 and falling > EARLY_FALL):
            why = stalled(fallback()[0])
            stalled = None  # asked once
            if why:
                reason, it = f"had not converged after {it - 1} iterations, and {why}", it - 1
                break
        trial = theta + damping * (target - theta)
        new = evaluate(trial, (theta, now["xh"], now["r"], now["L"], now["J"]), True)
        if new["f"] <= f * (1 + ftol):  # accepted
            change, f, theta, now, damping = f - new["f"], new["f"], trial, new, 1.0
            falling = change / max(f + change, 1e-300)
            if not history:  # the weights of the first accepted estimate: closer to the fixed point's than the start's
                scaled = preconditioner(now["L"])
                solve, std = _gram_solver(scaled, subspace)  # std: for the tolerance
            update = -solve(now["grad"])
            small = (np.abs(update) / std).max() < tol or np.abs(update).max() <= 1e-9 * np.abs(theta + update).max()
            if small and abs(change) <= ftol * f:
                break
            history = (history + [(update / std, theta + update)])[-(ANDERSON + 1) :]
            target = _anderson(history)
        elif small:  # the update is within tolerance of the accepted estimate: its fixed point
            break
        else:
            damping /= 2
            history = history[-1:]  # back to the plain update of the accepted estimate
            target = history[-1][1] if history else target
            if damping < 2.0**-halvings:
                reason = f"stalled after {it} iterations (no step along the update lowered the objective)"
                break
    else:
        reason = f"did not converge in {max_iter} iterations"
    info = {"iterations": it, "converged": reason is None, "objective_start": start, "objective_end": f,
            "fallback": None}  # fmt: skip
    if reason is None:
        if converged is not None:
            converged(theta, now["L"])
        return theta, info | {"factor": factor(now["L"]), "whitener": now["L"], "residuals": now["r"]}
    estimate, f_wls = fallback()
    info["objective_end"] = min(f_wls, start)
    if f_wls < start:
        info["fallback"] = (f"wls: maximum likelihood {reason} (objective {f:.4g}, from {start:.4g} at the OLS start); "
                            f"WLS lowers it to {f_wls:.4g}")
        return estimate, info
    info["fallback"] = (f"ols: maximum likelihood {reason}, and WLS did not lower the objective "
                        f"({f_wls:.4g} > {start:.4g})")
    return start_theta, info


def _ml(eq, x, sigma, theta, ctx, **options):
    """Maximum likelihood in memory (:func:`_ml_fit`, ``options`` its own): the columns of the
    equations ``ctx.phi`` are built once, at the measured signals; the corrected signals enter
    through the residuals, the weights and the weights' derivative, taken halfway between measured
    and corrected signals: that cancels the columns' own change to second order in the corrections
    (docs/theory/scale.md; the fixed point is that of re-linearised columns to 4e-8 standard errors
    on the servicer at 1e-3 noise). Converged, ``info["terms"]`` holds the covariance's terms at the
    estimate (:func:`spaceid.estimation._uncertainty._covariance_terms`)."""
    phi = ctx.phi

    def factor(L, single=False):  # the preconditioner and the bread: no refined solution needed
        if single:
            return _gram_matrix_factor(_whitened_gram(L, phi, True), limit=SINGLE_COND)
        scaled = _gram_matrix_factor(_whitened_gram(L, phi))
        if scaled is None:  # conditioned beyond GRAM_COND: by QR
            A, b = _split(_whitened(L, phi))
            scale = _column_scale(A)
            scaled = scale, _triangular_factor(A, b, scale)
        return scaled

    def evaluate(estimate, previous, gradient):
        return _ml_evaluate(eq, x, estimate, sigma, ML_PART, lambda rows, e, xe: phi[rows], previous, gradient)

    estimate, info = _ml_fit(x, theta, evaluate, factor, lambda: _wls(eq, x, sigma, theta, ctx)[0], **options)
    if "factor" in info:
        scale, R = info.pop("factor")
        L, r = info["whitener"], info.pop("residuals")
        info["whitened_factor"] = (scale, R)  # the checks' factor of the equations whitened by L
        info["terms"] = {"M": phi[..., :-1], "bread": _solve_factor(R, scale)[1], "L": L, "r": r,
                         "scored": _inverse_times(L, r[..., None])[..., 0], "white": _whitened(L, r[..., None])[..., 0]}
    return estimate, info


_KERNELS = {"ols": _ols, "wls": _wls, "tls": _tls, "iv": _iv, "ml": _ml, "angles": _angles_ml}
