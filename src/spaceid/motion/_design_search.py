"""The excitation search: local searches of the design problem from seeded random starts, in
worker processes, within a time budget.

Two local searches (``method``):

* ``slsqp`` (small regressors: planar arms). A criterion is the maximum of a few smooth
  *pieces* of ``Y``; SLSQP minimises ``tau`` subject to ``piece(z) <= tau`` and the limits. This
  epigraph form keeps the condition number smooth where its extreme singular values coalesce,
  which they do at the optimum. Each search imposes the limits on a coarse grid, then on the
  fine-grid points near the peaks of the signals, and is scaled back into the limits; the
  best two results are polished with all fine-grid limits that can become active.
* ``trust-region`` (spatial systems: a hundred or more columns, a spectrum that decays smoothly
  over decades, and a regressor costing tens of microseconds a sample). Each joint is kept on
  its limits by a radial map, so the search is unconstrained; the criterion is replaced by a
  smooth surrogate whose sharpness rises in stages; each step linearises ``Y`` in the joint
  signals and minimises the surrogate of that model (exact in the singular values, one SVD an
  evaluation, no regressor call) in a trust region. Many screened starts get a few steps, the
  best few the rest (successive halving), each continuing where its first round ended.

The multi-start search (:func:`_multistart_search`) runs one of them from every start, on the
workers of a campaign scheduler (local processes or Dask, :mod:`spaceid._campaign`) that each
receive the problem once, and keeps the best result.
"""

from __future__ import annotations

import contextlib
import pickle
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from functools import partial

import numpy as np
from threadpoolctl import threadpool_limits

from .._campaign import open_workers, resolve_scheduler
from .._errors import SpaceidError
from ._criteria import CRITERIA
from ._design_problem import _check_clock, _ExcitationProblem, _OutOfTime

_METHODS = ("auto", "slsqp", "trust-region")
TRUST_REGION_STEPS = 40  # the trust region's default ``max_steps``
_SLSQP_MAX_COLUMNS = 64  # "auto": SLSQP up to this many regressor columns, trust region above
_N_POLISH = 2  # SLSQP: distinct best results refined on the fine grid
# SLSQP polish of a subsampled problem: iterations a round on the subsample, then on all samples
_POLISH_SUB_ITERATIONS, _POLISH_FULL_ITERATIONS = 50, 25

# Trust region. Surrogate sharpness by stage: p = 2 lifts the whole lower spectrum and makes
# most of the gain; 8 and 32 close in on the criterion (within 2 log(k) / p).
_STAGES = (2.0, 8.0, 32.0)
# L-BFGS-B iterations on the model a step, their SVDs about one linearisation. Servicer, one
# search: 30 took 2.5 times as long as 10 to reach cond 5e7; 20 led 10 from 2 minutes on (1e6
# against 1.8e6 at 200 s), 10 led before
_MODEL_ITERATIONS = 15
_STAGE_TOL = 1e-3  # two steps in a row gaining less (in log) end a stage
# First trust region: half-width _FIRST_RADIUS / K in z, so that a joint's signals move by at
# most _FIRST_RADIUS limits (a fixed 0.25 lost the first step of every servicer search, K = 24)
_FIRST_RADIUS = 1.5
# A step's wall time over (2 n_joints + 2) trajectory evaluations (the linearisation, the one
# after the step, the model's SVDs): 1.5 on the servicer (19 s against 0.43 s, 14 joints)
_STEP_EVALUATIONS = 1.5
# Trajectory evaluations after a search's deadline: the step under way tried, the result on
# the limits two ways, the criterion at its start (servicer, 30 s budget: 33.3 s without)
_FINISH_EVALUATIONS = 4


def _choose_method(method, criterion, n_columns):
    """The local search for ``method`` (a key of _METHODS) and a regressor of ``n_columns``."""
    if method == "auto":
        method = "slsqp" if n_columns <= _SLSQP_MAX_COLUMNS else "trust-region"
    if method == "trust-region" and CRITERIA[criterion].adjoint is None:
        raise SpaceidError(f"`criterion` {criterion!r} has no adjoint: use `method` 'slsqp'")
    return method


