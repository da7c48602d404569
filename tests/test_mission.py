"""The mission loop on the twin (issue 13 item 5): the state-feedback hook of ``run_twin`` and
computed-torque joint control through ``H*`` of the identified, the true and a CAD prior's model."""

from dataclasses import replace

import numpy as np
import pytest

import spaceid
from spaceid import SpaceidError
from spaceid.data import to_log
from spaceid.identified import identified_model
from spaceid.motion import FourierTrajectory
from spaceid.twin import MotionCapture, TwinSettings, computed_torque, join_runs, spin_up

IDEAL = TwinSettings().without_effects()
TRUTH = spaceid.load_model("cepheus-rw")
PARAM = spaceid.minimal_parameters(TRUTH)
KP = 400.0  # position gain [1/s^2] (natural frequency 20 rad/s, critically damped)
ARM = ("left_shoulder", "left_elbow")


def _cad_values(seed):
    """Minimal parameters of a CAD prior: every body's inertial parameters (mass, first moments,
    inertia) scaled by a seeded factor in [0.7, 0.8] or [1.2, 1.3] (a rigid body with the same CoM)."""
    rng = np.random.default_rng(seed)
    factor = 1 + rng.choice([-1.0, 1.0], 4) * rng.uniform(0.2, 0.3, 4)
    bodies = tuple(replace(b, inertial=np.asarray(b.inertial) * f) for b, f in zip(TRUTH.bodies, factor))
    return spaceid.minimal_parameters(replace(TRUTH, bodies=bodies)).true_values


def _noise_free_model():
    """An IdentifiedModel of a noise-free identification (its pi equals the truth's)."""
    rng = np.random.default_rng(0)
    motion = FourierTrajectory(TRUTH.joints, 10.0, rng.uniform(-0.3, 0.3, (3, 3)), rng.uniform(-0.3, 0.3, (3, 3)))
    log = spaceid.simulate(PARAM, PARAM.true_values, motion, np.linspace(0, 10, 200), np.zeros(3), model=TRUTH)
    return identified_model(spaceid.identify(PARAM, log, np.zeros(3)))


def _arm_reference(seed, duration):
    """``reference(t) -> (q, qd, qdd)`` (n, 3) of all joints: the wheel at rest, a seeded Fourier
    motion of the arm (held after ``duration``)."""
    rng = np.random.default_rng(seed)
    arm = FourierTrajectory(ARM, duration, rng.uniform(-0.4, 0.4, (2, 4)), rng.uniform(-0.4, 0.4, (2, 4)))

    def reference(t):
        q, qd, qdd = arm.evaluate(np.minimum(np.asarray(t, float), duration))
        late = np.asarray(t)[:, None] > duration
        zero = np.zeros((len(q), 1))
        return np.hstack([zero, q]), np.hstack([zero, np.where(late, 0, qd)]), np.hstack([zero, np.where(late, 0, qdd)])

    return reference


def _tracking_rms(model, reference, duration, settings=IDEAL, seed=0):
    """RMS of the true arm joint errors [rad] (2,) when ``computed_torque`` of ``model`` drives the twin."""
    times = np.arange(round(duration * settings.controllers.rate) + 1) / settings.controllers.rate
    law = computed_torque(model, reference, times, kp=[0.0, KP, KP], kd=2 * np.sqrt(KP))
    run = spaceid.run_twin(lambda t: tuple(x[:, 1:] for x in reference(t)), duration=duration, settings=settings,
                           seed=seed, controller=law)  # fmt: skip
    return np.sqrt(np.mean((run.truth.q - reference(run.truth.t)[0])[:, 1:] ** 2, axis=0))


# ------------------------------------------------------------------ the hook ------------------


