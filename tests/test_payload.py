"""Payload identification with a known servicer (spaceid.identified._payload) and the design for it."""

import json
import warnings

import numpy as np
import pytest

import spaceid
from spaceid.cli import main
from spaceid.data import write_log
from spaceid.identified import (
    identify_payload,
    nominal_payload,
    payload_map,
    project_consistent,
    pseudo_inertia,
)
from spaceid.identified._payload import _lmi
from spaceid.models import inertial_vector
from spaceid.motion import FourierTrajectory, add_noise, payload_regressor, sample_times

# a 20 kg tool-held box, CoM off every axis, a full inertia tensor that obeys the triangle rule
SAT_PAYLOAD = (20.0, [0.05, -0.03, 0.3], np.diag([2.0, 2.5, 1.5]) + 0.1 * np.ones((3, 3)))
# on Cepheus' end effector: 0.3 kg, CoM 5 cm along and 1 cm across the link, Izz about the CoM
CEPHEUS_PAYLOAD = (0.3, [0.05, 0.01], 7.8e-4)
NOISE = spaceid.Noise(angle=1e-4, rate=1e-4, base_rate=1e-4, attitude=1e-4)


def _motion(model, duration, harmonics, amplitude, seed):
    rng = np.random.default_rng(seed)
    nj = model.n_joints
    return FourierTrajectory(model.joints, duration, rng.uniform(-amplitude, amplitude, (nj, harmonics)),
                             rng.uniform(-amplitude, amplitude, (nj, harmonics)))  # fmt: skip


def _planar_theta(mass, com, izz):
    """``m, mcx, mcy, Izz`` about the link origin of a planar payload."""
    c = np.asarray(com)
    return np.array([mass, *(mass * c), izz + mass * c @ c])


def _log_with_payload(pmap, theta, traj, n, h):
    """A noise-free log of the servicer holding ``theta``, the momentum checked from rigid bodies."""
    log = spaceid.simulate(pmap.param, pmap.pi(theta), traj, np.linspace(0, traj.duration, n), h,
                           model=pmap.model(theta))
    assert log.meta["momentum_rel_error"] < 1e-9 or not np.any(h)
    return log


@pytest.fixture(scope="module")
def satellite():
    pmap = payload_map("satellite-7dof", "arm_ee")  # a tool link on a fixed joint of the URDF
    return pmap, _motion(pmap.param.model, 15.0, 3, 0.3, 1)


@pytest.fixture(scope="module")
def cepheus():
    pmap = payload_map("cepheus", "link2")  # its declared zeros (mcy) cleared for the payload
    traj = _motion(pmap.param.model, 20.0, 3, 0.3, 1)
    theta = _planar_theta(*CEPHEUS_PAYLOAD)
    return pmap, traj, theta, _log_with_payload(pmap, theta, traj, 200, np.array([0, 0, 0.05]))


@pytest.mark.parametrize("h", [[0.5, -1.0, 2.0], pytest.param([0.0, 0.0, 0.0], marks=pytest.mark.slow)],
                         ids=["momentum", "from-rest"])
def test_spatial_noise_free_recovers_the_payload(satellite, h):
    pmap, traj = satellite
    mass, com, inertia = SAT_PAYLOAD
    log = _log_with_payload(pmap, inertial_vector(mass, com, inertia), traj, 120, np.array(h))
    est = identify_payload(pmap, log, "arm_ee", h, noise=spaceid.Noise())
    assert est.mass == pytest.approx(mass, rel=1e-8)
    np.testing.assert_allclose(est.com, com, atol=1e-8)
    np.testing.assert_allclose(est.inertia, inertia, atol=1e-8 * np.abs(inertia).max())
    assert est.not_identifiable == () and not est.settings["consistency"]["projected"]
    assert est.settings["gauss_newton_steps"] > 2  # nonlinear in the mass: more than the linear step


def test_momentum_is_nonlinear_in_the_payload_mass(satellite):
    pmap, _ = satellite
    theta = inertial_vector(*SAT_PAYLOAD)
    # pi(t theta) is not t-affine: the total mass M holds the payload's
    mid = pmap.pi(0.5 * theta) - 0.5 * (pmap.pi(np.zeros(10)) + pmap.pi(theta))
    assert np.abs(mid).max() > 1e-3 * np.abs(pmap.pi(theta) - pmap.pi(np.zeros(10))).max()
    # and the analytic Jacobian is the derivative
    step = 1e-6 * np.maximum(np.abs(theta), 1e-3)
    fd = np.stack([(pmap.pi(theta + s * e) - pmap.pi(theta - s * e)) / (2 * s) for s, e in zip(step, np.eye(10))], -1)
    np.testing.assert_allclose(pmap.columns(theta), fd, atol=1e-7 * np.abs(fd).max())


