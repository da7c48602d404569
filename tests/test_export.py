"""Export of an identified model: physical standard parameters that reproduce the identification,
closest to a prior, as a URDF that Pinocchio loads and whose momentum is the identified one."""

import dataclasses
import warnings
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pinocchio as pin
import pytest
from conftest import random_tree
from test_simulate_estimate import H, motion

import spaceid
from spaceid import SpaceidError
from spaceid.cli import main
from spaceid.data import write_json
from spaceid.dynamics import full_values, full_values_jacobian, minimal_parameters
from spaceid.estimation import Identification, identify
from spaceid.identified import export_model, pseudo_divergence, pseudo_inertia, urdf_text, write_export, yaml_text
from spaceid.models import inertial_vector, to_pinocchio
from spaceid.motion import add_noise, simulate


def perturbed(model, seed, spread=0.3):
    """``model`` with every mass and inertia about the CoM scaled by a factor in 1 +- spread (seeded)."""
    rng = np.random.default_rng(seed)
    out = []
    for b in model.bodies:
        i_c = pseudo_inertia(b.inertial)[:3, :3] - b.mass * np.outer(b.com, b.com)  # second moments about the CoM
        i_c = np.trace(i_c) * np.eye(3) - i_c
        out.append(inertial_vector(b.mass * rng.uniform(1 - spread, 1 + spread), b.com,
                                   i_c * rng.uniform(1 - spread, 1 + spread)))
    return model.with_inertials(out)


def exact_result(param):
    """The identification a noise-free log gives (pi to ~1e-12), without simulating one."""
    k = param.n_params
    return Identification(param.names, param.definitions, param.true_values, np.zeros(k), np.zeros((k, k)), 1.0,
                          np.ones(k), 0.0, 100, "ols", np.asarray(H), param.model.source, param.model.planar,
                          units=param.units)


def pinocchio_momentum(pmodel, joints, states):
    """Angular momentum about the CoM (Pinocchio's centroidal momentum) at base-at-origin states
    ``(q, qd, w0)``, base axes, shape (n, 3); the base linear velocity is arbitrary (it does not enter)."""
    data = pmodel.createData()
    ids = [pmodel.getJointId(j) for j in joints]
    out = []
    for q, qd, w0 in zip(*states):
        qp, v = pin.neutral(pmodel), np.zeros(pmodel.nv)
        v[:3], v[3:6] = [0.3, -0.2, 0.1], w0
        for j, a, r in zip(ids, q, qd):
            joint = pmodel.joints[j]  # a continuous joint's configuration is (cos, sin)
            qp[joint.idx_q : joint.idx_q + joint.nq] = [np.cos(a), np.sin(a)] if joint.nq == 2 else a
            v[joint.idx_v] = r
        out.append(np.array(pin.computeCentroidalMomentum(pmodel, data, qp, v).angular))
    return np.array(out)


def held_out_states(model, n=20, seed=7):
    rng = np.random.default_rng(seed)
    w0 = rng.standard_normal((n, 3))
    if model.planar:
        w0[:, :2] = 0.0
    return rng.uniform(-1.5, 1.5, (n, model.n_joints)), rng.standard_normal((n, model.n_joints)), w0


def check_export(true, prior, res, tmp_path, *, rtol=1e-8):
    """The exported URDF loads in Pinocchio and spaceid; pseudo-inertias PD; pi reproduced; momentum
    equal to the true model's on a held-out motion; closer to the truth than the prior."""
    path = tmp_path / "identified.urdf"
    write_export(res, path)
    pmodel = pin.buildModelFromUrdf(str(path), pin.JointModelFreeFlyer())
    back = spaceid.load_model(path, planar=true.planar)
    assert back.joints == true.joints and [b.name for b in back.bodies] == [b.name for b in true.bodies]
    for b in back.bodies:
        assert np.linalg.eigvalsh(pseudo_inertia(b.inertial)).min() > 0, b.name
    # recomputed from the file, on the prior's structure (URDF has no declared zeros)
    pi = minimal_parameters(true.with_inertials([b.inertial for b in back.bodies])).true_values
    pi_true = minimal_parameters(true).true_values
    assert np.abs(pi - pi_true).max() <= rtol * np.abs(pi_true).max()
    states = held_out_states(true)
    h = pinocchio_momentum(pmodel, true.joints, states)
    h_true = pinocchio_momentum(to_pinocchio(true), true.joints, states)
    axes = [2] if true.planar else [0, 1, 2]
    assert np.abs(h - h_true)[:, axes].max() <= rtol * np.abs(h_true[:, axes]).max()
    assert pseudo_divergence(true, back) < pseudo_divergence(true, prior)
    return back


