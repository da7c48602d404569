"""The paper's Cepheus experiment end to end, on the digital twin (seed sections "The NTUA CSL
emulator" and "Experiment results").

Protocol: the emulator starts at rest; the reaction wheel spins up to 170 rad/s relative to the
base and settles, so the rest of the system carries ``h = I_rw w_rw`` (about 0.3355 N m s); the
arm tracks the exciting trajectory (tf = 5 s) under its PD controllers; encoders and motion
capture are recorded as a ROS bag; the bag is read back, streams aligned and rates
differentiated exactly as for a lab recording; pi is identified from N samples (the paper's 29)
and from all samples, the total momentum zero and the wheel's measured spin momentum on the
right-hand side (its rotor inertia is the scale anchor). Then, from the state the excitation left,
the arm tracks a second, different trajectory (the held-out motion; by default the paper's
Table 2 trajectory, or a designed one when identification used that): the identified model is
re-simulated with its measured joint motion and compared with the measured base motion
(Fig. 6). Validation on the fitting motion checks only the fit (a model 36 % off fitted its own
log to 0.05 %), so its metrics are kept only as a labelled comparison.

By default the arm's PD loops get a feed-forward planned from the prior model, and rehearsals
can refine the reference, so that the executed motion is the designed one
(:mod:`~spaceid.studies._tracking`); the settings record the tracking error and cond(Y) of the
designed and of the executed motion.

The same reading, identification and validation steps are what ``spaceid identify`` and
``spaceid validate`` do with a real bag.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

from .._atomic import write_text_atomic
from .._errors import SpaceidError
from ..data import JOINT_RATE_POLICY, Log, read_bag_log, write_bag, write_json, write_log
from ..dynamics import minimal_parameters
from ..estimation import Identification, identify, resolve_anchors
from ..identified import HOLD
from ..models import load_model
from ..motion import FourierTrajectory, load_trajectory, sample_times
from ..twin import TwinSettings, drained_model, join_runs, run_twin
from ._tracking import (check_rehearsals, designed_condition_numbers, execute_excitation, readable_settings,
                        regressor_condition_number)
from ._servicing import CaptureProtocol, ServicingResult, initial_momentum, run_servicing, write_servicing
from ._torque_validation import validate_torques
from ._validate import validate

__all__ = ["ExperimentResult", "run_experiment", "BAG_NAMES"]

BAG_NAMES = {"ros1": "run.bag", "ros2": "run_ros2", "mcap": "run.mcap"}
ARM_JOINTS = ("left_shoulder", "left_elbow")
# the drift terms identified by default while the table's air-bearing friction acts (benchmarks/bench_experiment.py)
EXPERIMENT_DRIFT = ("viscous",)


@dataclass(frozen=True)
class ExperimentResult:
    """Outcome of :func:`run_experiment`.

    Attributes
    ----------
    ident, ident_all : Identification
        From ``samples`` samples of the excitation, and from all of them.
    true : ndarray of shape (k,)
        The twin's parameters at the start of the excitation.
    log : Log
        The excitation as read back from the bag (all samples).
    predicted : Log
        The identified model (N samples) re-simulated with the held-out motion's measured joints.
    metrics : dict
        Validation metrics on the held-out motion (:func:`spaceid.studies.validation_metrics`)., and when the bag
        carries joint efforts those of the torque level (:func:`spaceid.studies.torque_metrics`).
    trajectory : FourierTrajectory
        The identification excitation.
    validation_log : Log
        The held-out motion as read back from the bag (all its samples).
    validation_trajectory : FourierTrajectory
    fit_metrics : dict
        The same metrics on the fitting log ``log``: they check the fit, not the model.
    settings : dict
        Protocol, twin settings, seeds, bag.
    folder : Path or None
    servicing : ServicingResult or None
        With ``capture``: the grasp, change detection and payload identification
        (:mod:`~spaceid.studies._servicing`).
    """

    ident: Identification
    ident_all: Identification
    true: np.ndarray
    log: Log
    predicted: Log
    metrics: dict
    trajectory: FourierTrajectory
    validation_log: Log
    validation_trajectory: FourierTrajectory
    fit_metrics: dict
    settings: dict
    folder: Path | None = None
    servicing: ServicingResult | None = None

    def to_dict(self) -> dict:
        def errors(ident):
            return (100 * (ident.values - self.true) / np.abs(self.true)).tolist()

        return {
            "settings": self.settings,
            "true": self.true.tolist(),
            "relative_error_percent": errors(self.ident),
            "relative_error_percent_all_samples": errors(self.ident_all),
            "validation": self.metrics,
            "validation_fit_log": self.fit_metrics,
        } | ({} if self.servicing is None else {"capture": self.servicing.scores.to_dict()})


def _trajectory(trajectory, *, momentum, samples, seed, progress):
    if isinstance(trajectory, FourierTrajectory):
        return trajectory
    if str(trajectory) != "designed":
        return load_trajectory(trajectory, joints=ARM_JOINTS)
    from ..motion import design_excitation

    arm = minimal_parameters(load_model("cepheus"))  # the arm with the wheel locked: what is excited
    return design_excitation(arm, duration=5.0, harmonics=3, samples=samples, momentum=[0.0, 0.0, momentum], seed=seed,
                      progress=progress).trajectory  # fmt: skip


def _validation_trajectory(validation, identification: FourierTrajectory, *, momentum, samples, seed, progress):
    """The held-out excitation: ``validation`` as :func:`_trajectory` takes it (designed with
    seed ``seed + 1``); by default the paper's Table 2 trajectory, or a designed one when the
    identification excitation is that. Never the identification excitation itself.

    Returns ``(trajectory, name)``, the name as the settings record it."""
    if validation is None:
        validation = "designed" if identification.meta.get("name") == "paper-table2" else "paper-table2"
    traj = _trajectory(validation, momentum=momentum, samples=samples, seed=seed + 1, progress=progress)
    if traj == identification:
        raise SpaceidError(f"`validation` {validation!r}: it is the identification trajectory, and validation on the "
                           "fitting motion cannot fail: choose a different motion")  # fmt: skip
    return traj, traj.meta.get("name", str(validation))


def _excitation(full: Log, start: float, duration: float) -> Log:
    """The samples of ``full`` in ``[start, start + duration]`` [s], the window in its meta."""
    window = (full.t >= start - 1e-9) & (full.t <= start + duration + 1e-9)
    return replace(full.select(window), meta=dict(full.meta, window=[start, start + duration]))


def _held_out_log(run, traj: FourierTrajectory, folder: Path, bag_format: str, model, settings, joint_rates,
                  name: Path) -> Log:
    """The held-out phase ``run`` recorded as a second bag in ``folder`` (``validation.bag``, ...:
    a recording of its own, so that reading it leaves the identification bag's differentiation
    as it was), read back as the excitation's (its source named in ``name``) and cut to ``traj``'s
    window."""
    bag = folder / BAG_NAMES[bag_format].replace("run", "validation", 1)
    write_bag(bag, run.recording, format=bag_format)
    full = _read_bag(bag, model, settings, joint_rates, name / bag.name)
    start = run.truth.t[0] - full.meta["time_origin_ns"] / 1e9  # the reader's times start at a whole second
    return _excitation(full, start, traj.duration)


def _read_bag(bag: Path, model, settings: TwinSettings, joint_rates: str, source: Path) -> Log:
    """A bag of the twin read as a lab recording, whole, its source recorded as ``source``;
    ``spaceid identify BAG --mapping mapping.yaml`` reads it the same way (:func:`_write_mapping`)."""
    # the lab knows its motion-capture latency (calibrated); the pose stamps lag by it
    log = read_bag_log(bag, joints=model.joints, planar=True, wheels=model.wheels, joint_rates=joint_rates,
                       pose_latency=settings.mocap.latency)
    log.meta["source"] = str(source)
    return log


def _held_out_validation(ident: Identification, log: Log, held_out: Log, momentum, where: str) -> tuple:
    """``(predicted, metrics, fit_metrics)``: ``ident`` re-simulated on the held-out motion and
    compared with it, and the same metrics on the fitting window ``log`` (the check of the fit).

    ``momentum`` None (drift terms identified): the fitting window starts from the identified
    momentum, the held-out motion, later, from the identified model's momentum over its first
    samples (friction changed it in between)."""
    start = momentum if momentum is not None or not ident.drift else initial_momentum(ident, held_out)
    check = validate(ident, held_out, momentum=start, where=f"{where} (held-out motion)")
    fit_metrics = validate(ident, log, momentum=momentum, where=f"{where} (fitting window)").metrics
    return check.predicted, check.metrics, fit_metrics


def _held_out_seed(seed: int, rehearsals: int) -> int:
    """The seed of the held-out phase: after those of the excitation's phases and rehearsals."""
    return seed + 3 + rehearsals


