"""The excitation as executed: making the arm follow the designed motion on the twin, and
measuring how well it does.

The published PD gains follow an exciting trajectory loosely (about 0.14 rad RMS), so the
motion the regressor is built from is not the designed one and its condition number can be
2.5 times the designed one. Two remedies a lab can apply on the real table, neither reading a
state the robot does not measure:

* **feed-forward from the prior model**: the free-floating inverse dynamics of the reference
  planned offline with the model the lab believes before identification (the nominal preset:
  full tank, level table, no friction), the base velocity predicted by momentum conservation
  (:func:`~spaceid.twin.planned_feedforward`); while the wheel settles after its spin-up the arm
  is held at the start pose with the planned holding efforts, since the spinning base pulls the
  soft loops out of position;
* **rehearsals** (iterative learning control): the reference is refined over runs of the same
  protocol, ``ref_{k+1}(t) = ref_k(t) + L (designed(t) - executed_k(t))`` with ``executed_k``
  the encoder angles the lab records (50 Hz joint states), until the tracking error is within a
  tolerance.

The condition numbers are compared on one footing (:func:`designed_condition_numbers`): the regressor
identification builds, same parameter set, anchors and sample times, from the designed motion
(noise-free, base rate predicted by the prior model) and from the executed one (the bag).
"""

from __future__ import annotations

import warnings

import numpy as np

from .._errors import SpaceidError
from ..estimation import identify
from ..motion import simulate
from ..twin import planned_feedforward, run_twin, spin_up

__all__: list = []

SETTLE = 2.0  # [s] after the wheel's ramp: the spin-up's settling; with feed-forward, at the start pose
LEARNING_GAIN = 0.5  # L of the reference update: 1 stalls at ~5 mrad on the twin (measured), 0.5 converges on
TOLERANCE = 0.005  # [rad] largest joint tracking RMS at which rehearsing stops


def check_rehearsals(rehearsals) -> int:
    """``rehearsals`` as a count, or a SpaceidError naming the option."""
    try:
        count = int(rehearsals)
    except (TypeError, ValueError):
        count = None
    if isinstance(rehearsals, bool) or count is None or count != rehearsals or count < 0:
        raise SpaceidError(f"`rehearsals`: {rehearsals!r} is not a whole number of rehearsals, 0 or more")
    return count


def _position_joints(model, settings) -> list:
    """The position-controlled joints in model order (the columns of a callable reference)."""
    return [j for j in model.joints if j in settings.controllers.position]


def _designed_reference(traj, joints, correction=None):
    """``traj`` as a callable reference ``tau -> (q, qd, qdd)`` (n_t, len(joints)), held at its
    end value after its duration, plus ``correction = (t (m,), delta (m, len(joints)))`` [s, rad]
    as a cubic spline (held at its ends)."""
    from scipy.interpolate import CubicSpline
    order = [traj.joints.index(j) for j in joints]
    spline = None if correction is None else CubicSpline(*correction, axis=0)

    def reference(tau):
        tau = np.asarray(tau, float)
        q, qd, qdd = (x[:, order] for x in traj.evaluate(np.minimum(tau, traj.duration)))
        after = tau > traj.duration
        qd[after], qdd[after] = 0.0, 0.0
        if spline is not None:
            tc = np.clip(tau, spline.x[0], spline.x[-1])
            q, qd, qdd = q + spline(tc), qd + spline(tc, 1), qdd + spline(tc, 2)
        return q, qd, qdd

    return reference


def _encoder_error(run, traj, joints):
    """``(t (m,), designed - executed (m, len(joints)))`` [s, rad] at the phase's joint-state stamps,
    ``t`` since the start of the phase; executed: the encoder angles the robot publishes."""
    js = run.recording.joints
    t = js.t - run.truth.t[0]
    measured = js.position[:, [js.names.index(j) for j in joints]]
    return t, _designed_reference(traj, joints)(t)[0] - measured


