"""The Cepheus twin grasps a free-floating payload: momentum through the grasp and over the run, the
combined system afterwards, the truth record, the recorded bag and the settings' errors."""

import json
import math
from dataclasses import replace

import numpy as np
import pinocchio as pin
import pytest

from spaceid import SpaceidError, load_model
from spaceid.data import read_bag_log, write_bag
from spaceid.dynamics import angular_momentum, minimal_parameters
from spaceid.models import attach_payload
from spaceid.motion import hermite_motion, simulate
from spaceid.twin import (
    Capture,
    Tank,
    Thrusters,
    TwinSettings,
    TwinState,
    drained_model,
    join_runs,
    place_payload,
    planar_pinocchio,
    run_twin,
)

MODEL = load_model("cepheus-rw")
IDEAL = TwinSettings().without_effects()
MOVING = TwinState(base_wz=0.3, base_vxy=(0.01, -0.02))  # the robot carries momentum, angular and linear
# a drifting, turning payload, grasped at 1.2 s by the arm's end link, its CoM off the link's x axis
PAYLOAD = Capture(time=1.2, mass=0.6, com=(0.03, -0.02), position=(0.55, 0.25), yaw=0.4, velocity=(-0.015, 0.01),
                  rate=-0.2, inertia=((8e-4, 1e-4, 0.0), (1e-4, 9e-4, 0.0), (0.0, 0.0, 1.1e-3)))  # fmt: skip
POINT = np.array([0.3, -0.7])  # a fixed point of the table, not the origin
DURATION = 2.5


def reference(t):
    """Arm set points [rad, rad/s] on the twin's clock ``t`` [s]: a swing that moves through the grasp."""
    t = np.asarray(t, float)[:, None]
    w = np.array([2.1, 2.9])
    return 0.4 * np.sin(w * t), 0.4 * w * np.cos(w * t)


def run(settings, *, duration=DURATION, state=MOVING, start=0.0, seed=1):
    return run_twin(lambda t: reference(t + start), duration=duration, wheel_speed=20.0, settings=settings,
                    state=state, seed=seed)  # fmt: skip


@pytest.fixture(scope="module")
def grasping():
    return run(replace(IDEAL, capture=PAYLOAD))


def payload_in_link(q_pin, capture=PAYLOAD, link="link2"):
    """The payload's inertial parameters (10,) about the link origin, link axes, at the grasp
    configuration, by Pinocchio's rigid-body transforms (independent of spaceid.twin)."""
    pm = planar_pinocchio(MODEL)
    data = pm.createData()
    pin.framesForwardKinematics(pm, data, q_pin)
    yaw = capture.yaw + capture.rate * capture.time
    start = pin.SE3(pin.rpy.rpyToMatrix(0, 0, capture.yaw), np.r_[capture.position, 0.0])
    com0 = start.act(np.r_[capture.com, 0.0])
    com = com0[:2] + np.asarray(capture.velocity) * capture.time
    rot = pin.rpy.rpyToMatrix(0, 0, yaw)
    frame = pin.SE3(rot, np.r_[com, 0.0] - rot @ np.r_[capture.com, 0.0])
    body = pin.Inertia(capture.mass, np.r_[capture.com, 0.0], np.array(capture.inertia))
    link_frame = data.oMf[pm.getFrameId(link)]
    return link_frame.actInv(frame.act(body)).toDynamicParameters(), com


def momentum_about(model, q_pin, v_pin, point=POINT):
    """``[p_x, p_y, L_z]`` of the robot about a fixed table point, from Pinocchio's centroidal momentum."""
    pm = planar_pinocchio(model)
    data = pm.createData()
    h = pin.computeCentroidalMomentum(pm, data, q_pin, v_pin)
    r = data.com[0][:2] - point
    return np.array([h.linear[0], h.linear[1], h.angular[2] + r[0] * h.linear[1] - r[1] * h.linear[0]])


def payload_momentum(com, capture=PAYLOAD, point=POINT):
    p = capture.mass * np.asarray(capture.velocity)
    r = com - point
    return np.array([p[0], p[1], capture.inertia[2][2] * capture.rate + r[0] * p[1] - r[1] * p[0]])


