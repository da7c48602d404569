"""The excitation design problem: the free Fourier coefficients in scaled variables, the joint
limits and boundary values they must keep, and the regressor and criterion as functions of them.

Scaled variables. The free coefficients ``X = [a | b]`` (n_joints, 2 Nf) of
:class:`~spaceid.motion.FourierTrajectory` are searched as ``z`` (``X = S * z``, with ``S`` such
that ``|z_jk| = 1`` alone takes joint j to its tightest limit); the quintic through the boundary
values is added to them. q, qd and qdd are affine in ``z``, so the joint limits, imposed on a
fine time grid, are linear inequalities, and separate by joint.

Limits at all times. Per joint, a signal's *room* is what the quintic ``p`` (over the limit)
leaves it before the limit: ``1 - p`` upwards, ``1 + p`` downwards. The *room used* is the
largest fraction of it that the Fourier part takes at any time (above 1: a limit broken).
Between grid points a signal exceeds its grid values by up to 3e-4 of a limit, so each peak on
the grid is refined between its neighbours (a trigonometric sum, unimodal there). Dividing a
joint's coefficients by its room used puts it exactly on its limits.

Gradients. The rows of sample t of the stacked regressor ``Y`` depend on q(t), qd(t) alone, so
central differences of the joint signals (4 n_joints perturbed trajectories; the trust-region
model takes 2 n_joints forward ones) give ``dY/dq_j``, ``dY/dqd_j`` at every sample, and the
chain rule through the fixed Fourier basis gives the gradient in all n = 2 Nf n_joints
coefficients. A criterion supplies its gradient in ``Y``, never ``dY`` along each coefficient.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass, replace
from functools import cached_property

import numpy as np

from .._errors import SpaceidError
from .._svd import svd
from ._criteria import CRITERIA
from ._trajectory import BOUNDARY_FIELDS, boundary_quintic, fourier_basis, sample_times

# Samples a regressor call of the search: larger calls run out of cache (3 to 4 times slower a
# sample for 169 x 120 samples of a 7-joint arm)
_CALL_SAMPLES = 512
# The SLSQP search phase works on a subsample of at least this many samples a period of the top
# harmonic (and twice as many equations as columns); the polish and the result use them all
_SEARCH_SAMPLES_PER_PERIOD = 12


class _OutOfTime(Exception):
    """Raised inside a local search when its deadline has passed (caught by the search)."""


def _check_clock(deadline):
    """Raise :class:`_OutOfTime` if ``deadline`` (time.time(), or None) has passed."""
    if deadline is not None and time.time() > deadline:
        raise _OutOfTime


@dataclass(frozen=True)
class _ExcitationProblem:
    """The design problem in scaled coefficients; picklable, sent once to each worker process.

    ``z`` (..., n) are scaled coefficients, ``X = S * z.reshape(..., n_joints, K)``, n = n_joints K,
    K = 2 Nf. q, qd, qdd on the fine grid are ``B @ X.T + P`` (3, n_grid, n_joints), limits ``L``.
    """

    regressor: Callable  # regressor(q, qd), as for optimize_excitation
    criterion: str  # a key of CRITERIA
    S: np.ndarray  # (n_joints, K)
    B_samples: np.ndarray  # (2, n_samples, K): q, qd basis at the samples
    P_samples: np.ndarray  # (2, n_samples, n_joints)
    B: np.ndarray  # (3, n_grid, K)
    P: np.ndarray  # (3, n_grid, n_joints)
    L: np.ndarray  # (3, n_joints)
    coarse: np.ndarray  # fine-grid time indices constrained during an SLSQP search
    duration: float  # [s]; the fine grid spans [0, duration]
    boundary: np.ndarray  # (6, n_joints), BOUNDARY_FIELDS order: P at any time
    # finite-difference step in q [rad] and qd [rad/s]; a regressor may ask for another one
    # by an ``fd_step`` attribute (see whitened_regressor)
    step: float = 1e-6
    # The smooth room used is this norm of the room used over the fine grid: it exceeds the
    # max by a few % (a few points near a peak)
    room_norm: float = 64.0
    # the same problem on fewer samples, for the SLSQP search phase (None: the samples are few)
    subsampled: _ExcitationProblem | None = None

    @property
    def n(self):
        """Number of free coefficients, n_joints K."""
        return self.S.size

    def coefficients(self, z):
        """Fourier coefficients ``X`` (..., n_joints, K) of scaled coefficients ``z`` (..., n)."""
        return self.S * np.reshape(z, (*np.shape(z)[:-1], *self.S.shape))

    # -- the regressor and the criterion -------------------------------------------------------

    def _sampled_signals(self, Z):
        """q [rad], qd [rad/s] at the samples of ``Z (batch, n)``, shape
        (2, batch, n_samples, n_joints)."""
        X = self.coefficients(Z)
        return np.einsum("dtk,bjk->dbtj", self.B_samples, X) + self.P_samples[:, None]

    def stacked_regressor(self, Z):
        """Stacked regressors of scaled coefficients ``Z (batch, n)``: (batch, rows, k)."""
        q, qd = self._sampled_signals(Z)
        return self.regressor(q, qd)

    def objective(self, Z):
        """Objective of scaled coefficients ``Z (batch, n)``: (batch,), inf where singular."""
        with np.errstate(divide="ignore", invalid="ignore"):
            f = CRITERIA[self.criterion].pieces(self.stacked_regressor(Z)).max(-1)
        return np.where(np.isnan(f), np.inf, f)

    def smooth_objective(self, Z, p):
        """The criterion's smooth surrogate of sharpness ``p`` at ``Z (batch, n)``: (batch,)."""
        q, qd = self._sampled_signals(Z)
        chunk = max(1, _CALL_SAMPLES // q.shape[-2])  # and no (batch, rows, k) array at once
        Ys = (self.regressor(q[i : i + chunk], qd[i : i + chunk]) for i in range(0, len(q), chunk))
        return np.concatenate([self.smooth_objective_of_regressor(Y, p) for Y in Ys])

    def smooth_objective_of_regressor(self, Y, p):
        """The surrogate of the stacked regressors ``Y`` (..., n_rows, k): (...), inf where
        singular."""
        with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
            f = CRITERIA[self.criterion].smoothed_value(Y, p)
        return np.where(np.isnan(f), np.inf, f)

    def linearize_regressor(self, z, Y0=None, *, central=True, deadline=None):
        """Y at ``z`` (n_rows, k) and its derivatives along the joint signals at every sample,
        ``dY`` (n_samples, 2 n_joints, m k): ``dY[t, (d, j)]`` is d(rows of sample t) / d q_j
        (d = 0) or d qd_j (d = 1), flattened; each sample's derivatives contiguous, as they are
        written and read (a signal-last layout made writing them a quarter of the servicer's
        linearisation).

        Sample t's rows of Y depend on q(t), qd(t) alone, so perturbing joint j's signal at all
        samples at once gives them all: 4 n_joints central differences, or 2 n_joints forward
        ones (error O(step), for the trust-region model and the SLSQP search phase). ``Y0``, Y
        at ``z`` if known, saves its evaluation. Raises :class:`_OutOfTime` between regressor
        calls once ``deadline`` (time.time()) has passed.
        """
        x = np.einsum("dtk,jk->dtj", self.B_samples, self.coefficients(z)) + self.P_samples  # q, qd
        nj, n_s = self.S.shape[0], x.shape[1]
        E = self.step * np.eye(2 * nj).reshape(2 * nj, 2, 1, nj)  # signal (d, j), every sample
        signs = (1, -1) if central else (1,)
        group = max(1, _CALL_SAMPLES // (len(signs) * n_s))
        dY = None
        for c in range(0, 2 * nj, group):
            _check_clock(deadline)
            # Y at z rides with the first call: for small models the per-call cost dominates
            lead = [x[None]] if Y0 is None else []
            X = np.concatenate(lead + [x + sign * E[c : c + group] for sign in signs])
            Y = self.regressor(X[:, 0], X[:, 1])
            if lead:
                Y0, Y = Y[0], Y[1:]
            Y = Y.reshape(len(signs), -1, *Y0.shape)
            G = (Y[0] - Y[1]) / (2 * self.step) if central else (Y[0] - Y0) / self.step
            if dY is None:
                dY = np.empty((n_s, 2 * nj, Y0.size // n_s))
            dY[:, c : c + group] = G.reshape(len(G), n_s, -1).transpose(1, 0, 2)
        return Y0, dY

    def coefficient_gradient(self, W, dY):
        """Gradient in ``z`` (n,) of a function of Y with gradient ``W`` (n_rows, k) in Y.

        ``dY/dz_p = dY/dq_j B_q[t, k] S_jk + dY/dqd_j B_qd[t, k] S_jk`` for p = (j, k), so
        the gradient needs only the 2 n_joints signal derivatives ``dY`` (see
        :meth:`linearize_regressor`), never the n directional derivatives of Y.
        """
        n_s = dY.shape[0]
        w = (dY @ W.reshape(n_s, -1, 1)).reshape(n_s, 2, -1)  # <W_t, dY_t/d(q|qd)_j>
        return (np.einsum("tdj,dtk->jk", w, self.B_samples) * self.S).ravel()

    def linearize_criterion(self, z, *, central=True, deadline=None):
        """Pieces at ``z`` and their gradients (n_pieces, n), from one batched regressor call
        of 1 + 4 n_joints trajectories (1 + 2 n_joints unless ``central``; see
        :meth:`linearize_regressor`, :meth:`coefficient_gradient`)."""
        Y, dY = self.linearize_regressor(z, central=central, deadline=deadline)
        crit = CRITERIA[self.criterion]
        if crit.adjoint is not None:
            pieces, W = crit.adjoint(Y)
            return pieces, np.array([self.coefficient_gradient(w, dY) for w in W])
        # a criterion without adjoint: the n directional derivatives of Y, explicitly
        n_s, nj = dY.shape[0], self.S.shape[0]
        G = dY.reshape(n_s, 2, nj, -1, Y.shape[-1])
        dY_dz = np.einsum("tdjmk,dtl,jl->jltmk", G, self.B_samples, self.S)
        return crit.pieces(Y, dY_dz.reshape(self.n, *Y.shape))

    # -- the limits ----------------------------------------------------------------------------

    def signals_over_limits(self, Z):
        """q, qd, qdd on the fine grid over their limits, shape (..., 3, n_grid, n_joints)."""
        X = self.coefficients(Z)
        return (np.einsum("dtk,...jk->...dtj", self.B, X) + self.P) / self.L[:, None]

    @cached_property
    def grid_room_terms(self):
        """Fine-grid signals over limits per unit z, ``A`` (n_rows, n_joints, K), and the
        factors ``1 / (1 -+ p)`` (n_rows, n_joints), p the quintic over the limit, that turn
        a signal ``v`` of either sign into the fraction of its room it uses: ``v / (1 - p)``
        (v > 0) or ``-v / (1 + p)`` (v < 0)."""
        A = self.B[:, :, None, :] * self.S / self.L[:, None, :, None]
        p = (self.P / self.L[:, None]).reshape(-1, self.S.shape[0])
        return A.reshape(-1, *self.S.shape), *_inverse_rooms(p)

    def _room_used_on_grid(self, Z):
        """The signals over limits ``v`` of ``Z (..., n)`` on the fine grid and the fraction of
        their room they use, ``r``: both (..., n_rows, n_joints)."""
        A, up, down = self.grid_room_terms
        v = np.einsum("rjk,...jk->...rj", A, np.reshape(Z, (*np.shape(Z)[:-1], *self.S.shape)))
        return v, np.where(v > 0, v * up, -v * down)

    def room_used(self, Z):
        """Per joint, the largest fraction of its room that ``Z (..., n)``'s signals use at any
        time (above 1: a limit broken): (..., n_joints). The max over all times, not only the
        fine grid's (:meth:`_refine_room_peaks`), so ``Z_j / room_used_j`` keeps the limits on
        the continuous trajectory."""
        r = self._room_used_on_grid(Z)[1]
        return self._refine_room_peaks(np.reshape(Z, (-1, self.n)), r.reshape(-1, *r.shape[-2:])
                                       ).reshape(r.shape[:-2] + r.shape[-1:])  # fmt: skip

    def smooth_room_used(self, y):
        """For one ``y`` (n,), per joint: the ``room_norm``-norm of the room used over the fine
        grid (smooth, and >= its max, so ``y_j / rho_j`` keeps the limits there), ``rho``
        (n_joints,), and its gradient (n_joints, K)."""
        A, up, down = self.grid_room_terms
        v, r = self._room_used_on_grid(y)
        order = self.room_norm
        top = r.max(0)
        top = np.where(top > 0, top, 1.0)  # y_j = 0: no motion, nothing to scale
        w = r / top
        wp = w ** (order - 1)
        norm = (wp * w).sum(0) ** (1 / order)
        dr = wp * np.where(v > 0, up, -down)  # d(r^order) / dv, over order top^(order - 1)
        grad = np.einsum("rj,rjk->jk", dr, A) * norm[:, None] ** (1 - order)
        return top * norm, grad

    def _refine_room_peaks(self, Z, r):
        """Per joint, the max over all times of the room used, ``rho`` (batch, n_joints), for
        ``Z`` (batch, n) whose fine-grid values are ``r`` (batch, 3 n_grid, n_joints).

        Between grid points a signal can exceed its grid values (by 3e-4 of a limit for the
        servicer's qdd on the default grid). Each grid local maximum above half the joint's
        grid maximum (lower ones cannot overtake it unless the grid misses half a period of
        the top harmonic) brackets a true local maximum between its neighbours, where the
        trigonometric sum is unimodal; golden-section search finds it to round-off.
        """
        nj, n_grid = self.S.shape[0], self.B.shape[1]
        r = r.reshape(len(r), 3, n_grid, nj)
        rho = r.max(axis=(1, 2))
        edge = np.full_like(r[:, :, :1], -np.inf)
        ahead = np.concatenate([r[:, :, 1:], edge], 2)
        behind = np.concatenate([edge, r[:, :, :-1]], 2)
        top = (r >= ahead) & (r >= behind) & (r >= 0.5 * rho[:, None, None])
        b, d, i, j = np.nonzero(top & (rho[:, None, None] > 0))
        if not len(b):
            return rho
        L = self.L[d, j]
        coef = self.coefficients(Z)[b, j] / L[:, None]  # (n_peaks, K): Fourier part over limit
        at = np.arange(len(b))
        T, harmonics = self.duration, self.S.shape[1] // 2

        def room_used_at(t):
            v = np.sum(fourier_basis(t, duration=T, harmonics=harmonics)[d, at] * coef, -1)
            p = boundary_quintic(t, duration=T, boundary=self.boundary)[d, at, j] / L
            up, down = _inverse_rooms(p)
            return np.where(v > 0, v * up, -v * down)

        dt = T / (n_grid - 1)
        lo, hi = np.maximum(i - 1, 0) * dt, np.minimum(i + 1, n_grid - 1) * dt
        np.maximum.at(rho, (b, j), _golden_section_max(room_used_at, lo, hi))
        return rho

    def shrink_into_limits(self, Z):
        """``s Z`` with, per row, the largest ``s <= 1`` that keeps the limits at all times
        (:meth:`room_used`): all joints scaled together.

        ``z = 0`` (the boundary quintic alone) is feasible, so such an ``s >= 0`` exists.
        """
        with np.errstate(divide="ignore"):
            return Z * np.minimum(1.0, 1 / self.room_used(Z).max(-1))[..., None]

    def scale_onto_limits(self, Z, *, inside=False):
        """``Z (..., n)`` with every joint scaled onto its limits at all times (:meth:`room_used`),
        or, if ``inside``, only those beyond them."""
        Z = np.asarray(Z, float)
        rho = self.room_used(Z)
        rho = np.maximum(rho, 1.0) if inside else np.where(rho > 0, rho, 1.0)
        return (np.reshape(Z, (*Z.shape[:-1], *self.S.shape)) / rho[..., None]).reshape(Z.shape)

    def map_onto_limits(self, y):
        """The radial map ``z = y_j / rho_j`` joint by joint (``rho`` of
        :meth:`smooth_room_used`), which puts every joint of any ``y`` (n,) on its limits on the
        fine grid, and the map of a gradient in z to one in y: ``z, pull`` with ``pull(gz) -> gy``.
        """
        rho, drho = self.smooth_room_used(y)
        Y = np.reshape(y, self.S.shape)
        z = (Y / rho[:, None]).ravel()

        def pull(gz):
            gz = gz.reshape(self.S.shape)
            return (gz / rho[:, None] - drho * (np.sum(Y * gz, 1) / rho**2)[:, None]).ravel()

        return z, pull

    # -- random starts -------------------------------------------------------------------------

    def random_inside_limits(self, rng, m):
        """``m`` random feasible points (m, n): isotropic random directions, each scaled to a
        random fraction (1/4 to 1) of the largest feasible step along it."""
        Z = self.shrink_into_limits(1e6 * rng.standard_normal((m, self.n)))
        return Z * rng.uniform(0.25, 1, (m, 1))

    def random_on_limits(self, rng, m):
        """``m`` random points (m, n) on the limits: isotropic directions, each joint scaled
        onto its limits. Joint by joint rather than together: scaling by the tightest joint
        leaves the others at a fraction of their range (cond 10 times worse on a 7-joint arm)."""
        return self.scale_onto_limits(rng.standard_normal((m, self.n)))


def _inverse_rooms(p):
    """``1 / (1 - p)``, ``1 / (1 + p)`` for the quintic over the limit ``p`` (any shape): they
    turn a Fourier part over the limit of either sign into the fraction of its room it uses."""
    return 1 / np.maximum(1 - p, 1e-12), 1 / np.maximum(1 + p, 1e-12)


def _golden_section_max(f, lo, hi, iterations=40):
    """Vectorised golden-section search: the max of ``f`` (elementwise, of times (m,) [s]) in
    each bracket ``[lo, hi]`` (m,) [s] where it is unimodal, shape (m,). The bracket shrinks to
    0.618^iterations of its width (4e-9 for 40), so near a smooth maximum the value is exact
    to round-off."""
    g = (np.sqrt(5) - 1) / 2
    a, b = lo, hi
    c, d = b - g * (b - a), a + g * (b - a)
    fc, fd = f(c), f(d)
    for _ in range(iterations):
        left = fc >= fd  # the max lies in [a, d]: d becomes b, c becomes d
        a, b = np.where(left, a, c), np.where(left, d, b)
        new = np.where(left, b - g * (b - a), a + g * (b - a))
        c, d = np.where(left, new, d), np.where(left, c, new)
        f_new = f(new)
        fc, fd = np.where(left, f_new, fd), np.where(left, fc, f_new)
    return np.maximum(fc, fd)


# -- set-up and checks ----------------------------------------------------------------------------


def _set_up_problem(regressor, criterion, *, duration, harmonics, samples, limits, boundary,
                    n_grid):
    """The design problem in scaled variables (see _ExcitationProblem) for ``limits`` (3,
    n_joints) and ``boundary`` (6, n_joints), checking that the quintic through the boundary
    values keeps the limits."""
    t = sample_times(duration, n_grid)
    B = fourier_basis(t, duration=duration, harmonics=harmonics)
    t_s = sample_times(duration, samples)
    B_samples = fourier_basis(t_s, duration=duration, harmonics=harmonics)[:2]
    S = 1.0 / np.max(np.abs(B)[:, :, None, :] / limits[:, None, :, None], axis=(0, 1))
    n_coarse = 10 * harmonics + 1  # ten points a period of the top harmonic
    problem = _ExcitationProblem(
        regressor=regressor,
        criterion=criterion,
        S=S,
        B_samples=B_samples,
        P_samples=boundary_quintic(t_s, duration=duration, boundary=boundary)[:2],
        B=B,
        P=boundary_quintic(t, duration=duration, boundary=boundary),
        L=limits,
        coarse=np.unique(np.linspace(0, n_grid - 1, n_coarse).round().astype(int)),
        duration=duration,
        boundary=boundary,
        **({"step": float(regressor.fd_step)} if hasattr(regressor, "fd_step") else {}),
    )
    if np.abs(problem.signals_over_limits(np.zeros(problem.n))).max() > 1:
        raise SpaceidError(
            "`boundary`: the quintic through the boundary values alone breaks a joint limit; "
            "bring the boundary values inside the limits or relax the limits"
        )
    return problem


def _with_search_subsample(problem, *, harmonics, n_min_samples):
    """``problem`` holding, as ``subsampled``, a copy on fewer equally spaced samples for the
    SLSQP search phase: ``_SEARCH_SAMPLES_PER_PERIOD`` a period of the top harmonic, and at
    least ``2 n_min_samples`` (the fewest samples whose equations outnumber the columns);
    unchanged if it has no more samples than that. The criteria are sums over samples of
    smooth signals, so a subsample this dense ranks trajectories as all the samples do, at a
    fraction of the cost; the polish and the result use all of them."""
    n_samples, T = problem.B_samples.shape[1], problem.duration
    n_search = max(_SEARCH_SAMPLES_PER_PERIOD * harmonics, 2 * n_min_samples)
    if n_search >= n_samples:
        return problem
    t = sample_times(T, n_search)
    sub = replace(problem, B_samples=fourier_basis(t, duration=T, harmonics=harmonics)[:2],
                  P_samples=boundary_quintic(t, duration=T, boundary=problem.boundary)[:2])  # fmt: skip
    return replace(problem, subsampled=sub)


def _limit_array(joints, q_max, qd_max, qdd_max):
    """Limits as an array (3, n_joints): rows |q| [rad], |qd| [rad/s], |qdd| [rad/s^2]."""
    rows = []
    for name, value in (("q_max", q_max), ("qd_max", qd_max), ("qdd_max", qdd_max)):
        arr = np.asarray(value, dtype=float)
        if arr.ndim > 1 or arr.size not in (1, len(joints)):
            raise SpaceidError(
                f"`{name}` must be a number or one value per joint ({len(joints)}), got {value!r}"
            )
        if not np.all(np.isfinite(arr) & (arr > 0)):
            raise SpaceidError(f"`{name}` must be positive and finite, got {value!r}")
        rows.append(np.broadcast_to(arr, (len(joints),)))
    return np.array(rows)


def _boundary_array(joints, boundary):
    """Boundary values as an array (6, n_joints), rows in BOUNDARY_FIELDS order."""
    boundary = dict(boundary or {})
    unknown = set(boundary) - set(BOUNDARY_FIELDS)
    if unknown:
        raise SpaceidError(
            f"`boundary`: unknown key(s) {', '.join(sorted(unknown))}; "
            f"expected some of {', '.join(BOUNDARY_FIELDS)}"
        )
    out = np.zeros((6, len(joints)))
    for row, key in enumerate(BOUNDARY_FIELDS):
        if key in boundary:
            value = np.asarray(boundary[key], dtype=float)
            if value.shape != (len(joints),) or not np.all(np.isfinite(value)):
                raise SpaceidError(
                    f"`boundary` '{key}' must be {len(joints)} finite values, got {boundary[key]!r}"
                )
            out[row] = value
    return out


def _warm_start_coefficients(problem, initial, joints, duration, harmonics, bc):
    """Scaled coefficients (n,) of a warm-start trajectory, after checking that it fits."""
    if not (
        initial.joints == joints
        and initial.duration == float(duration)
        and initial.n_harmonics == harmonics
        and np.array_equal(initial.boundary, bc)
    ):
        raise SpaceidError(
            "`initial`: the warm-start trajectory must have the design's joints, duration, "
            "number of harmonics and boundary values"
        )
    return (initial.coefficients / problem.S).ravel()


def _checked_regressor_columns(problem, n_joints, samples):
    """The regressor's number of columns k and rows a sample m, after checking its output
    shape."""
    zeros = np.zeros((1, samples, n_joints))
    shape = np.shape(problem.regressor(zeros, zeros))
    if len(shape) != 3 or shape[0] != 1 or shape[1] % samples:
        raise SpaceidError(
            f"`regressor` must map (batch, {samples}, {n_joints}) joint arrays to "
            f"(batch, {samples} * m, k); got shape {shape}"
        )
    if shape[1] < shape[2]:
        raise SpaceidError(
            f"`samples`: {samples} give {shape[1]} equations for {shape[2]} parameters; "
            f"use at least {-(-shape[2] * samples // shape[1])} samples"
        )
    return shape[2], shape[1] // samples


def _check_rank(problem, Z0):
    """Full numerical rank of the stacked regressor at one of the starts ``Z0``, tried in turn until one has it
    (an SVD each: the servicer's eight took 0.3 s, where the first settles the check on any motion that can be
    designed)."""
    for Y in problem.stacked_regressor(Z0):
        s = svd(Y, compute_uv=False)
        if s[-1] > s[0] * max(Y.shape) * np.finfo(float).eps:  # numerical rank k
            return
    raise SpaceidError(
        "the regressor is rank deficient on random start trajectories: its columns are not "
        "identifiable together (reduce them to a minimal parameter set), or the motion is "
        "too poor to excite them all (more harmonics, samples or duration, wider limits)"
    )
