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

Spatial models (:mod:`spaceid.estimation._angles_spatial`): the attitude samples (a star tracker)
replace the yaw, the base rotation increments ``log(R_n^T R_n+1)`` the yaw increments of the
integral form, and the predicted attitude follows ``dR0/dt = R0 [w0]x`` from a nuisance initial
attitude, integrated on the rotation group.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from .._constants import KNOT_SPACING
from .._errors import SpaceidError
from ..data import Log, quat_to_yaw
from ..dynamics import base_rate
from . import _angles_spatial as spatial
from ._angle_path import _cumulative, _Path, automatic_knot_spacing
from ._equations import _equations
from ._linalg import _inverse_gram, _solve
from ._noise import Noise, signal_jacobian

__all__ = ["KNOT_SPACING", "cramer_rao_angles"]


def _phi(eq, x, rot=None):
    """``eq.phi`` at signals ``x (m, n_x)`` that are not the log's samples, with the base rotations
    ``rot (m, 3, 3)`` (planar: the yaw leaves the z row alone, so the identity)."""
    return replace(eq, rot=np.broadcast_to(np.eye(3), (len(x), 3, 3)) if rot is None else rot).phi(x)


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
    """Joint-angle and attitude noise levels [rad] of ``noise`` (planar: the yaw; spatial: per axis)."""
    if not (noise.angle > 0 and noise.attitude > 0):
        raise SpaceidError(f"{where}: the angles estimator weights by the angle and attitude noise levels, "
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
    likelihood on the angle samples from the integral-form start ``theta`` (or ``ctx.angles.start``); the rates
    in ``x`` are not used. Its covariance (``info["covariance"]``) is the inverse Fisher block of theta."""
    data = ctx.angles
    path, q = data.path, data.q
    theta = theta if data.start is None else data.start
    sigma_q, sigma_a = _levels(data.noise, data.where)
    if eq.planar:
        theta, coef, _, cov, r, (it, converged) = _gauss_newton(eq, path, q, data.attitude, theta, sigma_q, sigma_a)
        cov, n_u, r = cov[: len(theta), : len(theta)], cov.shape[0], (r[: q.size], r[q.size :])
    else:
        theta, coef, cov, r, (it, converged) = spatial._gauss_newton(eq, path, q, data.attitude, theta, sigma_q,
                                                                     sigma_a)  # fmt: skip
        n_u = len(theta) + coef.size + 3
    chi2, size = sum(x.ravel() @ x.ravel() for x in r), sum(x.size for x in r)
    raw = np.concatenate([r[0].ravel() * sigma_q, r[1].ravel() * sigma_a])
    covariance = (cov, float(chi2 / max(size - n_u, 1)), float(np.sqrt(np.mean(raw**2))))  # cov, chi2_dof, RMS [rad]
    info = {"iterations": it, "converged": converged, "knot_spacing": float(path.knots[4] - path.knots[3]),
            "spline_coefficients": coef.size, "covariance": covariance}  # fmt: skip
    return theta, info


def _integral_equations(eq, path: _Path, q, attitude) -> np.ndarray:
    """The integral form of the momentum equations, ``[A | -b]`` per knot span ``(spans, rows, p + 1)``:
    ``int_span (Y(q, qd, w0) theta_bar) dt`` by the trapezoid rule on the sample path, where on
    each step the rates are the angle increments over the step (the regressor is linear in the
    rates, so ``dt Phi(q, dq / dt, dphi / dt)`` is ``Y_j(q) dq_j + Y_w(q) dphi`` and ``R0^T h dt``),
    ``dphi`` the yaw increment (planar; ``attitude (n,)``) or the base rotation ``log(R_n^T R_n+1)``
    in base axes (spatial; ``attitude (n, 3, 3)``, the rotations at both ends)."""
    dt = np.diff(path.t)[:, None]
    if eq.planar:
        turn, rots = np.diff(attitude)[:, None], (None, None)
    else:
        turn = spatial.rotation_log(np.swapaxes(attitude[:-1], -1, -2) @ attitude[1:])
        turn = np.hstack([turn, np.zeros_like(turn)])  # no attitude perturbation: the signals' last columns
        rots = (attitude[:-1], attitude[1:])
    rates = np.hstack([np.diff(q, axis=0), turn]) / dt
    ends = [np.hstack([q[k], rates]) for k in (slice(None, -1), slice(1, None))]
    steps = 0.5 * dt[..., None] * (_phi(eq, ends[0], rots[0]) + _phi(eq, ends[1], rots[1]))
    span = np.clip(np.searchsorted(path.knots[3:-3], 0.5 * (path.t[1:] + path.t[:-1])) - 1, 0, None)
    out = np.zeros((span.max() + 1,) + steps.shape[1:])
    np.add.at(out, span, steps)
    return out


@dataclass(frozen=True)
class _AngleData:
    """What the ``angles`` kernel fits (``_FitContext.angles``): the joint paths' splines, the measured
    joint angles ``q (n, n_joints)``, the attitude (planar: the unwrapped yaw ``(n,)`` [rad]; spatial:
    the base-to-inertial rotations ``(n, 3, 3)``), the noise levels, the log's name for errors, and the start
    ``(p,)`` of the fit when not the integral form's (spatial: ML on differentiated rates), else None."""

    path: _Path
    q: np.ndarray
    attitude: np.ndarray
    noise: Noise
    where: str
    start: np.ndarray | None = None


def _angle_context(eq, log: Log, noise: Noise, where: str, spacing: float | None) -> tuple:
    """The integral-form equations of ``log`` (the start and excitation check) and the
    :class:`_AngleData` of the ``angles`` kernel: path, measured joint angles and attitude, noise levels.
    ``spacing`` None: ``KNOT_SPACING`` (planar), :func:`automatic_knot_spacing` (spatial)."""
    if spacing is None:  # spatial: the attitude's derivatives are dense in the spline coefficients, so as few as fit
        spacing = KNOT_SPACING if eq.planar or not noise.angle > 0 else automatic_knot_spacing(log.t, log.q, noise.angle)
    path = _Path(log.t, spacing, where)
    attitude = np.unwrap(quat_to_yaw(log.base_quat)) if eq.planar else eq.rot
    phi = _integral_equations(eq, path, log.q, attitude)
    if phi.shape[0] * phi.shape[1] < eq.p + 1:
        rows, spans = phi.shape[1], -(-(eq.p + 1) // phi.shape[1])
        raise SpaceidError(f"{where}: {len(phi)} knot spans give {len(phi) * rows} integral equations for {eq.p} "
                           f"unknowns: record at least {spans} spans of {spacing:g} s")  # fmt: skip
    return phi, _AngleData(path, log.q, attitude, noise, where)


def cramer_rao_angles(param, log: Log, momentum, noise: Noise, *, known=None, estimate_momentum=False,
                      knot_spacing: float = KNOT_SPACING):  # fmt: skip
    """Cramer-Rao bound on the parameters from angle measurements.

    The measurements are the joint angles and the base attitude at the log's sample times (planar:
    the yaw; spatial: the rotation, e.g. a star tracker's, with the noise a small rotation about
    each base axis), with white Gaussian noise ``noise.angle`` and ``noise.attitude`` [rad]. The
    true joint paths are a nuisance, cubic splines with knots every ``knot_spacing`` (their true
    values: the least-squares splines of the noise-free angles), with the initial attitude; the
    attitude follows from momentum conservation with the parameters. The bound is the parameter block of the inverse
    Fisher information ``J^T J`` of the whitened predictions, i.e. the inverse of its Schur
    complement with the nuisance eliminated.

    Parameters
    ----------
    param : Parameterization
        Its ``true_values`` are the true parameters.
    log : Log
        The noise-free motion.
    momentum : array_like of shape (3,)
        True inertial momentum [N m s].
    noise : Noise
        ``angle`` (joints) and ``attitude`` (yaw, or per base axis) levels [rad], both > 0.
    known : dict, optional
        Known parameters, as for :func:`spaceid.estimation.identify`.
    estimate_momentum : bool
        Whether the momentum is among the unknowns.
    knot_spacing : float
        Knot spacing of the joint-path splines [s].

    Returns
    -------
    names : list of str
        The unknowns (free parameters, then the momentum's components if estimated).
    cov : ndarray of shape (p, p)
    """
    momentum = np.asarray(momentum, float)
    eq, _ = _equations(param, log, None if estimate_momentum else momentum, known, "cramer_rao_angles")
    theta = np.concatenate([param.true_values[eq.free], momentum[eq.axes] if estimate_momentum else []])
    path = _Path(log.t, knot_spacing, "cramer_rao_angles")
    sigma_q, sigma_a = _levels(noise, "cramer_rao_angles")
    if not eq.planar:
        return eq.names(), spatial._bound(eq, path, log, theta, sigma_q, sigma_a)
    J, _ = _model_jacobian(eq, path, theta, path.fit(log.q), sigma_q, sigma_a)
    return eq.names(), _inverse_gram(J)[: eq.p, : eq.p]
