"""The controller-ready identified model against Pinocchio: the free-floating joint inertia, the
kinetic energy and the forward dynamics of a noise-free identification; the covariance
propagated from cov(pi); what pi does not fix; the RESULT.json round trip."""

from dataclasses import replace

import numpy as np
import pinocchio as pin
import pytest
from random_states import random_log
from hypothesis import given, settings
from hypothesis import strategies as st
from conftest import random_tree

import spaceid
from spaceid import SpaceidError
from spaceid.cli import main
from spaceid.data import quat_to_matrix, write_log
from spaceid.dynamics import body_states, full_values, minimal_parameters
from spaceid.estimation import Identification, Noise, identify
from spaceid.estimation import load_result as load_identification
from spaceid.identified import IdentifiedModel, identified_model
from spaceid.models import INERTIAL_NAMES, to_pinocchio
from spaceid.motion import add_noise, load_trajectory, simulate
from spaceid.twin import planar_pinocchio

H_CEPHEUS = np.array([0.0, 0.0, 0.4934])
H_SPATIAL = np.array([1.0, -2.0, 3.0])


@pytest.fixture(scope="module")
def cepheus():
    param = minimal_parameters(spaceid.load_model("cepheus"))
    log = simulate(param, param.true_values, lambda t: load_trajectory("paper-table2").evaluate(t)[:2],
                   np.linspace(0, 5, 101), H_CEPHEUS)
    return identified_model(identify(param, log, H_CEPHEUS)), log


