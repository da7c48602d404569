"""Free-floating motion under prescribed joint motion, from angular-momentum conservation.

The joints follow a given motion; the base angular velocity is the one that keeps the
angular momentum equal to ``h`` (the minimal regressor is linear in ``w0``), and the base
attitude is integrated on the unit-quaternion manifold. The same routine re-simulates an
identified model (only ``pi`` is needed) for prediction and validation.
"""

from __future__ import annotations

import functools
import warnings
from dataclasses import replace

import numpy as np
from scipy.integrate import solve_ivp
from scipy.interpolate import CubicHermiteSpline, CubicSpline

from .._errors import SpaceidError
from ..dynamics import angular_momentum, system_com
from ..dynamics import base_rate, rate_pieces
from ..dynamics import Parameterization
from ..data import Log, quat_to_matrix, yaw_to_quat
from ..estimation import drift_basis, drift_terms, drift_vector

__all__ = ["simulate", "hermite_motion", "add_noise"]


def hermite_motion(t, q, qd):
    """Joint motion through sampled angles and rates (cubic Hermite), as ``f(t) -> (q, qd)``."""
    spline = CubicHermiteSpline(np.asarray(t, float), np.asarray(q, float), np.asarray(qd, float), axis=0)
    deriv = spline.derivative()
    return lambda tt: (spline(tt), deriv(tt))


POINTS = 32_768
"""Time points whose base rate is evaluated at once: the regressor behind it takes ``rows x k``
floats a point (12 kB for the dual-arm servicer), so a long log is evaluated in blocks of this
many, and the memory stays bounded whatever its length."""


def _in_blocks(f, t):
    """``f(t)`` of a function of each time alone, evaluated on blocks of ``POINTS`` times of ``t
    (n,)`` and concatenated along the first axis (the same values as one call)."""
    t = np.asarray(t, float)
    if len(t) <= POINTS:
        return f(t)
    return np.concatenate([f(t[i : i + POINTS]) for i in range(0, len(t), POINTS)])


def _cumulative_integral(f, times, rtol):
    """``int_{t0}^{t_i} f dt`` at every time (composite 8-point Gauss-Legendre, vectorised).

    Each interval between output times is split into ``m`` panels, ``m`` doubling until two
    successive results agree to ``rtol`` (relative to the largest |integral|).
    """
    nodes, weights = np.polynomial.legendre.leggauss(8)
    lo, width = times[:-1], np.diff(times)
    previous = None
    for m in (1, 2, 4, 8, 16, 32, 64):
        edges = lo[:, None] + width[:, None] * np.arange(m) / m  # panel starts, (n - 1, m)
        half = (width / m / 2)[:, None, None]
        t = edges[..., None] + half * (nodes + 1)
        pieces = (_in_blocks(f, t.ravel()).reshape(t.shape) * weights).sum(-1) * half[..., 0]
        current = np.concatenate([[0.0], np.cumsum(pieces.sum(-1))])
        if previous is not None and np.abs(current - previous).max() <= rtol * max(np.abs(current).max(), 1e-300):
            return current
        previous = current
    raise SpaceidError("simulation failed: the base rate is too rough to integrate; sample the motion more finely")


def _quat_rate(quat, w):
    """Time derivative of a scalar-first quaternion for body-axes angular velocity ``w``."""
    qw, qx, qy, qz = quat
    wx, wy, wz = w
    return 0.5 * np.array(
        [-qx * wx - qy * wy - qz * wz, qw * wx + qy * wz - qz * wy,
         qw * wy - qx * wz + qz * wx, qw * wz + qx * wy - qy * wx]
    )


def _angles_and_rates(trajectory, t):
    q, qd, _ = trajectory.evaluate(t)
    return q, qd