def coordinates(r, i):
    return (np.r_[r.base_position[i], r.truth.base_yaw[i], r.truth.q[i]],
            np.r_[r.base_velocity[i], r.truth.base_w[i, 2], r.truth.qd[i]])  # fmt: skip


# ------------------------------------------------------------------ momentum --------------------


def test_grasp_conserves_total_momentum(grasping):
    record = grasping.meta["capture"]
    k = int(np.flatnonzero(np.isclose(grasping.truth.t, record["time"], rtol=0, atol=1e-9))[0])
    q, v_before = coordinates(grasping, k)  # the sample at the grasp tick is the state just before
    np.testing.assert_allclose(record["velocity_before"], v_before, rtol=0, atol=0)
    inertial, com = payload_in_link(q)
    combined = attach_payload(MODEL, "link2", inertial)
    before = momentum_about(MODEL, q, v_before) + payload_momentum(com)
    after = momentum_about(combined, q, np.array(record["velocity_after"]))
    assert np.abs(np.array(record["velocity_after"]) - v_before).max() > 0.05  # the grasp jolts the arm
    assert np.abs(after - before).max() <= 1e-10 * np.abs(before).max()
    # an attachment that kept the robot's rates would not conserve it: the test can tell
    assert np.abs(momentum_about(combined, q, v_before) - before).max() > 1e-3 * np.abs(before).max()


def test_momentum_conserved_over_the_run(grasping):
    record = grasping.meta["capture"]
    k = int(np.flatnonzero(np.isclose(grasping.truth.t, record["time"], rtol=0, atol=1e-9))[0])
    assert 0 < k < len(grasping.truth.t) - 1
    inertial, _ = payload_in_link(coordinates(grasping, k)[0])
    combined = attach_payload(MODEL, "link2", inertial)
    total = []
    for i in range(0, len(grasping.truth.t), 25):
        q, v = coordinates(grasping, i)
        if i <= k:  # the robot and the payload floating freely
            drift = np.asarray(PAYLOAD.velocity) * (grasping.truth.t[i] - record["time"])
            total.append(momentum_about(MODEL, q, v) + payload_momentum(record["payload_at_grasp"]["com"] + drift))
        else:
            total.append(momentum_about(combined, q, v))
    total = np.array(total)
    assert np.abs(total - total[0]).max() <= 1e-9 * np.abs(total[0]).max()


def test_grasp_impulse_acts_between_link_and_payload_only(grasping):
    """Every generalised coordinate (joints too) changes by the impulse the payload gives the link,
    as a plastic impact with no impulsive motor torque; the impact loses kinetic energy."""
    record = grasping.meta["capture"]
    k = int(round(record["time"] * 1000))
    q, v_before = coordinates(grasping, k)
    v_after = np.array(record["velocity_after"])
    _, com = payload_in_link(q)
    pm = planar_pinocchio(MODEL)
    data = pm.createData()
    jac = pin.computeFrameJacobian(pm, data, q, pm.getFrameId("link2"), pin.LOCAL_WORLD_ALIGNED)
    arm = np.r_[com, 0.0] - data.oMf[pm.getFrameId("link2")].translation
    j_com = jac[:3] - pin.skew(arm) @ jac[3:]  # velocity of the held payload's CoM, world axes
    # the payload's momentum change: linear at its CoM, angular about it (planar)
    push = PAYLOAD.mass * (j_com @ v_after - np.r_[PAYLOAD.velocity, 0.0])
    turn = PAYLOAD.inertia[2][2] * ((jac[5] @ v_after) - PAYLOAD.rate)
    mass_matrix = pin.crba(pm, data, q)
    mass_matrix = np.triu(mass_matrix) + np.triu(mass_matrix, 1).T
    generalised = -(j_com.T @ push + jac[5] * turn)
    np.testing.assert_allclose(mass_matrix @ (v_after - v_before), generalised, rtol=0,
                               atol=1e-12 * np.abs(generalised).max())  # fmt: skip
    assert abs(turn) > 1e-6 and np.abs(push).max() > 1e-3  # a real impulse
    inertial, _ = payload_in_link(q)
    pc = planar_pinocchio(attach_payload(MODEL, "link2", inertial))
    mass_after = pin.crba(pc, pc.createData(), q)
    mass_after = np.triu(mass_after) + np.triu(mass_after, 1).T
    payload_energy = PAYLOAD.mass * np.dot(PAYLOAD.velocity, PAYLOAD.velocity) + PAYLOAD.inertia[2][2] * PAYLOAD.rate**2
    energy_before = 0.5 * (v_before @ mass_matrix @ v_before + payload_energy)
    energy_after = 0.5 * v_after @ mass_after @ v_after
    assert 0 < energy_after < energy_before


