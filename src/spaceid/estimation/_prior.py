"""A CAD prior on the standard parameters: the maximum a posteriori estimate over physically
consistent models (``identify(..., prior=...)``; docs/theory/prior.md).

The identification fixes the minimal parameters ``pi = P [theta, phi(theta)]`` of the standard
parameters ``theta`` (every body's mass, first moments and inertia). The prior is Gaussian and
independent in ``theta`` about a CAD model's values (:func:`prior_deviations`); the data enter as
a Gaussian likelihood in ``pi``, ``|L pi_f - r|^2`` over the estimated parameters ``pi_f``: the
chosen estimator's point estimate and covariance when the data determine ``pi``, else the weighted
momentum equations at the prior, whose information is singular where the data say nothing. The
MAP minimises ``|L pi_f(theta) - r|^2 + |(theta - theta_0) / s|^2`` over ``theta`` with every
body's pseudo-inertia positive definite and the anchored minimal parameters met; ``pi`` is
homogeneous of degree one in ``theta``, so at ``theta_k`` it is ``A(theta_k) theta`` exactly and
each step is a convex program (Clarabel's) repeated until ``theta`` settles (Gauss-Newton,
halved when a step does not lower the objective).
"""

from __future__ import annotations

import re
import warnings
from dataclasses import dataclass, field, replace

import numpy as np

from .._errors import SpaceidError, shown
from .._svd import svd
from .._threads import one_blas_thread
from ..dynamics import Parameterization, full_parameter_names, full_values, full_values_jacobian
from ..models import Model, load_model
from ..models.internal import (Unknowns, cone, duplication, physical_rows, pseudo_inertia, pseudo_whitening,
                               solved_tightly, theta_slots, with_theta)
from ._determined import UNDETERMINED_FIX

__all__ = ["PRIOR_STD", "PriorRecord", "prior_deviations"]

PRIOR_STD = 0.2
"""Default relative standard deviation of the prior's masses and moments of inertia (20 %)."""
KNOWN_STD = 1e-6
"""Relative standard deviation of a mass given as known (``known`` m_base=180, m_total=...): a
tight prior, so that the covariance stays that of a proper density."""
ACTIVE = 1e-4
"""A body's physical constraint counts as active at the MAP when its whitened pseudo-inertia (the
prior at the identity) has an eigenvalue below this."""
STEP_TOL = 1e-9
"""The convex steps stop when ``theta`` moves less than this many prior standard deviations ..."""
VALUE_TOL = 1e-12
"""... or the objective falls by less than this fraction: in directions that neither data nor prior
pin down the solver's noise (a part in 1e8 of the whitened parameters) moves it without end."""
MAX_STEPS = 40
TEMPERED = (1e2, 1e6)
"""Data more informative than the prior by more than the last of these (their strongest direction)
are also tempered to these many times the prior's information, each stage starting from the last,
and the steps that end with the lower objective are kept: from the prior, a Gauss-Newton step
towards noise-free data can land far off their curved set of models (random planar robot 105, 3 arms
of 4 joints, stalled 1e-2 off the log's momentum), while other robots end closer without stages."""
FLOOR = 1e-12
"""The data never know a combination of the minimal parameters better than this fraction of the
prior's standard deviation (:func:`_floored`): 2e-13 of the parameter at the default 20 %, some
thousand units of round-off."""
CAPPED = 1e3
"""The convex steps meet the data exactly along directions where they are more than ``CAPPED**2``
times as informative as the prior (:class:`_MapProgram`); the polish that follows them weighs them."""
TOTAL_MASS = "m_total"
"""The name of the total mass in ``known``."""


def prior_deviations(model: Model, rel: float = PRIOR_STD) -> np.ndarray:
    """Standard deviations of an independent Gaussian prior on the standard parameters ``theta``.

    Each body's mass has the relative std ``rel``; its CoM the std ``L = rel r_g`` along each axis
    (``r_g = sqrt(tr(I_c) / 2m)``, the radius of gyration about the CoM: a fraction of the body's
    size, free of units); its inertia about the CoM ``rel sqrt(I_c,ii I_c,jj)`` per entry (``rel``
    on the principal moments). The first moments ``h = m c`` and the inertia about the frame
    origin ``I = I_c + m (|c|^2 1 - c c^T)`` then have, to first order,
    ``sqrt((rel h_k)^2 + (m L)^2)`` and
    ``sqrt((rel sqrt(I_c,ii I_c,jj))^2 + (rel m |c|^2)^2 + (m L (2|c| + L))^2)``.

    Parameters
    ----------
    model : Model
        The prior (CAD) model, every body physical.
    rel : float
        Relative standard deviation, > 0.

    Returns
    -------
    ndarray of shape (n_theta,)
        In the order of ``theta`` (``full_parameter_names``, declared zeros left out) [kg, kg m, kg m^2].
    """
    rows = []
    for body in model.bodies:
        m, c = body.mass, np.asarray(body.com, float)
        pseudo = pseudo_inertia(body.inertial)
        sigma_c = pseudo[:3, :3] - m * np.outer(c, c)  # second moments about the CoM
        i_c = np.trace(sigma_c) * np.eye(3) - sigma_c
        length = rel * np.sqrt(max(np.trace(i_c), 0.0) / (2 * m))
        moment = rel * np.sqrt(np.abs(np.outer(np.diag(i_c), np.diag(i_c))))
        inertia = np.sqrt(moment**2 + (rel * m * c @ c) ** 2 + (m * length * (2 * np.linalg.norm(c) + length)) ** 2)
        h = np.sqrt((rel * m * c) ** 2 + (m * length) ** 2)
        rows.append([rel * m, *h, inertia[0, 0], inertia[0, 1], inertia[1, 1], inertia[0, 2], inertia[1, 2],
                     inertia[2, 2]])  # fmt: skip
    return np.array([rows[b][k] for b, k in theta_slots(model)])


