"""The ``angles`` estimator and bound for spatial models: the base attitude propagated on the
rotation group (docs/theory/angles.md, "Spatial models").

The momentum equations in base axes, ``A(q) w0 + B(q) qd = R0^T h`` (``A`` the locked inertia
and ``B`` the joints' momentum per unit rate, both linear in pi), give the base rate
``w0 = A^-1 (R0^T h - B qd)``, and the attitude obeys ``dR0/dt = R0 [w0]x``. Along the spline
joint paths of :class:`~spaceid.estimation._angle_path._Path` the attitude is integrated from its
initial value (a nuisance, ``R0(t0) = R_meas(t0) exp([e]x)``) by a fourth-order Runge-Kutta-Munthe-
Kaas scheme on each panel between samples and knots, and its derivatives in the unknowns by the
variational equation of a small rotation in base axes ``d`` (``R0 -> R0 exp([d]x)``),

    dd/dt = -[w0]x d + dw0,   dw0 = -A^-1 (dg/dx dx + dg/dtheta dtheta) + A^-1 [R0^T h]x d,

integrated by the classical Runge-Kutta scheme on the same stages. The attitude residuals are
``log(R_pred^T R_meas)`` in base axes; the measured attitude carries isotropic white noise
``noise.attitude`` per axis. Gauss-Newton on the normal equations (the Jacobian of the attitude
is dense in the spline coefficients: a change of the joint path at one time turns the base for
good).
"""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
from scipy.linalg import cho_factor, cho_solve
from scipy.spatial.transform import Rotation

from ..dynamics import momentum_jacobian, skew
from ._angle_path import _basis
from ._linalg import _accumulate_factor, _blockwise, _column_scale, _solve_factor
from ._noise import signal_jacobian

__all__: list = []

def _exp(v):
    """Rotation matrix ``(3, 3)`` of a rotation vector ``v (3,)`` (Rodrigues; a scalar path for the
    sequential propagation, where numpy's batched routines cost more than they save)."""
    x, y, z = v.tolist()
    th2 = x * x + y * y + z * z
    if th2 < 1e-12:
        a, b = 1 - th2 / 6, 0.5 - th2 / 24
    else:
        th = math.sqrt(th2)
        a, b = math.sin(th) / th, 2 * math.sin(th / 2) ** 2 / th2
    k = np.array([[0.0, -z, y], [z, 0.0, -x], [-y, x, 0.0]])
    return np.eye(3) + a * k + b * (k @ k)


def _dexpinv(s, v):
    """The rate ``ds/dt`` of ``R = R_a exp([s]x)`` for ``dR/dt = R [v]x`` (both ``(3,)``): the inverse of
    the right-trivialised derivative of ``exp``, to the second order in ``s``, all that a
    fourth-order Munthe-Kaas step needs."""
    (a, b, c), (x, y, z) = s.tolist(), v.tolist()
    u = (b * z - c * y, c * x - a * z, a * y - b * x)  # s x v
    return np.array([x + u[0] / 2 + (b * u[2] - c * u[1]) / 12, y + u[1] / 2 + (c * u[0] - a * u[2]) / 12,
                     z + u[2] / 2 + (a * u[1] - b * u[0]) / 12])  # fmt: skip


def rotation_log(rot):
    """Rotation vectors ``(n, 3)`` of rotation matrices ``(n, 3, 3)``."""
    return Rotation.from_matrix(rot).as_rotvec()


class _Grid:
    """The integration stages of one log: the panel edges (sample times and knots), their
    midpoints, the spline bases there (``B, dB (m, c)`` at the ``m = 2 P + 1`` stages, edges at even
    indices), the four basis functions active at each stage (``first (m,)``, ``local, dlocal
    (m, 4)``), and the edge of each sample (``at (n,)``)."""

    def __init__(self, path):
        self.path = path
        edges = np.unique(np.concatenate([path.t, path.knots]))
        self.dt = np.diff(edges)
        self.times = np.empty(2 * len(edges) - 1)
        self.times[0::2], self.times[1::2] = edges, edges[:-1] + self.dt / 2
        self.B, self.dB = _basis(path.knots, self.times), _basis(path.knots, self.times, 1)
        c = self.B.shape[1]
        self.first = np.clip(np.searchsorted(path.knots, self.times, side="right") - 4, 0, c - 4)
        cols = self.first[:, None] + np.arange(4)
        self.local = np.take_along_axis(self.B, cols, 1)
        self.dlocal = np.take_along_axis(self.dB, cols, 1)
        self.at = np.searchsorted(edges, path.t)


def _pieces(param, pi, q, qd):
    """``A^-1 (m, 3, 3)`` and ``-A^-1 B qd (m, 3)`` at joint states ``q, qd (m, n_joints)``:
    ``w0 = a + A^-1 R0^T h``."""
    nj = q.shape[1]
    jac = momentum_jacobian(param, q, qd, np.zeros((len(q), 3)), pi)
    inverse = np.linalg.inv(jac[..., 2 * nj : 2 * nj + 3])
    return inverse, -np.einsum("mij,mjk,mk->mi", inverse, jac[..., nj : 2 * nj], qd)


