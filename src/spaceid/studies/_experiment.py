"""The paper's Cepheus experiment end to end, on the digital twin (seed sections "The NTUA CSL
emulator" and "Experiment results").

Protocol: the emulator starts at rest; the reaction wheel spins up to 170 rad/s relative to the
base and settles, so the rest of the system carries ``h = I_rw w_rw`` (about 0.3355 N m s); the
arm tracks the exciting trajectory (tf = 5 s) under its PD controllers; encoders and motion
capture are recorded as a ROS bag; the bag is read back, streams aligned and rates
differentiated exactly as for a lab recording; pi is identified from N samples (the paper's 29)
and from all samples, the total momentum zero and the wheel's measured spin momentum on the
right-hand side (its rotor inertia is the scale anchor); the identified model is re-simulated
with the measured joint motion and compared with the measured base motion (Fig. 6).

The same reading, identification and validation steps are what ``spaceid identify`` and
``spaceid validate`` do with a real bag.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

from .._errors import SpaceidError
from ..data import read_bag_log, write_bag
from ..estimation import Identification, identify, resolve_anchors
from ..data import write_json, write_log
from ..models import load_model
from ..dynamics import minimal_parameters
from ..data import Log
from ..motion import FourierTrajectory, load_trajectory, sample_times
from ..twin import TwinSettings, drained_model, join_runs, run_twin, spin_up
from ._torque_validation import validate_torques
from ._validate import validate

__all__ = ["ExperimentResult", "run_experiment", "BAG_NAMES"]

BAG_NAMES = {"ros1": "run.bag", "ros2": "run_ros2", "mcap": "run.mcap"}
ARM_JOINTS = ("left_shoulder", "left_elbow")


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
        The identified model (N samples) re-simulated with the measured joint motion.
    metrics : dict
        Validation metrics (:func:`spaceid.studies.validation_metrics`), and when the bag carries
        joint efforts those of the torque level (:func:`spaceid.studies.torque_metrics`).
    trajectory : FourierTrajectory
    settings : dict
        Protocol, twin settings, seeds, bag.
    folder : Path or None
    """

    ident: Identification
    ident_all: Identification
    true: np.ndarray
    log: Log
    predicted: Log
    metrics: dict
    trajectory: FourierTrajectory
    settings: dict
    folder: Path | None = None

    def to_dict(self) -> dict:
        def errors(ident):
            return (100 * (ident.values - self.true) / np.abs(self.true)).tolist()

        return {
            "settings": self.settings,
            "true": self.true.tolist(),
            "relative_error_percent": errors(self.ident),
            "relative_error_percent_all_samples": errors(self.ident_all),
            "validation": self.metrics,
        }


def _trajectory(trajectory, *, momentum, samples, seed, progress):
    if isinstance(trajectory, FourierTrajectory):
        return trajectory
    if str(trajectory) != "designed":
        return load_trajectory(trajectory, joints=ARM_JOINTS)
    from ..motion import design_excitation

    arm = minimal_parameters(load_model("cepheus"))  # the arm with the wheel locked: what is excited
    return design_excitation(arm, duration=5.0, harmonics=3, samples=samples, momentum=[0.0, 0.0, momentum], seed=seed,
                      progress=progress).trajectory  # fmt: skip


def _nearest(t, times):
    """Indices of the samples of ``t`` nearest to ``times``, distinct."""
    idx = np.clip(np.searchsorted(t, times), 1, len(t) - 1)
    idx = np.where(np.abs(t[idx - 1] - times) <= np.abs(t[idx] - times), idx - 1, idx)
    return np.unique(idx)


