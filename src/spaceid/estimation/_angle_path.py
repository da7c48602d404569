"""The joint paths of the ``angles`` estimator: cubic splines on uniform knots, and the quadrature
and integration grids on the panels between the sample times and the knots, on which the splines
are smooth (docs/theory/angles.md)."""

from __future__ import annotations

import numpy as np

from .._constants import KNOT_SPACING
from .._errors import SpaceidError

GAUSS_NODES = 4
"""Gauss-Legendre nodes per quadrature panel: exact for the spline pieces to ~1e-13 at 100 Hz."""

MIN_SAMPLES_PER_SPAN = 2
"""Fewest samples per knot span on average: fewer leave the splines (two coefficients per span
and joint at most) barely determined by their own joint's samples."""


LADDER_STEPS = 6
"""The spacings :func:`automatic_knot_spacing` tries: ``KNOT_SPACING`` times 1, 2, 4, ... (0.05 to 1.6 s; it
chooses 0.8 s at most)."""


def _spans(t, spacing: float) -> int:
    return max(1, round(float(t[-1] - t[0]) / spacing))


def enough_samples_for_knots(t, spacing: float | None) -> bool:
    """Whether the stamps ``t`` hold at least :data:`MIN_SAMPLES_PER_SPAN` samples per knot span of
    about ``spacing`` [s] (what the ``angles`` estimator needs); None: of the coarsest spacing that
    :func:`automatic_knot_spacing` tries."""
    spacing = KNOT_SPACING * 2.0 ** (LADDER_STEPS - 1) if spacing is None else spacing
    return len(t) - 1 >= MIN_SAMPLES_PER_SPAN * _spans(t, spacing)


def automatic_knot_spacing(t, q, sigma_q: float) -> float:
    """The knot spacing [s] of the spatial ``angles`` fit when none is given: half the coarsest of
    ``KNOT_SPACING`` times 1, 2, 4, ... (:data:`LADDER_STEPS` of them) at which least-squares cubic splines of the
    joint samples ``q (n, n_joints)`` at stamps ``t (n,)`` leave residuals consistent with white noise of
    ``sigma_q`` [rad] (their chi2, pooled over the joints, within three standard deviations of its degrees of
    freedom), every finer spacing passing as well; the finest with enough samples when none passes.

    The fit's nuisance (spline coefficients) and cost grow as the spacing shrinks: the attitude's derivatives are
    dense in the coefficients (samples x 3 x joints x coefficients: 2.4 GB for the 7-joint servicer over 120 s at
    50 Hz with knots every 0.05 s). The test sees a spline's approximation error only down to a fraction of the
    noise, which can still move the parameters by a third of a standard error; halving the spacing divides that
    error by 16 (docs/theory/angles.md, "Knots")."""
    from scipy.interpolate import make_lsq_spline

    admissible = [d for d in KNOT_SPACING * 2.0 ** np.arange(LADDER_STEPS) if enough_samples_for_knots(t, d)]
    passed = []
    for spacing in admissible:
        knots = _knot_vector(t, spacing, "automatic_knot_spacing")
        dof = q.size - (len(knots) - 4) * q.shape[1]
        chi2 = float(np.sum((q - make_lsq_spline(t, q, knots, k=3)(t)) ** 2)) / sigma_q**2
        if chi2 > dof + 3 * np.sqrt(2 * dof):
            break
        passed.append(float(spacing))
    if not admissible:  # too few samples: _knot_vector says so
        return KNOT_SPACING
    return passed[-2] if len(passed) > 1 else admissible[0]


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