def _validation_protocol(traj: FourierTrajectory, name: str, held_out: Log, phase_seed: int) -> dict:
    """The held-out motion's entries of the experiment's settings: trajectory, design seed, window
    (in the session's time, as the excitation window; the bag's own times start at a whole
    second), seeds."""
    origin = held_out.meta["time_origin_ns"] / 1e9
    return {
        "validation trajectory": name,
        "validation trajectory seed": traj.meta.get("seed"),
        "validation bag": Path(held_out.meta["source"]).name,
        "validation window [s]": [float(t + origin) for t in held_out.meta["window"]],
        "validation samples": int(held_out.n_samples),
        "validation phase seed": phase_seed,
    }


def _nearest(t, times):
    """Indices of the samples of ``t`` nearest to ``times``, distinct."""
    idx = np.clip(np.searchsorted(t, times), 1, len(t) - 1)
    idx = np.where(np.abs(t[idx - 1] - times) <= np.abs(t[idx] - times), idx - 1, idx)
    return np.unique(idx)


def _experiment_drift(drift, settings: TwinSettings) -> tuple:
    """The drift kinds the experiment identifies: ``drift`` as given, or for None
    ``EXPERIMENT_DRIFT`` while the twin's air-bearing friction acts and none without it."""
    if drift is not None:
        return tuple(drift)
    return EXPERIMENT_DRIFT if settings.bearing_friction.enabled else ()