@pytest.mark.parametrize("link", ["base", "link1"])
def test_other_links_grasp_and_conserve_momentum(link):
    capture = replace(PAYLOAD, link=link, time=0.3)
    r = run(replace(IDEAL, capture=capture), duration=0.5)
    record = r.meta["capture"]
    assert record["link"] == link
    k = int(round(record["time"] * 1000))
    q, v = coordinates(r, k)
    inertial, com = payload_in_link(q, capture, link)
    np.testing.assert_allclose(record["payload"]["inertial"], inertial, rtol=0, atol=1e-13)
    before = momentum_about(MODEL, q, v) + payload_momentum(com, capture)
    after = momentum_about(attach_payload(MODEL, link, inertial), q, np.array(record["velocity_after"]))
    assert np.abs(after - before).max() <= 1e-10 * np.abs(before).max()


# ------------------------------------------------------------------ after the grasp -------------


def test_post_grasp_motion_is_the_combined_model(grasping):
    """Up to the grasp tick, then from it: the same run in two phases; the second equals a twin
    of the combined model (the payload added to the link) started from the post-grasp state."""
    settings = replace(IDEAL, capture=PAYLOAD)
    a = run(settings, duration=PAYLOAD.time)  # ends at the grasp tick: the grasp is the next phase's
    assert "capture" not in a.meta and a.state.grasp is None
    b = run(settings, duration=DURATION - PAYLOAD.time, state=a.state, start=PAYLOAD.time, seed=2)
    assert b.meta["capture"]["time"] == PAYLOAD.time
    joined = join_runs(a, b)
    for name in ("q", "qd", "base_w"):
        np.testing.assert_allclose(getattr(joined.truth, name), getattr(grasping.truth, name), rtol=0, atol=1e-12)
    np.testing.assert_allclose(joined.effort, grasping.effort, rtol=0, atol=1e-12)
    assert joined.meta["capture"] == grasping.meta["capture"]

    inertial, _ = payload_in_link(coordinates(a, -1)[0])
    combined = replace(IDEAL, model=attach_payload(MODEL, "link2", inertial))
    v = np.array(b.meta["capture"]["velocity_after"])
    held = replace(a.state, base_vxy=v[:2], base_wz=v[2], qd=v[3:])
    c = run(combined, duration=DURATION - PAYLOAD.time, state=held, start=PAYLOAD.time, seed=2)
    for name in ("q", "qd", "base_w"):
        np.testing.assert_allclose(getattr(c.truth, name)[1:], getattr(b.truth, name)[1:], rtol=0, atol=1e-12)
    np.testing.assert_allclose(c.base_position, b.base_position, rtol=0, atol=1e-12)


@pytest.mark.slow
def test_post_grasp_base_motion_matches_the_kinematic_simulation(grasping):
    """spaceid.simulate of the combined model with the twin's post-grasp joint motion and momentum
    gives the twin's base motion (the tolerance of tests/test_twin.py's same comparison)."""
    record = grasping.meta["capture"]
    after = grasping.truth.select(grasping.truth.t > record["time"] + 1e-9)
    inertial, _ = payload_in_link(coordinates(grasping, int(round(record["time"] * 1000)))[0])
    combined = attach_payload(MODEL, "link2", inertial)
    h = angular_momentum(combined, after.q[:1], after.qd[:1], after.base_w[:1], after.base_quat[:1])[0]
    param = minimal_parameters(combined)
    sim = simulate(param, param.true_values, hermite_motion(after.t, after.q, after.qd), after.t, h,
                   initial_quat=after.base_quat[0], model=combined)  # fmt: skip
    assert np.abs(after.base_w[:, 2] - after.base_w[0, 2]).max() > 0.05  # the base turns: a real comparison
    np.testing.assert_allclose(sim.base_w[:, 2], after.base_w[:, 2], rtol=0, atol=1e-8)
    np.testing.assert_allclose(sim.base_yaw, after.base_yaw, rtol=0, atol=1e-8)


