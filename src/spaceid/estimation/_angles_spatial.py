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
``noise.attitude`` per axis. Levenberg-Marquardt on the normal equations (the Jacobian of the attitude
is dense in the spline coefficients: a change of the joint path at one time turns the base for
good), from ``ml`` on rates differentiated from the same angles (``_identify._rate_start``).
"""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
from scipy.linalg import cho_factor, cho_solve

from ..dynamics import momentum_jacobian, skew
from ._angle_path import _basis
from ._linalg import _column_scale, _factor_of_rows, _solve_factor
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
    from scipy.spatial.transform import Rotation
    return Rotation.from_matrix(rot).as_rotvec()


class _Grid:
    """The integration stages of one log: the panel edges (sample times and knots), their
    midpoints, the spline bases there (``B, dB (m, c)`` at the ``m = 2 P + 1`` stages, edges at even
    indices), the four basis functions active at each stage (``first (m,)``, ``local, dlocal
    (m, 4)``), the edge of each sample (``at (n,)``), and the segments of the attitude's propagation,
    ``starts`` (edge: segment number): one from the first sample (the likelihood), or with
    ``segment`` [s] one from a sample every ``segment`` seconds (multiple shooting, for tests and
    studies of the likelihood's shape)."""

    def __init__(self, path, segment=None):
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
        first = [0] if segment is None else np.unique(np.searchsorted(path.t, path.t[0] + np.arange(0, path.t[-1] - path.t[0], segment)))
        self.starts, self.first_samples = {int(self.at[i]): k for k, i in enumerate(first)}, np.asarray(first)


def _pieces(param, pi, q, qd):
    """``A^-1 (m, 3, 3)`` and ``-A^-1 B qd (m, 3)`` at joint states ``q, qd (m, n_joints)``:
    ``w0 = a + A^-1 R0^T h``."""
    nj = q.shape[1]
    jac = momentum_jacobian(param, q, qd, np.zeros((len(q), 3)), pi)
    inverse = np.linalg.inv(jac[..., 2 * nj : 2 * nj + 3])
    return inverse, -np.einsum("mij,mjk,mk->mi", inverse, jac[..., nj : 2 * nj], qd)


def _propagate(grid, inverse, a, h, rot0):
    """The attitude ``(m, 3, 3)`` at every stage from ``rot0 (segments, 3, 3)`` at the segments' first
    edges (:class:`_Grid`): to the scheme's fourth
    order at the edges, and at the midpoints (where only the variational equation uses it) from the
    quadratic through the stage rates, local error ``O(dt^4)``, which keeps the derivatives at
    fourth order too (a second-order midpoint leaves them at second order, and Gauss-Newton then
    crawls on ill-conditioned problems)."""
    out = np.empty((len(grid.times), 3, 3))

    def rate(i, r):
        return a[i] + inverse[i] @ (r.T @ h)

    for k, dt in enumerate(grid.dt):
        i = 2 * k
        if k in grid.starts:  # a segment's initial attitude
            rot = out[i] = rot0[grid.starts[k]]
        s1 = rate(i, rot)
        s2 = _dexpinv(dt / 2 * s1, rate(i + 1, rot @ _exp(dt / 2 * s1)))
        s3 = _dexpinv(dt / 2 * s2, rate(i + 1, rot @ _exp(dt / 2 * s2)))
        s4 = _dexpinv(dt * s3, rate(i + 2, rot @ _exp(dt * s3)))
        # the midpoint by the quadratic through the three stage rates (Hermite-Simpson): third order
        out[i + 1] = rot @ _exp(dt / 24 * (5 * s1 + 4 * (s2 + s3) - s4))
        rot = out[i + 2] = rot @ _exp(dt / 6 * (s1 + 2 * s2 + 2 * s3 + s4))
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
    """Derivatives ``(n, 3, p + n_joints c + 3 segments)`` of the attitude at the samples (a small
    rotation in base axes) in ``u = [theta, coef (joint by joint), e (segment by segment)]``: the
    variational equation integrated by the classical Runge-Kutta scheme on the stages, from
    ``d = e_k`` at the start of segment ``k``."""
    p, nj, c = d_theta.shape[-1], d_coef.shape[2], grid.B.shape[1]
    size = p + nj * c + 3 * len(grid.starts)
    out = np.empty((len(grid.at), 3, size))
    sample = dict(zip(grid.at.tolist(), range(len(grid.at))))
    offsets = p + c * np.arange(nj)[:, None] + np.arange(4)

    def deriv(i, x):
        k = M[i] @ x
        k[:, :p] += d_theta[i]
        k[:, offsets + grid.first[i]] += d_coef[i]
        return k

    for e, dt in enumerate(grid.dt):
        i = 2 * e
        if e in grid.starts:
            S = np.zeros((3, size))
            S[:, size - 3 * (len(grid.starts) - grid.starts[e]) :][:, :3] = np.eye(3)
            if e in sample:
                out[sample[e]] = S
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
    ``coef (c, n_joints)``, unknowns ``theta (p,)`` and the segments' initial attitudes ``rot0 (segments,
    3, 3)``, and
    with ``jacobian`` its derivatives (:func:`_sensitivity`), else a callable that returns them."""
    pi, h = eq.full(theta)
    inverse, a = _pieces(eq.param, pi, grid.B @ coef, grid.dB @ coef)
    rot = _propagate(grid, inverse, a, h, rot0)

    def derivatives():
        return _sensitivity(grid, *_forcing(eq, grid, theta, coef, rot, inverse, a)[:3])

    return rot[2 * grid.at], derivatives() if jacobian else derivatives


def _residuals(path, q, rot_meas, coef, rot, sigma_q, sigma_a):
    """Whitened residuals of the joint angles ``(n, n_joints)`` and of the attitude ``(n, 3)``,
    ``log(R_pred^T R_meas)`` in base axes."""
    return (q - path.B @ coef) / sigma_q, rotation_log(np.swapaxes(rot, -1, -2) @ rot_meas) / sigma_a


def _linearised(path, S, r_q, r_a, sigma_q, sigma_a, p):
    """The Gauss-Newton system at one point, with the nuisance eliminated: a callable
    ``solve(damping)`` returning the step ``(n_u,)`` in ``u = [theta, nuisance]`` and the covariance
    ``(p, p)`` of ``theta`` (undamped: the leading block of ``(J^T J)^-1``), and ``J^T r``; from the
    attitude derivatives ``S (n, 3, n_u)`` and the whitened residuals.

    The nuisance (spline coefficients and initial attitude) is eliminated first: its normal matrix
    is well conditioned (each joint's samples pin its spline; the joint rows are the spline basis of
    that joint's coefficients alone, so their blocks are added without forming them), and its
    Cholesky factor projects the nuisance out of the parameter columns and the residuals. The
    parameters, whose conditioning is the data's, are then solved by the Householder QR of the
    projected columns, which squares no condition number (the covariance holds ``eps cond``), with
    Levenberg-Marquardt rows ``sqrt(damping)`` times the column norms appended when damped."""
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
    b = np.concatenate([r_a.ravel() - Sc @ y, (r_q - fitted).T.ravel()])
    norms = _column_scale(A)

    def solve(damping=0.0):
        rows = (A, np.sqrt(damping) * np.diag(norms)) if damping else (A,)
        factor = _factor_of_rows(np.vstack(rows), np.concatenate([b, np.zeros(p if damping else 0)]), norms)
        step, cov = _solve_factor(factor, norms)
        return np.concatenate([step, y - X @ step]), cov

    return solve, np.concatenate([St.T @ r_a.ravel(), g])


def _gauss_newton(eq, path, q, rot_meas, theta, sigma_q, sigma_a):
    """Maximum likelihood from ``theta`` (:func:`_levenberg_marquardt`, the attitude propagated from the
    first sample): ``theta``, the splines, the covariance of ``theta``, the residuals, the iterations
    and whether they converged."""
    theta, coef, _, cov, r, info = _levenberg_marquardt(eq, _Grid(path), q, rot_meas, theta, path.fit(q), sigma_q,
                                                        sigma_a)  # fmt: skip
    return theta, coef, cov, r, info


def _levenberg_marquardt(eq, grid, q, rot_meas, theta, coef, sigma_q, sigma_a, max_iter=50, tol=1e-4):
    """Levenberg-Marquardt on the whitened residuals from ``theta``, the splines fitted to the joint
    samples and the measured initial attitude: Gauss-Newton steps while they lower the cost, damped
    in the parameters (tenfold per refusal, a tenth per success) where they do not. Stops when an
    undamped step's length in the metric of ``J^T J`` is below ``tol`` standard errors. Returns
    ``theta``, the splines, the segments' initial attitudes, the covariance of ``theta`` (inverse
    Fisher block, at the last step's start: it moved by less than ``tol`` standard errors since),
    the residuals and the iterations and whether they converged."""
    path, rot0 = grid.path, rot_meas[grid.first_samples]
    p, (c, nj) = len(theta), coef.shape
    rot, S = _predict(eq, grid, theta, coef, rot0)
    r = _residuals(path, q, rot_meas, coef, rot, sigma_q, sigma_a)
    solve, g = _linearised(path, S, *r, sigma_q, sigma_a, p)
    cost, damping, converged = sum(x.ravel() @ x.ravel() for x in r), 0.0, False
    for it in range(1, max_iter + 1):
        step, cov = solve(damping)
        turns = np.array([_exp(e) for e in step[p + nj * c :].reshape(-1, 3)])
        trial = (theta + step[:p], coef + step[p : p + nj * c].reshape(nj, c).T, rot0 @ turns)
        rot, derivatives = _predict(eq, grid, *trial, jacobian=False)
        r_new = _residuals(path, q, rot_meas, trial[1], rot, sigma_q, sigma_a)
        cost_new = sum(x.ravel() @ x.ravel() for x in r_new)
        # a rise of 1e-6 in chi2 is round-off, not a worse fit (noise-free data: the cost is ~0)
        if not cost_new <= cost * (1 + 1e-12) + 1e-6:
            damping = max(10 * damping, 1e-6)
            continue
        converged = not damping and bool(np.sqrt(max(step @ g, 0.0)) < tol)
        (theta, coef, rot0), r, cost, damping = trial, r_new, cost_new, damping / 10 if damping > 1e-9 else 0.0
        if converged:
            break
        solve, g = _linearised(path, derivatives(), *r, sigma_q, sigma_a, p)
    return theta, coef, rot0, cov, r, (it, converged)


def _bound(eq, path, log, theta, sigma_q, sigma_a):
    """The Cramer-Rao bound ``(p, p)`` on ``theta`` at the true values: the inverse Fisher block at
    the least-squares splines of the noise-free joint angles and the log's initial attitude."""
    coef = path.fit(log.q)
    _, S = _predict(eq, _Grid(path), theta, coef, eq.rot[:1])
    solve, _ = _linearised(path, S, np.zeros(log.q.shape), np.zeros((len(log.t), 3)), sigma_q, sigma_a, len(theta))
    return solve()[1]