def run_experiment(
    *,
    trajectory="designed",
    wheel_speed: float = 170.0,
    samples: int = 29,
    settings: TwinSettings | None = None,
    bag_format: str = "ros1",
    estimator: str = "ml",
    joint_rates: str = JOINT_RATE_POLICY,
    validation=None,
    seed: int = 0,
    out=None,
    out_name=None,
    progress=None,
    drift=None,
    feedforward: bool = True,
    rehearsals: int = 0,
    capture: CaptureProtocol | None = None,
    capture_trajectory="same",
) -> ExperimentResult:
    """Rehearse the Cepheus identification experiment on the twin.

    Parameters
    ----------
    trajectory : {"designed", "paper-table2"} or path or FourierTrajectory
        Arm excitation; ``designed``: min cond(Y) for the arm with the momentum the wheel
        leaves it, ``samples`` samples, seeded.
    wheel_speed : float
        Wheel speed relative to the base [rad/s].
    samples : int
        N, the samples identification uses (equally spaced over the excitation).
    settings : TwinSettings, optional
        The twin (default: every effect on, as on the real table).
    bag_format : {"ros1", "ros2", "mcap"}
    estimator : str
        See :func:`spaceid.estimation.identify`.
    joint_rates : {"differentiate", "velocity", "auto"}
        Joint rates from the encoder angles (Savitzky-Golay on the 50 Hz joint states; the
        default of every bag reader, :data:`spaceid.data.JOINT_RATE_POLICY`), or the published
        velocities (one-tick encoder differences: a count per millisecond is 1.5 rad/s on the
        wheel encoder, so these are far noisier).
    validation : {"designed", "paper-table2"} or path or FourierTrajectory, optional
        The held-out motion, run after the excitation and its hold; default ``paper-table2``,
        or ``designed`` (seed + 1) when ``trajectory`` is that.
    seed : int
        Seeds the design, the spin-up phase (seed), the excitation phase (seed + 1), the hold
        at the start pose (seed + 2), rehearsal k (seed + 3 + k), the validation design
        (seed + 1), the held-out phase (seed + 3 + rehearsals), and with ``capture`` the
        post-capture design (seed + 2) and phase (seed + 4 + rehearsals).
    out : path-like, optional
        Report folder: the bags of the excitation and of the held-out motion (``validation.bag``,
        ...), ``mapping.yaml`` (how to read them), the aligned log CSVs, results, figures and
        ``report.md``.
    out_name : path-like, optional
        The report folder as messages and records name it (the bags' sources), default ``out``:
        the command line writes into a temporary folder that it renames to this one at the end.
    progress : callable, optional
        ``progress(done, total)`` for the design.
    drift : iterable of {"torque", "viscous", "coulomb"}, optional
        Drift terms identified with the parameters (the table's friction; see
        :func:`spaceid.estimation.identify`); None (default): ``EXPERIMENT_DRIFT`` while the
        twin's air-bearing friction is on, none without it (``--ideal``); ``()``: none.
        Friction also acts during the spin-up, so the
        drift is integrated from rest (the bag's first sample, zero momentum) to each sample of
        the window; validation uses the identified drift and momentum at the window's start.
    feedforward : bool
        Add the arm's inverse dynamics planned offline from the prior model (the nominal preset)
        to the PD loops, after holding the arm at the start pose with the planned holding
        efforts (:mod:`spaceid.studies._tracking`); False: the PD loops alone, as published.
    rehearsals : int
        Rehearsals of the excitation at most before the recorded run, each refining the arm's
        reference by what the encoders showed (iterative learning control); they stop once the
        tracking error is within 5 mrad RMS.
    capture : CaptureProtocol, optional
        After the held-out motion, grasp this payload and run the servicing sequence
        (:mod:`~spaceid.studies._servicing`): post-capture excitation, change detection over the
        recording from the held-out motion on, the payload identified and scored against the
        twin's truth; the report gains a capture section.
    capture_trajectory : {"same", "designed"} or path or FourierTrajectory
        The post-capture excitation: ``same``, the identification excitation again; ``designed``,
        designed for the payload's parameters (``design_excitation(..., payload_link=...)``,
        seed + 2); or a trajectory file.

    The settings record how the excitation was executed, the tracking error (encoders against
    the design) and cond(Y) of the designed and the executed motion at the same instants.

    Returns
    -------
    ExperimentResult
    """
    if bag_format not in BAG_NAMES:
        raise SpaceidError(f"`bag_format`: '{bag_format}' is not one of {', '.join(BAG_NAMES)}")
    if int(samples) < 10:
        raise SpaceidError(f"`samples`: {samples!r} are too few: identification of Cepheus needs at least 10")
    rehearsals = check_rehearsals(rehearsals)
    settings = TwinSettings() if settings is None else settings
    drift = _experiment_drift(drift, settings)
    model = load_model(settings.model) if not hasattr(settings.model, "bodies") else settings.model
    if not model.wheels:
        raise SpaceidError(f"{model.name}: the experiment needs a model with a reaction wheel (e.g. cepheus-rw)")
    param = minimal_parameters(model)
    rotor = sum(value for value, _ in resolve_anchors(param, {}, model.name).values())  # I_rw from the model (CAD)
    traj = _trajectory(trajectory, momentum=rotor * wheel_speed, samples=int(samples), seed=seed, progress=progress)
    vtraj, vname = _validation_trajectory(validation, traj, momentum=rotor * wheel_speed, samples=int(samples),
                                          seed=seed, progress=progress)

    # the twin: rest -> wheel spin-up and settling (rehearsals) -> excitation (tf) and one second of hold
    phases, execution = execute_excitation(traj, settings, model, feedforward=feedforward, rehearsals=rehearsals,
                                           wheel_speed=wheel_speed, seed=seed)  # fmt: skip
    a = phases[0]
    c = run_twin(vtraj, duration=vtraj.duration + HOLD, state=phases[-1].state, settings=settings,
                 seed=_held_out_seed(seed, rehearsals))  # the held-out motion
    run = join_runs(*phases)
    start = phases[-1].truth.t[0]

    folder = Path(out) if out is not None else None
    scratch = None
    if folder is None:
        import tempfile

        scratch = tempfile.TemporaryDirectory()
        folder_bag = Path(scratch.name)
    else:
        folder.mkdir(parents=True, exist_ok=True)
        folder_bag = folder
    bag = folder_bag / BAG_NAMES[bag_format]
    named = Path(out_name) if out_name is not None and folder is not None else folder_bag
    where = str(named / bag.name)  # the bag as messages and the results name it
    try:
        write_bag(bag, run.recording, format=bag_format)
        full = _read_bag(bag, model, settings, joint_rates, named / bag.name)
        held_out = _held_out_log(c, vtraj, folder_bag, bag_format, model, settings, joint_rates, named)
        log = _excitation(full, start, traj.duration)
        chosen = _nearest(log.t, start + sample_times(traj.duration, int(samples)))
        zero = np.zeros(3)  # started at rest: the whole system, wheel included, carries no momentum
        rest = full.select(full.t <= start + traj.duration + 1e-9) if drift else None  # friction acts from rest on
        ident = identify(param, log.select(chosen), zero, estimator=estimator, where=where, drift=drift, history=rest)
        ident_all = identify(param, log, zero, estimator=estimator, where=where, drift=drift, history=rest)
        servicing = None if capture is None else _servicing_phase(
            capture, capture_trajectory, c, traj, ident_all, settings=settings, model=model, drift=drift,
            read_bag=lambda path: _read_bag(path, model, settings, joint_rates, named / path.name),
            bag=folder_bag / BAG_NAMES[bag_format].replace("run", "capture", 1), momentum=rotor * wheel_speed,
            samples=int(samples), seed=seed, rehearsals=rehearsals, progress=progress)  # fmt: skip
    finally:
        if scratch is not None:
            scratch.cleanup()
    predicted, metrics, fit_metrics = _held_out_validation(ident, log, held_out, None if drift else zero, where)
    if held_out.tau is not None:  # the twin's joint efforts: the torque level beside, restarted every second
        try:
            metrics |= validate_torques(ident, held_out, horizon=1.0, where=where,
                                        momentum=initial_momentum(ident, held_out) if drift else zero)[1]
        except SpaceidError as exc:  # an inconsistent identified model (H* not positive definite)
            metrics["torque_validation"] = str(exc)
    # the truth is the twin's model when the excitation starts: the CO2 tank may have drained
    drained = settings.tank.enabled and a.state.co2_mass is not None
    true = minimal_parameters(drained_model(model, settings.tank, phases[-1].co2_mass[0])).true_values if drained \
        else param.true_values
    protocol = {
        "model": model.name,
        "trajectory": traj.meta.get("name", str(trajectory)),
        "duration [s]": traj.duration,
        "wheel speed [rad/s]": wheel_speed,
        "wheel rotor inertia [kg m^2]": rotor,
        "momentum of the rest, I_rw w_rw [N m s]": rotor * wheel_speed,
        "excitation window [s]": [start, start + traj.duration],
        "samples (N)": int(len(chosen)),
        "samples (all)": int(log.n_samples),
        "estimator": estimator,
        "drift terms": ", ".join(drift) or "none",
        "bag": f"{BAG_NAMES[bag_format]} ({bag_format})",
        "seed": seed,
        "co2 mass start/end [kg]": [run.meta["co2_mass_start"], run.meta["co2_mass_end"]],
        "mocap frames/dropped": [run.meta["mocap_frames"], run.meta["mocap_dropped"]],
        "joint rates": joint_rates,
        **_execution_record(execution, param, traj, log, chosen, start, (ident, ident_all), wheel_speed),
    }
    protocol |= _validation_protocol(vtraj, vname, held_out, _held_out_seed(seed, rehearsals))
    if capture is not None:
        protocol |= _capture_record(capture, servicing, capture_trajectory, bag_format)
    result = ExperimentResult(ident, ident_all, true, log, predicted, metrics, traj, held_out, vtraj, fit_metrics,
                              dict(protocol, twin=settings.to_dict()), folder, servicing)  # fmt: skip
    if folder is not None:
        _write_report(result, run, c)
    return result