def _propagate(grid, inverse, a, h, rot0):
    """The attitude ``(m, 3, 3)`` at every stage from ``rot0`` at the first: exact (to the scheme's
    fourth order) at the edges, to third order at the midpoints (where only the variational
    equation uses it)."""
    out = np.empty((len(grid.times), 3, 3))
    rot = out[0] = rot0

    def rate(i, r):
        return a[i] + inverse[i] @ (r.T @ h)

    for k, dt in enumerate(grid.dt):
        i = 2 * k
        s1 = rate(i, rot)
        s2 = _dexpinv(dt / 2 * s1, rate(i + 1, rot @ _exp(dt / 2 * s1)))
        mid = rot @ _exp(dt / 2 * s2)
        s3 = _dexpinv(dt / 2 * s2, rate(i + 1, mid))
        s4 = _dexpinv(dt * s3, rate(i + 2, rot @ _exp(dt * s3)))
        out[i + 1], rot = mid, rot @ _exp(dt / 6 * (s1 + 2 * s2 + 2 * s3 + s4))
        out[i + 2] = rot
    return out


def _forcing(eq, grid, theta, coef, rot, inverse, a):
    """The variational equation's terms at every stage: ``M (m, 3, 3)`` (``dd/dt = M d + ...``), the
    base rate's derivatives in ``theta (m, 3, p)`` and in the active spline coefficients
    ``(m, 3, n_joints, 4)``, and the base rate ``(m, 3)``."""
    pi, h = eq.full(theta)
    q, qd = grid.B @ coef, grid.dB @ coef
    nj = q.shape[1]
    hb = np.einsum("mji,j->mi", rot, h)
    w = a + np.einsum("mij,mj->mi", inverse, hb)
    jac = signal_jacobian(eq.param, pi, q, qd, w, hb)
    g_theta = replace(eq, rot=rot).phi(np.hstack([q, qd, w, np.zeros((len(q), 3))]))[..., :-1]
    d_theta = -inverse @ g_theta
    d_q, d_qd = -inverse @ jac[..., :nj], -inverse @ jac[..., nj : 2 * nj]
    d_coef = d_q[..., None] * grid.local[:, None, None] + d_qd[..., None] * grid.dlocal[:, None, None]
    M = -skew(w) + inverse @ skew(hb)
    return M, d_theta, d_coef, w


def _sensitivity(grid, M, d_theta, d_coef):
    """Derivatives ``(n, 3, p + n_joints c + 3)`` of the attitude at the samples (a small rotation in
    base axes) in ``u = [theta, coef (joint by joint), e]``: the variational equation integrated by
    the classical Runge-Kutta scheme on the stages, from ``d(t0) = e``."""
    p, nj, c = d_theta.shape[-1], d_coef.shape[2], grid.B.shape[1]
    S = np.zeros((3, p + nj * c + 3))
    S[:, -3:] = np.eye(3)
    out = np.empty((len(grid.at), 3, S.shape[1]))
    sample = dict(zip(grid.at.tolist(), range(len(grid.at))))
    offsets = p + c * np.arange(nj)[:, None] + np.arange(4)

    def deriv(i, x):
        k = M[i] @ x
        k[:, :p] += d_theta[i]
        k[:, offsets + grid.first[i]] += d_coef[i]
        return k

    out[0] = S
    for e, dt in enumerate(grid.dt):
        i = 2 * e
        k1 = deriv(i, S)
        k2 = deriv(i + 1, S + dt / 2 * k1)
        k3 = deriv(i + 1, S + dt / 2 * k2)
        k4 = deriv(i + 2, S + dt * k3)
        S = S + dt / 6 * (k1 + 2 * k2 + 2 * k3 + k4)
        if e + 1 in sample:
            out[sample[e + 1]] = S
    return out


def _predict(eq, grid, theta, coef, rot0, jacobian=True):
    """The attitude ``(n, 3, 3)`` that momentum conservation gives at the samples for joint splines
    ``coef (c, n_joints)``, unknowns ``theta (p,)`` and the initial attitude ``rot0 (3, 3)``, and
    with ``jacobian`` its derivatives (:func:`_sensitivity`), else None."""
    pi, h = eq.full(theta)
    inverse, a = _pieces(eq.param, pi, grid.B @ coef, grid.dB @ coef)
    rot = _propagate(grid, inverse, a, h, rot0)
    if not jacobian:
        return rot[2 * grid.at], None
    M, d_theta, d_coef, _ = _forcing(eq, grid, theta, coef, rot, inverse, a)
    return rot[2 * grid.at], _sensitivity(grid, M, d_theta, d_coef)


def _residuals(path, q, rot_meas, coef, rot, sigma_q, sigma_a):
    """Whitened residuals of the joint angles ``(n, n_joints)`` and of the attitude ``(n, 3)``,
    ``log(R_pred^T R_meas)`` in base axes."""
    return (q - path.B @ coef) / sigma_q, rotation_log(np.swapaxes(rot, -1, -2) @ rot_meas) / sigma_a