# -- SLSQP (small regressors) ---------------------------------------------------------------------


def _limit_inequalities(problem, mask, z=None):
    """Limits of both signs where ``mask (3, n_grid, n_joints)`` is set, as ``A z <= b``.

    Given ``z``, a limit is left out where the signal at ``z`` is beyond half the opposite
    limit: it lies 1.5 limits away, further than a local refinement moves.
    """
    d, t, j = np.nonzero(mask)
    K = problem.S.shape[1]
    A = np.zeros((len(d), problem.n))
    np.put_along_axis(A, j[:, None] * K + np.arange(K), problem.B[d, t] * problem.S[j], axis=1)
    A /= problem.L[d, j][:, None]
    p = problem.P[d, t, j] / problem.L[d, j]
    A, b = np.vstack([A, -A]), np.concatenate([1 - p, 1 + p])
    if z is None:
        return A, b
    v = problem.signals_over_limits(z)[d, t, j]
    keep = np.concatenate([v > -0.5, v < 0.5])
    return A[keep], b[keep]


def _coarse_grid_mask(problem):
    """The fine-grid points (3, n_grid, n_joints) of the coarse grid, every signal and joint."""
    mask = np.zeros(problem.P.shape, dtype=bool)
    mask[:, problem.coarse] = True
    return mask


def _near_peaks(problem, z, *, threshold, width=3):
    """Fine-grid points (3, n_grid, n_joints) within ``width`` of a local maximum of
    |signal| / limit above ``threshold``."""
    v = np.abs(problem.signals_over_limits(z))
    edge = np.full_like(v[:, :1], -np.inf)
    ahead, behind = np.concatenate([v[:, 1:], edge], 1), np.concatenate([edge, v[:, :-1]], 1)
    mask = (v >= ahead) & (v >= behind) & (v >= threshold)
    for shift in range(1, width + 1):
        mask[:, shift:] |= mask[:, :-shift]
        mask[:, :-shift] |= mask[:, shift:]
    return mask


@dataclass
class _Budget:
    """What a local search may spend: the wall clock up to ``deadline`` (time.time(), None: no
    limit) and ``steps`` linearisations of the criterion (None: no limit), ``used`` so far. The
    steps end a search at the same iterate on any machine; the deadline, wherever it falls."""

    deadline: float | None = None
    steps: int | None = None
    used: int = 0

    def check(self):
        """Raise :class:`_OutOfTime` once the deadline has passed or the steps are spent."""
        _check_clock(self.deadline)
        if self.steps is not None and self.used >= self.steps:
            raise _OutOfTime

    def spend(self):
        """Count one linearisation (after :meth:`check`)."""
        self.check()
        self.used += 1


def _slsqp_epigraph(problem, z0, mask, *, ftol, budget, near=False, maxiter=200, central=True):
    """SLSQP in epigraph form from ``z0`` under the limits at the fine-grid points ``mask``
    (only those on the side of the signal at ``z0`` where it is large, if ``near``), gradients
    by central differences of the signals or, unless ``central``, forward ones. Each new iterate's
    linearisation is spent from ``budget`` (:class:`_Budget`); once it is spent, or past its
    deadline, it stops with its last iterate."""
    from scipy.optimize import minimize
    A, b = _limit_inequalities(problem, mask, z0 if near else None)
    A = np.hstack([A, np.zeros((len(A), 1))])  # variables w = (z, tau)
    n, cache = problem.n, {}

    def lin(w):  # SLSQP asks for values and gradients separately: evaluate once
        key = w[:n].tobytes()
        if key not in cache:
            cache.clear()
            budget.spend()
            cache[key] = problem.linearize_criterion(w[:n], central=central, deadline=budget.deadline)
        return cache[key]

    def epigraph_jac(w):  # of tau - piece(z) >= 0
        jac = lin(w)[1]
        return np.hstack([-jac, np.ones((len(jac), 1))])

    constraints = [
        {"type": "ineq", "fun": lambda w: w[n] - lin(w)[0], "jac": epigraph_jac},
        {"type": "ineq", "fun": lambda w: b - A @ w, "jac": lambda w: -A},
    ]
    e_tau = np.eye(n + 1)[n]
    last = [z0]  # the last iterate, returned if the budget interrupts an evaluation
    with np.errstate(divide="ignore", invalid="ignore"):
        try:
            x = minimize(
                lambda w: (w[n], e_tau),
                np.append(z0, lin(np.append(z0, 0.0))[0].max()),
                jac=True,
                method="SLSQP",
                constraints=constraints,
                callback=lambda w: last.__setitem__(0, w[:n].copy()),
                options={"maxiter": maxiter, "ftol": ftol},
            ).x[:n]
        except _OutOfTime:
            x = last[0]
    return x if np.all(np.isfinite(x)) else z0