@pytest.mark.slow
def test_servicer_captured_target_from_the_dual_arm_servicer():
    """The servicer-captured preset's target (150 kg, held 0.2 m beyond left_ee and turned 0.35 rad
    about z) identified in left_ee's frame with servicer-dual as the known servicer."""
    before, after = spaceid.load_model("servicer-dual"), spaceid.load_model("servicer-captured")
    pmap = payload_map(before, "left_ee")
    param = spaceid.minimal_parameters(after)
    assert param.definitions == pmap.param.definitions
    traj = _motion(before, 30.0, 4, 0.1, 0)
    h = np.array([1.0, -2.0, 3.0])
    log = spaceid.simulate(param, param.true_values, traj, np.linspace(0, 30, 300), h, model=after)
    est = identify_payload(pmap, log, "left_ee", h, noise=spaceid.Noise())
    c, s = np.cos(0.35), np.sin(0.35)
    rot = np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]])
    i_target = np.array([[18.4343, -0.0446216, 0.247962], [-0.0446216, 18.3235, 0.703207],
                         [0.247962, 0.703207, 14.5423]])
    assert est.mass == pytest.approx(150.0, rel=1e-8)
    np.testing.assert_allclose(est.com, rot @ [0.035, -0.022, 0.56] + [0, 0, 0.2], atol=1e-8)
    np.testing.assert_allclose(est.inertia, rot @ i_target @ rot.T, atol=1e-8 * 18.5)


def test_planar_noise_free_recovers_what_the_plane_shows(cepheus):
    pmap, _, _, log = cepheus
    mass, com, izz = CEPHEUS_PAYLOAD
    est = identify_payload(pmap, log, "link2", [0, 0, 0.05], noise=spaceid.Noise())
    assert est.names == ("m", "cx", "cy", "Izz")
    np.testing.assert_allclose(est.values, [mass, *com, izz], rtol=1e-8, atol=1e-12)
    assert est.not_identifiable == ("cz", "Ixx", "Ixy", "Iyy", "Ixz", "Iyz")
    assert np.isnan(est.com[2]) and np.isnan(est.inertia[0, 0]) and est.inertia[2, 2] == pytest.approx(izz)


def test_planar_capture_from_rest_and_unknown_momentum(cepheus):
    pmap, traj, theta, _ = cepheus
    log = _log_with_payload(pmap, theta, traj, 200, np.zeros(3))
    mass, com, izz = CEPHEUS_PAYLOAD
    for h in ([0, 0, 0], None):
        est = identify_payload(pmap, log, "link2", h, noise=spaceid.Noise())
        np.testing.assert_allclose(est.values, [mass, *com, izz], rtol=1e-8, atol=1e-12)
        assert abs(est.momentum[2]) < 1e-12
    assert est.settings["momentum_estimated"]


@pytest.mark.slow
def test_noisy_spread_agrees_with_the_standard_errors(cepheus):
    pmap, _, _, log = cepheus
    truth = np.array([CEPHEUS_PAYLOAD[0], *CEPHEUS_PAYLOAD[1], CEPHEUS_PAYLOAD[2]])
    runs = [identify_payload(pmap, add_noise(log, angle=1e-4, rate=1e-4, seed=s), "link2", [0, 0, 0.05], noise=NOISE)
            for s in range(80)]
    values = np.array([r.values for r in runs])
    std = np.mean([r.std for r in runs], 0)
    # 80 runs: the sample std is within ~16 % (2 sigma) of the true one
    np.testing.assert_allclose(values.std(0) / std, 1.0, atol=0.2)
    assert np.all(np.abs(values.mean(0) - truth) < 3 * std / np.sqrt(len(runs)) + 0.1 * std)
    assert all(r.settings["seed"] == 0 and r.settings["noise"]["angle"] == 1e-4 for r in runs)


