"""Estimators on data with known truth: noise-free recovery, spread vs predicted covariance,
bias removal, the Cramer-Rao bound vs a brute-force Fisher information, scale anchors."""

import dataclasses
import warnings

import numpy as np
import pytest
from conftest import random_tree

import spaceid
from spaceid import SpaceidError
from spaceid.estimation import ESTIMATORS, cramer_rao, identify
from spaceid.estimation import Noise
from spaceid.dynamics import minimal_parameters
from spaceid.dynamics import base_rate
from spaceid.motion import add_noise, simulate
from spaceid.motion import load_trajectory

H = np.array([0.0, 0.0, 0.4934])
TRAJ = load_trajectory("paper-table2")
RATE_BASED = tuple(e for e in ESTIMATORS if e != "angles")  # the angles estimator: tests/test_angles.py


def paper_motion(t):
    return TRAJ.evaluate(t)[:2]


@pytest.fixture(scope="module")
def cepheus():
    param = minimal_parameters(spaceid.load_model("cepheus"))
    return param, lambda n: simulate(param, param.true_values, paper_motion, np.linspace(0, 5, n), H)


@pytest.fixture(scope="module")
def cepheus_rw():
    """Cepheus with its reaction wheel spinning at 170 rad/s (plus a wobble): total momentum 0."""
    param = minimal_parameters(spaceid.load_model("cepheus-rw"))

    def motion(t):
        q, qd = paper_motion(t)
        wheel = 170 * t + 2 * np.sin(3 * t), 170 + 6 * np.cos(3 * t)
        return np.column_stack([wheel[0], q]), np.column_stack([wheel[1], qd])

    return param, simulate(param, param.true_values, motion, np.linspace(0, 5, 201), np.zeros(3))


@pytest.mark.parametrize("estimator", RATE_BASED)
def test_noise_free_recovery(cepheus, estimator):
    param, make = cepheus
    ident = identify(param, make(101), H, estimator=estimator)
    assert np.abs(ident.values / param.true_values - 1).max() < 1e-8


@pytest.mark.parametrize("estimator", RATE_BASED)
def test_noise_free_recovery_spatial(rng, estimator):
    model = random_tree(np.random.default_rng(7), [0, 1], planar=False)
    param = minimal_parameters(model)
    t = np.linspace(0, 5, 60)

    def motion(t):
        t = np.asarray(t)[:, None]
        w = np.array([1.1, 1.7, 0.9, 1.3, 2.3, 0.7])[: len(model.joints)]
        return np.sin(w * t + 0.3) + 0.3 * np.sin(2.9 * w * t), w * np.cos(w * t + 0.3) + 0.87 * w * np.cos(2.9 * w * t)

    h = np.array([0.3, -0.2, 0.5])
    log = simulate(param, param.true_values, motion, t, h, initial_quat=[0.8, 0.6, 0, 0])
    ident = identify(param, log, h, estimator=estimator)
    err = np.abs(ident.values - param.true_values) / np.abs(param.true_values).max()
    assert err.max() < 1e-8


@pytest.mark.slow
@pytest.mark.parametrize("estimator", RATE_BASED)
def test_spread_matches_predicted_covariance(cepheus, estimator):
    """150 noise draws: the empirical std agrees with the predicted standard error (the std of
    a 150-draw std estimate is ~6 %, so the band is about 4 sigma wide)."""
    param, make = cepheus
    log = make(101)
    noise = Noise(1e-3, 1e-3, 1e-3)
    runs = [identify(param, add_noise(log, angle=1e-3, rate=1e-3, seed=s), H, estimator=estimator, noise=noise)
            for s in range(150)]  # fmt: skip
    est = np.array([r.values for r in runs])
    ratio = est.std(axis=0) / np.mean([r.std for r in runs], axis=0)
    assert np.all((ratio > 0.78) & (ratio < 1.28)), ratio


