"""spaceid against MuJoCo, an engine nobody on the project wrote: random spatial robots (prismatic
joints, fixed links, rotated frames) and the dual-arm servicer flown with a free joint in zero
gravity (tests/mujoco_flight.py), their momentum, regressor and identification checked against
what MuJoCo computed."""

from __future__ import annotations

import warnings
from importlib import resources

import mujoco
import numpy as np
import pytest
from hypothesis import assume, given
from hypothesis import strategies as st
from mujoco_flight import Sensors, fly, sense
from random_robots import perturbed_prior, random_robot
from robot_tally import robots, stage
from test_random_robots import noise_free_identification

import spaceid
from spaceid.data import quat_to_matrix, write_json
from spaceid.dynamics import minimal_parameters
from spaceid.identified import export_model, write_export
from spaceid.motion import FourierTrajectory

SERVICER = resources.files("spaceid.models.presets").joinpath("servicer-dual.urdf")
RATE = 50.0


ONE = robots(1)
SOME = robots(4)


def _excitation(joints, duration, seed, amplitude=0.1, harmonics=3) -> FourierTrajectory:
    """An undesigned motion: random Fourier coefficients of the joint rates [rad/s]."""
    rng = np.random.default_rng(seed)
    shape = (len(joints), harmonics)
    return FourierTrajectory(joints, duration, amplitude * rng.standard_normal(shape),
                             amplitude * rng.standard_normal(shape), meta={"source": f"random:{seed}"})


def _flown(tmp_path, seed, duration, amplitude=0.1, harmonics=3, **size):
    """A random spatial robot and its flight in MuJoCo from a random base rate."""
    model = random_robot(seed, planar=False, **size).load(tmp_path)
    times = np.arange(round(duration * RATE) + 1) / RATE
    rng = np.random.default_rng(seed)
    flight = fly(tmp_path / f"robot{seed}.urdf", _excitation(model.joints, duration, seed, amplitude, harmonics),
                 times, base_w=rng.normal(0.0, 0.05, 3))
    return model, flight


def _relative(a, b) -> float:
    return float(np.abs(a - b).max() / np.abs(b).max())


def _momentum_agrees(tmp_path, seed, **size):
    with stage("MuJoCo momentum", seed=seed, planar=False, motion="random Fourier", **size):
        _check_momentum(tmp_path, seed, **size)


def _check_momentum(tmp_path, seed, **size):
    model, flight = _flown(tmp_path, seed, duration=1.0, **size)
    log = flight.log
    assert flight.drift < 1e-7  # the engine conserved it (RK4 at 1 ms)
    h = spaceid.dynamics.angular_momentum(model, log.q, log.qd, log.base_w, log.base_quat)
    assert _relative(h, flight.momentum) < 1e-7
    param = minimal_parameters(model)
    in_base = np.einsum("nji,nj->ni", quat_to_matrix(log.base_quat), flight.momentum)
    assert _relative(param.momentum(log.q, log.qd, log.base_w, param.true_values), in_base) < 1e-7


@ONE
@given(seed=st.integers(0, 10**6))
def test_momentum_and_regressor_agree_with_mujoco(tmp_path, seed):
    """The direct momentum and the minimal regressor times the true parameters give MuJoCo's
    angular momentum (about the system CoM, zero linear momentum) on MuJoCo's own states."""
    _momentum_agrees(tmp_path, seed, max_arms=2, max_joints=4)


@pytest.mark.slow
@SOME
@given(seed=st.integers(0, 10**6))
def test_momentum_and_regressor_agree_with_mujoco_on_larger_robots(tmp_path, seed):
    _momentum_agrees(tmp_path, seed)