def tracking_rms(run, traj, joints) -> dict:
    """RMS of designed minus encoder angles [rad] over the excitation ``[0, tf]``, per joint."""
    t, err = _encoder_error(run, traj, joints)
    inside = t <= traj.duration + 1e-9
    return {j: float(np.sqrt(np.mean(err[inside, c] ** 2))) for c, j in enumerate(joints)}


def _hold_start_pose(traj, state, settings, joints, *, wheel_speed, seed):
    """Hold the arm at the trajectory's start pose for :data:`SETTLE` s with the planned holding
    efforts (the base spins under the wheel: the PD alone leaves the arm ~0.17 rad off)."""
    q0 = _designed_reference(traj, joints)(np.zeros(1))[0]
    hold = lambda tau: (np.tile(q0, (len(tau), 1)), np.zeros((len(tau), len(joints))))  # noqa: E731
    effort = lambda tau: planned_feedforward(hold, tau, settings=settings, wheel_speed=wheel_speed)  # noqa: E731
    return run_twin(hold, duration=SETTLE, state=state, settings=settings, seed=seed, effort=effort)


def _rehearse(traj, state, settings, joints, rehearsals: int, *, effort, seed):
    """Refine the reference over at most ``rehearsals`` runs from ``state`` (each a twin run
    seeded ``seed + k``), ``ref_{k+1} = ref_k + L (designed - encoders_k)`` with ``L =``
    :data:`LEARNING_GAIN`.

    Returns the reference for the recorded run and one record per rehearsal (seed, tracking RMS
    per joint [rad]). Rehearsing stops early once the largest joint RMS is within
    :data:`TOLERANCE`; the reference is then not changed further.
    """
    reference, correction, records = _designed_reference(traj, joints), None, []
    for k in range(rehearsals):
        run = run_twin(reference, duration=traj.duration + 1.0, state=state, settings=settings, seed=seed + k,
                       effort=effort)  # fmt: skip
        rms = tracking_rms(run, traj, joints)
        records.append({"seed": seed + k, "tracking RMS [rad]": rms})
        if max(rms.values()) <= TOLERANCE:
            break
        t, err = _encoder_error(run, traj, joints)
        delta = LEARNING_GAIN * err if correction is None else correction[1] + LEARNING_GAIN * err
        correction = (t, delta)
        reference = _designed_reference(traj, joints, correction)
    return reference, records


def _once(effort):
    """``effort`` remembering its last result: every run of the protocol has the same tick grid."""
    last = {}

    def cached(tau):
        if "tau" not in last or not np.array_equal(last["tau"], tau):
            last.update(tau=np.array(tau), value=effort(tau))
        return last["value"]

    return cached


def execute_excitation(traj, settings, model, *, feedforward: bool, rehearsals: int, wheel_speed, seed):
    """The protocol from rest: wheel spin-up and settling, then the excitation, with the
    planned feed-forward and/or after rehearsals.

    Without feed-forward the spin-up settles for :data:`SETTLE` s with the arm under its PD
    loops; with it, the same time is spent holding the arm at the start pose with the planned
    holding efforts (the recording keeps its length and phases). The feed-forward is planned
    once, for the designed motion; rehearsals, from the state before the excitation, refine the
    position reference only. Seeds: the spin-up ``seed``, the excitation ``seed + 1``, the hold
    ``seed + 2``, rehearsal k ``seed + 3 + k``.

    Returns
    -------
    phases : list of TwinRun
        The recorded phases: the spin-up first, the excitation (and one second of hold) last.
    record : dict
        How it was executed, the rehearsals and the tracking RMS of the recorded run.
    """
    joints = _position_joints(model, settings)
    designed = _designed_reference(traj, joints)
    phases = [spin_up(wheel_speed, settle=0.0 if feedforward else SETTLE, settings=settings, seed=seed)]
    effort = None
    if feedforward:
        effort = _once(lambda tau: planned_feedforward(designed, tau, settings=settings, wheel_speed=wheel_speed))
        phases.append(_hold_start_pose(traj, phases[-1].state, settings, joints, wheel_speed=wheel_speed,
                                       seed=seed + 2))  # fmt: skip
    state = phases[-1].state
    reference, records = _rehearse(traj, state, settings, joints, rehearsals, effort=effort, seed=seed + 3)
    phases.append(run_twin(reference, duration=traj.duration + 1.0, state=state, settings=settings, seed=seed + 1,
                           effort=effort))  # fmt: skip
    record = {
        "feedforward": f"planned from the prior model ({model.name}), arm held at the start pose while the wheel "
        "settles" if feedforward else "none",
        "rehearsals (at most)": rehearsals,
        "rehearsal runs (seed, tracking RMS [rad])": records,
        "tracking RMS, encoders vs design [rad]": tracking_rms(phases[-1], traj, joints),
    }
    return phases, record


