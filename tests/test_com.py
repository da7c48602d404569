"""The system CM from a logged base position, and the generalized Jacobian it gives, against
Pinocchio on the true floating-base model (zero linear and angular momentum eliminated)."""

from dataclasses import replace

import numpy as np
import pinocchio as pin
import pytest
from random_states import random_log

import spaceid
from spaceid import SpaceidError
from spaceid.data import (
    Log,
    quat_to_matrix,
    quat_to_yaw,
    read_log,
    write_json,
    write_log,
)
from spaceid.dynamics import minimal_parameters, system_com
from spaceid.estimation import identify, load_result
from spaceid.identified import identified_model, identify_com, load_identified
from spaceid.models import to_pinocchio
from spaceid.motion import load_trajectory, simulate
from spaceid.twin import planar_pinocchio

MODELS = {"cepheus": np.array([0.0, 0.0, 0.3]), "satellite-7dof": np.array([1.0, -2.0, 3.0])}


def positioned_log(param, h, n, rng, noise=0.0):
    """Samples at random states and attitudes, the base rate from ``h`` and the base position
    that keeps the system CM at ``r_c`` (plus white noise of ``noise`` [m])."""
    log = random_log(param, h, n, rng)
    r_c = np.array([0.4, -0.2, 0.0 if param.model.planar else 0.7])
    position = r_c - np.einsum("nij,nj->ni", quat_to_matrix(log.base_quat), system_com(param.model, log.q))
    position += noise * rng.standard_normal((n, 3))
    if param.model.planar:
        position[:, 2] = 0.0
    return replace(log, base_position=position)


