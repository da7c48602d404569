"""The servicing sequence after the Cepheus experiment on the twin (``spaceid experiment --capture``).

After the identification excitation and the held-out motion (:mod:`~spaceid.studies._experiment`),
the end effector grasps a free-floating payload at rest on the table, at the gripper, the instant
the held-out phase ends (the arm then holds still); from that instant the arm runs a post-capture
excitation holding the payload. The held-out motion, the grasp and the post-capture excitation are
recorded as one bag (``capture.bag``, ...), read back as a lab recording; then

1. the change monitor (:class:`~spaceid.estimation.Monitor`, the servicer's minimal parameters as
   its structure, its default warm-up, the experiment's drift terms estimated in each segment
   while the table's friction acts) runs over it sample by sample and reports the change it
   detects, scored against the twin's grasp tick (an alarm raised before the grasp can show in the
   rates, the event's ``lead`` before it, is a false alarm: :func:`_split_at_grasp`). Its noise
   levels are those of the excitation's log, scaled so that the identification before fits it
   with chi2/dof = 1: the levels estimated from a log understate the error of differentiated
   rates (chi2/dof about 30 on the ideal twin), and the CUSUM's false-alarm rate holds only for
   the true levels. (The differentiated signals' errors are whitened with the raw angle noise
   that the bag reader's differentiator estimated; these levels are for the others.);
2. the payload is identified from the post-capture excitation (:func:`~spaceid.identified.identify_payload`)
   with the twin's servicer model (the CAD model with the tank as it was at the grasp): the known
   servicer of a servicing mission, and on the twin the truth, so that the z-scores against the
   payload's truth test the payload's estimate and its standard errors alone. The servicer
   identified before matches it only within its own errors, which would bias the payload by an
   amount its standard errors do not include. The window leaves out the samples whose
   differentiated rates blend the grasp, and with drift terms the momentum is the servicer's
   over the hold before the grasp; a payload that moves at the grasp adds its own, from its
   velocity and rate (:func:`_payload`, as 'spaceid payload --grasp' does it).

Only the phases from the grasp on carry the capture: the rehearsals, the excitation and the
held-out motion run on the servicer alone.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass, replace
from pathlib import Path

import numpy as np

from .._deprecation import deprecated_alias
from .._errors import SpaceidError
from .._inputs import MiB, read_input_text
from .._yaml import parse_yaml
from ..data import Log, write_bag, write_json, write_log
from ..dynamics import minimal_parameters
from ..estimation import Identification, Monitor, Noise
from ..identified import PayloadEstimate, mean_momentum, parameterization_of, payload_after_grasp, payload_units
from ..models import Model
from ..motion import FourierTrajectory
from ..twin import Capture, TwinRun, drained_model, join_runs, place_payload, run_twin

__all__ = ["CaptureProtocol", "PayloadScore", "ServicingResult", "ServicingScores", "capture_protocol",
           "run_servicing", "write_servicing"]

CAPTURE_OFFSET = (0.04, 0.0)
"""Default payload frame origin in the grasping link's frame at the grasp [m]: at the gripper."""
SETTINGS_KEYS = ("mass", "com", "inertia", "velocity", "rate", "link", "offset", "yaw")


@dataclass(frozen=True)
class CaptureProtocol:
    """What the servicer grasps and how (``spaceid experiment --capture``; docs/theory/capture.md).

    Attributes
    ----------
    payload : Capture
        The payload: mass [kg], CoM in its frame [m], inertia about the CoM [kg m^2], its velocity
        [m/s] and rate [rad/s], the grasping link; its time and pose are set at the grasp. Default
        :class:`~spaceid.twin.Capture`'s: a 0.5 kg cylinder at rest, grasped by ``link2``.
    offset : tuple of 2 floats
        Payload frame origin in the grasping link's frame at the grasp [m].
    yaw : float
        Payload frame turned from the link's axes [rad].
    """

    payload: Capture
    offset: tuple = CAPTURE_OFFSET
    yaw: float = 0.0


