"""Optimal excitation: choose the Fourier coefficients of Eq. 12 for a well-conditioned regressor.

The design, one module a step:

1. problem (``_design_problem``): the free Fourier coefficients of
   :class:`~spaceid.motion.FourierTrajectory` in scaled variables, the joint limits they must
   keep at all times, the boundary values, and the stacked regressor and its derivatives as
   functions of them;
2. criterion (``_criteria``): what to minimise, a function of the stacked regressor
   (:data:`CRITERIA`: ``cond``, ``logdet``, and on the noise-whitened regressor
   :class:`whitened_regressor`, ``dopt`` and ``crb``);
3. search (``_design_search``): local searches (SLSQP for small regressors, a trust region for
   spatial ones) from seeded random starts, in worker processes, within a time budget;
4. result: the best trajectory found, in a :class:`DesignResult`.

:func:`optimize_excitation` runs it for any regressor and limits; :func:`design_excitation` for
a model: limits from the model, the regressor (plain or whitened) from its nominal parameters.

References
----------
The Cepheus paper (NTUA Control Systems Lab; see docs/citing.md):
Eq. 12 (docs/theory/excitation.md).
"""

from __future__ import annotations

import os
import time
from dataclasses import dataclass, field, replace

import numpy as np
from threadpoolctl import threadpool_limits

from .._deprecation import deprecated_alias
from .._errors import SpaceidError
from ..dynamics import excitation_regressor
from ..estimation import LARGE_SHARE, Noise, momentum_scale
from ..models import INERTIAL_NAMES
from ._criteria import CRITERIA, _criterion_named, whitened_regressor
from ._design_problem import (
    _boundary_array,
    _check_rank,
    _checked_regressor_columns,
    _limit_array,
    _set_up_problem,
    _warm_start_coefficients,
    _with_search_subsample,
)
from ._design_search import _METHODS, _choose_method, _multistart_search
from ._trajectory import BOUNDARY_FIELDS, FourierTrajectory, sample_times

__all__ = ["DesignResult", "bound_summary", "optimize_excitation", "design_excitation"]


@dataclass(frozen=True)
class DesignResult:
    """Outcome of :func:`optimize_excitation`.

    Attributes
    ----------
    trajectory : FourierTrajectory
        The best trajectory found; its ``meta`` records criterion, value, seed, number of
        starts, samples, wall time and limits.
    criterion : str
        A key of :data:`CRITERIA`.
    value : float
        Criterion value of ``trajectory``: the condition number for ``cond``, log det of
        ``Yn^T Yn`` for ``logdet``, log det of the relative Fisher information for ``dopt``,
        the trace of the relative Cramer-Rao bound (sum of the parameters' relative
        variances) for ``crb``.
    seed : int
        Seed of the start points.
    n_starts : int
        Local searches completed (fewer than asked for when the time budget ran out).
    wall_time : float
        Wall time of the design [s].
    history : tuple of (float, float)
        ``(wall time [s], best value so far)`` at each improvement.
    noise : Noise or None
        The noise model of :func:`design_excitation`, if given.
    """

    trajectory: FourierTrajectory
    criterion: str
    value: float
    seed: int
    n_starts: int
    wall_time: float
    history: tuple = field(default=(), repr=False)
    noise: Noise | None = None

    def to_dict(self) -> dict:
        """JSON-ready dictionary."""
        return {
            "trajectory": self.trajectory.to_dict(),
            "criterion": self.criterion,
            "value": self.value,
            "seed": self.seed,
            "n_starts": self.n_starts,
            "wall_time": self.wall_time,
            "history": [list(h) for h in self.history],
            "noise": None if self.noise is None else self.noise.to_dict(),
        }



