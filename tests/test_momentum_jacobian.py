"""The analytic derivative of the momentum in the state against differences of the momentum."""

import numpy as np
import pytest
from conftest import random_states, random_tree

import spaceid
from spaceid.dynamics import minimal_parameters, momentum_jacobian
from spaceid.estimation import signal_jacobian

TREES = {  # parents, planar, prismatic joints
    "planar chain": ([0, 1, 2], True, ()),
    "planar prismatic": ([0, 1], True, (2,)),
    "spatial chain": ([0, 1], False, ()),
    "spatial two arms, prismatic": ([0, 1, 0, 3], False, (2,)),
    "spatial branch on a link": ([0, 1, 1], False, (3,)),
}


def richardson(param, pi, q, qd, w0, step=1e-3):
    """``d(momentum)/d[q, qd, w0]`` by central differences of steps h and h/2, extrapolated
    (error ~h^4: 1e-12 at h = 1e-3, against round-off ~1e-13 / h)."""
    nj = q.shape[1]
    x = np.hstack([q, qd, w0[:, 2:] if param.model.planar else w0])  # planar: w0 along z only

    def central(i, h):
        e = np.zeros(x.shape[1])
        e[i] = h
        plus, minus = x + e, x - e
        return (momentum(plus) - momentum(minus)) / (2 * h)

    def momentum(x):
        w = np.zeros((len(x), 3))
        w[:, 3 - (x.shape[1] - 2 * nj) :] = x[:, 2 * nj :]
        return param.momentum(x[:, :nj], x[:, nj : 2 * nj], w, pi)

    return np.stack([(4 * central(i, step / 2) - central(i, step)) / 3 for i in range(x.shape[1])], -1)


def check_against_differences(param, q, qd, w0, rng):
    pi = param.true_values * rng.uniform(0.5, 1.5, param.n_params)  # any pi, not only the model's
    jac = momentum_jacobian(param, q, qd, w0, pi)
    ref = richardson(param, pi, q, qd, w0)
    nj, n_w = q.shape[1], 1 if param.model.planar else 3
    assert jac.shape == ref.shape == (len(q), param.rows, 2 * nj + n_w)
    assert np.abs(jac - ref).max() < 1e-9 * np.abs(ref).max()
    # the velocity columns are the momentum matrix: exact, whatever the differences
    units = np.eye(nj + 3)[[*range(nj), *range(nj + 3 - n_w, nj + 3)]]  # unit qd, unit w0 (z if planar)
    cols = [param.momentum(q, np.broadcast_to(u[:nj], qd.shape), np.broadcast_to(u[nj:], w0.shape), pi) for u in units]
    np.testing.assert_allclose(jac[..., nj:], np.stack(cols, -1), rtol=0, atol=1e-13 * np.abs(jac).max())


@pytest.mark.parametrize("tree", TREES.values(), ids=TREES.keys())
def test_jacobian_equals_differences_on_random_trees(rng, tree):
    parents, planar, prismatic = tree
    model = random_tree(rng, parents, planar=planar, prismatic=prismatic)
    param = minimal_parameters(model)
    assert param.basis == ("planar" if planar and not prismatic else "columns")
    check_against_differences(param, *random_states(rng, model, 40), rng)


@pytest.mark.parametrize("name", ["cepheus", "cepheus-rw", "satellite-7dof"])
def test_jacobian_equals_differences_on_the_presets(rng, name):
    """Cepheus in its planar basis, with its reaction wheel, and the 7-DOF satellite."""
    param = minimal_parameters(spaceid.load_model(name))
    check_against_differences(param, *random_states(rng, param.model, 40), rng)


@pytest.mark.slow
def test_jacobian_equals_differences_on_the_servicer(rng):
    param = minimal_parameters(spaceid.load_model("servicer-dual"))
    check_against_differences(param, *random_states(rng, param.model, 20), rng)


def test_chunks_and_leading_shape_do_not_show(rng):
    model = random_tree(rng, [0, 1, 1], planar=False)
    param = minimal_parameters(model)
    q, qd, w0 = random_states(rng, model, 10)
    whole = momentum_jacobian(param, q, qd, w0, param.true_values)
    chunked = momentum_jacobian(param, q, qd, w0, param.true_values, chunk=3)
    np.testing.assert_allclose(chunked, whole, rtol=1e-13, atol=1e-13 * np.abs(whole).max())
    shaped = momentum_jacobian(param, q.reshape(2, 5, -1), qd.reshape(2, 5, -1), w0.reshape(2, 5, 3), param.true_values)
    np.testing.assert_allclose(shaped.reshape(whole.shape), whole, rtol=1e-14, atol=1e-14 * np.abs(whole).max())