@dataclass(frozen=True)
class PriorRecord:
    """What a CAD prior did to an identification (``Identification.prior``).

    Attributes
    ----------
    source : str
        The prior model (preset name or path).
    prior_std : float
        Relative standard deviation of its masses and moments (:func:`prior_deviations`).
    data_term : str
        How the data entered: ``"estimator"`` (the estimator's estimate and covariance) or
        ``"equations"`` (the weighted momentum equations at the prior: the data alone do not
        determine the parameters), with ``data_reason`` saying why.
    data_reason : str
    known : dict
        Standard parameters (or ``m_total``) given as known: a tight prior (``KNOWN_STD``).
    prior_values, prior_std_values : ndarray of shape (k,)
        The minimal parameters of the prior and their prior standard deviations.
    data_values, data_std : ndarray of shape (k,) or None
        The data's own estimate and standard errors (None with ``data_term`` ``"equations"``).
    directions : tuple of dict
        Per eigen-direction of the data's information relative to the prior's (largest first):
        ``ratio`` (the generalised eigenvalue), ``data_share`` (``ratio / (1 + ratio)``, the data's
        weight in the estimate along it), ``set_by`` (``"data"`` when ``ratio > 1``, else
        ``"prior"``) and ``leading`` (the standard parameters that dominate it, with their weights).
    active : tuple of str
        Bodies whose physical constraint is active at the estimate (there the covariance, taken
        with the constraints inactive, overstates the uncertainty towards the boundary).
    steps : int
        Convex programs solved.
    theta : dict
        The standard parameters: ``names``, the estimate ``map``, the ``prior`` and its deviations
        ``prior_std`` (lists in ``names`` order) [kg, kg m, kg m^2].
    """

    source: str
    prior_std: float
    data_term: str
    data_reason: str
    known: dict
    prior_values: np.ndarray
    prior_std_values: np.ndarray
    data_values: np.ndarray | None
    data_std: np.ndarray | None
    directions: tuple
    active: tuple = ()
    steps: int = 0
    theta: dict = field(default_factory=dict)

    @property
    def n_data(self) -> int:
        """Directions the data set (information ratio above 1)."""
        return sum(d["set_by"] == "data" for d in self.directions)

    @property
    def n_prior(self) -> int:
        """Directions the prior set."""
        return len(self.directions) - self.n_data

    def summary(self) -> str:
        """One line: the prior, how many directions each side set, the active constraints."""
        active = f"; physical constraint active on {', '.join(self.active)}" if self.active else ""
        how = "" if self.data_term == "estimator" else f" (data as weighted equations: {self.data_reason})"
        return (f"prior {self.source} at {100 * self.prior_std:g} %: the data set {self.n_data} of "
                f"{len(self.directions)} directions of the standard parameters, the prior {self.n_prior}{how}{active}")

    def to_dict(self) -> dict:
        """JSON-ready (the ``prior`` entry of RESULT.json; docs/formats/result-json.md)."""
        opt = (lambda a: None if a is None else np.asarray(a, float).tolist())  # noqa: E731
        return {"source": self.source, "prior_std": self.prior_std, "data_term": self.data_term,
                "data_reason": self.data_reason, "known": dict(self.known),
                "prior_values": opt(self.prior_values), "prior_std_values": opt(self.prior_std_values),
                "data_values": opt(self.data_values), "data_std": opt(self.data_std),
                "directions": [dict(d) for d in self.directions], "active": list(self.active),
                "steps": self.steps, "theta": dict(self.theta), "n_data": self.n_data,
                "n_prior": self.n_prior}  # fmt: skip

    @classmethod
    def from_dict(cls, data: dict | None) -> PriorRecord | None:
        """The record of :meth:`to_dict` (None for None: a result without a prior)."""
        if data is None:
            return None
        opt = (lambda a: None if a is None else np.asarray(a, float))  # noqa: E731
        return cls(str(data["source"]), float(data["prior_std"]), str(data["data_term"]),
                   str(data.get("data_reason", "")), dict(data.get("known", {})), opt(data["prior_values"]),
                   opt(data["prior_std_values"]), opt(data.get("data_values")), opt(data.get("data_std")),
                   tuple(dict(d) for d in data.get("directions", [])), tuple(data.get("active", [])),
                   int(data.get("steps", 0)), dict(data.get("theta", {})))  # fmt: skip


@dataclass(frozen=True)
class DataTerm:
    """The data as a Gaussian likelihood in the minimal parameters: ``|L pi[free] - r|^2``.

    ``kind`` is ``"estimator"`` or ``"equations"`` (:class:`PriorRecord`), ``reason`` why the latter;
    ``values``/``std`` the data's own estimate (None with ``"equations"``); ``anchors`` the
    anchored minimal parameters ``{index: value}`` (met exactly)."""

    L: np.ndarray
    r: np.ndarray
    free: np.ndarray
    kind: str
    reason: str = ""
    values: np.ndarray | None = None
    std: np.ndarray | None = None
    anchors: dict = field(default_factory=dict)


def data_from_estimate(values, cov, free, anchors) -> DataTerm:
    """The :class:`DataTerm` of an estimate ``values (k,)`` with covariance ``cov (k, k)``: the free
    parameters' covariance inverted through their correlation matrix (a covariance of an undesigned
    motion spans 15 decades; its correlations far fewer); only combinations of correlation exactly
    one (no variance at all: the anchors carry those) are left out."""
    free = np.asarray(free, int)
    c = np.asarray(cov, float)[np.ix_(free, free)]
    std = np.sqrt(np.clip(np.diag(c), 0, None))
    std = np.where(std > 0, std, 1.0)
    s, v = np.linalg.eigh(0.5 * (c + c.T) / np.outer(std, std))
    keep = s > 1e-13 * max(s.max(initial=0.0), np.finfo(float).tiny)
    L = (v[:, keep] / np.sqrt(s[keep])).T / std
    return DataTerm(L, L @ np.asarray(values, float)[free], free, "estimator", values=np.asarray(values, float),
                    std=np.sqrt(np.clip(np.diag(cov), 0, None)), anchors=dict(anchors))


