"""Design sweeps: how the best exciting trajectory depends on its duration, harmonics and samples.

Every setting of the grid ``durations x harmonics x samples`` is one campaign task
(:func:`spaceid._campaign.run_campaign`): an excitation designed for it
(:func:`spaceid.motion.design_excitation`, ``n_starts`` local searches, no time budget so that
the result depends on the seed alone; ``max_steps`` bounds each search's work on any machine),
then two figures of merit of that trajectory at its samples: the condition number of the stacked
regressor (the paper's criterion) and the predicted Cramer-Rao standard deviation of every
parameter relative to its nominal value, for the noise given (the worst over the parameters is
reported). Setting i designs from
``np.random.SeedSequence(seed).spawn(n_settings)[i]`` (:func:`spaceid._campaign.task_seeds`).
"""

from __future__ import annotations

import csv
import io
import itertools
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from .._atomic import write_text_atomic
from .._campaign import fingerprint, resolve_scheduler, run_campaign, task_seeds
from .._deprecation import deprecated_alias
from .._errors import SpaceidError
from ..dynamics import Parameterization, excitation_regressor
from ..estimation import Noise
from ..motion import design_excitation, sample_times
from ._montecarlo import DEFAULT_NOISE, _check_int, _check_momentum, _cores

__all__ = ["SweepResult", "run_sweep", "sweep_table", "write_sweep"]

_CSV_FIELDS = ("duration", "harmonics", "samples", "seed", "cond", "crb_relative_worst", "crb_worst_parameter",
               "criterion_value")  # fmt: skip


@dataclass(frozen=True)
class _Sweep:
    """What every setting needs; sent once to each worker."""

    param: Parameterization
    momentum: np.ndarray
    noise: Noise
    criterion: str
    n_starts: int
    max_steps: int | None = None

    def setting(self, duration: float, harmonics: int, samples: int, seed: int) -> dict:
        """Design for one setting, then its condition number and relative CRB (see the module
        docstring); the searches run in this process."""
        res = design_excitation(self.param, duration=duration, harmonics=harmonics, samples=samples,
                                momentum=self.momentum, seed=int(seed), criterion=self.criterion, noise=self.noise,
                                n_starts=self.n_starts, max_steps=self.max_steps, jobs=1,
                                scheduler="processes")  # fmt: skip
        q, qd, _ = res.trajectory.evaluate(sample_times(duration, samples))
        cond = float(np.linalg.cond(excitation_regressor(self.param, self.param.true_values, self.momentum)(q, qd)))
        relative = {n: v for n, v in res.trajectory.meta["crb_relative_std"].items() if v is not None}
        worst = max(relative, key=relative.get)
        return {"duration": float(duration), "harmonics": int(harmonics), "samples": int(samples), "seed": int(seed),
                "cond": cond, "crb_relative_worst": float(relative[worst]), "crb_worst_parameter": worst,
                "criterion_value": float(res.value), "crb_relative_std": relative,
                "trajectory": res.trajectory.to_dict()}  # fmt: skip


@dataclass(frozen=True)
class SweepResult:
    """Outcome of :func:`run_sweep`.

    Attributes
    ----------
    rows : tuple of dict
        One per setting, in grid order (durations slowest, samples fastest): ``duration`` [s],
        ``harmonics``, ``samples``, ``seed`` (of its design), ``cond`` (condition number of the
        stacked regressor), ``crb_relative_worst`` (largest predicted relative Cramer-Rao std
        over the parameters with a nonzero nominal value) and ``crb_worst_parameter``,
        ``criterion_value`` (the design criterion's value), ``crb_relative_std`` (per parameter)
        and ``trajectory`` (the designed trajectory's dictionary).
    settings : dict
        Model, grid, criterion, starts, each search's most steps (``max_steps``, None: its own),
        noise, momentum, root seed and how setting seeds derive from it, scheduler, jobs, resumed
        settings, wall time.
    """

    rows: tuple
    settings: dict = field(default_factory=dict)

    def to_dict(self) -> dict:
        """JSON-ready: settings and rows."""
        return {"settings": self.settings, "rows": list(self.rows)}


