"""Streaming identification: the momentum equations of a log built, used and dropped a chunk of
samples at a time (``identify(..., chunk=N)``), so that memory does not grow with the regressor.

What the estimators need from all samples is accumulated over the chunks in passes over the log,
each pass rebuilding the chunk's equations ``[A | -b]`` (``N x rows x (p + 1)``):

- the least-squares factor (:func:`_streamed_factor`): the unscaled ``R`` of ``[A | b]`` by blocked
  Householder QR (TSQR, :func:`~spaceid.estimation._linalg._accumulate_factor`), column-wise
  backward stable in one pass; the column scales are its column norms (``A^T A = R^T R``), so the
  scaled factor of :func:`~spaceid.estimation._linalg._triangular_factor` follows without a
  pass for the norms. (The in-memory path's Cholesky of the Gram matrix would need one more pass
  per refinement step.)
- ``wls``: one factor pass per iteration, the whitening recomputed per chunk;
- ``iv``: per iteration, the instruments' factor ``R_Z`` and the cross products ``Z^T A``, ``Z^T b``
  (column-scaled), from which the least squares in the instruments' orthonormal basis
  ``Q_Z = Z R_Z^-1`` is formed;
- ``ml``: the in-memory iteration itself (:func:`~spaceid.estimation._estimators._ml_fit`), whose
  evaluations are sums over parts of samples already: one pass per evaluation (the chunk's columns
  for the gradient ``A^T S^-1 r``; the signal Jacobian, the residuals and the weights' derivative
  need no regressor), and a factor pass for the preconditioner at the start and for the
  covariance at the estimate;
- the covariance: a pass for the per-sample residuals (``n x rows``, kept: the residual checks
  and the choice of covariance need them all) and the whiteners (``n x rows x rows``; ML brings
  both from its last evaluation), then, when the covariance follows the residuals, a pass for the
  sandwich or the Newey-West sum of the scores, whose lags reach back across chunks
  (:func:`~spaceid.estimation._uncertainty._hac`), and for rates differentiated by Savitzky-Golay
  a pass for the angle noise propagated through the filters, the rows under the windows that
  straddle a chunk's end carried to the next
  (:func:`~spaceid.estimation._differentiated.propagated_covariance`);
- the residual test for an unmodelled drift: two passes
  (:func:`~spaceid.estimation._residuals.drift_test`).

Kept for the whole log: the signals ``x (n, n_x)``, the attitudes, the residuals, the whiteners
and the drift test's momentum change per drift coefficient, ``O(n (n_x + 24))`` values, and for ML
the corrected signals of two estimates; never the ``n x rows x p`` regressor. Time is linear
in the samples. The total least squares (an SVD of the whole regressor) and the angles estimator
are in memory only.
"""

from __future__ import annotations

import functools

import numpy as np

from .._errors import SpaceidError
from .._threads import one_blas_thread
from ._equations import _split, equation_residuals
from ._estimators import _instrument_rows, _ml_evaluate, _ml_fit
from ._linalg import (SINGLE_COND, _accumulate_factor, _equation_whitener, _factor_of_rows, _gram_matrix_factor,
                      _gram_of_rows, _inverse_times, _sandwich, _solve_factor, _whitened, _whitened_gram)  # fmt: skip
from ._uncertainty import WEIGHTED, _covariance_choice, _covariance_record, _hac, _mapped_scores, _with_propagated

__all__ = ["STREAMED"]

STREAMED = ("ols", "wls", "iv", "ml")
"""The estimators that ``identify(..., chunk=N)`` streams."""


def check_chunk(chunk, estimator: str) -> int:
    """``chunk`` as a positive number of samples, or a SpaceidError naming the option and the fix."""
    if estimator not in STREAMED:
        raise SpaceidError(f"`chunk`: estimator '{estimator}' runs in memory only; streaming is available for "
                           f"{', '.join(STREAMED)}: use one of those, or no `chunk`")
    if isinstance(chunk, bool) or not isinstance(chunk, (int, np.integer)) or chunk < 1:
        raise SpaceidError(f"`chunk`: {chunk!r} is not a positive whole number of samples per chunk: give e.g. 4096")
    return int(chunk)


def _chunks(eq, x, chunk):
    """``(rows, eq_c, x_c)`` for consecutive chunks of ``chunk`` samples: the slice, the equations of
    those samples (their attitudes and drift basis) and their signals."""
    for start in range(0, len(x), chunk):
        rows = slice(start, min(start + chunk, len(x)))
        yield rows, eq.select(rows), x[rows]


def _accumulated_factor(blocks):
    """Upper triangular ``R (c + 1, c + 1)`` of the stacked rows ``[M_c | b_c]`` of the blocks
    ``(M_c (m, c), b_c (m,))``, by blocked Householder QR (``R^T R`` their Gram matrix)."""
    R = None
    for M, b in blocks:
        part = _factor_of_rows(M, b, np.ones(M.shape[1]))
        R = part if R is None else _accumulate_factor(R, np.asfortranarray(part))
    if not np.all(np.isfinite(R)):
        raise np.linalg.LinAlgError("the equations hold non-finite values")
    return R


