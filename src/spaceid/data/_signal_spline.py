"""Cubic smoothing spline on uneven stamps (Reinsch form, banded algebra), its penalty by GCV.

The spline is the natural cubic minimising ``sum (x_i - f(t_i))^2 + lam * integral f''(t)^2 dt``
(the function that :func:`scipy.interpolate.make_smoothing_spline` fits) [5]; ``lam`` minimises
generalised cross-validation [4], with the hat-matrix trace from random sign probes [6].

The numbered references are in the list of :mod:`spaceid.data._signals`.
"""

from __future__ import annotations

import numpy as np
from scipy.linalg import cho_solve_banded, cholesky_banded

from .._errors import SpaceidError

_PROBES = 16  # random sign vectors estimating the spline's hat-matrix trace for GCV


def _spline(t, y, lam, name):
    """Cubic smoothing spline of one channel (n,) in Reinsch form: values, derivative, penalty.

    With steps ``h``, the tridiagonal ``Q`` (n, n-2) of second divided differences and ``R``
    (n-2, n-2), the spline's second derivatives at the inner stamps solve
    ``(R + lam Q^T Q) gamma = Q^T y`` and its values are ``g = y - lam Q gamma`` [5]_.
    ``lam`` [s^3] None: chosen by :func:`_gcv_penalty`.
    """
    q_t, q, solve = _reinsch_operators(t)
    if lam is None:
        lam = _gcv_penalty(t, y, q_t, q, solve)
    try:
        gamma = solve(lam, q_t(y[:, None]))
    except np.linalg.LinAlgError:
        raise SpaceidError(
            f"{name}: `smoothing` {lam:.3g} makes the spline system numerically singular for this "
            "record: give a smaller value"
        ) from None
    value = y - lam * q(gamma)[:, 0]
    h = np.diff(t)
    second = np.r_[0.0, gamma[:, 0], 0.0]  # natural spline: f'' = 0 at both ends
    slope = np.diff(value) / h
    last = slope[-1] + h[-1] * (second[-2] + 2 * second[-1]) / 6  # the end of the last interval
    rate = np.r_[slope - h * (2 * second[:-1] + second[1:]) / 6, last]
    return value, rate, float(lam)


def _reinsch_operators(t):
    """``Q^T v`` (v (n, k)), ``Q gamma`` (gamma (n - 2, k)) and ``solve(lam, rhs)`` for
    ``(R + lam Q^T Q) x = rhs`` by a banded Cholesky factorisation, on the stamps ``t`` (n,)."""
    n, h = t.size, np.diff(t)
    a, c = 1.0 / h[:-1], 1.0 / h[1:]  # column j of Q holds (a_j, b_j, c_j) at rows j, j+1, j+2
    b = -a - c
    bands = np.zeros((2, 3, n - 2))  # upper banded storage of R and of Q^T Q
    bands[0, 2], bands[0, 1, 1:] = (h[:-1] + h[1:]) / 3, h[1:-1] / 6
    bands[1, 2] = a**2 + b**2 + c**2
    bands[1, 1, 1:] = b[:-1] * a[1:] + c[:-1] * b[1:]
    bands[1, 0, 2:] = c[:-2] * a[2:]

    def q_t(v):
        return a[:, None] * v[:-2] + b[:, None] * v[1:-1] + c[:, None] * v[2:]

    def q(gamma):
        out = np.zeros((n, gamma.shape[1]))
        out[:-2] += a[:, None] * gamma
        out[1:-1] += b[:, None] * gamma
        out[2:] += c[:, None] * gamma
        return out

    def solve(lam, rhs):
        return cho_solve_banded((cholesky_banded(bands[0] + lam * bands[1]), False), rhs)

    return q_t, q, solve


def _gcv_penalty(t, y, q_t, q, solve):
    """Spline penalty minimising GCV(lam) = n RSS / tr(I - A)^2 (A the hat matrix) [4]_.

    ``RSS = lam^2 |Q gamma|^2`` and ``tr(I - A) = lam tr(Q M^-1 Q^T)`` with
    ``M = R + lam Q^T Q``; the trace is estimated with fixed random sign probes ``z``
    (``mean z^T Q M^-1 Q^T z``, the same probes for every ``lam``, so the choice is
    reproducible) [6]_. ``lam`` is searched on a grid of quarter decades between equivalent
    bandwidths ``(lam h)^(1/4)`` of a quarter step and a quarter of the record, then refined.
    """
    from scipy.optimize import minimize_scalar
    n, step, span = t.size, np.median(np.diff(t)), t[-1] - t[0]
    probes = np.random.default_rng(0).choice([-1.0, 1.0], size=(n, _PROBES))
    rhs = q_t(np.column_stack([y, probes]))

    def gcv(log_lam):
        lam = 10.0**log_lam
        try:
            solution = solve(lam, rhs)
        except np.linalg.LinAlgError:
            return np.inf
        residual = lam**2 * np.sum(q(solution[:, :1]) ** 2)
        trace = lam * np.mean(np.sum(rhs[:, 1:] * solution[:, 1:], axis=0))
        return n * residual / trace**2

    bounds = np.log10([(step / 4) ** 4 / step, (span / 4) ** 4 / step])
    grid = np.arange(bounds[0], bounds[1] + 0.25, 0.25)
    values = [gcv(g) for g in grid]
    best = int(np.argmin(values))
    refined = minimize_scalar(
        gcv, bounds=(grid[max(best - 1, 0)], grid[min(best + 1, grid.size - 1)]), method="bounded",
        options={"xatol": 1e-3},
    )
    return 10.0 ** (refined.x if refined.fun <= values[best] else grid[best])