def data_from_equations(white, noise_gram, n_free: int, reason: str, anchors, free, score_covariance=None) -> DataTerm:
    """The :class:`DataTerm` of whitened momentum equations ``white = [A_f | A_n | -b]`` (any leading
    shape, last axis ``p + 1``; ``A_f`` the ``n_free`` free parameters' columns, ``A_n`` the nuisance:
    momentum, drift) whose own noise has the Gram matrix ``noise_gram (p + 1, p + 1)``.

    The regressor is measured: its Gram matrix ``G`` is the signal's plus the noise's, so the
    information is ``G - N`` (bias-compensated least squares), the nuisance profiled out of both.
    Only the directions where ``G`` stands out of ``N`` beyond the spread of a pure-noise Gram
    matrix (the Marchenko-Pastur edge ``(1 + sqrt(p / n))^2``, doubled in excess) carry information: a
    motion that does not excite a direction leaves it to the prior instead of to the noise.

    The rows ``L theta - rhs`` have unit covariance at the truth for white noise of negligible size. Their
    first-order errors are ``bread s``, ``s`` the weighted equations' score for the free parameters; with
    ``score_covariance(bread) = bread Omega bread^T`` given (``Omega`` the score's covariance: errors
    correlated over a differentiator's window, and the regressor's own noise) the rows are whitened by
    the larger of that sandwich and the identity in every direction: the data term carries no more
    information than its errors allow.

    The generalised eigenvalues ``mu = c^2 / s^2`` of ``G v = mu N v`` come from square roots
    ``G = R^T R``, ``N = M^T M`` (the cosine-sine decomposition of ``[R; M] = [Q1; Q2] T``:
    ``Q1 = U C W^T``, ``Q2 W = V S``), not from the Gram matrices: on a noise-free log ``N`` is 1e-20
    of ``G``, and the directions near the edge would be lost to its round-off."""
    from scipy.linalg import solve_triangular

    white = np.asarray(white, float).reshape(-1, np.shape(white)[-1])
    p = white.shape[1] - 1
    nuisance = p - n_free
    # the nuisance first: the free parameters' and b's rows with it profiled out
    upper = np.linalg.qr(white[:, np.r_[n_free:p, 0:n_free, p]], mode="r")[nuisance:, nuisance:]
    m = min(len(upper), n_free)  # fewer samples than parameters: the missing rows are zeros
    root, rhs_root = np.zeros((n_free, n_free)), np.zeros(n_free)
    root[:m], rhs_root[:m] = upper[:m, :n_free], upper[:m, n_free]
    n_ff, n_fb = _profile(np.asarray(noise_gram, float), n_free, p)
    # each column's noise scale; a column no noisy signal enters (the base inertia's, on a noise-free base rate)
    # has none: 1e-8 of its signal's instead, which leaves its noise negligible (a vanishing scale made 0 / 0)
    noise_scale, signal_scale = np.sqrt(np.clip(np.diag(n_ff), 0, None)), 1e-8 * np.linalg.norm(root, axis=0)
    scale = np.where(noise_scale > 0, noise_scale, np.where(signal_scale > 0, signal_scale, 1.0))
    n_s = n_ff / np.outer(scale, scale) + 1e-12 * np.eye(n_free)
    noise_root = np.linalg.cholesky(0.5 * (n_s + n_s.T)).T * scale  # N = M^T M
    q, t = np.linalg.qr(np.vstack([root, noise_root]))
    u, c, wt = svd(q[:n_free])
    s = np.linalg.norm(q[n_free:] @ wt.T, axis=0)
    edge = (1 + np.sqrt(max(p, 1) / max(len(white), 1))) ** 2
    keep = c**2 > (1 + 2 * (edge - 1)) * s**2
    gain = np.sqrt(np.clip(c**2 - s**2, 0, None))[keep]
    L = gain[:, None] * (wt @ t)[keep]
    # the right-hand side: W^T T^-T (g - n) with g = -R^T rhs_root (b enters as -b), n = -n_fb
    x_inv_g = -(c * (u.T @ rhs_root))
    x_inv_n = -(wt @ solve_triangular(t, n_fb, trans="T"))
    rhs = (x_inv_g - x_inv_n)[keep] / gain
    if score_covariance is not None and np.any(keep):
        from ._uncertainty import larger_of

        # the rows' errors at the truth are bread (the score), bread = diag(1 / gain) (W^T T^-T)[keep]; white
        # noise of negligible size makes their covariance the identity, the sandwich its larger
        bread = (wt @ solve_triangular(t, np.eye(n_free), trans="T"))[keep] / gain[:, None]
        C = larger_of(np.eye(len(gain)), score_covariance(bread))[0]
        U = np.linalg.inv(np.linalg.cholesky(0.5 * (C + C.T)))
        L, rhs = U @ L, U @ rhs
    return DataTerm(L, rhs, np.asarray(free, int), "equations", reason, anchors=dict(anchors))


def _profile(gram, n_free: int, p: int) -> tuple:
    """The Gram matrix of ``[A_f | A_n | -b]`` with the nuisance ``A_n`` profiled out: its blocks
    ``(ff, fb)``, shapes ``(n_free, n_free)`` and ``(n_free,)``."""
    f, n, b = np.arange(n_free), np.arange(n_free, p), np.array([p])
    keep = np.r_[f, b]
    block = gram[np.ix_(keep, keep)]
    if len(n):
        cross = gram[np.ix_(keep, n)]
        block = block - cross @ np.linalg.pinv(gram[np.ix_(n, n)], rcond=1e-13) @ cross.T
    return block[:n_free, :n_free], block[:n_free, n_free]