def _servicing_phase(capture: CaptureProtocol, choice, held_out_run, traj: FourierTrajectory, before: Identification,
                     *, settings, model, drift, read_bag, bag: Path, momentum, samples, seed, rehearsals, progress):
    """The servicing sequence of ``run_experiment(capture=...)`` after the held-out run
    (:func:`~spaceid.studies._servicing.run_servicing`): the post-capture excitation ``choice``
    (:func:`_capture_trajectory`), the phase seeded ``seed + 4 + rehearsals``."""
    trajectory = _capture_trajectory(choice, traj, capture, momentum=momentum, samples=samples, seed=seed,
                                     progress=progress)  # fmt: skip
    return run_servicing(held_out_run, capture, trajectory, settings=settings, model=model, before=before,
                         read_bag=read_bag, bag=bag, drift=drift, seed=seed + 4 + rehearsals)  # fmt: skip


def _capture_trajectory(choice, traj: FourierTrajectory, capture: CaptureProtocol, *, momentum, samples, seed,
                        progress) -> FourierTrajectory:
    """The post-capture excitation of ``run_experiment(capture_trajectory=choice)``."""
    if isinstance(choice, FourierTrajectory):
        return choice
    if str(choice) == "same":
        return traj
    if str(choice) != "designed":
        return load_trajectory(choice, joints=ARM_JOINTS)
    from ..motion import design_excitation

    locked = load_model("cepheus")  # the arm with the wheel locked, as for the excitation
    link = capture.payload.link or locked.bodies[-1].name  # the Capture default: the last body
    return design_excitation(minimal_parameters(locked), duration=traj.duration, harmonics=3, samples=samples,
                             momentum=[0.0, 0.0, momentum], seed=seed + 2, progress=progress,
                             payload_link=link).trajectory  # fmt: skip