def _cost_slopes(pmap, log, noise):
    """The weighted payload fit of ``log`` (the momentum given) and the slope of its cost, the whitened residuals' sum
    of squares, along each unknown at the estimate, per standard error (central differences of a tenth of one): near
    zero at a minimum, where a unit of standard error raises the cost by about one."""
    from spaceid.estimation._noise import signal_sigma
    from spaceid.identified import _payload

    fit = _payload._fit(pmap, log, np.array([0, 0, 0.05]), None, None, None, (), None, noise, False, "log", 1e10)
    eq, theta = fit.equations, fit.theta
    x = eq.signals(log)
    y = pmap.param.regressor(*eq.unpack(x)[:3])
    rhs, sigma = _payload._affine_momentum(eq, eq.p), signal_sigma(pmap.param, noise)

    def cost(t):
        r = _payload._whitened(pmap, eq, x, y, rhs, sigma, t)[0]
        return r.ravel() @ r.ravel()

    std = np.sqrt(np.diag(fit.cov))
    return np.array([(cost(theta + 0.1 * s * e) - cost(theta - 0.1 * s * e)) / 0.2 for s, e in zip(std, np.eye(len(std)))])


def test_the_weighted_payload_fit_ends_at_a_minimum_of_its_cost(cepheus, monkeypatch):
    """The weights move with the estimate and the Gauss-Newton steps include their derivative: the fit ends where
    the cost's slope along each unknown is near zero (measured on 4 noise draws: 8e-4 per standard error; one standard
    error off a minimum it is about 2). Steps at frozen weights instead (iteratively reweighted least squares: the
    weights' derivative patched to zero) end where it is not (0.35 to 0.49): off the cost's minimum."""
    from spaceid.identified import _payload

    pmap, _, _, log = cepheus
    noise = spaceid.Noise(angle=1e-3, rate=1e-3, base_rate=1e-3, attitude=1e-3)
    noisy = add_noise(log, angle=1e-3, rate=1e-3, seed=3)
    assert np.abs(_cost_slopes(pmap, noisy, noise)).max() < 0.05
    monkeypatch.setattr(_payload, "_weights_derivative", lambda *args: 0.0)
    assert np.abs(_cost_slopes(pmap, noisy, noise)).max() > 0.2


def test_residuals_that_contradict_the_given_noise_are_said_and_set_the_spread(cepheus):
    """Noise three times the levels given: chi2/dof about 9, which the noise model rejects. The payload fit says so in
    ``spaceid identify``'s words and takes its spread from the residuals (their scores' sandwich), which agrees with
    the Fisher information at the right levels (ratios 0.91 to 1.17 on two draws; the given levels' is three times too
    small); with the right levels nothing is said and the Fisher information stays."""
    pmap, _, _, log = cepheus
    noisy = add_noise(log, angle=3e-4, rate=3e-4, seed=1)
    with pytest.warns(UserWarning, match="contradict the noise model: the noise levels are too small"):
        understated = identify_payload(pmap, noisy, "link2", [0, 0, 0.05], noise=NOISE)
    right = identify_payload(pmap, noisy, "link2", [0, 0, 0.05], noise=spaceid.Noise(
        angle=3e-4, rate=3e-4, base_rate=3e-4, attitude=3e-4))
    assert 7 < understated.settings["chi2_dof"] < 11 and understated.settings["noise_model_warning"]
    assert understated.settings["covariance"].startswith("sandwich of the residuals' scores")
    assert not right.settings["noise_model_warning"] and right.settings["covariance"] == "inverse Fisher information"
    np.testing.assert_allclose(understated.std / right.std, 1.0, atol=0.25)