@pytest.mark.slow
def test_ml_removes_the_bias_of_least_squares(cepheus):
    """At 1 % noise OLS is biased by several standard deviations; ML is not, and reaches the CRB."""
    param, make = cepheus
    log = make(501)
    noise = Noise(1e-2, 1e-2, 1e-2)
    _, crb = cramer_rao(param, log, H, noise)
    errors = {}
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        for est in ("ols", "ml"):
            errors[est] = np.array([identify(param, add_noise(log, angle=1e-2, rate=1e-2, seed=s), H, estimator=est,
                                             noise=noise).values for s in range(40)]) - param.true_values  # fmt: skip
    z = {k: e.mean(0) / (e.std(0) / np.sqrt(len(e))) for k, e in errors.items()}  # bias in standard errors of the mean
    assert np.median(np.abs(z["ols"])) > 10
    assert np.abs(z["ml"]).max() < 4.5
    rmse = np.sqrt(np.mean(errors["ml"] ** 2, 0))
    assert np.all(rmse / np.sqrt(np.diag(crb)) < 1.5)


def test_ml_stops_close_to_its_fixed_point(cepheus, monkeypatch):
    """ML stops once a step moves no parameter by 1e-4 of its standard error; iterated on to
    1e-10 it moves by less than 1e-3 standard errors (at 1 % noise, where it iterates most)."""
    from spaceid.estimation import _estimators as estimate

    param, make = cepheus
    log = add_noise(make(501), angle=1e-2, rate=1e-2, seed=3)
    noise = Noise(1e-2, 1e-2, 1e-2)
    default = identify(param, log, H, estimator="ml", noise=noise)
    monkeypatch.setitem(estimate._KERNELS, "ml", lambda *args, **kw: estimate._ml(*args, **kw, tol=1e-10))
    tight = identify(param, log, H, estimator="ml", noise=noise)
    assert tight.diagnostics.estimator_info["iterations"] > default.diagnostics.estimator_info["iterations"] >= 3
    assert (np.abs(default.values - tight.values) / default.std).max() < 1e-3
    info = default.diagnostics.estimator_info
    assert info["converged"] and info["fallback"] is None and info["objective_end"] < info["objective_start"]


def test_ml_that_does_not_converge_falls_back(cepheus, monkeypatch):
    """Stopped after one iteration, ML reports WLS or OLS, whichever has the lower objective (the
    two are within 0.1 % here), with its covariance, says so in a warning and records it."""
    from spaceid.estimation import _estimators as estimate

    param, make = cepheus
    log = add_noise(make(501), angle=1e-2, rate=1e-2, seed=3)
    noise = Noise(1e-2, 1e-2, 1e-2)
    monkeypatch.setitem(estimate._KERNELS, "ml", lambda *args, **kw: estimate._ml(*args, **kw, max_iter=1))
    with pytest.warns(UserWarning, match=r"maximum likelihood failed, the estimate reported is (wls|ols): .*did not "
                                         r"converge in 1 iterations"):  # fmt: skip
        ml = identify(param, log, H, estimator="ml", noise=noise)
    info = ml.diagnostics.estimator_info
    fallback = info["fallback"].split(":")[0]
    assert not info["converged"] and fallback in ("wls", "ols")
    assert info["objective_end"] <= info["objective_start"]
    assert "WLS" in info["fallback"]  # why: WLS's objective against the start's
    reported = identify(param, log, H, estimator=fallback, noise=noise)
    assert ml.values == pytest.approx(reported.values, rel=1e-12) and ml.std == pytest.approx(reported.std, rel=1e-9)


@pytest.mark.slow
def test_ml_never_reports_physically_impossible_parameters_when_wls_has_none(cepheus):
    """Rates differentiated from angles with 3e-2 rad noise, taken as measured, levels estimated (far
    too small for the rates: chi2_dof ~3e2). The accelerated iteration converges here to a local minimum of the
    objective whose parameters are up to 9 times their size, an inertia-like one negative beyond
    2 sigma (the unaccelerated one ran off to 100 times). That is not reported: WLS's estimate,
    physically possible, is, and the result says why. (Noise seed 2: with the differentiator's window
    chosen for the estimate, seed 0's converges to a physical one; seeds 2, 3 and 5 of 0 to 7 do not.)"""
    from spaceid.data import differentiate_log

    param, _ = cepheus
    log = differentiate_log(add_noise(simulate(param, param.true_values, paper_motion, np.arange(0, 5.0001, 0.01), H),
                                      angle=3e-2, seed=2))  # fmt: skip
    # the differentiator's record dropped: the rates taken as measured, their levels estimated from the smoothed
    # log itself, far too small (with the record the weights take the filters' levels, and ML converges to a
    # physical estimate)
    log = dataclasses.replace(log, meta={k: v for k, v in log.meta.items() if k != "differentiation"})
    wls = identify(param, log, H, estimator="wls")
    with pytest.warns(UserWarning) as record:
        ml = identify(param, log, H, estimator="ml")
    messages = [str(w.message) for w in record]
    info = ml.diagnostics.estimator_info
    assert info["converged"] and info["fallback"].startswith("wls: the maximum-likelihood estimate converged to")
    assert any("the estimate reported is wls" in m for m in messages)
    assert not any("physically impossible parameters, negative" in m for m in messages)  # no longer reported
    # WLS's estimate; its standard errors at least WLS's own, widened by the change from OLS's (its weights, taken at
    # its own estimates, can pull it away: test_random_pipeline's robot 83 at rest, 71 of its standard errors off)
    assert ml.values == pytest.approx(wls.values, rel=1e-12) and np.all(ml.std >= wls.std * (1 - 1e-9))
    assert "widened along the change from OLS's estimate" in ml.diagnostics.covariance
    assert ml.diagnostics.chi2_dof > 1e2 and any("contradict the noise model" in m for m in messages)


