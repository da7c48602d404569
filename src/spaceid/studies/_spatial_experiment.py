"""The spatial protocol end to end on the servicer twin (docs/theory/twin-spatial.md).

Protocol: the lab designs an exciting trajectory with its CAD model (the twin's model with
every mass and principal moment 15 % off: the one its joint controllers use); the servicer,
turning slowly with a momentum the lab knows (the scale anchor: at zero momentum a servicer
without momentum wheels fixes its minimal parameters only up to a common factor), flies it
under computed torque through that CAD model (so the executed motion is not the designed one);
its encoders, star tracker and gyros are logged; the log is read as a recording
(:func:`spaceid.twin.servicer_log`: joint rates differentiated from the encoders, the base rate
from the gyros) and the minimal parameters identified from all its samples, with the CAD model as
the prior (the lab's knowledge: the data set the directions they determine, the prior the
others) or from the data alone. Then the arm is
set at the start of a second, different motion (the held-out motion: the start of a second
design, seed + 1;
the repositioning is not flown: the base keeps its attitude and the momentum, the joints start
at rest) and flown; the identified model and the
CAD prior each predict the base attitude from its measured joint motion and the measured start
attitude, and their attitude errors against the measured attitude are compared. The report
scores the identification against the twin's truth: the large parameters' z-scores (error /
standard error) and the held-out attitude errors.
"""

from __future__ import annotations

import inspect
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from .._errors import SpaceidError, finite_array
from ..data import Log, write_json, write_log
from ..dynamics import angular_momentum, minimal_parameters
from ..estimation import ESTIMATORS, Identification, identify
from ..motion import FourierTrajectory, design_excitation, hermite_motion, load_trajectory, simulate
from ..twin import ServicerSettings, ServicerState, cad_model, run_servicer, servicer_log, servicer_model
from ._validate import attitude_error_angle

__all__ = ["SpatialExperimentResult", "run_spatial_experiment", "large_parameters", "coverage"]

INITIAL_RATE = (0.01, -0.02, 0.015)
"""The base rate [rad/s] (base axes) at the start, the joints at rest on the excitation's start:
the momentum it gives is the default ``momentum`` of :func:`run_spatial_experiment`."""

LARGE = 1e-3
"""A parameter is large when its contribution to the momentum over the log (the RMS of its
regressor column times its true value) is at least this fraction of the largest contribution."""


@dataclass(frozen=True)
class SpatialExperimentResult:
    """Outcome of :func:`run_spatial_experiment`.

    Attributes
    ----------
    ident : Identification
        From all samples of the excitation (with the CAD prior unless ``prior=False``).
    true, prior : ndarray of shape (k,)
        The twin's minimal parameters and the CAD model's.
    log, validation_log : Log
        The excitation and the held-out motion as read from the sensors (all samples).
    predicted, prior_predicted : Log or None
        The held-out motion's base as the identified model and the CAD prior predict it; None
        for a model whose locked inertia is not positive definite along the motion (no rigid
        body has it: ``metrics["not predicted"]`` says why).
    trajectory, validation_trajectory : FourierTrajectory
    metrics : dict
        ``coverage`` (:func:`coverage` over the large parameters), the held-out attitude
        errors of both models [rad] and their ratio, the momentum drift of both flights.
    settings : dict
        Protocol, seeds, the twin's settings.
    folder : Path or None
    """

    ident: Identification
    true: np.ndarray
    prior: np.ndarray
    log: Log
    validation_log: Log
    predicted: Log
    prior_predicted: Log
    trajectory: FourierTrajectory
    validation_trajectory: FourierTrajectory
    metrics: dict
    settings: dict
    folder: Path | None = None

    def to_dict(self) -> dict:
        return {"settings": self.settings, "true": self.true.tolist(), "prior": self.prior.tolist(),
                "estimate": self.ident.values.tolist(), "std": self.ident.std.tolist(), "metrics": self.metrics}