def _capture_record(capture: CaptureProtocol, servicing, choice, bag_format: str) -> dict:
    """The capture's entries of the experiment's settings."""
    truth, traj = servicing.truth, servicing.trajectory
    return {
        "capture payload mass [kg]": capture.payload.mass,
        "capture payload CoM in its frame [m]": list(capture.payload.com),
        "capture payload inertia about its CoM [kg m^2]": [list(r) for r in capture.payload.inertia],
        "capture payload velocity [m/s], rate [rad/s]": [*capture.payload.velocity, capture.payload.rate],
        "capture link": truth["link"],
        "capture offset in the link [m], yaw [rad]": [*capture.offset, capture.yaw],
        "capture time (twin clock) [s]": truth["time"],
        "capture trajectory": traj.meta.get("name", str(choice) if not isinstance(choice, FourierTrajectory)
                                            else "given"),
        "capture trajectory seed": traj.meta.get("seed"),
        "capture bag": f"{BAG_NAMES[bag_format].replace('run', 'capture', 1)} ({bag_format})",
        "capture phase seed": servicing.scores.phase_seed,
        "capture payload servicer model": "the twin's (CAD) servicer, tank as at the grasp",
    }  # fmt: skip


def _execution_record(execution, param, traj, log, chosen, start, idents, wheel_speed) -> dict:
    """``execution`` (from :func:`execute_excitation`) with cond(Y) of the designed and of the
    executed motion (``idents``: from N samples and all) at the same instants, and their ratio."""
    times = [log.t[chosen] - start, log.t - start]
    designed = designed_condition_numbers(param, traj, times, wheel_speed=wheel_speed)
    executed = [i.condition_number if not i.drift else regressor_condition_number(param, part, "the executed motion")
                for i, part in zip(idents, (log.select(chosen), log))]  # fmt: skip
    record = dict(execution)
    for label, d, e in zip(("N samples", "all samples"), designed, executed):
        record[f"cond(Y) designed / executed, {label}"] = [d, e]
    record["cond(Y) executed / designed, N and all samples"] = [e / d for d, e in zip(designed, executed)]
    return record