def _reference_ml(eq, x, sigma, theta, iterations=40, subspace=None):
    """The fundamental numerical scheme as first written, with nothing reused: at each estimate the
    equations linearised at the corrected signals (their columns included, by
    ``Equations.linearized``), whitened by batched solves and refactorised by ``numpy.linalg.lstsq``;
    the next linearisation point is the corrected signals of the update. With ``subspace (p, k)``
    the update is confined to its span (the normal equations projected onto it)."""
    from spaceid.estimation._noise import equation_covariance

    xh = x
    for _ in range(iterations):
        phit = eq.linearized(xh, x - xh)
        J = eq.jacobian(xh, theta)
        L = np.linalg.cholesky(equation_covariance(J, sigma))
        white = np.linalg.solve(L, phit)
        A, b = white[..., :-1].reshape(-1, eq.p), -white[..., -1].ravel()
        u = np.linalg.solve(np.swapaxes(L, 1, 2), white @ np.append(theta, 1.0)[:, None])[..., 0]
        extra = eq.contracted_dphi(xh, sigma**2 * np.einsum("nrx,nr->nx", J, u), u)
        if subspace is None:
            theta = np.linalg.solve(A.T @ A, A.T @ b + extra)
        else:
            B = subspace
            theta = theta + B @ np.linalg.solve(B.T @ A.T @ A @ B, B.T @ (A.T @ b + extra - A.T @ A @ theta))
        u = np.linalg.solve(np.swapaxes(L, 1, 2), np.linalg.solve(L, phit @ np.append(theta, 1.0)[:, None]))[..., 0]
        xh = x - sigma**2 * np.einsum("nrx,nr->nx", J, u)
    return theta


@pytest.mark.parametrize("level", [1e-3, pytest.param(1e-2, marks=pytest.mark.slow)])
def test_ml_reaches_the_fixed_point_of_the_scheme_as_first_written(cepheus, level):
    """The iteration reuses the columns at the measured signals, one factorisation and Anderson
    acceleration; its estimate is still the fixed point of the plain scheme (:func:`_reference_ml`),
    to its tolerance (1e-4 standard errors), at 0.1 % and at 1 % noise (where the columns' own
    change with the corrections matters most: evaluating the weights' derivative at the measured
    signals instead of halfway to the corrected ones moved the estimate by 8e-4 standard errors)."""
    from spaceid.estimation._equations import _equations
    from spaceid.estimation import signal_sigma

    param, make = cepheus
    log = add_noise(make(501), angle=level, rate=level, seed=3)
    noise = Noise(level, level, level)
    ml = identify(param, log, H, estimator="ml", noise=noise)
    eq, _ = _equations(param, log, H, None, "log")
    ols = identify(param, log, H, estimator="ols").values[eq.free]
    reference = _reference_ml(eq, eq.signals(log), signal_sigma(param, noise), ols)
    assert np.abs(ml.values[eq.free] - reference).max() / ml.std[eq.free].min() < 2e-4


