"""Optimal excitation: choose the Fourier coefficients of Eq. 12 for a well-conditioned regressor.

The free coefficients ``X = [a | b]`` of :class:`~spaceid.motion.FourierTrajectory` are
searched in scaled variables ``z`` (``X = S * z``, with ``S`` such that ``|z_jk| = 1`` alone
takes joint j to its tightest limit). q, qd and qdd are affine in ``z``, so the joint limits,
imposed on a fine time grid, are linear inequalities, and separate by joint. Results are scaled
into the limits at all times: the grid's peaks are refined between its points (a trigonometric
sum, unimodal there), as the signals exceed their grid values by up to 3e-4 of a limit.

Criteria (:data:`CRITERIA`): the paper's cond(Y); log det of Y with unit-norm columns; and two
that know the measurement noise, on the regressor whitened sample by sample by the covariance
of its equation error and scaled by the nominal ``|pi|`` (:class:`whitened_regressor`), whose
Gram matrix is the Fisher information of the errors-in-variables model (MATH.md section 6):
``dopt`` maximises its log det, ``crb`` minimises the trace of its inverse, the sum of the
parameters' relative Cramer-Rao variances. cond(Y) ignores which signals are noisy and how the
noise reaches each equation; these weigh the samples by it.

Gradients: the rows of sample t of the stacked regressor ``Y`` depend on q(t), qd(t) alone, so
central differences of the joint signals (4 n_joints perturbed trajectories; the trust-region
model takes 2 n_joints forward ones) give ``dY/dq_j``, ``dY/dqd_j`` at every sample, and the
chain rule through the fixed Fourier basis gives the gradient in all n = 2 Nf n_joints
coefficients. A criterion supplies its gradient in ``Y`` (``d sigma_i = u_i^T dY v_i`` for
singular values), never ``dY`` along each coefficient.

Two local searches (``method``):

* ``slsqp`` (small regressors: planar arms). A criterion is the maximum of a few smooth
  *pieces* of ``Y``; SLSQP minimises ``tau`` subject to ``piece(z) <= tau`` and the limits. This
  epigraph form keeps the condition number smooth where its extreme singular values coalesce,
  which they do at the optimum. Each search imposes the limits on a coarse grid, then on the
  fine-grid points near the peaks of the signals, and is scaled back into the limits; the
  best two results are polished with all fine-grid limits that can become active.
* ``trust-region`` (spatial systems: a hundred or more columns, a spectrum that decays smoothly
  over decades, and a regressor costing tens of microseconds a sample). Each joint is kept on
  its limits by a radial map, so the search is unconstrained; the criterion is replaced by a
  smooth surrogate whose sharpness rises in stages; each step linearises ``Y`` in the joint
  signals and minimises the surrogate of that model (exact in the singular values, one SVD an
  evaluation, no regressor call) in a trust region. Many screened starts get a few steps, the
  best few the rest (successive halving), each continuing where its first round ended.

The global search runs the local searches from seeded random starts, in worker processes.

References
----------
Papadopoulos et al., identification of free-floating space robots from angular momentum
conservation, Eq. 12 (MATH.md section 3).
"""

from __future__ import annotations

import contextlib
import os
import pickle
import time
from collections.abc import Callable
from concurrent.futures import FIRST_COMPLETED, ProcessPoolExecutor, wait
from dataclasses import dataclass, field, replace
from functools import cached_property

import numpy as np
from scipy.optimize import Bounds, minimize
from scipy.special import logsumexp, softmax
from threadpoolctl import threadpool_limits

from .._errors import SpaceidError
from ..estimation import Noise, equation_covariance, signal_jacobian, signal_sigma
from ._trajectory import (
    BOUNDARY_FIELDS,
    FourierTrajectory,
    boundary_quintic,
    fourier_basis,
    sample_times,
)

__all__ = ["Criterion", "CRITERIA", "DesignResult", "optimize_excitation", "design_excitation",
           "whitened_regressor"]


# -- criteria ---------------------------------------------------------------------------------


def _dlog_sigma(Y, dY):
    """Log singular values of ``Y (r, k)`` and their derivatives along ``dY (p, r, k)``.

    Returns ``log_s (k,)`` (descending) and ``dlog_s (p, k)``, from ``d s_i = u_i^T dY v_i``.
    """
    U, s, Vt = np.linalg.svd(Y, full_matrices=False)
    ds = np.sum((dY @ Vt.T) * U, axis=-2)
    return np.log(s), ds / s


def _cond_pieces(Y, dY=None):
    """log cond(Y) as the max of ``log s_i - log s_j`` over the two largest i, two smallest j.

    Each piece is smooth where the singular values are distinct; their maximum is the log
    condition number, smooth in epigraph form even where s_1 = s_2 or s_k-1 = s_k.
    """
    if dY is None:
        log_s = np.log(np.linalg.svd(Y, compute_uv=False))
        return (log_s[..., :2, None] - log_s[..., None, -2:]).reshape(*Y.shape[:-2], -1)
    log_s, dlog_s = _dlog_sigma(Y, dY)
    pieces = (log_s[:2, None] - log_s[None, -2:]).ravel()
    jac = (dlog_s[:, :2, None] - dlog_s[:, None, -2:]).reshape(len(dY), -1).T
    return pieces, jac


def _cond_adjoint(Y):
    """The pieces of :func:`_cond_pieces` and their gradients ``W (n_pieces, n_rows, k)`` with
    respect to ``Y``: ``d piece = <W, dY>``, from ``d log s_i = u_i^T dY v_i / s_i``."""
    U, s, Vt = np.linalg.svd(Y, full_matrices=False)
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
    U, s, Vt = np.linalg.svd(Y, full_matrices=False)
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
    U, s, Vt = np.linalg.svd(Y, full_matrices=False)
    if not s[-1] > 0:
        return np.inf, np.zeros_like(Y)
    ls = np.log(s)
    return _power_mean_gap(ls, p), (U * ((softmax(p * ls) - softmax(-p * ls)) / s)) @ Vt


def _cond_smooth_value(Y, p):
    """The value of :func:`_cond_smooth` alone for ``Y`` (..., n_rows, k): (...), from the
    singular values (a third of the cost of the SVD with vectors); inf where singular."""
    s = np.linalg.svd(Y, compute_uv=False)
    with np.errstate(divide="ignore"):
        return np.where(s[..., -1] > 0, _power_mean_gap(np.log(s), p), np.inf)


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
        return -2 * np.log(np.linalg.svd(Y, compute_uv=False)).sum(-1, keepdims=True)
    log_s, dlog_s = _dlog_sigma(Y, dY)
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
        s = np.linalg.svd(Y, compute_uv=False)
        return np.log(np.sum(s**-2.0, -1, keepdims=True))
    log_s, dlog_s = _dlog_sigma(Y, dY)
    w = np.exp(-2 * log_s)
    return np.array([np.log(w.sum())]), (-2 * dlog_s @ w / w.sum())[None, :]


def _crb_adjoint(Y):
    """The piece of :func:`_crb_pieces` and its gradient ``W (1, n_rows, k)`` w.r.t. ``Y``:
    ``d tr(G^-1) = -tr(G^-1 dG G^-1) = <-2 Y G^-2, dY>`` for ``G = Y^T Y``, and
    ``Y G^-2 = U diag(s^-3) V^T``; divided by the trace for the log."""
    U, s, Vt = np.linalg.svd(Y, full_matrices=False)
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


