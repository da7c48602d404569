"""Regressors against the direct rigid-body momentum and Pinocchio; the minimal set."""

import numpy as np
import pytest
import sympy as sp
from conftest import pinocchio_momentum, random_states, random_tree
from hypothesis import given
from hypothesis import strategies as st
from robot_tally import robots

import spaceid
from spaceid._threads import one_blas_thread
from spaceid.dynamics._definitions import planar_symbol_values
from spaceid.dynamics import angular_momentum
from spaceid.models import to_pinocchio
from spaceid.dynamics._regressor import _random_states, full_regressor, full_values, minimal_parameters

PLANAR_TREES = {
    "1 link": [0],
    "2 links": [0, 1],
    "3 links": [0, 1, 2],
    "two arms": [0, 1, 0, 3],
    "branch on a link": [0, 1, 1],
}


def _rank(model, n=400, seed=7):
    q, qd, w0 = random_states(np.random.default_rng(seed), model, n)
    y = full_regressor(model, q, qd, w0)
    y = y[:, 2:3] if model.planar else y
    y = y.reshape(-1, y.shape[-1])
    norms = np.linalg.norm(y, axis=0)
    y = y[:, norms > 1e-12 * norms.max()]  # round-off columns are zero, not noise to normalise
    with one_blas_thread():  # threaded, on busy cores, these SVDs took 0.5 s each
        s = np.linalg.svd(y / np.linalg.norm(y, axis=0), compute_uv=False)
    return int(np.sum(s > 1e-8 * s[0]))


# the five-body tree's minimal set takes seconds (its definitions' symbolic factoring): slow, the others fast
TREES = [pytest.param(parents, id=name, marks=[pytest.mark.slow] if len(parents) > 3 else [])
         for name, parents in PLANAR_TREES.items()]


@pytest.mark.parametrize("parents", TREES)
def test_planar_regressor_equals_direct_momentum(rng, parents):
    model = random_tree(rng, parents)
    param = minimal_parameters(model)
    assert param.basis == "planar"
    q, qd, w0 = random_states(rng, model, 200)
    direct = angular_momentum(model, q, qd, w0)
    scale = np.abs(direct).max()
    assert np.abs(full_regressor(model, q, qd, w0) @ full_values(model) - direct).max() < 1e-12 * scale
    # only h_z is conserved on a table (it reacts the tilting torques); the z row is the planar regressor
    assert np.abs(param.regressor(q, qd, w0)[:, 0] @ param.true_values - direct[:, 2]).max() < 1e-12 * scale
    assert np.abs(param.momentum(q, qd, w0, param.true_values)[:, 0] - direct[:, 2]).max() < 1e-12 * scale
    assert np.abs(pinocchio_momentum(to_pinocchio(model), q, qd, w0) - direct).max() < 1e-12 * scale


@pytest.mark.parametrize("seed", range(6))
def test_planar_closed_form_equals_the_kinematics(seed):
    """The planar basis's functions in closed form (every axis along z: the rotations commute) against those of the
    general kinematics, on trees with frames turned upside down (a half-turn about x: the next axis is -z in
    base axes) and rotated about z; an axis tilted off z by more than round-off takes the kinematics."""
    from dataclasses import replace

    from spaceid.dynamics._regressor import _planar_functions, _planar_pairs, _planar_turns

    rng = np.random.default_rng(seed)
    model = random_tree(rng, [[0], [0, 1], [0, 1, 2], [0, 1, 0, 3], [0, 1, 1]][seed % 5])
    half_turn, quarter_y = np.diag([1.0, -1.0, -1.0]), np.array([[0.0, 0, 1], [0, 1, 0], [-1, 0, 0]])
    bodies = [b if i == 0 or rng.uniform() < 0.5 else replace(b, rotation=b.rotation @ half_turn)
              for i, b in enumerate(model.bodies)]  # fmt: skip
    for leaf in [i for i in range(1, len(bodies)) if all(b.parent != i for b in bodies)]:
        # the leaves' x axes out of the plane (each joint turns about its body's x axis, along z in base axes)
        bodies[leaf] = replace(bodies[leaf], rotation=bodies[leaf].rotation @ quarter_y, axis=-bodies[leaf].axis[::-1])
    model = replace(model.as_planar(), bodies=tuple(bodies)).as_planar()
    terms = _planar_pairs(len(model.bodies))
    closed = _planar_turns(model, terms)
    assert closed is not None and set(np.abs(closed.turns[closed.turns != 0])) == {1.0}
    q, qd, w0 = random_states(rng, model, 50)
    w0[:, :2] = rng.standard_normal((50, 2))  # a table's tilt rates: they do not enter h_z
    general = _planar_functions(model, terms, q, qd, w0)
    assert np.abs(_planar_functions(model, terms, q, qd, w0, closed) - general).max() < 1e-13 * np.abs(general).max()
    tilted = replace(bodies[1], axis=bodies[1].axis + 1e-10)
    assert _planar_turns(replace(model, bodies=(bodies[0], tilted, *bodies[2:])), terms) is None