# ------------------------------------------------------------------ scores --------------------


def large_parameters(param, log: Log, values, threshold: float = LARGE) -> np.ndarray:
    """Indices of the parameters whose contribution to the momentum over ``log`` is at least
    ``threshold`` times the largest: the RMS over the samples and axes of ``Y[:, :, k] values[k]``
    (``Y`` the minimal regressor on the log's states), a scale a reader can judge where the
    relative error of a parameter near zero means nothing."""
    Y = param.regressor(log.q, log.qd, log.base_w)
    contribution = np.sqrt(np.mean(Y**2, axis=(0, 1))) * np.abs(values)
    return np.flatnonzero(contribution >= threshold * contribution.max())


def coverage(result: Identification, true, large) -> dict:
    """The z-scores ``(estimate - true) / std`` of the parameters ``large``: the fraction within
    2, the largest ``|z|`` and its parameter, the root mean square of z (1 for honest standard
    errors), and the root mean square of the error whitened by the covariance of ``large`` (on its
    support): 1 for an honest covariance whatever the correlations that make the z of one run
    move together (a single run's RMS z can then be far from 1 either way)."""
    error = result.values[large] - true[large]
    z = error / result.std[large]
    worst = int(np.argmax(np.abs(z)))
    w, v = np.linalg.eigh(result.cov[np.ix_(large, large)])
    keep = w > 1e-12 * w.max()
    return {"n_large": len(large), "within_2_sigma": float(np.mean(np.abs(z) <= 2)),
            "max_abs_z": float(np.abs(z[worst])), "worst": result.names[large[worst]],
            "rms_z": float(np.sqrt(np.mean(z**2))),
            "whitened_rms": float(np.sqrt(np.mean((v[:, keep].T @ error / np.sqrt(w[keep])) ** 2)))}  # fmt: skip


def _attitude_errors(measured: Log, predicted: Log) -> dict:
    """The attitude error angle [rad] over the motion: at the end, largest, RMS."""
    e = attitude_error_angle(predicted.base_quat, measured.base_quat)
    return {"end": float(e[-1]), "max": float(e.max()), "rms": float(np.sqrt(np.mean(e**2)))}


# ------------------------------------------------------------------ the protocol --------------


def _designed(spec, prior_param, *, duration, harmonics, samples, seed, time_budget, max_steps, momentum, limits,
              progress):
    """The excitation: ``spec`` a FourierTrajectory or a file from ``design``, or ``"designed"``
    (with the lab's model ``prior_param``, the ``momentum``, the model's joint limits or ``limits``,
    ``time_budget`` [s] of wall time or ``max_steps`` steps of the search)."""
    if isinstance(spec, FourierTrajectory):
        return spec
    if str(spec) != "designed":
        return load_trajectory(spec, joints=prior_param.model.joints)
    return design_excitation(prior_param, duration=duration, harmonics=harmonics, samples=samples,
                             momentum=momentum, seed=seed, progress=progress, time_budget=time_budget,
                             max_steps=max_steps, **(limits or {})).trajectory  # fmt: skip


def _locked_inertia_check(param, pi, log: Log) -> str:
    """Empty when the system's locked inertia (3, 3) of the parameters ``pi``, the momentum of
    the base turning at a unit rate with the joints at rest, ``Y(q, 0, e_i) pi``, is positive
    definite at every 10th sample of ``log``; otherwise why not (a model no rigid body has, whose
    simulation would blow up or crawl)."""
    q = log.q[::10]
    zero = np.zeros_like(q)
    inertia = np.stack([param.regressor(q, zero, np.broadcast_to(e, (len(q), 3))) @ pi for e in np.eye(3)], -1)
    smallest = np.linalg.eigvalsh((inertia + np.swapaxes(inertia, -1, -2)) / 2)[:, 0]
    worst = int(np.argmin(smallest))
    if smallest[worst] > 0:
        return ""
    return (f"its locked inertia is not positive definite along the held-out motion (smallest eigenvalue "
            f"{smallest[worst]:.3g} kg m^2 at t = {log.t[::10][worst]:.4g} s): no rigid body has it, no prediction")