def test_ml_builds_the_regressor_once(cepheus, monkeypatch):
    """In memory the columns are built once, at the measured signals: no linearised equations,
    the corrected signals entering through the residuals and the weights (signal Jacobian). (The
    diagnostics' noise Gram matrix builds its own at perturbed signals: not counted.)"""
    from spaceid.estimation import _determined
    from spaceid.estimation._equations import Equations

    param, make = cepheus
    built = []
    monkeypatch.setattr(_determined, "noise_gram", lambda *a, _f=_determined.noise_gram, **k:
                        (built.append("noise"), _f(*a, **k), built.remove("noise"))[1])  # fmt: skip

    def counted(name, build):
        def call(self, *a, **k):
            if "noise" not in built:
                built.append(name)
            return build(self, *a, **k)

        return call

    for name in ("phi", "linearized"):
        monkeypatch.setattr(Equations, name, counted(name, getattr(Equations, name)))
    ml = identify(param, add_noise(make(201), angle=1e-3, rate=1e-3, seed=1), H, estimator="ml",
                  noise=Noise(1e-3, 1e-3, 1e-3))  # fmt: skip
    assert ml.diagnostics.estimator_info["converged"] and built == ["phi"]


def test_ml_on_threads_equals_serial(cepheus, monkeypatch):
    """The evaluations' parts and the whitened Gram matrix's blocks on two threads or one: the same
    estimate and covariance, bit for bit (the parts' sums are added in order)."""
    from spaceid.estimation import _linalg as linalg

    param, make = cepheus
    log, noise = add_noise(make(2501), angle=1e-3, rate=1e-3, seed=2), Noise(1e-3, 1e-3, 1e-3)
    results = []
    for threads in (1, 2):
        monkeypatch.setattr(linalg, "threads_for", lambda tasks, threads=threads: min(tasks, threads))
        results.append(identify(param, log, H, estimator="ml", noise=noise))
    assert np.array_equal(results[0].values, results[1].values) and np.array_equal(results[0].cov, results[1].cov)


def test_ml_preconditioned_in_single_precision_reaches_the_same_fixed_point(cepheus, monkeypatch):
    """With the preconditioners' Gram matrices formed in single precision (as from ``SINGLE_COLUMNS`` unknowns, here
    from one, at 1 % noise where ML iterates most): the same fixed point to within a tenth of the fit's tolerance, the
    covariance (formed in double) to 1e-6 (measured: 5e-7 standard errors and 1.7e-8, in 5 iterations as in double),
    bit for bit on two threads or one; above ``SINGLE_COND`` the first preconditioner is formed again in double, the
    second in double only, and the result is the double one's bit for bit."""
    from spaceid.estimation import _estimators as estimate
    from spaceid.estimation import _linalg as linalg

    param, make = cepheus
    log, noise = add_noise(make(501), angle=1e-2, rate=1e-2, seed=3), Noise(1e-2, 1e-2, 1e-2)
    double = identify(param, log, H, estimator="ml", noise=noise)
    formed, gram = [], estimate._whitened_gram
    monkeypatch.setattr(estimate, "_whitened_gram", lambda L, phi, single=False: formed.append(single) or
                        gram(L, phi, single))  # fmt: skip
    monkeypatch.setattr(estimate, "SINGLE_COLUMNS", 1)
    single = []
    for threads in (1, 2):
        monkeypatch.setattr(linalg, "threads_for", lambda tasks, threads=threads: min(tasks, threads))
        single.append(identify(param, log, H, estimator="ml", noise=noise))
    assert formed == [True, True, False] * 2  # two preconditioners, then the covariance's factor
    assert np.array_equal(single[0].values, single[1].values) and np.array_equal(single[0].cov, single[1].cov)
    assert single[0].diagnostics.estimator_info["converged"]
    assert (np.abs(single[0].values - double.values) / double.std).max() < 1e-5
    assert np.allclose(single[0].cov, double.cov, rtol=1e-6, atol=0)
    formed.clear()
    monkeypatch.setattr(estimate, "SINGLE_COND", 1.0)
    again = identify(param, log, H, estimator="ml", noise=noise)
    assert formed == [True, False, False, False]  # refused once, the second is formed in double straight away
    assert np.array_equal(again.values, double.values) and np.array_equal(again.cov, double.cov)


