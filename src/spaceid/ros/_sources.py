"""What ``spaceid ros play`` and ``spaceid ros twin`` publish: a log or a bag as a recording, and
a run of the Cepheus twin (optionally grasping a payload) as one."""

from __future__ import annotations

import dataclasses

import numpy as np

__all__ = ["recording_of_log", "twin_recording"]


def recording_of_log(log, gyro: bool = False):
    """A :class:`~spaceid.data.Recording` of a :class:`~spaceid.data.Log`: its angles and rates
    as joint states, its attitude (and base position, zero when not logged) as poses, both on
    the log's stamps; ``gyro``: its base rate as the poses' measured rate (written as Odometry)."""
    from ..data import JointStates, Poses, Recording

    position = log.base_position if log.base_position is not None else np.zeros((log.n_samples, 3))
    return Recording(JointStates(t=log.t, names=tuple(log.joints), position=log.q, velocity=log.qd, effort=log.tau),
                     Poses(t=log.t, position=position, quat=log.base_quat, rate=log.base_w if gyro else None),
                     meta={"source": log.meta.get("source", "log"),
                           "time_origin_ns": int(log.meta.get("time_origin_ns", 0) or 0)})  # fmt: skip


def twin_recording(*, trajectory: str = "paper-table2", duration: float = 9.0, wheel_speed: float = 170.0,
                   capture=None, capture_time: float = 4.0, ideal: bool = False, model: str = "cepheus-rw",
                   seed: int = 1):
    """The sensors of a Cepheus twin run: the wheel spun up (not recorded), then ``trajectory``
    for ``duration`` s, the end effector grasping ``capture`` ``capture_time`` s in.

    Parameters
    ----------
    trajectory : str
        A trajectory name or file (:func:`~spaceid.motion.load_trajectory`).
    duration : float
        Seconds recorded [s].
    wheel_speed : float
        Wheel speed relative to the base [rad/s].
    capture : CaptureProtocol, optional
        The payload grasped (:func:`~spaceid.studies.capture_protocol`); None: no grasp.
    capture_time : float
        When the grasp happens, after the recording's start [s].
    ideal : bool
        Switch off friction, torque limits, thrusters and the tank's drain.
    model : str
        The twin's model.
    seed : int
        Seed of the spin-up's sensor noise; the run's is ``seed + 1``.

    Returns
    -------
    TwinRun
        Its ``recording`` (stamps on the twin's clock) and, with a capture, ``meta["capture"]``
        (the grasp's ``time`` on that clock and the payload's truth).
    """
    from ..motion import load_trajectory
    from ..twin import TwinSettings, place_payload, run_twin, spin_up

    settings = TwinSettings(model=model)
    settings = settings.without_effects() if ideal else settings
    start = spin_up(wheel_speed, settings=settings, seed=seed)
    traj = load_trajectory(trajectory)
    if capture is None:
        return run_twin(traj, duration=duration, settings=settings, state=start.state, seed=seed + 1)
    before = run_twin(traj, duration=capture_time, settings=settings, state=start.state, seed=seed + 1)
    grasp = place_payload(capture.payload, model, before.state, offset=capture.offset, yaw=capture.yaw)
    return run_twin(traj, duration=duration, settings=dataclasses.replace(settings, capture=grasp), state=start.state,
                    seed=seed + 1)  # fmt: skip