def simulate(
    param: Parameterization,
    pi,
    motion,
    times,
    momentum,
    *,
    joints=None,
    initial_quat=None,
    model=None,
    rtol: float = 1e-12,
    drift=None,
    base_position: bool = False,
) -> Log:
    """Simulate the base motion for a prescribed joint motion and a constant or drifting momentum.

    Parameters
    ----------
    param : Parameterization
    pi : array_like of shape (k,)
        Parameters of the simulated system (true or identified).
    motion : callable or FourierTrajectory
        ``motion(t) -> (q, qd)`` with ``t`` of shape (n,) and results (n, n_joints) [rad,
        rad/s], or a trajectory (anything with ``evaluate(t) -> (q, qd, qdd)``).
    times : array_like of shape (n_samples,)
        Output time stamps [s], increasing.
    momentum : array_like of shape (3,)
        Inertial angular momentum [N m s] (at ``times[0]`` with ``drift``).
    joints : tuple of str, optional
        Joint names for the log (default: the model's).
    initial_quat : array_like of shape (4,), optional
        Base attitude at ``times[0]`` (default identity).
    model : Model, optional
        The physical model behind ``pi``: when given, the output's momentum is recomputed
        from rigid-body definitions and its largest relative error stored in
        ``meta["momentum_rel_error"]`` (a conservation check independent of ``pi``).
    rtol : float
        Relative tolerance of the attitude integration (Gauss-Legendre quadrature of the yaw
        rate for planar systems, DOP853 on the quaternion for spatial ones).
    drift : dict, optional
        External torques on the base, ``{"torque": tau, "viscous": c, "coulomb": mu}`` (any
        subset; ``tau`` [N m] 3 inertial components or, planar, a number about z; ``c`` [N m
        s/rad], ``mu`` [N m]): the momentum becomes a state, ``dh/dt = tau - c R0 w0 - mu R0 w0 /
        |w0|`` (docs/theory/drift.md), integrated with the attitude (DOP853; a Coulomb torque's
        sign changes are located as events, and a base it would hold at rest is an error).
        ``meta["momentum_balance_error"]`` then records the largest difference of the output's
        momentum change from the integral of the external torque (the quadrature that
        identification uses), relative to the momentum (a warning above 1e-6: samples too sparse
        to integrate the drift). Omitted or all zero: constant momentum.
    base_position : bool, default False
        Also output the base position (``Log.base_position``), which needs ``model``. Convention:
        zero linear momentum with the system CM fixed at the inertial origin, so the base origin
        is at ``-R0 c(q)`` (:func:`spaceid.dynamics.system_com`).

    Returns
    -------
    Log
        Noise-free joint and base motion at ``times``.
    """
    if hasattr(motion, "evaluate"):
        motion = functools.partial(_angles_and_rates, motion)
    times = np.asarray(times, float)
    momentum = np.asarray(momentum, float)
    quat0 = np.array([1.0, 0, 0, 0]) if initial_quat is None else np.asarray(initial_quat, float)
    terms = drift_terms(drift, param.model.planar, where="`drift`", physical=False)  # estimates may be < 0
    if any(np.any(v) for v in terms.values()):
        return _simulate_drifting(param, pi, motion, times, momentum, terms, quat0, model, joints, rtol)

    if param.model.planar:
        # the base rate does not depend on the yaw: the yaw is a quadrature, done vectorised
        rate = lambda t: base_rate(param, pi, *motion(t), momentum)[:, 2]  # noqa: E731
        quat = yaw_to_quat(2 * np.arctan2(quat0[3], quat0[0]) + _cumulative_integral(rate, times, rtol))
    else:
        # w0 = A(t)^-1 (R0^T h - b(t)): the locked inertia A and free momentum b depend on the
        # joint motion only, so they are evaluated once on a dense grid (batched) and splined;
        # the output rates are then solved exactly at the samples, so momentum holds there.
        locked, offset = _rate_splines(param, pi, motion, times)

        def rhs(t, quat):
            h_base = quat_to_matrix(quat / np.linalg.norm(quat)).T @ momentum
            return _quat_rate(quat, np.linalg.solve(locked(t), h_base - offset(t)))

        sol = solve_ivp(rhs, (times[0], times[-1]), quat0, method="DOP853", t_eval=times, rtol=rtol, atol=1e-14)
        if not sol.success:
            raise SpaceidError(f"simulation failed: {sol.message}")
        quat = sol.y.T / np.linalg.norm(sol.y.T, axis=1, keepdims=True)
    q, qd = motion(times)
    h_base = np.einsum("nji,j->ni", quat_to_matrix(quat), momentum)
    w0 = _in_blocks(lambda k: base_rate(param, pi, q[k.astype(int)], qd[k.astype(int)], h_base[k.astype(int)]),
                    np.arange(len(times)))
    meta = {"momentum": momentum.tolist(), "rtol": rtol}
    if model is not None:
        # planar: about z only; a body whose principal axes tilt out of the plane has momentum about x
        # and y too, which the air bearing's reaction takes up (it is not conserved)
        axes = [2] if param.model.planar else [0, 1, 2]
        h = angular_momentum(model, q, qd, w0, quat)[:, axes]
        meta["momentum_rel_error"] = float(np.abs(h - momentum[axes]).max() / max(np.linalg.norm(momentum), 1e-300))
    names = tuple(joints or param.model.joints)
    position = None
    if base_position:
        if model is None:
            raise SpaceidError("simulate: `base_position` needs the physical model (`model`): pi does not fix "
                               "the system centre of mass")
        position = -np.einsum("nij,nj->ni", quat_to_matrix(quat), system_com(model, q))
    return Log(times, names, q, qd, quat, w0, param.model.planar, meta, position)