@pytest.mark.parametrize("parents", TREES)
def test_minimal_count_equals_rank(rng, parents):
    model = random_tree(rng, parents)
    n_bodies = len(parents) + 1
    param = minimal_parameters(model)
    # a generic planar tree: one spin term per body, a cos and a sin term per pair of bodies
    assert param.n_params == _rank(model) == n_bodies + n_bodies * (n_bodies - 1)


@pytest.mark.slow
def test_spatial_regressor_equals_pinocchio(rng):
    model = random_tree(rng, [0, 1, 0, 3, 1], planar=False)
    param = minimal_parameters(model)
    assert param.basis == "columns" and param.n_params == _rank(model)
    q, qd, w0 = random_states(rng, model, 50)
    ref = pinocchio_momentum(to_pinocchio(model), q, qd, w0)
    scale = np.abs(ref).max()
    assert np.abs(angular_momentum(model, q, qd, w0) - ref).max() < 1e-12 * scale
    assert np.abs(param.regressor(q, qd, w0) @ param.true_values - ref).max() < 1e-11 * scale
    assert np.abs(param.momentum(q, qd, w0, param.true_values) - ref).max() < 1e-11 * scale


def test_spatial_columns_equal_their_definitions(rng):
    """Spatial tree with a prismatic joint: the full regressor times the full values is the direct
    rigid-body momentum, and every inertia column is ``R e_m1 wb_m2 + R e_m2 wb_m1`` (halved on the
    diagonal) from the body poses, column by column (the regressor forms them as cross products)."""
    from spaceid.dynamics import body_states
    from spaceid.dynamics._regressor import _INERTIA_ENTRIES, _layout

    model = random_tree(rng, [0, 1, 1], planar=False, prismatic=(2,))
    q, qd, w0 = random_states(rng, model, 40)
    q[:, 1] = rng.uniform(-0.5, 0.5, 40)
    y = full_regressor(model, q, qd, w0)
    direct = angular_momentum(model, q, qd, w0)
    assert np.abs(y @ full_values(model) - direct).max() < 1e-13 * np.abs(direct).max()
    st = body_states(model, q, qd, w0)
    wb = np.einsum("nbkr,nbk->nbr", st.rotation, st.omega)  # body-axes rates
    for c, (body, k) in enumerate(_layout(model)[0]):
        if k < 4:
            continue
        m1, m2 = _INERTIA_ENTRIES[k - 4]
        ref = st.rotation[:, body, :, m1] * wb[:, body, m2, None]
        ref = ref + st.rotation[:, body, :, m2] * wb[:, body, m1, None] if m1 != m2 else ref
        assert np.abs(y[:, :, c] - ref).max() < 1e-14 * np.abs(ref).max()


def test_prismatic_planar_tree_uses_column_basis(rng):
    model = random_tree(rng, [0, 1], prismatic=(2,))
    param = minimal_parameters(model)
    assert param.basis == "columns" and param.n_params == _rank(model)
    q, qd, w0 = random_states(rng, model, 50)
    q[:, 1] = rng.uniform(-0.5, 0.5, 50)
    direct = angular_momentum(model, q, qd, w0)[:, 2]
    assert np.abs(param.regressor(q, qd, w0)[:, 0] @ param.true_values - direct).max() < 1e-11 * np.abs(direct).max()


@pytest.mark.slow
def test_minimal_set_independent_of_seed(rng):
    model = random_tree(rng, [0, 1, 0])
    a, b = minimal_parameters(model, seed=0), minimal_parameters(model, seed=99)
    assert a.names == b.names and a.definitions == b.definitions
    np.testing.assert_allclose(a.true_values, b.true_values, rtol=1e-10)
    spatial = random_tree(rng, [0, 1], planar=False)
    assert minimal_parameters(spatial, seed=1).n_params == minimal_parameters(spatial, seed=2).n_params


