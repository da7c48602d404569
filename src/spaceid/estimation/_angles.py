"""Identification from the measured angles alone, and the Cramer-Rao bound for angle measurements
(docs/theory/angles.md).

Encoders and motion capture measure angles; differentiating them for the rates correlates and
colours the noise, and the rate-based estimators then stay 2 to 5 times above what the angles
allow. Here the angles are the data:

* Integral form. The momentum is linear in the rates, ``Y(q, qd, w0) = sum_j Y_j(q) qd_j +
  Y_w(q) w0``, so over any interval ``h (t_b - t_a)`` is the line integral of the regressor along
  the measured angle path, ``(int Y_j(q) dq_j + int Y_w(q) dyaw) pi``: no differentiation. The
  trapezoid rule on the sample path, one equation per knot span (:func:`_integral_equations`),
  gives the starting estimate and the excitation check of the ``angles`` estimator.
* Maximum likelihood on the angle samples (estimator ``angles``, :func:`_angles_ml`). The
  joint paths are cubic splines with uniform knots every ``KNOT_SPACING`` seconds (a smooth
  nuisance); the base yaw follows from momentum conservation, ``yaw(t) = yaw_0 + int w0(q, qd;
  pi, h) dt``, by Gauss-Legendre quadrature on the panels between samples and knots. The
  measured joint angles and yaw carry white noise of the given levels; Gauss-Newton minimises
  the whitened residuals over the parameters, the spline coefficients and ``yaw_0`` together.
  Its covariance is the inverse Fisher information with the nuisance eliminated, which at the
  true values is the bound :func:`cramer_rao_angles`.

Planar models only (the yaw is a quadrature of the base rate; a spatial attitude would follow
an ODE on the rotation group).
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np
from scipy.interpolate import BSpline

from .._constants import KNOT_SPACING
from .._errors import SpaceidError
from ..data import Log, quat_to_yaw
from ..dynamics import base_rate
from ._equations import _equations
from ._linalg import _inverse_gram, _solve
from ._noise import Noise, signal_jacobian

__all__ = ["KNOT_SPACING", "cramer_rao_angles"]

GAUSS_NODES = 4
"""Gauss-Legendre nodes per quadrature panel: exact for the spline pieces to ~1e-13 at 100 Hz."""

MIN_SAMPLES_PER_SPAN = 2
"""Fewest samples per knot span on average: fewer leave the splines (two coefficients per span
and joint at most) barely determined by their own joint's samples."""


def _planar_only(param, what: str) -> None:
    if not param.model.planar:
        raise SpaceidError(f"{what}: the angles estimator and bound support planar models only; for spatial systems "
                           "use a rate-based `estimator`, e.g. ml")  # fmt: skip


def _phi(eq, x):
    """``eq.phi`` at signals ``x (m, n_x)`` that are not the log's samples (planar: the yaw leaves
    the z row alone, so the base rotation is taken as the identity)."""
    return replace(eq, rot=np.broadcast_to(np.eye(3), (len(x), 3, 3))).phi(x)


def _knot_vector(t, spacing: float, where: str) -> np.ndarray:
    """Cubic-spline knots over ``[t[0], t[-1]]``: uniform spans of about ``spacing`` [s], the end
    knots repeated four times. Raises when the samples are too few for them."""
    if not spacing > 0:
        raise SpaceidError(f"{where}: `knot_spacing` {spacing!r} must be a positive time [s]")
    duration = float(t[-1] - t[0])
    spans = max(1, round(duration / spacing))
    if len(t) - 1 < MIN_SAMPLES_PER_SPAN * spans:
        raise SpaceidError(
            f"{where}: {len(t)} samples over {duration:.4g} s are too few for spline knots every {spacing:g} s "
            f"({spans} spans): the angles estimator needs at least {MIN_SAMPLES_PER_SPAN * spans + 1} samples "
            f"(sample at {MIN_SAMPLES_PER_SPAN / spacing:g} Hz or more)"
        )
    inner = np.linspace(t[0], t[-1], spans + 1)
    return np.concatenate([[t[0]] * 3, inner, [t[-1]] * 3])


def _basis(knots, s, deriv=0) -> np.ndarray:
    """Cubic B-spline basis (or its derivative) at times ``s (m,)``: ``(m, n_coef)``."""
    n_coef = len(knots) - 4
    spline = BSpline(knots, np.eye(n_coef), 3)
    return (spline.derivative(deriv) if deriv else spline)(s)