def _slsqp_search(problem, z0, deadline=None, steps=None, *, ftol=1e-3):
    """One SLSQP search from ``z0`` (n,): coarse grid, then the fine-grid peaks too, then
    scaled into the limits; on the subsampled problem if it has one, with forward differences
    (the polish refines the best). Returns ``(z, objective)`` with the objective on all
    samples; past ``deadline`` (time.time()) or after ``steps`` linearisations in all it stops
    with its last iterate (or the start, if better)."""
    search, budget = problem.subsampled or problem, _Budget(deadline, steps)
    z = _slsqp_epigraph(search, z0, _coarse_grid_mask(search), ftol=ftol, central=False, budget=budget)
    with contextlib.suppress(_OutOfTime):
        budget.check()
        mask = _coarse_grid_mask(search) | _near_peaks(search, z, threshold=0.8)
        z = _slsqp_epigraph(search, z, mask, ftol=ftol, near=True, central=False, budget=budget)
    # the start itself where the search, cut short by its budget, left a worse point
    Z = problem.shrink_into_limits(np.stack([z, z0]))
    f = problem.objective(Z)
    return Z[np.argmin(f)], float(f.min())


def _slsqp_polish(problem, z, deadline=None, steps=None, *, rounds=4):
    """Refine ``z`` (n,) under every fine-grid limit that can become active near it; returns
    ``(z, objective)``; past ``deadline`` (time.time()) or after ``steps`` linearisations in all
    it stops with its last iterate.

    With a subsampled problem, the rounds run on it (at most ``_POLISH_SUB_ITERATIONS`` each),
    then one round of at most ``_POLISH_FULL_ITERATIONS`` on all the samples, whose optimum
    lies close by: on a 4-joint tree at 200 samples (60 in the subsample), four full rounds
    took 6 minutes (loaded machine) and reached a cond within a few % of these."""
    budget = _Budget(deadline, steps)
    with contextlib.suppress(_OutOfTime):
        if problem.subsampled is None:
            z = _polish_rounds(problem, z, budget, rounds)
        else:
            z = _polish_rounds(problem.subsampled, z, budget, rounds, maxiter=_POLISH_SUB_ITERATIONS)
            z = _polish_rounds(problem, z, budget, 1, maxiter=_POLISH_FULL_ITERATIONS)
    z = problem.shrink_into_limits(z)
    return z, float(problem.objective(z[None])[0])


def _polish_rounds(problem, z, budget, rounds, maxiter=200):
    """The rounds of :func:`_slsqp_polish` on ``problem``; the last ``z``. Each adds the
    fine-grid points near the peaks at ``z`` to the limits imposed (the coarse grid keeps the
    refinement from running off to new peaks) until the limits hold."""
    mask = _coarse_grid_mask(problem)
    for _ in range(rounds):
        budget.check()
        mask |= _near_peaks(problem, z, threshold=0.8)
        z = _slsqp_epigraph(problem, z, mask, ftol=1e-8, near=True, maxiter=maxiter, budget=budget)
        if np.abs(problem.signals_over_limits(z)).max() <= 1 + 1e-9:
            break
    return z


# -- trust region (spatial systems) ---------------------------------------------------------------
#
# Limits are per joint, so the feasible set is a product of one convex set per joint. The radial
# map z_j = y_j / rho_j(y_j) (rho_j: how far y_j's signals exceed the room the quintic leaves,
# _ExcitationProblem.map_onto_limits) puts every joint on the boundary of its set, where exciting
# trajectories sit: the search is unconstrained in y, and every iterate is feasible on the fine
# grid.


