"""The torque-driven Cepheus twin: invariants, agreement with the kinematic pipeline, effects,
sensors, reproducibility and error messages."""

import json
import math
from dataclasses import replace

import numpy as np
import pinocchio as pin
import pytest

from spaceid import SpaceidError

from spaceid import load_model
from spaceid.dynamics import angular_momentum
from spaceid.dynamics import minimal_parameters
from spaceid.motion import hermite_motion, simulate
from spaceid.data import quat_to_yaw, yaw_to_quat
from spaceid.motion import load_trajectory
from spaceid.twin._settings import G0
from spaceid.twin import (
    PID,
    BearingFriction,
    Controllers,
    Encoders,
    JointFriction,
    MotionCapture,
    Tank,
    Thrusters,
    TorqueLimits,
    TwinSettings,
    TwinState,
    drained_model,
    join_runs,
    planar_pinocchio,
    planned_feedforward,
    run_twin,
    spin_up,
    thruster_wrenches,
)

MODEL = load_model("cepheus-rw")
I_RW = 0.00197372
IDEAL = TwinSettings().without_effects()
MOVING = TwinState(base_wz=0.5, base_vxy=(0.01, -0.02))  # nonzero momentum, angular and linear


def centroidal(run, model=MODEL, every=1):
    """Linear momentum (x, y) and angular momentum z about the CM, world axes, from Pinocchio."""
    pmodel = planar_pinocchio(model)
    data = pmodel.createData()
    out = []
    for i in range(0, len(run.truth.t), every):
        q = np.r_[run.base_position[i], run.truth.base_yaw[i], run.truth.q[i]]
        v = np.r_[run.base_velocity[i], run.truth.base_w[i, 2], run.truth.qd[i]]
        h = pin.computeCentroidalMomentum(pmodel, data, q, v)
        out.append([h.linear[0], h.linear[1], h.angular[2]])
    return np.array(out)


@pytest.fixture(scope="module")
def experiment():
    """30 s without friction or thrusters: spin-up to 170 rad/s, the exciting trajectory, hold."""
    a = spin_up(170.0, settle=2.0, settings=IDEAL, state=MOVING, seed=1)
    b = run_twin(load_trajectory("paper-table2"), duration=5.0, settings=IDEAL, state=a.state, seed=2)
    c = run_twin(None, duration=30.0 - b.state.t, settings=IDEAL, state=b.state, seed=3)
    return a, b, join_runs(a, b, c)


# ------------------------------------------------------------------ dynamics --------------------


def test_planar_model_momentum_matches_rigid_body_definition(rng):
    """The planar Pinocchio model's centroidal momentum equals spaceid.momentum (independent)."""
    pmodel = planar_pinocchio(MODEL)
    data = pmodel.createData()
    assert pmodel.nq == pmodel.nv == 3 + MODEL.n_joints
    assert math.isclose(sum(i.mass for i in pmodel.inertias), MODEL.mass, rel_tol=1e-14)
    for _ in range(5):
        q = rng.uniform(-3, 3, pmodel.nq)
        v = rng.standard_normal(pmodel.nv)
        h = pin.computeCentroidalMomentum(pmodel, data, q, v)
        w0 = np.array([0, 0, v[2]])
        ours = angular_momentum(MODEL, q[3:], v[3:], w0, yaw_to_quat(q[2]))
        np.testing.assert_allclose(h.angular, ours, atol=1e-13)


@pytest.mark.slow
def test_momentum_conserved_over_30_s(experiment):
    _, _, run = experiment
    log = run.truth
    assert math.isclose(log.t[-1], 30.0) and abs(log.qd[-1, 0] - 170.0) < 0.5
    h = angular_momentum(MODEL, log.q, log.qd, log.base_w, log.base_quat)  # rigid-body definition
    scale = max(abs(h[0, 2]), I_RW * np.abs(log.qd[:, 0] + log.base_w[:, 2]).max())
    assert np.abs(h[:, 2] - h[0, 2]).max() <= 1e-9 * scale
    assert np.abs(h[:, :2]).max() == 0  # planar
    p = centroidal(run, every=100)
    np.testing.assert_allclose(p[:, 2], h[::100, 2], rtol=0, atol=1e-13)  # two independent codes
    assert np.abs(p[:, :2] - p[0, :2]).max() <= 1e-9 * np.linalg.norm(p[0, :2])