# ------------------------------------------------------------------ the truth record ------------


def test_truth_record(grasping):
    record = grasping.meta["capture"]
    json.dumps(grasping.meta)  # JSON-ready, the settings' capture section too
    assert grasping.meta["settings"]["capture"]["inertia"] == [list(row) for row in PAYLOAD.inertia]
    assert record["time"] == PAYLOAD.time and record["link"] == "link2"
    assert grasping.recording.meta["capture"] == record and grasping.state.grasp == record
    q = coordinates(grasping, int(round(PAYLOAD.time * 1000)))[0]
    inertial, com = payload_in_link(q)
    np.testing.assert_allclose(record["payload"]["inertial"], inertial, rtol=0, atol=1e-13)
    np.testing.assert_allclose(record["payload_at_grasp"]["com"], com, rtol=0, atol=1e-13)
    payload = record["payload"]
    assert payload["mass"] == PAYLOAD.mass
    link_com = np.array(payload["com"])
    np.testing.assert_allclose(payload["mass"] * link_com, inertial[1:4], rtol=0, atol=1e-13)
    # the inertia about the CoM in link axes is the payload's own, turned about the vertical
    np.testing.assert_allclose(np.linalg.eigvalsh(payload["inertia"]), np.linalg.eigvalsh(PAYLOAD.inertia), atol=1e-15)
    assert payload["inertia"][2][2] == pytest.approx(PAYLOAD.inertia[2][2], abs=1e-16)
    assert abs(link_com[1]) > 1e-3  # off the link's x axis: the link's structural zero mcy is gone
    combined = attach_payload(MODEL, "link2", inertial)
    assert "mcy" not in combined.bodies[-1].known_zero and "mcz" in combined.bodies[-1].known_zero
    before, after = (minimal_parameters(m) for m in (MODEL, combined))
    for entry, param in zip((record["minimal_parameters"]["before"], record["minimal_parameters"]["after"]),
                            (before, after)):
        assert entry["names"] == list(param.names)
        np.testing.assert_allclose(entry["values"], param.true_values, rtol=1e-12, atol=0)
    assert after.n_params == before.n_params + 1


def test_payload_placed_at_the_gripper():
    """place_payload: at the grasp the payload frame sits at the offset in the link frame, turned by yaw."""
    a = run(IDEAL, duration=0.8)
    capture = place_payload(PAYLOAD, "cepheus-rw", a.state, offset=(0.05, -0.01), yaw=0.3)
    assert capture.time == a.state.t and capture.velocity == PAYLOAD.velocity and capture.mass == PAYLOAD.mass
    b = run(replace(IDEAL, capture=capture), duration=0.2, state=a.state, start=0.8)
    payload = b.meta["capture"]["payload"]
    turn = pin.rpy.rpyToMatrix(0, 0, 0.3)
    np.testing.assert_allclose(payload["com"], np.r_[0.05, -0.01, 0.0] + turn @ np.r_[PAYLOAD.com, 0.0], atol=1e-12)
    np.testing.assert_allclose(payload["inertia"], turn @ np.array(PAYLOAD.inertia) @ turn.T, rtol=0, atol=1e-15)


def test_truth_with_the_tank_drained_before_the_grasp():
    """With thrusters firing before the grasp, 'before' is the drained robot at the grasp."""
    settings = TwinSettings(thrusters=Thrusters(schedule=((0.0, 0.2, 0, 1),)), tank=Tank(),
                            capture=replace(PAYLOAD, time=0.3))  # fmt: skip
    r = run(settings, duration=0.4)
    record = r.meta["capture"]
    co2 = r.co2_mass[300]
    assert co2 < settings.tank.co2_mass and record["co2_mass"] == co2
    drained = minimal_parameters(drained_model(MODEL, settings.tank, co2))
    np.testing.assert_allclose(record["minimal_parameters"]["before"]["values"], drained.true_values, rtol=1e-12)