@pytest.fixture(scope="module", params=["cepheus", "cepheus-rw", "satellite-7dof"])
def noise_free(request):
    """Noise-free identifications: Cepheus from a simulated motion, the reaction-wheel Cepheus and
    a spatial 7-dof arm from samples at random states."""
    if request.param == "cepheus":
        return request.getfixturevalue("cepheus")[0]
    param = minimal_parameters(spaceid.load_model(request.param))
    h = H_SPATIAL if not param.model.planar else np.array([0.0, 0.0, 0.3])
    log = random_log(param, h, 4 * param.n_params // param.rows, np.random.default_rng(5))
    return identified_model(identify(param, log, h))


def pinocchio_reference(model, q, qd, w0, tau):
    """Pinocchio on the floating model, base at rest at the origin, linear momentum zero:
    ``H*`` (the base block eliminated), the kinetic energy, the angular momentum (base axes)
    and the joint accelerations of ABA under joint torques ``tau``. Planar models float on the
    table (base x, y, yaw), spatial ones are free flyers."""
    pmodel, nb = (planar_pinocchio(model), 3) if model.planar else (to_pinocchio(model), 6)
    lin, ang = ([0, 1], [2]) if model.planar else ([0, 1, 2], [3, 4, 5])
    data = pmodel.createData()
    config = pin.neutral(pmodel)
    config[-model.n_joints :] = q
    v = np.zeros(pmodel.nv)
    v[nb:], v[ang] = qd, w0[[2] if model.planar else [0, 1, 2]]
    ag = pin.ccrba(pmodel, data, config, v)
    v[lin] = np.linalg.solve(ag[lin][:, lin], -ag[lin] @ v)  # the base velocity of zero linear momentum
    h = pin.ccrba(pmodel, data, config, v) @ v
    full = pin.crba(pmodel, data, config)
    full = np.triu(full) + np.triu(full, 1).T
    reduced = full[nb:, nb:] - full[nb:, :nb] @ np.linalg.solve(full[:nb, :nb], full[:nb, nb:])
    energy = pin.computeKineticEnergy(pmodel, data, config, v)
    qdd = pin.aba(pmodel, data, config, v, np.r_[np.zeros(nb), tau])[nb:]
    assert np.abs(h[:3]).max() < 1e-12 * np.abs(ag).max() * np.abs(v).max()
    return reduced, energy, h[3:], qdd


def _states(model, rng, n):
    q = rng.uniform(-np.pi, np.pi, (n, model.n_joints))
    qd, tau = rng.standard_normal((2, n, model.n_joints))
    w0 = rng.standard_normal((n, 3))
    if model.planar:
        w0[:, :2] = 0.0
    return q, qd, w0, tau


def _close(got, ref, rtol=1e-8):
    assert np.abs(got - ref).max() <= rtol * np.abs(ref).max()


def test_reduced_inertia_and_energy_equal_pinocchio(noise_free, rng):
    model = noise_free.geometry
    q, qd, w0, tau = _states(model, rng, 5)
    reduced, energy = noise_free.reduced_inertia(q), noise_free.kinetic_energy(q, qd, w0)
    assert reduced.shape == (5, model.n_joints, model.n_joints) and energy.shape == (5,)
    for n in range(5):
        ref = pinocchio_reference(model, q[n], qd[n], w0[n], tau[n])
        _close(reduced[n], ref[0])
        _close(energy[n], ref[1])
    # base eliminated: the energy of a joint motion at zero momentum is the quadratic form of H*
    rest = noise_free.base_rate(q, qd, momentum=np.zeros(3))
    _close(noise_free.kinetic_energy(q, qd, rest), 0.5 * np.einsum("ni,nij,nj->n", qd, reduced, qd), 1e-12)


@pytest.mark.parametrize("at_rest", [False, True], ids=["momentum", "zero momentum"])
def test_forward_dynamics_equals_pinocchio_aba(noise_free, rng, at_rest):
    model = noise_free.geometry
    q, qd, w0, tau = _states(model, rng, 4)
    for n in range(4):
        if at_rest:
            w0[n] = noise_free.base_rate(q[n], qd[n], momentum=np.zeros(3))
        _, _, h, qdd = pinocchio_reference(model, q[n], qd[n], w0[n], tau[n])
        _close(noise_free.base_rate(q[n], qd[n], momentum=h), w0[n], 1e-10)
        _close(noise_free.forward_dynamics(q[n], qd[n], tau[n], momentum=h), qdd)
        _close(noise_free.inverse_dynamics(q[n], qd[n], qdd, momentum=h), tau[n])
    # batched, the momentum inertial: the attitude rotates it into base axes
    quat = rng.standard_normal((4, 4))
    if model.planar:
        quat[:, 1:3] = 0.0
    quat /= np.linalg.norm(quat, axis=1, keepdims=True)
    h_base = np.stack([pinocchio_reference(model, q[n], qd[n], w0[n], tau[n])[2] for n in range(4)])
    h = np.einsum("nij,nj->ni", quat_to_matrix(quat), h_base)
    batched = noise_free.forward_dynamics(q, qd, tau, momentum=h, attitude=quat)
    one_by_one = [noise_free.forward_dynamics(q[n], qd[n], tau[n], momentum=h_base[n]) for n in range(4)]
    _close(batched, np.stack(one_by_one), 1e-12)
    _close(noise_free.inverse_dynamics(q, qd, batched, momentum=h, attitude=quat), tau, 1e-10)


def test_zero_momentum_dynamics_are_lagrange_of_the_reduced_inertia(cepheus, rng):
    """At zero momentum the joints move as a Lagrangian system with ``T = 1/2 qd^T H* qd``:
    ``H* qdd + dH*/dt qd - 1/2 d/dq (qd^T H* qd) = tau`` (derivatives by central differences)."""
    ident = cepheus[0]
    q, qd, _, tau = _states(ident.geometry, rng, 3)
    qdd = ident.forward_dynamics(q, qd, tau, momentum=np.zeros(3))
    step = 1e-5 * np.eye(ident.geometry.n_joints)
    dh = np.stack([(ident.reduced_inertia(q + s) - ident.reduced_inertia(q - s)) / 2e-5 for s in step], 1)  # n, k, i, j
    lhs = (np.einsum("nij,nj->ni", ident.reduced_inertia(q), qdd) + np.einsum("nkij,nk,nj->ni", dh, qd, qd)
           - 0.5 * np.einsum("ni,nkij,nj->nk", qd, dh, qd))
    _close(lhs, tau, 1e-7)


@settings(max_examples=20, deadline=None)
@given(st.integers(0, 2**32 - 1))
def test_inertia_is_the_energy_and_its_base_rows_the_momentum(cepheus, seed):
    """For any ``pi`` (here an arbitrary one), ``T = 1/2 x^T M x`` and ``M[n:] x`` is the
    momentum regressor times ``pi``: the momentum is the energy's derivative in the base rate."""
    ident = cepheus[0]
    rng = np.random.default_rng(seed)
    q, qd, w0, _ = _states(ident.geometry, rng, 3)
    pi = ident.values * rng.uniform(0.5, 1.5, len(ident.values))
    m = ident.inertia(q, pi)
    x = np.concatenate([qd, w0[:, 2:]], 1)
    n = ident.geometry.n_joints
    _close(ident.kinetic_energy(q, qd, w0, pi), 0.5 * np.einsum("na,nab,nb->n", x, m, x), 1e-12)
    _close(np.einsum("nab,nb->na", m[:, n:], x), ident.param.momentum(q, qd, w0, pi), 1e-12)
    np.testing.assert_allclose(m, np.swapaxes(m, 1, 2), rtol=0, atol=0)


def test_momentum_rows_of_the_inertia(noise_free, rng):
    ident = noise_free
    q, qd, w0, _ = _states(ident.geometry, rng, 3)
    n = ident.geometry.n_joints
    x = np.concatenate([qd, w0[:, [2] if ident.geometry.planar else [0, 1, 2]]], 1)
    _close(np.einsum("nab,nb->na", ident.inertia(q)[:, n:], x), ident.param.momentum(q, qd, w0, ident.values), 1e-10)


@pytest.fixture(scope="module")
def noisy(cepheus):
    ident, log = cepheus
    noise = Noise(angle=1e-3, rate=1e-3, base_rate=1e-3)
    return identified_model(identify(ident.param, add_noise(log, angle=1e-3, rate=1e-3, seed=3),
                                     H_CEPHEUS, noise=noise))


def _jacobian(f, pi, eps):
    """Central-difference Jacobian of ``f`` in ``pi``, the parameter axis last."""
    return np.stack([(f(pi + e) - f(pi - e)) / (2 * eps) for e in eps * np.eye(len(pi))], -1)


def test_covariances_are_the_propagated_cov_of_pi(noisy, rng):
    ident = noisy
    q, qd, w0, _ = _states(ident.geometry, rng, 3)
    jac = _jacobian(lambda p: ident.reduced_inertia(q, p), ident.values, 1e-6 * np.abs(ident.values).max())
    ref = np.einsum("nijk,kl,nabl->nijab", jac, ident.cov, jac)
    _close(ident.reduced_inertia_cov(q), ref, 1e-6)
    a = _jacobian(lambda p: ident.kinetic_energy(q, qd, w0, p), ident.values, 1.0)  # linear: any step
    _close(ident.kinetic_energy_cov(q, qd, w0), a @ ident.cov @ a.T, 1e-10)
    assert np.all(np.linalg.eigvalsh(ident.kinetic_energy_cov(q, qd, w0)) > -1e-12 * np.abs(ref).max())


@pytest.mark.slow
def test_reduced_inertia_spread_matches_monte_carlo(noisy, rng):
    """First order is enough at the identified spread: 600 draws of pi ~ N(values, cov)."""
    ident = noisy
    q = rng.uniform(-np.pi, np.pi, ident.geometry.n_joints)
    draws = rng.multivariate_normal(ident.values, ident.cov, 600)
    sample = np.stack([ident.reduced_inertia(q, p) for p in draws])
    predicted = np.sqrt(np.einsum("ijij->ij", ident.reduced_inertia_cov(q)))
    np.testing.assert_allclose(sample.std(0), predicted, rtol=0.15)  # sampling error of a std: ~3 %


def test_dynamics_not_determined_raise(cepheus):
    ident = cepheus[0]
    broken = IdentifiedModel(ident.identification, replace(ident.param, projection=ident.param.projection[:-1]))
    with pytest.raises(SpaceidError, match="does not determine the kinetic energy"):
        broken.reduced_inertia(np.zeros(2))


def test_planar_com_is_not_fixed_by_pi(cepheus):
    """A test that can fail: a change of the body parameters that leaves pi unchanged to first
    order moves the system CM in the plane, so asking for it (or a linear velocity) raises."""
    ident = cepheus[0]
    model, q = ident.geometry, np.array([0.3, -0.7])
    base = np.array([b.inertial for b in model.bodies])
    free = tuple(np.array([(i, k) for i, b in enumerate(model.bodies)
                           for k, n in enumerate(INERTIAL_NAMES) if n not in b.known_zero]).T)
    st = body_states(model, q, np.zeros(2), np.zeros(3))

    def pi_and_com(theta):
        inertials = base.copy()
        inertials[free] = theta
        first = inertials[:, :1] * st.position + np.einsum("bij,bj->bi", st.rotation, inertials[:, 1:4])
        return np.r_[ident.param.projection @ full_values(model.with_inertials(inertials)),
                     first.sum(0)[:2] / inertials[:, 0].sum()]

    jac = _jacobian(pi_and_com, base[free], 1e-6)
    k = ident.param.n_params
    s, vt = np.linalg.svd(jac[:k])[1:]
    null = vt[np.sum(s > 1e-9 * s[0]) :]  # directions that keep pi
    assert np.linalg.norm(jac[k:] @ null.T) > 1e-3 * np.linalg.norm(jac[k:])  # round-off: 1e-10
    for ask in (lambda: ident.system_com(q), lambda: ident.linear_velocity(q, q, np.zeros(3), "link2")):
        with pytest.raises(SpaceidError, match="do not fix the (system com|linear velocity); it needs"):
            ask()
    with pytest.raises(SpaceidError, match="not a quantity that pi may leave free"):
        ident.requires("reduced_inertia")


def test_what_pi_leaves_free_follows_the_model(noise_free):
    """Planar systems leave the total mass and the CM free; spatial trees fix both to first order."""
    q = np.zeros(noise_free.geometry.n_joints)
    if noise_free.geometry.planar:
        assert set(noise_free.undetermined) == {"body_parameters", "total_mass", "system_com", "linear_velocity",
                                                "base_force_response"}
        assert noise_free.undetermined["system_com"].startswith("the total mass")
        match = "do not fix the system com; it needs the total mass"
    else:
        assert set(noise_free.undetermined) == {"body_parameters"}
        match = "pi fixes the system com of this model to first order"
    with pytest.raises(SpaceidError, match=match):
        noise_free.system_com(q)


def test_round_trip_from_identify_on_the_command_line(cepheus, tmp_path, rng):
    ident, log = cepheus
    write_log(tmp_path / "log.csv", log)
    args = ["identify", "cepheus", tmp_path / "log.csv", "--momentum", 0.4934, "-o", tmp_path / "r.json"]
    assert main([str(a) for a in args]) == 0
    loaded = spaceid.load_identified(tmp_path / "r.json")
    bare = load_identification(tmp_path / "r.json")
    assert isinstance(loaded, IdentifiedModel) and isinstance(bare, Identification)
    # one name, one thing: spaceid.load_result is the record everywhere
    assert spaceid.load_result is load_identification
    assert spaceid.load_result(tmp_path / "r.json").to_dict() == bare.to_dict()
    # everything an Identification offers, still offered
    assert loaded.to_dict() == bare.to_dict() and loaded.model == "cepheus" and loaded.units == bare.units
    np.testing.assert_array_equal(loaded.std, bare.std)
    assert loaded.joints == log.joints and loaded.where == str(tmp_path / "r.json")
    q, qd, w0, tau = _states(loaded.geometry, rng, 2)
    _close(loaded.reduced_inertia(q), ident.reduced_inertia(q), 1e-12)
    ref = pinocchio_reference(loaded.geometry, q[0], qd[0], w0[0], tau[0])
    _close(loaded.reduced_inertia(q[0]), ref[0])
    _close(loaded.forward_dynamics(q[0], qd[0], tau[0], momentum=ref[2]), ref[3])
    metrics = spaceid.validate(loaded, log, momentum=H_CEPHEUS).metrics
    assert metrics["base_w_nrms"] < 1e-9


@pytest.mark.parametrize("planar", [True, False], ids=["planar", "spatial"])
def test_trees_with_a_prismatic_joint_equal_pinocchio(rng, planar):
    """Any tree: a branch and a slide (whose derivative stencil is the central difference)."""
    model = random_tree(rng, [0, 1, 1], planar=planar, prismatic=(2,))
    param = minimal_parameters(model)
    h = np.array([0.0, 0.0, 0.7]) if planar else H_SPATIAL
    log = random_log(param, h, 4 * param.n_params // param.rows, rng)
    ident = IdentifiedModel(identify(param, log, h), param)  # an in-memory model: nothing to reload
    q, qd, w0, tau = _states(model, rng, 3)
    q[:, 1] = rng.uniform(-0.5, 0.5, 3)
    for n in range(3):
        reduced, energy, h_base, qdd = pinocchio_reference(model, q[n], qd[n], w0[n], tau[n])
        _close(ident.reduced_inertia(q[n]), reduced)
        _close(ident.kinetic_energy(q[n], qd[n], w0[n]), energy)
        _close(ident.forward_dynamics(q[n], qd[n], tau[n], momentum=h_base), qdd)