@pytest.mark.slow
def test_base_rate_matches_kinematic_simulation(experiment):
    """Same joint motion, same momentum: the planar pipeline's simulate() gives the same base
    motion. The joint motion is a cubic Hermite through the 1 kHz samples (error <= dt^4/384
    max|q''''| ~ 1e-13 rad), RK4's global error is O((lambda dt)^4) ~ 1e-8 relative at most:
    1e-8 bounds both with margin."""
    _, b, _ = experiment
    log = b.truth
    h = angular_momentum(MODEL, log.q[:1], log.qd[:1], log.base_w[:1], log.base_quat[:1])[0]
    param = minimal_parameters(MODEL)
    # output at every tick: the Hermite motion is smooth between ticks, so the quadrature converges
    sim = simulate(param, param.true_values, hermite_motion(log.t, log.q, log.qd), log.t, h,
                   initial_quat=log.base_quat[0], model=MODEL)
    assert np.abs(log.base_w[:, 2]).max() > 1.0  # the base turns: a real comparison
    np.testing.assert_allclose(sim.base_w[:, 2], log.base_w[:, 2], rtol=0, atol=1e-8)
    np.testing.assert_allclose(sim.base_yaw, log.base_yaw, rtol=0, atol=1e-8)


def test_phases_compose_exactly():
    """A phase split in two gives the same true motion and joint states as one phase (effects on,
    a thruster firing across the boundary)."""
    settings = TwinSettings(thrusters=Thrusters(schedule=((0.8, 1.3, 1, -1),)))
    one = run_twin(None, duration=2.0, wheel_speed=30.0, settings=settings, state=MOVING, seed=4)
    a = run_twin(None, duration=1.0, wheel_speed=30.0, settings=settings, state=MOVING, seed=4)
    b = run_twin(None, duration=1.0, settings=settings, state=a.state, seed=5)
    two = join_runs(a, b)
    np.testing.assert_allclose(two.truth.t, one.truth.t, rtol=0, atol=1e-12)
    for name in ("q", "qd", "base_w"):
        np.testing.assert_allclose(getattr(two.truth, name), getattr(one.truth, name), rtol=0, atol=1e-12)
    np.testing.assert_allclose(two.co2_mass, one.co2_mass, rtol=0, atol=1e-15)
    assert one.co2_mass[-1] < one.co2_mass[0]
    np.testing.assert_allclose(two.recording.joints.position, one.recording.joints.position, atol=1e-12)
    np.testing.assert_allclose(two.recording.joints.velocity, one.recording.joints.velocity, atol=1e-9)
    np.testing.assert_allclose(two.effort, one.effort, atol=1e-12)
    np.testing.assert_allclose(two.recording.joints.t, one.recording.joints.t, atol=1e-12)
    assert len(two.recording.base.t) == 0 or np.all(np.diff(two.recording.base.t) > 0)
    assert two.meta["seed"] == [4, 5] and two.meta["co2_mass_end"] == b.meta["co2_mass_end"]


# ------------------------------------------------------------------ controllers -----------------


def test_spin_up_reaches_170_within_effort_limit(experiment):
    a, _, _ = experiment
    wheel = a.truth.qd[:, 0]
    t_ramp = 170.0 / 100.0
    assert np.abs(wheel[a.truth.t > t_ramp + 1.3] - 170.0).max() < 0.5  # settled ~1 s after the ramp
    assert abs(wheel[-1] - 170.0) < 0.05
    assert np.abs(a.effort[:, 0]).max() <= 0.5  # within the model's effort limit (not saturated)
    # the rest of the system carries -I_rw (w0 + w_rw) + h0 (docs/theory/scale.md)
    h = angular_momentum(MODEL, a.truth.q, a.truth.qd, a.truth.base_w)[:, 2]
    spin = I_RW * (a.truth.qd[-1, 0] + a.truth.base_w[-1, 2])
    assert spin > 0.33 and abs(h[-1] - h[0]) < 1e-9 * spin  # the base counter-rotates