# fast representatives: test_momentum_and_regressor_agree_with_mujoco,
# test_mjcf_export_flies_in_mujoco_with_the_identified_momentum
@pytest.mark.slow
def test_flight_is_not_the_reference():
    """The controller's inertia is wrong, so the executed joint motion leaves the reference (the
    identification sees the executed one), and the momentum stays conserved."""
    model = spaceid.load_model("servicer-dual")
    traj = _excitation(model.joints, 2.0, seed=3)
    times = np.arange(101) / RATE
    flight = fly(SERVICER, traj, times, base_w=(0.01, -0.02, 0.015))
    assert np.abs(flight.log.q - traj.evaluate(times)[0]).max() > 1e-4
    assert flight.drift < 1e-7


@pytest.mark.slow
@robots(2)
@given(seed=st.integers(0, 10**6))
def test_identify_a_random_robot_flown_in_mujoco(tmp_path, seed):
    """Noise-free, rates measured: least squares recovers the true minimal parameters from
    MuJoCo's log to the integrator's error times the conditioning."""
    with stage("MuJoCo identify noise-free", seed=seed, planar=False, motion="random Fourier"):
        _identify_mujoco_flight(tmp_path, seed)


def _identify_mujoco_flight(tmp_path, seed):
    model, flight = _flown(tmp_path, seed, duration=20.0, amplitude=0.4, harmonics=6, max_arms=2, max_joints=4)
    # A robot whose base tumbles fast (random robot 378's at 17 rad/s) is not flown accurately by RK4 at 1 ms
    # (its momentum drifts by 2 %, 0.2 % at 0.5 ms): its log's error is the engine's, not the identification's
    assume(flight.drift < 1e-7)
    param = minimal_parameters(model)
    result = spaceid.identify(param, flight.log, flight.momentum[0], estimator="ols", cond_limit=1e12)
    truth = param.true_values
    # the log's own error is MuJoCo's integrator (momentum conserved to ~1e-9), amplified by the
    # conditioning of the column-scaled regressor
    assert np.abs(result.values - truth).max() <= 1e-9 * result.condition_number * np.abs(truth).max()


CONSERVED_LOGS = (1, 2, 3, 6)  # the robots of bench_false_alarms.py's undesigned logs 1, 2, 3, 6 (28 to 45 parameters)


@pytest.mark.slow
def test_drift_test_keeps_its_level_on_conserved_flights(tmp_path):
    """Conserved logs flown in MuJoCo as a servicer logs them (heavy base, encoders with a quantum, a
    star tracker, a gyro, no joint-rate sensor; the joint rates differentiated, the gyro kept;
    ``identify``'s default estimator): the drift test's warnings within the binomial bound of its level
    (two or more of four have probability 6e-6), and its p-values below 0.1 at most three times (four:
    1e-4 if they are uniform, as a test at its level makes them). Over 50 such logs:
    benchmarks/bench_false_alarms.py."""
    from spaceid.data import differentiate_log
    from spaceid.estimation import Noise

    quantum = 2 * np.pi / 2**18
    sensors = Sensors(encoder=1e-4, quantum=quantum, star_tracker=5e-5, gyro=1e-5)
    noise = Noise(angle=float(np.hypot(1e-4, quantum / np.sqrt(12))), base_rate=1e-5, attitude=5e-5)
    tests = []
    for seed in CONSERVED_LOGS:
        model, flight = _flown(tmp_path, seed, duration=20.0, amplitude=0.08, harmonics=6, max_arms=2, max_joints=4,
                               base_scale=10.0)
        log = differentiate_log(sense(flight.log, sensors, seed), base=False, quantum=quantum)
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")  # the directions the data do not determine, say
            result = spaceid.identify(minimal_parameters(model), log, flight.momentum[0], noise=noise)
        tests.append(result.diagnostics.drift_test)
    assert all(t.run for t in tests)
    assert sum(t.drift for t in tests) <= 1, [t.p_value for t in tests]
    assert sum(t.p_value < 0.1 for t in tests) <= 3, [t.p_value for t in tests]


