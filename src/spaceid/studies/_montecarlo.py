"""Monte Carlo studies of the estimators: bias, spread and efficiency against the Cramer-Rao bound.

A study simulates the noise-free motion once (:func:`spaceid.motion.simulate`), computes the
Cramer-Rao bound of the errors-in-variables model for it (:func:`spaceid.estimation.cramer_rao`),
then repeats runs: fresh measurement noise, identification with every requested estimator,
estimates and predicted standard errors kept. Per estimator and parameter it reports the
bias, standard deviation and RMSE over the runs, the mean predicted standard error, and RMSE /
CRB: how far the estimator is from the best any unbiased one can do.

Noise. Each run draws white Gaussian noise of the levels of a :class:`spaceid.estimation.Noise`:
``angle`` on the joint angles, ``rate`` on the joint rates, ``base_rate`` on the base angular
velocity and ``attitude`` on the base attitude, by two :func:`spaceid.motion.add_noise` draws
(joint signals from the first, base signals from the second, so that the four levels are
independent). The estimators get the true levels (``noise=``), as in a study where the sensors
are characterised.

Angles only (``angles_only=True``). Noise goes on the joint angles and the base attitude only;
the rates are then differentiated from them (:func:`spaceid.data.differentiate_log`,
automatic bandwidth unless ``differentiate=`` fixes it), as on hardware with encoders and motion
capture. The estimators then get the noise model of the differentiated signals
(:func:`spaceid.studies.differentiated_noise`): the differentiator's own noise estimate of each
channel, propagated through its filter weights (the RMS over samples of the white-noise
equivalent of the smoothed angles and of the rates). This is the level of the per-sample errors,
but they are correlated over the differentiator's window (and the windows trade noise for bias),
which the estimators' white-noise model ignores: predicted standard errors are then optimistic.
The "CRB" reported in that mode is the bound of that white-noise equivalent (levels RMS over the
runs), a yardstick rather than a bound.

Seeds. Run ``i`` draws its noise from ``np.random.SeedSequence(seed).spawn(runs)[i]``
(two 32-bit states, one per :func:`~spaceid.motion.add_noise` draw), so each run's noise
depends on ``(seed, i)`` alone: the numbers do not depend on ``jobs`` or on the order in which
runs finish. The root seed is recorded.

Parallelism. Chunks of runs (about runs / 64 each, whatever the workers) are the tasks of a
campaign (:func:`spaceid._campaign.run_campaign`): on a local process pool, a Dask
``LocalCluster`` or a running ``dask scheduler`` (``scheduler``), every worker limited to one
BLAS thread (the small factorisations gain nothing from more, and threads spinning on busy cores
slow every process down); one local job runs in the calling process, with the same limit, so
that its numbers equal the parallel ones exactly. With a study folder each chunk's output is
written there as it completes, and ``resume`` runs only the chunks whose output is missing
(docs/campaigns.md).
"""

from __future__ import annotations

import io
import os
import time
from collections import Counter
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np
from threadpoolctl import threadpool_limits

from .._campaign import fingerprint, resolve_scheduler, run_campaign
from .._deprecation import deprecated_alias
from .._errors import SpaceidError
from ..dynamics import Parameterization
from ..estimation import ESTIMATORS, Noise, cramer_rao, identify
from ..motion import FourierTrajectory, load_trajectory, sample_times, simulate
from ._montecarlo_runs import _WHERE, _differentiation_summary, _merge_chunks, _Study
from ._montecarlo_stats import STATISTICS, _statistics

__all__ = ["DEFAULT_NOISE", "MonteCarloResult", "run_montecarlo", "write_montecarlo"]

DEFAULT_NOISE = Noise(1e-4, 1e-4, 1e-4, 1e-4, source="default: issue 4 targets (1e-4 rad, rad/s)")
"""Noise of the issue's targets: 1e-4 rad on angles and attitude, 1e-4 rad/s on rates."""

_MAX_CHUNK = 25  # runs per task at most: progress updates and load balance