@pytest.mark.slow
def test_feedforward_improves_tracking():
    traj = load_trajectory("paper-table2")
    plain = run_twin(traj, duration=5.0, seed=0)
    ff = run_twin(traj, duration=5.0, seed=0, settings=TwinSettings(controllers=Controllers(feedforward=True)))
    for joint in ("left_shoulder", "left_elbow"):
        assert ff.meta["tracking_rms"][joint] < 0.5 * plain.meta["tracking_rms"][joint]
    assert Controllers().position["left_shoulder"] == PID(p=0.1, d=0.04)
    assert Controllers().position["left_elbow"] == PID(p=0.1, d=0.02)


def test_torque_limits_respected():
    gains = Controllers(position={"left_shoulder": PID(p=50.0, d=1.0), "left_elbow": PID(p=50.0, d=1.0)})
    step = lambda t: (np.tile([0.8, -0.8], (len(t), 1)), np.zeros((len(t), 2)))  # noqa: E731
    limited = run_twin(step, duration=0.3, settings=TwinSettings(controllers=gains))
    limits = np.array([0.5, 1.0, 1.0])  # the model's joint effort limits
    assert np.all(np.abs(limited.effort) <= limits + 1e-15)
    assert np.isclose(np.abs(limited.effort[:, 1:]).max(), 1.0)
    free = run_twin(step, duration=0.3, settings=TwinSettings(controllers=gains, torque_limits=TorqueLimits(enabled=False)))
    assert np.abs(free.effort[:, 1:]).max() > 10.0
    custom = run_twin(step, duration=0.3, settings=TwinSettings(
        controllers=gains, torque_limits=TorqueLimits(effort={"left_shoulder": 0.2})))
    assert np.isclose(np.abs(custom.effort[:, 1]).max(), 0.2) and np.abs(custom.effort[:, 2]).max() > 10.0


# ------------------------------------------------------------------ effects ---------------------


def test_thruster_couple_changes_angular_momentum_by_its_impulse():
    """The +1 thrusters of all three pairs: a pure couple 3 F r, no net force."""
    thrusters = Thrusters(schedule=tuple((0.2, 0.7, k, 1) for k in range(3)))
    settings = replace(IDEAL, thrusters=thrusters)  # tank off: no mass leaves
    run = run_twin(None, duration=1.0, settings=settings, state=MOVING)
    p = centroidal(run)
    impulse = 3 * thrusters.force * thrusters.radius * 0.5
    assert math.isclose(p[-1, 2] - p[0, 2], impulse, rel_tol=1e-9)
    assert np.abs(p[:, :2] - p[0, :2]).max() < 1e-12
    # the documented layout, by hand: pair 1 at 300 deg, pair 2 at 60 deg, 0.2 N at 0.2 m
    c30, s30 = math.sqrt(3) / 2, 0.5
    np.testing.assert_allclose(thruster_wrenches(thrusters), [
        [0, -0.2, 0.04], [0, 0.2, -0.04],
        [0.2 * c30, 0.2 * s30, 0.04], [-0.2 * c30, -0.2 * s30, -0.04],
        [-0.2 * c30, 0.2 * s30, 0.04], [0.2 * c30, -0.2 * s30, -0.04]], atol=1e-15)


def test_single_thruster_linear_impulse():
    """Pair 0, sign +1 at the back of the base (angle pi) pushes along base -y."""
    thrusters = Thrusters(schedule=((0.1, 0.3, 0, 1),))
    settings = replace(IDEAL, thrusters=thrusters)
    run = run_twin(None, duration=0.5, settings=settings)
    p = centroidal(run)
    t = run.truth.t
    f_b = thruster_wrenches(thrusters)[0, :2]
    np.testing.assert_allclose(f_b, [0, -0.2], atol=1e-15)
    # impulse of the base-fixed force R(yaw(t)) f_b over the open ticks [t_k, t_k+1): Gauss-Legendre
    # on the true yaw (cubic Hermite between ticks, error ~dt^4)
    k = np.flatnonzero((t >= 0.1 - 1e-12) & (t < 0.3 - 1e-12))
    nodes, weights = np.polynomial.legendre.leggauss(4)
    dt = t[1] - t[0]
    tt = (t[k][:, None] + dt * (nodes + 1) / 2).ravel()
    yaw = hermite_motion(t, run.truth.base_yaw, run.truth.base_w[:, 2])(tt)[0]
    f_w = np.column_stack([np.cos(yaw) * f_b[0] - np.sin(yaw) * f_b[1], np.sin(yaw) * f_b[0] + np.cos(yaw) * f_b[1]])
    expected = (f_w * np.tile(weights, len(k))[:, None]).sum(0) * dt / 2
    np.testing.assert_allclose(p[-1, :2] - p[0, :2], expected, rtol=0, atol=1e-12)
    assert len(k) == 200 and abs(expected[0]) > 1e-5  # the base turned while firing
    assert run.truth.base_w[-1, 2] > 0  # +1 thrusters turn the base counter-clockwise