def test_sensors_drop_the_rates_and_bias_the_gyro(tmp_path):
    """The sensed log has no joint rates when no rate sensor is flown, and a gyro bias shifts the
    base rate by the bias."""
    _, flight = _flown(tmp_path, 11, duration=1.0, max_arms=1, max_joints=3)
    bias = (3e-4, -2e-4, 1e-4)
    log = sense(flight.log, Sensors(gyro=0.0, gyro_bias=bias, encoder=0.0, star_tracker=0.0), seed=0)
    assert np.isnan(log.qd).all() and log.meta["rates"] == "missing"
    assert np.allclose(log.base_w - flight.log.base_w, bias, atol=1e-15)
    assert np.array_equal(log.q, flight.log.q)


@ONE
@given(seed=st.integers(0, 10**6))
def test_mjcf_export_flies_in_mujoco_with_the_identified_momentum(tmp_path, seed):
    """``export --format mjcf`` of an identification of a random robot: MuJoCo loads it as a free
    floater and, flying a joint motion with its own integrator, has the angular momentum that the
    identified parameters give on the same states."""
    with stage("MJCF export in MuJoCo", seed=seed, planar=False, motion="random Fourier"):
        _mjcf_flies(tmp_path, seed)


def _mjcf_flies(tmp_path, seed):
    true = random_robot(seed, planar=False, max_arms=2, max_joints=3).load(tmp_path)
    result = noise_free_identification(true, seed)
    write_export(export_model(result, perturbed_prior(true, seed + 1)), tmp_path / "robot.xml", fmt="mjcf")
    times = np.arange(51) / RATE
    rng = np.random.default_rng(seed)
    flight = fly(tmp_path / "robot.xml", _excitation(true.joints, 1.0, seed), times, base_w=rng.normal(0, 0.05, 3))
    log, param = flight.log, minimal_parameters(true)
    in_base = np.einsum("nji,nj->ni", quat_to_matrix(log.base_quat), flight.momentum)
    assert _relative(param.momentum(log.q, log.qd, log.base_w, result.values), in_base) < 1e-8


def test_mjcf_export_of_a_planar_robot_floats_on_an_air_bearing(tmp_path):
    """A planar model's MJCF has the air bearing's x, y and yaw on its base, every joint with its
    limits, and the exported masses."""
    true = random_robot(5, planar=True, max_arms=1, max_joints=3).load(tmp_path)
    res = export_model(noise_free_identification(true, 5), perturbed_prior(true, 6))
    write_export(res, tmp_path / "robot.xml", fmt="mjcf")
    m = mujoco.MjModel.from_xml_path(str(tmp_path / "robot.xml"))
    assert m.nq == m.nv == 3 + len(true.joints) and np.all(m.opt.gravity == 0)
    for body in res.model.bodies:
        index = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_BODY, body.name)
        assert m.body_mass[index] == pytest.approx(body.mass, rel=1e-12)
        if body.parent >= 0 and {"lower", "upper"} <= set(body.limits):
            joint = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_JOINT, body.joint)
            assert m.jnt_limited[joint] and tuple(m.jnt_range[joint]) == (body.limits["lower"], body.limits["upper"])


def test_export_command_writes_mjcf(tmp_path, capsys):
    """``spaceid export RESULT --prior MODEL --format mjcf -o robot.xml``: a file MuJoCo loads as a
    free floater with the model's joints."""
    from spaceid.cli import main

    true = random_robot(7, planar=False, max_arms=1, max_joints=3).load(tmp_path)
    prior = tmp_path / "prior.urdf"
    prior.write_text(random_robot(7, planar=False, max_arms=1, max_joints=3).urdf)
    result = tmp_path / "result.json"
    write_json(result, noise_free_identification(true, 7).to_dict())
    assert main(["export", str(result), "--prior", str(prior), "--format", "mjcf", "-o", str(tmp_path / "r.xml")]) == 0
    m = mujoco.MjModel.from_xml_path(str(tmp_path / "r.xml"))
    assert m.jnt_type[0] == mujoco.mjtJoint.mjJNT_FREE and m.njnt == 1 + len(true.joints)