def _quadrature(t, knots):
    """Gauss-Legendre nodes ``(m,)`` and weights ``(m,)`` on the panels between the sample times
    and the knots (the splines are smooth on each), and the panel index after which each sample
    time comes: ``cumsum`` of the panel sums at ``ends`` integrates from ``t[0]`` to each sample."""
    edges = np.unique(np.concatenate([t, knots]))
    x, w = np.polynomial.legendre.leggauss(GAUSS_NODES)
    half = np.diff(edges)[:, None] / 2
    nodes = (edges[:-1, None] + half * (x + 1)).ravel()
    weights = (half * w).ravel()
    return nodes, weights, np.searchsorted(edges, t)


def _cumulative(values, weights, ends):
    """``int_{t0}^{t_n} f dt`` at the sample times of node values ``(m, ...)``: ``(n, ...)``."""
    panels = (values * weights.reshape((-1,) + (1,) * (values.ndim - 1))).reshape((-1, GAUSS_NODES) + values.shape[1:])
    total = np.concatenate([np.zeros((1,) + values.shape[1:]), np.cumsum(panels.sum(1), 0)])
    return total[ends]


class _Path:
    """The sample times, knots and quadrature of one log, with the spline bases at the samples
    ``B (n, c)`` and at the quadrature nodes ``Bs, dBs (m, c)``."""

    def __init__(self, t, spacing, where):
        self.t = np.asarray(t, float)
        self.knots = _knot_vector(self.t, spacing, where)
        self.nodes, self.weights, self.ends = _quadrature(self.t, self.knots)
        self.B = _basis(self.knots, self.t)
        self.Bs, self.dBs = _basis(self.knots, self.nodes), _basis(self.knots, self.nodes, 1)

    def fit(self, q):
        """Least-squares spline coefficients ``(c, n_joints)`` of joint samples ``q (n, n_joints)``."""
        return np.linalg.lstsq(self.B, q, rcond=None)[0]


def _yaw_and_jacobian(eq, path: _Path, theta, coef):
    """The yaw change ``(n,)`` from ``t[0]`` that momentum conservation gives for joint splines
    ``coef (c, n_joints)`` and unknowns ``theta (p,)``, and its derivatives ``(n, p)`` in
    ``theta`` and ``(n, n_joints, c)`` in the coefficients.

    At the nodes, ``g = Y(q, qd, w0) pi - h = 0`` defines ``w0``; its derivatives are
    ``-(dg/dx) / (dg/dw0)`` for ``x`` the unknowns (the columns of the equations) and the joint
    angles and rates (:func:`~spaceid.estimation.signal_jacobian`), then chained to the spline
    coefficients through ``B`` and ``B'``."""
    nj = coef.shape[1]
    q, qd = path.Bs @ coef, path.dBs @ coef
    pi, h = eq.full(theta)
    h_base = np.broadcast_to(h, q.shape[:1] + (3,))  # planar: a yaw leaves h_z alone
    w = base_rate(eq.param, pi, q, qd, h_base)
    jac = signal_jacobian(eq.param, pi, q, qd, w)[:, 0]  # (m, 2 nj + 1)
    g_w = jac[:, 2 * nj]
    g_theta = _phi(eq, np.hstack([q, qd, w[:, 2:]]))[:, 0, :-1]
    dw_dcoef = -(jac[:, :nj, None] * path.Bs[:, None] + jac[:, nj : 2 * nj, None] * path.dBs[:, None])
    integrate = lambda f: _cumulative(f, path.weights, path.ends)  # noqa: E731
    return integrate(w[:, 2]), integrate(-g_theta / g_w[:, None]), integrate(dw_dcoef / g_w[:, None, None])


def _model_jacobian(eq, path: _Path, theta, coef, sigma_q, sigma_yaw):
    """Whitened derivatives ``(n (n_joints + 1), p + n_joints c + 1)`` of the predicted joint
    angles and yaw in ``u = [theta, coef (joint by joint), yaw_0]``, and the predicted yaw
    change ``(n,)``."""
    n, c = path.B.shape
    nj, p = coef.shape[1], len(theta)
    yaw, d_theta, d_coef = _yaw_and_jacobian(eq, path, theta, coef)
    J = np.zeros((n * (nj + 1), p + nj * c + 1))
    for j in range(nj):
        J[j * n : (j + 1) * n, p + j * c : p + (j + 1) * c] = path.B / sigma_q
    J[nj * n :, :p] = d_theta / sigma_yaw
    J[nj * n :, p : p + nj * c] = d_coef.reshape(n, -1) / sigma_yaw
    J[nj * n :, -1] = 1 / sigma_yaw
    return J, yaw