def _linearized_surrogate(problem, y, z0, Y0, dY, p):
    """Surrogate of sharpness p at ``z(y)`` for the regressor linearised in the joint
    signals about ``z0``, ``Y0 + sum_dj dY[.., dj] dsignal_dj``, and its gradient in y.

    An evaluation costs one SVD and no regressor call; the model keeps the criterion's
    own nonlinearity (the singular values) exact and linearises only Y(q, qd).
    """
    z, pull = problem.map_onto_limits(y)
    dX = problem.coefficients(z - z0)
    dsig = np.einsum("dtk,jk->tdj", problem.B_samples, dX).reshape(len(dY), 1, -1)
    Ym = Y0 + (dsig @ dY).reshape(Y0.shape)
    with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
        f, W = CRITERIA[problem.criterion].smoothed(Ym, p)
    if not np.isfinite(f):
        return 1e300, np.zeros_like(y)
    return f, pull(problem.coefficient_gradient(W, dY))


def _trust_region_step(problem, z, Y0, dY, f0, p, delta, deadline=None):
    """One step from ``z`` on the model linearised there (``Y0``, ``dY``; surrogate of
    sharpness ``p`` ``f0`` at ``z``): ``(z, Y, f, delta)`` with the new point, its stacked
    regressor and surrogate, and the next half-width; the point is None where the stage ends.

    Minimises the model (:func:`_linearized_surrogate`) by L-BFGS-B in a box of half-width
    ``delta`` about ``z``; the step is taken if the true surrogate (one more regressor call,
    reused by the next linearisation) decreases by at least a tenth of what the model
    predicted, else retried in a box that follows the agreement. The stage ends where the model
    has nothing to offer or the box is tiny. Past ``deadline`` (time.time()) L-BFGS-B stops
    at its current iterate, which is then tried.
    """
    from scipy.optimize import Bounds, minimize

    def halt(_):
        if deadline is not None and time.time() > deadline:
            raise StopIteration  # scipy ends the minimisation at the current iterate

    while True:
        res = minimize(lambda y: _linearized_surrogate(problem, y, z, Y0, dY, p), z, jac=True,
                       method="L-BFGS-B", bounds=Bounds(z - delta, z + delta), callback=halt,
                       options={"maxiter": _MODEL_ITERATIONS, "maxcor": 20})  # fmt: skip
        step = np.abs(res.x - z).max()
        predicted = f0 - res.fun
        if not predicted > 0:  # the model has nothing to offer: next stage
            return None, None, None, max(delta, 1e-3)
        z_new = problem.map_onto_limits(res.x)[0]
        Y_new = problem.stacked_regressor(z_new[None])[0]
        f_new = float(problem.smooth_objective_of_regressor(Y_new, p))
        ratio = (f0 - f_new) / predicted
        if ratio < 0.25:
            delta = step / 4
        elif ratio > 0.75 and step > 0.9 * delta:
            delta = min(2 * delta, 1.0)
        if ratio > 0.1:
            return z_new, Y_new, f_new, delta
        if delta < 1e-4:
            return None, None, None, 1e-3
        _check_clock(deadline)


def _trust_region_search(problem, z0, steps, deadline=None, resume=None):
    """One trust-region search from ``z0`` (n,): ``(z, objective, state)``, z on the
    limits; ``state`` continues the search when passed back as ``resume``.

    Each outer step linearises Y in the joint signals
    (:meth:`~_ExcitationProblem.linearize_regressor`) and takes a step on that model
    (:func:`_trust_region_step`). Sharpness p rises through ``_STAGES``, each stage ending when
    two steps in a row gain less than ``_STAGE_TOL``, or the model offers nothing. The search
    stops after ``steps`` linearisations or early, with its best point so far, at
    ``deadline`` (time.time(), checked within the steps too). ``state`` is the stage and
    the half-width it ended with.
    """
    z = problem.map_onto_limits(z0)[0]
    stage0, delta = (0, _FIRST_RADIUS / problem.S.shape[1]) if resume is None else resume
    state = [z, stage0, delta]  # the last accepted point, where a deadline leaves the search
    try:
        state[1:] = _trust_region_stages(problem, state, steps, deadline)
    except _OutOfTime:
        pass
    z, stage, delta = state
    return (*_best_on_limits(problem, z), (stage, delta))