def capture_protocol(path=None, *, mass: float | None = None) -> CaptureProtocol:
    """The capture of a YAML/JSON settings file ``path`` (keys ``SETTINGS_KEYS``, all optional), with
    ``mass`` [kg] overriding its mass; neither: the defaults of :class:`CaptureProtocol`.

    Raises
    ------
    SpaceidError
        Not a mapping, an unknown key, or a value the twin refuses (the message names the key).
    """
    values = {}
    if path is not None:
        values = parse_yaml(read_input_text(path, "capture settings file", MiB), str(path)) or {}
        if not isinstance(values, dict):
            raise SpaceidError(f"{path}: capture settings must be a mapping of {', '.join(SETTINGS_KEYS)}")
        unknown = sorted(set(values) - set(SETTINGS_KEYS))
        if unknown:
            raise SpaceidError(f"{path}: unknown capture setting(s) {', '.join(map(str, unknown))}: use "
                               f"{', '.join(SETTINGS_KEYS)}")  # fmt: skip
    if mass is not None:
        values["mass"] = mass
    offset = values.get("offset", CAPTURE_OFFSET)
    if not (isinstance(offset, (list, tuple)) and len(offset) == 2 and all(np.isfinite(np.asarray(offset, float)))):
        raise SpaceidError(f"capture offset must be 2 finite numbers (x, y) [m], got {offset!r}")
    payload = {k: v for k, v in values.items() if k not in ("offset", "yaw")}
    return CaptureProtocol(Capture(time=0.0, **payload), tuple(float(v) for v in offset),
                           float(values.get("yaw", 0.0)))  # fmt: skip


@dataclass(frozen=True)
class PayloadScore:
    """One of the payload's parameters, estimated against the twin's truth.

    Attributes
    ----------
    name : str
        ``m``, ``cx``, ``cy``, ``cz``, ``Ixx`` ... ``Izz`` (:data:`spaceid.identified.SPATIAL_NAMES`).
    true, estimate, std : float
        [kg, m or kg m^2].
    z : float or None
        ``(estimate - true) / std``; None when the standard error is zero.
    """

    name: str
    true: float
    estimate: float
    std: float
    z: float | None

    def to_dict(self) -> dict:
        """JSON-ready: the attributes by name."""
        return asdict(self)


@dataclass(frozen=True)
class ServicingScores:
    """How the servicing went, against the twin's truth (:attr:`ServicingResult.scores`); times [s] on the
    servicing recording's clock. The report and the command line label them
    (``spaceid.studies._report.SERVICING_LABELS``).

    Attributes
    ----------
    payload : tuple of PayloadScore
        The payload's parameters against the truth.
    not_identifiable : tuple of str
        The payload's parameters the motion cannot see (planar: ``cz`` and the inertia but ``Izz``).
    grasp_time : float
        The twin's grasp instant.
    detected_change_time, detected_at : float or None
        The change time the monitor estimated for the first event that can be the grasp's, and when it
        raised the alarm; None when no event can be.
    change_time_error : float or None
        ``detected_change_time - grasp_time``.
    change_time_error_samples : float or None
        The same in samples of the recording.
    change_time_lead : float or None
        How early the differentiated rates can show the grasp (the event's ``lead``).
    alarm_time_from_grasp : float or None
        ``detected_at - grasp_time``.
    false_alarms : int
        Events raised before the grasp could show.
    events : int
        All of the monitor's events.
    monitor_drift_terms : str
        The drift terms the monitor estimated in each segment (``none``).
    sample_period : float
        The recording's median sample step.
    payload_window : tuple of 2 floats
        The first and last samples the payload was identified from.
    payload_window_start_after_grasp : float
    payload_motion : tuple of 2 lists or None
        A payload that moved at the grasp: its velocity [m/s] and rate [rad/s], inertial axes.
    momentum_before_grasp, momentum_before_grasp_std : list of 3 floats or None
        The servicer's momentum over the hold before the grasp and its standard errors [N m s] (with drift
        terms; None otherwise).
    momentum_from : float or None
        Where the drift is integrated from (None without drift terms).
    phase_seed : int or None
        The seed of the post-capture phase.
    """

    payload: tuple = ()
    not_identifiable: tuple = ()
    grasp_time: float | None = None
    detected_change_time: float | None = None
    detected_at: float | None = None
    change_time_error: float | None = None
    change_time_error_samples: float | None = None
    change_time_lead: float | None = None
    alarm_time_from_grasp: float | None = None
    false_alarms: int = 0
    events: int = 0
    monitor_drift_terms: str = "none"
    sample_period: float | None = None
    payload_window: tuple | None = None
    payload_window_start_after_grasp: float | None = None
    payload_motion: tuple | None = None
    momentum_before_grasp: list | None = None
    momentum_before_grasp_std: list | None = None
    momentum_from: float | None = None
    phase_seed: int | None = None

    def to_dict(self) -> dict:
        """JSON-ready: the attributes by name, in order (``payload`` a list of :meth:`PayloadScore.to_dict`)."""
        out = {name: getattr(self, name) for name in self.__dataclass_fields__}
        out["payload"] = [p.to_dict() for p in self.payload]
        for name in ("not_identifiable", "payload_window", "payload_motion"):
            out[name] = None if out[name] is None else [list(v) if isinstance(v, tuple) else v for v in out[name]]
        return out