def test_tank_drains_by_the_integral_of_mass_flow():
    thrusters = Thrusters(schedule=((0.1, 0.6, 0, 1), (0.3, 0.5, 2, -1)))
    settings = replace(IDEAL, thrusters=thrusters, tank=Tank(bearing_flow=1e-4))
    run = run_twin(None, duration=1.0, settings=settings, seed=0)
    tank = settings.tank
    flow_valve = thrusters.force / (tank.isp * G0)
    used = (0.5 * flow_valve + 0.2 * flow_valve) + 1.0 * tank.bearing_flow
    assert math.isclose(run.co2_mass[0] - run.co2_mass[-1], used, rel_tol=1e-9)
    assert np.all(np.diff(run.co2_mass) <= 0)
    assert run.meta["co2_mass_start"] == 0.5 and math.isclose(run.meta["co2_mass_end"], 0.5 - used)
    assert math.isclose(run.meta["base_mass_start"] - run.meta["base_mass_end"], used)
    drained = drained_model(MODEL, tank, run.co2_mass[-1])
    assert math.isclose(drained.bodies[0].mass, MODEL.bodies[0].mass - used, rel_tol=1e-12)
    assert drained.bodies[0].com[0] > 0  # the tank sits at x = -0.05: the base CoM moves forward
    # the drained model is what the twin integrates: momentum of the drained system is conserved
    # once the valves close (bearing flow at the base CoM only, so it changes little)
    quiet = run_twin(None, duration=0.5, settings=replace(settings, tank=replace(tank, bearing_flow=0.0)),
                     state=run.state)
    drained_now = drained_model(MODEL, tank, quiet.co2_mass[-1])
    h = angular_momentum(drained_now, quiet.truth.q, quiet.truth.qd, quiet.truth.base_w)[:, 2]
    assert np.abs(h - h[0]).max() < 1e-12 and abs(h[0]) > 1e-3
    h_full = angular_momentum(MODEL, quiet.truth.q, quiet.truth.qd, quiet.truth.base_w)[:, 2]
    assert np.abs(h_full - h_full[0]).max() > 1e3 * np.abs(h - h[0]).max()


def test_empty_tank_gives_no_thrust():
    settings = replace(IDEAL, thrusters=Thrusters(schedule=((0.0, 1.0, 1, 1),)), tank=Tank(co2_mass=1e-4))
    run = run_twin(None, duration=1.0, settings=settings)
    empty = np.flatnonzero(run.co2_mass == 0)[0]
    assert 0 < empty < len(run.co2_mass) - 10
    p = centroidal(run, model=drained_model(MODEL, settings.tank, 0.0))
    assert np.abs(p[empty + 1 :] - p[empty + 1]).max() < 1e-12  # no impulse after the tank is empty
    assert np.abs(p[empty] - p[0]).max() > 1e-3


def test_bearing_friction_dissipates_momentum():
    viscous = replace(IDEAL, bearing_friction=BearingFriction(viscous_force=0.5, coulomb_force=0.0,
                                                              viscous_torque=0.01, coulomb_torque=0.0))
    run = run_twin(None, duration=3.0, settings=viscous, state=TwinState(base_vxy=(0.02, 0.01), base_yaw=1.0))
    p = centroidal(run, every=10)
    speed = np.linalg.norm(p[:, :2], axis=1)
    assert np.all(np.diff(speed) < 0)
    # a rigid translation (the arm holds; no rotation): p(t) = p0 exp(-c t / M), along p0
    np.testing.assert_allclose(p[-1, :2] / p[0, :2], math.exp(-0.5 * 3.0 / MODEL.mass), rtol=1e-4)
    spin = run_twin(None, duration=1.0, settings=viscous, state=TwinState(base_wz=0.3))
    h = centroidal(spin, every=10)[:, 2]
    assert np.all(np.diff(h) < 0) and h[-1] < 0.97 * h[0]
    coulomb = replace(IDEAL, bearing_friction=BearingFriction(viscous_force=0.0, coulomb_force=0.1,
                                                              viscous_torque=0.0, coulomb_torque=0.0))
    run = run_twin(None, duration=2.5, settings=coulomb, state=TwinState(base_vxy=(0.01, 0.0)))
    v = np.linalg.norm(run.base_velocity, axis=1)
    t_stop = 0.01 * MODEL.mass / 0.1  # ~1.0 s: constant deceleration F_c / M
    assert v[run.truth.t < 0.9 * t_stop].min() > 5e-4 and v[run.truth.t > 1.5 * t_stop].max() < 1e-4


