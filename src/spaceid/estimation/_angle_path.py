"""The joint paths of the ``angles`` estimator: cubic splines on uniform knots, and the quadrature
and integration grids on the panels between the sample times and the knots, on which the splines
are smooth (docs/theory/angles.md)."""

from __future__ import annotations

import numpy as np

from .._errors import SpaceidError

GAUSS_NODES = 4
"""Gauss-Legendre nodes per quadrature panel: exact for the spline pieces to ~1e-13 at 100 Hz."""

MIN_SAMPLES_PER_SPAN = 2
"""Fewest samples per knot span on average: fewer leave the splines (two coefficients per span
and joint at most) barely determined by their own joint's samples."""


def _spans(t, spacing: float) -> int:
    return max(1, round(float(t[-1] - t[0]) / spacing))


def enough_samples_for_knots(t, spacing: float) -> bool:
    """Whether the stamps ``t`` hold at least :data:`MIN_SAMPLES_PER_SPAN` samples per knot span of
    about ``spacing`` [s] (what the ``angles`` estimator needs)."""
    return len(t) - 1 >= MIN_SAMPLES_PER_SPAN * _spans(t, spacing)


def _knot_vector(t, spacing: float, where: str) -> np.ndarray:
    """Cubic-spline knots over ``[t[0], t[-1]]``: uniform spans of about ``spacing`` [s], the end
    knots repeated four times. Raises when the samples are too few for them."""
    if not spacing > 0:
        raise SpaceidError(f"{where}: `knot_spacing` {spacing!r} must be a positive time [s]")
    duration = float(t[-1] - t[0])
    spans = _spans(t, spacing)
    if not enough_samples_for_knots(t, spacing):
        raise SpaceidError(
            f"{where}: {len(t)} samples over {duration:.4g} s are too few for spline knots every {spacing:g} s "
            f"({spans} spans): the angles estimator needs at least {MIN_SAMPLES_PER_SPAN * spans + 1} samples "
            f"(sample at {MIN_SAMPLES_PER_SPAN / spacing:g} Hz or more)"
        )
    inner = np.linspace(t[0], t[-1], spans + 1)
    return np.concatenate([[t[0]] * 3, inner, [t[-1]] * 3])


def _basis(knots, s, deriv=0) -> np.ndarray:
    """Cubic B-spline basis (or its derivative) at times ``s (m,)``: ``(m, n_coef)``."""
    from scipy.interpolate import BSpline
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