@dataclass(frozen=True)
class ServicingResult:
    """Outcome of :func:`run_servicing`.

    Attributes
    ----------
    payload : PayloadEstimate
        The payload identified from the post-capture excitation.
    truth : dict
        The twin's grasp record (:mod:`spaceid.twin._capture`): grasp tick, payload in the link frame, ...
    events : dict
        The monitor's record (``EVENTS.json``).
    log : Log
        The servicing recording read back: the held-out motion, the grasp, the post-capture excitation.
    window : Log
        The post-capture excitation of ``log``, which the payload is identified from.
    trajectory : FourierTrajectory
        The post-capture excitation.
    scores : ServicingScores
        Payload estimate against truth (z-scores) and the detected change time against the grasp.
    run : TwinRun
        The post-capture phase on the twin (its ``truth`` is written beside the report).
    servicer : Model
        The known servicer the payload was identified with (the twin's model, the tank as at the grasp).
    """

    payload: PayloadEstimate
    truth: dict
    events: dict
    log: Log
    window: Log
    trajectory: FourierTrajectory
    scores: ServicingScores
    run: TwinRun
    servicer: Model

    def to_dict(self) -> dict:
        """JSON-ready: the ``scores``, the ``payload`` (its PAYLOAD.json object), the twin's grasp record
        ``truth``, the monitor's record ``events`` (EVENTS.json), the post-capture ``trajectory``, the
        ``servicer`` model's source and the ``window`` [s] of the recording the payload was identified from."""
        return {"scores": self.scores.to_dict(), "payload": self.payload.to_dict(), "truth": self.truth,
                "events": self.events, "trajectory": self.trajectory.to_dict(),
                "servicer": self.servicer.source or self.servicer.name,
                "window": [float(self.window.t[0]), float(self.window.t[-1])]}


def run_servicing(held_out_run, protocol: CaptureProtocol, trajectory: FourierTrajectory, *, settings, model,
                  before: Identification, read_bag, bag: Path, drift=(), seed: int = 0) -> ServicingResult:
    """Grasp, post-capture excitation, recording, change detection and payload identification.

    Parameters
    ----------
    held_out_run : TwinRun
        The held-out phase: the monitor's recording starts with it, and the grasp is at its end.
    protocol : CaptureProtocol
    trajectory : FourierTrajectory
        The post-capture excitation (run for its duration and one second of hold).
    settings : TwinSettings
        The twin without a capture (it is set here for the post-capture phase only).
    model : Model
        The twin's model (the servicer).
    before : Identification
        The identification before the grasp (all samples of the excitation): its noise levels,
        scaled by its chi2/dof, are the monitor's.
    read_bag : callable
        ``read_bag(path) -> Log``: how the experiment reads its bags.
    bag : Path
        Where the servicing bag is written (its format from the suffix the experiment chose).
    drift : tuple of str
        Drift terms estimated with the payload (its momentum is then estimated too) and in each of
        the monitor's segments.
    seed : int
        Seed of the post-capture phase; the minimal sets' seed.

    Returns
    -------
    ServicingResult
    """
    capture = place_payload(protocol.payload, model, held_out_run.state, offset=protocol.offset, yaw=protocol.yaw)
    run = run_twin(trajectory, duration=trajectory.duration + 1.0, state=held_out_run.state,
                   settings=replace(settings, capture=capture), seed=seed)  # fmt: skip
    truth = run.meta["capture"]
    write_bag(bag, join_runs(held_out_run, run).recording, format=_bag_format(bag))
    log = read_bag(bag)
    grasp = truth["time"] - log.meta["time_origin_ns"] / 1e9  # the reader's times start at a whole second
    events = _monitor(model, log, before, drift, seed)
    servicer = drained_model(model, settings.tank, truth["co2_mass"]) if settings.tank.enabled else model
    estimate, window, record = _payload(servicer, log, truth["link"], grasp, trajectory.duration, drift,
                                        _payload_motion(protocol.payload), seed, f"{bag} (post-capture excitation)")
    scores = ServicingScores(**_scores(estimate, truth, events, log, grasp), **record, phase_seed=seed)
    return ServicingResult(estimate, truth, events, log, window, trajectory, scores, run, servicer)