def test_joint_friction_is_internal():
    """Joint friction slows the wheel relative to the base but does not change the momentum."""
    settings = replace(IDEAL, controllers=Controllers(position={}, velocity={}),
                       joint_friction=JointFriction(viscous={"reaction_wheel_joint": 1e-4},
                                                    coulomb={"reaction_wheel_joint": 1e-3}))
    state = TwinState(q=np.zeros(3), qd=np.array([20.0, 0, 0]))
    run = run_twin(None, duration=3.0, settings=settings, state=state)
    log = run.truth
    h = angular_momentum(MODEL, log.q, log.qd, log.base_w)[:, 2]
    assert np.abs(h - h[0]).max() < 1e-9 * abs(h[0])
    rel = log.qd[:, 0]
    assert np.all(np.diff(rel) < 0)
    # sliding friction c qd + F_c on the relative rate, I_rel = I_rw I_rest / (I_rw + I_rest):
    # qd(t) = (qd0 + F_c / c) exp(-c t / I_rel) - F_c / c
    i_rel = 1.0 / (1.0 / I_RW + 1.0 / (MODEL.bodies[0].inertial[9] + 0.0148))  # rest: base + arm
    expected = (20.0 + 10.0) * np.exp(-1e-4 * log.t / i_rel) - 10.0
    np.testing.assert_allclose(rel, expected, rtol=2e-3)
    assert run.effort.max() == 0.0  # no controllers


def test_table_tilt_accelerates_the_system():
    tilt = 1e-3
    settings = replace(IDEAL, table_tilt=tilt, tilt_azimuth=math.pi / 2)
    run = run_twin(None, duration=1.0, settings=settings)
    p = centroidal(run)
    np.testing.assert_allclose(p[-1, :2], [0.0, MODEL.mass * G0 * math.sin(tilt) * 1.0], rtol=1e-9, atol=1e-12)


# ------------------------------------------------------------------ sensors ---------------------


def test_encoders_quantise_and_publish_at_50_hz():
    run = run_twin(load_trajectory("paper-table2"), duration=1.0, wheel_speed=20.0, seed=0)
    js = run.recording.joints
    assert js.names == ("reaction_wheel_joint", "left_shoulder", "left_elbow")
    np.testing.assert_allclose(np.diff(js.t), 0.02, atol=1e-12)
    assert js.t[0] == 0.0 and js.t[-1] < 1.0
    res = 2 * np.pi / np.array([4096, 20000, 20000])
    counts = js.position / res
    np.testing.assert_allclose(counts, np.round(counts), atol=1e-6)
    rows = np.searchsorted(run.truth.t, js.t)
    err = js.position - run.truth.q[rows]
    assert np.all(np.abs(err) <= res / 2 + 1e-12) and np.abs(err).max() > 0.1 * res.min()
    steps = js.velocity / (res * 1000.0)  # one count per control period
    np.testing.assert_allclose(steps, np.round(steps), atol=1e-6)
    np.testing.assert_allclose(js.effort, run.effort[rows], atol=0)
    quiet = run_twin(None, duration=0.2, settings=TwinSettings(encoders=Encoders(velocity=None, counts_per_rev={})))
    assert quiet.recording.joints.velocity is None
    np.testing.assert_array_equal(quiet.recording.joints.position, quiet.truth.q[:-1:20])