def test_directions_the_data_do_not_determine_are_said_and_widened(cepheus):
    """A slow motion (0.02 rad amplitudes) under 2e-2 of noise: two of the four directions of Cepheus' payload have
    regressor noise as large as their signal (ratios 0.84 and 0.64). The fit says so in ``identify``'s words and
    widens its covariance along them; the ratios are those of the columns formed anew at each signal's step (the
    noise Gram matrix of :func:`noise_gram`, independent of the derivatives the fit takes through the residuals'
    Jacobian). On the module's motion at 1e-4 it says nothing."""
    from spaceid.estimation._determined import noise_gram, noise_rows, noise_to_signal, regressor_factor, \
        signal_levels
    from spaceid.identified import _payload

    pmap, _, theta, quiet = cepheus
    log = _log_with_payload(pmap, theta, _motion(pmap.param.model, 20.0, 3, 0.02, 1), 200, np.array([0, 0, 0.05]))
    level = 2e-2
    noise = spaceid.Noise(angle=level, rate=level, base_rate=level, attitude=level)
    noisy = add_noise(log, angle=level, rate=level, seed=0)
    with pytest.warns(UserWarning, match=r"log: 2 of 4 directions of parameter space are not determined by the data"):
        est = identify_payload(pmap, noisy, "link2", [0, 0, 0.05], noise=noise)
    ratios = [d["noise_to_signal"] for d in est.settings["undetermined"]]
    assert ratios == sorted(ratios, reverse=True) and min(ratios) >= 0.5
    assert est.settings["covariance"].endswith("to their values' scale (the estimate's)")

    fit = _payload._fit(pmap, noisy, np.array([0, 0, 0.05]), None, None, None, (), None, noise, False, "log", 1e10)
    eq, x, t = fit.equations, fit.equations.signals(noisy), fit.theta
    sigma = spaceid.estimation.signal_sigma(pmap.param, noise)
    rhs = _payload._affine_momentum(eq, eq.p)
    a = _payload._whitened(pmap, eq, x, pmap.param.regressor(*eq.unpack(x)[:3]), rhs, sigma, t)[1]
    chol = _payload._whitener(pmap, eq, x, sigma, t)[0]
    rows, scale = noise_rows(len(x))
    part = eq.select(rows)

    def columns(signals):  # the whitened columns at the fit's weights, formed anew from the signals
        q, qd, w, _ = part.unpack(signals)
        raw = _payload._whitened(pmap, part, signals, pmap.param.regressor(q, qd, w), rhs, None, t)[1]
        return np.linalg.solve(chol[rows], raw)

    gram = noise_gram(columns, x[rows], signal_levels(pmap.param, noisy, sigma), scale, eq.rate_channels)
    mu = noise_to_signal(regressor_factor(a.reshape(-1, a.shape[-1])), gram)[0]
    np.testing.assert_allclose(sorted(mu[mu >= 0.5], reverse=True), ratios, rtol=1e-3)  # (forward differences)
    assert fit.undetermined == est.settings["undetermined"]

    with pytest.MonkeyPatch.context() as patch:  # unwidened, the same fit's standard errors are smaller
        patch.setattr(_payload, "_noise_ratios", lambda *args: (np.zeros(0), np.zeros((len(t), 0))))
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            unwidened = _payload._fit(pmap, noisy, np.array([0, 0, 0.05]), None, None, None, (), None, noise, False,
                                      "log", 1e10)  # fmt: skip
    assert np.all(np.diag(fit.cov) >= np.diag(unwidened.cov)) and np.any(np.diag(fit.cov) > 2 * np.diag(unwidened.cov))

    with warnings.catch_warnings():
        warnings.simplefilter("error")  # no warning at all on the module's motion
        assert identify_payload(pmap, add_noise(quiet, angle=1e-4, rate=1e-4, seed=0), "link2", [0, 0, 0.05],
                                noise=NOISE).settings["undetermined"] == []


def test_projection_of_an_inconsistent_optimum():
    # principal moments 1, 1, 3: the triangle rule fails (3 > 1 + 1), although the tensor is positive definite
    theta = inertial_vector(2.0, [0.1, 0.0, 0.0], np.diag([1.0, 1.0, 3.0]))
    cov = np.diag([1e-2, *[1e-4] * 3, *[1e-2] * 6])
    assert np.linalg.eigvalsh(pseudo_inertia(theta))[0] < 0
    near, distance = project_consistent(theta, cov, planar=False)
    assert np.linalg.eigvalsh(pseudo_inertia(near))[0] > 0 and distance > 0
    # nearest in the covariance metric: no consistent point on random rays from it is nearer
    metric = np.linalg.inv(cov)
    d_near = np.sqrt((near - theta) @ metric @ (near - theta))
    assert d_near == pytest.approx(distance, rel=1e-6)
    rng = np.random.default_rng(0)
    for _ in range(200):
        trial = near + 0.05 * np.sqrt(np.diag(cov)) * rng.standard_normal(10)
        if np.linalg.eigvalsh(pseudo_inertia(trial))[0] > 0:
            assert np.sqrt((trial - theta) @ metric @ (trial - theta)) >= d_near * (1 - 1e-6)
    consistent = inertial_vector(2.0, [0.1, 0.0, 0.0], np.diag([1.0, 1.5, 2.0]))
    assert project_consistent(consistent, cov, planar=False) == (pytest.approx(consistent), 0.0)