def run_experiment(
    *,
    trajectory="designed",
    wheel_speed: float = 170.0,
    samples: int = 29,
    settings: TwinSettings | None = None,
    bag_format: str = "ros1",
    estimator: str = "ml",
    joint_rates: str = "differentiate",
    seed: int = 0,
    out=None,
    progress=None,
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
    joint_rates : {"differentiate", "velocity"}
        Joint rates from the encoder angles (Savitzky-Golay on the 50 Hz joint states), or the
        published velocities (one-tick encoder differences: a count per millisecond is
        1.5 rad/s on the wheel encoder, so these are far noisier).
    seed : int
        Seeds the design, the spin-up phase (seed) and the excitation phase (seed + 1).
    out : path-like, optional
        Report folder: the bag, the aligned log CSV, results, figures and ``report.md``.
    progress : callable, optional
        ``progress(done, total)`` for the design.

    Returns
    -------
    ExperimentResult
    """
    if bag_format not in BAG_NAMES:
        raise SpaceidError(f"--format: '{bag_format}' is not one of {', '.join(BAG_NAMES)}")
    if int(samples) < 10:
        raise SpaceidError(f"--samples {samples}: identification of Cepheus needs at least 10 samples")
    settings = TwinSettings() if settings is None else settings
    model = load_model(settings.model) if not hasattr(settings.model, "bodies") else settings.model
    if not model.wheels:
        raise SpaceidError(f"{model.name}: the experiment needs a model with a reaction wheel (e.g. cepheus-rw)")
    param = minimal_parameters(model)
    rotor = sum(value for value, _ in resolve_anchors(param, {}, model.name).values())  # I_rw from the model (CAD)
    traj = _trajectory(trajectory, momentum=rotor * wheel_speed, samples=int(samples), seed=seed, progress=progress)

    # the twin: rest -> wheel spin-up and settling -> excitation (tf) and one second of hold
    a = spin_up(wheel_speed, settings=settings, seed=seed)
    b = run_twin(traj, duration=traj.duration + 1.0, state=a.state, settings=settings, seed=seed + 1)
    run = join_runs(a, b)
    start = a.state.t

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
    try:
        write_bag(bag, run.recording, format=bag_format)
        # the lab knows its motion-capture latency (calibrated); the pose stamps lag by it
        full = read_bag_log(bag, joints=model.joints, planar=True, wheels=model.wheels, joint_rates=joint_rates,
                            pose_latency=settings.mocap.latency)
    finally:
        if scratch is not None:
            scratch.cleanup()
    window = (full.t >= start - 1e-9) & (full.t <= start + traj.duration + 1e-9)
    log = full.select(window)
    log = replace(log, meta=dict(full.meta, window=[start, start + traj.duration]))
    chosen = _nearest(log.t, start + sample_times(traj.duration, int(samples)))
    zero = np.zeros(3)  # started at rest: the whole system, wheel included, carries no momentum
    ident = identify(param, log.select(chosen), zero, estimator=estimator, where=str(bag))
    ident_all = identify(param, log, zero, estimator=estimator, where=str(bag))
    predicted, metrics = validate(ident, log, momentum=zero, where=str(bag))
    if log.tau is not None:  # the twin's joint efforts: the torque level beside, restarted every second
        try:
            metrics |= validate_torques(ident, log, horizon=1.0, momentum=zero, where=str(bag))[1]
        except SpaceidError as exc:  # an inconsistent identified model (H* not positive definite)
            metrics["torque_validation"] = str(exc)
    # the truth is the twin's model when the excitation starts: the CO2 tank may have drained
    drained = settings.tank.enabled and a.state.co2_mass is not None
    true = minimal_parameters(drained_model(model, settings.tank, a.state.co2_mass)).true_values if drained \
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
        "bag": f"{BAG_NAMES[bag_format]} ({bag_format})",
        "seed": seed,
        "co2 mass start/end [kg]": [run.meta["co2_mass_start"], run.meta["co2_mass_end"]],
        "mocap frames/dropped": [run.meta["mocap_frames"], run.meta["mocap_dropped"]],
    }
    result = ExperimentResult(ident, ident_all, true, log, predicted, metrics, traj,
                              dict(protocol, twin=settings.to_dict()), folder)  # fmt: skip
    if folder is not None:
        _write_report(result, run)
    return result


def _write_report(result: ExperimentResult, run) -> None:
    from ._figures import plot_parameters, plot_singular_values, plot_validation
    from ._report import write_markdown_report

    folder = result.folder
    result.trajectory.save(folder / "trajectory.json")
    write_log(folder / "log.csv", result.log)
    write_log(folder / "truth.csv", run.truth)
    write_json(folder / "result.json", result.ident.to_dict())
    write_json(folder / "result_all_samples.json", result.ident_all.to_dict())
    write_json(folder / "experiment.json", result.to_dict())
    figures = {
        "Validation: measured (twin, from the bag) vs identified model (N samples)": "validation.png",
        "Parameter estimates (N samples)": "parameters.png",
        "Singular values of the regressor (N samples)": "singular_values.png",
    }
    plot_validation(result.log, result.predicted, folder / figures[next(iter(figures))])
    plot_parameters(result.ident, folder / "parameters.png", true=result.true)
    plot_singular_values(result.ident, folder / "singular_values.png")
    worst_all = float(np.max(np.abs(result.ident_all.values - result.true) / np.abs(result.true))) * 100
    settings = {k: v for k, v in result.settings.items() if k != "twin"}
    settings["worst relative error, all samples [%]"] = round(worst_all, 4)
    effects = {k: v.get("enabled") for k, v in result.settings["twin"].items() if isinstance(v, dict) and "enabled" in v}
    settings["twin effects"] = ", ".join(f"{k} {'on' if on else 'off'}" for k, on in effects.items())
    write_markdown_report(
        folder, title="spaceid: the Cepheus experiment on the digital twin", ident=result.ident, settings=settings,
        figures=figures, true=result.true, metrics=result.metrics,
    )