def _step(path, S, r_q, r_a, sigma_q, sigma_a, p):
    """The Gauss-Newton step ``(n_u,)`` in ``u = [theta, nuisance]``, the covariance ``(p, p)`` of
    ``theta`` (the leading block of ``(J^T J)^-1``) and ``J^T r``, from the attitude derivatives
    ``S (n, 3, n_u)`` and the whitened residuals.

    The nuisance (spline coefficients and initial attitude) is eliminated first: its normal matrix
    is well conditioned (each joint's samples pin its spline; the joint rows are the spline basis of
    that joint's coefficients alone, so their blocks are added without forming them), and its
    Cholesky factor projects the nuisance out of the parameter columns and the residuals. The
    parameters, whose conditioning is the data's, are then solved by the Householder QR of the
    projected columns, which squares no condition number: the covariance holds ``eps cond``."""
    Sa = S.reshape(-1, S.shape[-1]) / sigma_a
    St, Sc = Sa[:, :p], Sa[:, p:]
    c, nj = path.B.shape[1], r_q.shape[1]
    N, g = Sc.T @ Sc, Sc.T @ r_a.ravel()
    rhs = path.B.T @ r_q / sigma_q
    gram = path.B.T @ path.B / sigma_q**2
    for j in range(nj):
        N[j * c : (j + 1) * c, j * c : (j + 1) * c] += gram
        g[j * c : (j + 1) * c] += rhs[:, j]
    scale = np.sqrt(np.diag(N))
    chol = cho_factor(N / np.outer(scale, scale))
    X = cho_solve(chol, (Sc.T @ St) / scale[:, None]) / scale[:, None]  # N_cc^-1 N_ct
    y = cho_solve(chol, g / scale) / scale  # N_cc^-1 g_c
    joints = [path.B @ X[j * c : (j + 1) * c] / sigma_q for j in range(nj)]
    fitted = (path.B @ y[: nj * c].reshape(nj, c).T) / sigma_q
    A = np.vstack([St - Sc @ X, -np.vstack(joints)])
    scale = _column_scale(A)  # Householder QR: its inverse Gram matrix holds eps cond, not eps cond^2
    factor = _blockwise(A, np.concatenate([r_a.ravel() - Sc @ y, (r_q - fitted).T.ravel()]), scale,
                        _accumulate_factor, _accumulate_factor)  # fmt: skip
    step, cov = _solve_factor(factor, scale)
    return np.concatenate([step, y - X @ step]), cov, np.concatenate([St.T @ r_a.ravel(), g])


def _gauss_newton(eq, path, q, rot_meas, theta, sigma_q, sigma_a, max_iter=30, tol=1e-6):
    """Gauss-Newton on the whitened residuals from ``theta``, the splines fitted to the joint samples
    and the measured initial attitude; stops when a step's length in the metric of ``J^T J`` is below
    ``tol`` standard errors. Returns ``theta``, the splines, the covariance of ``theta`` (inverse Fisher
    block, at the last step's start: it moved by less than ``tol`` standard errors since), the
    residuals and the iterations and whether they converged."""
    grid = _Grid(path)
    coef, rot0 = path.fit(q), rot_meas[0]
    p, (c, nj) = len(theta), coef.shape
    rot, S = _predict(eq, grid, theta, coef, rot0)
    r = _residuals(path, q, rot_meas, coef, rot, sigma_q, sigma_a)
    for it in range(1, max_iter + 1):
        step, cov, g = _step(path, S, *r, sigma_q, sigma_a, p)
        cost, lam = sum(x.ravel() @ x.ravel() for x in r), 1.0
        while True:  # halve the step while the cost grows: a safeguard against a poor start
            trial = (theta + lam * step[:p], coef + lam * step[p:-3].reshape(nj, c).T, rot0 @ _exp(lam * step[-3:]))
            rot, S_new = _predict(eq, grid, *trial)
            r_new = _residuals(path, q, rot_meas, trial[1], rot, sigma_q, sigma_a)
            # a rise of 1e-6 in chi2 is round-off, not a worse fit (noise-free data: the cost is ~0)
            if sum(x.ravel() @ x.ravel() for x in r_new) <= cost * (1 + 1e-12) + 1e-6 or lam < 1e-3:
                break
            lam /= 2
        (theta, coef, rot0), S, r = trial, S_new, r_new
        converged = bool(lam * np.sqrt(max(step @ g, 0.0)) < tol)
        if converged:
            break
    return theta, coef, cov, r, (it, converged)


def _bound(eq, path, log, theta, sigma_q, sigma_a):
    """The Cramer-Rao bound ``(p, p)`` on ``theta`` at the true values: the inverse Fisher block at
    the least-squares splines of the noise-free joint angles and the log's initial attitude."""
    coef = path.fit(log.q)
    _, S = _predict(eq, _Grid(path), theta, coef, eq.rot[0])
    return _step(path, S, np.zeros(log.q.shape), np.zeros((len(log.t), 3)), sigma_q, sigma_a, len(theta))[1]