def _predictions(param, values: dict, held: Log, momentum) -> tuple:
    """Each model's (``values``: label -> minimal parameters) base motion over the held-out
    joint motion, from the measured start attitude, with the known ``momentum`` (3,) [N m s]:
    ``(predicted, refused)``, ``refused`` the models not simulated and why."""
    motion = hermite_motion(held.t, held.q, held.qd)
    predicted, refused = {}, {}
    for label, pi in values.items():
        refused[label] = _locked_inertia_check(param, pi, held)
        if not refused[label]:
            predicted[label] = simulate(param, pi, motion, held.t, momentum, initial_quat=held.base_quat[0])
    return predicted, {k: v for k, v in refused.items() if v}


def _check_identify_options(options) -> dict:
    """``identify_options`` as keywords of :func:`spaceid.estimation.identify` (the protocol
    sets the parameters, log, momentum, estimator, source and prior itself)."""
    options = dict(options or {})
    accepted = set(inspect.signature(identify).parameters) - {"param", "log", "momentum", "estimator", "where", "prior"}
    unknown = sorted(set(options) - accepted)
    if unknown:
        raise SpaceidError(f"`identify_options`: {', '.join(unknown)} is not an option of identify (options: "
                           f"{', '.join(sorted(accepted))})")  # fmt: skip
    return options