def _trust_region_stages(problem, state, steps, deadline):
    """The stages of :func:`_trust_region_search` from ``state = [z, stage, delta]``, which
    holds the last accepted point as they go; returns the final ``(stage, delta)``."""
    z, stage0, delta = state
    outer, Y0, Y_z = 0, None, None
    for stage in range(stage0, len(_STAGES)):
        p, stalls, f0 = _STAGES[stage], 0, None
        while stalls < 2:
            if outer == steps or (deadline is not None and time.time() > deadline):
                return stage, delta
            if Y0 is None:  # a new point: linearise (a new stage keeps the last one)
                Y0, dY = problem.linearize_regressor(z, Y_z, central=False, deadline=deadline)
                outer += 1
            if f0 is None:
                f0 = float(problem.smooth_objective_of_regressor(Y0, p))
            z_new, Y_new, f_new, delta = _trust_region_step(problem, z, Y0, dY, f0, p, delta, deadline)
            if z_new is None:
                break
            stalls = stalls + 1 if f0 - f_new < _STAGE_TOL else 0
            z, Y_z, f0, Y0 = z_new, Y_new, f_new, None
            state[:] = z, stage, delta
    return len(_STAGES), delta


def _best_on_limits(problem, z):
    """The better of ``z`` (inside the fine-grid limits by the smooth room used; scaled into
    them between grid points too) and ``z`` scaled onto them exactly, by the criterion
    itself: ``(z, objective)``."""
    Z = np.stack([problem.scale_onto_limits(z, inside=True), problem.scale_onto_limits(z)])
    f = problem.objective(Z)
    return Z[np.argmin(f)], float(f.min())