def test_the_projection_solves_the_program_cvxpy_states():
    """The projection states its program to Clarabel directly (cvxpy's import took a second of every projected
    payload). On random inconsistent estimates, planar and spatial, with covariances over three decades, it lands
    where the same program stated in cvxpy and solved by Clarabel lands: a wrong cone vector (the off-diagonal
    entries' sqrt 2, the triangle's order) moves it."""
    import cvxpy as cp

    from spaceid.identified._payload import _lmi_basis
    from spaceid.models.internal import CLARABEL_TOLERANCES, MARGIN

    rng, compared = np.random.default_rng(7), 0
    for trial in range(60):
        planar = trial % 2 == 0
        nominal = np.array([1.0, 0, 0, 0.02] if planar else [1.0, 0, 0, 0, 0.05, 0, 0.05, 0, 0, 0.05])
        spread = np.array([1, 0.1, 0.1, 0.1, 0.05, 0.01, 0.05, 0.01, 0.01, 0.05])[np.array([0, 1, 2, 9]) if planar
                                                                                   else slice(None)]
        theta = nominal + spread * rng.standard_normal(len(nominal))
        basis = _lmi_basis(planar, len(theta))
        lmi = np.einsum("i,ijk->jk", theta, basis)
        eig = np.linalg.eigvalsh(lmi)
        if eig[0] >= MARGIN * abs(eig).max():
            continue
        a = rng.standard_normal((len(theta),) * 2) * 10 ** rng.uniform(-3, 0, len(theta))
        cov = 1e-2 * a @ a.T
        near, distance = project_consistent(theta, cov, planar)
        w, v = np.linalg.eigh(cov)
        root = v * np.sqrt(np.maximum(w, 1e-12 * w.max()) / w.max())
        z = cp.Variable(len(theta))
        stated = lmi + sum((root @ z)[i] * basis[i] for i in range(len(theta)))
        cp.Problem(cp.Minimize(cp.sum_squares(z)), [stated >> MARGIN * abs(eig).max() * np.eye(len(lmi))]).solve(
            solver=cp.CLARABEL, **CLARABEL_TOLERANCES)
        gap = np.linalg.solve(root, near - (theta + root @ z.value))  # in the covariance's own units
        assert np.abs(gap).max() <= 1e-6 * max(1.0, np.linalg.norm(z.value))
        assert distance == pytest.approx(np.linalg.norm(z.value) / np.sqrt(w.max()), rel=1e-6)
        assert np.linalg.eigvalsh(np.einsum("i,ijk->jk", near, basis))[0] > 0
        compared += 1
    assert compared > 30


def test_a_noisy_point_mass_is_projected_to_a_consistent_estimate(cepheus):
    pmap, traj, _, _ = cepheus
    theta = _planar_theta(0.3, [0.05, 0.01], 1e-7)  # nearly a point mass: Izz about the CoM ~ 0
    log = _log_with_payload(pmap, theta, traj, 200, np.array([0, 0, 0.05]))
    projected = []
    for seed in range(6):
        est = identify_payload(pmap, add_noise(log, angle=1e-4, rate=1e-4, seed=seed), "link2", [0, 0, 0.05],
                               noise=NOISE)
        assert est.mass > 0 and est.values[3] > 0
        assert np.linalg.eigvalsh(np.array(_lmi(est.standard[[0, 1, 2, 9]], True), float))[0] > 0
        if est.settings["consistency"]["projected"]:
            projected.append(est)
            assert est.settings["consistency"]["unconstrained"]["Izz"] < 0
    assert projected  # Izz std ~2e-5 against 1e-7: about half the runs come out negative


def test_an_estimate_beyond_the_noises_reach_of_any_payload_is_said_and_widened(cepheus):
    """A payload held by the link before the one named: no rigid payload on ``link2`` fits the data
    (chi2/dof 2,100), and the unconstrained estimate lies 13 standard errors from any physical one,
    where the noise reaches 4.3 (chi-square of 4 at the significance). The projection's step is then
    error, not noise: a warning says so and the step is added to the covariance, so the standard
    errors cover it. On the right link nothing is said (the live node's first payload fits on too
    few samples after the grasp did the same: ``tests/test_ros.py``)."""
    pmap, traj, theta, right_log = cepheus
    wrong_log = _log_with_payload(payload_map("cepheus", "link1"), theta, traj, 200, np.array([0, 0, 0.05]))
    with pytest.warns(UserWarning, match=r"lay 1\d\.\d standard errors from any physical payload, where the noise "
                                         r"reaches 4\.3: the data contradict a rigid payload on `link`"):
        wrong = identify_payload(pmap, add_noise(wrong_log, angle=1e-4, rate=1e-4, seed=0), "link2", [0, 0, 0.05],
                                 noise=NOISE)
    consistency = wrong.settings["consistency"]
    assert consistency["contradicted"] and consistency["mahalanobis_distance"] > consistency["noise_reach"]
    step = np.array([wrong.values[k] - consistency["unconstrained"][name] for k, name in enumerate(wrong.names)])
    assert np.all(wrong.std >= 0.99 * np.abs(step)) and np.any(np.abs(step) > 10 * NOISE.angle)
    assert wrong.settings["covariance"].endswith("the estimate lying beyond the noise's reach of any")
    right = identify_payload(pmap, add_noise(right_log, angle=1e-4, rate=1e-4, seed=0), "link2", [0, 0, 0.05],
                             noise=NOISE)
    assert not right.settings["consistency"]["contradicted"] and "step" not in right.settings["covariance"]


