"""Excitation criteria: functions of the stacked regressor that the design minimises, and the
noise-whitened regressor that two of them are meant for.

A criterion (:class:`Criterion`) is the maximum of a few smooth *pieces* of the stacked
regressor ``Y`` (n_rows, k); it supplies their gradients in ``Y`` (``adjoint``: ``d sigma_i =
u_i^T dY v_i`` for singular values), which the design pulls back to the Fourier coefficients,
and a smooth surrogate of increasing sharpness for the trust-region search. :data:`CRITERIA`:

* ``cond``: the paper's condition number of Y (as log cond, the max over the two largest and
  the two smallest singular values of ``log s_i - log s_j``);
* ``logdet``: log det of Y with unit-norm columns (scale-free);
* ``dopt`` and ``crb``, which know the measurement noise: on the regressor whitened sample by
  sample by the covariance of its equation error and scaled by the nominal ``|pi|``
  (:class:`whitened_regressor`), whose Gram matrix is the Fisher information of the
  errors-in-variables model (docs/theory/noise.md), ``dopt`` maximises its log det and ``crb``
  minimises the trace of its inverse, the sum of the parameters' relative Cramer-Rao
  variances. cond(Y) ignores which signals are noisy and how the noise reaches each equation;
  these weigh the samples by it.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
import scipy.linalg
from scipy.special import logsumexp, softmax

from .._errors import SpaceidError
from .._svd import svd
from ..estimation import equation_covariance, signal_jacobian, signal_sigma

__all__ = ["Criterion", "CRITERIA", "whitened_regressor"]


# -- the criteria -------------------------------------------------------------------------------


def _log_sigma_and_derivatives(Y, dY):
    """Log singular values of ``Y (r, k)`` and their derivatives along ``dY (p, r, k)``.

    Returns ``log_s (k,)`` (descending) and ``dlog_s (p, k)``, from ``d s_i = u_i^T dY v_i``.
    """
    U, s, Vt = svd(Y, full_matrices=False)
    ds = np.sum((dY @ Vt.T) * U, axis=-2)
    return np.log(s), ds / s


def _cond_pieces(Y, dY=None):
    """log cond(Y) as the max of ``log s_i - log s_j`` over the two largest i, two smallest j.

    Each piece is smooth where the singular values are distinct; their maximum is the log
    condition number, smooth in epigraph form even where s_1 = s_2 or s_k-1 = s_k.
    """
    if dY is None:
        log_s = np.log(svd(Y, compute_uv=False))
        return (log_s[..., :2, None] - log_s[..., None, -2:]).reshape(*Y.shape[:-2], -1)
    log_s, dlog_s = _log_sigma_and_derivatives(Y, dY)
    pieces = (log_s[:2, None] - log_s[None, -2:]).ravel()
    jac = (dlog_s[:, :2, None] - dlog_s[:, None, -2:]).reshape(len(dY), -1).T
    return pieces, jac


def _cond_adjoint(Y):
    """The pieces of :func:`_cond_pieces` and their gradients ``W (n_pieces, n_rows, k)`` with
    respect to ``Y``: ``d piece = <W, dY>``, from ``d log s_i = u_i^T dY v_i / s_i``."""
    U, s, Vt = svd(Y, full_matrices=False)
    top, bottom = np.arange(min(2, len(s))), np.arange(max(len(s) - 2, 0), len(s))
    ends = np.concatenate([top, bottom])
    G = U[:, ends].T[:, :, None] * (Vt[ends] / s[ends, None])[:, None, :]  # d log s_i / dY
    with np.errstate(divide="ignore"):
        log_s = np.log(s[ends])
    t = len(top)
    pieces = (log_s[:t, None] - log_s[None, t:]).ravel()
    return pieces, (G[:t, None] - G[None, t:]).reshape(len(pieces), *Y.shape)


def _dopt_adjoint(Y):
    """``-log det(Y^T Y)`` (one piece) and its gradient ``W (1, n_rows, k)`` w.r.t. ``Y``:
    ``d log det(Y^T Y) = 2 <Y^+T, dY>``, ``Y^+T = U diag(1/s) V^T``."""
    U, s, Vt = svd(Y, full_matrices=False)
    return np.array([-2 * np.log(s).sum()]), (-2 * (U / s) @ Vt)[None]


def _logdet_adjoint(Y):
    """The piece of :func:`_logdet_pieces` and its gradient ``W (1, n_rows, k)`` w.r.t. ``Y``:
    :func:`_dopt_adjoint` of ``Yn``, pulled back through the column normalisation."""
    norms = np.linalg.norm(Y, axis=-2, keepdims=True)
    Yn = Y / norms
    pieces, G = _dopt_adjoint(Yn)
    return pieces, (G - Yn * np.sum(G * Yn, axis=-2)) / norms


def _cond_smooth(Y, p):
    """Smooth surrogate of log cond(Y) and its gradient ``W (n_rows, k)`` with respect to Y.

    ``log M_p(s) - log M_-p(s)`` with ``M_p`` the power mean of the singular values: it tends
    to log cond from below as p grows and is within ``2 log(k) / p`` of it. Every singular
    value pulls on it (weights softmax(+-p log s)), so a search lifts the whole lower end of
    the spectrum at once instead of the smallest value alone, which for a spectrum that decays
    smoothly over many decades (spatial arms) only hands the minimum on to the next one.
    """
    if p == 2:
        return _trace_gap(Y, gradient=True)
    U, s, Vt = svd(Y, full_matrices=False)
    if not s[-1] > 0:
        return np.inf, np.zeros_like(Y)
    ls = np.log(s)
    return _power_mean_gap(ls, p), (U * ((softmax(p * ls) - softmax(-p * ls)) / s)) @ Vt


def _cond_smooth_value(Y, p):
    """The value of :func:`_cond_smooth` alone for ``Y`` (..., n_rows, k): (...), from the
    singular values (a third of the cost of the SVD with vectors); inf where singular."""
    if p == 2:
        Ys = np.reshape(Y, (-1, *np.shape(Y)[-2:]))
        return np.array([_trace_gap(y) for y in Ys]).reshape(np.shape(Y)[:-2])
    s = svd(Y, compute_uv=False)
    with np.errstate(divide="ignore"):
        return np.where(s[..., -1] > 0, _power_mean_gap(np.log(s), p), np.inf)


def _trace_gap(Y, *, gradient=False):
    """:func:`_cond_smooth` at p = 2 for one ``Y`` (n_rows, k), without an SVD: the value
    ``(log tr G + log tr G^-1) / 2 - log k``, ``G = Y^T Y``, and, if ``gradient``, its gradient
    ``Y / tr G - Y G^-2 / tr G^-1`` w.r.t. Y; inf (and a zero gradient) where singular.

    With ``Y = Q R``: ``tr G = |Y|_F^2``, ``G^-1 = R^-1 R^-T`` and ``Y G^-2 = Q R^-T G^-1``, as
    accurate as the SVD (relative error about eps cond(Y)) at 55 % of its cost with vectors and
    65 % without (servicer, 1200 x 496). ``Y G^-2`` as ``Y (G^-1 G^-1)`` instead loses the
    gradient along the large singular values (a factor cond(Y) more error: the model's gradient
    had the wrong sign at cond 6e10). The trust-region search spends its first stage, and on
    large problems its whole time budget, at p = 2.
    """
    if gradient:
        Q, R = scipy.linalg.qr(Y, mode="economic", check_finite=False)
    else:
        R = scipy.linalg.qr(Y, mode="r", check_finite=False)[0][: Y.shape[1]]
    R_inv, info = scipy.linalg.lapack.dtrtri(R)
    if info != 0 or not np.all(np.isfinite(R_inv)):
        return (np.inf, np.zeros_like(Y)) if gradient else np.inf
    G_inv = R_inv @ R_inv.T
    tr, tr_inv = np.sum(Y * Y), np.trace(G_inv)
    value = (np.log(tr) + np.log(tr_inv)) / 2 - np.log(Y.shape[1])
    return (value, Y / tr - Q @ (R_inv.T @ G_inv) / tr_inv) if gradient else value


def _power_mean_gap(ls, p):
    """``log M_p(s) - log M_-p(s)`` from ``ls = log s`` (..., k): (...)."""
    return (logsumexp(p * ls, -1) + logsumexp(-p * ls, -1) - 2 * np.log(ls.shape[-1])) / p


def _logdet_smooth(Y, p):
    """The logdet criterion is smooth already: its value and gradient, ``p`` unused."""
    pieces, W = _logdet_adjoint(Y)
    return pieces[0], W[0]


def _dopt_pieces(Y, dY=None):
    """``-log det(Y^T Y)``, one piece: D-optimality for ``Y`` the whitened, pi-scaled
    regressor (:class:`whitened_regressor`), whose ``Y^T Y`` is the Fisher information."""
    if dY is None:
        return -2 * np.log(svd(Y, compute_uv=False)).sum(-1, keepdims=True)
    log_s, dlog_s = _log_sigma_and_derivatives(Y, dY)
    return np.array([-2 * log_s.sum()]), -2 * dlog_s.sum(-1)[None, :]


def _logdet_pieces(Y, dY=None):
    """``-log det(Yn^T Yn)``, ``Yn`` = Y with unit-norm columns; one piece. Scale-free: it
    rewards independent columns, not their size (for that, ``dopt`` on the whitened Y)."""
    norms = np.linalg.norm(Y, axis=-2, keepdims=True)
    Yn = Y / norms
    if dY is None:
        return _dopt_pieces(Yn)
    # d(y / |y|) = dy / |y| - y (y . dy) / |y|^3, column by column
    return _dopt_pieces(Yn, dY / norms - Yn * (np.sum(Yn * dY, axis=-2, keepdims=True) / norms))


def _crb_pieces(Y, dY=None):
    """``log tr((Y^T Y)^-1)``, one piece: A-optimality for ``Y`` the whitened, pi-scaled
    regressor, whose ``(Y^T Y)^-1`` is the relative Cramer-Rao bound. In log, as SLSQP's
    tolerance is absolute and the trace spans decades with the noise level.

    ``tr = sum s_i^-2``, so ``d log tr = -2 sum s_i^-2 d log s_i / tr``.
    """
    if dY is None:
        s = svd(Y, compute_uv=False)
        return np.log(np.sum(s**-2.0, -1, keepdims=True))
    log_s, dlog_s = _log_sigma_and_derivatives(Y, dY)
    w = np.exp(-2 * log_s)
    return np.array([np.log(w.sum())]), (-2 * dlog_s @ w / w.sum())[None, :]


def _crb_adjoint(Y):
    """The piece of :func:`_crb_pieces` and its gradient ``W (1, n_rows, k)`` w.r.t. ``Y``:
    ``d tr(G^-1) = -tr(G^-1 dG G^-1) = <-2 Y G^-2, dY>`` for ``G = Y^T Y``, and
    ``Y G^-2 = U diag(s^-3) V^T``; divided by the trace for the log."""
    U, s, Vt = svd(Y, full_matrices=False)
    tr = np.sum(s**-2.0)
    return np.array([np.log(tr)]), (-2 / tr * (U * s**-3.0) @ Vt)[None]


@dataclass(frozen=True)
class Criterion:
    """An excitation criterion: the maximum of smooth pieces of the regressor, minimised.

    Attributes
    ----------
    name : str
    pieces : callable
        ``pieces(Y)`` with ``Y`` of shape (..., n_rows, k) returns (..., n_pieces);
        ``pieces(Y, dY)`` with ``Y`` (n_rows, k) and directions ``dY`` (p, n_rows, k) returns
        the pieces (n_pieces,) and their derivatives (n_pieces, p).
    report : callable
        Maps the objective (the max of the pieces) to the reported value.
    adjoint : callable, optional
        ``adjoint(Y)`` with ``Y`` (n_rows, k) returns the pieces (n_pieces,) and their
        gradients with respect to ``Y``, ``W`` (n_pieces, n_rows, k): ``d piece = <W, dY>``.
        The design uses it when given (it needs no directions ``dY``, so the gradient costs
        O(n_joints) regressor evaluations), else ``pieces(Y, dY)``. The trust-region search
        needs it.
    smooth : callable, optional
        ``smooth(Y, p)`` returns a smooth surrogate of the objective (the max of the pieces)
        that tends to it as ``p`` grows, and its gradient ``W`` (n_rows, k) with respect to
        ``Y``; for the trust-region search. Default: the log-sum-exp of the pieces.
    smooth_value : callable, optional
        ``smooth_value(Y, p)`` with ``Y`` (..., n_rows, k): the value of ``smooth`` alone,
        (...), cheaper than with its gradient. Default: ``smooth(Y, p)[0]`` matrix by matrix,
        or the log-sum-exp of ``pieces(Y)``.
    noise_aware : bool
        The criterion is meant for the whitened, pi-scaled regressor
        (:class:`whitened_regressor`), whose Gram matrix is the Fisher information:
        :func:`design_excitation` then needs a noise model and builds that regressor.
    """

    name: str
    pieces: Callable
    report: Callable
    adjoint: Callable | None = None
    smooth: Callable | None = None
    smooth_value: Callable | None = None
    noise_aware: bool = False

    def smoothed(self, Y, p):
        """A smooth surrogate of the objective, sharper as ``p`` grows, and its gradient W
        w.r.t. ``Y``: ``smooth(Y, p)`` if given, else the log-sum-exp of the pieces."""
        if self.smooth is not None:
            return self.smooth(Y, p)
        pieces, W = self.adjoint(Y)
        if not np.all(np.isfinite(pieces)):
            return np.inf, np.zeros_like(Y)
        return logsumexp(p * pieces) / p, np.tensordot(softmax(p * pieces), W, 1)

    def smoothed_value(self, Y, p):
        """The surrogate of :meth:`smoothed` alone, for ``Y`` (..., n_rows, k): (...)."""
        if self.smooth_value is not None:
            return self.smooth_value(Y, p)
        if self.smooth is not None:
            Ys = np.reshape(Y, (-1, *np.shape(Y)[-2:]))
            return np.array([self.smooth(y, p)[0] for y in Ys]).reshape(np.shape(Y)[:-2])
        pieces = self.pieces(Y)
        return np.where(np.all(np.isfinite(pieces), -1), logsumexp(p * pieces, -1) / p, np.inf)


CRITERIA = {
    "cond": Criterion("cond", _cond_pieces, np.exp, _cond_adjoint, _cond_smooth,  # lower: better
                      _cond_smooth_value),
    "logdet": Criterion("logdet", _logdet_pieces, np.negative, _logdet_adjoint, _logdet_smooth),
    # on the whitened, pi-scaled regressor: log det of the relative Fisher information (higher:
    # better) and the trace of the relative Cramer-Rao bound (sum of relative variances)
    "dopt": Criterion("dopt", _dopt_pieces, np.negative, _dopt_adjoint, noise_aware=True),
    "crb": Criterion("crb", _crb_pieces, np.exp, _crb_adjoint, noise_aware=True),
}
"""Criteria by name. Another one is one more entry."""


def _criterion_named(name):
    """``CRITERIA[name]``, or an error that lists the choices."""
    if name not in CRITERIA:
        raise SpaceidError(f"`criterion` must be one of {', '.join(CRITERIA)}, got {name!r}")
    return CRITERIA[name]


# -- the noise-aware regressor ------------------------------------------------------------------


class whitened_regressor:  # noqa: N801 - used like a function; a class so it pickles
    """Stacked regressor of a joint motion, whitened by the covariance of its equation errors:
    its Gram matrix is the Fisher information of the errors-in-variables model.

    ``whitened_regressor(param, pi, momentum, noise)(q, qd)`` with ``q, qd`` of shape
    ``(..., n_samples, n_joints)`` [rad, rad/s] returns ``Yw (..., n_samples * rows, k)``:
    sample n's rows ``Y_n`` of :class:`~spaceid.dynamics.excitation_regressor` (base rate
    from momentum conservation) times ``L_n^-1``, where ``L_n L_n^T = S_n = J_n diag(sigma^2)
    J_n^T`` is the first-order covariance of the equation error (:mod:`spaceid.estimation`) at
    ``pi`` and the motion's own base rate. So ``Yw^T Yw = sum_n Y_n^T S_n^-1 Y_n`` is the
    Fisher information of ``pi`` and its inverse the Cramer-Rao (KCR) bound; with
    ``relative``, column i is also scaled by ``|pi_i|``, which makes the bound that of
    ``pi_i / |pi_i|``: relative variances.

    Parameters
    ----------
    param : Parameterization
    pi : array_like of shape (k,)
        Nominal parameters: where ``S_n`` and the bound are evaluated, and the scale of
        ``relative``.
    momentum : array_like of shape (3,)
        Angular momentum [N m s], taken in base axes at every sample (as excitation_regressor).
    noise : Noise
        Standard deviations of the measured signals; not all zero.
    relative : bool
        Scale column i by ``|pi_i|`` (then every ``pi_i`` must be nonzero).

    Attributes
    ----------
    fd_step : float
        Step [rad, rad/s] of the design's central differences of this callable (see
        ``_ExcitationProblem.linearize_regressor``). When ``S_n`` held central differences in q
        of step ``noise.FD_STEP`` (it is analytic now), their round-off (about 1e-11 relative)
        and the design's default step of 1e-6 gave errors of 4e-5 in ``dYw/dq`` and 2e-6 in the
        gradients of ``crb`` and ``dopt`` (cepheus, against 5-point differences of step 1e-3);
        a step of 1e-4 gives 3e-7 and 1e-7 (tests/test_design.py checks it).
    """

    fd_step = 1e-4

    def __init__(self, param, pi, momentum, noise, *, relative=True):
        from ..dynamics import excitation_regressor

        if noise.is_zero:
            raise SpaceidError(
                "`noise`: every standard deviation is zero, so the Fisher information is "
                "unbounded; give at least one of `noise.angle`, `noise.rate`, `noise.base_rate`"
            )
        self.base = excitation_regressor(param, pi, momentum)
        self.noise, self.sigma = noise, signal_sigma(param, noise)
        pi = self.base.pi
        self.scale = np.abs(pi) if relative else np.ones_like(pi)
        if not np.all(self.scale > 0):
            zero = ", ".join(n for n, v in zip(param.names, self.scale) if not v > 0)
            raise SpaceidError(
                f"relative Cramer-Rao bound: nominal value zero for {zero}; use an absolute "
                "criterion (cond or logdet) for this model"
            )

    def __call__(self, q, qd):
        q, qd = np.asarray(q, float), np.asarray(qd, float)
        base = self.base
        Y, w0 = base.with_rate(q, qd)  # (..., n_samples, rows, k), (..., n_samples, 3)
        nj = q.shape[-1]
        jac = signal_jacobian(base.param, base.pi, q.reshape(-1, nj), qd.reshape(-1, nj),
                              w0.reshape(-1, 3), base.momentum)  # fmt: skip
        S = equation_covariance(jac, self.sigma).reshape(*Y.shape[:-1], Y.shape[-2])
        try:
            L = np.linalg.cholesky(S)
        except np.linalg.LinAlgError:
            raise SpaceidError(
                "`noise`: the equation-error covariance is singular at some sample (the noisy "
                "signals do not reach every equation); give a nonzero `noise.base_rate`"
            ) from None
        Yw = np.linalg.solve(L, Y) * self.scale
        return Yw.reshape(*Yw.shape[:-3], -1, Yw.shape[-1])

    def crb(self, q, qd):
        """Cramer-Rao bound of ``pi`` (k, k) for the samples ``q, qd (n_samples, n_joints)``:
        ``(Yw^T Yw)^-1``; of ``pi / |pi|`` (relative) if ``relative``."""
        Yw = self(q, qd)
        return np.linalg.inv(Yw.T @ Yw)