def run_spatial_experiment(
    *,
    settings: ServicerSettings | None = None,
    trajectory="designed",
    duration: float = 120.0,
    validation_duration: float = 60.0,
    harmonics: int = 12,
    samples: int = 600,
    time_budget: float | None = 30.0,
    max_steps: int | None = None,
    limits: dict | None = None,
    momentum=None,
    estimator: str = "ml",
    prior: bool = True,
    base_rate: str = "gyro",
    identify_options: dict | None = None,
    seed: int = 0,
    out=None,
    out_name=None,
    progress=None,
) -> SpatialExperimentResult:
    """Design, fly, identify and predict a held-out motion on the servicer twin.

    Parameters
    ----------
    settings : ServicerSettings, optional
        The twin (default: the dual-arm servicer, its sensors and a 15 %-off CAD model).
    trajectory : "designed" or path or FourierTrajectory
        The excitation; ``designed`` (default): designed with the CAD model (min cond(Y),
        ``duration``, ``harmonics``, ``samples``, seed ``seed``, at most ``time_budget`` or
        ``max_steps``).
    duration, validation_duration : float
        Lengths of the designed excitation and of the held-out motion [s].
    harmonics, samples : int
        The design's harmonics and N, the samples it optimises the regressor's condition at
        (identification uses every sample of the log).
    time_budget : float or None
        Wall time of each design's search [s] (the held-out motion's: a third of it); None: no
        wall-clock limit.
    max_steps : int, optional
        Each design's budget in linearisations of the regressor
        (:func:`spaceid.motion.design_excitation`): a design that does not depend on the
        machine's speed.
    limits : dict, optional
        ``q_max``, ``qd_max``, ``qdd_max`` for the designs where the model has none or to
        override its limits (as :func:`spaceid.motion.design_excitation` takes them).
    momentum : array_like of shape (3,), optional
        The system's angular momentum [N m s] (inertial axes, the base starting at identity),
        known to the lab: the scale anchor (at zero momentum the minimal parameters of a servicer
        without momentum wheels are fixed only up to a common factor). Default: the momentum of
        the twin turning at :data:`INITIAL_RATE` with the joints at rest at the excitation's start.
    estimator : str
        See :func:`spaceid.estimation.identify`.
    prior : bool
        Identify with the CAD model as the prior (``identify(prior=...)``, a maximum a posteriori
        estimate over physically consistent models; ``identify_options`` may give ``prior_std``);
        False: from the data alone, where the directions the data do not determine are reported
        and their standard errors widened, and an estimate no rigid body has is not predicted.
    base_rate : {"gyro", "attitude"}
        The base rate identification uses: the gyros' or the star tracker's attitude
        differentiated.
    identify_options : dict, optional
        Further keywords of :func:`spaceid.estimation.identify` (e.g. ``noise``, ``known``).
    seed : int
        Seeds the design (seed), the held-out design (seed + 1), the excitation's flight
        (seed + 2) and the held-out flight (seed + 3); the CAD model's errors are
        ``settings.control.model_seed``.
    out : path-like, optional
        Report folder: trajectories, logs, truths, result, ``experiment.json``, figures and
        ``report.md``.
    out_name : path-like, optional
        The report folder as records name it (default ``out``).
    progress : callable, optional
        ``progress(done, total)`` of the designs.

    Returns
    -------
    SpatialExperimentResult
    """
    settings = ServicerSettings() if settings is None else settings
    if not isinstance(settings, ServicerSettings):
        raise SpaceidError(f"`settings` must be a ServicerSettings(...), got {type(settings).__name__}")
    if estimator not in ESTIMATORS:
        raise SpaceidError(f"`estimator`: {estimator!r} is not one of {', '.join(ESTIMATORS)}")
    options = _check_identify_options(identify_options)
    model = servicer_model(settings.model)
    param, cad = minimal_parameters(model), cad_model(settings)
    prior_param = minimal_parameters(cad)
    h = None if momentum is None else finite_array(momentum, (3,), "`momentum` [N m s]", "experiment")
    design = {"harmonics": int(harmonics), "samples": int(samples), "limits": limits, "progress": progress,
              "max_steps": max_steps}
    zero_rate = h if h is not None else angular_momentum(cad, np.zeros(len(model.joints)), np.zeros(len(model.joints)),
                                                          np.asarray(INITIAL_RATE))  # the lab's guess, to design
    traj = _designed(trajectory, prior_param, duration=duration, seed=seed, time_budget=time_budget, momentum=zero_rate,
                     **design)  # fmt: skip
    # the held-out motion: the start of a second design as long as the excitation (a shorter one
    # may not move the servicer's joints enough for the design's full-rank check)
    vtraj = _designed("designed", prior_param, duration=max(traj.duration, validation_duration), seed=seed + 1,
                      time_budget=None if time_budget is None else time_budget / 3, momentum=zero_rate, **design)  # fmt: skip
    if h is None:
        q0 = traj.evaluate(np.zeros(1))[0][0]
        h = angular_momentum(model, q0[[traj.joints.index(j) for j in model.joints]], np.zeros(len(q0)),
                             np.asarray(INITIAL_RATE))  # fmt: skip

    flight = run_servicer(traj, duration=traj.duration, settings=settings, seed=seed + 2,
                          state=ServicerState(momentum=h))
    start = flight.state
    held_run = run_servicer(vtraj, duration=validation_duration, settings=settings, seed=seed + 3,
                            state=ServicerState(t=start.t, base_quat=start.base_quat, momentum=h,
                                                base_position=start.base_position, gyro_walk=start.gyro_walk))
    log, held = (servicer_log(r, settings, base_rate=base_rate) for r in (flight, held_run))
    where = str(Path(out_name if out_name is not None else out or ".") / "log.csv")
    ident = identify(param, log, h, estimator=estimator, where=where, **({"prior": cad} if prior else {}), **options)
    true, cad_values = param.true_values, prior_param.true_values
    predicted, refused = _predictions(param, {"identified": ident.values, "CAD prior": cad_values}, held, h)
    large = large_parameters(param, log, true)
    errors = {label: _attitude_errors(held, predicted[label]) if label in predicted else None
              for label in ("identified", "CAD prior")}  # fmt: skip
    metrics = {
        "coverage": coverage(ident, true, large),
        "held-out attitude error, identified [rad]": errors["identified"],
        "held-out attitude error, CAD prior [rad]": errors["CAD prior"],
        "CAD prior / identified, largest attitude error": errors["CAD prior"]["max"] / errors["identified"]["max"]
        if None not in errors.values() else None,
        "not predicted": refused,
        "momentum drift, excitation and held-out flights [N m s]": [flight.meta["momentum_drift"],
                                                                     held_run.meta["momentum_drift"]],
        "momentum drift relative to the joints' momentum": [flight.meta["momentum_drift_relative"],
                                                             held_run.meta["momentum_drift_relative"]],
    }  # fmt: skip
    protocol = {
        "model": model.name,
        "CAD model": (f"masses and principal moments {100 * settings.control.model_error:g} % off (seed "
                      f"{settings.control.model_seed})") if settings.control.model is None else flight.meta["cad model"],
        "trajectory": traj.meta.get("name", "designed" if trajectory == "designed" else str(trajectory)),
        "duration [s]": traj.duration, "held-out duration [s]": validation_duration,
        "held-out motion": f"the first {validation_duration:g} s of a design of {vtraj.duration:g} s (seed {seed + 1})", "harmonics": int(harmonics),
        "design time budget [s]": time_budget, "design steps": max_steps, "samples (N, design)": int(samples),
        "samples (identification)": int(log.n_samples), "momentum (known) [N m s]": h.tolist(), "estimator": estimator,
        "prior": "the CAD model" if prior else "none (the data alone)", "base rate": base_rate, "identify options": sorted(options),
        "seed": seed, "flight seeds (excitation, held-out)": [seed + 2, seed + 3],
        "star tracker frames/lost": [flight.meta["star_tracker_frames"], flight.meta["star_tracker_dropped"]],
        "tracking RMS, truth vs reference [rad]": flight.meta["tracking_rms"],
        "cond(Y)": ident.condition_number,
    }  # fmt: skip
    result = SpatialExperimentResult(ident, true, cad_values, log, held, predicted.get("identified"),
                                     predicted.get("CAD prior"),
                                     traj, vtraj, metrics, dict(protocol, twin=settings.to_dict()),
                                     Path(out) if out is not None else None)  # fmt: skip
    if out is not None:
        _write_report(result, flight, held_run)
    return result