def _math_md_pi(m0, I0, r0, m1, I1, l1, r1, m2, I2, l2):
    """docs/theory/cepheus.md, written out independently of the package."""
    M, L1 = m0 + m1 + m2, l1 + r1
    r0x, r0y = r0
    return np.array([
        m0 * (m1 * l1 + m2 * L1) * r0x / M,
        m0 * m2 * l2 * r0x / M,
        m0 * (m1 * l1 + m2 * L1) * r0y / M,
        m0 * m2 * l2 * r0y / M,
        I0 + m0 * (m1 + m2) * (r0x**2 + r0y**2) / M,
        m2 * l2 * (m0 * L1 + m1 * r1) / M,
        I1 + (m0 * m1 * l1**2 + m0 * m2 * L1**2 + m1 * m2 * r1**2) / M,
        I2 + (m0 + m1) * m2 * l2**2 / M,
    ])


def test_cepheus_yields_the_papers_eight_parameters():
    param = minimal_parameters(spaceid.load_model("cepheus"))
    expected = _math_md_pi(9.951, 0.1214, (0.17, 0.09), 0.083, 3.46e-4, 0.119, 0.062, 0.187, 7.17e-4, 0.146)
    assert param.n_params == 8
    np.testing.assert_allclose(param.true_values, expected, rtol=1e-9)
    # the rounded values of docs/theory/cepheus.md
    np.testing.assert_allclose(param.true_values, [0.007237, 0.004519, 0.003831, 0.002392, 0.131126, 0.004825, 0.007461, 0.004630], rtol=2e-4)
    # the columns of docs/theory/cepheus.md: Y1 = c1 (2 w0 + qd1), ..., Y8 = w0 + qd1 + qd2
    q, qd, w0 = _random_states(param.model, 20, 3)
    c1, s1, c2 = np.cos(q[:, 0]), np.sin(q[:, 0]), np.cos(q[:, 1])
    c12, s12 = np.cos(q.sum(1)), np.sin(q.sum(1))
    w, d1, d2 = w0[:, 2], qd[:, 0], qd[:, 1]
    cols = np.stack([c1 * (2 * w + d1), c12 * (2 * w + d1 + d2), s1 * (2 * w + d1), s12 * (2 * w + d1 + d2),
                     w, c2 * (2 * w + 2 * d1 + d2), w + d1, w + d1 + d2], -1)
    np.testing.assert_allclose(param.regressor(q, qd, w0)[:, 0], cols, atol=1e-13)


def test_link_com_off_the_joint_line_adds_a_ninth_parameter():
    model = spaceid.load_model("cepheus")
    bodies = tuple(b.__class__(**{**b.__dict__, "known_zero": frozenset()}) for b in model.bodies)
    free = model.__class__(model.name, bodies, True, (), "cepheus-free")
    assert minimal_parameters(free).n_params == 9


@pytest.mark.parametrize("name", ["cepheus", "cepheus-rw"])
def test_definitions_evaluate_to_the_values(name):
    param = minimal_parameters(spaceid.load_model(name))
    values = planar_symbol_values(param.model)
    for definition, value in zip(param.definitions, param.true_values):
        expr = sp.sympify(definition)
        got = float(expr.subs({s: values[s.name] for s in expr.free_symbols}))
        assert got == pytest.approx(value, rel=1e-12)


@pytest.mark.slow
def test_definitions_of_random_tree(rng):
    model = random_tree(rng, [0, 1, 0])
    param = minimal_parameters(model)
    values = planar_symbol_values(model)
    for definition, value in zip(param.definitions, param.true_values):
        expr = sp.sympify(definition)
        assert float(expr.subs({s: values[s.name] for s in expr.free_symbols})) == pytest.approx(value, rel=1e-10, abs=1e-14)


def _pinocchio_energy(pmodel, q, qd, w0):
    """Kinetic energy with zero linear momentum, from Pinocchio (base at identity)."""
    import pinocchio as pin

    data = pmodel.createData()
    out = []
    for qi, qdi, wi in zip(q, qd, w0):
        config = pin.neutral(pmodel)
        for joint, angle in zip(pmodel.joints[2:], qi):
            config[joint.idx_q : joint.idx_q + joint.nq] = [np.cos(angle), np.sin(angle)] if joint.nq == 2 else angle
        v = np.r_[np.zeros(3), wi, qdi]
        ag = pin.ccrba(pmodel, data, config, v)
        v[:3] = np.linalg.solve(ag[:3, :3], -ag[:3, 3:] @ v[3:])
        out.append(pin.computeKineticEnergy(pmodel, data, config, v))
    return np.array(out)