def split_known(param: Parameterization, known: dict | None, where: str) -> tuple:
    """``known`` split into minimal-parameter anchors (as ``identify`` takes them) and known standard
    parameters (``m_base``, ``m_total``, any of ``full_parameter_names``' standard ones), which
    only a prior can take: ``(minimal, standard)``."""
    names = set(full_parameter_names(param.model)[: len(theta_slots(param.model))]) | {TOTAL_MASS}
    minimal, standard = {}, {}
    alone = {d.strip() for d in param.definitions}
    for name, value in dict(known or {}).items():
        target = standard if (name in names and name not in param.names and name not in alone) else minimal
        target[name] = value
    for name, value in standard.items():
        if not (np.isfinite(value) and value > 0) and name.startswith("m_"):  # m_total too
            raise SpaceidError(f"{where}: `known` {name}={shown(value)}: a mass must be positive and finite")
    return minimal, standard


def standard_anchor_error(name: str, param: Parameterization, where: str) -> SpaceidError:
    """The error for a known standard parameter without a prior: why the momentum cannot take it."""
    alone = ", ".join(d.strip() for d in param.definitions if re.fullmatch(r"\s*[A-Za-z_][A-Za-z_0-9]*\s*", d))
    return SpaceidError(
        f"{where}: `known` {name}: not a minimal parameter, and the momentum fixes it only in combinations with other "
        f"bodies' parameters, so no equation takes it alone (those that do: {alone or 'none'}): give a CAD prior "
        "(`prior`), with which it is a tight prior on that mass")


def _prior_terms(prior: Model, rel: float, known_standard: dict, where: str) -> tuple:
    """The prior as rows ``|D theta - d|^2`` (``D (n_theta + extra, n_theta)``), its mean ``theta_0``
    and deviations ``s``: independent in ``theta``, a known standard parameter held to ``KNOWN_STD``
    and a known total mass as one more row."""
    names = full_parameter_names(prior)[: len(theta_slots(prior))]
    theta0 = full_values(prior)[: len(names)].copy()
    s = prior_deviations(prior, rel)
    rows, rhs = [], []
    for name, value in known_standard.items():
        if name == TOTAL_MASS:
            row = np.array([1.0 / (KNOWN_STD * value) if n.startswith("m_") else 0.0 for n in names])
            rows.append(row)
            rhs.append(1.0 / KNOWN_STD)
            continue
        if name not in names:
            raise SpaceidError(f"{where}: `known` {name}: not a standard parameter of the prior")
        i = names.index(name)
        theta0[i], s[i] = value, KNOWN_STD * max(abs(value), s[i])
    D = np.vstack([np.diag(1 / s), *[r[None] for r in rows]])
    return D, np.concatenate([theta0 / s, rhs]), theta0, s