def _streamed_factor(blocks, p, refined=True, gram=None):
    """``(scale (p,), R (p + 1, p + 1))`` of :func:`~spaceid.estimation._linalg._triangular_factor`
    for the rows of the blocks ``(A_c (m, p), b_c (m,))`` that ``blocks()`` yields anew at each pass.

    As in memory: from their Gram matrix (a pass, or ``gram`` when given) by
    :func:`~spaceid.estimation._linalg._gram_matrix_factor`, the solution refined on the data (a
    pass per step, two to four) when ``refined``; when the scaled condition number is above
    ``GRAM_COND``, by TSQR of the unscaled rows (:func:`_accumulated_factor`, a pass), scaled by the
    column norms of ``A`` read from ``R``."""

    def refine(y):
        correlation, square = 0.0, 0.0
        for A, b in blocks():
            residual = b - A @ y
            correlation, square = correlation + residual @ A, square + residual @ residual
        return correlation, np.sqrt(square)

    if gram is None:
        gram = sum(_gram_of_rows(A, b, np.ones(p)) for A, b in blocks())
    scaled = _gram_matrix_factor(gram, refine if refined else None)
    if scaled is not None:
        return scaled
    R = _accumulated_factor(blocks())
    scale = np.linalg.norm(R[:, :p], axis=0)
    scale[scale == 0] = 1.0
    return scale, R / np.append(scale, 1.0)


def streamed_ols_factor(eq, x, chunk) -> tuple:
    """The factor ``(scale, R)`` of the equations of ``x``, a chunk at a time, and whether their
    right-hand side is nonzero anywhere."""
    nonzero = []

    def blocks():
        for _, e, xc in _chunks(eq, x, chunk):
            A, b = _split(e.phi(xc))
            nonzero.append(bool(np.any(b)))
            yield A, b

    return _streamed_factor(blocks, eq.p), any(nonzero)


def weighted_factor(eq, x, theta, sigma, chunk=None, refined=True, phi=None) -> tuple:
    """The factor ``(scale, R)`` of the equations of ``x`` whitened by the noise model at ``theta`` (levels
    ``sigma``), WLS's at its weights: a chunk of ``chunk`` samples at a time, or in one block (of their columns
    ``phi``, when built)."""
    def blocks():
        if phi is not None:
            return iter([_split(_whitened(_equation_whitener(eq, x, theta, sigma), phi))])
        return (_split(_whitened(_equation_whitener(e, xc, theta, sigma), e.phi(xc))) for _, e, xc in
                _chunks(eq, x, chunk or len(x)))  # fmt: skip

    return _streamed_factor(blocks, eq.p, refined)


def _streamed_wls(eq, x, sigma, theta, chunk, iterations=2):
    """:func:`~spaceid.estimation._estimators._wls`, a factor per iteration."""
    for _ in range(iterations):
        theta = _solve_factor(*weighted_factor(eq, x, theta, sigma, chunk)[::-1])[0]
    return theta, {"iterations": iterations}


def _streamed_iv(eq, x, theta, ctx, chunk, iterations=2):
    """:func:`~spaceid.estimation._estimators._iv`: least squares of the column-scaled ``A`` in the
    orthonormal basis ``Q_Z`` of the scaled instruments ``Z_s``, read from the factor of
    ``[Z_s | A_s | b]``, whose blocks right of ``R_ZZ`` are ``Q_Z^T A_s`` and ``Q_Z^T b`` (as
    accurate as the in-memory products with ``Q_Z``)."""
    scale, p = ctx.factor[0], eq.p
    q, qd = ctx.reference

    def blocks(theta):
        for rows, e, xc in _chunks(eq, x, chunk):
            A, b = _split(e.phi(xc))
            yield np.hstack([_instrument_rows(e, xc, theta, (q[rows], qd[rows])), A]) / np.append(scale, scale), b

    for _ in range(iterations):
        R = _accumulated_factor(blocks(theta))
        with one_blas_thread():
            theta_z, theta = theta, np.linalg.lstsq(R[:p, p:-1], R[:p, -1], rcond=None)[0] / scale
            cross = R[:p, :p].T @ R[:p, p:-1]  # Z_s^T A_s, the bread of the covariance
    return theta, {"iterations": iterations, "instruments": ctx.instruments, "cross": cross, "theta_z": theta_z}


def _streamed_ml(eq, x, sigma, theta, chunk):
    """:func:`~spaceid.estimation._estimators._ml_fit` with every evaluation a pass over the chunks:
    each chunk's columns are built for its part of the gradient and dropped."""

    def evaluate(estimate, previous, gradient):  # the signal Jacobians are recomputed, not kept
        return _ml_evaluate(eq, x, estimate, sigma, chunk, lambda rows, e, xc: e.phi(xc), previous, gradient,
                            keep_jacobian=False)

    def factor(L, single=False):  # the preconditioner and the bread, as in memory: no refined solution needed
        G = functools.reduce(np.add, (_whitened_gram(L[rows], e.phi(xc), single) for rows, e, xc in
                                      _chunks(eq, x, chunk)))  # fmt: skip
        if single:
            return _gram_matrix_factor(G, limit=SINGLE_COND)
        blocks = lambda: (_split(_whitened(L[rows], e.phi(xc))) for rows, e, xc in _chunks(eq, x, chunk))  # noqa: E731
        return _streamed_factor(blocks, eq.p, refined=False, gram=G)

    return _ml_fit(x, theta, evaluate, factor, lambda: _streamed_wls(eq, x, sigma, theta, chunk)[0])