# ------------------------------------------------------------------ the report ----------------


def _write_report(result: SpatialExperimentResult, flight, held_run) -> None:
    """The report folder: trajectories, logs, truths, results, figures and ``report.md``."""
    from ._figures import plot_attitude_errors, plot_parameters, plot_singular_values, plot_tracking, \
        plot_validation  # fmt: skip
    from ._html_report import write_html_report
    from ._report import write_markdown_report
    from ._tracking import readable_settings

    folder = result.folder
    folder.mkdir(parents=True, exist_ok=True)
    result.trajectory.save(folder / "trajectory.json")
    result.validation_trajectory.save(folder / "validation_trajectory.json")
    for name, log in (("log", result.log), ("validation_log", result.validation_log), ("truth", flight.truth),
                      ("validation_truth", held_run.truth)):  # fmt: skip
        write_log(folder / f"{name}.csv", log)
    write_json(folder / "result.json", result.ident.to_dict())
    write_json(folder / "experiment.json", result.to_dict())
    held = result.validation_log
    t = held.t - held.t[0]
    predicted = {label: p for label, p in (("identified model", result.predicted), ("CAD prior",
                 result.prior_predicted)) if p is not None}  # fmt: skip
    figures = {}
    if predicted:
        plot_attitude_errors(t, {label: attitude_error_angle(p.base_quat, held.base_quat) for label, p in
                                 predicted.items()}, folder / "attitude.png", title="Held-out motion: predicted base "
                             "attitude against the measured one (star tracker)")  # fmt: skip
        figures["Held-out motion: attitude error of the identified model and of the CAD prior"] = "attitude.png"
    if result.predicted is not None:
        plot_validation(held, result.predicted, folder / "validation.png",
                        title="Held-out motion: measured base motion vs the identified model")
        figures["Held-out motion: measured base motion vs the identified model"] = "validation.png"
    plot_parameters(result.ident, folder / "parameters.png", true=result.true)
    plot_singular_values(result.ident, folder / "singular_values.png")
    worst = np.argsort(-np.array(list(flight.meta["tracking_rms"].values())))[:4]  # the loosest joints
    joints = [result.log.joints[j] for j in sorted(worst)]
    tlog = result.log.t - result.log.t[0]
    traj = result.trajectory
    plot_tracking(tlog, traj.evaluate(np.clip(tlog, 0, traj.duration))[0][:, [traj.joints.index(j) for j in joints]],
                  result.log.q[:, [result.log.joints.index(j) for j in joints]], joints, folder / "tracking.png",
                  title="Tracking of the excitation (the four loosest joints): computed torque "
                  "through the CAD model")  # fmt: skip
    figures |= {
        "Parameter estimates": "parameters.png",
        "Singular values of the regressor": "singular_values.png",
        "Tracking: designed (commanded) and executed (encoders)": "tracking.png",
    }
    report = dict(title="spaceid: the spatial protocol on the servicer twin", result=result.ident,
                  settings=readable_settings({k: v for k, v in result.settings.items() if k != "twin"}),
                  true=result.true, sections={"Scores against the twin's truth": _score_lines(result)})
    write_markdown_report(folder, figures=figures, **report)
    interactive = ("validation.png", "parameters.png", "singular_values.png")  # drawn by the page itself
    validations = [] if result.predicted is None else [
        (held, result.predicted, "Held-out motion: measured base motion vs the identified model")]
    write_html_report(folder, figures={c: f for c, f in figures.items() if f not in interactive},
                      validations=validations, **report)