class _MapProgram:
    """One convex step: ``min |Ld theta - rd|^2 + |D theta - d|^2`` over ``theta = G vec X``,
    ``X_b - MARGIN 1`` PSD, declared zeros, ``C theta = c`` (the anchors, linearised), the data's
    rows (:func:`_rows`) more than ``CAPPED**2`` times as informative as the prior met exactly
    (``E theta = e``). Stated to Clarabel directly (:mod:`spaceid.models._conic`), the residuals of both terms
    unknowns of their own (``r``, tied to ``theta`` by equalities: the objective ``|r|^2``, not ``theta``'s Gram
    matrix, whose condition would be the data's squared)."""

    def __init__(self, g, z, D, d, s):
        self.g, self.z, self.D, self.d, self.s = g, z, D, d, s
        self.dup = duplication(g.shape[1] // 16)
        self.gd = g @ self.dup  # theta = gd x

    def _theta(self, c, cv, n_exact: int, sv, rows, rhs, exact):
        """``theta`` of the program with the data's ``n_exact`` strongest rows met exactly (the others weighted,
        at most ``CAPPED``), or None when it is not solved."""
        weight = np.minimum(sv, CAPPED) * (~exact if n_exact else 1)
        soft, soft_rhs = weight[:, None] * rows, weight * rhs
        fit = np.vstack([self.D, soft]) @ self.gd
        u = Unknowns(x=len(self.dup.T), r=len(fit))
        stated = physical_rows(u, self.z)
        stated.append((u.rows(len(fit), x=fit, r=-np.eye(len(fit))), np.concatenate([self.d, soft_rhs]),
                       cone("zero", len(fit))))  # r = fit x - [d; rd]
        for a_eq, b_eq in ((c, cv), (rows[exact], rhs[exact])) if n_exact else ((c, cv),):
            if len(a_eq):
                stated.append((u.rows(len(a_eq), x=a_eq @ self.gd), b_eq, cone("zero", len(a_eq))))
        P = np.zeros((u.n, u.n))
        P[u.at["r"] :, u.at["r"] :] = 2.0 * np.eye(len(fit))
        x = solved_tightly(P, np.zeros(u.n), stated)
        return None if x is None else self.gd @ u.of(x, "x")

    def solve(self, L, a, rd, c, cv):
        """``theta`` of the step (None when the solver fails): the data's strongest rows met exactly,
        else (no physical model meets them, as noisy data may ask) all capped at ``CAPPED``."""
        sv, rows, rhs = _rows(L, a, rd, self.s)
        exact = sv > CAPPED
        for n_exact in (int(exact.sum()), 0) if exact.any() else (0,):
            theta = self._theta(c, cv, n_exact, sv, rows, rhs, exact)
            if theta is not None:
                return theta
        return None


def _rows(L, a, rd, s) -> tuple:
    """The data rows ``|L a theta - rd|^2`` (``L (n, n_free)``, ``a = d pi_f / d theta (n_free, n_theta)``,
    ``rd (n,)``) on the singular directions of ``L a diag(s)`` (the data's information relative to the
    prior's), those of round-off left out: ``(sv (m,), rows (m, n_theta), rhs (m,))`` with the data
    term ``sum sv_i^2 (rows_i theta - rhs_i)^2`` up to a constant, ``m <= min(n, n_theta)``.

    The minimal parameters do not depend on some combinations of the standard ones (``a v = 0``):
    computed, ``L a v`` is round-off, up to ``n eps |L| |a diag(s)|`` (spectral norms; noise-free
    data: 1e2 to 1e4, as much as the prior's information or more), which the rotation leaves out.
    Noise-free data are up to 1e24 times as informative as the prior (:data:`FLOOR`) along the
    directions they determine and leave others to the prior alone: no interior-point solver resolves
    both in one objective, so the convex steps meet the first exactly (:class:`_MapProgram`) and
    :func:`_polish` weighs them against the prior."""
    ld, aw = L @ a, a * s
    if not ld.size:
        return np.zeros(0), ld[:0], rd[:0]
    u, sv, vt = svd(ld * s, full_matrices=False)
    round_off = aw.shape[1] * np.finfo(float).eps * np.linalg.norm(L, 2) * np.linalg.norm(aw, 2)
    keep = sv > max(round_off, np.finfo(float).tiny)
    return sv[keep], vt[keep] / s, (u[:, keep].T @ rd) / sv[keep]


def _weighted_rows(L, a, rd, s) -> tuple:
    """:func:`_rows` as least-squares rows ``(ld (m, n_theta), rd (m,))``."""
    sv, rows, rhs = _rows(L, a, rd, s)
    return sv[:, None] * rows, sv * rhs


def _floored(data: DataTerm, floor) -> DataTerm:
    """``data`` with its information capped so that no combination of the free parameters is known
    better than ``floor (n_free,)`` [their units] allows: ``L^T (1 + L F^2 L^T)^-1 L`` with
    ``F = diag(floor)``, the data's covariance plus ``F^2``.

    A noise-free log claims the parameters to a part in 1e17 of the prior: beyond what the model
    computes them to in double precision, and beyond what any later step can tell from round-off
    (the data's information on a direction the minimal parameters do not depend on, ``L A v`` with
    ``A v`` zero to round-off, would be as large as the prior's)."""
    if not data.L.size:
        return data
    u, sv, _ = svd(data.L * floor, full_matrices=False)
    rotate = u.T / np.sqrt(1 + sv**2)[:, None]
    return replace(data, L=rotate @ data.L, r=rotate @ data.r)


def _jacobian(param, theta):
    """``d pi / d theta (k, n_theta)`` at ``theta``; ``pi(theta) = jac @ theta`` (degree one)."""
    return param.projection @ full_values_jacobian(with_theta(param.model, theta))


def map_estimate(param: Parameterization, prior, data: DataTerm, *, prior_std: float = PRIOR_STD,
                 known_standard: dict | None = None, where: str = "log") -> tuple:
    """The MAP of the minimal parameters under a CAD prior, over physically consistent models.

    Parameters
    ----------
    param : Parameterization
        The identification's minimal set; its model's geometry must be the prior's.
    prior : Model or str or Path
        The CAD model (loaded in ``param``'s planar mode).
    data : DataTerm
    prior_std : float
        Relative standard deviation (:func:`prior_deviations`).
    known_standard : dict, optional
        Known standard parameters (``m_base``) or the total mass (``m_total``) [kg ...].

    Returns
    -------
    tuple
        ``(values (k,), cov (k, k), PriorRecord)``: the MAP, its posterior covariance (from the
        combined information at the MAP, the physical constraints taken as inactive; anchors exact).
    """
    with one_blas_thread():  # small factorisations throughout: on busy cores BLAS threads only wait
        return _map_estimate(param, prior, data, prior_std=prior_std, known_standard=known_standard, where=where)


def _map_estimate(param, prior, data, *, prior_std, known_standard, where) -> tuple:
    if not (np.isfinite(prior_std) and prior_std > 0):
        raise SpaceidError(f"`prior_std`: {shown(prior_std)} is not a positive relative standard deviation: give "
                           "e.g. 0.2 (20 %)")
    model = _prior_model(param, prior, where)
    known_standard = dict(known_standard or {})
    D, d, theta0, s = _prior_terms(model, prior_std, known_standard, where)
    # the prior as the program sees it: its declared zeros zero (a planar link's out-of-plane CoM)
    g, z = pseudo_whitening(with_theta(model, full_values(model)[: len(theta0)]), "`prior`")
    idx = np.array(sorted(data.anchors), int)
    cv = np.array([data.anchors[i] for i in idx], float)
    prior_pi, prior_jac = param.projection @ full_values(model), _jacobian(param, theta0)
    prior_cov = prior_jac @ np.linalg.pinv(D.T @ D) @ prior_jac.T
    prior_pi_std = np.sqrt(np.clip(np.diag(prior_cov), 0, None))
    data = _floored(data, FLOOR * prior_pi_std[data.free])
    program = _MapProgram(g, z, D, d, s)
    theta, steps = _convex_steps(param, program, data, D, d, theta0.copy(), idx, cv, s, where)
    strongest = np.linalg.norm((data.L @ prior_jac[data.free]) * s, 2) if data.L.size else 0.0
    if strongest**2 > TEMPERED[-1]:  # also through tempered stages; the lower objective is kept
        other = theta0.copy()
        for weight in (*(w / strongest**2 for w in TEMPERED), 1.0):
            tempered = replace(data, L=np.sqrt(weight) * data.L, r=np.sqrt(weight) * data.r)
            other, n = _convex_steps(param, program, tempered, D, d, other, idx, cv, s, where)
            steps += n
            if other is None:
                break
        value = (lambda th: np.inf if th is None else _objective(param, data, D, d, th))  # noqa: E731
        theta = other if value(other) < value(theta) else theta
    if theta is None:  # nothing to meet: the solver failed, on data far more informative than the prior
        ratio = (np.linalg.norm(data.L @ prior_jac[data.free], 2) / np.linalg.norm(D, 2)) ** 2
        raise SpaceidError(f"{where}: the MAP's convex step did not solve (the data are up to {ratio:.2g} times "
                           "as informative as the prior, as on a noise-free log): identify without `prior`")
    theta = _polish(param, data, D, d, theta, idx, cv, s, g, z)
    cov, jac = _posterior(param, data, D, theta, idx, s)
    least = [_least_whitened(g, z, th) for th in (theta, theta0)]
    active = tuple(b.name for b, at, start in zip(model.bodies, *least) if at < min(ACTIVE, 0.5 * start))
    pi = param.projection @ full_values(with_theta(model, theta))
    names = full_parameter_names(model)[: len(theta)]
    data_root = _weighted_rows(data.L, jac[data.free], data.r, s)[0]
    record = PriorRecord(
        str(model.source or model.name), float(prior_std), data.kind, data.reason, known_standard, prior_pi,
        prior_pi_std, data.values, data.std, attribution(data_root, D, names), active, steps,
        {"names": names, "map": theta.tolist(), "prior": theta0.tolist(), "prior_std": s.tolist()})
    return pi, cov, record


def _convex_steps(param, program, data, D, d, theta, idx, cv, s, where) -> tuple:
    """Convex steps from ``theta`` until it settles: ``(theta, steps)``, ``theta`` None when a step
    does not solve."""
    moved = lambda a, b: np.abs((a - b) / s).max()  # noqa: E731
    value, step = np.inf, np.inf
    objective = lambda th: _objective(param, data, D, d, th)  # noqa: E731
    for steps in range(1, MAX_STEPS + 1):
        jac = _jacobian(param, theta)
        out = program.solve(data.L, jac[data.free], data.r, jac[idx], cv)
        if out is None and len(idx):
            raise SpaceidError(f"{where}: no physically consistent model meets the anchored parameters "
                               f"({', '.join(param.names[i] for i in idx)}) near the prior: check `known` and the "
                               "prior (`prior`)")
        if out is None:  # nothing to meet: the solver failed (the caller says so)
            return None, steps
        new, value_new = out, objective(out)
        for _ in range(30):  # a Gauss-Newton step that does not lower the objective is halved (convex set)
            if value_new <= value * (1 + 1e-12) or not np.isfinite(value):
                break
            new = 0.5 * (theta + new)
            value_new = objective(new)
        step, gain, theta, value = moved(new, theta), value - value_new, new, value_new
        if step < STEP_TOL or gain <= VALUE_TOL * value:  # settled, or only the solver's noise moves it
            break
    else:
        warnings.warn(f"{where}: the MAP did not settle in {MAX_STEPS} convex steps (last move {step:.2g} prior "
                      "standard deviations)", stacklevel=5)
    return theta, steps


def _polish(param, data, D, d, theta, idx, cv, s, g, z):
    """Gauss-Newton steps without the physical constraints, kept while every body stays physical and
    the objective does not rise: the convex steps meet the optimum to the solver's tolerance (a part in
    1e7 of the parameters, a fraction of a standard error on rich data), these to round-off."""
    value = _objective(param, data, D, d, theta)
    for _ in range(3):
        jac = _jacobian(param, theta)
        ld, rd = _weighted_rows(data.L, jac[data.free], data.r, s)
        rows, rhs = np.vstack([ld, D]) * s, np.r_[rd, d]  # columns scaled by s
        start, basis = np.zeros(len(theta)), np.eye(len(theta))
        if len(idx):
            from scipy.linalg import null_space

            start = np.linalg.lstsq(jac[idx] * s, cv, rcond=None)[0]
            basis = null_space(jac[idx] * s, rcond=1e-12)
        new = s * (start + basis @ np.linalg.lstsq(rows @ basis, rhs - rows @ start, rcond=None)[0])
        new_value = _objective(param, data, D, d, new)
        if not (_least_whitened(g, z, new).min() > 0 and new_value <= value):
            break
        theta, value = new, new_value
    return theta


def _least_whitened(g, z, theta) -> np.ndarray:
    """The smallest eigenvalue of each body's whitened pseudo-inertia ``X_b`` at ``theta``, (nb,)."""
    rhs = np.r_[theta, np.zeros(len(z))]
    x = np.linalg.lstsq(np.vstack([g, z]), rhs, rcond=None)[0].reshape(-1, 4, 4).transpose(0, 2, 1)
    return np.array([np.linalg.eigvalsh(0.5 * (xb + xb.T))[0] for xb in x])


def _objective(param, data, D, d, theta) -> float:
    pi = param.projection @ full_values(with_theta(param.model, theta))
    return float(np.sum((data.L @ pi[data.free] - data.r) ** 2) + np.sum((D @ theta - d) ** 2))


def _posterior(param, data, D, theta, idx, s) -> tuple:
    """The covariance ``(k, k)`` of ``pi`` from the combined information at ``theta`` in the null
    space of the anchors (the physical constraints inactive), and the Jacobian there. From the
    singular values of the stacked square roots, in the prior's deviations ``s`` (the information
    itself, the data's 1e24 times the prior's, would be singular in double precision)."""
    jac = _jacobian(param, theta)
    rows = np.vstack([_weighted_rows(data.L, jac[data.free], data.r, s)[0], D]) * s
    basis = np.eye(len(theta))
    if len(idx):
        from scipy.linalg import null_space

        basis = null_space(jac[idx] * s, rcond=1e-12)
    _, sv, vt = svd(rows @ basis, full_matrices=False)  # sv > 0: the prior's rows have full rank
    root = s[:, None] * (basis @ (vt.T / sv))  # cov_theta = root root^T
    cov = (jac @ root) @ (jac @ root).T
    return 0.5 * (cov + cov.T), jac


def attribution(data_root, prior_root, names, top: int = 3) -> tuple:
    """Per eigen-direction of the data's information relative to the prior's: who sets it.

    Parameters
    ----------
    data_root : ndarray of shape (m, n)
        The data's information as a square root: ``data_root^T data_root``.
    prior_root : ndarray of shape (p, n)
        The prior's, of full column rank (``p >= n``).
    names : sequence of str
        The variables' names.

    Returns
    -------
    tuple of dict
        Largest ratio first: ``ratio`` (``lambda`` of ``data_info v = lambda prior_info v``),
        ``data_share`` (``lambda / (1 + lambda)``), ``set_by`` (``"data"`` when ``lambda > 1``) and
        ``leading``: the ``top`` variables with the largest weights in the direction (prior-whitened,
        unit norm), as ``[name, weight]``. The ratios are squared singular values of the whitened
        root (from the information matrices, a ratio of 1e-3 beside one of 1e20 would be lost).
    """
    from scipy.linalg import solve_triangular

    data_root, prior_root = np.atleast_2d(data_root), np.atleast_2d(prior_root)
    n = prior_root.shape[1]
    upper = np.linalg.qr(prior_root, mode="r")  # prior_info = R^T R
    white = solve_triangular(upper, data_root.T, trans="T").T if data_root.size else np.zeros((0, n))
    _, sv, vt = svd(np.vstack([white, np.zeros((max(0, n - len(white)), n))]))  # n values at least
    lam, vec = sv[:n] ** 2, vt.T
    out = []
    for i in np.argsort(-lam, kind="stable"):
        v = vec[:, i] * np.sign(vec[np.argmax(np.abs(vec[:, i])), i])
        order = np.argsort(-np.abs(v))[:top]
        out.append({"ratio": float(lam[i]), "data_share": float(lam[i] / (1 + lam[i])),
                    "set_by": "data" if lam[i] > 1 else "prior",
                    "leading": [[names[j], round(float(v[j]), 4)] for j in order]})  # fmt: skip
    return tuple(out)


def _prior_model(param: Parameterization, prior, where: str) -> Model:
    """The prior in ``param``'s planar mode, refused unless it has ``param``'s joints, standard
    parameters and geometry (its bodies' placements and axes): the minimal set acts on its values."""
    model = load_model(prior, planar=param.model.planar)
    mine = param.model
    if tuple(model.joints) != tuple(mine.joints):
        raise SpaceidError(f"`prior`: joints {list(model.joints)} differ from the model's {list(mine.joints)}: "
                           "give a CAD model of the same robot")
    same = full_parameter_names(model) == full_parameter_names(mine) and all(
        a.parent == b.parent and np.allclose(a.axis, b.axis) and np.allclose(a.rotation, b.rotation)
        and np.allclose(a.translation, b.translation, atol=1e-9)
        for a, b in zip(model.bodies, mine.bodies))
    if not same:
        raise SpaceidError(f"`prior`: its bodies or geometry differ from the model's ({where}): give a prior with the "
                           "model's kinematics and declared zeros")
    return model


def identify_with_prior(identify, param: Parameterization, log, momentum, *, prior, prior_std, known, estimator,
                        noise, where, cond_limit, drift, history, **options):
    """``identify(..., prior=...)``: the data term (the estimator's estimate when the data determine
    the parameters, else the weighted equations at the prior), the MAP and the record; ``identify``
    is :func:`spaceid.estimation.identify` without a prior."""
    minimal, standard = split_known(param, known, where)
    model = _prior_model(param, prior, where)
    reason, eq = _undetermined(param, log, momentum, minimal, where, cond_limit, drift, history)
    data_fit = None
    if not reason:
        try:
            with warnings.catch_warnings(record=True) as caught:
                warnings.simplefilter("always")
                data_fit = identify(param, log, momentum, known=minimal, estimator=estimator, noise=noise,
                                    where=where, cond_limit=cond_limit, drift=drift, history=history, **options)
        except SpaceidError as exc:  # the estimator's system is singular though the condition number passed
            if "singular or non-finite" not in str(exc):
                raise
            reason = f"the {estimator} estimate failed on a singular system"
        for w in caught:  # the data fit's advice to give a prior is moot here: the prior sets those directions
            warnings.warn(str(w.message).replace(UNDETERMINED_FIX, "the prior sets them"), w.category, stacklevel=3)
    if data_fit is not None:
        data = data_from_estimate(data_fit.values, data_fit.cov, eq.free, dict(zip(eq.known, eq.known_values)))
        weak = data_fit.diagnostics.undetermined
        if len(data.L) == len(eq.free) and not weak:
            pi, cov, record = map_estimate(param, model, data, prior_std=prior_std, known_standard=standard,
                                           where=where)
            d = data_fit.diagnostics
            diagnostics = replace(d, covariance=f"posterior of the CAD prior and the data's: {d.covariance}")
            return replace(data_fit, values=pi, cov=cov, std=np.sqrt(np.clip(np.diag(cov), 0, None)), prior=record,
                           diagnostics=diagnostics)
        # directions the data do not determine are the prior's (the equations' information there is the noise's, and
        # the estimate's is widened out of reach); a covariance of lower rank claims exact knowledge the data
        # cannot have (a sandwich of few samples)
        reason = (f"the data do not determine {len(weak)} directions" if weak else
                  f"the {estimator} covariance ({data_fit.diagnostics.covariance_method}) has rank {len(data.L)} "
                  f"for {len(eq.free)} parameters")
    return _equations_with_prior(param, log, eq, model, prior_std, standard, noise, estimator, reason, where)


def _score_covariance(log, eq, x, theta, sigma, whitener, white):
    """``covariance(bread)``: ``bread Omega bread^T`` for ``bread (k, n_free)``, ``Omega`` the covariance
    of the weighted equations' score for the free parameters, ``sum_n A_n^T S_n^-1 e_n`` with the
    nuisance (momentum, drift) profiled out, from the signals' noise: the differentiated ones through
    their filters (correlated over the windows), the others white
    (:func:`~spaceid.estimation._differentiated.propagated_covariance`). ``whitener (n, rows, rows)``
    ``L_n^-1``, ``white`` the whitened equations ``[A | -b]``."""
    from ._differentiated import differentiated_series, propagated_covariance

    nf, p = len(eq.free), white.shape[-1] - 1
    A = white[..., :p]
    profile = np.zeros((0, nf))
    if p > nf:  # the nuisance's least squares on the free columns, profiled out of them
        flat = A.reshape(-1, p)
        with one_blas_thread():
            gram = flat.T @ flat[:, nf:]
        profile = np.linalg.pinv(gram[nf:], rcond=1e-13) @ gram[:nf].T
    scores = np.swapaxes(whitener, -1, -2) @ (A[..., :nf] - A[..., nf:] @ profile)  # S_n^-1 A_n, profiled
    series = differentiated_series(log, attitude=True) or []
    jac = eq.jacobian(x, theta)
    return lambda bread: propagated_covariance(series, log.t, [(slice(None), scores, jac)], bread, sigma)


def _undetermined(param, log, momentum, minimal, where, cond_limit, drift, history) -> tuple:
    """Why the data alone do not determine the parameters (``""``: they do), and the equations."""
    from ._equations import _equations, _split
    from ._identify import excitation_condition

    eq, _ = _equations(param, log, momentum, minimal, where, drift, history, scale_free=True)
    if not len(eq.known) and (momentum is None or not np.linalg.norm(momentum) > 0):
        return "no momentum and no anchored minimal parameter: the data fix the parameters only up to scale", eq
    phi = eq.phi(eq.signals(log))
    if not np.any(_split(phi)[1]):
        return "the right-hand side is zero (no momentum to identify from)", eq
    cond = excitation_condition(phi)
    if not cond < cond_limit:
        return f"the motion does not excite every parameter (scaled condition number {cond:.3g})", eq
    return "", eq


def _equations_with_prior(param, log, eq, model, prior_std, standard, noise, estimator, reason, where):
    """The MAP with the momentum equations weighted by their noise at the prior as the data."""
    from ._diagnostics import Diagnostics
    from ._equations import _split
    from ._linalg import _equation_whitener, lower_inverse
    from ._determined import noise_gram, noise_rows
    from ._differentiated import weighting_sigma
    from ._noise import noise_from_log
    from ._result import Identification

    noise = noise or noise_from_log(log)
    x = eq.signals(log)
    phi = eq.phi(x)
    A, b = _split(phi)
    A, b = A.reshape(-1, A.shape[-1]), b.reshape(-1)
    nf = len(eq.free)
    pi0 = param.projection @ full_values(model)

    def nuisance(pi_f):  # the momentum and drift that fit best with the parameters ``pi_f``
        rest = A[:, nf:]
        return np.linalg.lstsq(rest, b - A[:, :nf] @ pi_f, rcond=None)[0] if rest.shape[1] else np.zeros(0)

    theta0 = np.concatenate([pi0[eq.free], nuisance(pi0[eq.free])])
    sigma = weighting_sigma(param, log, noise)  # as identify weights them
    whitener = lower_inverse(_equation_whitener(eq, x, theta0, sigma))
    white = whitener @ phi
    rows, scale = noise_rows(len(x))  # the regressor's own noise, propagated from each signal's
    part = eq.select(rows)
    gram = noise_gram(lambda signals: whitener[rows] @ part.phi(signals), x[rows], sigma, scale, eq.rate_channels)
    score_covariance = _score_covariance(log, eq, x, theta0, sigma, whitener, white)
    with one_blas_thread():  # a QR of the equations, then factorisations of p x p matrices
        data = data_from_equations(white, gram, nf, reason, dict(zip(eq.known, eq.known_values)), eq.free,
                                   score_covariance)
    pi, cov, record = map_estimate(param, model, data, prior_std=prior_std, known_standard=standard, where=where)
    theta = np.concatenate([pi[eq.free], nuisance(pi[eq.free])])
    h = eq.full(theta)[1]
    s = svd(A, compute_uv=False)
    diagnostics = Diagnostics(covariance_method="prior", covariance=(
        "posterior of the CAD prior and the momentum equations weighted by the noise model at the prior "
        f"({reason})"), estimator_info={"data_term": "equations"})
    return Identification(
        names=param.names, definitions=param.definitions, values=pi, std=np.sqrt(np.clip(np.diag(cov), 0, None)),
        cov=cov, condition_number=float(s[0] / s[-1]) if s[-1] > 0 else np.inf, singular_values=s,
        residual_rms=float(np.sqrt(np.mean((A @ theta - b) ** 2))), n_samples=log.n_samples, estimator=estimator,
        momentum=h, model=param.model.source or param.model.name, planar=param.model.planar,
        settings={"parameterization": param.to_dict(), "log": dict(log.meta), "noise": noise.to_dict(),
                  "anchors": [{"name": param.names[i], "definition": param.definitions[i], "value": float(v),
                               "source": "given"} for i, v in zip(eq.known, eq.known_values)],
                  "momentum_estimated": eq.momentum is None},
        units=param.units, diagnostics=diagnostics, prior=record)
