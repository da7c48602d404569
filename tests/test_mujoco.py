"""spaceid against MuJoCo, an engine nobody on the project wrote: random spatial robots (prismatic
joints, fixed links, rotated frames) and the dual-arm servicer flown with a free joint in zero
gravity (tests/mujoco_flight.py), their momentum, regressor and identification checked against
what MuJoCo computed."""

from __future__ import annotations

from importlib import resources

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from mujoco_flight import Sensors, fly, sense
from random_robots import random_robot

import spaceid
from spaceid.data import quat_to_matrix
from spaceid.motion import FourierTrajectory

SERVICER = resources.files("spaceid.models.presets").joinpath("servicer-dual.urdf")
RATE = 50.0


def _excitation(
    joints, duration, seed, amplitude=0.1, harmonics=3
) -> FourierTrajectory:
    """An undesigned motion: random Fourier coefficients of the joint rates [rad/s]."""
    rng = np.random.default_rng(seed)
    shape = (len(joints), harmonics)
    return FourierTrajectory(
        joints,
        duration,
        amplitude * rng.standard_normal(shape),
        amplitude * rng.standard_normal(shape),
        meta={"source": f"random:{seed}"},
    )


def _flown(tmp_path, seed, duration, amplitude=0.1, harmonics=3, **size):
    robot = random_robot(seed, planar=False, **size)
    model = robot.load(tmp_path)
    times = np.arange(round(duration * RATE) + 1) / RATE
    rng = np.random.default_rng(seed)
    flight = fly(
        tmp_path / f"robot{seed}.urdf",
        _excitation(model.joints, duration, seed, amplitude, harmonics),
        times,
        base_w=rng.normal(0.0, 0.05, 3),
    )
    return model, flight


def _relative(a, b) -> float:
    return float(np.abs(a - b).max() / np.abs(b).max())


@settings(
    max_examples=2,
    deadline=None,
    suppress_health_check=[HealthCheck.function_scoped_fixture],
)
@given(seed=st.integers(0, 10**6))
def test_momentum_and_regressor_agree_with_mujoco(tmp_path, seed):
    """The direct momentum and the minimal regressor times the true parameters give MuJoCo's
    angular momentum (about the system CoM, zero linear momentum) on MuJoCo's own states."""
    model, flight = _flown(tmp_path, seed, duration=1.0)
    log = flight.log
    assert flight.drift < 1e-7  # the engine conserved it (RK4 at 1 ms)
    h = spaceid.dynamics.angular_momentum(
        model, log.q, log.qd, log.base_w, log.base_quat
    )
    assert _relative(h, flight.momentum) < 1e-7
    param = spaceid.minimal_parameters(model)
    rotation = quat_to_matrix(log.base_quat)
    in_base = np.einsum("nji,nj->ni", rotation, flight.momentum)
    assert (
        _relative(param.momentum(log.q, log.qd, log.base_w, param.true_values), in_base)
        < 1e-7
    )


def test_flight_is_not_the_reference(tmp_path):
    """The controller's inertia is wrong, so the executed joint motion leaves the reference (the
    identification sees the executed one), and the momentum stays conserved."""
    model = spaceid.load_model("servicer-dual")
    traj = _excitation(model.joints, 4.0, seed=3)
    times = np.arange(201) / RATE
    flight = fly(SERVICER, traj, times, base_w=(0.01, -0.02, 0.015))
    q_ref = traj.evaluate(times)[0]
    assert np.abs(flight.log.q - q_ref).max() > 1e-4
    assert flight.drift < 1e-7


@pytest.mark.slow
@settings(
    max_examples=3,
    deadline=None,
    suppress_health_check=[HealthCheck.function_scoped_fixture],
)
@given(seed=st.integers(0, 10**6))
def test_identify_a_random_robot_flown_in_mujoco(tmp_path, seed):
    """Noise-free, rates measured: least squares recovers the true minimal parameters from
    MuJoCo's log to the integrator's error times the conditioning."""
    model, flight = _flown(
        tmp_path,
        seed,
        duration=20.0,
        amplitude=0.4,
        harmonics=6,
        max_arms=2,
        max_joints=4,
    )
    param = spaceid.minimal_parameters(model)
    result = spaceid.identify(
        param, flight.log, flight.momentum[0], estimator="ols", cond_limit=1e12
    )
    truth = param.true_values
    # the log's own error is MuJoCo's integrator (momentum conserved to ~1e-9), amplified by the
    # conditioning of the column-scaled regressor
    bound = 1e-9 * result.condition_number * np.abs(truth).max()
    assert np.abs(result.values - truth).max() <= bound


def test_sensors_drop_the_rates_and_bias_the_gyro(tmp_path):
    """The sensed log has no joint rates when no rate sensor is flown, and a gyro bias shifts the
    base rate by the bias."""
    _, flight = _flown(tmp_path, 11, duration=1.0)
    bias = (3e-4, -2e-4, 1e-4)
    log = sense(
        flight.log,
        Sensors(gyro=0.0, gyro_bias=bias, encoder=0.0, star_tracker=0.0),
        seed=0,
    )
    assert np.isnan(log.qd).all() and log.meta["rates"] == "missing"
    assert np.allclose(log.base_w - flight.log.base_w, bias, atol=1e-15)
    assert np.array_equal(log.q, flight.log.q)