def _payload(servicer, log: Log, link: str, grasp: float, duration: float, drift, motion, seed: int,
             where: str) -> tuple:
    """The payload identified from the post-capture excitation of ``log`` (grasp at ``grasp`` [s],
    the excitation ``duration`` [s] long, the arm held still for ``identified._grasp.HOLD`` s before the grasp), as
    'spaceid payload --grasp' does it (:func:`~spaceid.identified.payload_after_grasp`).

    The servicer's momentum before the grasp: without drift terms it is zero (the system started
    at rest and nothing outside acts); with them it is the servicer's over the hold before the
    grasp, the drift integrated from there. Estimating the momentum with the payload instead
    leaves it nearly collinear with the mass (correlation 0.94 on the twin; 0.99 with drift): the
    differentiated rates' errors then bias the mass (by -1 % to -3 % on the twin, -5 % to -11 %
    with drift). A payload that moves at the grasp (``motion``: the velocity of its CoM and its
    rate, inertial axes; None at rest) adds its own momentum, a function of its parameters.

    Returns the estimate, its window of ``log`` and the record for the scores (:class:`ServicingScores`' keys).
    """
    momentum = "hold" if drift else np.zeros(3)
    cut = payload_after_grasp(servicer, log, link, grasp, momentum, payload_motion=motion, end=grasp + duration,
                              drift=drift, seed=seed, where=where)  # fmt: skip
    estimate, window, g = cut.estimate, cut.window, cut.grasp
    record = {"payload_window": tuple(g["window"]),
              "payload_window_start_after_grasp": g["window_start_after_grasp"],
              "payload_motion": None if motion is None else tuple(v.tolist() for v in motion),
              "momentum_before_grasp": None if g["hold"] is None else g["hold"]["momentum"],
              "momentum_before_grasp_std": None if g["hold"] is None else g["hold"]["momentum_std"],
              "momentum_from": None if g["hold"] is None else g["hold"]["drift_from"]}  # fmt: skip
    return estimate, window, record


def _payload_motion(payload) -> tuple | None:
    """The velocity [m/s] and rate [rad/s] (inertial axes, each (3,)) of the twin's payload
    :class:`~spaceid.twin.Capture` before the grasp; None when it is at rest."""
    if not (np.any(payload.velocity) or payload.rate):
        return None
    return np.array([*payload.velocity, 0.0]), np.array([0.0, 0.0, payload.rate])


def _bag_format(bag: Path) -> str:
    return {".bag": "ros1", ".mcap": "mcap"}.get(bag.suffix, "ros2")


def _monitor(model, log: Log, before: Identification, drift, seed: int) -> dict:
    """The monitor's record over ``log``, the structure of the servicer before the grasp, the noise
    levels of ``before`` scaled to its chi2/dof = 1 (the equation-error covariance is quadratic in
    them). Its default warm-up (200 samples, 4 s at the bag's 50 Hz): after 2 s of the held-out
    motion the estimate was off by several times its standard errors on the twin, and the first
    tested samples raised false alarms (docs/theory/capture.md).

    The momentum is zero without ``drift`` (the system started at rest, the wheel measured). With
    it, the table's friction has moved it since: its value at the log's first samples by the model
    identified before (as the experiment's validation takes it), and each segment's drift
    coefficients estimated with its parameters (without them the friction raised 16 alarms before
    the grasp in 24 runs)."""
    levels = before.settings["noise"]
    scale = np.sqrt(before.diagnostics.chi2_dof or 1.0)
    noise = Noise(**{k: levels[k] * scale for k in ("angle", "rate", "base_rate", "attitude")},
                  source=f"{levels['source']}, scaled by sqrt(chi2/dof) = {scale:.3g} of the identification before")
    momentum = initial_momentum(before, log) if drift else np.zeros(3)
    mon = Monitor(minimal_parameters(model, seed=seed), momentum, noise=noise, drift=drift,
                  where=str(log.meta.get("source", "log")))
    mon.update(log)
    return mon.finish().to_dict()


def initial_momentum(ident: Identification, log: Log, samples: int = 10) -> np.ndarray:
    """The inertial angular momentum [N m s] (3,) of the identified model over the first
    ``samples`` samples of ``log``, their mean (from the measured joint and base rates)."""
    first = log.select(np.arange(min(samples, log.n_samples)))
    return mean_momentum(parameterization_of(ident), ident.values, first)