def _grid_values(values, option: str, kind) -> tuple:
    """``values`` as a non-empty tuple of distinct positive durations (``kind`` float) or of
    integers (``int``: harmonics >= 1, samples >= 2)."""
    values = tuple(dict.fromkeys(np.atleast_1d(np.asarray(values, dtype=object)).tolist()))
    if not values:
        raise SpaceidError(f"{option}: no value given: give at least one")
    if kind is int:
        minimum = 2 if option == "`samples`" else 1
        return tuple(_check_int(v, option, minimum, "give integers") for v in values)
    for v in values:
        if isinstance(v, bool) or not isinstance(v, (int, float, np.number)) or not (np.isfinite(v) and v > 0):
            raise SpaceidError(f"{option}: {v!r} is not a positive number of seconds")
    return tuple(float(v) for v in values)


@deprecated_alias(old="folder", new="out")
def run_sweep(param: Parameterization, *, momentum, durations, harmonics, samples, noise: Noise = DEFAULT_NOISE,
              criterion: str = "cond", n_starts: int = 8, max_steps: int | None = None, seed: int = 0,
              scheduler: str | None = None, jobs: int | None = None, out=None, resume: bool = False,
              progress=None) -> SweepResult:
    """Design an excitation for every setting of a grid; condition number and relative CRB of each.

    Parameters
    ----------
    param : Parameterization
        Minimal parameters; the design and the bound are evaluated at ``param.true_values``.
    momentum : array_like of shape (3,)
        Angular momentum [N m s], nonzero.
    durations : sequence of float
        Trajectory durations [s].
    harmonics : sequence of int
        Fourier harmonics (>= 1).
    samples : sequence of int
        Equally spaced samples over each duration (>= 2).
    noise : Noise
        Measurement noise of the predicted Cramer-Rao bound (and of ``dopt``, ``crb``).
    criterion : str
        Design criterion (see :func:`spaceid.motion.design_excitation`).
    n_starts : int
        Local searches of each design.
    max_steps : int, optional
        Most linearisations of the regressor each design's local search makes
        (:func:`spaceid.motion.design_excitation`): the work of a setting bounded alike on any machine
        (the dual-arm servicer's 496 parameters take about 80 s a start to their default of 40).
        Default: each search's own (to convergence for small regressors, 40 for large ones).
    seed : int
        Root seed (>= 0); setting i designs from its i-th spawned seed.
    scheduler, jobs, out, resume
        As for :func:`spaceid.studies.run_montecarlo`: a setting is a task.
    progress : callable, optional
        ``progress(done, total)`` in settings.

    Returns
    -------
    SweepResult

    Raises
    ------
    SpaceidError
        A bad grid value or option (named), or a setting whose design fails (e.g. too few
        samples for the parameters).
    """
    t_start = time.perf_counter()
    seed = _check_int(seed, "`seed`", 0, "give a non-negative integer")
    n_starts = _check_int(n_starts, "`n_starts`", 1, "give 1 or more local searches")
    if max_steps is not None:
        max_steps = _check_int(max_steps, "`max_steps`", 1, "give 1 or more linearisations, or None")
    jobs = _cores() if jobs is None else _check_int(jobs, "`jobs`", 1, "give 1 or more worker processes")
    scheduler = resolve_scheduler(scheduler)
    grid = list(itertools.product(_grid_values(durations, "`durations`", float),
                                  _grid_values(harmonics, "`harmonics`", int),
                                  _grid_values(samples, "`samples`", int)))  # fmt: skip
    sweep = _Sweep(param, _check_momentum(momentum), noise, criterion, n_starts, max_steps)
    seeds = task_seeds(seed, len(grid))
    tasks = {f"setting-{i:05d}": (*setting, int(s)) for i, (setting, s) in enumerate(zip(grid, seeds))}
    settings = {"model": param.model.source or param.model.name, "names": list(param.names),
                "durations": sorted({g[0] for g in grid}), "harmonics": sorted({g[1] for g in grid}),
                "samples": sorted({g[2] for g in grid}), "criterion": criterion, "n_starts": n_starts,
                "max_steps": max_steps,
                "noise": noise.to_dict(), "momentum": sweep.momentum.tolist(), "seed": seed,
                "setting_seeds": "np.random.SeedSequence(seed).spawn(n_settings)[i].generate_state(1)[0], settings "
                                 "in grid order (durations slowest, samples fastest)"}  # fmt: skip
    campaign = fingerprint({**settings, "grid": grid}, param.true_values)
    rows = run_campaign(_Sweep.setting, sweep, tasks, scheduler=scheduler, jobs=jobs, folder=out,
                        campaign=campaign, resume=resume, progress=progress)  # fmt: skip
    settings |= {"scheduler": scheduler, "jobs": jobs, "wall_time_s": time.perf_counter() - t_start}
    return SweepResult(tuple(rows.values()), settings)


