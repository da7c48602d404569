"""Physically consistent standard parameters for an identified model: :func:`export_model`.

The identification fixes only the minimal combinations ``pi = P [theta, phi(theta)]`` of the
standard parameters ``theta``. A robot description needs every body's mass, centre of mass and
inertia, and a physical one. Among the ``theta`` that reproduce ``pi`` (or lie in its confidence
ellipsoid), with every body's pseudo-inertia ``J = [[Sigma, h], [h^T, m]]`` positive definite, the
one closest to a prior model in the log-det divergence of pseudo-inertias is taken
(docs/theory/export.md). The lumped products ``phi`` make the constraint nonlinear; being
homogeneous of degree one in ``theta``, its linearisation at ``theta_k`` is ``A(theta_k) theta``
(``A`` its Jacobian), so each step is a convex program (Clarabel's) and the steps repeat
until ``theta`` stops moving.
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass
from functools import partial

import numpy as np

from .._distributions import chi2_ppf
from .._errors import SpaceidError, shown
from .._svd import svd
from .._threads import one_blas_thread
from ..dynamics import Parameterization, full_parameter_names, full_values, full_values_jacobian, no_effect_parameters
from ..dynamics import minimal_parameters
from ..estimation import Identification
from ..models import INERTIAL_NAMES, Model, load_model
from ..models.internal import (Unknowns, cone, duplication, inertial_from_pseudo, physical_rows, pseudo_inertia,
                               pseudo_whitening, reference_pseudo, solved_tightly, theta_slots, triangle,
                               whitened_physical, with_theta)

__all__ = ["Export", "export_model", "inertial_from_pseudo", "pseudo_divergence", "pseudo_inertia", "unphysical_bodies"]

STEP_TOL = 1e-7
"""The convex steps stop when the whitened parameters (the prior at the identity) move less (the
solver's own noise is ~3e-9); the last Newton steps then meet the equalities to round-off."""
MAX_STEPS = 60
STAGES = 4
"""When the steps from the prior stall, the export searches again along the way from the prior's own minimal
parameters to the estimate's, in this many stages, each starting where the last ended (a local search that
the non-convex conditions had stopped short finds the model from a nearer start)."""
AUTO_REGIONS = (0.95, 0.99, 0.999)
"""The confidence ellipsoids searched, when an estimate is not physically realisable exactly and no region
is given, for the smallest that holds a physical model (:func:`_auto_export`)."""
MET = 1e-9
"""Largest violation of the equalities, in units of the prior's distribution (each row of the conditions of
unit norm in the whitened parameters), that an export takes as met."""
ROUNDING = 100
"""The equalities are also met when their violation in the parameters' own units is at most this many times
``eps`` times the identification's condition number, relative to the parameters' norm: the estimate's own
accuracy. A spatial system has more minimal parameters than the standard ones span, and even a noise-free
estimate lies on the set they reach only to its round-off, which the Newton steps cannot reduce: 2.9e-11 and
4.2e-12 of the largest parameter on two random trees of 120 and 171 parameters (condition numbers 3.6e6 and
2.3e4), 1.2e-9 and 1.5e-9 in the prior's units. A noisy estimate's is the noise's, far above."""
REACHED = 1e-6
"""An elastic program's optimum (the linearised conditions' violation: the equalities' in the units of :data:`MET`,
the ellipsoid's in its whitened radius) above this shows them out of every physical model's reach where they were
linearised, so the main program there is infeasible; a reachable point's is at the solver's tolerance (1e-12)."""
UNREACHED = 1e4
"""The exact search is skipped when Gauss-Newton steps from the prior, over every model, physical or not, stall
with the estimate missed by more than this many times the accuracy :func:`_met` accepts: no model reproduces it, and
the search would spend a dozen convex programs to find that out (a noisy estimate of a system with more minimal
parameters than its models span). Noise-free estimates of the presets, from priors 20 % off, were reached to 1e-15
of their norm in 3 to 5 steps; the noisy estimates of the three presets that ``bench_cli`` exports are missed by
4.1e-5 (Cepheus), 0.85 (satellite-7dof) and 0.64 (servicer-dual) of theirs, 5e6 to 5e8 times that accuracy."""
SHRINK = 1e-6
"""``region``: the ellipsoid used is this much smaller (relative radius), so the exported
parameters lie inside the stated one despite the solver's tolerance."""
DRIFT = 1e-3
"""An ellipsoid's main step that raises the violation of the conditions (not linearised) by more than this fraction
of the ellipsoid's radius above the last accepted step's is taken again within a trust region of half its length
(doubled after each step taken): each step meets the ellipsoid as linearised where it stands, and unchecked, the
steps of random spatial robots 13652 and 252543 walked out to 160 and 36 times its radius, oscillating."""
RESOLVED = 1e-12
"""Smallest variance, relative to the largest (of the correlations: each parameter's scaled to one), that an
ellipsoid resolves from none: a covariance holds its smaller variances to about ``k eps`` of its largest, and a
combination below this one a hundred times that is not known to 1 %. On an estimate that the data determine
everywhere, only the anchored parameters fall below (exactly zero); an estimate widened along directions the data
do not determine to their values' scale can hold variances 1e18 apart (undesigned random spatial robot 3657496:
1e-9 to 1e9), and its determined combinations fall below: held exactly, as if of no variance (a model within any
ellipsoid of them), they may meet no physical model, and a refusal then names that cause (:func:`_refusal`)."""
PROJECTIONS = 5
"""Most projections that move the end of an ellipsoid's steps into it (:meth:`_Search.inside`), when they end
outside it by the second-order terms of their conditions."""
OUTSIDE_SHRINK = 1e-2
"""``region``: when the search ends outside the ellipsoid (the linearised conditions held, and the model's own
parameters are outside by their second-order terms), it runs again within one this much smaller (relative
radius). Random spatial robot 13652 (15 parameters, a noisy estimate): the steps came within 1.002 of the 0.95
radius, then walked out to 160 times it, oscillating; within 0.99 of the radius the best step lies inside."""


def pseudo_divergence(model: Model, reference: Model) -> float:
    """Log-det (Bregman) divergence of ``model``'s pseudo-inertias from ``reference``'s, summed
    over the bodies: ``sum_b -log det(J_ref^-1 J) + tr(J_ref^-1 J) - 4`` (zero only when equal).

    Invariant to the choice of body frames and units; infinite if a pseudo-inertia of ``model``
    is not positive definite. A degenerate reference body (a plate or a rod) counts with a small
    isotropic spread ``SPREAD tr(Sigma)`` added to its second moments.
    """
    total = 0.0
    for body, ref in zip(model.bodies, reference.bodies):
        ref_pseudo = reference_pseudo(ref.inertial, reference.name, ref.name)
        ratio = np.linalg.solve(ref_pseudo, pseudo_inertia(body.inertial))
        eig = np.linalg.eigvals(ratio).real
        total += np.inf if eig.min() <= 0 else float(eig.sum() - np.log(eig).sum() - 4)
    return max(total, 0.0)  # nonnegative: below zero only by round-off


@dataclass(frozen=True)
class Export:
    """Standard inertial parameters for an identification, physical and close to a prior.

    Attributes
    ----------
    model : Model
        The prior's kinematics with the exported inertial parameters.
    prior : Model
    param : Parameterization
        The minimal set of the identification, on the prior's geometry.
    values : ndarray of shape (k,)
        Minimal parameters of the exported model.
    region : float or None
        Probability of the confidence ellipsoid searched, None for an exact fit.
    mahalanobis : float
        ``(values - pi)^T cov^+ (values - pi)`` over the parameters with variance.
    bound : float or None
        ``chi2_dof(region)``, the ellipsoid's bound on ``mahalanobis``.
    divergence : float
        :func:`pseudo_divergence` of ``model`` from ``prior``.
    steps : int
        Convex programs solved.
    seen : dict of str to tuple of str
        Per body, the standard parameters that enter the momentum (set by the data).
    """

    model: Model
    prior: Model
    param: Parameterization
    values: np.ndarray
    region: float | None
    mahalanobis: float
    bound: float | None
    divergence: float
    steps: int
    seen: dict

    def changes(self) -> list:
        """Per body what changed from the prior: ``body``, ``mass_prior``, ``mass`` [kg],
        ``com_shift`` (distance between the CoMs) [m], ``inertia_change`` (relative Frobenius norm
        of the change of the inertia about the CoM) and ``seen`` (the standard parameters set by
        the data)."""
        out = []
        for new, old in zip(self.model.bodies, self.prior.bodies):
            i_new, i_old = (pseudo_inertia(b.inertial)[:3, :3] - b.mass * np.outer(b.com, b.com) for b in (new, old))
            out.append({"body": new.name, "mass_prior": old.mass, "mass": new.mass,
                        "com_shift": float(np.linalg.norm(new.com - old.com)),
                        "inertia_change": float(np.linalg.norm(i_new - i_old) / np.linalg.norm(i_old)),
                        "seen": self.seen[new.name]})  # fmt: skip
        return out


def _constraint_rows(result: Identification, region):
    """The conditions on ``r = P theta - pi`` as ``E r = 0`` and ``|W r| <= radius``.

    Exact fit: ``E = 1``, no ``W``. Within the ``region`` ellipsoid: ``W`` whitens the residual
    with the covariance; the anchored parameters (zero variance) and the combinations the
    covariance gives no variance (:func:`_spectrum`) go to ``E``. Returns ``(E, labels of E's rows, W, radius)``.
    """
    k = len(result.values)
    if region is None:
        return np.eye(k), list(result.names), np.zeros((0, k)), 0.0
    std, var, s, v, null = _spectrum(result)
    e = np.zeros((k - len(var) + null.sum(), k))
    e[np.arange(k - len(var)), np.setdiff1d(np.arange(k), var)] = 1.0
    e[k - len(var) :, var] = (v[:, null] / std[var, None]).T
    labels = [result.names[i] for i in np.setdiff1d(np.arange(k), var)] + ["a zero-variance combination"] * null.sum()
    w = np.zeros(((~null).sum(), k))
    w[:, var] = (v[:, ~null] / np.sqrt(s[~null]) / std[var, None]).T
    dof = int((~null).sum())
    return e, labels, w, float(np.sqrt(chi2_ppf(region, dof))) if dof else 0.0


def _spectrum(result: Identification) -> tuple:
    """``(std (k,), var, s, v, null)``: the standard errors, the indices ``var`` of the parameters with variance,
    the eigenvalues ``s`` and vectors ``v`` of their correlations, and which count as none (:data:`RESOLVED`)."""
    std = np.sqrt(np.clip(np.diag(result.cov), 0, None))
    var = np.flatnonzero(std > 0)
    corr = result.cov[np.ix_(var, var)] / np.outer(std[var], std[var])
    s, v = np.linalg.eigh(0.5 * (corr + corr.T))
    return std, var, s, v, s <= RESOLVED * s.max() if len(s) else np.zeros(0, bool)


def _refusal(result: Identification, unmet: "_Unmet", where: str) -> SpaceidError:
    """The error of an export that found no physical model (``unmet``'s); for an estimate whose covariance, widened
    along directions the data do not determine, left combinations they do determine below its round-off
    (:data:`RESOLVED`), which an ellipsoid holds exactly as if of no variance, that cause named instead (an exact
    search's refusal never gets here with such a covariance: it falls back on the ellipsoids)."""
    if not result.diagnostics.undetermined:
        return unmet.error()
    std, _, _, _, null = _spectrum(result)
    if not null.any():
        return unmet.error()
    return SpaceidError(
        f"{where}: no physical model found: the estimate's covariance, widened along the "
        f"{len(result.diagnostics.undetermined)} directions the data do not determine (standard errors up to "
        f"{std.max():.3g}), leaves {null.sum()} combinations the data do determine below its round-off, and held "
        "exactly, as if of no variance, no physical model was found to meet them: identify with a `prior` (it sets "
        "those directions) or on a designed motion (spaceid design)")


class _Program:
    """The convex step: ``min sum_b -log det X_b + tr X_b`` over ``X_b - MARGIN 1`` PSD, declared
    zeros, ``A_eq theta = b_eq`` and ``|A_w theta - b_w| <= radius`` (``theta = G vec X``).
    ``elastic`` instead minimises the violation of the conditions (to name what is infeasible).

    Stated to Clarabel directly (:mod:`spaceid.models._conic`; cvxpy's compilation of each program took most of a
    solve, 0.5 of the servicer's 0.6 s). The unknowns: each ``X_b``'s upper triangle ``x`` (``vec X = E x``) and
    ``theta``, tied to it by equalities (substituted, the servicer's solves took 1.6 times as long and some failed
    numerically); for the log-det objective, :func:`_log_det_rows`' ``d`` and ``t``; for the elastic program, the
    equalities' violations ``slack = s+ - s-`` and the ellipsoid's ``excess``."""

    def __init__(self, g, z, radius, *, elastic=False):
        self.g, self.z, self.radius, self.elastic = g, z, radius, elastic
        self.slack = self.excess = self.solution = None
        self.nb = g.shape[1] // 16
        self.dup = duplication(self.nb)
        self.gd = g @ self.dup  # theta = gd x

    def solve(self, a_eq, b_eq, a_w, b_w, around=None, nearest=None):
        """The solution ``vec X`` (16 nb,), or None when the program is infeasible (also kept as ``solution``);
        ``around = (x, delta)``: within ``delta`` of ``vec X = x`` in every entry (a trust region); ``nearest``: the
        point of the conditions nearest to that ``vec X`` instead of the one closest to the prior (a projection)."""
        nb, dup, m_eq = self.nb, self.dup, len(a_eq)
        u = Unknowns(x=10 * nb, theta=len(self.gd), **({"plus": m_eq, "minus": m_eq, "excess": 1} if self.elastic else
                                   {} if nearest is not None else {"d": 10 * nb, "t": 4 * nb}))  # fmt: skip
        stated = physical_rows(u, self.z)
        stated.append((u.rows(len(self.gd), x=self.gd, theta=-np.eye(len(self.gd))), np.zeros(len(self.gd)),
                       cone("zero", len(self.gd))))
        if around is not None:
            stated.append((u.rows(2 * len(dup), x=np.vstack([dup, -dup])),
                           np.concatenate([around[1] + around[0], around[1] - around[0]]),
                           cone("nonnegative", 2 * len(dup))))
        if m_eq:
            violations = {"plus": -np.eye(m_eq), "minus": np.eye(m_eq)} if self.elastic else {}
            stated.append((u.rows(m_eq, theta=a_eq, **violations), b_eq, cone("zero", m_eq)))
        if len(a_w):
            m_ball, c_ball = _ball_rows(a_w, b_w)
            ball = np.vstack([u.rows(1, **({"excess": -1.0} if self.elastic else {})),
                              u.rows(len(m_ball), theta=-m_ball)])
            stated.append((ball, np.concatenate([[self.radius], -c_ball]), cone("soc", len(m_ball) + 1)))
        P, q = None, np.zeros(u.n)
        if self.elastic:  # |slack|_1 + excess, each part non-negative
            tail = np.zeros((u.n - u.at["plus"], u.n))
            tail[:, u.at["plus"] :] = -np.eye(len(tail))
            stated.append((tail, np.zeros(len(tail)), cone("nonnegative", len(tail))))
            q[u.at["plus"] :] = 1.0
        elif nearest is not None:  # |E x - nearest|^2, its constant left out
            P = np.zeros((u.n, u.n))
            P[: 10 * nb, : 10 * nb], q[: 10 * nb] = 2.0 * dup.T @ dup, -2.0 * dup.T @ nearest
        else:  # tr X_b - sum t
            i, j, _ = triangle(4)
            stated += _log_det_rows(u)
            q[: 10 * nb], q[u.at["t"] :] = np.tile(i == j, nb), -1.0
        x = solved_tightly(P, q, stated)
        self.solution = None if x is None else dup @ u.of(x, "x")
        if x is not None and self.elastic:
            self.slack = u.of(x, "plus") - u.of(x, "minus") if m_eq else None
            self.excess = float(u.of(x, "excess")[0])
        return self.solution


def _log_det_rows(u) -> list:
    """The cones that make ``sum t`` at most ``sum_b log det X_b``: ``[[diag Z_b, Z_b], [Z_b^T, X_b]]`` PSD with
    ``Z_b`` upper triangular (its ten entries, :func:`~spaceid.models._conic.triangle`'s order, the unknowns ``d``),
    whose diagonal's product is then at most ``det X_b`` and can reach it, and ``t <= log diag Z_b`` (exponential
    cones ``(t, 1, Z_kk)``; cvxpy's statement of ``log_det``, whose pattern Clarabel's chordal decomposition of the
    cone follows), on the :class:`~spaceid.models._conic.Unknowns` ``u`` (``x``, ``d``: ``10 nb`` each, ``t``:
    ``4 nb``)."""
    i, j, w = triangle(8)
    upper = list(zip(*triangle(4)[:2]))
    one_x, one_d = np.zeros((36, 10)), np.zeros((36, 10))
    for k, (r, c) in enumerate(zip(i, j)):
        if r >= 4:  # the lower right block: X
            one_x[k, upper.index((r - 4, c - 4))] = -w[k]
        elif c >= 4 and r <= c - 4:  # the upper right block: Z
            one_d[k, upper.index((r, c - 4))] = -w[k]
        elif r == c:  # the upper left block: diag Z
            one_d[k, upper.index((r, r))] = -w[k]
    out, nb = [], u.sizes["x"] // 10
    for b in range(nb):
        at_b = np.eye(nb)[b : b + 1]
        out.append((u.rows(36, x=np.kron(at_b, one_x), d=np.kron(at_b, one_d)), np.zeros(36), cone("psd", 8)))
        for k in range(4):
            t, d = np.zeros((3, 4 * nb)), np.zeros((3, 10 * nb))
            t[0, 4 * b + k], d[2, 10 * b + upper.index((k, k))] = -1.0, -1.0
            out.append((u.rows(3, t=t, d=d), np.array([0.0, 1.0, 0.0]), cone("exp")))
    return out


def _ball_rows(a_w, b_w) -> tuple:
    """``(M, c)`` with ``|M theta - c| = |A_w theta - b_w|``: with more rows than unknowns (a spatial robot's
    minimal parameters outnumber the standard ones), ``M = [R; 0]``, ``c = [Q^T b_w; -|b_w - Q Q^T b_w|]`` from the
    economy QR ``A_w = Q R``, exact up to rounding: the ellipsoid's cone holds ``n_theta + 1`` entries, not one a
    minimal parameter (the servicer's programs: 170 + 1 against 496, each solve ~0.4 s with the dense one)."""
    if len(a_w) <= a_w.shape[1]:
        return a_w, b_w
    q, r = np.linalg.qr(a_w)
    qb = q.T @ b_w
    return np.vstack([r, np.zeros((1, r.shape[1]))]), np.concatenate([qb, [-np.linalg.norm(b_w - q @ qb)]])


def _conditions(param, g, theta, e, w, pi, *, project=True):
    """The linearised conditions at ``theta`` (``A(theta) theta``, exact there) as ``(A_eq,
    b_eq, A_w, b_w)``, each row of ``E`` scaled to unit norm in the whitened variables.

    ``project``: the equalities only along the directions the linearisation reaches (the range of
    ``E A``, a Gauss-Newton step): a spatial system has more minimal parameters than standard
    ones, so the linearised equalities alone are overdetermined and met only at the solution.
    They are at most ``n_theta`` (``len(theta)``) rows."""
    jac = _minimal_jacobian(param, theta)
    a_eq, b_eq = e @ jac, e @ pi
    scale = np.linalg.norm(a_eq @ g, axis=1)
    scale = np.where(scale > 0, scale, 1.0)
    a_eq, b_eq = a_eq / scale[:, None], b_eq / scale
    if project and len(a_eq):
        u, s, _ = svd(a_eq @ g, full_matrices=False)
        u = u[:, s > 1e-9 * s[0]]
        a_eq, b_eq = u.T @ a_eq, u.T @ b_eq
    return a_eq, b_eq, w @ jac, w @ pi


def _infeasible(result, param, g, z, e, labels, w, radius, theta, where, region, program=None):
    """The error naming the conditions that no physical model meets, from the elastic program at ``theta``:
    ``program`` when it was just solved there (the restoring step's, whose stall ends the export), else solved
    here."""
    if program is None:
        program = _Program(g, z, radius, elastic=True)
        program.solve(*_conditions(param, g, theta, e, w, result.values, project=False))
    x = program.solution
    names = []
    if x is not None and program.slack is not None:
        slack = np.abs(program.slack)
        worst = [i for i in np.argsort(-slack) if slack[i] > 1e-6 * max(1.0, slack.max())]
        names = [f"{labels[i]} = {result.values[i]:.6g}" if labels[i] in result.names else labels[i] for i in worst[:3]]
        names += [f"{len(worst) - 3} more"] if len(worst) > 3 else []
    if region is None:
        return SpaceidError(
            f"{where}: the identified parameters are not physically realisable from the prior (no positive masses, "
            f"inertias and triangle inequalities found near it reproduce {', '.join(names) or 'them'}; the search is "
            "local): export within the confidence ellipsoid (`region`, a probability such as 0.95), give a prior "
            "closer to the robot, or check the identification")
    outside = "" if x is None or program.excess <= 1e-9 else "the ellipsoid reaches no physical model; "
    unmet = f"{', '.join(names)} cannot be met" if names else "the steps from the prior stalled; the search is local"
    return SpaceidError(
        f"{where}: no physical model found within the {region:g} confidence ellipsoid ({outside}{unmet}): try a "
        "larger `region`, give a prior closer to the robot, or check the identification")


def _polish(param, theta, e, pi, slots_scale, g):
    """Newton steps of least change (in ``theta`` relative to ``slots_scale``) onto ``E (P
    full(theta) - pi) = 0``: the convex steps meet the conditions to the solver's tolerance, this
    to round-off. The minimal parameters of a tree are dependent functions of ``theta`` (the
    Jacobian of a planar 4-joint tree: rank 16 of 25 rows), so the step ignores the directions
    whose singular value is below ``1e-10`` of the largest: left in, a round-off residual along
    them became a step of tens of per cent that left a body unphysical. A step that would leave a
    body unphysical or raise the residual is halved."""
    def residual(th):
        return e @ (_minimal_at(param, th) - pi)

    for _ in range(4 if len(e) else 0):  # no equalities (a region and no anchors): nothing to polish
        r = residual(theta)
        a = e @ _minimal_jacobian(param, theta) * slots_scale
        row = np.linalg.norm(a, axis=1)
        row = np.where(row > 0, row, 1.0)
        step = np.linalg.lstsq(a / row[:, None], -r / row, rcond=1e-10)[0] * slots_scale
        for _halving in range(30):
            trial = theta + step
            if whitened_physical(g, trial) and np.abs(residual(trial)).max() <= np.abs(r).max():
                break
            step = step / 2
        else:
            break
        theta = trial
        if np.abs(step).max() <= 1e-15 * np.abs(theta).max():
            break
    return theta


def _minimal_at(param: Parameterization, theta) -> np.ndarray:
    """The minimal parameters ``P [theta, phi(theta)]`` of the standard parameters ``theta``, shape (n_params,)."""
    return param.projection @ full_values(with_theta(param.model, theta))


def _minimal_jacobian(param: Parameterization, theta) -> np.ndarray:
    """The Jacobian of :func:`_minimal_at` at ``theta``, shape (n_params, n_theta)."""
    return param.projection @ full_values_jacobian(with_theta(param.model, theta))


def _accuracy(result: Identification) -> float:
    """The estimate's own accuracy relative to its norm: :data:`ROUNDING` ``eps`` times its condition number."""
    return ROUNDING * np.finfo(float).eps * result.condition_number


def _miss(result: Identification, param, theta, scale) -> float:
    """How far the estimate lies from every model, physical or not, relative to its norm: ``|P [theta, phi] - pi|``
    where Gauss-Newton steps from ``theta`` (the prior's standard parameters; steps of least change relative to
    ``scale``) stall. A step is halved until the residual falls; the steps stop when it falls by less than 1e-3 of
    itself, or is within the estimate's accuracy (:func:`_accuracy`)."""
    pi = np.asarray(result.values, float)
    r = _minimal_at(param, theta) - pi
    for _ in range(MAX_STEPS):
        a = _minimal_jacobian(param, theta) * scale
        step = np.linalg.lstsq(a, -r, rcond=1e-10)[0] * scale
        for fraction in 0.5 ** np.arange(14):
            trial = _minimal_at(param, theta + fraction * step) - pi
            if np.linalg.norm(trial) < np.linalg.norm(r):
                break
        else:
            break
        fell, theta, r = 1 - np.linalg.norm(trial) / np.linalg.norm(r), theta + fraction * step, trial
        if fell < 1e-3 or np.linalg.norm(r) <= _accuracy(result) * np.linalg.norm(pi):
            break
    return float(np.linalg.norm(r) / np.linalg.norm(pi))


def unphysical_bodies(model: Model) -> list:
    """Names of the bodies of ``model`` whose pseudo-inertia is not positive definite (a mass that
    is not positive, an inertia about the CoM that is not positive definite, or principal moments
    that break the triangle inequality); empty for a physically consistent model."""
    return [b.name for b in model.bodies if np.linalg.eigvalsh(pseudo_inertia(b.inertial)).min() <= 0]


def _checked_prior(result: Identification, prior, where: str, prior_name: str):
    """The prior in the result's planar mode and its minimal set, which must be the
    identification's (same joints and geometry): ``(Model, Parameterization)``."""
    prior = load_model(prior)
    try:
        identified = load_model(result.model).joints
    except SpaceidError:
        identified = None  # the identified model's file is elsewhere: the parameter sets decide
    if identified is not None and tuple(identified) != tuple(prior.joints):
        raise SpaceidError(f"{prior_name}: joints {list(prior.joints)} differ from the identified model's "
                           f"{list(identified)} ({result.model}): give a prior of the same robot")
    prior = load_model(prior, planar=result.planar)
    tol = result.settings.get("parameterization", {}).get("rank_tol")  # the identification's, if recorded
    param = minimal_parameters(prior, **({"tol": tol} if tol else {}))
    if param.names != tuple(result.names) or param.definitions != tuple(result.definitions):
        raise SpaceidError(
            f"{prior_name}: its {param.n_params} minimal parameters differ from the {len(result.names)} of {where} "
            "(other joints, geometry or declared zeros): give a prior with the identified model's kinematics")
    return prior, param


def export_model(result: Identification, prior: Model, *, region: float | None = None, where: str = "result",
                 prior_name: str = "prior") -> Export:
    """Standard inertial parameters that reproduce an identification, physical and close to a prior.

    Parameters
    ----------
    result : Identification
        Minimal parameters ``pi`` and their covariance.
    prior : Model
        Same joints and geometry as the identified model; its inertial parameters are the prior
        guess (every body's pseudo-inertia positive definite). Loaded in the result's planar mode.
    region : float, optional
        Probability ``P`` in (0, 1): search the ``P`` confidence ellipsoid of ``pi`` (anchored
        parameters exact) instead of reproducing ``pi`` exactly. None (the default): reproduce
        ``pi`` exactly when a physical model does; when none does (a noisy estimate), the
        smallest of the ``AUTO_REGIONS`` ellipsoids that holds one, with a warning, and
        ``Export.region`` records it. The exact search is skipped when no model, physical or
        not, is found to reproduce ``pi`` (:data:`UNREACHED`).
    where, prior_name : str
        Names of the result and the prior in error messages.

    Returns
    -------
    Export

    Raises
    ------
    SpaceidError
        A prior of other joints or geometry, a point-mass prior body, ``region`` outside (0, 1),
        or no physical model meeting the conditions (the message names the parameters).
    """
    if region is not None and not 0 < region < 1:
        raise SpaceidError(f"`region`: {shown(region)} is not a probability between 0 and 1: give e.g. 0.95")
    prior, param = _checked_prior(result, prior, where, prior_name)
    auto = region is None and np.any(np.diag(result.cov) > 0)  # an ellipsoid to fall back on
    with one_blas_thread():  # small dense factorisations: threads only wait on busy cores
        miss, unmet = 0.0, None
        if auto:
            g = pseudo_whitening(prior, prior_name)[0]
            miss = _miss(result, param, full_values(prior)[: g.shape[0]], np.abs(g).max(axis=1))
        if not miss > UNREACHED * _accuracy(result):  # NaN (no finite condition number): search
            try:
                return _export(result, prior, param, region, where, prior_name)
            except _Unmet as exact_failure:
                if not auto:
                    raise _refusal(result, exact_failure, where) from None
                unmet = exact_failure
        export = _auto_export(result, prior, param, where, prior_name)  # the estimate is not physical
        if isinstance(export, _Unmet):
            raise _refusal(result, unmet or export, where) from None
        why = "" if unmet else " (no model, physical or not, reproduces it)"
        warnings.warn(f"{where}: the estimate is not physically realisable exactly{why}: exported the model "
                      f"closest to the prior within its {export.region:g} confidence ellipsoid", stacklevel=2)
        return export


def _auto_export(result, prior, param, where, prior_name) -> Export | _Unmet:
    """:func:`_export` within the smallest of the :data:`AUTO_REGIONS` ellipsoids that holds a physical model
    (when none does, the largest's :class:`_Unmet`). The smallest is tried first, then the largest: the ellipsoids
    are nested, so when the largest holds none, neither does one between them (a refusal costs two attempts, not
    one an ellipsoid); when it holds one, those between are tried in turn."""
    def attempt(region):
        try:
            return _export(result, prior, param, region, where, prior_name, staged=False)
        except _Unmet as unmet:
            return unmet

    smallest, *between, largest = AUTO_REGIONS
    found = attempt(smallest)
    if isinstance(found, _Unmet) and not isinstance(found := attempt(largest), _Unmet):
        found = next((export for export in map(attempt, between) if not isinstance(export, _Unmet)), found)
    return found


def _export(result, prior, param, region, where, prior_name, staged=True) -> Export:
    """:func:`export_model` once the prior is checked; ``staged``: when the steps from the prior stall, search
    again in :data:`STAGES` (the automatic ellipsoids are not: a refusal would take three times as long). When the
    steps stall, or end where the checks of :func:`_finished` fail, the main step that met the conditions best is
    exported if it passes them, with a warning; when an ellipsoid's steps end outside it, the search is run again
    within a smaller one (:data:`OUTSIDE_SHRINK`). Raises :class:`_Unmet` when no physical model is found."""
    pi = np.asarray(result.values, float)
    g, z = pseudo_whitening(prior, prior_name)
    e, labels, w, radius = _constraint_rows(result, region)
    prior_theta = full_values(prior)[: g.shape[0]]
    start = np.concatenate([np.eye(4).ravel()] * len(prior.bodies))  # vec X of the prior
    finished = partial(_finished, result, prior, param, g, z, e, labels, w, radius, where, region)

    def searched(shrink):
        search = _Search(param, g, z, e, w, radius, pi, shrink)
        try:
            try:
                x = search.run(pi, start, prior_theta)
            except _Stalled:  # the steps from the prior stalled
                if not staged:
                    raise
                x = _staged(search, param.projection @ full_values(prior), pi, start, prior_theta)
        except _Stalled as stall:
            if search.best[1] is None:
                raise _Unmet(partial(_infeasible, result, param, g, z, e, labels, w, radius, g @ stall.x, where,
                                     region, stall.restore)) from None
            return _best_step(search, finished, where, "stalled before they settled")
        return _settled(search, finished, x, where)

    try:
        return searched(SHRINK)
    except _Outside:  # an ellipsoid's steps ended outside it: again within a smaller one
        return searched(OUTSIDE_SHRINK)


def _settled(search, finished, x, where: str) -> Export:
    """``finished`` at the end ``x`` of ``search``'s steps; when its checks fail, at the main step that met the
    conditions best (:func:`_best_step`), if another."""
    try:
        export = _projected(search, finished, x, where)
    except _Unmet:
        if search.best[1] is None or search.best[1] is x:
            raise
        return _best_step(search, finished, where, "ended outside the conditions")
    if search.moved >= STEP_TOL:
        warnings.warn(f"{where}: the export did not settle in {MAX_STEPS} convex steps (last move "
                      f"{search.moved:.2g})", stacklevel=5)
    return export


def _projected(search, finished, x, where: str) -> Export:
    """``finished`` at ``x`` moved into the ellipsoid (:meth:`_Search.inside`), with a warning when it was."""
    moved, projections = search.inside(x)
    export = finished(moved, search.steps)
    if projections:
        warnings.warn(f"{where}: the export's steps ended outside the ellipsoid by its conditions' second-order terms: "
                      f"moved into it by {projections} projection(s) (a physical model closer to the prior may exist)",
                      stacklevel=6)  # fmt: skip
    return export


def _best_step(search, finished, where: str, how: str) -> Export:
    """``finished`` at the main step of ``search`` that met the conditions best, with a warning that says ``how`` the
    steps ended."""
    export = _projected(search, finished, search.best[1], where)
    warnings.warn(f"{where}: the convex steps {how}: exported the step that met the conditions best (a physical "
                  "model closer to the prior may exist)", stacklevel=5)
    return export


def _finished(result, prior, param, g, z, e, labels, w, radius, where, region, x, steps) -> Export:
    """The :class:`Export` of the search's ``vec X`` ``x`` after ``steps`` convex programs: polished onto the
    equalities (:func:`_polish`), the parameters without effect on the momentum at the prior's values; raises
    :class:`_Unmet` when the equalities are not met, the model is not within the ellipsoid (``region``), or it is not
    physical."""
    pi = np.asarray(result.values, float)
    prior_theta = full_values(prior)[: g.shape[0]]
    scale = np.abs(g).max(axis=1)  # of each standard parameter, for a unit change of X
    theta = _polish(param, g @ x, e, pi, scale, g)
    hidden = _hidden(param)
    # the parameters the momentum does not see are at the prior up to the solver's noise: exactly there
    theta = np.where(hidden & (np.abs(theta - prior_theta) <= 1e-9 * scale), prior_theta, theta)
    a_eq, b_eq, *_ = _conditions(param, g, theta, e, w, pi, project=False)
    if len(a_eq) and not _met(result, param, theta, e, pi, np.abs(a_eq @ theta - b_eq).max()):
        raise _Unmet(partial(_infeasible, result, param, g, z, e, labels, w, radius, theta, where, region))
    model = with_theta(prior, theta)
    values = param.projection @ full_values(model)
    distance = float(np.sum((w @ (values - pi)) ** 2))
    if region is not None and distance > radius**2:  # the steps' linearised ellipsoid held, the ellipsoid not
        raise _Outside(partial(SpaceidError, f"{where}: the export's steps within the {region:g} confidence ellipsoid "
                             f"ended outside it (distance^2 {distance:.4g} > {radius**2:.4g}): try a larger `region`"))
    if unphysical_bodies(model):  # never hand on (or write) an unphysical model as a result
        raise _Unmet(partial(SpaceidError, f"{where}: the export ended on a model whose bodies "
                             f"{', '.join(unphysical_bodies(model))} are not physically consistent: nothing was "
                             "written; please report this"))
    seen = {b.name: tuple(INERTIAL_NAMES[k] for (i, k), h in zip(theta_slots(prior), hidden) if i == n and not h)
            for n, b in enumerate(prior.bodies)}  # fmt: skip
    return Export(model, prior, param, values, region, distance, float(radius**2) if region is not None else None,
                  pseudo_divergence(model, prior), steps, seen)


class _Unmet(Exception):
    """No physical model met the conditions; ``error()`` builds the :class:`SpaceidError` that names them (an
    elastic program's solve: only when it is shown, not for an attempt that the automatic ellipsoids follow)."""

    def __init__(self, error):
        super().__init__()
        self.error = error


class _Outside(_Unmet):
    """The model an ellipsoid's search ended on is outside the ellipsoid (its linearisation held, not itself)."""


class _Stalled(Exception):
    """The restoring steps of :meth:`_Search.run` found no step that lowers the violation, at ``x`` (vec X);
    ``restore``: their program (its last solve names what is infeasible)."""

    def __init__(self, x, restore):
        super().__init__()
        self.x, self.restore = x, restore


class _Search:
    """The convex steps of an export, from some ``vec X`` to the conditions at some minimal parameters: each a
    :class:`_Program` at the conditions linearised where it stands; where that reaches no physical model, an
    elastic program's step towards them first (:func:`_damped`). ``steps`` counts them over every run, ``moved``
    is the last one's size; ``best``: ``(violation, vec X)`` of the main steps towards the export's ``target`` that
    violated its conditions least (:func:`_actual_violation`), over every run."""

    def __init__(self, param, g, z, e, w, radius, target, shrink=SHRINK):
        self.param, self.g, self.z, self.e, self.w, self.radius = param, g, z, e, w, radius
        self.program = _Program(g, z, radius * (1 - shrink))
        self.steps, self.moved = 0, 0.0
        self.target, self.best = target, (np.inf, None)

    def inside(self, x) -> tuple:
        """``(x, projections)``: ``x`` (``vec X``) moved into an ellipsoid whose conditions it violates (not
        linearised) by their second-order terms, onto the nearest point of their linearisation where it stands, again
        from there, up to :data:`PROJECTIONS` times (each a short step, whose own second-order terms are far smaller;
        the model is then no longer the one closest to the prior), and how many; ``(x, 0)`` when that does not end
        inside, or there is no ellipsoid."""
        param, g, e, w, pi, radius = self.param, self.g, self.e, self.w, self.target, self.radius

        def outside(x):  # the ellipsoid's own excess (the equalities are polished after)
            return len(w) and np.linalg.norm(w @ (_minimal_at(param, g @ x) - pi)) > radius

        moved, projections = x, 0
        while outside(moved):
            if projections == PROJECTIONS:
                return x, 0
            self.steps, projections = self.steps + 1, projections + 1
            moved = self.program.solve(*_conditions(param, g, g @ moved, e, w, pi), nearest=moved)
            if moved is None:
                return x, 0
        return moved, projections

    def run(self, pi, x, theta=None) -> np.ndarray:
        """The ``vec X`` that meets the conditions at ``pi``, stepping from ``x`` (linearised first at ``theta``,
        by default ``g x``), after at most :data:`MAX_STEPS` steps; raises :class:`_Stalled`. After a restoring
        step the elastic program is solved first, and the main one only once the conditions are within reach
        (:data:`REACHED`): a main program out of reach is infeasible (a third of a refusal's programs were)."""
        param, g, e, w, radius = self.param, self.g, self.e, self.w, self.radius
        theta, restore, violation, restoring = g @ x if theta is None else theta, None, np.inf, False
        delta, now = np.inf, _actual_violation(param, g, x, e, w, pi, radius) if len(w) else None
        for _ in range(MAX_STEPS):
            self.steps += 1
            towards = restore.solve(*_conditions(param, g, theta, e, w, pi, project=False)) if restoring else None
            out_of_reach = towards is not None and _violation(restore) > REACHED
            around = None if delta == np.inf else (x, delta)
            new = None if out_of_reach else self.program.solve(*_conditions(param, g, theta, e, w, pi), around)
            after = None if new is None else _actual_violation(param, g, new, e, w, pi, radius)
            if now is not None and after is not None:  # an ellipsoid's step: a trust region when it walks out
                if after > max(now, 0.0) + DRIFT * radius:
                    delta = 0.5 * np.abs(new - x).max()
                    if delta < STEP_TOL:
                        break
                    continue
                delta = 2 * delta
            restoring = new is None
            if restoring:  # linearised at theta, the conditions reach no physical model: move towards them first
                restore = restore or _Program(g, self.z, radius, elastic=True)
                if towards is None:
                    towards = restore.solve(*_conditions(param, g, theta, e, w, pi, project=False))
                new, violation = _damped(param, g, x, towards, e, w, pi, radius, violation)
                if new is None:
                    raise _Stalled(x, restore)
                after = violation
            elif after < self.best[0] and np.allclose(pi, self.target, rtol=1e-12, atol=0):  # towards the target
                self.best = (after, new)
            now = after if now is not None else None
            self.moved = np.abs(new - x).max()
            x, theta = new, g @ new
            if self.moved < STEP_TOL:
                break
        return x


def _violation(program: _Program) -> float:
    """The optimum of an elastic ``program``'s last solve: the summed violation of the conditions."""
    slack = 0.0 if program.slack is None else np.abs(program.slack).sum()
    return float(slack + program.excess)


def _staged(search, own, pi, start, theta) -> np.ndarray:
    """``search`` run to ``own + k / STAGES (pi - own)``, ``k = 1 .. STAGES``, each stage from where the last
    ended (the first from ``start``, linearised at ``theta``): the ``vec X`` at ``pi``. Raises :class:`_Stalled`,
    with no program unless the last stage's (an earlier one's is at other values)."""
    for stage in range(1, STAGES + 1):
        try:
            start = search.run(own + stage / STAGES * (pi - own), start, theta if stage == 1 else None)
        except _Stalled as stall:
            raise stall if stage == STAGES else _Stalled(stall.x, None) from None
    return start


def _met(result: Identification, param, theta, e, pi, violation: float) -> bool:
    """Whether the equalities ``E (P full(theta) - pi) = 0`` are met: their ``violation`` in the prior's units at
    most :data:`MET`, or their residual at the estimate's own accuracy (:data:`ROUNDING`)."""
    if violation <= MET:
        return True
    if not np.isfinite(result.condition_number):
        return False
    residual = e @ (_minimal_at(param, theta) - pi)
    return bool(np.linalg.norm(residual) <= _accuracy(result) * np.linalg.norm(pi))


def _damped(param, g, x, new, e, w, pi, radius, violation) -> tuple:
    """The restoring step from ``x`` towards ``new`` (``vec X``; None: none found), shortened until
    the conditions' actual violation falls below 0.9 of ``violation``, and that violation; ``(None,
    violation)`` when no step of at least 1/16 does. The linearised step alone may overshoot: on a
    1-joint spatial robot (15 parameters, two of them products of the base's and the link's first
    moments) it raised the violation from 52 to 55 and the export gave up on a 0.95 ellipsoid that
    held the true robot. A shortened step stays physical (the bodies' set is convex)."""
    if new is None:
        return None, violation
    for fraction in (1.0, 0.5, 0.25, 0.125, 0.0625):
        step = x + fraction * (new - x)
        if (actual := _actual_violation(param, g, step, e, w, pi, radius)) < 0.9 * violation:
            return step, actual
    return None, violation


def _actual_violation(param, g, x, e, w, pi, radius) -> float:
    """The violation of the conditions (not linearised) at ``vec X`` ``x``: the equalities' in their own units
    (``|E r|_1``) plus the whitened residual's excess over the ellipsoid's ``radius``."""
    r = _minimal_at(param, g @ x) - pi
    return float(np.abs(e @ r).sum() + max(0.0, float(np.linalg.norm(w @ r)) - radius))


def _hidden(param: Parameterization) -> np.ndarray:
    """Which standard parameters (``theta``) do not enter the momentum at all, shape (n_theta,)."""
    hidden = set(no_effect_parameters(param))
    return np.array([name in hidden for name in full_parameter_names(param.model)[: len(theta_slots(param.model))]])