def test_controller_hook_efforts_are_saturated_and_held():
    calls = []

    def law(t, q, qd, base_yaw, base_wz):
        calls.append((t, q.copy(), qd.copy(), base_yaw, base_wz))
        return np.array([0.0, 10.0, -0.01])  # the shoulder far above its limit

    settings = replace(IDEAL, torque_limits=replace(IDEAL.torque_limits, enabled=True, effort={"left_shoulder": 0.5}))
    run = spaceid.run_twin(duration=0.01, settings=settings, controller=law)
    limit = 0.5
    assert len(calls) == 10 and np.allclose([c[0] for c in calls], np.arange(10) * 1e-3)
    assert np.all(run.effort[:, 2] == -0.01) and np.all(run.effort[:, 1] == limit) and limit < 10.0
    assert np.allclose(calls[0][1], 0) and calls[-1][1][1] > 0  # the encoders see the shoulder move
    # the reaction: the base turns the other way, and the law reads it
    assert calls[-1][4] != 0.0 and np.isclose(calls[-1][4], run.truth.base_w[-2, 2])


@pytest.mark.parametrize("law, message", [
    (lambda t, q, qd, yaw, wz: np.zeros(2), "must return 3 efforts"),
    (lambda t, q, qd, yaw, wz: np.full(3, np.nan), "NaN"),
    ("pd", "`controller` must be a callable"),
])  # fmt: skip
def test_controller_hook_bad_laws_are_one_line_errors(law, message):
    with pytest.raises(SpaceidError, match=message):
        spaceid.run_twin(duration=0.01, settings=IDEAL, controller=law)


# ------------------------------------------------------------------ computed torque -----------


def test_computed_torque_tracks_with_the_true_model_and_not_with_a_cad_prior():
    model = _noise_free_model()
    reference = _arm_reference(4, 2.0)
    exact = _tracking_rms(model.with_values(PARAM.true_values), reference, 2.0)
    cad = _tracking_rms(model.with_values(_cad_values(2)), reference, 2.0)
    assert np.all(exact < 3e-4), exact
    assert np.linalg.norm(cad) > 5 * np.linalg.norm(exact), (cad, exact)  # measured: 21 times


def test_computed_torque_rejects_bad_times():
    with pytest.raises(SpaceidError, match="`times` must be increasing"):
        computed_torque(_noise_free_model(), _arm_reference(0, 1.0), [0.0])


def test_with_values_checks_the_shape():
    with pytest.raises(SpaceidError, match="with_values: `pi` has shape"):
        _noise_free_model().with_values(np.ones(2))


# ------------------------------------------------------------------ the mission loop ----------


def _twin_identification(seed):
    """The IdentifiedModel of Cepheus identified on the ideal twin: wheel spin-up, the paper's
    exciting trajectory, the recording (50 Hz joint states, 0.01 mrad motion capture: with 0.1 mrad
    the parameters are off by 1-3 % and H* tracks no better than the CAD prior's) read back as a log."""
    settings = TwinSettings(mocap=MotionCapture(attitude_noise=1e-5)).without_effects()
    traj = spaceid.load_trajectory("paper-table2")
    a = spin_up(170.0, settings=settings, seed=seed)
    b = spaceid.run_twin(traj, duration=traj.duration + 1.0, state=a.state, settings=settings, seed=seed + 100)
    log = to_log(join_runs(a, b).recording, joints=TRUTH.joints, planar=True, wheels=TRUTH.wheels,
                 pose_latency=settings.mocap.latency)  # fmt: skip
    start = b.truth.t[0]
    return identified_model(spaceid.identify(PARAM, log.select((log.t >= start) & (log.t <= start + traj.duration)),
                                             np.zeros(3)))


@pytest.mark.slow
@pytest.mark.parametrize("seed", [0, 1, 2])
def test_mission_loop_identified_tracks_like_true_and_better_than_cad(seed):
    identified = _twin_identification(seed)
    reference = _arm_reference(10 + seed, 4.0)
    rms = {name: _tracking_rms(m, reference, 4.0, seed=seed) for name, m in (
        ("true", identified.with_values(PARAM.true_values)), ("identified", identified),
        ("cad", identified.with_values(_cad_values(seed))))}  # fmt: skip
    total = {name: float(np.linalg.norm(r)) for name, r in rms.items()}  # both arm joints
    # measured over seeds 0-2 (kp = 400): the identified model's excess over the true one 2-10 % of
    # the CAD prior's, the CAD prior's errors 6-18 times the identified model's
    assert total["identified"] - total["true"] < 0.25 * (total["cad"] - total["true"]), rms
    assert total["cad"] > 4 * total["identified"], rms