def _criterion(name):
    """``CRITERIA[name]``, or an error that lists the choices."""
    if name not in CRITERIA:
        raise SpaceidError(f"criterion must be one of {', '.join(CRITERIA)}, got {name!r}")
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
        ``_Problem.jet``). ``S_n`` holds central differences in q of step
        ``noise.FD_STEP``, whose round-off (about 1e-11 relative) the design's default step
        of 1e-6 turns into errors of 4e-5 in ``dYw/dq`` and 2e-6 in the gradients of ``crb``
        and ``dopt`` (cepheus, against 5-point differences of step 1e-3); a step of 1e-4
        gives 3e-7 and 1e-7 (tests/test_design.py checks it).
    """

    fd_step = 1e-4

    def __init__(self, param, pi, momentum, noise, *, relative=True):
        from ..dynamics import excitation_regressor

        if noise.is_zero:
            raise SpaceidError(
                "noise: every standard deviation is zero, so the Fisher information is "
                "unbounded; give at least one of --noise-angle, --noise-rate, --noise-base-rate"
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
                "noise: the equation-error covariance is singular at some sample (the noisy "
                "signals do not reach every equation); give a nonzero --noise-base-rate"
            ) from None
        Yw = np.linalg.solve(L, Y) * self.scale
        return Yw.reshape(*Yw.shape[:-3], -1, Yw.shape[-1])

    def crb(self, q, qd):
        """Cramer-Rao bound of ``pi`` (k, k) for the samples ``q, qd (n_samples, n_joints)``:
        ``(Yw^T Yw)^-1``; of ``pi / |pi|`` (relative) if ``relative``."""
        Yw = self(q, qd)
        return np.linalg.inv(Yw.T @ Yw)


# -- the problem in scaled variables ------------------------------------------------------------

# Samples a regressor call of the search: larger calls run out of cache (3 to 4 times slower a
# sample for 169 x 120 samples of a 7-joint arm)
_CALL_SAMPLES = 512


@dataclass(frozen=True)
class _Problem:
    """What a local search needs; picklable, sent once to each worker process.

    ``z`` (..., n) are scaled coefficients, ``X = S * z.reshape(..., n_joints, K)``, n = n_joints K.
    q, qd, qdd on the fine grid are ``B @ X.T + P`` (3, n_grid, n_joints), limits ``L``.
    """

    regressor: Callable
    criterion: str
    S: np.ndarray  # (n_joints, K)
    B_samples: np.ndarray  # (2, n_samples, K): q, qd basis at the samples
    P_samples: np.ndarray  # (2, n_samples, n_joints)
    B: np.ndarray  # (3, n_grid, K)
    P: np.ndarray  # (3, n_grid, n_joints)
    L: np.ndarray  # (3, n_joints)
    coarse: np.ndarray  # fine-grid time indices constrained during the search
    duration: float  # [s]; the fine grid spans [0, duration]
    boundary: np.ndarray  # (6, n_joints), BOUNDARY_FIELDS order: P at any time
    # finite-difference step in q [rad] and qd [rad/s]; a regressor may ask for another one
    # by an ``fd_step`` attribute (see whitened_regressor)
    step: float = 1e-6
    # Trust-region search. Surrogate sharpness by stage: p = 2 lifts the whole lower spectrum
    # and makes most of the gain; 8 and 32 close in on the criterion (within 2 log(k) / p).
    stages: tuple = (2.0, 8.0, 32.0)
    # Gauge: a 64-norm over the fine grid exceeds the max by a few % (a few points near a peak)
    sharpness: float = 64.0
    # L-BFGS-B iterations on the model a step, their SVDs about one jet. Servicer, one search:
    # 30 took 2.5 times as long as 10 to reach cond 5e7; 20 led 10 from 2 minutes on (1e6
    # against 1.8e6 at 200 s), 10 led before
    inner: int = 15
    tr_tol: float = 1e-3  # two steps in a row gaining less (in log) end a stage
    # First trust region: half-width tr_radius / K in z, so that a joint's signals move by at
    # most tr_radius limits (a fixed 0.25 lost the first step of every servicer search, K = 24)
    tr_radius: float = 1.5

    @property
    def n(self):
        return self.S.size

    def X(self, z):
        return self.S * np.reshape(z, (*np.shape(z)[:-1], *self.S.shape))

    def stacked(self, Z):
        """Stacked regressors of scaled coefficients ``Z (batch, n)``: (batch, rows, k)."""
        q, qd = np.einsum("dtk,bjk->dbtj", self.B_samples, self.X(Z)) + self.P_samples[:, None]
        return self.regressor(q, qd)

    def objective(self, Z):
        """Objective of scaled coefficients ``Z (batch, n)``: (batch,), inf where singular."""
        with np.errstate(divide="ignore", invalid="ignore"):
            f = CRITERIA[self.criterion].pieces(self.stacked(Z)).max(-1)
        return np.where(np.isnan(f), np.inf, f)

    def jet(self, z, Y0=None, *, central=True):
        """Y at ``z`` (n_rows, k) and its derivatives along the joint signals at every sample,
        ``Gt`` (n_samples, m k, 2 n_joints): ``Gt[t, :, (d, j)]`` is d(rows of sample t) / d q_j
        (d = 0) or d qd_j (d = 1), flattened.

        Sample t's rows of Y depend on q(t), qd(t) alone, so perturbing joint j's signal at all
        samples at once gives them all: 4 n_joints central differences, or 2 n_joints forward
        ones (error O(step), for the trust-region model). ``Y0``, Y at ``z`` if known, saves
        its evaluation.
        """
        x = np.einsum("dtk,jk->dtj", self.B_samples, self.X(z)) + self.P_samples  # q, qd
        nj, n_s = self.S.shape[0], x.shape[1]
        E = self.step * np.eye(2 * nj).reshape(2 * nj, 2, 1, nj)  # signal (d, j), every sample
        signs = (1, -1) if central else (1,)
        group = max(1, _CALL_SAMPLES // (len(signs) * n_s))
        Gt = None
        for c in range(0, 2 * nj, group):
            # Y at z rides with the first call: for small models the per-call cost dominates
            lead = [x[None]] if Y0 is None else []
            X = np.concatenate(lead + [x + sign * E[c : c + group] for sign in signs])
            Y = self.regressor(X[:, 0], X[:, 1])
            if lead:
                Y0, Y = Y[0], Y[1:]
            Y = Y.reshape(len(signs), -1, *Y0.shape)
            G = (Y[0] - Y[1]) / (2 * self.step) if central else (Y[0] - Y0) / self.step
            if Gt is None:
                Gt = np.empty((n_s, Y0.size // n_s, 2 * nj))
            Gt[:, :, c : c + group] = G.reshape(len(G), n_s, -1).transpose(1, 2, 0)
        return Y0, Gt

    def pullback(self, W, Gt):
        """Gradient in ``z`` (n,) of a function of Y with gradient ``W`` (n_rows, k) in Y.

        ``dY/dz_p = dY/dq_j B_q[t, k] S_jk + dY/dqd_j B_qd[t, k] S_jk`` for p = (j, k), so
        the gradient needs only the 2 n_joints signal derivatives ``Gt`` (see :meth:`jet`),
        never the n directional derivatives of Y.
        """
        n_s = Gt.shape[0]
        w = (W.reshape(n_s, 1, -1) @ Gt).reshape(n_s, 2, -1)  # <W_t, dY_t/d(q|qd)_j>
        return (np.einsum("tdj,dtk->jk", w, self.B_samples) * self.S).ravel()

    def linearize(self, z):
        """Pieces at ``z`` and their gradients (n_pieces, n), from one batched regressor call
        of 1 + 4 n_joints trajectories (see :meth:`jet`, :meth:`pullback`)."""
        Y, Gt = self.jet(z)
        crit = CRITERIA[self.criterion]
        if crit.adjoint is not None:
            pieces, W = crit.adjoint(Y)
            return pieces, np.array([self.pullback(w, Gt) for w in W])
        # a criterion without adjoint: the n directional derivatives of Y, explicitly
        n_s, nj = Gt.shape[0], self.S.shape[0]
        G = Gt.reshape(n_s, -1, Y.shape[-1], 2, nj)
        dY = np.einsum("tmkdj,dtl,jl->jltmk", G, self.B_samples, self.S)
        return crit.pieces(Y, dY.reshape(self.n, *Y.shape))

    def signals(self, Z):
        """q, qd, qdd on the fine grid over their limits, shape (..., 3, n_grid, n_joints)."""
        return (np.einsum("dtk,...jk->...dtj", self.B, self.X(Z)) + self.P) / self.L[:, None]

    def shrink(self, Z):
        """``s Z`` with, per row, the largest ``s <= 1`` that keeps the limits at all times
        (:meth:`gauge`): all joints scaled together.

        ``z = 0`` (the boundary quintic alone) is feasible, so such an ``s >= 0`` exists.
        """
        with np.errstate(divide="ignore"):
            return Z * np.minimum(1.0, 1 / self.gauge(Z).max(-1))[..., None]

    def limit_rows(self, mask, z=None):
        """Limits of both signs where ``mask (3, n_grid, n_joints)`` is set, as ``A z <= b``.

        Given ``z``, a limit is left out where the signal at ``z`` is beyond half the opposite
        limit: it lies 1.5 limits away, further than a local refinement moves.
        """
        d, t, j = np.nonzero(mask)
        K = self.S.shape[1]
        A = np.zeros((len(d), self.n))
        np.put_along_axis(A, j[:, None] * K + np.arange(K), self.B[d, t] * self.S[j], axis=1)
        A /= self.L[d, j][:, None]
        p = self.P[d, t, j] / self.L[d, j]
        A, b = np.vstack([A, -A]), np.concatenate([1 - p, 1 + p])
        if z is None:
            return A, b
        v = self.signals(z)[d, t, j]
        keep = np.concatenate([v > -0.5, v < 0.5])
        return A[keep], b[keep]

    def coarse_mask(self):
        mask = np.zeros(self.P.shape, dtype=bool)
        mask[:, self.coarse] = True
        return mask

    def peaks(self, z, *, threshold, width=3):
        """Fine-grid points within ``width`` of a local maximum of |signal| above ``threshold``."""
        v = np.abs(self.signals(z))
        edge = np.full_like(v[:, :1], -np.inf)
        ahead, behind = np.concatenate([v[:, 1:], edge], 1), np.concatenate([edge, v[:, :-1]], 1)
        mask = (v >= ahead) & (v >= behind) & (v >= threshold)
        for shift in range(1, width + 1):
            mask[:, shift:] |= mask[:, :-shift]
            mask[:, :-shift] |= mask[:, shift:]
        return mask

    def local(self, z0, mask, *, ftol, near=False, maxiter=200):
        """SLSQP in epigraph form from ``z0`` under the limits at the fine-grid points ``mask``
        (only those on the side of the signal at ``z0`` where it is large, if ``near``)."""
        A, b = self.limit_rows(mask, z0 if near else None)
        A = np.hstack([A, np.zeros((len(A), 1))])  # variables w = (z, tau)
        n, cache = self.n, {}

        def lin(w):  # SLSQP asks for values and gradients separately: evaluate once
            key = w[:n].tobytes()
            if key not in cache:
                cache.clear()
                cache[key] = self.linearize(w[:n])
            return cache[key]

        def epigraph_jac(w):  # of tau - piece(z) >= 0
            jac = lin(w)[1]
            return np.hstack([-jac, np.ones((len(jac), 1))])

        constraints = [
            {"type": "ineq", "fun": lambda w: w[n] - lin(w)[0], "jac": epigraph_jac},
            {"type": "ineq", "fun": lambda w: b - A @ w, "jac": lambda w: -A},
        ]
        e_tau = np.eye(n + 1)[n]
        with np.errstate(divide="ignore", invalid="ignore"):
            res = minimize(
                lambda w: (w[n], e_tau),
                np.append(z0, lin(np.append(z0, 0.0))[0].max()),
                jac=True,
                method="SLSQP",
                constraints=constraints,
                options={"maxiter": maxiter, "ftol": ftol},
            )
        return res.x[:n] if np.all(np.isfinite(res.x)) else z0

    def search(self, z0, *, ftol=1e-3):
        """One local search: coarse grid, then the fine-grid peaks too, then scaled into the
        limits. Returns ``(z, objective)``."""
        z = self.local(z0, self.coarse_mask(), ftol=ftol)
        mask = self.coarse_mask() | self.peaks(z, threshold=0.8)
        z = self.shrink(self.local(z, mask, ftol=ftol, near=True))
        return z, float(self.objective(z[None])[0])

    def polish(self, z, *, rounds=4):
        """Refine ``z`` under every fine-grid limit that can become active near it."""
        mask = self.coarse_mask()  # keeps the refinement from running off to new peaks
        for _ in range(rounds):
            mask |= self.peaks(z, threshold=0.8)
            z = self.local(z, mask, ftol=1e-8, near=True)
            if np.abs(self.signals(z)).max() <= 1 + 1e-9:
                break
        z = self.shrink(z)
        return z, float(self.objective(z[None])[0])

    def starts(self, rng, m):
        """``m`` random feasible starts (m, n): isotropic random directions, each scaled to a
        random fraction (1/4 to 1) of the largest feasible step along it."""
        return self.shrink(1e6 * rng.standard_normal((m, self.n))) * rng.uniform(0.25, 1, (m, 1))

    # -- trust-region search (spatial systems) ---------------------------------------------
    #
    # Limits are per joint, so the feasible set is a product of one convex set per joint. The
    # radial map z_j = y_j / rho_j(y_j) (rho_j: how far y_j's signals exceed the room the
    # quintic leaves) puts every joint on the boundary of its set, where exciting trajectories
    # sit: the search is unconstrained in y, and every iterate is feasible on the fine grid.

    @cached_property
    def _rooms(self):
        """Fine-grid signals over limits per unit z, ``A`` (n_rows, n_joints, K), and the
        factors ``1 / (1 -+ p)`` (n_rows, n_joints), p the quintic over the limit, that turn
        a signal of either sign into the fraction of the room it uses."""
        A = self.B[:, :, None, :] * self.S / self.L[:, None, :, None]
        p = (self.P / self.L[:, None]).reshape(-1, self.S.shape[0])
        return A.reshape(-1, *self.S.shape), *_room_factors(p)

    def gauge(self, y, sharp=None):
        """Per joint, how far ``y``'s signals exceed their room: the max over time of
        ``r = v / (1 - p)`` (v > 0) or ``-v / (1 + p)`` (v < 0), for ``y`` (..., n);
        (..., n_joints). The max over all times, not only the fine grid's (:meth:`_room_peak`),
        so ``y_j / rho_j`` keeps the limits on the continuous trajectory.

        With ``sharp``, for one ``y`` (n,): the ``sharp``-norm of r over the fine grid
        instead (smooth, and >= its max, so ``y / rho`` keeps the limits there) and its
        gradient (n_joints, K).
        """
        A, up, down = self._rooms
        v = np.einsum("rjk,...jk->...rj", A, np.reshape(y, (*np.shape(y)[:-1], *self.S.shape)))
        r = np.where(v > 0, v * up, -v * down)
        if sharp is None:
            return self._room_peak(np.reshape(y, (-1, self.n)), r.reshape(-1, *r.shape[-2:])
                               ).reshape(r.shape[:-2] + r.shape[-1:])  # fmt: skip
        top = r.max(0)
        top = np.where(top > 0, top, 1.0)  # y_j = 0: no motion, nothing to scale
        w = r / top
        wp = w ** (sharp - 1)
        norm = (wp * w).sum(0) ** (1 / sharp)
        dr = wp * np.where(v > 0, up, -down)  # d(r^sharp) / dv, over sharp top^(sharp - 1)
        grad = np.einsum("rj,rjk->jk", dr, A) * norm[:, None] ** (1 - sharp)
        return top * norm, grad

    def _room_peak(self, Y, r):
        """Per joint, the max over all times of the room used, ``rho`` (batch, n_joints), for
        ``Y`` (batch, n) whose fine-grid values are ``r`` (batch, 3 n_grid, n_joints).

        Between grid points a signal can exceed its grid values (by 3e-4 of a limit for the
        servicer's qdd on the default grid). Each grid local maximum above half the joint's
        grid maximum (lower ones cannot overtake it unless the grid misses half a period of
        the top harmonic) brackets a true local maximum between its neighbours, where the
        trigonometric sum is unimodal; golden-section search finds it to round-off.
        """
        nj, n_grid = self.S.shape[0], self.B.shape[1]
        r = r.reshape(len(r), 3, n_grid, nj)
        rho = r.max(axis=(1, 2))
        edge = np.full_like(r[:, :, :1], -np.inf)
        ahead = np.concatenate([r[:, :, 1:], edge], 2)
        behind = np.concatenate([edge, r[:, :, :-1]], 2)
        top = (r >= ahead) & (r >= behind) & (r >= 0.5 * rho[:, None, None])
        b, d, i, j = np.nonzero(top & (rho[:, None, None] > 0))
        if not len(b):
            return rho
        L = self.L[d, j]
        coef = self.X(Y)[b, j] / L[:, None]  # (n_peaks, K): the Fourier part over the limit
        at = np.arange(len(b))
        T, harmonics = self.duration, self.S.shape[1] // 2

        def room_used(t):
            v = np.sum(fourier_basis(t, duration=T, harmonics=harmonics)[d, at] * coef, -1)
            p = boundary_quintic(t, duration=T, boundary=self.boundary)[d, at, j] / L
            up, down = _room_factors(p)
            return np.where(v > 0, v * up, -v * down)

        dt = T / (n_grid - 1)
        lo, hi = np.maximum(i - 1, 0) * dt, np.minimum(i + 1, n_grid - 1) * dt
        np.maximum.at(rho, (b, j), _golden_max(room_used, lo, hi))
        return rho

    def radial(self, y, sharp):
        """``z = y_j / rho_j`` joint by joint (:meth:`gauge`) and the map of a gradient in z
        to one in y: ``z, pull`` with ``pull(gz) -> gy``."""
        rho, drho = self.gauge(y, sharp)
        Y = np.reshape(y, self.S.shape)
        z = (Y / rho[:, None]).ravel()

        def pull(gz):
            gz = gz.reshape(self.S.shape)
            return (gz / rho[:, None] - drho * (np.sum(Y * gz, 1) / rho**2)[:, None]).ravel()

        return z, pull

    def to_limits(self, Z, *, inside=False):
        """``Z (..., n)`` with every joint scaled onto its limits at all times (:meth:`gauge`),
        or, if ``inside``, only those beyond them."""
        Z = np.asarray(Z, float)
        rho = self.gauge(Z)
        rho = np.maximum(rho, 1.0) if inside else np.where(rho > 0, rho, 1.0)
        return (np.reshape(Z, (*Z.shape[:-1], *self.S.shape)) / rho[..., None]).reshape(Z.shape)

    def smooth_objective(self, Z, p):
        """The criterion's smooth surrogate of sharpness ``p`` at ``Z (batch, n)``: (batch,)."""
        q, qd = np.einsum("dtk,bjk->dbtj", self.B_samples, self.X(Z)) + self.P_samples[:, None]
        chunk = max(1, _CALL_SAMPLES // q.shape[-2])  # and no (batch, rows, k) array at once
        Ys = (self.regressor(q[i : i + chunk], qd[i : i + chunk]) for i in range(0, len(q), chunk))
        return np.concatenate([self._smooth_value(Y, p) for Y in Ys])

    def _smooth_value(self, Y, p):
        """The surrogate of the stacked regressors ``Y`` (..., n_rows, k): (...), inf where
        singular."""
        with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
            f = CRITERIA[self.criterion].smoothed_value(Y, p)
        return np.where(np.isnan(f), np.inf, f)

    def _model(self, y, z0, Y0, Gt, p):
        """Surrogate of sharpness p at ``z(y)`` for the regressor linearised in the joint
        signals about ``z0``, ``Y0 + sum_dj Gt[.., dj] dsignal_dj``, and its gradient in y.

        An evaluation costs one SVD and no regressor call; the model keeps the criterion's
        own nonlinearity (the singular values) exact and linearises only Y(q, qd).
        """
        z, pull = self.radial(y, self.sharpness)
        dsig = np.einsum("dtk,jk->tdj", self.B_samples, self.X(z - z0)).reshape(len(Gt), -1, 1)
        Ym = Y0 + (Gt @ dsig).reshape(Y0.shape)
        with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
            f, W = CRITERIA[self.criterion].smoothed(Ym, p)
        if not np.isfinite(f):
            return 1e300, np.zeros_like(y)
        return f, pull(self.pullback(W, Gt))

    def tr_search(self, z0, steps, deadline=None, resume=None):
        """One trust-region search from ``z0`` (n,): ``(z, objective, state)``, z on the
        limits; ``state`` continues the search when passed back as ``resume``.

        Each outer step linearises Y in the joint signals (:meth:`jet`) and minimises the
        surrogate of that model (:meth:`_model`, cheap) by L-BFGS-B in a box of half-width
        ``delta`` about the current point; the step is taken if the true surrogate (one more
        regressor call, reused by the next linearisation) decreases by at least a tenth of what
        the model predicted, and ``delta`` follows the agreement. Sharpness p rises through
        ``self.stages``, each stage ending when a step gains less than ``self.tr_tol``. The
        search stops early, with its best point so far, at ``deadline`` (time.monotonic()).
        ``state`` is the stage and ``delta`` it ended with.
        """
        z = self.radial(z0, self.sharpness)[0]
        stage0, delta = (0, self.tr_radius / self.S.shape[1]) if resume is None else resume
        outer, Y0, Y_z = 0, None, None
        for stage in range(stage0, len(self.stages)):
            p, stalls, f0 = self.stages[stage], 0, None
            while stalls < 2:
                if outer == steps or (deadline is not None and time.monotonic() > deadline):
                    return (*self._tr_result(z), (stage, delta))
                if Y0 is None:  # a new point: linearise (a new stage keeps the last one)
                    (Y0, Gt), outer = self.jet(z, Y_z, central=False), outer + 1
                if f0 is None:
                    f0 = float(self._smooth_value(Y0, p))
                while True:  # on this linearisation, until a step is taken or delta is tiny
                    res = minimize(self._model, z, args=(z, Y0, Gt, p), jac=True,
                                   method="L-BFGS-B", bounds=Bounds(z - delta, z + delta),
                                   options={"maxiter": self.inner, "maxcor": 20})  # fmt: skip
                    step = np.abs(res.x - z).max()
                    predicted = f0 - res.fun
                    if not predicted > 0:  # the model has nothing to offer: next stage
                        stalls, delta = 2, max(delta, 1e-3)
                        break
                    z_new = self.radial(res.x, self.sharpness)[0]
                    Y_new = self.stacked(z_new[None])[0]
                    f_new = float(self._smooth_value(Y_new, p))
                    ratio = (f0 - f_new) / predicted
                    if ratio < 0.25:
                        delta = step / 4
                    elif ratio > 0.75 and step > 0.9 * delta:
                        delta = min(2 * delta, 1.0)
                    if ratio > 0.1:
                        stalls = stalls + 1 if f0 - f_new < self.tr_tol else 0
                        z, Y_z, f0, Y0 = z_new, Y_new, f_new, None
                        break
                    if delta < 1e-4:
                        stalls, delta = 2, 1e-3
                        break
        return (*self._tr_result(z), (len(self.stages), delta))

    def _tr_result(self, z):
        """The better of ``z`` (inside the fine-grid limits by the smooth gauge; scaled into
        them between grid points too) and ``z`` scaled onto them exactly, by the criterion
        itself: ``(z, objective)``."""
        Z = np.stack([self.to_limits(z, inside=True), self.to_limits(z)])
        f = self.objective(Z)
        return Z[np.argmin(f)], float(f.min())

    def tr_starts(self, rng, m):
        """``m`` random starts (m, n) on the limits: isotropic directions, each joint scaled
        onto its limits. Joint by joint rather than together: scaling by the tightest joint
        leaves the others at a fraction of their range (cond 10 times worse on a 7-joint arm)."""
        return self.to_limits(rng.standard_normal((m, self.n)))


def _room_factors(p):
    """``1 / (1 - p)``, ``1 / (1 + p)`` for the quintic over the limit ``p`` (any shape): they
    turn a Fourier part over the limit of either sign into the fraction of its room it uses."""
    return 1 / np.maximum(1 - p, 1e-12), 1 / np.maximum(1 + p, 1e-12)


def _golden_max(f, lo, hi, iterations=40):
    """Vectorised golden-section search: the max of ``f`` (elementwise, of times (m,) [s]) in
    each bracket ``[lo, hi]`` (m,) [s] where it is unimodal, shape (m,). The bracket shrinks to
    0.618^iterations of its width (4e-9 for 40), so near a smooth maximum the value is exact
    to round-off."""
    g = (np.sqrt(5) - 1) / 2
    a, b = lo, hi
    c, d = b - g * (b - a), a + g * (b - a)
    fc, fd = f(c), f(d)
    for _ in range(iterations):
        left = fc >= fd  # the max lies in [a, d]: d becomes b, c becomes d
        a, b = np.where(left, a, c), np.where(left, d, b)
        new = np.where(left, b - g * (b - a), a + g * (b - a))
        c, d = np.where(left, new, d), np.where(left, c, new)
        f_new = f(new)
        fc, fd = np.where(left, f_new, fd), np.where(left, fc, f_new)
    return np.maximum(fc, fd)


def _problem(regressor, criterion, *, duration, harmonics, samples, limits, boundary, n_grid):
    """The design problem in scaled variables (see _Problem); limits (3, n_joints)."""
    t = sample_times(duration, n_grid)
    B = fourier_basis(t, duration=duration, harmonics=harmonics)
    t_s = sample_times(duration, samples)
    B_samples = fourier_basis(t_s, duration=duration, harmonics=harmonics)[:2]
    S = 1.0 / np.max(np.abs(B)[:, :, None, :] / limits[:, None, :, None], axis=(0, 1))
    n_coarse = 10 * harmonics + 1  # ten points a period of the top harmonic
    return _Problem(
        regressor=regressor,
        criterion=criterion,
        S=S,
        B_samples=B_samples,
        P_samples=boundary_quintic(t_s, duration=duration, boundary=boundary)[:2],
        B=B,
        P=boundary_quintic(t, duration=duration, boundary=boundary),
        L=limits,
        coarse=np.unique(np.linspace(0, n_grid - 1, n_coarse).round().astype(int)),
        duration=duration,
        boundary=boundary,
        **({"step": float(regressor.fd_step)} if hasattr(regressor, "fd_step") else {}),
    )


# -- the global search --------------------------------------------------------------------------

_N_POLISH = 2  # distinct best results refined on the fine grid

_WORKER_PROBLEM = None


def _init_worker(problem):
    threadpool_limits(1)  # see optimize_excitation
    global _WORKER_PROBLEM
    _WORKER_PROBLEM = problem


def _call(method, *args):
    """``problem.method(*args)`` in a worker process, on the problem it received at start-up."""
    return getattr(_WORKER_PROBLEM, method)(*args)


def _imap(problem, pool, n_jobs, calls, *, stop):
    """Run ``problem.method(*args)`` for ``calls``, an iterable of ``(key, method, args)``.

    Yields ``(key, result)`` in completion order, from ``pool`` or from this process when
    ``pool`` is None. No call starts once ``stop()`` is true; started calls finish.
    """
    calls = iter(calls)
    if pool is None:
        for key, method, args in calls:
            if stop():
                return
            yield key, getattr(problem, method)(*args)
        return
    pending = {}
    while True:
        while len(pending) < n_jobs and not stop():
            call = next(calls, None)
            if call is None:
                break
            key, method, args = call
            pending[pool.submit(_call, method, *args)] = key
        if not pending:
            return
        done, _ = wait(pending, return_when=FIRST_COMPLETED)
        for future in done:
            yield pending.pop(future), future.result()


def _picklable(obj):
    try:
        pickle.dumps(obj)
    except (pickle.PicklingError, TypeError, AttributeError):
        return False
    return True


def _distinct(found, m):
    """The first ``m`` of the sorted results ``(f, i, z)`` whose z differ."""
    out = []
    for cand in found:
        if all(np.linalg.norm(cand[2] - c[2]) > 1e-3 for c in out):
            out.append(cand)
        if len(out) == m:
            break
    return out


@dataclass(frozen=True)
class DesignResult:
    """Outcome of :func:`optimize_excitation`.

    Attributes
    ----------
    trajectory : FourierTrajectory
        The best trajectory found; its ``meta`` records criterion, value, seed, number of
        starts, samples, wall time and limits.
    criterion : str
        A key of :data:`CRITERIA`.
    value : float
        Criterion value of ``trajectory``: the condition number for ``cond``, log det of
        ``Yn^T Yn`` for ``logdet``, log det of the relative Fisher information for ``dopt``,
        the trace of the relative Cramer-Rao bound (sum of the parameters' relative
        variances) for ``crb``.
    seed : int
        Seed of the start points.
    n_starts : int
        Local searches completed (fewer than asked for when the time budget ran out).
    wall_time : float
        Wall time of the design [s].
    history : tuple of (float, float)
        ``(wall time [s], best value so far)`` at each improvement.
    noise : Noise or None
        The noise model of :func:`design_excitation`, if given.
    """

    trajectory: FourierTrajectory
    criterion: str
    value: float
    seed: int
    n_starts: int
    wall_time: float
    history: tuple = field(default=(), repr=False)
    noise: Noise | None = None

    def to_dict(self) -> dict:
        """JSON-ready dictionary."""
        return {
            "trajectory": self.trajectory.to_dict(),
            "criterion": self.criterion,
            "value": self.value,
            "seed": self.seed,
            "n_starts": self.n_starts,
            "wall_time": self.wall_time,
            "history": [list(h) for h in self.history],
            "noise": None if self.noise is None else self.noise.to_dict(),
        }


_METHODS = ("auto", "slsqp", "trust-region")
_SLSQP_MAX_COLUMNS = 64  # "auto": SLSQP up to this many regressor columns, trust region above


def optimize_excitation(
    regressor,
    joints,
    *,
    duration,
    harmonics,
    samples,
    q_max,
    qd_max,
    qdd_max,
    criterion="cond",
    seed=0,
    n_starts=64,
    n_jobs=None,
    progress=None,
    boundary=None,
    time_budget=None,
    initial=None,
    n_grid=1001,
    method="auto",
    max_steps=40,
    n_screen=64,
):
    """Design an exciting trajectory (paper Eq. 12) by a seeded multi-start search.

    Parameters
    ----------
    regressor : callable
        ``regressor(q, qd)`` with q [rad], qd [rad/s] of shape (..., samples, n_joints),
        batched over leading dimensions, returning the stacked regressor (..., samples * m, k)
        (m = 1 planar, 3 spatial). Worker processes need it picklable; otherwise the search
        runs in this process.
    joints : sequence of str
        Joint names, the column order of q.
    duration : float
        Trajectory duration tf [s].
    harmonics : int
        Number of harmonics Nf.
    samples : int
        Number of equally spaced samples over ``[0, duration]`` (both ends included) at which
        the regressor is stacked.
    q_max, qd_max, qdd_max : float or array_like of shape (n_joints,)
        Limits on |q| [rad], |qd| [rad/s], |qdd| [rad/s^2], held at all times (imposed on
        ``n_grid`` times during the search, the result scaled into them between those).
    criterion : {"cond", "logdet", "dopt", "crb"}
        ``cond``: minimise the 2-norm condition number of the stacked regressor; ``logdet``:
        maximise log det of ``Yn^T Yn``, ``Yn`` with unit-norm columns. For a whitened,
        pi-scaled regressor (:class:`whitened_regressor`; :func:`design_excitation` builds it):
        ``dopt`` maximises log det of ``Y^T Y``, the Fisher information (D-optimality);
        ``crb`` minimises the trace of ``(Y^T Y)^-1``, the Cramer-Rao bound (A-optimality).
    seed : int
        Seed (an integer >= 0) of the random start points. The same seed gives the same
        result, whatever ``n_jobs``, unless ``time_budget`` cuts the search short; a larger
        ``n_starts`` adds starts to those of a smaller one.
    n_starts : int
        Number of local searches (an upper bound when ``time_budget`` is given).
    n_jobs : int, optional
        Worker processes; default: one per core. 1 runs in this process.
    progress : callable, optional
        ``progress(done, total)``, called as local searches complete (``total = n_starts``;
        trust region: plus the searches continued in the second round).
    boundary : mapping, optional
        Boundary values ``q0, qd0, qdd0, qf, qdf, qddf`` (keys), arrays (n_joints,) [rad,
        rad/s, rad/s^2]; missing ones are zero. The quintic through them must keep the limits.
    time_budget : float, optional
        Wall time [s]. SLSQP: local searches stop early enough, by an estimate from those
        done, to finish and polish within it. Trust region: each search, as it starts, gets a
        share of the time left in proportion to its steps, and stops at its end with its best
        point. At least one search runs. The result then depends on the machine's speed.
    initial : FourierTrajectory, optional
        Warm start: used as the first start point, scaled down if it breaks a limit (trust
        region: each joint scaled onto its limits).
    n_grid : int
        Number of equally spaced times on which the search imposes the limits.
    method : {"auto", "slsqp", "trust-region"}
        Local search. ``slsqp``: the condition number itself in epigraph form under linear
        limits on a grid, from random starts; best for small regressors (planar arms), where
        the optimum has coalescing singular values. ``trust-region``: a smooth surrogate of
        the criterion of sharpness rising to 32, in variables that keep every joint on its
        limits, minimised on a model that linearises the regressor in the joint signals; for
        spatial systems (tens to hundreds of columns, a spectrum decaying over decades).
        ``auto``: ``slsqp`` up to 64 regressor columns, else ``trust-region``.
    max_steps : int
        Trust region: most steps of a search, each one linearisation (a regressor evaluation
        of 1 + 2 n_joints trajectories) and an L-BFGS-B solve of its model. Every start gets
        a fifth of them, the best quarter of the starts (at least two) the rest, so a design
        makes about ``(n_starts + 4 max(2, n_starts / 4)) max_steps / 5`` steps, shared by the
        workers; a step takes about 0.2 s on one core for a 7-joint arm (153 parameters,
        N = 120) and 3.5 s for a 14-joint one (496 parameters, N = 400).
    n_screen : int
        Trust region: random starts on the limits (start i drawn from ``(seed, i)``) whose
        surrogate is evaluated; the ``n_starts`` best are searched from (so a larger
        ``n_starts`` adds the next best).

    Returns
    -------
    DesignResult
        The trajectory's ``meta`` also records ``method`` and ``start_value``, the criterion
        at the start of the search that found it.

    Raises
    ------
    SpaceidError
        Invalid options, boundary values that break the limits, too few samples for the
        regressor's columns, or a regressor rank deficient on every start.

    References
    ----------
    Papadopoulos et al., identification of free-floating space robots from angular momentum
    conservation, Eq. 12 (MATH.md section 3).
    """
    t_start = time.perf_counter()
    joints = tuple(joints)
    _check_options(criterion, duration, time_budget, harmonics=harmonics, samples=samples,
                   n_starts=n_starts, n_grid=n_grid, seed=seed, max_steps=max_steps,
                   n_screen=n_screen)  # fmt: skip
    if method not in _METHODS:
        raise SpaceidError(f"method must be one of {', '.join(_METHODS)}, got {method!r}")
    limits = _limits(joints, q_max, qd_max, qdd_max)
    bc = _boundary(joints, boundary)
    problem = _problem(regressor, criterion, duration=float(duration), harmonics=harmonics,
                       samples=samples, limits=limits, boundary=bc, n_grid=n_grid)  # fmt: skip
    if np.abs(problem.signals(np.zeros(problem.n))).max() > 1:
        raise SpaceidError(
            "boundary: the quintic through the boundary values alone breaks a joint limit; "
            "bring the boundary values inside the limits or relax the limits"
        )
    k = _check_shape(problem, len(joints), samples)
    if method == "auto":
        method = "slsqp" if k <= _SLSQP_MAX_COLUMNS else "trust-region"
    if method == "trust-region":
        if CRITERIA[criterion].adjoint is None:
            raise SpaceidError(f"criterion {criterion!r} has no adjoint: use method='slsqp'")
        draw = problem.tr_starts
    else:
        draw = problem.starts
    _check_rank(problem, draw(np.random.default_rng(seed), 8))
    z_initial = None
    if initial is not None:
        z_initial = problem.shrink(_initial_z(problem, initial, joints, duration, harmonics, bc))
    n_jobs = min(os.cpu_count() or 1, n_starts) if n_jobs is None else int(n_jobs)
    report = CRITERIA[criterion].report
    found, history, start_of = [], [], {}
    best = (np.inf, np.inf, None)  # (objective, start index, z): ties go to the lower index

    def consider(f, i, z):
        nonlocal best
        if f < best[0] - 1e-9:  # smaller gains in the objective are not worth a record
            history.append((time.perf_counter() - t_start, float(report(f))))
        if (f, i) < best[:2]:
            best = (f, i, z)

    def completed(results, total):
        for i, (z, f) in results:
            found.append((f, i, z))
            consider(f, i, z)
            if progress is not None:
                progress(len(found), total)

    with contextlib.ExitStack() as stack:
        # One BLAS thread per process: SLSQP's small LAPACK calls gain nothing from more, and
        # OpenBLAS threads spinning on busy cores make it up to 30 times slower.
        stack.enter_context(threadpool_limits(1))
        pool = None
        if n_jobs > 1 and _picklable(regressor):
            pool = stack.enter_context(
                ProcessPoolExecutor(n_jobs, initializer=_init_worker, initargs=(problem,))
            )
        workers, t_search = (n_jobs if pool else 1), time.perf_counter()

        if method == "slsqp":

            def searches():
                """One task per start; start i is drawn from (seed, i) alone, so it is the same
                whatever n_starts and the order in which tasks run."""
                for i in range(n_starts):
                    z0 = problem.starts(np.random.default_rng([seed, i]), 1)[0]
                    start_of[i] = z_initial if i == 0 and z_initial is not None else z0
                    yield i, "search", (start_of[i],)

            def out_of_time():
                # Keep time to finish the running searches and to polish (a polish costs about
                # one to five searches, whose mean wall time the searches so far tell)
                if time_budget is None or not found:
                    return False
                now = time.perf_counter()
                per_search = (now - t_search) * workers / len(found)
                reserve = per_search * (1 + 3 * -(-_N_POLISH // workers))
                return now + reserve > t_start + time_budget

            completed(_imap(problem, pool, n_jobs, searches(), stop=out_of_time), n_starts)
            found.sort(key=lambda c: c[:2])  # by value, then start index: independent of timing
            polish = ((i, "polish", (z,)) for _, i, z in _distinct(found, _N_POLISH))
            polished = _imap(problem, pool, n_jobs, polish, stop=lambda: False)
            for i, (z, f) in sorted(polished, key=lambda r: r[0]):
                consider(f, i, z)
        else:
            starts = _screened_starts(problem, pool, n_jobs, seed, n_starts, n_screen, z_initial)
            t_end = None if time_budget is None else time.monotonic() + time_budget - (
                time.perf_counter() - t_start)  # fmt: skip
            # Successive halving: every start gets a fifth of the steps (a search gains most in
            # its first steps, and where it gets to then ranks it fairly well), the best
            # quarter (at least two) the rest; on the 7-joint arm this beats four full searches
            # at a lower cost.
            first = max(1, round(max_steps / 5))
            keep = min(len(starts), max(2, len(starts) // 4)) if max_steps > first else 0
            total = len(starts) + keep

            def searches(items, steps, later):
                """``tr_search`` tasks of ``steps`` steps from ``(index, z)`` items. With a
                budget, each gets a share of the time left in proportion to its steps, among
                the work not yet started (``later`` steps after these): its deadline is set as
                it starts."""
                for n, (i, z0) in enumerate(items):
                    deadline = None
                    if t_end is not None:
                        now, left = time.monotonic(), steps * (len(items) - n) + later
                        deadline = now + (t_end - now) * steps / max(left / workers, steps)
                    yield i, "tr_search", (z0, steps, deadline, state.get(i))

            def out_of_time():  # at least one search runs, however short the budget
                return t_end is not None and bool(found) and time.monotonic() > t_end

            def kept(results):  # each search's state, so that the second round continues it
                for i, (z, f, state[i]) in results:
                    yield i, (z, f)

            start_of.update(enumerate(starts))
            state = {}
            round_one = searches(list(enumerate(starts)), first, keep * (max_steps - first))
            completed(kept(_imap(problem, pool, n_jobs, round_one, stop=out_of_time)), total)
            found.sort(key=lambda c: c[:2])
            chosen = [(i, z) for _, i, z in _distinct(found, keep)]
            round_two = _imap(problem, pool, n_jobs, searches(chosen, max_steps - first, 0),
                              stop=out_of_time)  # fmt: skip
            for n, (i, (z, f, _)) in enumerate(round_two):
                consider(f, i, z)
                if progress is not None:
                    progress(len(found) + n + 1, total)

    f, i_best, z = best
    if not np.isfinite(f):
        raise SpaceidError(
            "no local search found a trajectory with a full-rank regressor; check that its "
            "columns are identifiable together and that the limits allow motion"
        )
    wall = time.perf_counter() - t_start
    value = float(report(f))
    X = problem.X(z)
    meta = {
        "source": "optimize_excitation",
        "criterion": criterion,
        "value": value,
        "seed": seed,
        "n_starts": len(found),
        "samples": samples,
        "wall_time": wall,
        "limits": dict(zip(("q_max", "qd_max", "qdd_max"), limits.tolist())),
        "method": method,
        "start_value": float(report(problem.objective(start_of[i_best][None])[0])),
    }
    trajectory = FourierTrajectory(
        joints, duration, X[:, :harmonics], X[:, harmonics:], **dict(zip(BOUNDARY_FIELDS, bc)),
        meta=meta,
    )  # fmt: skip
    return DesignResult(trajectory, criterion, value, seed, len(found), wall, tuple(history))


def _screened_starts(problem, pool, n_jobs, seed, n_starts, n_screen, z_initial):
    """The trust-region starts: the ``n_starts`` best by the first-stage surrogate of
    ``max(n_screen, n_starts)`` random starts on the limits (start i from ``(seed, i)``, so a
    larger ``n_starts`` adds the next best), after ``z_initial`` if given."""
    m = max(n_screen, n_starts)
    Z = np.concatenate([problem.tr_starts(np.random.default_rng([seed, i]), 1) for i in range(m)])
    chunk = -(-m // max(n_jobs, 1) // 2) if pool is not None else m  # two chunks a worker
    calls = ((c, "smooth_objective", (Z[c : c + chunk], problem.stages[0]))
             for c in range(0, m, chunk))  # fmt: skip
    f = np.empty(m)
    for c, values in _imap(problem, pool, n_jobs, calls, stop=lambda: False):
        f[c : c + len(values)] = values
    order = np.argsort(np.where(np.isfinite(f), f, np.inf), kind="stable")
    starts = [] if z_initial is None else [z_initial]
    return starts + [Z[i] for i in order[: n_starts - len(starts)]]


# -- input checks -------------------------------------------------------------------------------


def _check_options(criterion, duration, time_budget, **integers):
    _criterion(criterion)
    low = {"harmonics": 1, "samples": 2, "n_starts": 1, "n_grid": 100, "seed": 0, "max_steps": 1,
           "n_screen": 1}
    for name, value in integers.items():
        if not isinstance(value, (int, np.integer)) or value < low[name]:
            raise SpaceidError(f"{name} must be an integer >= {low[name]}, got {value!r}")
    if not (np.isfinite(duration) and duration > 0):
        raise SpaceidError(f"duration must be a positive number of seconds, got {duration!r}")
    if time_budget is not None and not time_budget > 0:
        raise SpaceidError(f"time_budget must be a positive number of seconds, got {time_budget!r}")


def _limits(joints, q_max, qd_max, qdd_max):
    """Limits as an array (3, n_joints): rows |q| [rad], |qd| [rad/s], |qdd| [rad/s^2]."""
    rows = []
    for name, value in (("q_max", q_max), ("qd_max", qd_max), ("qdd_max", qdd_max)):
        arr = np.asarray(value, dtype=float)
        if arr.ndim > 1 or arr.size not in (1, len(joints)):
            raise SpaceidError(
                f"{name} must be a number or one value per joint ({len(joints)}), got {value!r}"
            )
        if not np.all(np.isfinite(arr) & (arr > 0)):
            raise SpaceidError(f"{name} must be positive and finite, got {value!r}")
        rows.append(np.broadcast_to(arr, (len(joints),)))
    return np.array(rows)


def _boundary(joints, boundary):
    """Boundary values as an array (6, n_joints), rows in BOUNDARY_FIELDS order."""
    boundary = dict(boundary or {})
    unknown = set(boundary) - set(BOUNDARY_FIELDS)
    if unknown:
        raise SpaceidError(
            f"boundary: unknown key(s) {', '.join(sorted(unknown))}; "
            f"expected some of {', '.join(BOUNDARY_FIELDS)}"
        )
    out = np.zeros((6, len(joints)))
    for row, key in enumerate(BOUNDARY_FIELDS):
        if key in boundary:
            value = np.asarray(boundary[key], dtype=float)
            if value.shape != (len(joints),) or not np.all(np.isfinite(value)):
                raise SpaceidError(
                    f"boundary['{key}'] must be {len(joints)} finite values, got {boundary[key]!r}"
                )
            out[row] = value
    return out


def _initial_z(problem, initial, joints, duration, harmonics, bc):
    """Scaled coefficients of a warm-start trajectory, after checking that it fits."""
    if not (
        initial.joints == joints
        and initial.duration == float(duration)
        and initial.n_harmonics == harmonics
        and np.array_equal(initial.boundary, bc)
    ):
        raise SpaceidError(
            "initial: the warm-start trajectory must have the design's joints, duration, "
            "number of harmonics and boundary values"
        )
    return (initial.coefficients / problem.S).ravel()


def _check_shape(problem, n_joints, samples):
    """The regressor's output shape, checked; returns its number of columns k."""
    zeros = np.zeros((1, samples, n_joints))
    shape = np.shape(problem.regressor(zeros, zeros))
    if len(shape) != 3 or shape[0] != 1 or shape[1] % samples:
        raise SpaceidError(
            f"regressor must map (batch, {samples}, {n_joints}) joint arrays to "
            f"(batch, {samples} * m, k); got shape {shape}"
        )
    if shape[1] < shape[2]:
        raise SpaceidError(
            f"samples={samples} give {shape[1]} equations for {shape[2]} parameters; "
            f"use at least {-(-shape[2] * samples // shape[1])} samples"
        )
    return shape[2]


def _check_rank(problem, Z0):
    """Full numerical rank of the stacked regressor at one of the starts ``Z0``."""
    Y = problem.stacked(Z0)
    s = np.linalg.svd(Y, compute_uv=False)
    if np.all(s[:, -1] <= s[:, 0] * max(Y.shape[1:]) * np.finfo(float).eps):  # numerical rank < k
        raise SpaceidError(
            "the regressor is rank deficient on random start trajectories: its columns are not "
            "identifiable together (reduce them to a minimal parameter set), or the motion is "
            "too poor to excite them all (more harmonics, samples or duration, wider limits)"
        )


def design_excitation(param, *, duration, harmonics, samples, momentum, seed=0, progress=None,
               criterion="cond", noise=None, **options):
    """Optimal exciting trajectory for ``param``'s model, joint limits from the model, the base
    rate from momentum conservation at the model's nominal parameters.

    Parameters
    ----------
    param : Parameterization
    duration, harmonics, samples, seed, progress
        As for :func:`optimize_excitation`.
    momentum : array_like of shape (3,)
        Angular momentum [N m s].
    criterion : str
        A key of :data:`CRITERIA`. ``dopt`` and ``crb`` are searched on the whitened,
        pi-scaled regressor (:class:`whitened_regressor`) and need ``noise``.
    noise : Noise, optional
        Measurement noise. When given (not all zero), the trajectory's ``meta`` also records
        it and the predicted Cramer-Rao standard deviation of every parameter, absolute
        (``crb_std``) and relative to its nominal value (``crb_relative_std``, None where
        that is zero), whatever the criterion.
    **options
        ``q_max``, ``qd_max``, ``qdd_max`` override the model's limits (and must be given
        where it has none); the others go to :func:`optimize_excitation`.

    Returns
    -------
    DesignResult
        ``noise`` set to ``noise``.
    """
    crit = _criterion(criterion)
    if noise is not None and not isinstance(noise, Noise):
        raise SpaceidError(f"noise must be a spaceid.estimation.Noise, got {type(noise).__name__}")
    if crit.noise_aware and (noise is None or noise.is_zero):
        raise SpaceidError(
            f"criterion {criterion!r} minimises the estimation error under measurement noise: "
            "give --noise-angle, --noise-rate, --noise-base-rate (rad, rad/s; spatial also "
            "--noise-attitude), or use --criterion cond"
        )
    model = param.model
    limits = {
        "q_max": np.fmin(np.abs(model.joint_limits("lower")), np.abs(model.joint_limits("upper"))),
        "qd_max": model.joint_limits("velocity"),
        "qdd_max": model.joint_limits("acceleration"),
    }
    for key, value in list(limits.items()):
        if options.get(key) is not None:
            limits[key] = np.broadcast_to(np.asarray(options.pop(key), float), value.shape).copy()
    for key, value in limits.items():
        if np.isnan(value).any():
            missing = [j for j, v in zip(model.joints, value) if np.isnan(v)]
            raise SpaceidError(
                f"{model.source}: no {key.replace('_max', '')} limit for joint(s) {', '.join(missing)}: "
                f"give --{key.replace('_', '-')} (rad, rad/s, rad/s^2)"
            )
    options = {k: v for k, v in options.items() if v is not None}
    from ..dynamics import excitation_regressor

    noisy = noise is not None and not noise.is_zero
    if crit.noise_aware:
        regressor = whitened_regressor(param, param.true_values, momentum, noise)
    else:
        regressor = excitation_regressor(param, param.true_values, momentum)
    result = optimize_excitation(
        regressor,
        model.joints,
        duration=duration,
        harmonics=harmonics,
        samples=samples,
        seed=seed,
        progress=progress,
        criterion=criterion,
        **limits,
        **options,
    )
    if not noisy:
        return result
    # the record: absolute bound (defined for zero nominal values too), then relative
    q, qd, _ = result.trajectory.evaluate(sample_times(duration, samples))
    bound = whitened_regressor(param, param.true_values, momentum, noise, relative=False)
    std = np.sqrt(np.diag(bound.crb(q, qd)))
    pi = np.abs(param.true_values)
    meta = {
        **result.trajectory.meta,
        "noise": noise.to_dict(),
        "crb_std": dict(zip(param.names, std.tolist())),
        "crb_relative_std": {n: s / p if p > 0 else None for n, s, p in zip(param.names, std, pi)},
    }
    return replace(result, trajectory=replace(result.trajectory, meta=meta), noise=noise)