def _plot_tracking(result: ExperimentResult, path) -> None:
    """The tracking figure of the recorded excitation: encoder angles (the bag) against the design."""
    from ._figures import plot_tracking

    traj, log = result.trajectory, result.log
    start = result.settings["excitation window [s]"][0]
    t = log.t - start
    designed = traj.evaluate(np.clip(t, 0.0, traj.duration))[0]
    executed = log.q[:, [log.joints.index(j) for j in traj.joints]]
    (d_n, e_n), ratio = result.settings["cond(Y) designed / executed, N samples"], \
        result.settings["cond(Y) executed / designed, N and all samples"][0]
    how = "feed-forward from the prior model" if result.settings["feedforward"] != "none" else "PD loops alone"
    title = (f"Tracking of the exciting trajectory: {how}, "
             f"{len(result.settings['rehearsal runs (seed, tracking RMS [rad])'])} rehearsals\n"
             f"cond(Y), N = {result.ident.n_samples}: designed {d_n:.4g}, executed {e_n:.4g} (x {ratio:.3g})")
    plot_tracking(t, designed, executed, traj.joints, path, times=log.t[_nearest(log.t, start + sample_times(
        traj.duration, result.ident.n_samples))] - start, title=title)  # fmt: skip


def _write_report(result: ExperimentResult, run, held_out_run) -> None:
    from ._figures import plot_parameters, plot_singular_values, plot_validation
    from ._html_report import write_html_report
    from ._report import write_markdown_report

    folder = result.folder
    result.trajectory.save(folder / "trajectory.json")
    result.validation_trajectory.save(folder / "validation_trajectory.json")
    write_log(folder / "log.csv", result.log)
    write_log(folder / "validation_log.csv", result.validation_log)
    _write_mapping(folder / "mapping.yaml", result.settings["twin"]["mocap"]["latency"])
    write_log(folder / "truth.csv", run.truth)
    write_log(folder / "validation_truth.csv", held_out_run.truth)
    write_json(folder / "result.json", result.ident.to_dict())
    write_json(folder / "result_all_samples.json", result.ident_all.to_dict())
    write_json(folder / "experiment.json", result.to_dict())
    figures = {
        "Validation on the held-out motion: measured (twin, from the bag) vs identified model (N samples)":
            "validation.png",
        "Parameter estimates (N samples)": "parameters.png",
        "Singular values of the regressor (N samples)": "singular_values.png",
        "Tracking: the arm as designed (commanded) and as executed (encoders, from the bag)": "tracking.png",
    }
    plot_validation(result.validation_log, result.predicted, folder / "validation.png",
                    title=f"Validation on the held-out motion ({result.settings['validation trajectory']}): "
                    "measured base motion vs the identified model")
    _plot_tracking(result, folder / "tracking.png")
    plot_parameters(result.ident, folder / "parameters.png", true=result.true)
    plot_singular_values(result.ident, folder / "singular_values.png")
    worst_all = float(np.max(np.abs(result.ident_all.values - result.true) / np.abs(result.true))) * 100
    settings = readable_settings({k: v for k, v in result.settings.items() if k != "twin"})
    settings["worst relative error, all samples [%]"] = round(worst_all, 4)
    effects = {k: v.get("enabled") for k, v in result.settings["twin"].items()
               if isinstance(v, dict) and "enabled" in v}
    settings["twin effects"] = ", ".join(f"{k} {'on' if on else 'off'}" for k, on in effects.items())
    sections = {}
    if result.servicing is not None:
        lines, capture_figures = write_servicing(folder, result.servicing)
        sections["Capture: change detection and the payload"] = lines
        figures |= capture_figures
    report = dict(title="spaceid: the Cepheus experiment on the digital twin", result=result.ident, settings=settings,
                  true=result.true, metrics=_labelled_metrics(result), sections=sections)
    write_markdown_report(folder, figures=figures, **report)
    interactive = ("validation.png", "parameters.png", "singular_values.png")  # drawn by the page itself
    write_html_report(folder, figures={c: f for c, f in figures.items() if f not in interactive},
                      validations=[(result.validation_log, result.predicted, "Validation on the held-out motion "
                                    f"({result.settings['validation trajectory']}): measured vs the identified model")],
                      **report)  # fmt: skip


def _write_mapping(path: Path, latency: float) -> None:
    """The bag's mapping file: the motion-capture latency the lab calibrated [s], which the bag
    does not carry, so that ``spaceid identify ... --mapping mapping.yaml`` reads it as here."""
    write_text_atomic(path, f"# how the experiment read its bag\npose_latency: {latency!r}\n")


def _labelled_metrics(result: ExperimentResult) -> dict:
    """The report's validation table: the held-out metrics, then the fit-log ones, each labelled."""
    from ._report import metric_label

    held_out = f"held-out motion ({result.settings['validation trajectory']})"
    rows = {f"{held_out}: {metric_label(k)}": v for k, v in result.metrics.items()}
    return rows | {f"fitting log (checks the fit, not the model): {metric_label(k)}": v
                   for k, v in result.fit_metrics.items()}  # fmt: skip