@pytest.fixture(scope="module")
def cepheus():
    """Noise-free identification of Cepheus (simulated log, ols) and a prior 30 % off."""
    true = spaceid.load_model("cepheus")
    param = minimal_parameters(true)
    log = simulate(param, param.true_values, motion, np.linspace(0, 5, 35), H, model=true)
    ident = identify(param, log, H, estimator="ols")
    prior = perturbed(true, seed=3)
    return true, prior, ident, export_model(ident, prior)


def test_full_values_are_homogeneous_of_degree_one():
    model = spaceid.load_model("satellite-7dof")
    jac, values = full_values_jacobian(model), full_values(model)
    assert np.abs(jac @ values[: jac.shape[1]] - values).max() < 1e-13 * np.abs(values).max()


def test_pseudo_inertia_is_pd_for_physical_bodies_only():
    body = spaceid.load_model("cepheus").bodies[1].inertial
    assert np.linalg.eigvalsh(pseudo_inertia(body)).min() > 0
    flat = body.copy()
    flat[9] = flat[4] + flat[6] + 1e-4  # Izz above Ixx + Iyy (about the origin): no rigid body
    assert np.linalg.eigvalsh(pseudo_inertia(flat)).min() < 0


def test_planar_export_reproduces_pi_and_momentum(cepheus, tmp_path):
    true, prior, ident, res = cepheus
    np.testing.assert_allclose(ident.values, minimal_parameters(true).true_values, rtol=1e-9)
    back = check_export(true, prior, res, tmp_path)
    assert res.divergence == pytest.approx(pseudo_divergence(res.model, prior))
    # the out-of-plane part the planar data cannot see stays at the prior: mcz, Ixz, Iyz and the
    # out-of-plane second moment Szz = (Ixx + Iyy - Izz) / 2 of every body
    for b, p in zip(back.bodies, prior.bodies):
        for index in (3, 7, 8):
            assert b.inertial[index] == p.inertial[index]
        assert pseudo_inertia(b.inertial)[2, 2] == pytest.approx(pseudo_inertia(p.inertial)[2, 2], rel=1e-7)
    assert res.seen["base"] == ("m", "mcx", "mcy", "Izz") and res.seen["link1"] == ("m", "mcx", "Izz")


def test_generated_urdf_keeps_joints_and_limits(cepheus, tmp_path):
    true, _, _, res = cepheus
    text = urdf_text(res)  # the prior is YAML: a URDF written from the model
    assert '<joint name="left_elbow" type="revolute">' in text and 'acceleration="3.0"' in text
    (tmp_path / "cepheus.urdf").write_text(text)
    back = spaceid.load_model(tmp_path / "cepheus.urdf")
    for b, t in zip(back.bodies, true.bodies):
        assert b.name == t.name and b.joint == t.joint and b.limits == t.limits
        np.testing.assert_array_equal(b.translation, t.translation)
        np.testing.assert_allclose(b.rotation, t.rotation, atol=1e-15)


def test_yaml_keeps_planar_mode_and_declared_zeros(cepheus, tmp_path):
    true, _, ident, res = cepheus
    path = tmp_path / "identified.yaml"
    write_export(res, path, fmt="yaml")
    assert path.read_text() == yaml_text(res)
    back = spaceid.load_model(path)  # planar and known_zero from the file: the identified minimal set itself
    param = minimal_parameters(back)
    assert back.planar and [b.known_zero for b in back.bodies] == [b.known_zero for b in true.bodies]
    assert param.definitions == ident.definitions
    np.testing.assert_allclose(param.true_values, ident.values, rtol=1e-12)
    with pytest.raises(spaceid.SpaceidError, match="`fmt`: 'step' is not one of urdf, yaml"):
        write_export(res, path, fmt="step")