def _residuals(path, q, yaw_meas, coef, yaw0, yaw, sigma_q, sigma_yaw):
    """Whitened residuals ``(n (n_joints + 1),)``: joint by joint, then the yaw."""
    return np.concatenate([((q - path.B @ coef) / sigma_q).T.ravel(), (yaw_meas - yaw0 - yaw) / sigma_yaw])


def _levels(noise: Noise, where: str) -> tuple:
    """Joint-angle and yaw noise levels [rad] of ``noise`` (the yaw is the planar attitude)."""
    if not (noise.angle > 0 and noise.attitude > 0):
        raise SpaceidError(f"{where}: the angles estimator weights by the angle and attitude (yaw) noise levels, "
                           f"given as {noise.angle:g} and {noise.attitude:g} rad: give both > 0 (`noise.angle`, "
                           "`noise.attitude`)")  # fmt: skip
    return noise.angle, noise.attitude


def _gauss_newton(eq, path, q, yaw_meas, theta, sigma_q, sigma_yaw, max_iter=30, tol=1e-8):
    """Gauss-Newton on the whitened angle residuals from ``theta``; stops when a step changes no
    unknown by more than ``tol`` of its standard error (quadratic convergence for small
    residuals: a few steps). Returns ``theta``, the joint splines, ``yaw_0``, the inverse Fisher
    matrix of ``u`` (in whitened units: the covariance for the given levels), the residuals and
    the iterations and whether they converged."""
    coef = path.fit(q)
    p, nj = len(theta), q.shape[1]
    J, yaw = _model_jacobian(eq, path, theta, coef, sigma_q, sigma_yaw)
    yaw0 = float(np.mean(yaw_meas - yaw))
    u = np.concatenate([theta, coef.T.ravel(), [yaw0]])
    unpack = lambda u: (u[:p], u[p:-1].reshape(nj, -1).T, u[-1])  # noqa: E731
    r = _residuals(path, q, yaw_meas, coef, yaw0, yaw, sigma_q, sigma_yaw)
    for it in range(1, max_iter + 1):
        step, cov = _solve(J, r)
        cost, lam = r @ r, 1.0
        while True:  # halve the step while the cost grows: a safeguard against a poor start
            trial = unpack(u + lam * step)
            J_new, yaw = _model_jacobian(eq, path, *trial[:2], sigma_q, sigma_yaw)
            r_new = _residuals(path, q, yaw_meas, trial[1], trial[2], yaw, sigma_q, sigma_yaw)
            if r_new @ r_new <= cost * (1 + 1e-12) or lam < 1e-3:
                break
            lam /= 2
        u, J, r = u + lam * step, J_new, r_new
        converged = bool(np.max(np.abs(lam * step) / np.sqrt(np.diag(cov))) < tol)
        if converged:
            break
    _, cov = _solve(J, r)
    theta, coef, yaw0 = unpack(u)
    return theta, coef, yaw0, cov, r, (it, converged)


def _angles_ml(eq, x, sigma, theta, ctx):
    """Kernel of estimator ``angles`` (see :mod:`spaceid.estimation._estimators`): maximum
    likelihood on the angle samples from the integral-form start ``theta``; the rates in ``x``
    are not used. Its covariance (``info["covariance"]``) is the inverse Fisher block of theta."""
    data = ctx.angles
    path, q, yaw_meas = data.path, data.q, data.yaw
    sigma_q, sigma_yaw = _levels(data.noise, data.where)
    theta, coef, _, cov, r, (it, converged) = _gauss_newton(eq, path, q, yaw_meas, theta, sigma_q, sigma_yaw)
    p, dof = len(theta), max(len(r) - cov.shape[0], 1)
    raw = np.concatenate([(r[: q.size] * sigma_q), r[q.size :] * sigma_yaw])
    covariance = (cov[:p, :p], float(r @ r / dof), float(np.sqrt(np.mean(raw**2))))  # cov, chi2_dof, RMS [rad]
    info = {"iterations": it, "converged": converged, "knot_spacing": float(path.knots[4] - path.knots[3]),
            "spline_coefficients": coef.size, "covariance": covariance}  # fmt: skip
    return theta, info


