"""Torque-level validation: the identified model driven by measured torques, against a noise-free
Pinocchio (ABA) simulation of the true floating model under the same torques."""

from dataclasses import replace

import numpy as np
import pinocchio as pin
import pytest
from scipy.integrate import solve_ivp

import spaceid
from spaceid import SpaceidError
from spaceid.cli import main
from spaceid.data import Log, quat_to_matrix, read_log, write_json, write_log, yaw_to_quat
from spaceid.dynamics import minimal_parameters
from spaceid.estimation import identify
from spaceid.identified import identified_model
from spaceid.motion import load_trajectory, simulate
from spaceid.studies import validate_torques
from spaceid.twin import planar_pinocchio

H = np.array([0.0, 0.0, 0.4934])


def aba_log(model, duration=3.0, rate=100.0):
    """The planar floating model under known piecewise-linear joint torques (Pinocchio ABA), from a
    moving state of zero linear momentum; returns the log (with ``tau``) and its angular momentum."""
    pmodel = planar_pinocchio(model)
    data = pmodel.createData()
    n = model.n_joints
    t = np.arange(0.0, duration + 1e-9, 1 / rate)
    tau = np.column_stack([0.002 * np.sin(1.3 * t + j) + 0.001 * np.cos(2.9 * t) for j in range(n)])
    v0 = np.r_[0.0, 0.0, 0.05, 0.2 * np.ones(n)]
    config0 = np.r_[0.0, 0.0, 0.1, 0.3 * np.ones(n)]
    ag = pin.ccrba(pmodel, data, config0, v0)
    v0[:2] = np.linalg.solve(ag[:2, :2], -ag[:2] @ v0)
    h = pin.ccrba(pmodel, data, config0, v0) @ v0

    torque = np.zeros(3 + n)  # the base's generalised forces stay zero

    def rhs(time, y):  # (np.r_ here took 3 of the solve's 5 s: 50,000 calls)
        torque[3:] = [np.interp(time, t, tau[:, j]) for j in range(n)]
        return np.concatenate([y[3 + n :], pin.aba(pmodel, data, y[: 3 + n], y[3 + n :], torque)])

    sol = solve_ivp(rhs, (0, duration), np.r_[config0, v0], method="DOP853", t_eval=t, rtol=1e-12, atol=1e-14)
    y = sol.y.T
    base_w = np.zeros((len(t), 3))
    base_w[:, 2] = y[:, 3 + n + 2]
    log = Log(t, model.joints, y[:, 3 : 3 + n], y[:, 6 + n :], yaw_to_quat(y[:, 2]), base_w, True, {}, None, tau)
    return log, np.r_[0.0, 0.0, h[5]]


@pytest.fixture(scope="module")
def setup():
    model = spaceid.load_model("cepheus")
    param = minimal_parameters(model)
    sim = simulate(param, param.true_values, lambda t: load_trajectory("paper-table2").evaluate(t)[:2],
                   np.linspace(0, 5, 101), H)
    return identified_model(identify(param, sim, H)), aba_log(model)


@pytest.mark.slow  # seconds of batched forward dynamics
def test_true_parameters_tiny_error_perturbed_clearly_larger(setup):
    ident, (log, h) = setup
    _, exact = validate_torques(ident, log, momentum=h, horizon=1.0)
    perturbed = replace(ident.identification,
                        values=ident.values * (1 + 0.05 * np.random.default_rng(0).standard_normal(len(ident.values))))
    _, wrong = validate_torques(perturbed, log, momentum=h, horizon=1.0)
    assert exact["windows"] == 3
    # the integration's error at the default 10 ms steps (8.2e-9 rad, 4.3e-8 rad/s; 5 ms: under 1e-8 both)
    assert exact["torque_q_rms"] < 1e-8 and exact["torque_qd_rms"] < 1e-7 and exact["torque_base_yaw_rms"] < 1e-8
    assert wrong["torque_q_rms"] > 1e4 * exact["torque_q_rms"] and wrong["torque_q_rms"] > 1e-4
    assert wrong["torque_base_w_rms"] > 1e-4