@pytest.mark.slow
def test_spatial_noisy_spread_agrees_with_the_standard_errors(satellite):
    pmap, traj = satellite
    h = np.array([0.5, -1.0, 2.0])
    log = _log_with_payload(pmap, inertial_vector(*SAT_PAYLOAD), traj, 120, h)
    noise = spaceid.Noise(angle=1e-5, rate=1e-5, base_rate=1e-5, attitude=1e-5)
    runs = [identify_payload(pmap, add_noise(log, angle=1e-5, rate=1e-5, seed=s), "arm_ee", h, noise=noise)
            for s in range(30)]
    ratio = np.array([r.values for r in runs]).std(0) / np.mean([r.std for r in runs], 0)
    np.testing.assert_allclose(ratio, 1.0, atol=0.3)  # 30 runs: the sample std is within ~26 % (2 sigma)


def test_drift_is_estimated_with_the_payload(cepheus):
    pmap, traj, theta, _ = cepheus
    h = np.array([0, 0, 0.05])
    log = spaceid.simulate(pmap.param, pmap.pi(theta), traj, np.linspace(0, traj.duration, 200), h,
                           model=pmap.model(theta), drift={"torque": 2e-4, "viscous": 1e-4})
    est = identify_payload(pmap, log, "link2", h, noise=spaceid.Noise(), drift=("torque", "viscous"))
    np.testing.assert_allclose(est.values, [CEPHEUS_PAYLOAD[0], *CEPHEUS_PAYLOAD[1], CEPHEUS_PAYLOAD[2]], rtol=1e-6)
    assert [d["name"] for d in est.drift] == ["torque_z", "viscous"]
    np.testing.assert_allclose([d["value"] for d in est.drift], [2e-4, 1e-4], rtol=1e-5)
    # without the drift terms the fit is off: the test can fail
    off = identify_payload(pmap, log, "link2", h, noise=spaceid.Noise())
    assert abs(off.mass - CEPHEUS_PAYLOAD[0]) > 1e-4


# fast representatives: test_drift.py::test_drift_integrated_over_a_history,
# test_drift_is_estimated_with_the_payload
@pytest.mark.slow
def test_drift_integrated_over_a_history_from_a_known_momentum(cepheus):
    """A window cut from a longer record: the momentum is known at the record's start (before the
    window) and the drift is integrated from there, as after a grasp (docs/theory/capture.md)."""
    pmap, traj, theta, _ = cepheus
    h = np.array([0, 0, 0.05])
    record = spaceid.simulate(pmap.param, pmap.pi(theta), traj, np.linspace(0, traj.duration, 200), h,
                              model=pmap.model(theta), drift={"viscous": 1e-4})  # fmt: skip
    window = record.select(record.t > 6.0)
    est = identify_payload(pmap, window, "link2", h, noise=spaceid.Noise(), drift=("viscous",), history=record)
    np.testing.assert_allclose(est.values, [CEPHEUS_PAYLOAD[0], *CEPHEUS_PAYLOAD[1], CEPHEUS_PAYLOAD[2]], rtol=1e-6)
    np.testing.assert_allclose(est.drift[0]["value"], 1e-4, rtol=1e-5)
    # the same momentum taken at the window's start instead is wrong by the drift before it: off
    off = identify_payload(pmap, window, "link2", h, noise=spaceid.Noise(), drift=("viscous",))
    assert abs(off.mass - CEPHEUS_PAYLOAD[0]) > 1e-4


@pytest.mark.slow
def test_differentiated_rates_spread_agrees_with_the_propagated_errors(cepheus):
    """Rates differentiated from noisy angles have errors correlated over the differentiator's
    window: the angle noise carried through the Savitzky-Golay filters gives standard errors that
    match the spread (RMS z 0.82-1.06 over 30 seeds; the Newey-West estimate from the residuals,
    before: 0.52-0.59, twice too wide)."""
    from spaceid.data import differentiate_log

    pmap, traj, theta, _ = cepheus
    log = _log_with_payload(pmap, theta, traj, 1000, np.array([0, 0, 0.05]))
    truth = np.array([CEPHEUS_PAYLOAD[0], *CEPHEUS_PAYLOAD[1], CEPHEUS_PAYLOAD[2]])
    runs = [identify_payload(pmap, differentiate_log(add_noise(log, angle=1e-3, seed=s)), "link2", [0, 0, 0.05])
            for s in range(30)]  # fmt: skip
    assert "propagated through their Savitzky-Golay filters" in runs[0].settings["covariance"]
    assert all(r.settings["newey_west_std"] is not None for r in runs)
    z = (np.array([r.values for r in runs]) - truth) / np.array([r.std for r in runs])
    rms = np.sqrt((z**2).mean(0))
    assert np.all((rms > 0.7) & (rms < 1.3)) and np.abs(z).max() < 4, rms