def test_equation_error_without_the_regressor(cepheus):
    """``Equations.error`` (the signal Jacobian's rate columns times the rates) is ``Phi(x) [theta; 1]``,
    planar and spatial, with a known or an estimated momentum, a known parameter and drift columns."""
    from spaceid.estimation._equations import _equations

    spatial = minimal_parameters(random_tree(np.random.default_rng(4), [0, 1, 1], planar=False))
    for param in (cepheus[0], spatial):
        rng = np.random.default_rng(5)
        n, nj = 40, len(param.model.joints)
        q, qd = rng.uniform(-2, 2, (n, nj)), rng.uniform(-1, 1, (n, nj))
        h = np.array([0.3, -0.2, 0.5])
        w = base_rate(param, param.true_values, q, qd, h) + 0.01
        log = spaceid.data.Log(np.arange(n) * 0.01, param.model.joints, q, qd, np.tile([0.8, 0.6, 0, 0], (n, 1)), w,
                               param.model.planar)  # fmt: skip
        for momentum, known, drift in ((h, None, ()), (None, {param.names[0]: 0.5}, ("torque", "viscous"))):
            eq, _ = _equations(param, log, momentum, known, "log", drift)
            x = eq.signals(log) + 1e-3 * rng.standard_normal((n, len(eq.signals(log)[0])))
            theta = rng.standard_normal(eq.p)
            expected = eq.phi(x) @ np.append(theta, 1.0)
            error = eq.error(x, theta, eq.jacobian(x, theta))
            assert np.abs(error - expected).max() <= 1e-13 * np.abs(expected).max()


def test_chi2_far_from_one_warns_and_the_covariance_follows_the_residuals(cepheus):
    """Noise levels given 100 times too small: chi2_dof ~ 1e4 is reported with a warning that
    says what it means, and the standard errors are those of the residuals (close to the ones
    with the right levels), not 100 times too small."""
    param, make = cepheus
    log = add_noise(make(201), angle=1e-3, rate=1e-3, seed=2)
    right = identify(param, log, H, estimator="wls", noise=Noise(1e-3, 1e-3, 1e-3))
    with pytest.warns(UserWarning, match=r"chi2_dof = .*contradict the noise model: the noise levels are too small.*"
                                         r"unmodelled drift.*one-tick differences"):  # fmt: skip
        wrong = identify(param, log, H, estimator="wls", noise=Noise(1e-5, 1e-5, 1e-5))
    assert wrong.diagnostics.chi2_dof > 1e3 and wrong.diagnostics.covariance_from_residuals
    assert "sandwich of the residuals" in wrong.diagnostics.covariance
    assert wrong.diagnostics.noise_model_warning.startswith("chi2_dof")
    assert not right.diagnostics.covariance_from_residuals and right.diagnostics.noise_model_warning == ""
    assert np.all((wrong.std / right.std > 0.6) & (wrong.std / right.std < 1.6)), wrong.std / right.std


def test_autocorrelated_residuals_give_a_newey_west_covariance(cepheus):
    """An unmodelled slow disturbance of the base rate (a drift the white-noise model does not
    describe): the residuals fail the Ljung-Box test and the covariance is Newey-West."""
    param, make = cepheus
    log = add_noise(make(201), angle=1e-4, rate=1e-4, seed=4)
    log = dataclasses.replace(log, base_w=log.base_w + np.outer(2e-3 * np.sin(1.3 * log.t), [0, 0, 1]))
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # chi2_dof far from 1 as well
        ident = identify(param, log, H, estimator="wls", noise=Noise(1e-4, 1e-4, 1e-4))
    checks = ident.diagnostics.residual_checks
    assert checks.ljung_box_p < 1e-3 and checks.lag1_autocorrelation > 0.5
    assert "residuals autocorrelated" in ident.diagnostics.covariance and ident.diagnostics.covariance_from_residuals


def test_crb_equals_brute_force_fisher(cepheus):
    """The KCR bound equals the inverse Fisher information of the explicit model: unknowns pi and
    the true joint signals, observations q, qd and the base rate that momentum conservation gives."""
    param, make = cepheus
    log = make(12)
    noise = Noise(2e-4, 5e-4, 3e-4)
    _, crb = cramer_rao(param, log, H, noise)
    k, n, nj = param.n_params, log.n_samples, 2

    def observe(z):
        pi, q, qd = z[:k], z[k : k + n * nj].reshape(n, nj), z[k + n * nj :].reshape(n, nj)
        w = base_rate(param, pi, q, qd, H)[:, 2]
        return np.concatenate([q.ravel(), qd.ravel(), w])

    z0 = np.concatenate([param.true_values, log.q.ravel(), log.qd.ravel()])
    step = 1e-6 * np.maximum(np.abs(z0), 1e-3)
    jac = np.column_stack([(observe(z0 + e) - observe(z0 - e)) / (2 * s) for e, s in zip(np.diag(step), step)])
    weights = np.concatenate([np.full(n * nj, noise.angle), np.full(n * nj, noise.rate), np.full(n, noise.base_rate)]) ** -2
    brute = np.linalg.inv(jac.T @ (weights[:, None] * jac))[:k, :k]
    assert np.sqrt(np.diag(crb)) == pytest.approx(np.sqrt(np.diag(brute)), rel=1e-5)
    assert crb == pytest.approx(brute, rel=1e-4, abs=1e-6 * np.abs(brute).max())