@pytest.mark.slow
def test_motion_capture_noise_drops_and_latency():
    mc = MotionCapture(drop_probability=0.2, latency=0.0123)
    run = run_twin(None, duration=10.0, settings=TwinSettings(mocap=mc), state=MOVING, seed=7)
    poses = run.recording.base
    n = run.meta["mocap_frames"]
    assert n == 1000 and run.meta["mocap_dropped"] == n - len(poses.t)
    assert abs(run.meta["mocap_dropped"] - 0.2 * n) < 4 * math.sqrt(n * 0.2 * 0.8)
    capture = poses.t - mc.latency
    np.testing.assert_allclose(capture * 100, np.round(capture * 100), atol=1e-6)  # 100 Hz grid
    true_pose, _ = hermite_motion(run.truth.t, np.column_stack([run.base_position, run.truth.base_yaw]),
                                  np.column_stack([run.base_velocity, run.truth.base_w[:, 2]]))(capture)
    dpos = poses.position[:, :2] - true_pose[:, :2]
    dyaw = np.angle(np.exp(1j * (quat_to_yaw(poses.quat) - true_pose[:, 2])))
    assert 0.9 < dpos.std() / mc.position_noise < 1.1 and 0.9 < dyaw.std() / mc.attitude_noise < 1.1
    assert np.all(poses.position[:, 2] == 0) and np.all(poses.quat[:, 0] >= 0)
    np.testing.assert_allclose(np.linalg.norm(poses.quat, axis=1), 1.0)
    assert poses.frame == "world"
    exact = run_twin(None, duration=1.0, state=MOVING, settings=TwinSettings(
        mocap=MotionCapture(position_noise=0, attitude_noise=0, drop_probability=0, latency=0.01)))
    p = exact.recording.base
    rows = np.searchsorted(exact.truth.t, p.t - 0.01 - 1e-9)
    np.testing.assert_allclose(p.position[:, :2], exact.base_position[rows], atol=1e-12)
    np.testing.assert_allclose(quat_to_yaw(p.quat), np.angle(np.exp(1j * exact.truth.base_yaw[rows])), atol=1e-12)


def test_reproducible_with_a_seed():
    a = run_twin(None, duration=1.0, state=MOVING, seed=11)
    b = run_twin(None, duration=1.0, state=MOVING, seed=11)
    c = run_twin(None, duration=1.0, state=MOVING, seed=12)
    for x, y in ((a, b),):
        np.testing.assert_array_equal(x.recording.base.position, y.recording.base.position)
        np.testing.assert_array_equal(x.recording.base.t, y.recording.base.t)
        np.testing.assert_array_equal(x.recording.joints.position, y.recording.joints.position)
    assert not np.array_equal(a.recording.base.position[:50], c.recording.base.position[:50])
    np.testing.assert_array_equal(a.truth.q, c.truth.q)  # only the sensors are random
    assert a.meta["seed"] == 11 and a.recording.meta["seed"] == 11 and c.meta["seed"] == 12
    json.dumps(a.meta)  # provenance is JSON-ready (settings included)
    assert a.meta["settings"]["controllers"]["position"]["left_shoulder"]["p"] == 0.1


# ------------------------------------------------------------------ errors ----------------------


@pytest.mark.parametrize(
    "make, match",
    [
        (lambda: Controllers(rate=-1000), r"controllers.rate \[Hz\] must be greater than 0"),
        (lambda: MotionCapture(rate=0), r"mocap.rate \[Hz\] must be greater than 0"),
        (lambda: MotionCapture(drop_probability=1.0), r"mocap.drop_probability must be in \[0, 1\)"),
        (lambda: MotionCapture(position_noise=-1e-3), r"mocap.position_noise must be at least 0"),
        (lambda: PID(p=-0.1), r"PID.p must be at least 0"),
        (lambda: Controllers(position={"left_shoulder": PID(0.1)}, velocity={"left_shoulder": PID(0.1)}),
         r"joint 'left_shoulder' has both a position and a velocity controller"),
        (lambda: Controllers(velocity={"reaction_wheel_joint": PID(0.1, d=0.1)}), r"velocity\['reaction_wheel_joint'\].d"),
        (lambda: Thrusters(schedule=((1.0, 0.5, 0, 1),)), r"thrusters.schedule\[0\]: t_off = 0.5 s must be after"),
        (lambda: Thrusters(schedule=((0.0, 0.5, 3, 1),)), r"thrusters.schedule\[0\]: pair must be 0, 1 or 2"),
        (lambda: Thrusters(schedule=((0.0, 0.5, 0, 2),)), r"sign must be \+1 or -1"),
        (lambda: Tank(isp=0), r"tank.isp \[s\] must be greater than 0"),
        (lambda: BearingFriction(speed_scale=0), r"bearing_friction.speed_scale must be greater than 0"),
        (lambda: Encoders(velocity="filtered"), r"encoders.velocity must be 'difference' or None"),
        (lambda: TwinSettings(controllers="fast"), r"settings.controllers must be a Controllers"),
    ],
)
def test_bad_settings(make, match):
    with pytest.raises(SpaceidError, match=match):
        make()