@dataclass(frozen=True)
class MonteCarloResult:
    """Outcome of :func:`run_montecarlo`.

    Attributes
    ----------
    names, definitions : tuple of str
        The k minimal parameters.
    true : ndarray of shape (k,)
        True values.
    estimators : tuple of str
    estimates : dict of str to ndarray of shape (runs, k)
        Estimates of every run per estimator; NaN where the run failed.
    predicted_std : dict of str to ndarray of shape (runs, k)
        Standard errors each run's identification predicted; NaN where it failed.
    crb_cov : ndarray of shape (k, k)
        Cramer-Rao bound of the noise-free motion and the noise model.
    crb_std : ndarray of shape (k,)
    stats : dict of str to dict of str to ndarray of shape (k,)
        ``stats[estimator][statistic]``, the statistics of :data:`STATISTICS` over the runs
        that succeeded.
    failures : tuple of dict
        ``{"run", "estimator", "reason"}`` of every run that raised (a ``SpaceidError`` or a
        singular linear system).
    warnings : tuple of dict
        ``{"run", "estimator", "warning"}`` (e.g. maximum likelihood did not converge).
    settings : dict
        Everything needed to reproduce the study: model, trajectory, times, momentum, noise
        and the model given to the estimators, runs, root seed and how run seeds derive from
        it, estimators, differentiation, wall time.
    """

    names: tuple
    definitions: tuple
    true: np.ndarray
    estimators: tuple
    estimates: dict
    predicted_std: dict
    crb_cov: np.ndarray
    crb_std: np.ndarray
    stats: dict
    failures: tuple = ()
    warnings: tuple = ()
    settings: dict = field(default_factory=dict)

    @property
    def runs(self) -> int:
        return int(self.settings["runs"])

    def summary(self, estimator: str) -> dict:
        """Worst cases over the parameters: ``relative_rmse``, ``rmse_crb``, ``abs_bias_std``
        (max over parameters; NaN entries ignored) and ``runs_ok``."""
        s = self.stats[estimator]
        worst = lambda x: float(np.nanmax(x)) if np.any(np.isfinite(x)) else float("nan")  # noqa: E731
        ok = int(np.all(np.isfinite(self.estimates[estimator]), axis=1).sum())
        return {"relative_rmse": worst(s["relative_rmse"]), "rmse_crb": worst(s["rmse_crb"]),
                "abs_bias_std": worst(np.abs(s["bias_std"])), "runs_ok": ok}  # fmt: skip

    def plot(self, fig=None, *, max_panels: int = 12):
        """Draw the errors of every estimator per parameter in the Cramer-Rao band and RMSE / CRB
        (:func:`spaceid.studies.plot_montecarlo`), and return the :class:`matplotlib.figure.Figure`.

        Parameters
        ----------
        fig : matplotlib.figure.Figure or SubFigure, optional
            Draw into it; default: a new figure.
        max_panels : int
            Parameters with a box-plot panel at most (those with the largest relative RMSE).
        """
        from ._figures import _draw_montecarlo

        return _draw_montecarlo(self, max_panels, fig)

    def to_dict(self) -> dict:
        """JSON-ready: settings, parameters with their CRB, per estimator the statistics and
        worst cases, failures, warnings, and the estimates and predicted standard errors of
        every run."""
        return {
            "settings": self.settings,
            "parameters": [
                {"name": n, "definition": d, "true": float(t), "crb_std": float(c)}
                for n, d, t, c in zip(self.names, self.definitions, self.true, self.crb_std)
            ],
            "crb_covariance": self.crb_cov.tolist(),
            "estimators": {
                e: {
                    "worst": self.summary(e),
                    "parameters": [
                        {"name": n, **{s: float(self.stats[e][s][i]) for s in STATISTICS}}
                        for i, n in enumerate(self.names)
                    ],
                }
                for e in self.estimators
            },
            "failures": list(self.failures),
            "warnings": list(self.warnings),
            "runs": {e: {"estimates": self.estimates[e].tolist(), "predicted_std": self.predicted_std[e].tolist()}
                     for e in self.estimators},  # fmt: skip
        }


# --- the runs as campaign tasks -----------------------------------------------------------------


def _noise_states(seed: int, runs: int) -> np.ndarray:
    """The two 32-bit ``add_noise`` seeds ``(runs, 2)`` of every run: run i's from the i-th
    child of the root seed alone (see the module docstring)."""
    return np.array([s.generate_state(2) for s in np.random.SeedSequence(seed).spawn(runs)])