@pytest.mark.parametrize("momentum", [np.zeros(3), None])
def test_homogeneous_problem_needs_an_anchor(cepheus, momentum):
    param, make = cepheus
    with pytest.raises(SpaceidError, match="homogeneous.*`known` NAME=VALUE"):
        identify(param, make(51), momentum)


def test_unknown_momentum_with_a_known_parameter(cepheus):
    param, make = cepheus
    ident = identify(param, make(101), None, known={"pi5": param.true_values[4]})
    assert np.abs(ident.values / param.true_values - 1).max() < 1e-8
    assert ident.momentum == pytest.approx(H, abs=1e-9)
    assert ident.std[4] == 0 and ident.settings["momentum_estimated"]
    assert ident.settings["anchors"][0]["source"] == "given"


def test_reaction_wheel_spin_momentum_anchors_zero_momentum(cepheus_rw):
    param, log = cepheus_rw
    ident = identify(param, log, np.zeros(3))
    assert np.abs(ident.values / param.true_values - 1).max() < 1e-8
    (anchor,) = ident.settings["anchors"]
    assert anchor["definition"] == "Iczz_wheel" and "reaction wheel" in anchor["source"]
    # the wheel inertia given by its physical name overrides the model's: the scale follows it
    scaled = identify(param, log, np.zeros(3), known={"Iczz_wheel": 2 * anchor["value"]})
    assert scaled.values == pytest.approx(2 * param.true_values, rel=1e-8)


def test_anchor_naming_an_unknown_parameter(cepheus_rw):
    param, log = cepheus_rw
    with pytest.raises(SpaceidError, match="`known` m_base: not a minimal parameter.*Iczz_wheel"):
        identify(param, log, np.zeros(3), known={"m_base": 9.0})


def test_tls_is_consistent_under_its_own_assumptions():
    """Independent, equal (after scaling) errors in the regressor columns: TLS removes the
    attenuation bias of OLS. (The momentum equations do not meet these assumptions.)"""
    from spaceid.estimation import _estimators as estimate

    rng = np.random.default_rng(0)
    a0 = rng.normal(size=(3000, 4))
    theta = rng.normal(size=4)
    d = np.array([0.3, 0.1, 0.5, 0.2])

    class Stub:
        def phi(self, x):
            return np.concatenate([self.a[:, None, :], -(a0 @ theta)[:, None, None]], -1)

    stub = Stub()
    original = estimate._column_noise
    estimate._column_noise = lambda *args: np.append(d, 0.0)
    try:
        errors = []
        for _ in range(40):
            stub.a = a0 + rng.normal(size=a0.shape) * d
            errors.append(estimate._tls(stub, None, None, None, estimate._FitContext(stub.phi(None)))[0] - theta)
    finally:
        estimate._column_noise = original
    errors = np.array(errors)
    assert np.abs(errors.mean(0) / (errors.std(0) / np.sqrt(len(errors)))).max() < 4.5


@pytest.mark.slow
def test_standard_errors_stay_honest_with_differentiated_rates(cepheus):
    """Angles only at 100 Hz, rates from a Savitzky-Golay window: the errors are correlated over
    the window and the white-noise covariance would understate them ~4 times; the Newey-West
    covariance keeps the predicted standard errors near the actual spread (30 draws: the band
    allows for the few effective samples per window)."""
    from spaceid.data import differentiate_log

    param, _ = cepheus
    log = simulate(param, param.true_values, paper_motion, np.arange(0, 5.0001, 0.01), H)
    runs = [identify(param, differentiate_log(add_noise(log, angle=1e-4, seed=s), window=101, order=5), H)
            for s in range(30)]  # fmt: skip
    assert "Newey-West" in runs[0].diagnostics.covariance
    error = np.array([r.values for r in runs]) - param.true_values
    ratio = np.mean([r.std for r in runs], axis=0) / np.sqrt(np.mean(error**2, axis=0))
    assert np.all((ratio > 0.55) & (ratio < 1.6)), ratio


