"""The base attitude of simulate, predict and validate: Gauss-Legendre collocation on stage
values evaluated beforehand (spatial) and a vectorised quadrature (planar), checked against
SciPy's adaptive DOP853 with the base rate solved from the momentum at every evaluation, on
random robots, and against the true simulation for a prediction from the samples."""

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from random_robots import random_robot
from scipy.integrate import solve_ivp

from spaceid.data import quat_to_matrix, yaw_to_quat
from spaceid.dynamics import base_rate, minimal_parameters
from spaceid.motion import FourierTrajectory, _attitude, _simulate, simulate
from spaceid.studies import attitude_error_angle, predict

SEEDS = st.integers(0, 2**31 - 1)
FAST = settings(max_examples=1, deadline=None, suppress_health_check=[HealthCheck.too_slow,
                                                                      HealthCheck.function_scoped_fixture])
SLOW = settings(max_examples=20, deadline=None, suppress_health_check=[HealthCheck.too_slow,
                                                                       HealthCheck.function_scoped_fixture])


def _motion(model, seed, duration):
    """A random smooth joint motion of three harmonics within the joints' ranges."""
    rng = np.random.default_rng(seed)
    shape = (model.n_joints, 3)
    return FourierTrajectory(model.joints, duration, rng.uniform(-0.15, 0.15, shape), rng.uniform(-0.15, 0.15, shape))


def _reference(param, motion, times, momentum, quat0):
    """Attitudes ``(n, 4)`` by DOP853 at rtol 1e-13, the base rate solved from the momentum at each
    evaluation (no stage values, no splines: the old solver's route, tightened)."""
    def rhs(t, y):
        q, qd, _ = motion.evaluate(np.array([t]))
        if param.model.planar:
            return base_rate(param, param.true_values, q, qd, momentum[None])[0, 2:]
        w = base_rate(param, param.true_values, q, qd, (quat_to_matrix(y / np.linalg.norm(y)).T @ momentum)[None])[0]
        return _simulate._quat_rate(y, w)

    y0 = [2 * np.arctan2(quat0[3], quat0[0])] if param.model.planar else quat0
    y = solve_ivp(rhs, (times[0], times[-1]), y0, method="DOP853", t_eval=times, rtol=1e-13, atol=1e-15).y.T
    return yaw_to_quat(y[:, 0]) if param.model.planar else y / np.linalg.norm(y, axis=1, keepdims=True)


def _agrees_with_adaptive_solver(seed, planar, tmp_path):
    model = random_robot(seed, planar=planar, max_arms=2, max_joints=3).load(tmp_path)
    param = minimal_parameters(model)
    rng = np.random.default_rng(seed)
    momentum = np.r_[0.0, 0.0, rng.uniform(-1, 1)] if planar else rng.uniform(-1, 1, 3)
    quat0 = yaw_to_quat(rng.uniform(-np.pi, np.pi)) if planar else rng.standard_normal(4)
    quat0 = quat0 / np.linalg.norm(quat0)
    motion, times = _motion(model, seed, 8.0), np.linspace(0.0, 8.0, 41)
    log = simulate(param, param.true_values, motion, times, momentum, initial_quat=quat0)
    ref = _reference(param, motion, times, momentum, quat0)
    turned = attitude_error_angle(ref[:1], ref).max()
    assert attitude_error_angle(ref, log.base_quat).max() <= 1e-8 * max(turned, 1.0)


@FAST
@given(seed=SEEDS, planar=st.booleans())
def test_attitude_agrees_with_the_adaptive_solver_on_random_robots(seed, planar, tmp_path):
    _agrees_with_adaptive_solver(seed, planar, tmp_path)


@pytest.mark.slow
@SLOW
@given(seed=SEEDS, planar=st.booleans())
def test_attitude_agrees_with_the_adaptive_solver_on_more_random_robots(seed, planar, tmp_path):
    _agrees_with_adaptive_solver(seed, planar, tmp_path)


@pytest.mark.slow  # fast representative: test_attitude_agrees_with_the_adaptive_solver_on_random_robots
def test_steps_halved_until_two_solutions_agree(monkeypatch, tmp_path):
    """Samples 4 s apart: the collocation halves its steps until two solutions agree, and then
    matches the adaptive solver; each pass evaluates the stage values of twice as many steps."""
    model = random_robot(5, planar=False, max_arms=2, max_joints=3).load(tmp_path)
    param = minimal_parameters(model)
    steps = []
    original = _simulate.collocation_steps
    monkeypatch.setattr(_simulate, "collocation_steps", lambda *a: steps.append(len(a[6])) or original(*a))
    motion, times, momentum = _motion(model, 5, 20.0), np.linspace(0.0, 20.0, 6), np.array([0.3, -0.2, 0.5])
    log = simulate(param, param.true_values, motion, times, momentum)
    assert len(steps) >= 3 and steps == [5 * 2**i for i in range(len(steps))]
    ref = _reference(param, motion, times, momentum, np.array([1.0, 0, 0, 0]))
    assert attitude_error_angle(ref, log.base_quat).max() <= 1e-9


def test_unit_quaternion_kept_by_the_collocation():
    """Gauss-Legendre collocation keeps |q| (a quadratic invariant of the flow) without
    renormalising: steps of a rate that tumbles the base, |q| stays 1 to round-off."""
    c, b, a = _attitude.gauss_tableau()
    assert np.allclose(a.sum(1), c) and np.isclose(b.sum(), 1.0)  # the tableau's consistency
    rng = np.random.default_rng(0)
    n = 200
    inverse = np.broadcast_to(np.linalg.inv(np.diag([2.0, 3.0, 5.0])), (n, 4, 3, 3)).copy()
    offset = rng.uniform(-1, 1, (n, 4, 3))
    out = np.empty((n + 1, 7))
    start = np.array([1.0, 0, 0, 0, 3.0, -1.0, 2.0])  # the attitude, then the momentum: constant without drift
    assert _attitude.collocation_steps(start, inverse, offset, np.zeros(3), 0.0, 0.0, np.full(n, 0.05), a, b, out) == -1
    assert np.abs(np.linalg.norm(out[:, :4], axis=1) - 1).max() < 1e-13 and (out[:, 4:] == start[4:]).all()


@pytest.mark.parametrize("name", [pytest.param("satellite-7dof", marks=pytest.mark.slow), "cepheus"])
def test_prediction_from_samples_follows_the_true_simulation(name):
    """``predict`` with the true parameters, from the samples of a simulated log (the joint motion
    interpolated between them), reproduces the simulated attitude; the error is the interpolation's,
    of order 4: 16 times smaller at twice the rate."""
    from spaceid.models import load_model

    model = load_model(name)
    param = minimal_parameters(model)
    momentum = np.array([0.0, 0.0, 0.05]) if model.planar else np.array([1.0, -2.0, 3.0])
    motion = _motion(model, 3, 10.0)
    errors = []
    for n in (101, 201):
        times = np.linspace(0.0, 10.0, n)
        true = simulate(param, param.true_values, motion, times, momentum, initial_quat=[0.6, 0.0, 0.8, 0.0]
                        if not model.planar else None)
        pred = predict(name, times, true.q, true.qd, momentum=momentum, initial_quat=true.base_quat[0])
        errors.append(attitude_error_angle(true.base_quat, pred.base_quat).max())
    assert errors[0] < 1e-5
    assert 8 < errors[0] / errors[1] < 32
