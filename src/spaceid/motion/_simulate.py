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

from .._errors import SpaceidError
from ..dynamics import angular_momentum, system_com
from ..dynamics import base_rate, rate_pieces
from ..dynamics import Parameterization
from ..data import Log, quat_to_matrix, yaw_to_quat
from ..estimation import Noise, drift_basis, drift_terms, drift_vector
from ._attitude import collocation_steps, gauss_tableau

__all__ = ["simulate", "hermite_motion", "add_noise"]


def hermite_motion(t, q, qd):
    """Joint motion through sampled angles and rates (cubic Hermite), as ``f(t) -> (q, qd)``: on each
    interval of ``t (n,)`` the cubic with the samples' angles ``q (n, ...)`` and rates ``qd`` at its ends,
    past the first and last samples the end intervals' cubics (as SciPy's ``CubicHermiteSpline``, to
    round-off, without importing ``scipy.interpolate``: 0.3 s of a ``validate`` command's start)."""
    t, q, qd = (np.asarray(a, float) for a in (t, q, qd))
    if len(t) < 2 or not np.all(np.diff(t) > 0):
        raise ValueError("hermite_motion: the sample times must be at least two, strictly increasing")

    def motion(times):
        times = np.asarray(times, float)
        i = np.clip(np.searchsorted(t, times, side="right") - 1, 0, len(t) - 2)
        h = t[i + 1] - t[i]
        s = (times - t[i]) / h
        s, h = (np.reshape(a, np.shape(a) + (1,) * (q.ndim - 1)) for a in (s, h))
        q0, q1, m0, m1 = q[i], q[i + 1], qd[i], qd[i + 1]
        s2 = s * s
        angles = (q0 + s2 * (2 * s - 3) * (q0 - q1)) + h * s * ((s - 1) ** 2 * m0 + s * (s - 1) * m1)
        rates = 6 * s * (s - 1) * (q0 - q1) / h + (3 * s2 - 4 * s + 1) * m0 + s * (3 * s - 2) * m1
        return angles, rates

    return motion


POINTS = 32_768
"""Time points whose base rate is evaluated at once: the regressor behind it takes ``rows x k``
floats a point (12 kB for the dual-arm servicer), so a long log is evaluated in blocks of this
many, and the memory stays bounded whatever its length."""


def _in_blocks(f, t):
    """``f(t)`` of a function of each time alone, evaluated on blocks of ``POINTS`` times of ``t
    (n,)`` and concatenated along the first axis (the same values as one call; a tuple of arrays
    element by element)."""
    t = np.asarray(t, float)
    if len(t) <= POINTS:
        return f(t)
    parts = [f(t[i : i + POINTS]) for i in range(0, len(t), POINTS)]
    if isinstance(parts[0], tuple):
        return tuple(np.concatenate(p) for p in zip(*parts))
    return np.concatenate(parts)


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


def _gauss_cumulative(order: int = 8) -> np.ndarray:
    """``S (order, order)``: ``S @ v`` is the integral from -1 to each Gauss-Legendre node of the polynomial
    (degree ``order - 1``) through the values ``v`` at the nodes."""
    from numpy.polynomial import legendre

    nodes, _ = legendre.leggauss(order)
    lagrange = np.linalg.inv(legendre.legvander(nodes, order - 1))  # column j: coefficients of the j-th basis
    return legendre.legval(nodes, legendre.legint(lagrange, lbnd=-1)).T


def _planar_pieces(param, pi, motion, t) -> tuple:
    """The joints' own momentum about z [N m s] and the locked inertia about z [kg m^2] at the times ``t (n,)``,
    each ``(n,)``: the yaw rate for a momentum ``h`` is ``(h - own) / locked``."""
    def pieces(t):
        free, unit, _ = rate_pieces(param, *motion(t), functools.partial(param.momentum, pi=pi))
        return np.column_stack([free[:, 0], unit[0][:, 0]])

    both = _in_blocks(pieces, np.atleast_1d(np.asarray(t, float)))
    return both[:, 0], both[:, 1]