def _score_lines(result: SpatialExperimentResult) -> list:
    """The report's scores: what set the estimate, coverage of the large parameters, held-out
    attitude errors, momentum."""
    metrics = result.metrics
    c = metrics["coverage"]
    ident, prior = metrics["held-out attitude error, identified [rad]"], metrics["held-out attitude error, CAD prior [rad]"]
    drift = metrics["momentum drift relative to the joints' momentum"]
    record = result.ident.prior
    source = ("From the data alone." if record is None else f"With the CAD model as the prior: of the "
              f"{len(record.directions)} directions of the information, the data set {record.n_data}, the prior "
              f"{record.n_prior}.")
    return [
        source,
        "",
        (f"- Large parameters (contribution to the momentum at least {LARGE:g} of the largest): {c['n_large']}; "
         f"{100 * c['within_2_sigma']:.1f} % within 2 standard errors of the truth, largest |z| {c['max_abs_z']:.3g} "
         f"(`{c['worst']}`), root-mean-square z {c['rms_z']:.3g}, whitened by their covariance {c['whitened_rms']:.3g} "
         "(honest standard errors give about 1)."),
        "",
        "| held-out attitude error [rad] | at the end | largest | RMS |",
        "|---|---|---|---|",
        *(f"| {label} | {e['end']:.3g} | {e['max']:.3g} | {e['rms']:.3g} |" if e is not None else
          f"| {label} | {metrics['not predicted'][key]} | | |"
          for label, key, e in (("identified model", "identified", ident), ("CAD prior", "CAD prior", prior))),
        "",
        (f"The CAD prior's largest attitude error is {metrics['CAD prior / identified, largest attitude error']:.3g} "
         "times the identified model's." if metrics["CAD prior / identified, largest attitude error"] else ""),
        (f"Momentum of the true states (spaceid.dynamics.angular_momentum): largest change {drift[0]:.2g} (excitation) "
         f"and {drift[1]:.2g} (held-out) of the joints' momentum."),
    ]