def streamed_estimate(eq, x, sigma, theta, estimator, ctx, chunk):
    """``theta`` and the estimator's record of ``estimator`` (``wls``, ``iv`` or ``ml``) from the OLS ``theta``."""
    if estimator == "wls":
        return _streamed_wls(eq, x, sigma, theta, chunk)
    if estimator == "ml":
        return _streamed_ml(eq, x, sigma, theta, chunk)
    return _streamed_iv(eq, x, theta, ctx, chunk)


def _residual_pass(eq, x, sigma, theta, estimator, info, ctx, chunk) -> tuple:
    """The residuals ``r (n, rows)``, the whiteners ``L (n, rows, rows)`` (None for ``ols``) and the
    bread of the covariance, in one pass (for ``wls`` with the factor of its whitened equations)."""
    n, rows = len(x), eq.param.rows
    r = np.empty((n, rows))
    L = None if estimator == "ols" else np.empty((n, rows, rows))

    def blocks():
        for sl, e, xc in _chunks(eq, x, chunk):
            phi = e.phi(xc)
            r[sl] = equation_residuals(phi, theta)
            if L is not None:
                L[sl] = _equation_whitener(e, xc, theta, sigma)
            if estimator == "wls":
                yield _split(_whitened(L[sl], phi))

    if estimator == "wls":  # the first pass fills r and L; a fallback to TSQR passes again
        return r, L, _solve_factor(*_streamed_factor(blocks, eq.p, refined=False)[::-1])[1]
    for _ in blocks():
        pass
    scale = ctx.factor[0]
    return r, L, (info.pop("ginv") if estimator == "ols" else np.linalg.inv(info.pop("cross")) / np.outer(scale, scale))


def streamed_covariance(eq, x, sigma, theta, estimator, info, ctx, log, estimated, chunk):
    """:func:`~spaceid.estimation._uncertainty._reported_covariance` from the residuals and whiteners
    (a pass, :func:`_residual_pass`; ML brings them and the factor of its whitened equations from its
    last evaluation) and, when the covariance follows the residuals or is the instruments' sandwich,
    a pass for the Newey-West sum of the scores or the sandwich (see
    :func:`~spaceid.estimation._uncertainty._covariance_terms` for ``M`` and the scored residuals), and
    one for the propagated covariance of differentiated rates. The whiteners stay in ``info["whitener"]``
    for the drift test."""
    if estimator == "ml":  # its whitener stays for the drift test, its factor for the directions' ratios
        L, r = info["whitener"], info.pop("residuals")
        info["whitened_factor"] = info.pop("factor")
        bread = _solve_factor(*info["whitened_factor"][::-1])[1]
    else:
        r, L, bread = _residual_pass(eq, x, sigma, theta, estimator, info, ctx, chunk)
        if L is not None:  # the drift test whitens by the same factors: not formed again
            info["whitener"] = L
    white = None if L is None else _whitened(L, r[..., None])[..., 0]
    chi2, checks, choice = _covariance_choice(eq, r, white, estimator, log, estimated)
    q, qd = ctx.reference or (None, None)
    theta_z = info.pop("theta_z", None)

    def influence():  # M_c of each chunk, its samples and their equations
        for sl, e, xc in _chunks(eq, x, chunk):
            if estimator == "iv":
                yield sl, _instrument_rows(e, xc, theta_z, (q[sl], qd[sl])).reshape(-1, eq.param.rows, eq.p), e, xc
            else:
                yield sl, e.phi(xc)[..., :-1], e, xc

    if choice["covariance_from_residuals"]:
        scored = _inverse_times(L, r[..., None])[..., 0] if estimator in WEIGHTED else r
        cov_t = _hac((_mapped_scores(bread, M, scored[sl]) for sl, M, _, _ in influence()), choice["bandwidth"], eq.p)
        cov_t = _with_propagated(cov_t, choice, log, estimator, bread, sigma, lambda: (
            (sl, M, None if L is None else L[sl], e.jacobian(xc, theta)) for sl, M, e, xc in influence()))
    elif estimator in WEIGHTED:  # the noise model's sandwich is the bread (_model_covariance)
        cov_t = bread * choice["variance_factor"]
    else:
        cov_t = sum(_sandwich(bread, M, L[sl]) for sl, M, _, _ in influence()) * choice["variance_factor"]
    return cov_t, float(np.sqrt(np.mean(r**2))), _covariance_record(chi2, checks, choice, log, estimated)