BALANCE_TOLERANCE = 1e-6
"""Largest relative momentum-balance error of a drifting simulation without a warning."""


def _rate_splines(param, pi, motion, times):
    """Splines of the locked inertia ``(rows, n_axes)`` and free momentum ``(rows,)`` of the joint
    motion on a grid 8 times denser than ``times`` (the output times among its nodes): the base
    rate for a momentum ``h_base`` in base axes is ``locked^-1 (h_base[rows] - offset)``."""
    grid = np.unique(np.concatenate([times, np.linspace(times[0], times[-1], 8 * len(times) + 2001)]))

    def pieces(t):  # (n, rows, 1 + axes): the free momentum, then the locked inertia's columns
        free, unit, _ = rate_pieces(param, *motion(t), functools.partial(param.momentum, pi=pi))
        return np.stack([free, *unit], -1)

    both = _in_blocks(pieces, grid)
    return CubicSpline(grid, both[..., 1:]), CubicSpline(grid, both[..., 0])


def _drift_rhs(param, locked, offset, terms):
    """``f(t, y, s)`` of the state ``y = [yaw, h_z]`` (planar) or ``[quat, h]`` (spatial) under
    the external torque ``terms``, and the base rate about z ``w(t, y)`` (planar; its sign ``s``
    is held between the events of a Coulomb torque)."""
    tau = np.asarray(terms.get("torque", np.zeros(3)), float)
    c, mu = terms.get("viscous", 0.0), terms.get("coulomb", 0.0)
    if param.model.planar:
        def rate(t, y):
            return (y[1] - offset(t)[0]) / locked(t)[0, 0]

        def rhs(t, y, s):
            w = rate(t, y)
            return np.array([w, tau[2] - c * w - mu * s])

        return rhs, rate

    def rhs(t, y, s):
        quat = y[:4] / np.linalg.norm(y[:4])
        rot = quat_to_matrix(quat)
        w = np.linalg.solve(locked(t), rot.T @ y[4:] - offset(t))
        wi = rot @ w
        norm = np.linalg.norm(wi)
        return np.concatenate([_quat_rate(y[:4], w), tau - c * wi - (mu * wi / norm if norm > 0 else 0.0)])

    return rhs, None


def _moves_away(rhs, rate, t, y, s, span):
    """Whether the base rate, at a zero, moves to the side of sign ``s`` under the Coulomb torque
    of that sign (``False``: the torque would hold the base at rest)."""
    step = 1e-7 * span
    return s * (rate(t + step, y + step * rhs(t, y, s)) - rate(t, y)) > 0


def _integrate_drifting(rhs, rate, y0, times, rtol, coulomb):
    """States ``(n, len(y0))`` at ``times``; with a planar Coulomb torque, segment by segment
    between the zero crossings of the base rate (events), the sign of the torque flipped at each."""
    out, t0, y = [], times[0], np.asarray(y0, float)
    span = times[-1] - times[0]
    stuck = "the Coulomb torque (drift coulomb) holds the base at rest (stiction), which is not modelled: use a " \
            "smaller coulomb value"
    s, events = 0.0, None
    if rate is not None:
        s = np.sign(rate(t0, y)) or next((c for c in (1.0, -1.0) if _moves_away(rhs, rate, t0, y, c, span)), 0.0)
        if coulomb and not s:
            raise SpaceidError(f"simulation failed: at t = {t0:.6g} s {stuck}")
    while True:
        if coulomb and rate is not None:
            events = lambda t, yy, s=s: s * rate(t, yy)  # noqa: E731 - positive until the rate crosses zero
            events.terminal, events.direction = True, -1
        sol = solve_ivp(rhs, (t0, times[-1]), y, method="DOP853", t_eval=times[times >= t0], rtol=rtol, atol=1e-14,
                        args=(s,), events=events)  # fmt: skip
        if not sol.success:
            raise SpaceidError(f"simulation failed: {sol.message}")
        done = sol.t_events[0] if events is not None and len(sol.t_events[0]) else []
        out.append(sol.y.T[sol.t < done[0]] if len(done) else sol.y.T)
        if not len(done):
            break
        t0, y, s = done[0], sol.y_events[0][0], -s
        if not _moves_away(rhs, rate, t0, y, s, span):
            raise SpaceidError(f"simulation failed: at t = {t0:.6g} s {stuck}")
        if len(out) > 10 * len(times) + 1000:
            raise SpaceidError("simulation failed: the base rate changes sign too often for the Coulomb torque")
    return np.concatenate(out)