def test_cli_offers_exactly_the_estimators():
    from spaceid.cli import app

    choices = next(p.type.choices for p in app.commands["identify"].params if p.name == "estimator")
    assert tuple(choices) == ESTIMATORS


def test_wrong_sign_of_the_momentum_warns_of_negative_inertias(cepheus):
    """Planar: the momentum negated negates every parameter; the inertia-like ones (led by Izz)
    are named, with the likely cause, and the warning is recorded in the result."""
    param, make = cepheus
    with pytest.warns(UserWarning, match=r"physically impossible .*pi5 = .*Izz_base.*pi7.*pi8.*wrong sign of the momentum"):
        ident = identify(param, make(101), -H, estimator="ols")
    assert np.allclose(ident.values, -param.true_values)
    assert "pi5" in ident.diagnostics.plausibility and "pi1 " not in ident.diagnostics.plausibility


def test_wrong_sign_of_the_momentum_warns_spatial():
    model = random_tree(np.random.default_rng(7), [0, 1], planar=False)
    param = minimal_parameters(model)

    def motion(t):
        t = np.asarray(t)[:, None]
        w = np.array([1.1, 1.7])
        return np.sin(w * t + 0.3) + 0.3 * np.sin(2.9 * w * t), w * np.cos(w * t + 0.3) + 0.87 * w * np.cos(2.9 * w * t)

    h = np.array([0.3, -0.2, 0.5])
    log = simulate(param, param.true_values, motion, np.linspace(0, 5, 60), h, initial_quat=[0.8, 0.6, 0, 0])
    with pytest.warns(UserWarning, match=r"physically impossible .*\(leads with Ixx_base\).*every one of them negative"):
        identify(param, log, -h, estimator="ols")
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        ident = identify(param, log, h, estimator="ols")
    assert ident.diagnostics.plausibility == "no inertia-like parameter negative"


@pytest.mark.parametrize("estimator", RATE_BASED)
def test_correct_identification_gives_no_plausibility_warning(cepheus, estimator):
    param, make = cepheus
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        ident = identify(param, add_noise(make(101), angle=1e-3, rate=1e-3, seed=1), H, estimator=estimator)
    assert ident.diagnostics.plausibility == "no inertia-like parameter negative"


@pytest.mark.parametrize("bandwidth", [0, 1, 5, 12])
def test_newey_west_from_window_sums_equals_the_lagged_products(bandwidth):
    """The Bartlett-weighted covariance as one Gram matrix of window sums equals the sum of the lagged
    products it replaces, in one chunk or streamed in chunks shorter than the bandwidth."""
    from spaceid.estimation._uncertainty import _hac

    rng = np.random.default_rng(bandwidth)
    x = np.cumsum(rng.standard_normal((300, 4)), 0) * 0.1 + rng.standard_normal((300, 4))  # correlated scores
    lagged = x.T @ x
    for lag in range(1, bandwidth + 1):
        c = x[lag:].T @ x[:-lag]
        lagged += (1 - lag / (bandwidth + 1)) * (c + c.T)
    b = bandwidth / len(x)
    expected = lagged * len(x) / (len(x) - 4) / (1 - b + b * b / 3)
    for parts in ([x], [x[:7], x[7:8], x[8:150], x[150:]]):
        assert np.abs(_hac(iter(parts), bandwidth, 4) - expected).max() <= 1e-13 * np.abs(expected).max()