@pytest.mark.parametrize("planar", [True, False])
def test_energy_regressor_equals_pinocchio(rng, planar):
    from spaceid.dynamics import energy_regressor

    model = random_tree(rng, [0, 1, 0], planar=planar)
    q, qd, w0 = random_states(rng, model, 40)
    ref = _pinocchio_energy(to_pinocchio(model), q, qd, w0)
    np.testing.assert_allclose(energy_regressor(model, q, qd, w0) @ full_values(model), ref, rtol=1e-12)


def test_identifiability_report():
    from spaceid.dynamics import identifiability

    rw = identifiability(minimal_parameters(spaceid.load_model("cepheus-rw")))
    assert rw.determines_dynamics and rw.individually_identifiable == ("Izz_wheel",)
    assert "Ixx_link1" in rw.no_effect and "m_base" not in rw.no_effect  # masses act through M
    assert rw.to_dict()["individually_identifiable"] == ["Izz_wheel"]
    spatial = identifiability(minimal_parameters(random_tree(np.random.default_rng(3), [0, 1], planar=False)))
    assert spatial.determines_dynamics and spatial.energy_residual < 1e-10


def test_dynamics_not_determined_when_energy_escapes():
    """A test that can fail: a projection that drops one parameter cannot fix the energy."""
    from dataclasses import replace

    from spaceid.dynamics import identifiability

    param = minimal_parameters(spaceid.load_model("cepheus"))
    report = identifiability(replace(param, projection=param.projection[:-1]))
    assert not report.determines_dynamics and report.energy_residual > 1e-3


@pytest.mark.slow
def test_column_definitions_evaluate_to_the_values(rng):
    from spaceid.dynamics import full_parameter_names

    model = random_tree(rng, [0, 1, 0], planar=False)
    param = minimal_parameters(model)
    values = dict(zip(full_parameter_names(model), full_values(model)), M=model.mass)
    for definition, value in zip(param.definitions, param.true_values):
        expr = sp.sympify(definition)
        got = float(expr.subs({s: values[s.name] for s in expr.free_symbols}))
        assert got == pytest.approx(value, rel=1e-4, abs=1e-9)  # coefficients printed to 6 digits


def test_kinematics_equal_pinocchio(rng):
    """Body frames and velocities against Pinocchio's forward kinematics (base at rest at the
    origin, so absolute velocities are the velocities relative to the base origin)."""
    import pinocchio as pin

    from spaceid.dynamics import body_states

    model = random_tree(rng, [0, 1, 0, 3], planar=False, prismatic=(2,))
    q, qd, w0 = random_states(rng, model, 10)
    q[:, 1] = rng.uniform(-0.5, 0.5, 10)
    st = body_states(model, q, qd, w0)
    pmodel = to_pinocchio(model)
    data = pmodel.createData()
    for n in range(len(q)):
        pin.forwardKinematics(pmodel, data, np.r_[np.zeros(6), 1.0, q[n]], np.r_[np.zeros(3), w0[n], qd[n]])
        for b in range(len(model.bodies)):
            pose, twist = data.oMi[b + 1], data.v[b + 1]  # joint b + 1 carries body b
            np.testing.assert_allclose(st.rotation[n, b], pose.rotation, atol=1e-14)
            np.testing.assert_allclose(st.position[n, b], pose.translation, atol=1e-14)
            np.testing.assert_allclose(st.omega[n, b], pose.rotation @ twist.angular, atol=1e-13)
            np.testing.assert_allclose(st.velocity[n, b], pose.rotation @ twist.linear, atol=1e-13)


@robots(1)
@given(seed=st.integers(0, 2**31 - 1), planar=st.booleans(),
       shape=st.integers(1, 4).flatmap(lambda n: st.tuples(*[st.integers(0, i) for i in range(n)])))