def test_missing_efforts_and_bad_horizon(setup):
    ident, (log, h) = setup
    with pytest.raises(SpaceidError, match="no joint efforts"):
        validate_torques(ident, replace(log, tau=None), momentum=h)
    with pytest.raises(SpaceidError, match="positive horizon"):
        validate_torques(ident, log, momentum=h, horizon=0.0)


@pytest.mark.slow  # seconds of batched forward dynamics
def test_csv_and_command_line(setup, tmp_path, capsys):
    ident, (log, h) = setup
    write_log(tmp_path / "log.csv", log)
    back = read_log(tmp_path / "log.csv", joints=log.joints, planar=True)
    np.testing.assert_array_equal(back.tau, log.tau)
    write_json(tmp_path / "r.json", ident.identification.to_dict())
    capsys.readouterr()
    assert main(["validate", str(tmp_path / "r.json"), str(tmp_path / "log.csv"), "--momentum", str(h[2]),
                 "--torques", "--horizon", "1.5", "-o", str(tmp_path / "out"), "--png"]) == 0
    printed = capsys.readouterr().out
    assert "torque-driven joint angles, RMS error [rad]" in printed
    metrics = spaceid.data.read_json(tmp_path / "out" / "torque_metrics.json")
    assert metrics["torque_q_rms"] < 1e-8 and metrics["windows"] == 2
    assert (tmp_path / "out" / "torque_validation.png").stat().st_size > 10_000
    write_log(tmp_path / "bare.csv", replace(log, tau=None))
    assert main(["validate", str(tmp_path / "r.json"), str(tmp_path / "bare.csv"), "--momentum", str(h[2]),
                 "--torques", "-o", str(tmp_path / "out2")]) == 2
    assert "no joint efforts (columns tau_left_shoulder, tau_left_elbow)" in capsys.readouterr().err


def test_inconsistent_parameters_are_refused(setup):
    """Parameters whose H* is indefinite would run away: the validation says so instead."""
    ident, (log, h) = setup
    broken = replace(ident.identification, values=ident.values * np.where(np.arange(len(ident.values)) == 0, -5, 1))
    assert (np.linalg.eigvalsh(identified_model(broken).reduced_inertia(log.q))[:, 0] <= 0).any()
    with pytest.raises(SpaceidError, match="not positive definite"):
        validate_torques(broken, log, momentum=h)


@pytest.mark.slow  # seconds of batched forward dynamics
def test_the_twin_under_its_own_efforts():
    """The twin's true 1 kHz motion and applied efforts (zero-order hold): the true model's
    forward dynamics reproduce it; its bag carries the mocap position and published efforts."""
    import tempfile

    from spaceid.data import read_bag_log, write_bag
    from spaceid.estimation import Identification
    from spaceid.identified import IdentifiedModel
    from spaceid.twin import TwinSettings, run_twin

    settings = TwinSettings().without_effects()
    model = spaceid.load_model("cepheus-rw")
    run = run_twin(load_trajectory("paper-table2"), duration=0.4, wheel_speed=20.0, settings=settings, seed=1)
    param = minimal_parameters(model)
    k = param.n_params
    true = IdentifiedModel(Identification(param.names, param.definitions, param.true_values, np.zeros(k),
                                          np.zeros((k, k)), 1.0, np.ones(1), 0.0, 0, "ols", np.zeros(3),
                                          "cepheus-rw", True), param)
    truth = replace(run.truth, tau=run.effort).select(slice(0, 200))
    _, held = validate_torques(true, truth, momentum=np.zeros(3), hold="zero", max_step=0.001)
    _, linear = validate_torques(true, truth, momentum=np.zeros(3), hold="linear", max_step=0.001)
    assert held["torque_q_rms"] < 1e-9 and linear["torque_q_rms"] > 1e-6
    with tempfile.TemporaryDirectory() as folder:
        write_bag(f"{folder}/run.bag", run.recording, format="ros1")
        log = read_bag_log(f"{folder}/run.bag", joints=model.joints, planar=True, wheels=model.wheels,
                           pose_latency=settings.mocap.latency)
    assert log.tau is not None and log.tau.shape == log.q.shape
    at = np.searchsorted(run.truth.t, log.t)
    noise = settings.mocap.position_noise  # the spline through noisy frames stays within a few sigma
    assert 0 < np.abs(log.base_position[:, :2] - run.base_position[at]).max() < 6 * noise
    np.testing.assert_allclose(log.tau, run.effort[at], atol=1e-12)