def test_a_noise_free_logs_differentiated_rates_take_the_given_levels(cepheus):
    """The differentiator estimates each series' raw angle level from the angles' scatter about its fits: about none on
    a noise-free log, whose differentiated rates then err by the filters' truncation errors, which no noise level
    describes. Given levels (1e-4) bound the raw ones in the covariance as in the weights: the noise-free log's rates
    differentiated by cubics over 11 and 21 samples give estimates within 2 standard errors, which are those of a log
    with that noise (within a factor 2). From the levels the differentiator found alone they were 5,190 and 73,187
    standard errors off (the live engine's cubics on random robot 60775: 9), as they still are with the levels
    estimated from the log (open: the truncation errors are not in the covariance), which the warning says."""
    from spaceid.data import differentiate_log

    pmap, _, theta, log = cepheus
    truth = np.array([CEPHEUS_PAYLOAD[0], *CEPHEUS_PAYLOAD[1], CEPHEUS_PAYLOAD[2]])
    for window in (11, 21):
        clean = identify_payload(pmap, differentiate_log(log, window=window, order=3), "link2", [0, 0, 0.05],
                                 noise=NOISE)  # fmt: skip
        noisy = identify_payload(pmap, differentiate_log(add_noise(log, angle=1e-4, seed=0), window=window, order=3),
                                 "link2", [0, 0, 0.05], noise=NOISE)  # fmt: skip
        assert np.abs((clean.values - truth) / clean.std).max() < 2, (clean.values - truth) / clean.std
        assert np.all((clean.std > noisy.std / 2) & (clean.std < 2 * noisy.std)), (clean.std, noisy.std)
    # levels estimated: about none, and the residuals (chi2/dof 1.4e6) contradict them; the warning says what the
    # standard errors then are, which is not the residuals' spread
    with pytest.warns(UserWarning, match="the standard errors carry the angle noise through the differentiator's"):
        estimated = identify_payload(pmap, differentiate_log(log, window=11, order=3), "link2", [0, 0, 0.05])
    assert estimated.settings["chi2_dof"] > 1e5


def test_a_noise_free_spatial_logs_differentiated_attitude_takes_the_given_levels(satellite):
    """A spatial base's differentiated attitude leaves the payload's covariance to the Newey-West estimate from the
    residuals, which on a noise-free log are the filters' truncation errors: given levels (1e-4) bound it by the
    inverse Fisher information at them. The noise-free log (600 samples over 15 s) differentiated by cubics over 11
    and 21 samples: within 2 standard errors (from the residuals alone, 5.05 and 3.91 off)."""
    from spaceid.data import differentiate_log

    pmap, traj = satellite
    h = np.array([0.5, -1.0, 2.0])
    log = _log_with_payload(pmap, inertial_vector(*SAT_PAYLOAD), traj, 600, h)
    mass, com, inertia = SAT_PAYLOAD
    truth = np.array([mass, *com, *inertia[np.triu_indices(3)][[0, 1, 3, 2, 4, 5]]])
    for window in (11, 21):
        est = identify_payload(pmap, differentiate_log(log, window=window, order=3), "arm_ee", h, noise=NOISE)
        assert "inverse Fisher information at the levels given" in est.settings["covariance"]
        assert np.abs((est.values - truth) / est.std).max() < 2, (est.values - truth) / est.std


def test_links_from_a_urdf_file_and_unknown_links(satellite, tmp_path):
    from importlib import resources

    path = tmp_path / "servicer.urdf"
    path.write_text(resources.files("spaceid.models.presets").joinpath("satellite-7dof.urdf").read_text())
    pmap = payload_map(path, "arm_ee")
    assert pmap.body == satellite[0].body and np.allclose(pmap.transform, satellite[0].transform)
    assert not np.allclose(pmap.transform, payload_map(path, pmap.param.model.bodies[pmap.body].name).transform)
    with pytest.raises(spaceid.SpaceidError, match="`link` names 'gripper', which is not a body"):
        payload_map("satellite-7dof", "gripper")
    with pytest.raises(spaceid.SpaceidError, match="differs from the payload map's link"):
        identify_payload(pmap, None, "other", [0, 0, 0])