@pytest.mark.parametrize("rows, cols", [(496, 170), (153, 80), (8, 30)])
def test_the_ellipsoid_cone_holds_as_many_entries_as_unknowns(rows, cols):
    """The ellipsoid's residual ``A_w theta - b_w`` reduced to ``n_theta + 1`` entries of the same norm where the
    minimal parameters outnumber the standard ones (the servicer: 171 against 496; its solves 0.4 -> 0.03 s), as
    it is otherwise."""
    from spaceid.identified._export import _ball_rows

    rng = np.random.default_rng(rows)
    a_w, b_w, theta = rng.standard_normal((rows, cols)), rng.standard_normal(rows), rng.standard_normal(cols)
    m, c = _ball_rows(a_w, b_w)
    assert m.shape == ((cols + 1, cols) if rows > cols else (rows, cols))
    assert np.linalg.norm(m @ theta - c) == pytest.approx(np.linalg.norm(a_w @ theta - b_w), rel=1e-12)


def _cvxpy_program(program, a_eq, b_eq, a_w, b_w, around=None, nearest=None):
    """The export's convex step stated in cvxpy as it was before it was stated to Clarabel directly: ``(vec X,
    slack, excess)`` of cvxpy's solution by Clarabel at the export's tolerances."""
    import cvxpy as cp

    from spaceid.models.internal import CLARABEL_TOLERANCES, MARGIN

    x = [cp.Variable((4, 4), symmetric=True) for _ in range(program.g.shape[1] // 16)]
    vec = cp.hstack([cp.vec(b, order="F") for b in x])
    theta = program.g @ vec
    cons = [b >> MARGIN * np.eye(4) for b in x] + ([program.z @ vec == 0] if len(program.z) else [])
    cons += [cp.abs(vec - around[0]) <= around[1]] if around is not None else []
    ball = cp.norm(a_w @ theta - b_w)
    if program.elastic:
        slack, excess = cp.Variable(len(a_eq)), cp.Variable(nonneg=True)
        cons += [a_eq @ theta - b_eq == slack, ball <= program.radius + excess]
        objective = cp.norm1(slack) + excess
    else:
        slack = excess = None
        cons += [a_eq @ theta == b_eq, ball <= program.radius]
        objective = (cp.sum_squares(vec - nearest) if nearest is not None else
                     sum(cp.trace(b) - cp.log_det(b) for b in x))  # fmt: skip
    cp.Problem(cp.Minimize(objective), cons).solve(solver=cp.CLARABEL, **CLARABEL_TOLERANCES)
    return np.concatenate([b.value.ravel(order="F") for b in x]), slack, excess


@pytest.mark.parametrize("kind", ["log-det", "trust region", "nearest", "elastic"])
def test_the_convex_step_solves_the_program_cvxpy_states(kind):
    """The export's convex step states its program to Clarabel directly (its log-det objective by exponential and
    semidefinite cones): on random trees of 2 to 5 bodies, planar and spatial, from priors 30 % off their robots,
    with conditions linearised at the truth and an ellipsoid around it, each kind of program lands where the same
    program stated in cvxpy lands, to the solver's tolerance. A wrong cone vector (the off-diagonal entries' sqrt 2,
    the triangle's order, ``D``'s side) moves it."""
    from spaceid.identified import _export
    from spaceid.models.internal import theta_slots

    rng, compared = np.random.default_rng(["log-det", "trust region", "nearest", "elastic"].index(kind)), 0
    for trial in range(6):
        parents = [int(rng.integers(0, i + 1)) for i in range(int(rng.integers(1, 5)))]
        true = random_tree(rng, parents, planar=trial % 2 == 0)
        prior = true.with_inertials(np.array([b.inertial for b in true.bodies]) * rng.uniform(0.7, 1.3,
                                                                                               (len(true.bodies), 1)))
        param = minimal_parameters(true)
        g, z = _export.pseudo_whitening(prior, "prior")
        theta = np.array([true.bodies[b].inertial[k] for b, k in theta_slots(true)])
        pi = param.true_values
        e = np.eye(len(pi))[: max(1, len(pi) // 2)]
        w = np.eye(len(pi))[len(e):] / (0.05 * np.maximum(np.abs(pi[len(e):]), 1e-3))[:, None]
        program = _export._Program(g, z, 3.0, elastic=kind == "elastic")
        conditions = _export._conditions(param, g, theta, e, w, pi + 0.05 * (kind == "elastic"))
        start = np.linalg.lstsq(g, theta, rcond=None)[0]
        options = {"around": (start, 0.3)} if kind == "trust region" else {"nearest": start} if kind == "nearest" else {}
        ours = program.solve(*conditions, **options)
        theirs, slack, excess = _cvxpy_program(program, *conditions, **options)
        if ours is None:
            assert theirs is None or not np.all(np.isfinite(theirs))
            continue
        if kind == "elastic":  # its optimum, not its solution, is unique: the same violation, met by its own
            theta_ours = g @ ours
            assert _export._violation(program) == pytest.approx(np.abs(slack.value).sum() + excess.value, abs=1e-7)
            assert np.abs(conditions[0] @ theta_ours - conditions[1] - program.slack).max() <= 1e-7
            assert np.linalg.norm(conditions[2] @ theta_ours - conditions[3]) <= 3.0 + program.excess + 1e-7
        else:
            assert np.abs(ours - theirs).max() <= 1e-5 * max(1.0, np.abs(theirs).max())
        assert min(np.linalg.eigvalsh(x.reshape(4, 4, order="F"))[0] for x in np.split(ours, len(ours) // 16)) > 0
        compared += 1
    assert compared >= 4


def test_the_exact_search_is_skipped_when_no_model_reproduces_the_estimate(cepheus, monkeypatch):
    """Cepheus's 8 minimal parameters are functions of fewer independent combinations of its standard ones: its
    noise-free estimate is reached from the prior (and exported exactly), a noisy one is missed by far more than the
    estimate's accuracy, and its export goes to the ellipsoids without the exact search."""
    from spaceid.identified import _export

    true, prior, ident, exported = cepheus
    param = minimal_parameters(true)
    g = _export.pseudo_whitening(prior, "prior")[0]
    start, scale = full_values(prior)[: g.shape[0]], np.abs(g).max(axis=1)
    assert exported.region is None
    assert _export._miss(ident, param, start, scale) <= _export._accuracy(ident)
    std = 1e-3 * np.abs(ident.values)
    noisy = Identification(**{**ident.__dict__, "values": ident.values + std * np.random.default_rng(1).standard_normal(
        len(std)), "std": std, "cov": np.diag(std**2)})
    assert _export._miss(noisy, param, start, scale) > 1e3 * _export.UNREACHED * _export._accuracy(noisy)
    attempt, regions = _export._export, []
    monkeypatch.setattr(_export, "_export", lambda result, prior, param, region, *args, **kwargs: (
        regions.append(region), attempt(result, prior, param, region, *args, **kwargs))[1])
    with pytest.warns(UserWarning, match=r"exactly \(no model, physical or not, reproduces it\)"):
        assert export_model(noisy, prior).region == regions[0] == 0.95


def test_combinations_a_widening_left_below_round_off_are_held_exactly_and_named_when_unmet(cepheus):
    """A noisy estimate (standard errors 1e-3 of its values) whose covariance is widened along one direction the
    data do not determine to a variance 1e18 times its own: the other seven combinations' variances are lost to its
    round-off. Held exactly, as if of no variance, they are met by a physical model, which is exported (within an
    ellipsoid of any size along them). With the first parameter's sign flipped they meet none, and the refusal
    names that cause in one line, with the remedies; widened by 1e6 only, every variance resolved, the same
    estimate's refusal is the usual one."""
    true, prior, ident, _ = cepheus
    std = 1e-3 * np.abs(ident.values)
    values = ident.values + std * np.random.default_rng(1).standard_normal(len(std))
    flipped = values * np.where(np.arange(len(values)) == 0, -1.0, 1.0)
    direction = np.ones(len(std)) / np.sqrt(len(std))
    undetermined = ({"noise_to_signal": 4.5, "parameters": ["pi1"]},)

    def widened(pi, widening):
        cov = np.diag(std**2) + widening * std.min() ** 2 * np.outer(direction, direction)
        return Identification(**{**ident.__dict__, "values": pi, "std": np.sqrt(np.diag(cov)), "cov": cov,
                                 "diagnostics": dataclasses.replace(ident.diagnostics, undetermined=undetermined)})

    with pytest.warns(UserWarning, match="not physically realisable exactly"):
        assert export_model(widened(values, 1e18), prior).region == 0.95
    with pytest.raises(SpaceidError, match=r"^result: no physical model found: the estimate's covariance, widened "
                       r"along the 1 directions the data do not determine \(standard errors up to .*\), leaves 7 "
                       r"combinations .* below its round-off, and held exactly, as if of no variance, no physical model "
                       r"was found to meet them: identify with a `prior` .* or on a designed motion"):  # fmt: skip
        export_model(widened(flipped, 1e18), prior)
    with pytest.raises(SpaceidError, match=r"^result: no physical model found within the 0.999 confidence ellipsoid"):
        export_model(widened(flipped, 1e6), prior)


def test_infeasible_pi_is_one_line_naming_it(cepheus, monkeypatch):
    """Refused after three attempts (the exact one, searched again in stages, then the smallest and the largest
    automatic ellipsoid), in one line naming the parameter no physical body has."""
    from spaceid.identified import _export

    _, prior, ident, _ = cepheus
    values = ident.values.copy()
    values[7] = -abs(values[7])  # pi8 = Iczz_link2 + (positive terms): negative, no physical body has it
    bad = Identification(**{**ident.__dict__, "values": values})
    attempt, regions = _export._export, []

    def counted(result, prior, param, region, *args, **kwargs):
        regions.append((region, kwargs.get("staged", True)))
        return attempt(result, prior, param, region, *args, **kwargs)

    monkeypatch.setattr(_export, "_export", counted)
    with pytest.raises(spaceid.SpaceidError, match=r"not physically realisable from the prior.*pi8.*local.*`region`.*"
                                                    r"closer to the robot") as info:
        export_model(bad, prior, where="bad.json")
    assert "\n" not in str(info.value)
    assert regions == [(None, True), (0.95, False), (0.999, False)]


@pytest.mark.slow  # 3 to 4 s; fast representative of the search: test_infeasible_pi_is_one_line_naming_it
def test_a_search_stalled_from_the_prior_is_run_again_in_stages(tmp_path):
    """Random planar robot 3 released at rest, identified from its noise-free log (9 parameters): from a prior 20 % /
    1 cm off, the steps stalled at a violation of 0.0042 (no step lowered it) and the export was refused though the
    true robot meets the conditions well inside the margin; from the prior's own minimal parameters to the
    estimate's in stages, it reproduces the estimate with a physical model."""
    from random_robots import perturbed_prior
    from test_random_pipeline import flown_at_rest

    from spaceid.identified import unphysical_bodies

    flown, anchor = flown_at_rest(3, True, tmp_path)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        exact = identify(flown.param, flown.log, flown.momentum, known=anchor, estimator="ols")
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # exact: no automatic ellipsoid
        export = export_model(exact, perturbed_prior(flown.model, 4))
    assert export.region is None and not unphysical_bodies(export.model)
    assert np.abs(export.values - exact.values).max() <= 1e-9 * np.abs(exact.values).max()


@pytest.mark.parametrize("holds", [0.95, 0.99, 0.999, None])
def test_automatic_ellipsoid_is_the_smallest_that_holds_a_physical_model(holds, monkeypatch):
    """Whichever automatic ellipsoid is the first to hold one (None: none does), the export is within the smallest
    that does, and a refusal tries two (the ellipsoids are nested) and hands on the largest's unmet conditions."""
    from spaceid.identified import _export

    tried = []

    def export_from(result, prior, param, region, where, prior_name, staged):
        tried.append(region)
        if holds is None or region < holds:
            raise _export._Unmet(lambda: spaceid.SpaceidError(f"none within {region}"))
        return SimpleNamespace(region=region)

    monkeypatch.setattr(_export, "_export", export_from)
    found = _export._auto_export(None, None, None, "r.json", "prior")
    if holds is None:
        assert str(found.error()) == "none within 0.999"
    else:
        assert found.region == holds
    assert tried == {0.95: [0.95], 0.99: [0.95, 0.999, 0.99], 0.999: [0.95, 0.999, 0.99], None: [0.95, 0.999]}[holds]


def test_bad_region_and_other_joints_are_refused(cepheus):
    _, prior, ident, _ = cepheus
    with pytest.raises(spaceid.SpaceidError, match="`region`: 1.5 is not a probability"):
        export_model(ident, prior, region=1.5)
    with pytest.raises(spaceid.SpaceidError, match="joints .* differ from the identified model"):
        export_model(ident, "satellite-7dof", prior_name="satellite-7dof")


def test_point_mass_prior_is_refused(cepheus):
    _, prior, ident, _ = cepheus
    inertials = [b.inertial for b in prior.bodies]
    inertials[1] = inertial_vector(prior.bodies[1].mass, [0, 0, 0], np.zeros((3, 3)))  # a point at the joint
    with pytest.raises(spaceid.SpaceidError, match="body 'link1' of the prior is a point mass"):
        export_model(ident, prior.with_inertials(inertials), prior_name="prior.yaml")


@pytest.mark.slow
def test_flat_wheel_prior_gets_a_small_spread():
    """The cepheus-rw wheel is a disc (Izz = Ixx + Iyy: pseudo-inertia singular): it is measured
    with 1e-6 of isotropic spread added, and its identified axial inertia is reproduced exactly."""
    true = spaceid.load_model("cepheus-rw")
    param = minimal_parameters(true)
    res = export_model(exact_result(param), perturbed(true, seed=2))
    assert np.abs(res.values - param.true_values).max() <= 1e-12 * np.abs(param.true_values).max()
    wheel = res.model.bodies[1]
    assert wheel.inertial[9] == pytest.approx(true.bodies[1].inertial[9], rel=1e-12)
    thickness = pseudo_inertia(wheel.inertial)[2, 2]  # Szz = (Ixx + Iyy - Izz) / 2
    assert 0 < thickness < 1e-5 * wheel.inertial[9]


@pytest.mark.slow
def test_noisy_planar_export_within_the_ellipsoid_anchor_exact(tmp_path):
    """Noisy Cepheus, momentum unknown and the scale anchored by a known pi5 (zero variance)."""
    true = spaceid.load_model("cepheus")
    param = minimal_parameters(true)
    log = simulate(param, param.true_values, motion, np.linspace(0, 5, 201), H, model=true)
    ident = identify(param, add_noise(log, angle=1e-3, rate=1e-3, seed=5), None, estimator="wls",
                     known={"pi5": param.true_values[4]})
    assert ident.std[4] == 0 and ident.std[np.arange(8) != 4].min() > 0
    prior = perturbed(true, seed=4)
    res = export_model(ident, prior, region=0.95)
    free = np.arange(8) != 4
    r = (res.values - ident.values)[free]
    d2 = r @ np.linalg.solve(ident.cov[np.ix_(free, free)], r)
    assert d2 <= res.bound == pytest.approx(14.0671, rel=1e-4)  # chi2_7(0.95): the anchor has no variance
    assert res.mahalanobis == pytest.approx(d2, rel=1e-6)
    assert res.values[4] == pytest.approx(ident.values[4], rel=1e-12)
    for b in res.model.bodies:
        assert np.linalg.eigvalsh(pseudo_inertia(b.inertial)).min() > 0
    assert pseudo_divergence(true, res.model) < pseudo_divergence(true, prior)


@pytest.mark.slow
def test_spatial_export_reproduces_pi_and_momentum(tmp_path):
    true = spaceid.load_model("satellite-7dof")
    prior = perturbed(true, seed=1)
    res = export_model(exact_result(minimal_parameters(true)), prior)
    check_export(true, prior, res, tmp_path)
    text = (tmp_path / "identified.urdf").read_text()
    # the prior's file is kept (visuals, limits); the end effector on its fixed joint is merged into link 7
    preset = (Path(spaceid.__file__).parent / "models" / "presets" / "satellite-7dof.urdf").read_text()
    assert text.count("<visual>") == preset.count("<visual>") > 0 and 'acceleration="0.5"' in text
    assert "merged into the link of its body" in text
    # everything but the inertials is the prior's: joints, materials, visuals and collisions element by element
    import defusedxml.ElementTree as ET

    def without_inertials(xml):
        root = ET.fromstring(xml)
        for link in root.findall("link"):
            for inertial in link.findall("inertial"):
                link.remove(inertial)
        return [" ".join(ET.tostring(child, encoding="unicode").split()) for child in root]

    assert without_inertials(text) == without_inertials(preset)


@pytest.mark.slow
def test_noisy_spatial_export_takes_the_region_by_itself(tmp_path, monkeypatch):
    """153 noisy combinations of 80 standard parameters: no model, physical or not, reproduces them, and the export
    goes to the ellipsoids without searching for an exact one."""
    from spaceid.identified import _export

    attempt, regions = _export._export, []
    monkeypatch.setattr(_export, "_export", lambda result, prior, param, region, *args, **kwargs: (
        regions.append(region), attempt(result, prior, param, region, *args, **kwargs))[1])
    true = spaceid.load_model("satellite-7dof")
    param = minimal_parameters(true)
    exact = exact_result(param)
    std = 1e-3 * np.abs(param.true_values) + 1e-6 * np.abs(param.true_values).max()
    values = param.true_values + std * np.random.default_rng(2).standard_normal(param.n_params)
    noisy = Identification(**{**exact.__dict__, "values": values, "std": std, "cov": np.diag(std**2)})
    prior = perturbed(true, seed=1)
    with pytest.warns(UserWarning, match=r"not physically realisable exactly \(no model, physical or not, reproduces "
                                         r"it\): .* within its 0.95 confidence"):
        res = export_model(noisy, prior)
    assert res.region == 0.95 and res.mahalanobis <= res.bound and regions == [0.95]
    for b in res.model.bodies:
        assert np.linalg.eigvalsh(pseudo_inertia(b.inertial)).min() > 0
    given = export_model(noisy, prior, region=0.95)
    np.testing.assert_array_equal(given.values, res.values)
    check_export(true, prior, res, tmp_path, rtol=1e-2)


def test_cli_errors_are_one_line(cepheus, tmp_path, capsys):
    _, _, ident, _ = cepheus
    result = tmp_path / "result.json"
    write_json(result, ident.to_dict())
    assert main(["export", str(tmp_path / "missing.json"), "--prior", "cepheus", "-o", str(tmp_path / "x.urdf")]) == 2
    assert main(["export", str(result), "--prior", "satellite-7dof", "-o", str(tmp_path / "x.urdf")]) == 2
    assert main(["export", str(result), "--prior", "cepheus", "--region", "0", "-o", str(tmp_path / "x.urdf")]) == 2
    errors = capsys.readouterr().err.strip().splitlines()
    assert len(errors) == 3 and all(e.startswith("error: ") for e in errors)
    assert "missing.json" in errors[0] and "differ" in errors[1] and "--region" in errors[2]
    assert not (tmp_path / "x.urdf").exists()


@pytest.mark.slow
def test_cli_writes_the_urdf_and_refuses_its_inputs(cepheus, tmp_path, capsys):
    true, _, ident, _ = cepheus
    result, prior = tmp_path / "result.json", tmp_path / "prior.yaml"
    write_json(result, ident.to_dict())
    prior.write_text((Path(spaceid.__file__).parent / "models" / "presets" / "cepheus.yaml").read_text())
    before = prior.read_text(), result.read_text()
    assert main(["export", str(result), "--prior", str(prior), "-o", str(prior)]) == 2
    assert main(["export", str(result), "--prior", str(prior), "-o", str(result)]) == 2
    assert capsys.readouterr().err.count("is the input") == 2 and (prior.read_text(), result.read_text()) == before
    out = tmp_path / "identified.urdf"
    assert main(["export", str(result), "--prior", str(prior), "-o", str(out)]) == 0
    printed = capsys.readouterr().out
    assert "link2" in printed and "m mcx Izz" in printed and "exact" in printed
    back = spaceid.load_model(out, planar=True)
    pi = minimal_parameters(true.with_inertials([b.inertial for b in back.bodies])).true_values
    np.testing.assert_allclose(pi, ident.values, rtol=1e-8)


def test_an_unphysical_model_is_never_written(cepheus, tmp_path):
    true, prior, ident, res = cepheus
    inertials = np.array([b.inertial for b in res.model.bodies])
    inertials[1, 4:] *= -1  # link 1's inertia negative: no pseudo-inertia is positive definite
    bad = dataclasses.replace(res, model=res.model.with_inertials(inertials))
    path = tmp_path / "bad.urdf"
    with pytest.raises(spaceid.SpaceidError, match=f"not written: the bodies {res.model.bodies[1].name} "):
        write_export(bad, path)
    assert not path.exists() and list(tmp_path.iterdir()) == []