def _scores(estimate, truth: dict, events: dict, log: Log, grasp: float) -> dict:
    """The payload against its truth (z-scores), and the first event that can be the grasp's
    (:func:`_split_at_grasp`) against the grasp, in seconds and in samples of ``log``: a dict of
    :class:`ServicingScores`' keys."""
    payload = truth["payload"]
    true = {"m": payload["mass"], "cx": payload["com"][0], "cy": payload["com"][1], "cz": payload["com"][2]}
    inertia = np.asarray(payload["inertia"])
    true |= dict(zip(("Ixx", "Ixy", "Iyy", "Ixz", "Iyz", "Izz"), inertia[[0, 0, 1, 0, 1, 2], [0, 1, 1, 2, 2, 2]]))
    true = np.array([true[n] for n in estimate.names])
    dt = float(np.median(np.diff(log.t)))
    early, found = _split_at_grasp(events["events"], grasp, dt)
    first = found[0] if found else None
    return {
        "payload": tuple(PayloadScore(n, float(t), float(v), float(e), float((v - t) / e) if e > 0 else None)
                         for n, t, v, e in zip(estimate.names, true, estimate.values, estimate.std)),
        "not_identifiable": tuple(estimate.not_identifiable),
        "grasp_time": grasp,
        "detected_change_time": None if first is None else first["time"],
        "detected_at": None if first is None else first["detected_at"],
        "change_time_error": None if first is None else first["time"] - grasp,
        "change_time_error_samples": None if first is None else round((first["time"] - grasp) / dt, 1),
        "change_time_lead": None if first is None else first["lead"],
        "alarm_time_from_grasp": None if first is None else first["detected_at"] - grasp,
        "false_alarms": len(early),
        "events": len(events["events"]),
        "monitor_drift_terms": ", ".join(events["settings"]["drift"]) or "none",
        "sample_period": dt,
    }


def _split_at_grasp(events: list, grasp: float, dt: float) -> tuple:
    """The monitor's ``events`` split into false alarms and those that can be the grasp's (grasp at
    ``grasp`` [s], sample step ``dt`` [s]): the differentiated rates show the grasp up to an event's
    ``lead`` early, so an alarm raised before ``grasp - lead`` (to within a step) is a false alarm,
    however close; one raised after it can be the grasp's even when its estimated change ``time``
    comes earlier than the lead allows (the CUSUM places the change within its last excursion,
    a few samples either way)."""
    early = [e for e in events if e["detected_at"] + dt < grasp - e["lead"]]
    return early, [e for e in events if e["detected_at"] + dt >= grasp - e["lead"]]


@deprecated_alias(old="folder", new="out")
def write_servicing(out: Path, result: ServicingResult) -> tuple:
    """The servicing files in ``out`` (payload.json, events.json, capture_log.csv, capture_truth.csv
    of the post-capture phase, capture_trajectory.json, capture.png, payload.png).

    Returns
    -------
    lines : list of str
        The report's capture section (Markdown).
    figures : dict
        Its figures, caption -> file name.
    """
    from ._figures import plot_capture_monitor, plot_payload
    from ._report import _md_table, servicing_label

    folder = Path(out)
    write_json(folder / "payload.json", result.payload.to_dict())
    write_json(folder / "events.json", result.events)
    write_log(folder / "capture_log.csv", result.log)
    write_log(folder / "capture_truth.csv", result.run.truth)
    result.trajectory.save(folder / "capture_trajectory.json")
    s = result.scores
    plot_capture_monitor(result.log, s, folder / "capture.png", joints=result.trajectory.joints)
    plot_payload([p.to_dict() for p in s.payload], folder / "payload.png", link=result.truth["link"],
                 truth_label="truth (twin)")
    units = payload_units([p.name for p in s.payload])
    rows = [(p.name, unit, f"{p.true:.6g}", f"{p.estimate:.6g}", f"{p.std:.2g}",
             "" if p.z is None else f"{p.z:+.2f}") for p, unit in zip(s.payload, units)]  # fmt: skip
    lines = [f"The payload grasped by `{result.truth['link']}` (mass, CoM and inertia about the CoM in its frame), "
             "identified from the post-capture excitation with the twin's servicer model, against the twin's truth:",
             "", *_md_table(["parameter", "unit", "true", "estimate", "std", "z"], rows), ""]  # fmt: skip
    if s.not_identifiable:
        lines += [f"Not identifiable from planar motion: {', '.join(s.not_identifiable)}.", ""]
    timing = [(servicing_label(k), "none" if v is None else f"{v:.4g}" if isinstance(v, float) else str(v))
              for k, v in s.to_dict().items() if k not in ("payload", "not_identifiable")]  # fmt: skip
    lines += ["Change detection over the servicing recording (held-out motion, grasp, post-capture excitation):", "",
              *_md_table(["", "value"], timing)]  # fmt: skip
    figures = {"Change detection: the servicing recording, the grasp and the detected change": "capture.png",
               "The payload: estimate against truth, with one standard error": "payload.png"}
    return lines, figures