# One BLAS thread for the whole design, set-up and final evaluations too (the search's workers
# limit theirs): threads spinning on busy cores made the servicer's rank check on 8 starts take
# 65 s, and a 30 s budget 120 s
@deprecated_alias(old="n_jobs", new="jobs")
@threadpool_limits.wrap(limits=1)
def optimize_excitation(
    regressor,
    joints,
    *,
    duration,
    harmonics,
    samples,
    q_max,
    qd_max,
    qdd_max,
    criterion="cond",
    seed=0,
    n_starts=None,
    jobs=None,
    progress=None,
    boundary=None,
    time_budget=None,
    initial=None,
    n_grid=1001,
    method="auto",
    max_steps=None,
    n_screen=64,
    scheduler=None,
    patience=None,
    status=None,
):
    """Design an exciting trajectory (paper Eq. 12) by a seeded multi-start search.

    Parameters
    ----------
    regressor : callable
        ``regressor(q, qd)`` with q [rad], qd [rad/s] of shape (..., samples, n_joints),
        batched over leading dimensions, returning the stacked regressor (..., samples * m, k)
        (m = 1 planar, 3 spatial). Worker processes need it picklable; otherwise the search
        runs in this process.
    joints : sequence of str
        Joint names, the column order of q.
    duration : float
        Trajectory duration tf [s].
    harmonics : int
        Number of harmonics Nf.
    samples : int
        Number of equally spaced samples over ``[0, duration]`` (both ends included) at which
        the regressor is stacked.
    q_max, qd_max, qdd_max : float or array_like of shape (n_joints,)
        Limits on ``|q|`` [rad], ``|qd|`` [rad/s], ``|qdd|`` [rad/s^2], held at all times (imposed on
        ``n_grid`` times during the search, the result scaled into them between those).
    criterion : {"cond", "logdet", "dopt", "crb"}
        ``cond``: minimise the 2-norm condition number of the stacked regressor; ``logdet``:
        maximise log det of ``Yn^T Yn``, ``Yn`` with unit-norm columns. For a whitened,
        pi-scaled regressor (:class:`whitened_regressor`; :func:`design_excitation` builds it):
        ``dopt`` maximises log det of ``Y^T Y``, the Fisher information (D-optimality);
        ``crb`` minimises the trace of ``(Y^T Y)^-1``, the Cramer-Rao bound (A-optimality).
    seed : int
        Seed (an integer >= 0) of the random start points. The same seed gives the same
        result, whatever ``jobs``, unless ``time_budget`` cuts the search short; a larger
        ``n_starts`` adds starts to those of a smaller one.
    n_starts : int, optional
        Number of local searches (an upper bound when ``time_budget`` or ``patience`` ends the
        search earlier). Default: by the problem's size (``_default_starts``), 64 for
        Cepheus, fewer where a search costs more.
    jobs : int, optional
        Worker processes; default: one per core. 1 runs in this process.
    progress : callable, optional
        ``progress(done, total)``, called as local searches complete (``total = n_starts``;
        trust region: plus the searches continued in the second round).
    boundary : mapping, optional
        Boundary values ``q0, qd0, qdd0, qf, qdf, qddf`` (keys), arrays (n_joints,) [rad,
        rad/s, rad/s^2]; missing ones are zero. The quintic through them must keep the limits.
    time_budget : float, optional
        Wall time [s] of the design from its call, a hard limit: every local search (in
        every worker) checks the clock inside its iterations and stops at the end of the
        budget with its best point, which is then scaled into the limits. SLSQP: no search
        starts once those done tell that it and the polish would not finish in time. Trust
        region: screening takes at most a tenth of the budget; only as many starts are
        searched as the budget affords steps for (at least one a worker, then each runs to
        the end of the budget), each, as it starts, getting a share of the time left in
        proportion to its steps. At least one search runs. The result then depends on the
        machine's speed, and ``meta["stop"]`` is ``"budget"`` if the budget ended it.
    initial : FourierTrajectory, optional
        Warm start: used as the first start point, scaled down if it breaks a limit (trust
        region: each joint scaled onto its limits).
    n_grid : int
        Number of equally spaced times on which the search imposes the limits.
    method : {"auto", "slsqp", "trust-region"}
        Local search. ``slsqp``: the condition number itself in epigraph form under linear
        limits on a grid, from random starts; best for small regressors (planar arms), where
        the optimum has coalescing singular values. ``trust-region``: a smooth surrogate of
        the criterion of sharpness rising to 32, in variables that keep every joint on its
        limits, minimised on a model that linearises the regressor in the joint signals; for
        spatial systems (tens to hundreds of columns, a spectrum decaying over decades).
        ``auto``: ``slsqp`` up to 64 regressor columns, else ``trust-region``.
    max_steps : int, optional
        Most steps of a local search, each one linearisation of the regressor: the budget that
        ends the search at the same point on any machine (``time_budget`` is the machine's).
        SLSQP: each iteration's, in all over a search's passes, and as many again for each
        polish of the best; default none (every pass runs to its tolerance, at most 200
        iterations). Trust region (default 40): each step a linearisation (a regressor evaluation
        of 1 + 2 n_joints trajectories) and an L-BFGS-B solve of its model. Every start gets
        a fifth of them, the best quarter of the starts (at least two) the rest, so a design
        makes about ``(n_starts + 4 max(2, n_starts / 4)) max_steps / 5`` steps, shared by the
        workers; a step takes about 0.2 s on one core for a 7-joint arm (153 parameters,
        N = 120) and 3 s of CPU time for a 14-joint one (496 parameters, N = 400).
    n_screen : int
        Trust region: random starts on the limits (start i drawn from ``(seed, i)``) whose
        surrogate is evaluated; the ``n_starts`` best are searched from (so a larger
        ``n_starts`` adds the next best).
    scheduler : str, optional
        Where the local searches run: ``processes`` (``jobs`` local processes), ``dask``
        (a Dask LocalCluster of ``jobs`` workers) or a ``dask scheduler`` address
        ``tcp://HOST:PORT`` (its workers); default ``DASK_SCHEDULER_ADDRESS`` if set, else
        ``processes`` (docs/campaigns.md).
    patience : int, optional
        Convergence of the multi-start search: it stops when the last ``patience`` starts
        (taken in start order, whatever the order in which they complete) improved the best
        objective by less than 1e-3 (the objective is log cond for ``cond`` and log of the
        trace for ``crb``, so 0.1 % relative; log det for ``logdet`` and ``dopt``). Default:
        half the starts, at least 8 (on Cepheus, seed 1: 35.76 after 50 of the 64 starts, as
        from all 64; a patience of 8 stopped after 11 at 37.07). ``patience >= n_starts`` runs
        every start. Trust region: this applies to the first round.
    status : callable, optional
        ``status(line)``, called with a one-line summary as local searches complete, such as
        ``"start 12/64, best cond 41.2, 18 s"`` (``"continued 1/2 of the best"`` for the trust
        region's second round, ``"polished the best 2"`` after SLSQP's polish): the last line's
        value is the result's ``value``.

    Returns
    -------
    DesignResult
        The trajectory's ``meta`` also records ``method``, ``start_value`` (the criterion at
        the start of the search that found it), the budgets ``max_steps`` and ``time_budget``
        as given (None: not given), and ``stop``, what ended the search:
        ``"converged"`` (``patience``), ``"budget"`` (``time_budget``) or ``"starts"`` (all
        ``n_starts`` searched).

    Raises
    ------
    SpaceidError
        Invalid options, boundary values that break the limits, too few samples for the
        regressor's columns, or a regressor rank deficient on every start.

    References
    ----------
    The Cepheus paper (NTUA Control Systems Lab; see docs/citing.md):
    Eq. 12 (docs/theory/excitation.md).
    """
    t_start = time.perf_counter()
    joints = tuple(joints)
    _check_options(criterion, duration, time_budget, harmonics=harmonics, samples=samples,
                   n_grid=n_grid, seed=seed, n_screen=n_screen,
                   **({} if n_starts is None else {"n_starts": n_starts}),
                   **({} if max_steps is None else {"max_steps": max_steps}),
                   **({} if patience is None else {"patience": patience}))  # fmt: skip
    if method not in _METHODS:
        raise SpaceidError(f"`method` must be one of {', '.join(_METHODS)}, got {method!r}")
    limits = _limit_array(joints, q_max, qd_max, qdd_max)
    bc = _boundary_array(joints, boundary)
    problem = _set_up_problem(regressor, criterion, duration=float(duration),
                              harmonics=harmonics, samples=samples, limits=limits, boundary=bc,
                              n_grid=n_grid)  # fmt: skip
    k, rows = _checked_regressor_columns(problem, len(joints), samples)
    method = _choose_method(method, criterion, k)
    if method == "slsqp":
        problem = _with_search_subsample(problem, harmonics=harmonics, n_min_samples=-(-k // rows))
    if n_starts is None:
        n_starts = _default_starts((problem.subsampled or problem).B_samples.shape[1], len(joints), k)
    draw = problem.random_on_limits if method == "trust-region" else problem.random_inside_limits
    _check_rank(problem, draw(np.random.default_rng(seed), 8))
    z_initial = None
    if initial is not None:
        z0 = _warm_start_coefficients(problem, initial, joints, duration, harmonics, bc)
        z_initial = problem.shrink_into_limits(z0)
    jobs = min(os.cpu_count() or 1, n_starts) if jobs is None else int(jobs)
    patience = max(8, n_starts // 2) if patience is None else patience
    tally = _multistart_search(problem, method, seed=seed, n_starts=n_starts, n_jobs=jobs,
                               progress=progress, time_budget=time_budget, z_initial=z_initial,
                               max_steps=max_steps, n_screen=n_screen, t_start=t_start,
                               scheduler=scheduler, patience=patience, status=status)  # fmt: skip

    f, i_best, z = tally.best
    if not np.isfinite(f):
        raise SpaceidError(
            "no local search found a trajectory with a full-rank regressor; check that its "
            "columns are identifiable together and that the limits allow motion"
        )
    wall = time.perf_counter() - t_start
    report = CRITERIA[criterion].report
    value = float(report(f))
    X = problem.coefficients(z)
    meta = {
        "source": "optimize_excitation",
        "criterion": criterion,
        "value": value,
        "seed": seed,
        "n_starts": len(tally.found),
        "samples": samples,
        "wall_time": wall,
        "limits": dict(zip(("q_max", "qd_max", "qdd_max"), limits.tolist())),
        "method": method,
        "start_value": float(report(problem.objective(tally.starts[i_best][None])[0])),
        "stop": tally.stop,
        "max_steps": max_steps,
        "time_budget": time_budget,
    }
    trajectory = FourierTrajectory(
        joints, duration, X[:, :harmonics], X[:, harmonics:], **dict(zip(BOUNDARY_FIELDS, bc)),
        meta=meta,
    )  # fmt: skip
    return DesignResult(trajectory, criterion, value, seed, len(tally.found), wall,
                        tuple(tally.history))


# Default number of starts: this many samples x joints x columns of search a design, so that
# Cepheus (35 x 2 x 8) keeps 64 starts and a 4-joint planar tree at 200 samples (a 60-sample
# search, 25 columns) gets 6
_DEFAULT_START_WORK = 40_000


def _default_starts(samples, n_joints, n_columns):
    """The default number of local searches for a search on ``samples`` samples of a regressor
    of ``n_joints`` joints and ``n_columns`` columns: ``_DEFAULT_START_WORK / (samples
    n_joints n_columns)``, between 4 and 64.

    A search's cost is its iterations (growing with the coefficients, n_joints Nf) times a
    linearisation (1 + 2 n_joints trajectories of ``samples`` samples, a regressor whose cost
    a sample grows with the columns, and an SVD of their rows): a fixed amount of work split
    into starts keeps the default design to about a minute on two cores."""
    return int(np.clip(_DEFAULT_START_WORK // (samples * n_joints * n_columns), 4, 64))


def _check_options(criterion, duration, time_budget, **integers):
    """The options of :func:`optimize_excitation` other than limits, boundary and method."""
    _criterion_named(criterion)
    low = {"harmonics": 1, "samples": 2, "n_starts": 1, "n_grid": 100, "seed": 0, "max_steps": 1,
           "n_screen": 1, "patience": 1}
    for name, value in integers.items():
        if not isinstance(value, (int, np.integer)) or value < low[name]:
            raise SpaceidError(f"`{name}` must be an integer >= {low[name]}, got {value!r}")
    if not (np.isfinite(duration) and duration > 0):
        raise SpaceidError(f"`duration` must be a positive number of seconds, got {duration!r}")
    if time_budget is not None and not time_budget > 0:
        raise SpaceidError(f"`time_budget` must be a positive number of seconds, got {time_budget!r}")


@deprecated_alias(old="n_jobs", new="jobs")
def design_excitation(param, *, duration, harmonics, samples, momentum, seed=0, progress=None,
                      criterion="cond", noise=None, payload_link=None, payload=None, **options):
    """Optimal exciting trajectory for ``param``'s model, joint limits from the model, the base
    rate from momentum conservation at the model's nominal parameters.

    Parameters
    ----------
    param : Parameterization
    duration, harmonics, samples, seed, progress
        As for :func:`optimize_excitation`.
    momentum : array_like of shape (3,)
        Angular momentum [N m s].
    criterion : str
        A key of :data:`CRITERIA`. ``dopt`` and ``crb`` are searched on the whitened,
        pi-scaled regressor (:class:`whitened_regressor`) and need ``noise``.
    noise : Noise, optional
        Measurement noise. When given (not all zero), the trajectory's ``meta`` also records
        it and the predicted Cramer-Rao standard deviation of every parameter, absolute
        (``crb_std``), relative to its nominal value (``crb_relative_std``, None where
        that is zero) and as the momentum it causes, a fraction of the motion's momentum scale
        (``crb_scaled_std``; the scale itself in ``momentum_scale``:
        :func:`spaceid.estimation.momentum_scale`), whatever the criterion.
    payload_link : str, optional
        Design for the parameters of a payload held by this link (a body, or a URDF link on
        fixed joints below one) instead of the minimal parameters: the criterion is on their
        (scaled) regressor, :class:`~spaceid.motion.payload_regressor`, and the trajectory's
        ``meta`` records the link and, with ``noise``, the payload's predicted Cramer-Rao
        standard deviations (``payload_crb_std``).
    payload : array_like, optional
        With ``payload_link``: the nominal payload's standard parameters in the link's frame (ten;
        planar ``m, mcx, mcy, Izz`` about the link origin); default none (zero mass).
    **options
        ``q_max``, ``qd_max``, ``qdd_max`` override the model's limits (and must be given
        where it has none); the others go to :func:`optimize_excitation`.

    Returns
    -------
    DesignResult
        With ``noise`` set to ``noise``.

    Raises
    ------
    SpaceidError
        An unknown criterion, a noise-aware one without noise, a joint without a limit that
        ``options`` does not give, or as for :func:`optimize_excitation`.
    """
    crit = _criterion_named(criterion)
    if noise is not None and not isinstance(noise, Noise):
        raise SpaceidError(f"`noise` must be a spaceid.estimation.Noise, got {type(noise).__name__}")
    if crit.noise_aware and (noise is None or noise.is_zero):
        raise SpaceidError(
            f"`criterion` {criterion!r} minimises the estimation error under measurement noise: "
            "give `noise.angle`, `noise.rate`, `noise.base_rate` (rad, rad/s; spatial also "
            "`noise.attitude`), or use `criterion` cond"
        )
    overrides = {key: options.pop(key, None) for key in ("q_max", "qd_max", "qdd_max")}
    limits = _model_limits(param.model, overrides)
    options = {k: v for k, v in options.items() if v is not None}
    from ..dynamics import excitation_regressor

    if payload_link is not None:
        from ..identified import payload_map
        from ._design_payload import payload_regressor

        pmap = payload_map(param.model, payload_link, seed=param.seed)
        regressor = payload_regressor(pmap, momentum, noise if crit.noise_aware else None, payload)
    elif crit.noise_aware:
        regressor = whitened_regressor(param, param.true_values, momentum, noise)
    else:
        regressor = excitation_regressor(param, param.true_values, momentum)
    result = optimize_excitation(
        regressor,
        param.model.joints,
        duration=duration,
        harmonics=harmonics,
        samples=samples,
        seed=seed,
        progress=progress,
        criterion=criterion,
        **limits,
        **options,
    )
    if payload_link is not None:
        result = _with_payload_record(result, pmap, payload, momentum, noise, duration=duration, samples=samples)
    if noise is None or noise.is_zero:
        return result
    return _with_predicted_bound(result, param, momentum, noise, duration=duration, samples=samples)


def _with_payload_record(result, pmap, payload, momentum, noise, *, duration, samples):
    """``result`` with the payload's link, nominal and reference scale in its trajectory's ``meta``
    and, given ``noise``, the payload's predicted Cramer-Rao standard deviations."""
    from ._design_payload import payload_regressor

    names = ("m", "mcx", "mcy", "Izz") if pmap.planar else INERTIAL_NAMES
    nominal = np.zeros(pmap.n) if payload is None else np.asarray(payload, float)
    meta = {**result.trajectory.meta, "payload_link": pmap.link, "payload_nominal": dict(zip(names, nominal.tolist()))}
    if noise is not None and not noise.is_zero:
        q, qd, _ = result.trajectory.evaluate(sample_times(duration, samples))
        bound = payload_regressor(pmap, momentum, noise, payload)
        meta["payload_crb_std"] = dict(zip(names, np.sqrt(np.diag(bound.crb(q, qd))).tolist()))
    return replace(result, trajectory=replace(result.trajectory, meta=meta))


def _model_limits(model, overrides):
    """The joint limits of ``model`` as arrays (n_joints,) by keyword of
    :func:`optimize_excitation`: ``q_max`` [rad] (the nearer of the lower and upper position
    limits), ``qd_max`` [rad/s], ``qdd_max`` [rad/s^2]; ``overrides`` (the same keys, None where
    not given) replace them. Every joint must have all three."""
    lower, upper = model.joint_limits("lower"), model.joint_limits("upper")
    outside = np.flatnonzero((lower >= 0) | (upper <= 0))  # NaN (no limit) compares False
    if outside.size:  # |q| <= q_max about 0 cannot keep such a joint inside its range
        j = outside[0]
        raise SpaceidError(
            f"{model.source}: joint '{model.joints[j]}' has the range [{lower[j]:g}, {upper[j]:g}], which does "
            "not hold q = 0 inside: designed trajectories move about q = 0, so they would leave it; put the "
            "joint's zero inside its range (shift the joint origin) and design again"
        )
    limits = {
        "q_max": np.fmin(np.abs(lower), np.abs(upper)),
        "qd_max": model.joint_limits("velocity"),
        "qdd_max": model.joint_limits("acceleration"),
    }
    for key, value in list(limits.items()):
        if overrides[key] is not None:
            limits[key] = np.broadcast_to(np.asarray(overrides[key], float), value.shape).copy()
    for key, value in limits.items():
        if np.isnan(value).any():
            missing = [j for j, v in zip(model.joints, value) if np.isnan(v)]
            raise SpaceidError(
                f"{model.source}: no {key.replace('_max', '')} limit for joint(s) "
                f"{', '.join(missing)}: "
                f"give `{key}` (rad, rad/s, rad/s^2)"
            )
    return limits


def bound_summary(meta: dict) -> str | None:
    """One line on a design's predicted Cramer-Rao bound (its trajectory's ``meta``): the worst
    standard deviation as the momentum it causes (a percentage of the momentum scale), and the
    worst relative one among the large parameters (:data:`spaceid.estimation.LARGE_SHARE`); None
    when the meta has no bound (no noise given)."""
    scaled, scale = meta.get("crb_scaled_std"), meta.get("momentum_scale")
    if not scaled or not scale:
        return None
    names = list(scaled)
    worst = max(names, key=lambda n: scaled[n])
    line = f"predicted CRB: worst std {100 * scaled[worst]:.3g} % of the momentum scale ({worst})"
    relative = meta.get("crb_relative_std", {})
    large = [n for n, share in zip(names, scale["share"]) if share >= LARGE_SHARE and relative.get(n) is not None]
    if large:
        top = max(large, key=lambda n: relative[n])
        line += f"; worst relative std of the {len(large)} large parameters {100 * relative[top]:.3g} % ({top})"
    return line


def _with_predicted_bound(result, param, momentum, noise, *, duration, samples):
    """``result`` with ``noise`` and, in its trajectory's ``meta``, the noise and the predicted
    Cramer-Rao standard deviation of every parameter, absolute (defined for zero nominal
    values too), relative to its nominal value, and as a fraction of the momentum scale of the
    designed motion (:func:`spaceid.estimation.momentum_scale`, at the nominal base rate)."""
    q, qd, _ = result.trajectory.evaluate(sample_times(duration, samples))
    bound = whitened_regressor(param, param.true_values, momentum, noise, relative=False)
    std = np.sqrt(np.diag(bound.crb(q, qd)))
    pi = np.abs(param.true_values)
    w0 = excitation_regressor(param, param.true_values, momentum).with_rate(q, qd)[1]
    scale = momentum_scale(param, q, qd, w0)
    meta = {
        **result.trajectory.meta,
        "noise": noise.to_dict(),
        "crb_std": dict(zip(param.names, std.tolist())),
        "crb_relative_std": {n: s / p if p > 0 else None for n, s, p in zip(param.names, std, pi)},
        "crb_scaled_std": dict(zip(param.names, scale.scaled(std).tolist())),
        "momentum_scale": scale.to_dict(),
    }
    return replace(result, trajectory=replace(result.trajectory, meta=meta), noise=noise)