def _plan_chunks(states) -> dict:
    """Tasks ``{key: (first run, states)}`` of about ``runs / 64`` runs each (at most
    ``_MAX_CHUNK``), whatever the workers, so that a campaign resumes on any scheduler."""
    runs = len(states)
    size = max(1, min(_MAX_CHUNK, -(-runs // 64)))
    return {f"runs-{first:07d}-{min(first + size, runs) - 1:07d}": (first, states[first : first + size])
            for first in range(0, runs, size)}  # fmt: skip


def _campaign_fingerprint(study: _Study, trajectory: dict, seed: int, runs: int) -> str:
    """What the task results of a study folder must belong to for ``resume`` (the trajectory without
    its ``meta``: a design's wall time changes from call to call; the motion is in the arrays)."""
    settings = {"model": study.param.model.source or study.param.model.name, "names": list(study.param.names),
                "trajectory": {k: v for k, v in trajectory.items() if k != "meta"},
                "momentum": study.momentum.tolist(), "noise": study.noise.to_dict(),
                "estimators": list(study.estimators), "angles_only": study.angles_only,
                "differentiate": study.differentiate, "seed": seed, "runs": runs}  # fmt: skip
    clean = study.clean
    return fingerprint(settings, study.param.true_values, clean.t, clean.q, clean.qd, clean.base_w)


def _execute(study: _Study, states, *, scheduler, jobs, folder, campaign, resume, progress) -> list:
    """All runs, in chunks, as campaign tasks (see :func:`spaceid._campaign.run_campaign`);
    chunk outputs in run order."""
    tasks = _plan_chunks(states)
    sizes = {key: len(task[1]) for key, task in tasks.items()}
    outputs = run_campaign(_Study.chunk, study, tasks, scheduler=scheduler, jobs=jobs, folder=folder,
                           campaign=campaign, resume=resume, progress=progress, sizes=sizes)  # fmt: skip
    return list(outputs.values())


# --- the options --------------------------------------------------------------------------------


def _cores() -> int:
    """Cores this process may run on."""
    if hasattr(os, "sched_getaffinity"):
        return max(1, len(os.sched_getaffinity(0)))
    return os.cpu_count() or 1


def _check_int(value, option, minimum, fix):
    if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or value < minimum:
        raise SpaceidError(f"{option}: {value!r} is not an integer >= {minimum}: {fix}")
    return int(value)


def _check_estimators(estimators) -> tuple:
    names = (estimators,) if isinstance(estimators, str) else tuple(estimators or ())
    if not names:
        raise SpaceidError(f"`estimators`: none given: name at least one of {', '.join(ESTIMATORS)}")
    for e in names:
        if e not in ESTIMATORS:
            raise SpaceidError(f"`estimators`: '{e}' is not one of {', '.join(ESTIMATORS)}")
    return tuple(dict.fromkeys(names))


def _check_noise(noise, angles_only: bool) -> None:
    """Raise unless ``noise`` is a :class:`~spaceid.estimation.Noise` with a nonzero level on
    the signals that get noise."""
    if not isinstance(noise, Noise):
        raise SpaceidError(f"`noise` must be a spaceid.estimation.Noise, got {type(noise).__name__}")
    relevant = (noise.angle, noise.attitude) + (() if angles_only else (noise.rate, noise.base_rate))
    if not any(relevant):
        raise SpaceidError("`noise`: the noise is zero"
                           + (" on the angles and attitude (`angles_only`)" if angles_only else "")
                           + ": a Monte Carlo study needs noise (e.g. `noise.angle` 1e-4)")  # fmt: skip


def _check_sampling(samples, times, duration):
    """``samples`` as an int (or None when ``times`` are given); raises on a bad combination."""
    if (samples is None) == (times is None):
        raise SpaceidError("`samples`: give exactly one of `samples` (a number, equally spaced) or `times`")
    if samples is not None:
        samples = _check_int(samples, "`samples`", 2, "give the number of equally spaced samples, e.g. 35")
    if duration is not None and not (np.isfinite(duration) and duration > 0):
        raise SpaceidError(f"`duration`: {duration!r} is not a positive number of seconds")
    return samples


def _check_momentum(momentum) -> np.ndarray:
    """``momentum`` as a finite, nonzero 3-vector [N m s]."""
    momentum = np.asarray(momentum, float).reshape(3)
    if not (np.all(np.isfinite(momentum)) and np.linalg.norm(momentum) > 0):
        raise SpaceidError(f"`momentum`: {momentum.tolist()} N m s: a Monte Carlo study needs the finite, nonzero "
                           "momentum of the simulated motion (it fixes the parameters' scale)")  # fmt: skip
    return momentum


def _trajectory(param, spec, *, duration, samples, momentum, noise, seed, design, progress):
    """``spec`` as a FourierTrajectory or a motion callable, and its record for the settings."""
    if isinstance(spec, FourierTrajectory):
        return spec, {"name": spec.meta.get("name", spec.meta.get("source", "trajectory")), **spec.to_dict()}
    if callable(spec):
        return spec, {"name": getattr(spec, "__name__", type(spec).__name__), "callable": True}
    if str(spec) == "designed":
        from ..motion import design_excitation

        if duration is None or samples is None:
            raise SpaceidError("`trajectory` 'designed': give the `duration` [s] and the `samples` of the design")
        options = {"harmonics": 3, **dict(design or {})}
        traj = design_excitation(param, duration=duration, samples=samples, momentum=momentum, seed=seed,
                                 progress=progress, noise=noise, **options).trajectory  # fmt: skip
        traj = replace(traj, meta={**traj.meta, "name": f"designed ({traj.meta.get('criterion')}, seed {seed})"})
        return traj, {"name": traj.meta["name"], **traj.to_dict()}
    traj = load_trajectory(spec, joints=param.model.joints)
    return traj, {"name": str(spec), **traj.to_dict()}


def _motion_and_times(traj, duration, samples, times) -> tuple:
    """The motion callable ``motion(t) -> (q, qd)`` of ``traj`` and the sample times ``(N,)`` [s]:
    ``times`` if given, else ``samples`` equally spaced over the duration (default the
    trajectory's)."""
    if isinstance(traj, FourierTrajectory):
        motion = lambda t: traj.evaluate(t)[:2]  # noqa: E731
        if duration is None:
            duration = traj.duration
        elif duration > traj.duration + 1e-12:
            raise SpaceidError(f"`duration`: {duration:g} s is longer than the trajectory ({traj.duration:g} s): "
                               "omit it or give at most the trajectory's")  # fmt: skip
    else:
        motion = traj
    if times is None:
        if duration is None:
            raise SpaceidError("`duration`: a motion callable needs the duration [s] (or the sample `times`)")
        times = sample_times(duration, samples)
    times = np.asarray(times, float)
    if times.ndim != 1 or times.size < 2 or not np.all(np.isfinite(times)) or np.any(np.diff(times) <= 0):
        raise SpaceidError("`times`: expected at least 2 finite, strictly increasing sample times [s]")
    return motion, times


# --- the study ----------------------------------------------------------------------------------


def _settings(study: _Study, trajectory: dict, times, differentiation, *, runs, seed, failures, warned, jobs,
              scheduler, wall_time) -> dict:
    """Everything needed to reproduce the study (:attr:`MonteCarloResult.settings`)."""
    param, angles_only = study.param, study.angles_only
    return {
        "model": param.model.source or param.model.name,
        "planar": param.model.planar,
        "trajectory": trajectory,
        "duration": float(times[-1] - times[0]),
        "n_samples": int(times.size),
        "times": {"first": float(times[0]), "last": float(times[-1]),
                  "equally_spaced": bool(np.allclose(np.diff(times), times[1] - times[0]))},
        "momentum": study.momentum.tolist(),
        "noise": study.noise.to_dict(),
        "angles_only": angles_only,
        "noise_given_to_estimators": "per run, from the differentiator (see differentiation)" if angles_only
        else "the simulated levels (noise)",
        "differentiation": differentiation,
        "crb": "white-noise equivalent of the differentiated signals: a yardstick, not a bound" if angles_only
        else "Cramer-Rao bound of the errors-in-variables model (spaceid.estimation.cramer_rao) at the noise-free "
             "motion",
        "runs": runs,
        "seed": seed,
        "run_seeds": "np.random.SeedSequence(seed).spawn(runs)[i].generate_state(2): add_noise seeds of the joint "
                     "and of the base signals",
        "estimators": list(study.estimators),
        "instruments_iv": "commanded joint motion (noise-free q, qd at the sample times)",
        "failures": {"count": len(failures), "reasons": dict(Counter(f["reason"] for f in failures))},
        "warnings": {"count": len(warned), "messages": dict(Counter(w["warning"] for w in warned))},
        "jobs": jobs,
        "scheduler": scheduler,
        "wall_time_s": wall_time,
    }  # fmt: skip


@deprecated_alias(old="folder", new="out")
def run_montecarlo(
    param: Parameterization,
    trajectory,
    *,
    momentum,
    noise: Noise,
    duration: float | None = None,
    samples: int | None = None,
    times=None,
    runs: int = 200,
    estimators=("ml", "ols"),
    seed: int = 0,
    jobs: int | None = None,
    progress=None,
    angles_only: bool = False,
    differentiate: dict | None = None,
    design: dict | None = None,
    scheduler: str | None = None,
    out=None,
    resume: bool = False,
) -> MonteCarloResult:
    """Repeat simulate-and-identify with fresh noise; statistics against the truth and the CRB.

    Parameters
    ----------
    param : Parameterization
        Minimal parameters of the model; ``param.true_values`` is the simulated truth.
    trajectory : FourierTrajectory, callable, or str
        The joint motion: a trajectory, a callable ``motion(t) -> (q, qd)`` with ``t`` of shape
        (n,) and results (n, n_joints) [rad, rad/s], a named trajectory or file (see
        :func:`spaceid.motion.load_trajectory`), or ``"designed"``: designed now by
        :func:`spaceid.motion.design_excitation` with ``duration``, ``samples``, ``seed``, ``noise``
        and the options in ``design`` (default 3 harmonics, criterion ``cond``), its searches on
        the study's ``jobs`` and ``scheduler``.
    momentum : array_like of shape (3,)
        Inertial angular momentum [N m s], nonzero (known to the estimators).
    noise : Noise
        Measurement noise levels [rad, rad/s]; not all zero.
    duration : float, optional
        Sampled span [0, duration] [s]; default the trajectory's (for a callable it is needed
        unless ``times`` is given).
    samples : int, optional
        Equally spaced samples over [0, duration], at least 2 (give this or ``times``).
    times : array_like of shape (N,), optional
        Sample times [s], increasing.
    runs : int
        Noise draws, at least 2.
    estimators : sequence of str
        Keys of :data:`spaceid.estimation.ESTIMATORS`; ``iv`` gets the commanded joint motion as
        instruments.
    seed : int
        Root seed (>= 0) of the noise (and of a ``"designed"`` trajectory); recorded.
    jobs : int, optional
        Worker processes; default all cores available; 1 runs in this process.
    progress : callable, optional
        ``progress(done, total)``: design starts, then runs.
    angles_only : bool
        Noise on joint angles (``noise.angle``) and base attitude (``noise.attitude``) only; the
        rates differentiated from them (see the module docstring).
    differentiate : dict, optional
        Options of :func:`spaceid.data.differentiate_log` (``method``, ``window``,
        ``order``, ``smoothing``, ``quantum``) for ``angles_only``; default automatic.
    design : dict, optional
        Options of :func:`spaceid.motion.design_excitation` for ``"designed"`` (``harmonics``,
        ``criterion``, ``n_starts``, ...).
    scheduler : str, optional
        ``processes``, ``dask`` (a LocalCluster of ``jobs`` workers) or a ``dask scheduler``
        address ``tcp://HOST:PORT``; default ``DASK_SCHEDULER_ADDRESS`` if set, else
        ``processes``. The results do not depend on it.
    out : path, optional
        Study folder: each chunk of runs is written beside it (:func:`spaceid._campaign.task_folder`) as it completes.
    resume : bool
        Use the chunks in ``out`` (they must be of the same settings) and run the others.

    Returns
    -------
    MonteCarloResult

    Raises
    ------
    SpaceidError
        Bad options (named), a trajectory that does not excite every parameter, zero
        momentum, or every run of every estimator failing.
    """
    t_start = time.perf_counter()
    runs = _check_int(runs, "`runs`", 2, "the spread needs at least 2 noise draws (200 or more for stable statistics)")
    seed = _check_int(seed, "`seed`", 0, "give a non-negative integer")
    jobs = _cores() if jobs is None else _check_int(jobs, "`jobs`", 1, "give 1 or more worker processes")
    scheduler = resolve_scheduler(scheduler)
    estimators = _check_estimators(estimators)
    _check_noise(noise, angles_only)
    samples = _check_sampling(samples, times, duration)
    diff_options = dict(differentiate or {})
    if diff_options and not angles_only:
        raise SpaceidError("`differentiate`: options given without `angles_only`: the rates are measured")
    momentum = _check_momentum(momentum)
    traj, traj_record = _trajectory(param, trajectory, duration=duration, samples=samples, momentum=momentum,
                                    noise=noise, seed=seed, progress=progress,
                                    design={"jobs": jobs, "scheduler": scheduler, **dict(design or {})})  # fmt: skip
    motion, times = _motion_and_times(traj, duration, samples, times)

    with threadpool_limits(1):
        clean = simulate(param, param.true_values, motion, times, momentum, model=param.model)
        # a noise-free identification first: rank deficiency and a zero momentum fail here, once
        identify(param, clean, momentum, estimator="ols", noise=noise, where=_WHERE)
    study = _Study(param, clean, momentum, noise, estimators, bool(angles_only), diff_options)
    outputs = _execute(study, _noise_states(seed, runs), scheduler=scheduler, jobs=jobs, folder=out, resume=resume,
                       campaign=_campaign_fingerprint(study, traj_record, seed, runs), progress=progress)  # fmt: skip
    estimates, predicted, failures, warned = _merge_chunks(outputs, estimators, runs, param.n_params)

    model_noise, diff_record = _differentiation_summary(outputs, diff_options) if angles_only else (noise, None)
    with threadpool_limits(1):
        _, crb_cov = cramer_rao(param, clean, momentum, model_noise)
    crb_std = np.sqrt(np.diag(crb_cov))
    true = np.asarray(param.true_values, float)
    stats = {e: _statistics(estimates[e], predicted[e], true, crb_std) for e in estimators}
    settings = _settings(study, traj_record, times, diff_record, runs=runs, seed=seed, failures=failures,
                         warned=warned, jobs=jobs, scheduler=scheduler,
                         wall_time=time.perf_counter() - t_start)  # fmt: skip
    return MonteCarloResult(param.names, param.definitions, true, estimators, estimates, predicted, crb_cov, crb_std,
                            stats, failures, warned, settings)  # fmt: skip


@deprecated_alias(old="folder", new="out")
def write_montecarlo(result: MonteCarloResult, out) -> dict:
    """Write ``montecarlo.json``, ``table.txt`` (the terminal table), ``montecarlo.png`` and
    ``report.html`` (interactive, docs/formats/report-html.md) into ``folder`` (created if needed),
    each atomically.

    Returns
    -------
    dict of str to Path
        ``{"json", "table", "figure", "html"}``.
    """
    from rich.console import Console

    from ._figures import plot_montecarlo
    from ._html_report import write_montecarlo_html

    from ._tables import montecarlo_table
    from .._atomic import write_text_atomic
    from ..data import write_json

    folder = Path(out)
    try:
        folder.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise SpaceidError(f"`out`: cannot create {folder} ({exc.strerror or exc}): give a writable folder") from None
    paths = {"json": folder / "montecarlo.json", "table": folder / "table.txt", "figure": folder / "montecarlo.png"}
    write_json(paths["json"], result.to_dict())
    buffer = io.StringIO()
    Console(file=buffer, width=100, color_system=None, force_terminal=False, markup=False, emoji=False).print(
        montecarlo_table(result))
    write_text_atomic(paths["table"], buffer.getvalue())
    plot_montecarlo(result, paths["figure"])
    paths["html"] = write_montecarlo_html(result, folder / "report.html")
    return paths