def test_groups_and_threads_do_not_show(seed, planar, shape, monkeypatch):
    """Samples are evaluated in groups on threads, each sample on its own by compiled kernels
    without fastmath: on a random planar or spatial tree (its prismatic joints drawn too), small groups on two
    threads, one sample at a time and the default groups give the same regressor, momentum and linearised
    regressor bit for bit, the same energy, and the momentum is the regressor times pi."""
    from spaceid.dynamics import _regressor as regressor
    from spaceid.dynamics import energy_regressor

    rng = np.random.default_rng(seed)
    prismatic = tuple(i + 1 for i in range(len(shape)) if rng.uniform() < 0.3)
    model = random_tree(rng, list(shape), planar=planar, prismatic=prismatic)
    param = minimal_parameters(model)
    q, qd, w0 = random_states(rng, model, 29)
    for body in prismatic:  # a travel of half a metre at most
        q[:, body - 1] = rng.uniform(-0.5, 0.5, 29)
    direction = random_states(rng, model, 29)

    def evaluate(*x):
        return (param.regressor(*x[:3]), param.momentum(*x[:3], param.true_values),
                param.linearized_regressor(*x[:3], x[3:], step=1e-6))  # fmt: skip

    whole, energy = evaluate(q, qd, w0, *direction), energy_regressor(model, q, qd, w0)
    one_by_one = [np.stack(a) for a in zip(*(evaluate(*(a[n] for a in (q, qd, w0, *direction))) for n in range(29)))]
    with monkeypatch.context() as patch:  # undone after each example
        patch.setattr(regressor, "_GROUP", 12)  # several groups, the last one short
        patch.setattr(regressor, "threads_for", lambda tasks: min(tasks, 2))  # three groups, two threads
        patch.setattr(regressor, "_THREADED_WORK", 0)  # however small the work
        for got, ref in zip([*evaluate(q, qd, w0, *direction), *one_by_one], [*whole, *whole]):
            np.testing.assert_array_equal(got, ref)
        np.testing.assert_allclose(energy_regressor(model, q, qd, w0), energy, rtol=0,
                                   atol=1e-14 * np.abs(energy).max())  # fmt: skip
    h = whole[0] @ param.true_values
    np.testing.assert_allclose(whole[1], h, rtol=0, atol=1e-14 * np.abs(h).max())


def test_blas_thread_limit_is_scoped():
    """Small factorisations run on one BLAS thread, and the limit ends with its block (the
    regressor's threads follow the BLAS limit, so a leaked limit would make it serial). Two
    threads first, so that the check means something on a one-core machine too."""
    from threadpoolctl import threadpool_limits

    from spaceid._threads import blas_threads, one_blas_thread

    with threadpool_limits(2, user_api="blas"):
        assert blas_threads() == 2
        with one_blas_thread():
            assert blas_threads() == 1
        assert blas_threads() == 2


def test_work_threads_leave_busy_cores_alone(monkeypatch):
    """Block-parallel work takes the BLAS limit on idle cores, one thread on a loaded machine."""
    import os

    from threadpoolctl import threadpool_limits

    from spaceid import _threads
    from spaceid._threads import work_threads

    monkeypatch.setattr(os, "cpu_count", lambda: 2)
    monkeypatch.setattr(_threads, "_running_now", lambda: 14)
    monkeypatch.setattr(_threads, "_busy_others", lambda: None)  # (the load average alone decides)
    with threadpool_limits(2, user_api="blas"):
        monkeypatch.setattr(os, "getloadavg", lambda: (0.2, 0.0, 0.0))
        assert work_threads() == 2
        monkeypatch.setattr(os, "getloadavg", lambda: (14.0, 8.0, 4.0))
        assert work_threads() == 1
    with threadpool_limits(1, user_api="blas"):
        monkeypatch.setattr(os, "getloadavg", lambda: (0.0, 0.0, 0.0))
        assert work_threads() == 1


def test_one_block_runs_in_the_caller_without_asking_the_machine(monkeypatch):
    """:func:`threads_for` of one block is 1 without reading the machine's load (0.13 ms, more than a few samples'
    kinematics), of more at most one thread a block; the regressor's plan of a geometry and columns is kept."""
    from spaceid import _threads
    from spaceid.dynamics._regressor import _plan

    def asked():
        raise AssertionError("asked the machine")

    monkeypatch.setattr(_threads, "work_threads", asked)
    assert _threads.threads_for(1) == 1 and _threads.threads_for(0) == 1
    monkeypatch.setattr(_threads, "work_threads", lambda: 2)
    assert _threads.threads_for(5) == 2
    monkeypatch.setattr(_threads, "work_threads", lambda: 8)
    assert _threads.threads_for(3) == 3
    model = random_tree(np.random.default_rng(1), [0, 1])
    assert _plan(model, None) is _plan(model, None) and _plan(model, [0, 2]) is _plan(model, np.array([0, 2]))
    assert list(_plan(model, [2, 0]).columns) == [2, 0]