def _planar_linear_drift(param, pi, motion, times, y0, tau, c, rtol) -> tuple:
    """States ``[yaw, h_z]`` ``(n, 2)`` at ``times`` from ``y0`` at ``times[0]``, of a planar system under a
    constant torque ``tau`` and viscous friction ``c`` about z: with ``L`` the locked inertia and ``o`` the
    joints' own momentum, the momentum obeys the linear ``dh/dt = -(c / L) h + tau + c o / L``, solved through
    its integrating factor ``exp(int c / L)`` and the yaw rate ``(h - o) / L`` integrated, all on the 8-point
    Gauss-Legendre panels of :func:`_gauss_cumulative` (each sample interval, where the joint motion is
    smooth, split into ``m`` panels, ``m`` doubling until two results agree to ``rtol``): a quadrature,
    vectorised, where an ODE solver stepped through every kink of the interpolated joint rates (agreeing to
    ``rtol`` of the momentum's magnitude and of the yaw's, or of the most the rate could turn it: a short span
    where the rate crosses zero turns it by next to nothing). Also the panels' node times and the yaw rate
    there, each ``(n - 1, 8 m)`` in time order (where a Coulomb torque's sign change shows)."""
    from itertools import accumulate

    nodes, weights = np.polynomial.legendre.leggauss(8)
    cumulative = _gauss_cumulative(8).T
    lo, width, previous = times[:-1], np.diff(times), None
    for m in (1, 2, 4, 8, 16, 32, 64):
        half = np.repeat(width / m / 2, m)  # of each panel, (P,)
        t = (lo[:, None] + width[:, None] * np.arange(m) / m).ravel()[:, None] + half[:, None] * (nodes + 1)
        own, locked = (a.reshape(t.shape) for a in _planar_pieces(param, pi, motion, t.ravel()))
        a, f = c / locked, tau + c * own / locked
        grow = half[:, None] * (a @ cumulative)  # int a from the panel's start to each node
        lift = np.exp(grow) * f
        gain = half[:, None] * (lift @ cumulative)
        # the momentum at the panels' starts: h_{p+1} = exp(-int_p a) (h_p + int_p exp(int a) f)
        steps = zip(np.exp(-half * (a @ weights)), half * (lift @ weights))
        starts = np.fromiter(accumulate(steps, lambda h, step: step[0] * (h + step[1]), initial=float(y0[1])), float,
                             len(half) + 1)
        rate = (np.exp(-grow) * (starts[:-1, None] + gain) - own) / locked
        turned = np.concatenate([[0.0], np.cumsum((half * (rate @ weights)).reshape(-1, m).sum(1))])
        current = np.column_stack([turned, starts[::m]])
        reach = [abs(y0[0]) + np.abs(rate).max() * (times[-1] - times[0]), 1e-300]
        if previous is not None and np.all(np.abs(current - previous).max(0)
                                           <= rtol * np.maximum(np.abs(current).max(0), reach)):
            return current + [y0[0], 0.0], t.reshape(len(lo), -1), rate.reshape(len(lo), -1)
        previous = current
    raise SpaceidError("simulation failed: the base rate is too rough to integrate; sample the motion more finely")


_AHEAD = 128
"""Samples a segment of :func:`_planar_drift` integrates at a time: past a sign change the rest is integrated
again with the other sign, so the work a change wastes is bounded."""
_STICTION = "the Coulomb torque (drift coulomb) holds the base at rest (stiction), which is not modelled: use a " \
            "smaller coulomb value"