def test_cli_payload_end_to_end(cepheus, tmp_path, capsys):
    log = cepheus[3]
    path = tmp_path / "after.csv"
    write_log(path, add_noise(log, angle=1e-5, rate=1e-5, seed=3))
    out = tmp_path / "payload.json"
    args = ["payload", "cepheus", str(path), "--link", "link2", "--momentum", "0.05", "--noise-angle", "1e-5",
            "--noise-rate", "1e-5", "--noise-base-rate", "1e-5", "-o", str(out)]
    assert main(args) == 0
    data = json.loads(out.read_text())
    mass, com, izz = CEPHEUS_PAYLOAD
    assert abs(data["mass"] - mass) < 4 * data["std"]["mass"]
    assert abs(data["com"][0] - com[0]) < 4 * data["std"]["com"][0] and data["com"][2] is None
    assert abs(data["inertia"][2][2] - izz) < 4 * data["std"]["inertia"][2][2]
    assert data["link"] == "link2" and "Ixx" in data["not_identifiable"] and data["settings"]["seed"] == 0
    assert len(data["covariance"]["matrix"]) == 4 and data["units"]["inertia"] == "kg m^2"
    assert "not identifiable from planar motion" in capsys.readouterr().out
    assert main(args[:3] + ["--link", "nowhere"] + args[5:]) == 2
    assert "error: --link names 'nowhere', which is not a body of model cepheus" in capsys.readouterr().err
    # the design reads it back as its nominal payload
    std = data["standard_parameters"]
    np.testing.assert_allclose(nominal_payload(out, planar=True), [std["m"], std["mcx"], std["mcy"], std["Izz"]])
    (tmp_path / "empty.json").write_text("{}")
    with pytest.raises(spaceid.SpaceidError, match="no standard_parameters"):
        nominal_payload(tmp_path / "empty.json", planar=True)
    assert main(["design", "cepheus", "--duration", "5", "--harmonics", "1", "--samples", "20", "--momentum", "0",
                 "--payload-nominal", str(out), "-o", str(tmp_path / "t.json")]) == 2
    assert "--payload-nominal needs --payload-link" in capsys.readouterr().err


@pytest.mark.slow
def test_design_for_the_payload_and_its_bound(cepheus, tmp_path, capsys):
    pmap, _, theta, _ = cepheus
    param = spaceid.minimal_parameters(spaceid.load_model("cepheus"))
    noise = spaceid.Noise(angle=1e-4, rate=1e-4, base_rate=1e-4)
    h = np.array([0, 0, 0.05])
    res = spaceid.design_excitation(param, duration=10.0, harmonics=2, samples=40, momentum=h, criterion="crb",
                                    noise=noise, payload_link="link2", payload=theta, n_starts=2, seed=0)
    meta = res.trajectory.meta
    assert meta["payload_link"] == "link2" and set(meta["payload_crb_std"]) == {"m", "mcx", "mcy", "Izz"}
    # the criterion is the relative bound's trace, on the payload's scaled unknowns
    q, qd, _ = res.trajectory.evaluate(sample_times(10.0, 40))
    reg = payload_regressor(pmap, h, noise, theta)
    assert res.value == pytest.approx(np.trace(reg.crb(q, qd) / np.outer(reg.scale, reg.scale)), rel=1e-6)
    # within the joint limits
    assert np.all(np.abs(q) <= pmap.param.model.joint_limits("upper") + 1e-9)
    # the bound is what identification on that motion then reports (the mass is m in both)
    log = _log_with_payload(pmap, theta, res.trajectory, 40, h)
    runs = [identify_payload(pmap, add_noise(log, angle=1e-4, rate=1e-4, seed=s), "link2", h, noise=noise)
            for s in range(3)]
    assert np.mean([r.std[0] for r in runs]) == pytest.approx(meta["payload_crb_std"]["m"], rel=0.1)
    traj = tmp_path / "traj.json"
    assert main(["design", "cepheus", "--duration", "10", "--harmonics", "2", "--samples", "40", "--momentum", "0.05",
                 "--payload-link", "link2", "--noise-angle", "1e-4", "--noise-rate", "1e-4", "--noise-base-rate",
                 "1e-4", "--starts", "1", "-o", str(traj)]) == 0
    assert "predicted payload CRB std" in capsys.readouterr().err
    assert json.loads(traj.read_text())["meta"]["payload_link"] == "link2"