def _simulate_drifting(param, pi, motion, times, momentum, terms, quat0, model, joints, rtol) -> Log:
    """:func:`simulate` with the momentum a state driven by the external torque ``terms``."""
    locked, offset = _rate_splines(param, pi, motion, times)
    rhs, rate = _drift_rhs(param, locked, offset, terms)
    if param.model.planar:
        y0 = [2 * np.arctan2(quat0[3], quat0[0]), momentum[2]]
    else:
        y0 = np.concatenate([quat0, momentum])
    y = _integrate_drifting(rhs, rate, y0, times, rtol, coulomb=bool(terms.get("coulomb")))
    if param.model.planar:
        quat, h = yaw_to_quat(y[:, 0]), np.outer(y[:, 1], [0.0, 0.0, 1.0])
    else:
        quat, h = y[:, :4] / np.linalg.norm(y[:, :4], axis=1, keepdims=True), y[:, 4:]
    q, qd = motion(times)
    rot = quat_to_matrix(quat)
    w0 = base_rate(param, pi, q, qd, np.einsum("nji,nj->ni", rot, h))
    log = Log(times, tuple(joints or param.model.joints), q, qd, quat, w0, param.model.planar, {})
    kinds = tuple(terms)
    h_out = np.einsum("nij,nj->ni", rot, param.momentum(q, qd, w0, pi) if not param.model.planar
                      else np.pad(param.momentum(q, qd, w0, pi), ((0, 0), (2, 0))))  # fmt: skip
    expected = h[0] + np.einsum("nki,k->ni", drift_basis(log, kinds), drift_vector(terms, kinds, param.model.planar))
    scale = max(np.abs(h).max(), 1e-300)
    meta = {"momentum": h[0].tolist(), "rtol": rtol, "drift": {k: np.asarray(v).tolist() for k, v in terms.items()},
            "momentum_end": h[-1].tolist(), "momentum_balance_error": float(np.abs(h_out - expected).max() / scale)}
    if model is not None:
        axes = [2] if param.model.planar else [0, 1, 2]  # planar: about z only (see simulate)
        meta["momentum_rel_error"] = float(np.abs(angular_momentum(model, q, qd, w0, quat) - h)[:, axes].max() / scale)
    if meta["momentum_balance_error"] > BALANCE_TOLERANCE:
        warnings.warn(f"simulate: the samples are too sparse to integrate the drift (momentum balance off by "
                      f"{meta['momentum_balance_error']:.2g} of the momentum): identification with `drift` from this "
                      "log will be biased by as much; sample more finely", stacklevel=3)
    return replace(log, meta=meta)


def add_noise(log: Log, *, angle: float = 0.0, rate: float = 0.0, seed: int = 0) -> Log:
    """White Gaussian noise on the measured signals, seeded and recorded in ``meta``.

    ``angle`` [rad] on joint angles and on the base attitude (a small rotation about each
    base axis; about z only for planar logs), ``rate`` [rad/s] on joint rates and the base
    angular velocity.
    """
    if angle < 0 or rate < 0:
        raise SpaceidError(f"`angle`, `rate`: noise levels must be non-negative, got {angle:g} and {rate:g}")
    rng = np.random.default_rng(seed)
    n, nj = log.q.shape
    q = log.q + angle * rng.standard_normal((n, nj))
    qd = log.qd + rate * rng.standard_normal((n, nj))
    axes = slice(2, 3) if log.planar else slice(None)
    w = log.base_w.copy()
    w[:, axes] += rate * rng.standard_normal(w[:, axes].shape)
    tilt = np.zeros((n, 3))
    tilt[:, axes] = angle * rng.standard_normal(tilt[:, axes].shape)
    # small rotation exp(tilt/2) applied in base axes: q_meas = q_true * dq
    half = np.linalg.norm(tilt, axis=1, keepdims=True) / 2
    dq = np.hstack([np.cos(half), np.sinc(half / np.pi) * tilt / 2])
    w0_, x0, y0, z0 = log.base_quat.T
    w1, x1, y1, z1 = dq.T
    quat = np.stack(
        [w0_ * w1 - x0 * x1 - y0 * y1 - z0 * z1, w0_ * x1 + x0 * w1 + y0 * z1 - z0 * y1,
         w0_ * y1 - x0 * z1 + y0 * w1 + z0 * x1, w0_ * z1 + x0 * y1 - y0 * x1 + z0 * w1], -1
    )
    meta = dict(log.meta, noise_angle=angle, noise_rate=rate, noise_seed=seed)
    return Log(log.t, log.joints, q, qd, quat, w, log.planar, meta, log.base_position, log.tau)