@pytest.mark.parametrize("planar", [True, False])
def test_signal_jacobian_columns(rng, planar):
    """Signal order ``[q, qd, w0 (z if planar), dtheta (spatial)]``; the attitude columns are
    ``-[hb]x``."""
    model = random_tree(rng, [0, 1], planar=planar)
    param = minimal_parameters(model)
    q, qd, w0 = random_states(rng, model, 6)
    hb = rng.standard_normal((6, 3))
    jac = signal_jacobian(param, param.true_values, q, qd, w0, hb)
    full = momentum_jacobian(param, q, qd, w0, param.true_values)
    nj = model.n_joints
    if planar:
        assert jac.shape == (6, 1, 2 * nj + 1)
        np.testing.assert_array_equal(jac, full)
    else:
        np.testing.assert_array_equal(jac[..., : 2 * nj + 3], full)
        d = rng.standard_normal(3)
        np.testing.assert_allclose(jac[..., 2 * nj + 3 :] @ d, -np.cross(hb, d), rtol=1e-14)  # R0 exp([d]x)


@pytest.mark.parametrize("tree", [*TREES.values(), "cepheus"], ids=[*TREES.keys(), "cepheus"])
def test_regressor_derivative_along_a_direction(rng, tree):
    """``linearized_regressor`` (kinematics differenced, columns formed once) against Richardson
    differences of the regressor, and its contraction formed without the columns."""
    if tree == "cepheus":
        model = spaceid.load_model("cepheus")
    else:
        model = random_tree(rng, tree[0], planar=tree[1], prismatic=tree[2])
    param = minimal_parameters(model)
    x = random_states(rng, model, 300)
    d = [1e-2 * rng.standard_normal(a.shape) for a in x]
    if model.planar:
        d[2][:, :2] = 0.0
    tangent = param.linearized_regressor(*x, d, step=1e-5, primal=False)
    h = 1e-3 / np.abs(np.hstack(d)).max()

    def central(s):
        return (param.regressor(*(a + s * b for a, b in zip(x, d)))
                - param.regressor(*(a - s * b for a, b in zip(x, d)))) / (2 * s)  # fmt: skip

    ref = (4 * central(h / 2) - central(h)) / 3
    assert np.abs(tangent - ref).max() < 1e-8 * np.abs(ref).max()
    linear = param.linearized_regressor(*x, d, step=1e-5)
    np.testing.assert_allclose(linear - tangent, param.regressor(*x), rtol=0, atol=1e-13 * np.abs(linear).max())
    u = rng.standard_normal((300, param.rows))
    contracted = param.contracted_tangent(*x, d, u, step=1e-5)
    # the two difference the inertia terms differently (the tangent R e_m wb as R e_(m+1) x R e_(m+2) wb,
    # the contraction directly): they agree to the round-off of differences of step 1e-5, ~1e-11
    np.testing.assert_allclose(contracted, np.einsum("nrk,nr->k", tangent, u), rtol=0,
                               atol=1e-9 * np.abs(contracted).max())  # fmt: skip


def test_equations_linearised_and_contracted(rng):
    """The stacked equations with a known parameter and the momentum estimated (attitude columns):
    linearised derivative against Richardson differences of ``phi``, and its contraction."""
    from spaceid.data import quat_to_matrix
    from spaceid.estimation._equations import Equations

    model = random_tree(rng, [0, 1, 1], planar=False, prismatic=(2,))
    param = minimal_parameters(model)
    n, k = 200, param.n_params
    quat = rng.standard_normal((n, 4))
    eq = Equations(param, quat_to_matrix(quat / np.linalg.norm(quat, axis=1, keepdims=True)), np.arange(1, k),
                    np.array([0]), param.true_values[:1], None)  # fmt: skip
    x = np.hstack([*random_states(rng, model, n), 0.1 * rng.standard_normal((n, 3))])
    v = 1e-2 * rng.standard_normal(x.shape)
    tangent = eq.linearized(x, v, primal=False)
    h = 1e-1

    def central(s):
        return (eq.phi(x + s * v) - eq.phi(x - s * v)) / (2 * s)

    ref = (4 * central(h / 2) - central(h)) / 3
    assert np.abs(tangent - ref).max() < 1e-8 * np.abs(ref).max()
    phi = eq.phi(x)
    np.testing.assert_allclose(eq.linearized(x, v) - tangent, phi, rtol=0, atol=1e-13 * np.abs(phi).max())
    u = rng.standard_normal((n, 3))
    contracted = eq.contracted_dphi(x, v, u)
    np.testing.assert_allclose(contracted, np.einsum("nrp,nr->p", tangent[..., :-1], u), rtol=0,
                               atol=1e-9 * np.abs(contracted).max())  # fmt: skip  (round-off, as above)