def sweep_table(result: SweepResult):
    """The sweep as a rich table (fits 80 columns): per setting duration, harmonics, samples,
    condition number and the worst predicted relative CRB with its parameter."""
    from rich.table import Table

    s = result.settings
    starts = f"{s['n_starts']} start{'s' * (s['n_starts'] != 1)}"
    table = Table(title=f"Design sweep: {s['criterion']}, {starts} a setting, seed {s['seed']}")
    for name in (r"tf \[s]", "Nf", "N", "cond", "worst CRB [%]", "parameter"):
        table.add_column(name, justify="left" if name == "parameter" else "right", no_wrap=True)
    for r in result.rows:
        table.add_row(f"{r['duration']:g}", str(r["harmonics"]), str(r["samples"]), f"{r['cond']:.4g}",
                      f"{100 * r['crb_relative_worst']:.3g}", r["crb_worst_parameter"])  # fmt: skip
    return table


def _draw_sweep(result: SweepResult):
    """The figure of :func:`write_sweep`: condition number and worst relative CRB against the
    duration, one line per (harmonics, samples)."""
    from matplotlib.ticker import FuncFormatter

    from .._figure_style import new_figure, styled

    @styled
    def draw():
        fig = new_figure((8.0, 3.4))
        axes = fig.subplots(1, 2)
        for (nf, n), rows in itertools.groupby(sorted(result.rows, key=lambda r: (r["harmonics"], r["samples"])),
                                               key=lambda r: (r["harmonics"], r["samples"])):  # fmt: skip
            rows = sorted(rows, key=lambda r: r["duration"])
            t = [r["duration"] for r in rows]
            label = f"Nf = {nf}, N = {n}"
            axes[0].plot(t, [r["cond"] for r in rows], marker="o", label=label)
            axes[1].plot(t, [100 * r["crb_relative_worst"] for r in rows], marker="o", label=label)
        noise = result.settings["noise"]
        plain = FuncFormatter(lambda v, _: f"{v:g}")
        axes[0].set(yscale="log", xlabel="duration tf [s]", ylabel="condition number of Y [-]",
                    title="Condition number of the designed excitation")  # fmt: skip
        axes[1].set(yscale="log", xlabel="duration tf [s]", ylabel="worst relative CRB std [%]",
                    title="Worst predicted relative std (Cramer-Rao)")  # fmt: skip
        for ax in axes:
            low, high = ax.dataLim.intervaly
            ax.yaxis.set_major_formatter(plain)
            if high < 10 * low:  # less than a decade: label the minor ticks too, in plain numbers
                ax.yaxis.set_minor_formatter(plain)
        axes[1].legend(loc="best")
        fig.suptitle(f"Design sweep of {result.settings['model']} (criterion {result.settings['criterion']}; noise "
                     f"{noise['angle']:.2g} rad, {noise['rate']:.2g} rad/s)")  # fmt: skip
        return fig

    return draw()


@deprecated_alias(old="folder", new="out")
def write_sweep(result: SweepResult, out) -> dict:
    """Write ``sweep.json`` (settings and every row, trajectories included), ``sweep.csv`` (one
    line a setting, the columns of the table), ``table.txt`` and ``sweep.png`` into ``out``,
    each atomically.

    Returns
    -------
    dict of str to Path
        ``{"json", "csv", "table", "figure"}``.
    """
    from rich.console import Console

    from ..data import write_json
    from .._figure_style import save_figure

    folder = Path(out)
    try:
        folder.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise SpaceidError(f"`out`: cannot create {folder} ({exc.strerror or exc}): give a writable folder") from None
    paths = {name: folder / f"sweep.{ext}" for name, ext in (("json", "json"), ("csv", "csv"), ("figure", "png"))}
    paths["table"] = folder / "table.txt"
    write_json(paths["json"], result.to_dict())
    buffer = io.StringIO()
    writer = csv.DictWriter(buffer, fieldnames=_CSV_FIELDS, extrasaction="ignore", lineterminator="\n")
    writer.writeheader()
    writer.writerows({**r, "cond": repr(r["cond"]), "crb_relative_worst": repr(r["crb_relative_worst"])}
                     for r in result.rows)  # fmt: skip
    write_text_atomic(paths["csv"], buffer.getvalue())
    buffer = io.StringIO()
    Console(file=buffer, width=80, color_system=None, force_terminal=False).print(sweep_table(result))
    write_text_atomic(paths["table"], buffer.getvalue())
    save_figure(_draw_sweep(result), paths["figure"])
    return paths