def test_work_threads_do_not_count_the_load_of_this_process(monkeypatch):
    """The load this process made itself is not another's: a load of 1.9 on 2 cores leaves both to a process
    that kept them busy, one to a process that did not, unless nothing else runs now. Its share follows its processor time as the kernel's
    1-minute average follows the runnable threads: 2 cores busy for a minute make 2 (1 - 1/e)."""
    import os

    from threadpoolctl import threadpool_limits

    from spaceid import _threads

    clock = {"wall": 100.0, "cpu": 10.0}
    monkeypatch.setattr(_threads.time, "monotonic", lambda: clock["wall"])
    monkeypatch.setattr(_threads.time, "process_time", lambda: clock["cpu"])
    monkeypatch.setattr(_threads, "_own", {"at": 100.0, "cpu": 10.0, "share": 0.0})
    clock.update(wall=160.0, cpu=130.0)
    assert _threads._own_load() == pytest.approx(2 * (1 - np.exp(-1)))
    clock.update(wall=220.0)  # idle for a minute: the share decays by 1/e
    assert _threads._own_load() == pytest.approx(2 * (1 - np.exp(-1)) * np.exp(-1))
    monkeypatch.setattr(os, "cpu_count", lambda: 2)
    monkeypatch.setattr(os, "getloadavg", lambda: (1.9, 1.0, 0.5))
    monkeypatch.setattr(_threads, "_busy_others", lambda: None)  # (not yet measured)
    with threadpool_limits(2, user_api="blas"):
        for own, running, threads in ((1.8, 1, 2), (0.0, 1, 1), (0.0, 0, 2)):  # the last: the load's maker has ended
            monkeypatch.setattr(_threads, "_own_load", lambda own=own: own)
            monkeypatch.setattr(_threads, "_running_now", lambda running=running: running)
            assert _threads.work_threads() == threads


def test_threads_running_now_leave_out_this_process(monkeypatch):
    """The threads running now that :func:`work_threads` counts are other processes': while a thread of this
    process works beside the caller, the machine's count of running threads holds both, the count of others
    neither (counted as others, they had kept a process on one thread)."""
    import threading

    from spaceid import _threads

    if _threads._running_now() is None:
        pytest.skip("no /proc/loadavg on this platform")
    stop, a = threading.Event(), np.random.default_rng(0).standard_normal((300, 300))

    def work():  # array work: running, the GIL released
        while not stop.is_set():
            np.linalg.eigvalsh(a)

    worker = threading.Thread(target=work)
    worker.start()
    try:
        own = []
        for _ in range(50):
            with open("/proc/loadavg") as f:
                running = int(f.read().split()[3].split("/")[0])
            own.append(running - _threads._running_now())
    finally:
        stop.set()
        worker.join()
    assert np.median(own) >= 2


def test_work_threads_count_the_cores_others_kept_busy_lately(monkeypatch):
    """A process that runs for an instant, counted running now, does not take a core (one reading of it had kept an
    identification on one thread): the cores the others kept busy lately, the machine's processor time less this
    process's over the last window, are what counts; a process that keeps running counts, and a window too short
    to measure changes nothing."""
    import os

    from threadpoolctl import threadpool_limits

    from spaceid import _threads

    clock = {"wall": 10.0, "cpu": 1.0, "busy": 100.0}
    monkeypatch.setattr(_threads.time, "monotonic", lambda: clock["wall"])
    monkeypatch.setattr(_threads.time, "process_time", lambda: clock["cpu"])
    monkeypatch.setattr(_threads, "_busy_time", lambda: clock["busy"])
    monkeypatch.setattr(_threads, "_busy", {"at": 10.0, "cpu": 1.0, "busy": 100.0, "share": None})
    monkeypatch.setattr(_threads, "_own_load", lambda: 0.0)
    monkeypatch.setattr(_threads, "_running_now", lambda: 1)  # another process running as the threads are counted
    monkeypatch.setattr(os, "cpu_count", lambda: 2)
    monkeypatch.setattr(os, "getloadavg", lambda: (0.9, 0.5, 0.2))
    with threadpool_limits(2, user_api="blas"):
        clock.update(wall=10.1, cpu=1.2, busy=100.2)  # 0.1 s: too short a window to measure
        assert _threads._busy_others() is None and _threads.work_threads() == 1
        clock.update(wall=10.5, cpu=1.9, busy=100.91)  # 0.5 s: this process 0.9 s, the others 0.01 s
        assert _threads._busy_others() == pytest.approx(0.02) and _threads.work_threads() == 2
        clock.update(wall=11.5, cpu=2.9, busy=102.91)  # a second: the others kept a core busy
        assert _threads._busy_others() == pytest.approx(1.0) and _threads.work_threads() == 1