def _planar_drift(param, pi, motion, times, y0, terms, rtol) -> np.ndarray:
    """States ``[yaw, h_z]`` ``(n, 2)`` at ``times`` (a block of :func:`_in_sample_blocks`) from ``y0``: the
    quadrature of :func:`_planar_linear_drift`, under a Coulomb torque ``-mu sign(w)`` segment by segment, the
    torque constant between the zero crossings of the yaw rate ``w``, :data:`_AHEAD` samples at a time. A
    crossing shows as a sign change of the rate at the samples or the panels' nodes; Brent's method locates it
    to round-off (the state at each trial time integrated from the sample before), and the next segment starts
    from there with the other sign; a torque that would hold the base at rest there is an error (stiction is
    not modelled)."""
    from scipy.optimize import brentq

    tau = float(np.asarray(terms.get("torque", np.zeros(3)), float)[2])
    c, mu = float(terms.get("viscous", 0.0)), float(terms.get("coulomb", 0.0))
    if not mu:
        return _planar_linear_drift(param, pi, motion, times, y0, tau, c, rtol)[0]

    def rate(t, h):
        own, locked = _planar_pieces(param, pi, motion, t)
        return (h - own) / locked

    def leaves(t, h, s):  # whether the rate, at zero, moves to the side of s under the torque of that sign
        step = 1e-7 * (times[-1] - times[0])
        return s * (rate(t + step, h + step * (tau - mu * s)) - rate(t, h))[0] > 0

    t0, y = times[0], np.asarray(y0, float)
    s = np.sign(rate(t0, y[1])[0]) or next((side for side in (1.0, -1.0) if leaves(t0, y[1], side)), 0.0)
    out = []
    while True:
        if not s:
            raise SpaceidError(f"simulation failed: at t = {t0:.6g} s {_STICTION}")
        after = np.searchsorted(times, t0, "right")
        grid = np.concatenate([[t0], times[after : after + _AHEAD]])
        states, node_t, node_w = _planar_linear_drift(param, pi, motion, grid, y, tau - mu * s, c, rtol)
        probe_t = np.append(np.column_stack([grid[:-1], node_t]).ravel(), grid[-1])  # samples and nodes in order
        at_samples = rate(grid, states[:, 1])  # one evaluation of the joint motion at every sample
        probe_w = np.append(np.column_stack([at_samples[:-1], node_w]).ravel(), at_samples[-1])
        past = np.flatnonzero(s * probe_w[1:] <= 0)
        if not len(past):  # on to the next samples, or done
            out.append(states if not out else states[1:])
            if grid[-1] == times[-1]:
                return np.concatenate(out)
            t0, y = grid[-1], states[-1]
            continue
        left, right = probe_t[past[0]], probe_t[past[0] + 1]  # the rate of sign s at left, past zero at right
        k = np.searchsorted(grid, left, "right") - 1  # the sample interval holding both

        def state(t, k=k, start=states[k], s=s):  # from the sample before, under the torque of sign s
            if t == grid[k]:
                return start
            return _planar_linear_drift(param, pi, motion, np.array([grid[k], t]), start, tau - mu * s, c, rtol)[0][-1]

        def signed(t, s=s):  # s w (t); at the segment's start, where w is zero to round-off, of sign s
            value = s * rate(t, state(t)[1])[0]
            return max(value, np.finfo(float).tiny) if t == grid[0] else value

        t0 = brentq(signed, left, right, xtol=1e-14 * max(abs(right), 1.0), rtol=4 * np.finfo(float).eps)
        out.append(states[: k + 1] if not out else states[1 : k + 1])  # the samples before the crossing
        y, s = state(t0), -s
        if not leaves(t0, y[1], s):
            raise SpaceidError(f"simulation failed: at t = {t0:.6g} s {_STICTION}")
        if len(out) > 10 * len(times) + 1000:  # (windows and sign changes)
            raise SpaceidError("simulation failed: the base rate changes sign too often for the Coulomb torque")


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
    where: str = "`pi`",
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
        Relative tolerance of the attitude integration: for planar systems a Gauss-Legendre
        quadrature of the yaw rate, for spatial ones Gauss-Legendre collocation on the quaternion
        (order 8), both with their steps halved until two successive results agree to ``rtol``
        at every sample; with ``drift``, planar: the same quadrature of the momentum's linear
        equation (:func:`_planar_drift`; under a Coulomb torque segment by segment between its sign
        changes), spatial: the same collocation carrying the momentum.
    drift : dict, optional
        External torques on the base, ``{"torque": tau, "viscous": c, "coulomb": mu}`` (any
        subset; ``tau`` [N m] 3 inertial components or, planar, a number about z; ``c`` [N m
        s/rad], ``mu`` [N m]): the momentum becomes a state, ``dh/dt = tau - c R0 w0 - mu R0 w0 /
        |w0|`` (docs/theory/drift.md), integrated with the attitude (see ``rtol``; a planar Coulomb
        torque's sign changes are located by root finding, and a base it would hold at rest is an error).
        ``meta["momentum_balance_error"]`` then records the largest difference of the output's
        momentum change from the integral of the external torque (the quadrature that
        identification uses), relative to the momentum (a warning above 1e-6: samples too sparse
        to integrate the drift). Omitted or all zero: constant momentum.
    base_position : bool, default False
        Also output the base position (``Log.base_position``), which needs ``model``. Convention:
        zero linear momentum with the system CM fixed at the inertial origin, so the base origin
        is at ``-R0 c(q)`` (:func:`spaceid.dynamics.system_com`).

    where : str
        What ``pi`` is, for the error message (e.g. the result file it came from).

    Returns
    -------
    Log
        Noise-free joint and base motion at ``times``.

    Raises
    ------
    SpaceidError
        ``pi`` gives a locked inertia (the base rate to angular momentum map at fixed joints) that
        is not positive definite somewhere along the motion: checked, vectorised, at the output
        times before anything is integrated and at every stage time of the attitude integration
        (with ``drift``: on a grid 8 times denser before each block); the message names
        the time, the eigenvalue's direction in base axes and the parameters that make it
        negative. Or the attitude integration fails or exceeds :data:`MAX_EVALUATIONS`.
    """
    if hasattr(motion, "evaluate"):
        motion = functools.partial(_angles_and_rates, motion)
    times = np.asarray(times, float)
    momentum = np.asarray(momentum, float)
    quat0 = np.array([1.0, 0, 0, 0]) if initial_quat is None else np.asarray(initial_quat, float)
    terms = drift_terms(drift, param.model.planar, where="`drift`", physical=False)  # estimates may be < 0
    # before integrating: at the samples here (planar: on the denser grid too, a 1 x 1 inertia), and at the
    # stage times of the spatial collocation as it goes (the pieces are evaluated there anyway)
    check = _grid(times) if param.model.planar else times
    _in_blocks(lambda t: _check_locked_inertia(param, pi, motion, t, where), check)
    if any(np.any(v) for v in terms.values()):
        return _simulate_drifting(param, pi, motion, times, momentum, terms, quat0, model, joints, rtol, where)

    if param.model.planar:
        # the base rate does not depend on the yaw: the yaw is a quadrature, done vectorised
        rate = lambda t: base_rate(param, pi, *motion(t), momentum)[:, 2]  # noqa: E731
        quat = yaw_to_quat(2 * np.arctan2(quat0[3], quat0[0]) + _cumulative_integral(rate, times, rtol))
    else:
        # w0 = A(t)^-1 (R0^T h - b(t)): A and b depend on the joint motion only, evaluated vectorised at
        # every stage time; the attitude is then integrated step by step (:mod:`._attitude`); the output
        # rates are solved exactly at the samples, so momentum holds there
        quat = _integrated_attitude(param, pi, motion, times, momentum, quat0, rtol, where)[:, :4]
    q, qd = _in_blocks(motion, times)
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


def _integrated_attitude(param, pi, motion, times, momentum, quat0, rtol, where, torque=None, viscous=0.0,
                         coulomb=0.0) -> np.ndarray:
    """Base attitudes and inertial momenta ``(n, 7)`` at ``times`` of a spatial system whose momentum is
    ``momentum`` at ``times[0]`` and changes by a constant external ``torque`` (3, inertial axes; default
    none), viscous friction ``viscous`` [N m s/rad] and Coulomb friction ``coulomb`` [N m] (default 0: the
    momentum constant).

    A block of :data:`BLOCK_SAMPLES` samples at a time (:func:`_in_sample_blocks`): Gauss-Legendre collocation
    (:func:`._attitude.collocation_steps`) with ``m`` steps between samples, ``m`` doubling from 1 until two
    successive solutions differ by at most ``rtol`` at every sample of the block (the momentum relative to its
    largest; the error of the finer, of order 8, is then about ``rtol / 256``), or by no more than round-off
    explains. The locked inertia is refused where it is not positive definite at a stage time
    (:func:`_refuse_indefinite`); the stage times evaluated count against :data:`MAX_EVALUATIONS`."""
    c, b, a = gauss_tableau()
    budget = [MAX_EVALUATIONS[0] + MAX_EVALUATIONS[1] * len(times)]
    drift = (np.zeros(3) if torque is None else np.asarray(torque, float), float(viscous), float(coulomb))
    state = np.concatenate([np.asarray(quat0, float) / np.linalg.norm(quat0), np.asarray(momentum, float)])
    states = _in_sample_blocks(times, state, lambda state, block: _attitude_block(
        param, pi, motion, block, state, rtol, where, (c, b, a), budget, drift))
    states[:, :4] /= np.linalg.norm(states[:, :4], axis=1, keepdims=True)
    return states


def _attitude_block(param, pi, motion, block, state, rtol, where, tableau, budget, drift) -> np.ndarray:
    """:func:`_integrated_attitude` over the samples ``block (n,)`` from ``state`` (attitude and momentum) at
    ``block[0]`` under ``drift`` (torque, viscous, Coulomb); ``budget`` (one number in a list) is what is left
    of the evaluations and is spent here."""
    c, b, a = tableau
    if len(block) < 2:
        return state[None]
    previous, gap, where_worst, m = None, np.inf, block[0], 1
    while True:
        widths = np.repeat(np.diff(block) / m, m)
        starts = np.repeat(block[:-1], m) + widths * np.tile(np.arange(m), len(block) - 1)
        nodes = starts[:, None] + widths[:, None] * c  # (steps, stages)
        budget[0] -= nodes.size
        if budget[0] < 0:
            total = MAX_EVALUATIONS[0] + MAX_EVALUATIONS[1] * len(block)
            raise SpaceidError(f"simulation failed: the base rate is too steep to integrate near t = {where_worst:.6g} "
                               f"s ({total} evaluations): {_softest(param, pi, motion, where_worst)}; check the "
                               "parameters against a physical model, or sample the motion more finely")
        inverse, offset = _in_blocks(lambda t: _inverse_pieces(param, pi, motion, t, where), nodes.ravel())
        shape = nodes.shape
        out = np.empty((len(widths) + 1, 7))
        failed = collocation_steps(state, inverse.reshape(shape + (3, 3)), offset.reshape(shape + (3,)), *drift,
                                   widths, a, b, out)
        if failed >= 0:  # the stage equations diverge on steps this long: halve them
            previous, where_worst = None, starts[failed]
        else:
            current = out[::m]
            if previous is not None:
                scale = np.r_[np.ones(4), np.full(3, max(np.abs(current[:, 4:]).max(), 1e-300))]
                diff = (np.abs(current - previous) / scale).max(axis=1)
                # within the tolerance, or refinement no longer changes it beyond round-off
                floor = 64 * np.finfo(float).eps * np.sqrt(len(widths))
                if diff.max() <= max(rtol, floor) or (diff.max() >= gap / 4 and diff.max() <= 1e3 * floor):
                    return current
                gap, where_worst = diff.max(), block[int(np.argmax(diff))]
            previous = current
        m *= 2


def _softest(param, pi, motion, t) -> str:
    """The locked inertia's smallest eigenvalue at time ``t`` [s] and its direction in base axes,
    as words (where a base rate grows fastest for a given momentum)."""
    q, qd = motion(np.array([float(t)]))
    unit = rate_pieces(param, q, np.zeros_like(qd), functools.partial(param.momentum, pi=pi))[1]
    locked = np.stack(unit, -1)[0]
    eig, vec = np.linalg.eigh(0.5 * (locked + locked.T))
    axis = ", ".join(f"{x:.3g}" for x in vec[:, 0])
    return (f"the locked inertia there has its smallest eigenvalue {eig[0]:.3g} kg m^2 (largest {eig[-1]:.3g}) "
            f"along base axes ({axis})")


def _inverse_pieces(param, pi, motion, t, where):
    """The inverse locked inertia ``(n, 3, 3)`` and the base rate the joints' own momentum
    cancels ``(n, 3)`` (``A^-1 b``) at the times ``t (n,)``; the locked inertia refused where it
    is not positive definite (:func:`_refuse_indefinite`)."""
    free, unit, _ = rate_pieces(param, *motion(t), functools.partial(param.momentum, pi=pi))
    locked = np.stack(unit, -1)
    _refuse_indefinite(param, pi, motion, t, locked, where)
    inverse = np.linalg.inv(locked)
    return inverse, np.einsum("nij,nj->ni", inverse, free)


BALANCE_TOLERANCE = 1e-6
"""Largest relative momentum-balance error of a drifting simulation without a warning."""


BLOCK_SAMPLES = 4096
"""Output samples per block of a re-simulation (:func:`_in_sample_blocks`): the collocation's stage values of a
block (spatial) or the quadrature's panels (planar, with drift) are held a block at a time, so memory is bounded
by the block whatever the log's length."""


def _in_sample_blocks(times, y0, advance) -> np.ndarray:
    """States ``(n, len(y0))`` at ``times``, integrated a block of :data:`BLOCK_SAMPLES` samples at a
    time: ``advance(y, block)`` integrates from ``block[0]``, where the state is ``y``, and returns the
    states at ``block``; consecutive blocks share their boundary sample."""
    parts, y = [], np.asarray(y0, float)
    for start in range(0, max(len(times) - 1, 1), BLOCK_SAMPLES):
        part = advance(y, times[start : start + BLOCK_SAMPLES + 1])
        parts.append(part if start == 0 else part[1:])
        y = part[-1]
    return np.concatenate(parts)


def _grid(times):
    """The output times and a grid 8 times denser, shape ``(m,)``: where a planar joint motion's
    locked inertia is checked (:func:`_check_locked_inertia`). The dense points within 1e-4 of their
    spacing of an output time are left out (a node a rounding error from another: ``k / 50`` and
    ``13.92 j / 7576`` differ by 1e-15 s)."""
    dense = np.linspace(times[0], times[-1], 8 * len(times) + 2001)
    after = np.clip(np.searchsorted(times, dense), 1, max(len(times) - 1, 1))
    gap = np.minimum(np.abs(dense - times[after - 1]), np.abs(times[np.minimum(after, len(times) - 1)] - dense))
    return np.union1d(times, dense[gap > 1e-4 * (dense[1] - dense[0])])


MAX_EVALUATIONS = (100_000, 200)
"""An attitude integration stops with an error after ``a + b n`` evaluations of the base rate
for ``n`` output times, stage times of the collocation (12 a sample when the first halving agrees,
as on 900 samples of a 30 s satellite-7dof motion, with or without drift). A base rate that grows
without bound (a locked inertia singular between the checked times) would otherwise make the steps
ever smaller for hours."""


def _check_locked_inertia(param, pi, motion, t, where):
    """Refuse ``pi`` when the locked inertia of the joint motion is not positive definite at one of
    the times ``t (n,)`` (:func:`_refuse_indefinite`); an empty array otherwise (for :func:`_in_blocks`)."""
    q, qd = motion(t)
    _, unit, _ = rate_pieces(param, q, np.zeros_like(qd), functools.partial(param.momentum, pi=pi))
    _refuse_indefinite(param, pi, motion, t, np.stack(unit, -1), where)
    return np.zeros(0)


INDEFINITE_TOLERANCE = 1e-9
"""A locked inertia whose smallest eigenvalue is below this fraction of its largest counts as
singular: the base rate a momentum gives grows past what an integration can follow."""


def _refuse_indefinite(param, pi, motion, t, locked, where):
    """Raise when the locked inertia ``locked (n, rows, axes)`` (base rate to angular momentum in
    base axes, joints fixed) is not positive definite at one of the times ``t (n,)``: one line with
    the time, the eigenvalue and its direction in base axes, and the parameters whose terms make
    it negative."""
    if param.model.planar:
        locked = locked[..., -1:, :]  # the z row (about the plane's normal)
    sym = 0.5 * (locked + np.swapaxes(locked, -1, -2))
    eig, vec = np.linalg.eigh(sym)
    size = np.abs(eig).max(-1)
    bad = ~(eig[:, 0] > INDEFINITE_TOLERANCE * size)  # NaN counts as bad
    if not bad.any():
        return
    i = int(np.nanargmin(np.where(bad, eig[:, 0] / np.maximum(size, 1e-300), np.inf)))
    v = vec[i, :, 0]
    q, qd = (np.atleast_2d(a)[0] for a in motion(t[i : i + 1]))
    per = np.stack(rate_pieces(param, q, np.zeros_like(qd), param.regressor)[1], -1)  # (rows, k, axes)
    per = per[-1:] if param.model.planar else per
    share = np.asarray(pi, float) * np.einsum("a,akb,b->k", v, per, v)  # eigenvalue = sum of shares
    worst = [k for k in np.argsort(share)[:3] if share[k] < 0]
    axis = "about the base z axis" if param.model.planar else "along base axes (" + ", ".join(f"{x:.3g}" for x in v) + ")"
    names = ", ".join(f"{param.names[k]} ({share[k]:.3g})" for k in worst) or "none negative alone"
    raise SpaceidError(
        f"{where}: the locked inertia (base rate to momentum, joints fixed) is not positive definite along the "
        f"motion: eigenvalue {eig[i, 0]:.3g} kg m^2 (largest magnitude {size[i]:.3g}) {axis} at t = {t[i]:.6g} s ({int(bad.sum())} "
        f"of {len(t)} times checked); the parameters whose terms make it negative: {names}: physically impossible "
        "parameters, whose base rate diverges: use a physical model or an identification that is one")


def _simulate_drifting(param, pi, motion, times, momentum, terms, quat0, model, joints, rtol, where) -> Log:
    """:func:`simulate` with the momentum a state driven by the external torque ``terms``."""
    if param.model.planar:
        y0 = [2 * np.arctan2(quat0[3], quat0[0]), momentum[2]]
    else:
        y0 = np.concatenate([quat0, momentum])

    if param.model.planar:  # linear in the momentum between a Coulomb torque's sign changes: a quadrature
        y = _in_sample_blocks(times, y0, lambda y, block: _planar_drift(param, pi, motion, block, y, terms, rtol))
    else:  # the attitude's collocation, the momentum with it
        y = _integrated_attitude(param, pi, motion, times, momentum, quat0, rtol, where, torque=terms.get("torque"),
                                 viscous=terms.get("viscous", 0.0), coulomb=terms.get("coulomb", 0.0))
    if param.model.planar:
        quat, h = yaw_to_quat(y[:, 0]), np.outer(y[:, 1], [0.0, 0.0, 1.0])
    else:
        quat, h = y[:, :4] / np.linalg.norm(y[:, :4], axis=1, keepdims=True), y[:, 4:]
    q, qd = _in_blocks(motion, times)
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


def _gyro_bias_vector(bias, planar: bool, where: str = "`gyro_bias`") -> np.ndarray:
    """A gyro bias as a 3-vector in base axes [rad/s]: ``bias`` 3 components, or for a planar log a
    number, about z (a planar gyro measures the yaw rate only)."""
    try:
        b = np.atleast_1d(np.asarray(bias, float))
    except (TypeError, ValueError):
        b = np.full(0, np.nan)
    if b.shape == (1,) and planar:
        b = np.array([0.0, 0.0, b[0]])
    if b.shape != (3,) or not np.all(np.isfinite(b)):
        form = "a number (about z) or 3 components" if planar else "3 components (base axes)"
        raise SpaceidError(f"{where}: {bias!r} is not a gyro bias: give {form} [rad/s]")
    if planar and np.any(b[:2]):
        raise SpaceidError(f"{where}: a planar log's gyro measures the yaw rate only: give the bias about z alone")
    return b


def add_noise(log: Log, *, angle: float = 0.0, rate: float = 0.0, seed: int = 0, noise: Noise | None = None,
              quantum: float = 0.0, gyro_bias=None, joint_rate_sensors: bool = True) -> Log:
    """Each sensor's measurement model applied to a noise-free log, seeded and recorded in ``meta``.

    The sensors (docs/theory/sensors.md): joint encoders (white noise, then quantisation to
    ``quantum``), joint-rate sensors (white noise; none without ``joint_rate_sensors``), a star
    tracker (white noise as a small rotation about each base axis; about z only for planar logs)
    and gyros (white noise per axis plus a constant bias).

    Parameters
    ----------
    log : Log
        The true motion.
    angle, rate : float
        One level for joints and base alike: ``angle`` [rad] on the joint angles and the attitude,
        ``rate`` [rad/s] on the joint and base rates (``noise`` gives each sensor its own).
    seed : int
        Seed of the noise; the draws do not depend on how the levels were given.
    noise : Noise, optional
        Each sensor's level: ``angle`` the encoders [rad or m], ``rate`` the joint-rate sensors
        [rad/s or m/s], ``attitude`` the star tracker [rad per axis], ``base_rate`` the gyros'
        white noise [rad/s per axis]; instead of ``angle`` and ``rate``.
    quantum : float
        Encoder resolution [rad or m per count]: the noisy angles are rounded to it (0: none);
        its error is uniform, of std ``quantum / sqrt(12)``.
    gyro_bias : float or array_like of shape (3,), optional
        Constant gyro bias in base axes [rad/s], added to the measured base rate; for a planar
        log a number, about z.
    joint_rate_sensors : bool
        False: no joint-rate sensors: the joint rates are NaN, ``meta["missing_rates"]`` names them
        and :func:`spaceid.data.write_log` leaves their columns out (as a log that had none).

    Returns
    -------
    Log
        The measured log; ``meta`` records ``noise_angle``, ``noise_rate`` (the joints'),
        ``noise_attitude``, ``noise_base_rate``, ``encoder_quantum``, ``gyro_bias`` (3 components,
        base axes), ``joint_rate_sensors`` and ``noise_seed``.
    """
    if not (np.isfinite(angle) and np.isfinite(rate) and angle >= 0 and rate >= 0):
        raise SpaceidError(f"`angle`, `rate`: noise levels must be finite and non-negative, got {angle:g} and {rate:g}")
    if noise is None:
        noise = Noise(angle, rate, rate, angle)
    elif angle or rate:
        raise SpaceidError("`angle`, `rate`: give one level for joints and base alike, or `noise` per sensor, not both")
    if not (np.isfinite(quantum) and quantum >= 0):
        raise SpaceidError(f"`quantum`: {quantum!r} is not an encoder resolution: give a number >= 0 (0: none)")
    bias = np.zeros(3) if gyro_bias is None else _gyro_bias_vector(gyro_bias, log.planar)
    rng = np.random.default_rng(seed)
    n, nj = log.q.shape
    q = log.q + noise.angle * rng.standard_normal((n, nj))
    if quantum:
        q = quantum * np.round(q / quantum)
    qd = log.qd + noise.rate * rng.standard_normal((n, nj))
    if not joint_rate_sensors:
        qd = np.full_like(qd, np.nan)
    axes = slice(2, 3) if log.planar else slice(None)
    w = log.base_w.copy()
    w[:, axes] += noise.base_rate * rng.standard_normal(w[:, axes].shape) + bias[axes]
    tilt = np.zeros((n, 3))
    tilt[:, axes] = noise.attitude * rng.standard_normal(tilt[:, axes].shape)
    # small rotation exp(tilt/2) applied in base axes: q_meas = q_true * dq
    half = np.linalg.norm(tilt, axis=1, keepdims=True) / 2
    dq = np.hstack([np.cos(half), np.sinc(half / np.pi) * tilt / 2])
    w0_, x0, y0, z0 = log.base_quat.T
    w1, x1, y1, z1 = dq.T
    quat = np.stack(
        [w0_ * w1 - x0 * x1 - y0 * y1 - z0 * z1, w0_ * x1 + x0 * w1 + y0 * z1 - z0 * y1,
         w0_ * y1 - x0 * z1 + y0 * w1 + z0 * x1, w0_ * z1 + x0 * y1 - y0 * x1 + z0 * w1], -1
    )
    meta = dict(log.meta, noise_angle=noise.angle, noise_rate=noise.rate, noise_attitude=noise.attitude,
                noise_base_rate=noise.base_rate, encoder_quantum=float(quantum), gyro_bias=bias.tolist(),
                joint_rate_sensors=bool(joint_rate_sensors), noise_seed=seed)
    if not joint_rate_sensors:
        meta.update(rates="missing", missing_rates=[f"qd_{j}" for j in log.joints])
    return Log(log.t, log.joints, q, qd, quat, w, log.planar, meta, log.base_position, log.tau)