@pytest.mark.parametrize(
    "kwargs, match",
    [
        (dict(settings=TwinSettings(controllers=Controllers(position={"left_wrist": PID(0.1)}))),
         r"controllers.position names joint 'left_wrist', which is not in model cepheus-rw"),
        (dict(settings=TwinSettings(encoders=Encoders(counts_per_rev={"wheel": 100}))),
         r"encoders.counts_per_rev names joint 'wheel'"),
        (dict(settings=TwinSettings(encoders=Encoders(rate=2000.0))), r"encoders.rate = 2000 Hz exceeds controllers.rate"),
        (dict(settings=TwinSettings(joint_friction=JointFriction(rate_scale=1e-4))),
         r"friction on joint 'left_elbow' is too stiff .* raise joint_friction.rate_scale"),
        (dict(settings=TwinSettings(model=load_model("cepheus-rw", planar=False))), r"is not planar"),
        (dict(settings=TwinSettings(tank=Tank(co2_mass=20.0))), r"tank.co2_mass = 20 kg leaves the base"),
        (dict(duration=1e-5), r"`duration` = 1e-05 s is shorter than one control period"),
        (dict(duration=-1.0), r"`duration` \[s\] must be greater than 0"),
        (dict(reference=load_trajectory("paper-table2"), settings=TwinSettings(
            controllers=Controllers(position={"left_shoulder": PID(0.1)}))),
         r"`reference` drives joints \(left_shoulder, left_elbow\) but the position-controlled joints are "
         r"\(left_shoulder\)"),
        (dict(reference=lambda t: (np.zeros((len(t), 3)), np.zeros((len(t), 3)))),
         r"`reference`\(t\) returned 3 columns"),
        (dict(state=TwinState(q=[0.0, 0.0])), r"twin: field 'state.q' must have shape \(3,\), got \(2,\)"),
        (dict(state=TwinState(co2_mass=1.0)), r"state.co2_mass = 1 kg exceeds the full tank"),
        (dict(wheel_speed=float("nan")), r"`wheel_speed` \[rad/s\] must be a finite number"),
    ],
)
def test_bad_run_arguments(kwargs, match):
    kwargs = {"duration": 0.01, **kwargs}
    with pytest.raises(SpaceidError, match=match):
        run_twin(kwargs.pop("reference", None), **kwargs)


def test_join_runs_refuses_a_gap():
    a = run_twin(None, duration=0.05)
    b = run_twin(None, duration=0.05)  # starts at 0 again, not at a.state
    with pytest.raises(SpaceidError, match=r"join_runs: a phase starts at t = 0 s but the previous one ends at 0.05 s"):
        join_runs(a, b)


@pytest.mark.slow
def test_planned_feedforward_tracks_like_the_true_state_one():
    # the prior model is the twin's own here: planned offline (base rate from zero momentum) it
    # must do what the feed-forward reading the true state does
    traj = load_trajectory("paper-table2")
    ideal = TwinSettings().without_effects()
    planned = lambda t: planned_feedforward(traj, t, settings=ideal)  # noqa: E731
    ff = run_twin(traj, duration=5.0, seed=0, settings=ideal, effort=planned)
    plain = run_twin(traj, duration=5.0, seed=0, settings=ideal)
    for joint in ("left_shoulder", "left_elbow"):
        assert ff.meta["tracking_rms"][joint] < 1e-3 < 0.1 * plain.meta["tracking_rms"][joint]
    efforts = planned(np.linspace(0.0, 5.0, 11))
    assert efforts.shape == (11, 2) and np.abs(efforts).max() > 0.01


def test_effort_input_is_checked():
    with pytest.raises(SpaceidError, match="`effort`\\(t\\) must return an array of shape"):
        run_twin(None, duration=0.01, effort=lambda t: np.zeros((len(t), 3)))
    with pytest.raises(SpaceidError, match="`effort` must be a callable"):
        run_twin(None, duration=0.01, effort=np.zeros(2))