def test_side_by_side_keeps_the_callers_threads_and_gives_its_workers_one(monkeypatch):
    """In a side-by-side block the caller's block-parallel work keeps the threads it had (BLAS's one thread is the
    block's own limit, not a busy machine's), its workers' work runs on one, and the caller's count ends with it."""
    from threadpoolctl import threadpool_limits

    from spaceid import _threads

    monkeypatch.setattr(_threads, "_running_now", lambda: 0)
    monkeypatch.setattr(_threads.os, "getloadavg", lambda: (0.0, 0.0, 0.0))
    monkeypatch.setattr(_threads.os, "cpu_count", lambda: 2)
    with threadpool_limits(2, user_api="blas"):
        with _threads.side_by_side(2) as submit:
            assert _threads.work_threads() == 2 and _threads.blas_threads() == 1
            assert submit(_threads.work_threads).result() == 1
        assert _threads.work_threads() == 2 and not hasattr(_threads._caller, "threads")
        # a process held to one thread (design's workers) stays on one
        with threadpool_limits(1, user_api="blas"), _threads.side_by_side(2):
            assert _threads.work_threads() == 1


def test_side_by_side_runs_beside_on_an_idle_core_else_inline(monkeypatch):
    """Work submitted side by side runs on a worker thread when a core is idle and in the caller otherwise, gives
    its value or raises its error from ``result()`` either way, and the block's one-thread BLAS limit ends with it."""
    import threading

    from threadpoolctl import threadpool_limits

    from spaceid import _threads

    def where(x):
        assert _threads.blas_threads() == 1  # the block's limit, in the worker too
        return threading.current_thread().name, 2 * x

    def fail():
        raise ValueError("from the work")

    for threads, beside in ((2, True), (1, False)):
        monkeypatch.setattr(_threads, "work_threads", lambda threads=threads: threads)
        with threadpool_limits(2, user_api="blas"):
            with _threads.side_by_side() as submit:
                name, value = submit(where, 21).result()
                failed = submit(fail)
                assert _threads.blas_threads() == 1
                with pytest.raises(ValueError, match="from the work"):
                    failed.result()
            assert _threads.blas_threads() == 2
        assert value == 42 and (name != threading.current_thread().name) == beside


def test_one_naming_scheme_for_inertial_parameters():
    """Standard parameters are named as in the YAML known_zero (Pinocchio's order, body after an
    underscore); the planar definitions' CoM inertia has a distinct name, Iczz."""
    from spaceid.dynamics import full_parameter_names
    from spaceid.models import INERTIAL_NAMES

    model = spaceid.load_model("cepheus-rw")
    names = full_parameter_names(model)
    assert names[:10] == [f"{n}_base" for n in INERTIAL_NAMES]
    assert "m_base*mcx_link1/M" in names and "mcy_link1" not in names  # declared zero in the YAML
    for name in names:
        for factor in name.removesuffix("/M").split("*"):
            assert factor.split("_")[0] in INERTIAL_NAMES, name
    definitions = " ".join(minimal_parameters(model).definitions)
    assert "Iczz_wheel" in definitions and "Izz_" not in definitions


@pytest.mark.parametrize("name", ["cepheus", "satellite-7dof"])
def test_units_are_those_of_the_leading_full_parameter(name):
    """Planar basis: kg m^2 for every pi (h [N m s] = Y [1/s] pi). Columns basis: the unit of
    the full parameter a pi starts with (kg, kg m, kg m^2; a product theta_a theta_b / M has
    the units of theta_a theta_b over kg)."""
    from spaceid.dynamics import full_parameter_names

    param = minimal_parameters(spaceid.load_model(name))
    assert len(param.units) == param.n_params
    if param.basis == "planar":
        assert set(param.units) == {"kg m^2"}
        return
    power = {"m": 0, "mcx": 1, "mcy": 1, "mcz": 1}  # lengths in kg m^p; the inertias: 2
    names = full_parameter_names(param.model)
    for row, unit in zip(param.projection, param.units):
        leading = names[np.flatnonzero(row)[0]]
        p = sum(power.get(f.split("_")[0], 2) for f in leading.removesuffix("/M").split("*"))
        assert unit == ("kg", "kg m", "kg m^2")[p], leading
    assert {"kg m", "kg m^2"} <= set(param.units)  # the masses are absorbed (into M and the inertias)
    assert [d["unit"] for d in param.to_dict()["parameters"]] == list(param.units)