def _integral_equations(eq, path: _Path, q, yaw) -> np.ndarray:
    """The integral form of the momentum equations, ``[A | -b]`` per knot span ``(spans, 1, p + 1)``:
    ``int_span (Y(q, qd, w0) theta_bar) dt`` by the trapezoid rule on the sample path, where on
    each step the rates are the angle increments over the step (the regressor is linear in the
    rates, so ``dt Phi(q, dq / dt, dyaw / dt)`` is ``Y_j(q) dq_j + Y_w(q) dyaw`` and ``R0^T h dt``)."""
    dt = np.diff(path.t)[:, None]
    rates = np.hstack([np.diff(q, axis=0), np.diff(yaw)[:, None]]) / dt
    nj = q.shape[1]
    ends = [np.hstack([q[k], rates[:, :nj], rates[:, nj:]]) for k in (slice(None, -1), slice(1, None))]
    steps = 0.5 * dt[..., None] * (_phi(eq, ends[0]) + _phi(eq, ends[1]))
    span = np.clip(np.searchsorted(path.knots[3:-3], 0.5 * (path.t[1:] + path.t[:-1])) - 1, 0, None)
    out = np.zeros((span.max() + 1,) + steps.shape[1:])
    np.add.at(out, span, steps)
    return out


@dataclass(frozen=True)
class _AngleData:
    """What the ``angles`` kernel fits (``_FitContext.angles``): the joint paths' splines, the measured
    joint angles ``q (n, n_joints)`` and unwrapped yaw ``(n,)`` [rad], the noise levels, and the log's
    name for errors."""

    path: _Path
    q: np.ndarray
    yaw: np.ndarray
    noise: Noise
    where: str


def _angle_context(eq, log: Log, noise: Noise, where: str, spacing: float) -> tuple:
    """The integral-form equations of ``log`` (the start and excitation check) and the
    :class:`_AngleData` of the ``angles`` kernel: path, measured joint angles, unwrapped yaw, noise levels."""
    _planar_only(eq.param, where)
    path = _Path(log.t, spacing, where)
    yaw = np.unwrap(quat_to_yaw(log.base_quat))
    phi = _integral_equations(eq, path, log.q, yaw)
    if len(phi) < eq.p + 1:
        raise SpaceidError(f"{where}: {len(phi)} knot spans give {len(phi)} integral equations for {eq.p} unknowns: "
                           f"record at least {eq.p + 1} spans of {spacing:g} s")  # fmt: skip
    return phi, _AngleData(path, log.q, yaw, noise, where)


def cramer_rao_angles(param, log: Log, momentum, noise: Noise, *, known=None, estimate_momentum=False,
                      knot_spacing: float = KNOT_SPACING):  # fmt: skip
    """Cramer-Rao bound on the parameters from angle measurements.

    The measurements are the joint angles and the base yaw at the log's sample times, with
    white Gaussian noise ``noise.angle`` and ``noise.attitude`` [rad]. The true joint paths are a
    nuisance, cubic splines with knots every ``knot_spacing`` (their true values: the
    least-squares splines of the noise-free angles), with the initial yaw; the yaw follows from
    momentum conservation with the parameters. The bound is the parameter block of the inverse
    Fisher information ``J^T J`` of the whitened predictions, i.e. the inverse of its Schur
    complement with the nuisance eliminated.

    Parameters
    ----------
    param : Parameterization
        Planar; its ``true_values`` are the true parameters.
    log : Log
        The noise-free motion.
    momentum : array_like of shape (3,)
        True inertial momentum [N m s].
    noise : Noise
        ``angle`` (joints) and ``attitude`` (yaw) levels [rad], both > 0.
    known : dict, optional
        Known parameters, as for :func:`spaceid.estimation.identify`.
    estimate_momentum : bool
        Whether the momentum is among the unknowns.
    knot_spacing : float
        Knot spacing of the joint-path splines [s].

    Returns
    -------
    names : list of str
        The unknowns (free parameters, then ``h_z`` if estimated).
    cov : ndarray of shape (p, p)
    """
    _planar_only(param, "cramer_rao_angles")
    momentum = np.asarray(momentum, float)
    eq, _ = _equations(param, log, None if estimate_momentum else momentum, known, "cramer_rao_angles")
    theta = np.concatenate([param.true_values[eq.free], momentum[eq.axes] if estimate_momentum else []])
    path = _Path(log.t, knot_spacing, "cramer_rao_angles")
    sigma_q, sigma_yaw = _levels(noise, "cramer_rao_angles")
    J, _ = _model_jacobian(eq, path, theta, path.fit(log.q), sigma_q, sigma_yaw)
    return eq.names(), _inverse_gram(J)[: eq.p, : eq.p]
