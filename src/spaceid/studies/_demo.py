"""The paper's simulation study on the built-in Cepheus model, end to end.

Design (or take the paper's) exciting trajectory, simulate the free-floating motion with
h = 0.4934 N m s, sample N = 35 points, identify pi by least squares, validate the identified
model by re-simulation, and write a report folder.

References
----------
.. [1] The Cepheus paper (NTUA Control Systems Lab; see docs/citing.md), Section "Simulation results", Tables 1-3.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..motion import design_excitation
from .._constants import FALSE_ALARM_RATE
from ..estimation import Identification, cusum_threshold, identify
from ..data import write_json, write_log
from ..models import PRESETS, load_model
from ..estimation import Noise
from ..dynamics import minimal_parameters, momentum_jacobian, no_effect_parameters
from ..motion import add_noise, simulate
from ..motion import FourierTrajectory, load_trajectory, sample_times
from ._validate import validate

__all__ = ["PAPER_TABLE3", "CEPHEUS_STUDY", "DemoResult", "run_demo", "warm_preset_sets", "warm_spatial_kernels"]

PAPER_TABLE3 = {
    # Table 3 of the paper as read in docs/theory/cepheus.md: 'true values' and relative errors [%]
    "true": np.array([0.0074, 0.0046, 0.0039, 0.0024, 0.1314, 0.0048, 0.0075, 0.0046]),
    "relative_error_percent": np.array([0.5162, 0.4071, 0.3191, 1.2574, 0.0432, 0.7286, 1.3010, 0.6634]),
}
CEPHEUS_STUDY = {"duration": 5.0, "harmonics": 3, "samples": 35, "momentum": 0.4934}


@dataclass(frozen=True)
class DemoResult:
    """What the demo produced: the identification, the truth, and where the report is."""

    ident: Identification
    true: np.ndarray
    trajectory: FourierTrajectory
    metrics: dict
    folder: Path | None

    def to_dict(self) -> dict:
        rel = (self.ident.values - self.true) / self.true * 100
        return {
            "parameters": [
                {"name": n, "definition": d, "true": float(t), "estimate": float(v), "std": float(s),
                 "relative_error_percent": float(r)}
                for n, d, t, v, s, r in zip(self.ident.names, self.ident.definitions, self.true, self.ident.values,
                                            self.ident.std, rel)
            ],
            "condition_number": self.ident.condition_number,
            "n_samples": self.ident.n_samples,
            "trajectory": self.ident.settings["trajectory"],
            "validation": self.metrics,
            "settings": self.ident.settings,
            "report": str(self.folder) if self.folder else None,
        }


def run_demo(
    *,
    trajectory: str = "designed",
    noise_angle: float = 0.0,
    noise_rate: float = 0.0,
    seed: int = 0,
    out=None,
    progress=None,
    design_starts: int = 32,
) -> DemoResult:
    """Run the paper's simulation study on ``cepheus``.

    Parameters
    ----------
    trajectory : {"designed", "paper-table2"} or path
        Exciting trajectory: designed now (seeded), the paper's, or a file from ``design``.
    noise_angle, noise_rate : float
        White noise on measured angles [rad] and rates [rad/s].
    seed : int
        Seed of the design and of the noise; recorded.
    out : path, optional
        Report folder (plots, JSON, CSV, Markdown); nothing is written when None.
    progress : callable, optional
        ``progress(done, total)`` for the design's global search.
    design_starts : int
        Local starts of the design's global search (no time budget, so the result depends on
        the seed only; 32 starts take a few seconds and reach cond ~ 36).
    """
    model = load_model("cepheus")
    param = minimal_parameters(model)
    study = CEPHEUS_STUDY
    momentum = np.array([0.0, 0.0, study["momentum"]])
    if trajectory == "designed":
        traj = design_excitation(
            param, duration=study["duration"], harmonics=study["harmonics"], samples=study["samples"],
            momentum=momentum, seed=seed, progress=progress, n_starts=design_starts,
        ).trajectory
    else:
        traj = load_trajectory(trajectory, joints=model.joints)
    motion = lambda t: traj.evaluate(t)[:2]  # noqa: E731
    times = sample_times(traj.duration, study["samples"])
    clean = simulate(param, param.true_values, motion, times, momentum, model=model)
    log = add_noise(clean, angle=noise_angle, rate=noise_rate, seed=seed) if noise_angle or noise_rate else clean
    # the noise levels are known here: the estimator weights by them (none: estimated, ~0)
    noise = None
    if noise_angle or noise_rate:
        noise = Noise(noise_angle, noise_rate, noise_rate, noise_angle, "given (simulated)")
    ident = identify(param, log, momentum, noise=noise, where="demo")
    ident.settings.update(trajectory=traj.meta.get("name", str(trajectory)), seed=seed, noise_angle=noise_angle,
                          noise_rate=noise_rate)
    # validation on a fine grid: the true system vs the identified model for the same joint motion
    fine = simulate(param, param.true_values, motion, np.linspace(0, traj.duration, 501), momentum, model=model)
    check = validate(ident, fine, momentum=momentum, where="demo")
    result = DemoResult(ident, param.true_values, traj, check.metrics, Path(out) if out else None)
    if out:
        _write_report(result, log, fine, check.predicted)
    return result


def warm_spatial_kernels() -> None:
    """Compile the kernels that the commands on spatial robots call and the Cepheus study does not (or load
    them from Numba's cache): the momentum of the re-simulation, the attitude's collocation steps and their
    stage rate, the linearised regressor (``monitor``), its contracted derivative and the momentum's Jacobian
    (``ml``; Cepheus's study calls the last too), each once on a few samples of the satellite-7dof preset, whose
    minimal set is cached on the way. ``spaceid demo`` ends with it, so that a first spatial command compiles
    nothing (about 3 s of CPU on fresh caches; 0.7 s on warm ones, mostly loading the kernels; a kernel left out
    cost the first spatial ``identify`` 0.5 s)."""
    model = load_model("satellite-7dof")
    param = minimal_parameters(model)
    n = len(model.joints)
    times = np.linspace(0.0, 0.2, 3)

    def motion(t):  # a slow ramp of every joint
        return 0.1 * np.outer(t, np.ones(n)), 0.1 * np.ones((len(t), n))

    log = simulate(param, param.true_values, motion, times, np.array([0.1, -0.2, 0.3]), model=model)
    param.linearized_regressor(log.q, log.qd, log.base_w, (log.qd, log.qd, log.base_w), step=1e-6)
    param.contracted_tangent(log.q, log.qd, log.base_w, (log.qd, log.qd, log.base_w), np.ones((len(log.t), 3)),
                             step=1e-6)  # ml's weights' derivative
    momentum_jacobian(param, log.q, log.qd, log.base_w, param.true_values)  # and its signal Jacobian


def warm_preset_sets(presets=PRESETS) -> None:
    """Derive the minimal parameter set of every preset model in ``presets`` (default: all) into the on-disk
    cache (:func:`~spaceid.dynamics.minimal_parameters`; read from it when it is there), and those of a payload
    on each of its bodies with declared zeros (a payload frees them: another set; Cepheus's links, 0.4 s each
    in a first ``spaceid payload``), and the monitor's CUSUM threshold at its default false-alarm rate for
    each preset's equations (:func:`~spaceid.estimation.cusum_threshold`, 0.12 s of a first ``monitor``) and the
    parameters without effect on its momentum (:func:`~spaceid.dynamics.no_effect_parameters`, 0.45 s of the
    servicer's first ``export``). ``spaceid demo`` ends with it, so that no first command on a preset derives one
    (the servicer's set: about 3 s of CPU, the others' under 1 s; reading a cached set takes milliseconds)."""
    from ..identified import payload_map

    for name in presets:
        model = load_model(name)
        param = minimal_parameters(model)
        cusum_threshold(FALSE_ALARM_RATE, param.rows)
        no_effect_parameters(param)
        for body in model.bodies:
            if body.known_zero:
                payload_map(model, body.name)


def _write_report(result: DemoResult, log, fine, predicted) -> None:
    from ._figures import plot_parameters, plot_singular_values, plot_trajectory, plot_validation
    from ._html_report import write_html_report
    from ._report import write_markdown_report

    folder = result.folder
    folder.mkdir(parents=True, exist_ok=True)
    traj = result.trajectory
    traj.save(folder / "trajectory.json")
    write_log(folder / "log.csv", log)
    write_json(folder / "result.json", result.ident.to_dict())
    # "report": the folder itself, which the command line writes under a temporary name and then renames
    write_json(folder / "demo.json", {**result.to_dict(), "report": "."})
    grid = np.linspace(0, traj.duration, 501)
    q, qd, qdd = traj.evaluate(grid)
    model = load_model("cepheus")
    limits = {"q": model.joint_limits("upper"), "qd": model.joint_limits("velocity"),
              "qdd": model.joint_limits("acceleration")}
    figures = {
        "Exciting trajectory": "trajectory.png",
        "Validation: measured vs identified model": "validation.png",
        "Parameter estimates": "parameters.png",
        "Singular values of the regressor": "singular_values.png",
    }
    plot_trajectory(grid, q, qd, qdd, traj.joints, folder / figures["Exciting trajectory"], limits=limits,
                    times=log.t)
    plot_validation(fine, predicted, folder / figures["Validation: measured vs identified model"])
    plot_parameters(result.ident, folder / figures["Parameter estimates"], true=result.true,
                    reference=PAPER_TABLE3["relative_error_percent"])
    plot_singular_values(result.ident, folder / figures["Singular values of the regressor"])
    settings = {
        "model": "cepheus (paper Table 1)",
        "trajectory": result.ident.settings["trajectory"],
        "duration [s]": traj.duration,
        "harmonics": traj.a.shape[1],
        "samples": result.ident.n_samples,
        "momentum [N m s]": CEPHEUS_STUDY["momentum"],
        "noise angle [rad]": result.ident.settings["noise_angle"],
        "noise rate [rad/s]": result.ident.settings["noise_rate"],
        "seed": result.ident.settings["seed"],
        "estimator": result.ident.estimator,
        "rank tolerance": result.ident.settings["parameterization"]["rank_tol"],
    }
    report = dict(title="spaceid: identification of Cepheus (paper simulation study)", result=result.ident,
                  settings=settings, true=result.true, reference=PAPER_TABLE3["relative_error_percent"],
                  reference_true=PAPER_TABLE3["true"], metrics=result.metrics)
    write_markdown_report(folder, figures=figures, **report)
    write_html_report(folder, figures={"Exciting trajectory": "trajectory.png"},
                      validations=[(fine, predicted, "Validation: measured vs identified model")], **report)