@pytest.mark.parametrize("axis_z", [pytest.param(3e-4, marks=pytest.mark.slow), 5e-5, 1e-7])  # fast: one of each kind
def test_minimal_set_of_a_joint_axis_nearly_in_a_frame_plane(rng, axis_z):
    """A joint axis nearly in the x-y plane of its frame: the link's mcz depends on the columns before
    it through coefficients ~1/axis_z (3e-4, 5e-5: the round-off cleanup must keep the small true
    coefficients of the other relations), or a column before it is only weakly independent (1e-7:
    taken at once, it made the basis ill-conditioned and dependent columns were kept too, 17
    parameters instead of 15)."""
    from dataclasses import replace

    from spaceid.models._model import _validate

    generic = random_tree(rng, [0], planar=False)
    axis = np.array([0.8, 0.6, axis_z]) / np.linalg.norm([0.8, 0.6, axis_z])
    model = _validate(replace(generic, bodies=(generic.bodies[0], replace(generic.bodies[1], axis=axis))))
    param = minimal_parameters(model)
    assert param.n_params == minimal_parameters(generic).n_params == _rank(model)
    # the same columns for another seed (the round-off kept in ill-conditioned relations may differ)
    other = minimal_parameters(model, seed=1).true_values
    np.testing.assert_allclose(other, param.true_values, rtol=1e-9, atol=1e-9 * np.abs(other).max())
    q, qd, w0 = random_states(rng, model, 20)
    ref = pinocchio_momentum(to_pinocchio(model), q, qd, w0)
    error = np.abs(param.regressor(q, qd, w0) @ param.true_values - ref).max() / np.abs(ref).max()
    assert error < 1e-10


def _worker_signals():
    import signal

    return signal.getsignal(signal.SIGINT) is signal.SIG_IGN, bool(signal.pthread_sigmask(signal.SIG_BLOCK, []))


@pytest.mark.skipif(not hasattr(__import__("signal"), "pthread_sigmask"), reason="POSIX signal masks")
def test_pool_workers_are_forked_with_the_signals_held_and_start_ignoring_ctrl_c(monkeypatch):
    """The workers are forked with Ctrl-C and SIGTERM held back, and start with Ctrl-C ignored and nothing held;
    the parent holds nothing back once they run (a Ctrl-C that came as a worker was forked had run the parent's
    handler in it and left it hung)."""
    import os
    import signal

    from spaceid._threads import process_pool

    fork, held = os.fork, []

    def recorded():  # the parent's mask as it forks
        held.append(signal.pthread_sigmask(signal.SIG_BLOCK, []))
        return fork()

    monkeypatch.setattr(os, "fork", recorded)
    with process_pool(2, int) as pool:
        assert len(held) == 2 and all({signal.SIGINT, signal.SIGTERM} <= mask for mask in held)
        assert not signal.pthread_sigmask(signal.SIG_BLOCK, [])
        assert pool.submit(_worker_signals).result(timeout=60) == (True, False)


def test_a_ctrl_c_as_the_pool_waits_for_its_last_tasks_ends_its_workers_and_manager(monkeypatch):
    """A Ctrl-C that comes while the block's end waits for the last tasks stops the pool as one inside the block
    does: workers reaped and the manager thread joined (left running, Python's exit woke it through a pipe it was
    closing: "Exception ignored ... Bad file descriptor" after the command's last line, seen once in CI; the join
    had looked for the thread after the executor's shutdown, which drops it, and never ran)."""
    from concurrent.futures import ProcessPoolExecutor

    from spaceid._threads import process_pool

    shutdown, seen = ProcessPoolExecutor.shutdown, []

    def interrupted(self, wait=True, **kwargs):
        if wait and not seen:
            seen.append(self)
            raise KeyboardInterrupt
        return shutdown(self, wait=wait, **kwargs)

    monkeypatch.setattr(ProcessPoolExecutor, "shutdown", interrupted)
    with pytest.raises(KeyboardInterrupt), process_pool(2, int) as pool:
        assert pool.submit(int).result(timeout=60) == 0
        processes, manager = list(pool._processes.values()), pool._executor_manager_thread
    assert seen == [pool] and not any(p.is_alive() for p in processes) and not manager.is_alive()