@pytest.mark.slow
def test_bag_carries_the_whole_run(tmp_path):
    """The realistic twin grasps; its bag, read back, covers the run before and after the grasp."""
    r = run(TwinSettings(capture=PAYLOAD), seed=3)
    write_bag(tmp_path / "run.bag", r.recording)
    log = read_bag_log(tmp_path / "run.bag", joints=MODEL.joints, planar=True, wheels=MODEL.wheels)
    t = log.t + log.meta["time_origin_ns"] / 1e9
    assert t[0] < 0.1 and t[-1] > DURATION - 0.1
    # the arm joints as recorded follow the truth on both sides of the grasp
    true = np.interp(t, r.truth.t, r.truth.q[:, 2])
    assert np.abs(log.q[:, 2] - true).max() < 1e-2
    assert r.meta["capture"]["time"] == PAYLOAD.time


# ------------------------------------------------------------------ errors ----------------------


@pytest.mark.parametrize(
    "make, match",
    [
        (lambda: Capture(time=-1.0), r"capture.time \[s\] must be at least 0"),
        (lambda: Capture(time=1.0, mass=0.0), r"capture.mass \[kg\] must be greater than 0"),
        (lambda: Capture(time=1.0, com=(0.0, 0.0, 0.1)), r"capture.com must be 2 finite numbers"),
        (lambda: Capture(time=1.0, velocity=(math.nan, 0.0)), r"capture.velocity must be 2 finite numbers"),
        (lambda: Capture(time=1.0, inertia=(1e-3, 1e-3)), r"capture.inertia must be a 3 x 3 matrix or 3 principal"),
        (lambda: Capture(time=1.0, inertia=(1e-3, -1e-3, 1e-3)), r"capture.inertia: the payload .* not positive"),
        (lambda: Capture(time=1.0, inertia=(1e-3, 1e-3, 3e-3)), r"capture.inertia: the payload violates the triangle"),
        (lambda: Capture(time=1.0, inertia=((1, 0.5, 0), (0, 1, 0), (0, 0, 1))), r"capture.inertia must be symmetric"),
        (lambda: Capture(time=1.0, link=3), r"capture.link must be a body name"),
        (lambda: Capture(time=1.0, rate="fast"), r"capture.rate must be a number"),
        (lambda: TwinSettings(capture={"time": 1.0}), r"settings.capture must be a Capture"),
    ],
)
def test_bad_capture_settings(make, match):
    with pytest.raises(SpaceidError, match=match):
        make()


@pytest.mark.parametrize(
    "kwargs, match",
    [
        (dict(settings=replace(IDEAL, capture=Capture(time=0.0, link="gripper"))),
         (r"capture.link names 'gripper', which is not a body of model cepheus-rw "
          r"\(bodies: base, wheel, link1, link2\): use one of these names")),
        (dict(settings=replace(IDEAL, capture=Capture(time=0.5)), state=TwinState(t=1.0)),
         r"capture.time = 0.5 s is before the phase's start \(t = 1 s\) but the state holds no payload"),
        (dict(state=TwinState(grasp={"link": "link2"})), r"state.grasp must be the grasp record of a run"),
    ],
)
def test_bad_capture_runs(kwargs, match):
    with pytest.raises(SpaceidError, match=match):
        run_twin(None, duration=0.01, **kwargs)


def test_attach_payload_checks_its_inputs():
    with pytest.raises(SpaceidError, match=r"link names 'hand', which is not a body of model cepheus-rw"):
        attach_payload(MODEL, "hand", np.r_[1.0, np.zeros(9)])
    with pytest.raises(SpaceidError, match=r"the payload needs 10 finite inertial parameters with a positive mass"):
        attach_payload(MODEL, "link2", np.zeros(10))