@pytest.mark.parametrize("estimator", ["ols", "ml"])
def test_no_negative_variance_on_a_noise_free_log_at_condition_1e9(estimator):
    """The satellite preset on a random motion (scaled condition number 1e9), noise-free: the covariance
    from the residuals' scores (Newey-West for ``ols``, White for ``ml``) has no negative variance and
    every standard error is a number, without a warning (the sandwich as products gave 26 and 76 NaN
    standard errors and 'invalid value encountered in sqrt', its bread at condition number 1e18)."""
    from spaceid.motion import FourierTrajectory

    model = spaceid.load_model("satellite-7dof")
    param = minimal_parameters(model)
    a, b = 0.05 * np.random.default_rng(123).standard_normal((2, model.n_joints, 5))
    h = [1.0, -2.0, 3.0]
    log = simulate(param, param.true_values, FourierTrajectory(model.joints, 20.0, a, b), np.arange(2001) / 100, h)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        ident = identify(param, log, h, estimator=estimator)
    assert ident.diagnostics.condition_number_scaled > 1e8 and "residuals" in ident.diagnostics.covariance
    assert np.all(np.isfinite(ident.std)) and np.all(np.diag(ident.cov) >= 0)
    assert not [w for w in caught if issubclass(w.category, RuntimeWarning)]


def test_mapped_sandwich_is_the_product():
    """``bread Omega bread^T`` as a Gram matrix equals the product where that is accurate (a rank-deficient
    ``Omega`` too); that it has no negative variance where the product has: the satellite test above."""
    from spaceid.estimation._uncertainty import _mapped_psd

    rng = np.random.default_rng(5)
    scores = rng.standard_normal((40, 6)) @ np.diag([1e3, 1, 1, 1e-2, 1, 5])
    scores[:, 2] = scores[:, 0] - scores[:, 1]
    omega, bread = scores.T @ scores, rng.standard_normal((6, 6))
    want = bread @ omega @ bread.T
    assert np.abs(_mapped_psd(bread, omega) - want).max() <= 1e-10 * np.abs(want).max()


@pytest.mark.parametrize("seed", [0, 1])
def test_one_negative_inertia_among_hundreds_is_chance_not_a_wrong_model(seed, tmp_path):
    """The impossible-parameter warning tests every inertia-like parameter at once (family-wise
    1 %): on a robot of many parameters one at -2.5 standard errors is chance (a servicer's fit
    named one at -2.3 and blamed the momentum's sign), one at -6 is not; ML's choice of WLS still
    compares each parameter at 2 standard errors."""
    from random_robots import random_robot
    from spaceid.estimation._identify import FALLBACK_Z, _implausible, _leading_parameters

    param = minimal_parameters(random_robot(seed, planar=False, max_arms=2, max_joints=3).load(tmp_path))
    lead = _leading_parameters(param)
    like = [i for i, name in enumerate(lead) if name.split("_")[0] in {"m", "Ixx", "Iyy", "Izz"} and "*" not in name
            and param.true_values[i] > 0]  # fmt: skip
    std = np.abs(param.true_values) + 1.0
    k = like[len(like) // 2]
    for z, named in ((2.5, False), (6.0, True)):
        pi = param.true_values.copy()
        pi[k] = -z * std[k]
        said = _implausible(param, pi, std, "log")
        assert bool(said) == named and (not named or param.names[k] in said), (z, said)
        assert param.names[k] in _implausible(param, pi, std, "log", z=FALLBACK_Z)


@pytest.mark.parametrize("times, check", [(5, "EARLY_CHECK"), (0.5, "STALL_CHECK")])
def test_ml_asks_whether_it_stalled_once_early_only_while_its_objective_still_falls_fast(times, check):
    """A fit that does not converge asks ``stalled`` once: after ``EARLY_CHECK`` iterations when its objective still
    fell by more than ``EARLY_FALL`` in the last, else after ``STALL_CHECK``; it stops when given a reason, and
    reports that many iterations."""
    from spaceid.estimation import _estimators as estimate

    p, objective, asked = 2, [100.0], []
    fall, asked_after = times * estimate.EARLY_FALL, getattr(estimate, check)

    def evaluate(theta, previous, gradient):  # an objective that falls by `fall` an evaluation, never converging
        objective.append(objective[-1] * (1 - fall))
        return {"f": objective[-1], "grad": -np.ones(p), "L": None, "xh": None, "r": None, "J": None}

    def stalled(theta):
        asked.append(len(objective))
        return "a reason"

    factor = lambda L, single=False: (np.ones(p), np.eye(p + 1))  # noqa: E731
    theta, info = estimate._ml_fit(np.zeros((3, 1)), np.zeros(p), evaluate, factor, lambda: np.zeros(p),
                                   stalled=stalled)
    assert len(asked) == 1 and info["iterations"] == asked_after and not info["converged"]
    assert f"had not converged after {asked_after} iterations, and a reason" in info["fallback"]