def _screened_starts(problem, run, workers, seed, n_starts, n_screen, z_initial, t_end=None):
    """The trust-region starts: the ``n_starts`` best by the first-stage surrogate of
    ``max(n_screen, n_starts)`` random starts on the limits (start i from ``(seed, i)``, so a
    larger ``n_starts`` adds the next best), after ``z_initial`` if given; and the wall time of
    one trajectory's evaluation [s] on a worker. Given ``t_end`` (time.time()), screening
    stops after a tenth of the time left (the starts screened by then are ranked)."""
    m = max(n_screen, n_starts)
    Z = np.concatenate([problem.random_on_limits(np.random.default_rng([seed, i]), 1)
                        for i in range(m)])
    chunk = -(-m // workers // 2) if workers > 1 else m  # two chunks a worker
    if t_end is not None:
        chunk = min(chunk, 4)  # small calls, so that screening can stop on time
    t0 = time.time()
    t_stop = None if t_end is None else t0 + (t_end - t0) / 10
    calls = ((c, _ExcitationProblem.smooth_objective, (Z[c : c + chunk], _STAGES[0]))
             for c in range(0, m, chunk))  # fmt: skip
    f, screened = np.full(m, np.nan), 0
    for c, values in run(calls, stop=lambda: t_stop is not None and screened and time.time() > t_stop):
        f[c : c + len(values)] = values
        screened += len(values)
    t_eval = (time.time() - t0) * min(workers, -(-screened // chunk)) / screened
    order = [i for i in np.argsort(np.where(np.isfinite(f), f, np.inf), kind="stable") if not np.isnan(f[i])]
    starts = [] if z_initial is None else [z_initial]
    return starts + [Z[i] for i in order[: n_starts - len(starts)]], t_eval


# -- the multi-start search -----------------------------------------------------------------------

def _run_calls(problem, workers, calls, *, stop):
    """Run ``function(problem, *args)`` for ``calls``, an iterable of ``(key, function, args)``.

    Yields ``(key, result)`` in completion order, from the campaign ``workers`` (at most
    ``workers.n`` calls at once; see :func:`spaceid._campaign.open_workers`) or from this process
    when ``workers`` is None. No call starts once ``stop()`` is true; started calls finish.
    """
    calls = iter(calls)
    if workers is None:
        for key, function, args in calls:
            if stop():
                return
            yield key, function(problem, *args)
        return
    pending = {}
    while True:
        while len(pending) < workers.n and not stop():
            call = next(calls, None)
            if call is None:
                break
            key, function, args = call
            pending[workers.submit(function, *args)] = key
        if not pending:
            return
        for future in workers.wait_first(set(pending)):
            yield pending.pop(future), future.result()


def _picklable(obj):
    try:
        pickle.dumps(obj)
    except (pickle.PicklingError, TypeError, AttributeError):
        return False
    return True


def _distinct_best(found, m):
    """The first ``m`` of the sorted results ``(f, i, z)`` whose z differ."""
    out = []
    for cand in found:
        if all(np.linalg.norm(cand[2] - c[2]) > 1e-3 for c in out):
            out.append(cand)
        if len(out) == m:
            break
    return out


@dataclass
class _Tally:
    """The local searches of a multi-start search so far, the best result, and why it stopped.

    Results are taken in start-index order (one that completes early waits for those before
    it), so the best, the history and the convergence test do not depend on timing.
    Convergence: the best objective has gained less than ``tol`` over the last ``patience``
    starts taken (the objective is log cond for ``cond``, so ``tol`` is a relative gain).
    """

    report: Callable  # the criterion's report: objective -> value
    t_start: float  # time.perf_counter() at the start of the design
    progress: Callable | None  # progress(done, total), or None
    name: str = "objective"  # the criterion's name, for status lines
    status: Callable | None = None  # status(line): a one-line summary as searches complete
    patience: int | None = None  # starts without gain that end the search (None: never)
    tol: float = 1e-3  # least gain in the objective that counts
    found: list = field(default_factory=list)  # (objective, start index, z), in index order
    history: list = field(default_factory=list)  # (wall time [s], best value) at improvements
    best: tuple = (np.inf, np.inf, None)  # (objective, start index, z): ties go to the lower index
    starts: dict = field(default_factory=dict)  # start index -> start z (n,)
    waiting: dict = field(default_factory=dict)  # start index -> (z, f) done out of index order
    stop: str | None = None  # why the search stopped: "converged", "budget" or "starts"
    done: int = 0  # searches completed

    def consider(self, f, i, z):
        """Keep ``z`` of objective ``f`` from start ``i`` if it is the best so far."""
        if f < self.best[0] - 1e-9:  # smaller gains in the objective are not worth a record
            self.history.append((time.perf_counter() - self.t_start, float(self.report(f))))
        if (f, i) < self.best[:2]:
            self.best = (f, i, z)

    def converged(self):
        """The last ``patience`` starts taken gained less than ``tol`` on the best before them."""
        k = self.patience
        if k is None or len(self.found) <= k:
            return False
        before = min(c[0] for c in self.found[:-k])
        return bool(np.isfinite(before) and before - self.best[0] < self.tol)

    def add(self, results, total, starts=None):
        """Record the searches ``results``, pairs ``(i, (z, f))`` with i from 0 up, of ``total``
        planned (``starts`` of them from new starts, default all), until the search converges
        (later ones are left out)."""
        for i, (z, f) in results:
            self.waiting[i] = (z, f)
            while self.stop != "converged" and len(self.found) in self.waiting:  # the budget takes all done
                j = len(self.found)
                z_j, f_j = self.waiting.pop(j)
                self.found.append((f_j, j, z_j))
                self.consider(f_j, j, z_j)
                if self.converged():
                    self.stop = "converged"
            self.tick(total, f"start {self.done + 1}/{starts or total}")

    def tick(self, total, what):
        """One more search completed of ``total``: progress, and a status line saying ``what``."""
        self.done += 1
        if self.progress is not None:
            self.progress(self.done, total)
        self.announce(what)

    def announce(self, what):
        """A status line: ``what``, then the best value so far, the one the result reports (to
        its 6 digits), and the wall time."""
        if self.status is not None:
            wall = time.perf_counter() - self.t_start
            self.status(f"{what}, best {self.name} {self.report(self.best[0]):.6g}, {wall:.0f} s")


def _multistart_search(problem, method, *, seed, n_starts, n_jobs, progress, time_budget, z_initial,
                       max_steps, n_screen, t_start, scheduler=None, patience=None, status=None):
    """Local searches by ``method`` ("slsqp" or "trust-region") from seeded random starts, on
    ``scheduler`` (:func:`spaceid._campaign.open_workers`; ``processes``: ``n_jobs`` worker
    processes, this process if 1 or the regressor does not pickle); options as for
    :func:`~spaceid.motion.optimize_excitation`, ``t_start`` its time.perf_counter() at start.
    Returns the :class:`_Tally`, its ``stop`` set."""
    tally = _Tally(CRITERIA[problem.criterion].report, t_start, progress, name=problem.criterion,
                   status=status, patience=patience)  # fmt: skip
    scheduler = resolve_scheduler(scheduler)
    # the hard end of the budget on the wall clock, which worker processes (and the synchronised
    # machines of a Dask cluster) share; a monotonic clock is per machine
    t_end = None if time_budget is None else time.time() + time_budget - (time.perf_counter() - t_start)
    with contextlib.ExitStack() as stack:
        # One BLAS thread per process: SLSQP's small LAPACK calls gain nothing from more, and
        # OpenBLAS threads spinning on busy cores make it up to 30 times slower.
        stack.enter_context(threadpool_limits(1))
        pool = None
        if (n_jobs > 1 or scheduler != "processes") and _picklable(problem.regressor):
            pool = stack.enter_context(open_workers(scheduler, n_jobs, problem))
        run, workers = partial(_run_calls, problem, pool), (pool.n if pool else 1)
        if method == "slsqp":
            _slsqp_multistart(problem, tally, run, workers, seed=seed, n_starts=n_starts,
                              z_initial=z_initial, t_end=t_end, steps=max_steps)  # fmt: skip
        else:
            max_steps = TRUST_REGION_STEPS if max_steps is None else max_steps
            starts, t_eval = _screened_starts(problem, run, workers, seed, n_starts, n_screen, z_initial, t_end)
            if t_end is not None:
                t_end -= _FINISH_EVALUATIONS * t_eval  # the searches end early enough to finish
                starts = _starts_within_budget(starts, workers, t_end, t_eval, problem.S.shape[0], max_steps)
            _trust_region_multistart(tally, run, workers, starts, max_steps=max_steps, t_end=t_end)
    if tally.stop is None:
        tally.stop = "budget" if t_end is not None and time.time() >= t_end else "starts"
    return tally


def _slsqp_multistart(problem, tally, run, workers, *, seed, n_starts, z_initial, t_end, steps=None):
    """SLSQP searches from ``n_starts`` random feasible starts (the first ``z_initial`` if
    given), then the best ``_N_POLISH`` distinct results polished, each search and each polish
    at most ``steps`` linearisations (None: to their tolerance); none starts after ``t_end``
    (time.time()), and those running stop there."""
    t_search = time.time()

    def searches():
        """One task per start; start i is drawn from (seed, i) alone, so it is the same
        whatever n_starts and the order in which tasks run."""
        for i in range(n_starts):
            z0 = problem.random_inside_limits(np.random.default_rng([seed, i]), 1)[0]
            tally.starts[i] = z_initial if i == 0 and z_initial is not None else z0
            yield i, _slsqp_search, (tally.starts[i], t_end, steps)

    def stop():
        # Keep time to finish the running searches and to polish (a polish costs about
        # one to five searches, whose mean wall time the searches so far tell)
        if tally.stop is not None or t_end is None or not tally.done:
            return tally.stop is not None
        now = time.time()
        per_search = (now - t_search) * workers / tally.done
        if now + per_search * (1 + 3 * -(-_N_POLISH // workers)) > t_end:
            tally.stop = "budget"
        return tally.stop is not None

    tally.add(run(searches(), stop=stop), n_starts)
    found = sorted(tally.found, key=lambda c: c[:2])  # by value, then start index: independent of timing
    if t_end is not None and time.time() > t_end:  # no time left to polish
        return
    chosen = _distinct_best(found, _N_POLISH)
    polish = ((i, _slsqp_polish, (z, t_end, steps)) for _, i, z in chosen)
    for i, (z, f) in sorted(run(polish, stop=lambda: False), key=lambda r: r[0]):
        tally.consider(f, i, z)
    tally.announce(f"polished the best {len(chosen)}")  # the polish changes the best the result reports


def _successive_halving(n_starts, max_steps):
    """Steps of the first round a start, starts continued, and total steps of
    :func:`_trust_region_multistart` from ``n_starts`` starts."""
    first = max(1, round(max_steps / 5))
    keep = min(n_starts, max(2, n_starts // 4)) if max_steps > first else 0
    return first, keep, n_starts * first + keep * (max_steps - first)


def _starts_within_budget(starts, workers, t_end, t_eval, n_joints, max_steps):
    """The first of ``starts`` that the ``workers`` can search by ``t_end`` (time.time()),
    at least one a worker. A step costs about ``_STEP_EVALUATIONS (2 n_joints + 2)``
    trajectory evaluations of ``t_eval`` [s] (a linearisation, its model solved, one more
    evaluation), so the budget affords ``workers (t_end - now) / t_step`` steps; a start that
    runs out of time loses its step under way, and many short searches lose more than few
    long ones (servicer: 30 one-step searches reach a cond 10 times worse than one of 15)."""
    t_step = _STEP_EVALUATIONS * (2 * n_joints + 2) * t_eval
    affordable = workers * (t_end - time.time()) / t_step
    n = min(len(starts), workers)
    while n < len(starts) and _successive_halving(n + 1, max_steps)[2] <= affordable:
        n += 1
    return starts[:n]


def _trust_region_multistart(tally, run, workers, starts, *, max_steps, t_end):
    """Trust-region searches from ``starts`` by successive halving: every start gets a fifth of
    the ``max_steps`` steps (a search gains most in its first steps, and where it gets to then
    ranks it fairly well), the best quarter (at least two) the rest; on the 7-joint arm this
    beats four full searches at a lower cost. None starts after ``t_end`` (time.time()),
    and those running stop there."""
    first, keep, _ = _successive_halving(len(starts), max_steps)
    if t_end is not None and len(starts) <= workers:  # one search a worker: no halving
        first, keep = max_steps, 0
    total = len(starts) + keep
    state = {}  # each search's state, so that the second round continues it

    def searches(items, steps, later):
        """``_trust_region_search`` tasks of ``steps`` steps from ``(index, z)`` items. With a
        budget, each gets a share of the time left in proportion to its steps, among the work
        not yet started (``later`` steps after these): its deadline is set as it starts."""
        for n, (i, z0) in enumerate(items):
            deadline = None
            if t_end is not None:
                now, left = time.time(), steps * (len(items) - n) + later
                deadline = now + (t_end - now) * steps / max(left / workers, steps)
            yield i, _trust_region_search, (z0, steps, deadline, state.get(i))

    def stop():  # at least one search runs, however short the budget
        if tally.stop is None and t_end is not None and tally.done and time.time() > t_end:
            tally.stop = "budget"
        return tally.stop is not None

    def kept(results):
        for i, (z, f, state[i]) in results:
            yield i, (z, f)

    tally.starts.update(enumerate(starts))
    round_one = searches(list(enumerate(starts)), first, keep * (max_steps - first))
    tally.add(kept(run(round_one, stop=stop)), total, len(starts))
    converged, tally.stop = tally.stop, None if tally.stop == "converged" else tally.stop
    found = sorted(tally.found, key=lambda c: c[:2])
    chosen = [(i, z) for _, i, z in _distinct_best(found, keep)] if keep else []
    for n, (i, (z, f, _)) in enumerate(run(searches(chosen, max_steps - first, 0), stop=stop), 1):
        tally.consider(f, i, z)
        tally.tick(total, f"continued {n}/{len(chosen)} of the best")
    tally.stop = tally.stop or converged