def _designed_motion(traj, model, wheel_speed):
    """The designed joint motion of every model joint, ``t -> (q, qd)`` (n_t, n_joints): the
    trajectory's joints as designed, the others (the reaction wheel) at ``wheel_speed`` [rad/s]."""
    columns = [traj.joints.index(j) if j in traj.joints else None for j in model.joints]

    def motion(t):
        t = np.asarray(t, float)
        q, qd, _ = traj.evaluate(np.minimum(t, traj.duration))
        out_q, out_qd = np.empty((len(t), len(columns))), np.empty((len(t), len(columns)))
        for i, c in enumerate(columns):
            out_q[:, i], out_qd[:, i] = (q[:, c], qd[:, c]) if c is not None else (wheel_speed * t, wheel_speed)
        return out_q, out_qd

    return motion


def designed_condition_numbers(param, traj, times, *, wheel_speed) -> list:
    """cond(Y) of identification's regressor from the designed motion at each of ``times``.

    The regressor :func:`~spaceid.estimation.identify` builds with the parameter set ``param``,
    its anchors and zero momentum, from the noise-free designed motion: the arm as designed, the
    wheel at ``wheel_speed`` [rad/s] and the base rate the prior model (``param``'s nominal
    values) predicts. Compare with the ``condition_number`` of the identification from the
    executed motion at the same instants.

    Parameters
    ----------
    times : sequence of ndarray
        Sample instants since the start of the excitation [s], one array per condition number.

    Returns
    -------
    list of float
    """
    zero = np.zeros(3)
    motion = _designed_motion(traj, param.model, wheel_speed)
    return [regressor_condition_number(param, simulate(param, param.true_values, motion, t, zero),
                                       "the designed motion") for t in times]


def regressor_condition_number(param, log, where: str) -> float:
    """cond(Y) of the regressor that :func:`~spaceid.estimation.identify` builds from ``log``
    with ``param``'s anchors and zero momentum, without drift columns: the figure that compares
    an executed motion with its design (the identification's own condition number counts the
    drift columns it estimates too)."""
    with warnings.catch_warnings():  # only the regressor is wanted: the fit's warnings are the identification's
        warnings.simplefilter("ignore")
        return identify(param, log, np.zeros(3), estimator="ols", where=where).condition_number


def readable_settings(settings: dict) -> dict:
    """``settings`` for a report table: per-joint values (dicts) as ``name value, ...`` and the
    rehearsal runs as ``seed s: largest joint RMS``."""
    out = {}
    for key, value in settings.items():
        if isinstance(value, dict):
            value = ", ".join(f"{k} {v:.3g}" for k, v in value.items())
        elif key.startswith("rehearsal runs"):
            value = "; ".join(f"seed {r['seed']}: {max(r['tracking RMS [rad]'].values()):.3g}" for r in value) or "none"
            key = "rehearsal runs (seed: largest joint tracking RMS [rad])"
        out[key] = value
    return out