@pytest.mark.slow
def test_spatial_model_against_free_flyer_aba():
    """The spatial path (quaternion attitude): the 7-joint arm under known torques, Pinocchio ABA on
    the free flyer from a state of zero linear momentum, against the true parameters."""
    from spaceid.estimation import Identification
    from spaceid.identified import IdentifiedModel
    from spaceid.models import to_pinocchio

    model = spaceid.load_model("satellite-7dof")
    param = minimal_parameters(model)
    pmodel = to_pinocchio(model)
    data = pmodel.createData()
    n, duration, rate = model.n_joints, 0.4, 50.0
    t = np.arange(0.0, duration + 1e-9, 1 / rate)
    tau = np.column_stack([0.5 * np.sin(2.0 * t + j) for j in range(n)])
    config0 = np.r_[np.zeros(3), 0.1, -0.2, 0.3, 0.0, 0.2 * np.ones(n)]
    config0[3:7] /= np.linalg.norm(config0[3:7])
    v0 = np.r_[np.zeros(3), 0.02, -0.01, 0.03, 0.1 * np.ones(n)]
    ag = pin.ccrba(pmodel, data, config0, v0)
    v0[:3] = np.linalg.solve(ag[:3, :3], -ag[:3] @ v0)
    h = (pin.ccrba(pmodel, data, config0, v0) @ v0)[3:]

    def rhs(time, y):
        torque = np.r_[np.zeros(6), [np.interp(time, t, tau[:, j]) for j in range(n)]]
        config, v = y[: pmodel.nq], y[pmodel.nq :]
        x, w = config[3:6], v[3:6]  # quaternion [x, y, z, w] of the base, body-axes rates
        s = config[6]
        rotation = quat_to_matrix(np.r_[s, x])
        quat_rate = 0.5 * np.r_[s * w + np.cross(x, w), -x @ w]
        return np.r_[rotation @ v[:3], quat_rate, v[6:], pin.aba(pmodel, data, config, v, torque)]

    y = solve_ivp(rhs, (0, duration), np.r_[config0, v0], method="DOP853", t_eval=t, rtol=1e-12, atol=1e-14).y.T
    quat = y[:, [6, 3, 4, 5]] / np.linalg.norm(y[:, 3:7], axis=1, keepdims=True)
    nq = pmodel.nq
    log = Log(t, model.joints, y[:, 7:nq], y[:, nq + 6 :], quat, y[:, nq + 3 : nq + 6], False, {}, None, tau)
    k = param.n_params
    true = IdentifiedModel(Identification(param.names, param.definitions, param.true_values, np.zeros(k),
                                          np.zeros((k, k)), 1.0, np.ones(1), 0.0, 0, "ols", h, "satellite-7dof",
                                          False), param)
    _, metrics = validate_torques(true, log, momentum=h, max_step=0.005)
    assert metrics["torque_q_rms"] < 1e-8 and 0 < metrics["torque_attitude_rms"] < 1e-9, metrics
    wrong = replace(true.identification, values=true.values * (1 + 0.05 * np.random.default_rng(1).standard_normal(k)))
    _, off = validate_torques(wrong, log, momentum=h, max_step=0.005)
    assert off["torque_q_rms"] > 1e4 * metrics["torque_q_rms"] and off["torque_attitude_rms"] > 1e-6, off