@pytest.fixture(scope="module", params=list(MODELS))
def identified(request):
    param = minimal_parameters(spaceid.load_model(request.param))
    h = MODELS[request.param]
    log = positioned_log(param, h, 4 * param.n_params // param.rows + 20, np.random.default_rng(3))
    return identify_com(identified_model(identify(param, log, h)), log), log


def pinocchio_jacobian(model, q, quat, frame):
    """The generalized Jacobian of ``frame`` from Pinocchio: frame Jacobian (world-aligned) with the
    base velocity of zero centroidal momentum (``ccrba``) substituted."""
    if model.planar:
        pmodel, nb, rows = planar_pinocchio(model), 3, [0, 1, 5]
        config = np.r_[0.3, -0.1, quat_to_yaw(quat), q]
    else:
        pmodel, nb, rows = to_pinocchio(model), 6, slice(None)
        config = np.r_[0.3, -0.1, 0.2, quat[1:], quat[0], q]
    data = pmodel.createData()
    ag = pin.ccrba(pmodel, data, config, np.zeros(pmodel.nv))[rows]
    pin.computeJointJacobians(pmodel, data, config)
    pin.updateFramePlacements(pmodel, data)
    jac = pin.getFrameJacobian(pmodel, data, pmodel.getFrameId(frame), pin.LOCAL_WORLD_ALIGNED)
    base = -np.linalg.solve(ag[:, :nb], ag[:, nb:])
    return jac[:, nb:] + jac[:, :nb] @ base


def test_noise_free_com_terms_are_exact(identified):
    ident, _ = identified
    com = ident.identification.com
    assert com["residual_rms"] < 1e-12
    q = np.random.default_rng(8).uniform(-np.pi, np.pi, (5, ident.geometry.n_joints))
    truth = system_com(ident.geometry, q)
    axes = slice(0, 2) if ident.geometry.planar else slice(None)
    np.testing.assert_allclose(ident.system_com(q)[:, axes], truth[:, axes], atol=1e-10)
    np.testing.assert_allclose(com["inertial_com"][:2], [0.4, -0.2], atol=1e-10)
    assert "system_com" not in ident.undetermined and "linear_velocity" not in ident.undetermined


def test_generalized_jacobian_equals_pinocchio(identified):
    ident, _ = identified
    model, rng = ident.geometry, np.random.default_rng(11)
    for frame in (model.bodies[-1].name, model.bodies[len(model.bodies) // 2].name):
        for _ in range(3):
            q = rng.uniform(-np.pi, np.pi, model.n_joints)
            quat = rng.standard_normal(4)
            if model.planar:
                quat[1:3] = 0.0
            quat /= np.linalg.norm(quat)
            ref = pinocchio_jacobian(model, q, quat, frame)
            got = ident.generalized_jacobian(q, frame, attitude=quat)
            assert np.abs(got - ref).max() <= 1e-8 * np.abs(ref).max()
    # batched, and a wrong CM (first term off by 1 %) fails it
    q = rng.uniform(-np.pi, np.pi, (4, model.n_joints))
    batch = ident.generalized_jacobian(q, frame)
    np.testing.assert_allclose(batch[2], ident.generalized_jacobian(q[2], frame), rtol=0, atol=1e-14)
    ref = pinocchio_jacobian(model, q[0], np.array([1.0, 0, 0, 0]), frame)
    com = dict(ident.identification.com, values=(np.asarray(ident.identification.com["values"]) * 1.01).tolist())
    wrong = type(ident)(replace(ident.identification, com=com), ident.param)
    assert np.abs(wrong.generalized_jacobian(q[0], frame) - ref).max() > 1e-5 * np.abs(ref).max()


def test_frame_velocity_adds_the_momentum_drift(identified):
    """With momentum, the frame velocity is J* qd plus the drift; checked by differentiating the
    frame's inertial position along a simulated noise-free motion (cepheus) or against Pinocchio."""
    ident, log = identified
    model = ident.geometry
    frame = model.bodies[-1].name
    k = 3
    v = ident.frame_velocity(log.q[k], log.qd[k], frame, attitude=log.base_quat[k])
    # reference: Pinocchio's frame velocity with the logged base rate and the base linear velocity
    # of zero linear momentum
    if model.planar:
        pmodel, lin = planar_pinocchio(model), [0, 1]
        config = np.r_[0.0, 0.0, quat_to_yaw(log.base_quat[k]), log.q[k]]
        vel = np.r_[0.0, 0.0, log.base_w[k, 2], log.qd[k]]
    else:
        pmodel, lin = to_pinocchio(model), [0, 1, 2]
        config = np.r_[0.0, 0.0, 0.0, log.base_quat[k, 1:], log.base_quat[k, 0], log.q[k]]
        vel = np.r_[0.0, 0.0, 0.0, log.base_w[k], log.qd[k]]
    data = pmodel.createData()
    ag = pin.ccrba(pmodel, data, config, vel)
    vel[lin] = np.linalg.solve(ag[lin][:, lin], -ag[lin] @ vel)
    pin.forwardKinematics(pmodel, data, config, vel)
    pin.updateFramePlacements(pmodel, data)
    ref = pin.getFrameVelocity(pmodel, data, pmodel.getFrameId(frame), pin.LOCAL_WORLD_ALIGNED).vector
    assert np.abs(v - ref).max() <= 1e-8 * np.abs(ref).max()


def test_simulate_keeps_the_cm_at_the_origin_and_the_csv_round_trip(tmp_path):
    model = spaceid.load_model("cepheus")
    param = minimal_parameters(model)
    def motion(t):
        return load_trajectory("paper-table2").evaluate(t)[:2]

    log = simulate(param, param.true_values, motion, np.linspace(0, 5, 201), MODELS["cepheus"], model=model,
                   base_position=True)
    pmodel = planar_pinocchio(model)
    data = pmodel.createData()
    for k in (0, 100, 200):
        config = np.r_[log.base_position[k, :2], log.base_yaw[k], log.q[k]]
        assert np.abs(pin.centerOfMass(pmodel, data, config)[:2]).max() < 1e-12
    write_log(tmp_path / "log.csv", log)
    back = read_log(tmp_path / "log.csv", joints=model.joints, planar=True)
    np.testing.assert_array_equal(back.base_position, log.base_position * [1, 1, 0])
    # the CM terms from the simulated motion reproduce the true CM
    ident = identify_com(identified_model(identify(param, back, MODELS["cepheus"])), back)
    q = np.random.default_rng(1).uniform(-2, 2, (4, 2))
    np.testing.assert_allclose(ident.system_com(q)[:, :2], system_com(model, q)[:, :2], atol=1e-8)
    with pytest.raises(SpaceidError, match="needs the physical model"):
        simulate(param, param.true_values, motion, np.linspace(0, 1, 5), MODELS["cepheus"], base_position=True)


def test_noisy_com_terms_spread_as_predicted():
    """Position noise: the estimates' errors over repeated draws match the predicted std."""
    param = minimal_parameters(spaceid.load_model("cepheus"))
    h = MODELS["cepheus"]
    base = positioned_log(param, h, 300, np.random.default_rng(4))
    ident = identified_model(identify(param, base, h))
    truth = identify_com(ident, base).identification.com["values"]
    errors, stds = [], []
    for seed in range(40):
        noisy = Log(base.t, base.joints, base.q, base.qd, base.base_quat, base.base_w, True, {},
                    base.base_position + 1e-3 * np.random.default_rng(seed).standard_normal(base.base_position.shape)
                    * [1, 1, 0])
        com = identify_com(ident, noisy).identification.com
        errors.append(np.subtract(com["values"], truth)), stds.append(com["std"])
    ratio = np.std(errors, 0) / np.mean(stds, 0)
    assert np.all((ratio > 0.7) & (ratio < 1.3)), ratio


def test_missing_position_and_result_round_trip(identified, tmp_path):
    ident, log = identified
    with pytest.raises(SpaceidError, match="no base position"):
        identify_com(ident, replace(log, base_position=None))
    write_json(tmp_path / "r.json", ident.identification.to_dict())
    loaded = load_identified(tmp_path / "r.json")
    frame = ident.geometry.bodies[-1].name
    q = np.zeros(ident.geometry.n_joints)
    np.testing.assert_array_equal(loaded.generalized_jacobian(q, frame), ident.generalized_jacobian(q, frame))
    old = ident.identification.to_dict()
    old.pop("com")
    write_json(tmp_path / "old.json", old)
    assert load_result(tmp_path / "old.json").com is None
    with pytest.raises(SpaceidError, match="system com"):
        load_identified(tmp_path / "old.json").generalized_jacobian(q, frame)
    with pytest.raises(SpaceidError, match="not a body"):
        ident.generalized_jacobian(q, "nowhere")


def test_identify_com_on_the_command_line(tmp_path, capsys):
    from spaceid.cli import main

    model = spaceid.load_model("cepheus")
    param = minimal_parameters(model)
    log = simulate(param, param.true_values, lambda t: load_trajectory("paper-table2").evaluate(t)[:2],
                   np.linspace(0, 5, 101), MODELS["cepheus"], model=model, base_position=True)
    write_log(tmp_path / "log.csv", log)
    args = ["identify", "cepheus", "--momentum", "0.3", "--estimator", "ols", "--com", "-o"]
    assert main(args + [str(tmp_path / "r.json"), str(tmp_path / "log.csv")]) == 0
    ident = load_identified(tmp_path / "r.json")
    q = np.array([0.2, -0.4])
    np.testing.assert_allclose(ident.system_com(q)[:2], system_com(model, q)[:2], atol=1e-8)
    write_log(tmp_path / "bare.csv", replace(log, base_position=None))
    capsys.readouterr()
    assert main(args + [str(tmp_path / "s.json"), str(tmp_path / "bare.csv")]) == 2
    assert "no base position (base_x, base_y columns)" in capsys.readouterr().err
