"""Momentum that is not conserved: drift terms (external torque, base friction) simulated,
identified with the parameters, recorded, re-simulated; the residual test for an unmodelled drift."""

import json
import warnings
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st
from random_robots import random_robot
from robot_tally import robots, stage
from test_simulate_estimate import H as H_SIMULATE
from test_simulate_estimate import motion

import spaceid
from spaceid.cli import main
from spaceid.dynamics import angular_momentum, base_rate, minimal_parameters
from spaceid.estimation import DriftTest, Identification, Noise, cramer_rao, identify, load_result
from spaceid.motion import FourierTrajectory, add_noise, sample_times, simulate
from spaceid.studies import validate

PRESETS = Path(spaceid.__file__).parent / "models" / "presets"
H = np.array([0.0, 0.0, 0.02])  # small: the arm reverses the base, so a Coulomb torque changes sign
DRIFT = {"torque": 1e-3, "viscous": 5e-3, "coulomb": 2e-3}
TIMES = np.linspace(0, 5, 2001)


@pytest.fixture(scope="module")
def cepheus():
    return minimal_parameters(spaceid.load_model("cepheus"))


def drifting(param, kinds, times=None):
    """A Cepheus log under the drift terms ``kinds``; by default 400 Hz with Coulomb friction (its
    sign changes are integrated to fourth order in the sample spacing), else 100 Hz (exact)."""
    times = (TIMES if "coulomb" in kinds else TIMES[::4]) if times is None else times
    return simulate(param, param.true_values, motion, times, H, model=param.model,
                    drift={k: DRIFT[k] for k in kinds})


def values(ident):
    return {d["name"]: d["value"] for d in ident.drift}


SUBSETS = [("torque",), ("viscous",), ("coulomb",), ("torque", "viscous"), ("viscous", "coulomb"),
           ("torque", "viscous", "coulomb")]
# the fast subset recovers all three kinds at once; each kind alone and the pairs run in the full suite
FAST_SUBSETS = [kinds if len(kinds) == 3 else pytest.param(kinds, marks=pytest.mark.slow) for kinds in SUBSETS]


@pytest.mark.parametrize("kinds", FAST_SUBSETS)
def test_planar_noise_free_recovers_pi_and_drift(cepheus, kinds):
    log = drifting(cepheus, kinds)
    if "coulomb" in kinds:
        assert np.count_nonzero(np.diff(np.sign(log.base_w[:, 2]))) >= 2  # the friction changes sign
    for momentum, known in [(H, None), (None, {"pi1": cepheus.true_values[0]})]:
        ident = identify(cepheus, log, momentum, drift=kinds, known=known, estimator="ols")
        np.testing.assert_allclose(ident.values, cepheus.true_values, rtol=1e-8)
        expected = {"torque_z" if k == "torque" else k: DRIFT[k] for k in kinds}
        assert values(ident).keys() == expected.keys()
        for name, v in values(ident).items():
            assert v == pytest.approx(expected[name], rel=1e-8)
        np.testing.assert_allclose(ident.momentum, H, atol=1e-10)
        assert ident.diagnostics.drift_test == DriftTest(False, f"drift terms modelled: {', '.join(kinds)}")


def test_simulated_momentum_balances_the_external_torque(cepheus):
    kinds = ("torque", "viscous")
    log = drifting(cepheus, kinds)
    assert log.meta["momentum_balance_error"] < 1e-12 and log.meta["momentum_rel_error"] < 1e-12
    # independent of pi and of the identification's quadrature: the rigid-body momentum of the
    # output against h0 + tau (t - t0) - c (yaw - yaw0)
    h = angular_momentum(cepheus.model, log.q, log.qd, log.base_w, log.base_quat)[:, 2]
    external = DRIFT["torque"] * (log.t - log.t[0]) - DRIFT["viscous"] * (log.base_yaw - log.base_yaw[0])
    np.testing.assert_allclose(h - H[2], external, atol=1e-12)
    assert log.meta["momentum_end"][2] - H[2] == pytest.approx(external[-1], abs=1e-12)
    # with Coulomb friction the balance holds to the quadrature of the sign changes
    assert drifting(cepheus, ("coulomb",)).meta["momentum_balance_error"] < 1e-9


@pytest.mark.parametrize("drift", [{"torque": 1e-3, "viscous": 5e-3}, {"viscous": 5e-3, "coulomb": 2e-3}])
def test_drifting_simulation_in_blocks_of_samples(cepheus, drift, monkeypatch):
    """A long log is integrated a block of samples at a time, each from the state the last ended with (the memory
    stays bounded): in blocks of 16 samples, as in one (the quadrature; with a Coulomb torque, DOP853)."""
    from spaceid.motion import _simulate

    whole = simulate(cepheus, cepheus.true_values, motion, TIMES[::8], H, drift=drift)
    monkeypatch.setattr(_simulate, "BLOCK_SAMPLES", 16)
    blocks = simulate(cepheus, cepheus.true_values, motion, TIMES[::8], H, drift=drift)
    np.testing.assert_allclose(blocks.base_w, whole.base_w, rtol=0, atol=1e-10 * np.abs(whole.base_w).max())
    np.testing.assert_allclose(blocks.base_yaw, whole.base_yaw, rtol=0, atol=1e-10)


def _random_flight(seed, planar, folder, smallest=-1.3):
    """A random robot of at most two arms of two joints (in ``folder``), its minimal set, the seeded generator and
    a random 10 s motion of three harmonics, amplitudes 10^(``smallest`` .. -0.3) rad."""
    model = random_robot(seed, planar=planar, max_arms=2, max_joints=2).load(folder)
    param, rng = minimal_parameters(model), np.random.default_rng(seed)
    a, b = 10 ** rng.uniform(smallest, -0.3) * rng.standard_normal((2, model.n_joints, 3))
    return model, param, rng, FourierTrajectory(model.joints, 10.0, a, b)


@pytest.mark.slow  # 4 to 8 s: its reference restarts DOP853 at every sign change
@robots(4)
@given(seed=st.integers(0, 2**31 - 1), coulomb=st.floats(1e-4, 0.02), viscous=st.sampled_from([0.0, 0.01]))
def test_coulomb_friction_against_an_ode_solver_on_random_robots(seed, coulomb, viscous, tmp_path):
    """A random planar robot whose base turns back and forth under Coulomb friction ``-mu sign(w)`` (and viscous),
    on a motion nobody designed, against DOP853 on ``[yaw, h]`` with the base rate solved from the momentum at every
    evaluation and the torque's sign flipped at each zero crossing (events): the quadrature segment by segment,
    its crossings located by root finding. Where it reports stiction, the friction can indeed hold the base: the
    torque that keeps the base rate at zero, the joints' own momentum's rate (the rigid-body momentum at a base at
    rest, differenced), is within mu."""
    from scipy.integrate import solve_ivp

    model, param, rng, trajectory = _random_flight(seed, True, tmp_path, smallest=-1.0)
    pi, times = param.true_values, sample_times(10.0, 201)
    h0 = np.array([0.0, 0.0, rng.uniform(-0.02, 0.02)])  # small: the arms turn the base back
    drift = {"coulomb": coulomb, "viscous": viscous}

    def rate(t, h):
        q, qd, _ = trajectory.evaluate(np.atleast_1d(t))
        return base_rate(param, pi, q, qd, np.array([0.0, 0.0, h]))[0, 2]

    def own(t):  # the joints' own momentum about z, the base at rest (rigid-body definitions)
        q, qd, _ = trajectory.evaluate(np.atleast_1d(t))
        return angular_momentum(model, q, qd, np.zeros((1, 3)))[0, 2]

    with stage("simulate coulomb", seed=seed, coulomb=coulomb, viscous=viscous):
        try:
            log = simulate(param, pi, trajectory, times, h0, drift=drift)
        except spaceid.SpaceidError as exc:
            assert "stiction" in str(exc)
            t_stuck, dt = float(str(exc).split("at t = ")[1].split(" s")[0]), 1e-5
            assert abs((own(t_stuck + dt) - own(t_stuck - dt)) / (2 * dt)) <= coulomb * (1 + 1e-3)
            return
        t0, y, s, ys, ts = 0.0, np.array([0.0, h0[2]]), np.sign(rate(0.0, h0[2])), [], []
        while t0 < 10.0:
            def crossed(t, y, s=s):
                return s * rate(t, y[1])
            crossed.terminal, crossed.direction = True, -1
            ref = solve_ivp(lambda t, y, s=s: [rate(t, y[1]), -viscous * rate(t, y[1]) - coulomb * s], (t0, 10.0), y,
                            method="DOP853", t_eval=times[times > t0] if ys else times, rtol=1e-12, atol=1e-14,
                            events=crossed)
            ys.append(ref.y.T), ts.append(ref.t)
            if ref.status != 1:
                break
            t0, y, s = ref.t_events[0][0], ref.y_events[0][0], -s
        ref_y, ref_t = np.concatenate(ys), np.concatenate(ts)
        np.testing.assert_array_equal(ref_t, times)
        assert np.count_nonzero(np.diff(np.sign(log.base_w[:, 2]))) == len(ys) - 1  # the same crossings
        scale = np.abs(log.base_w[:, 2]).max()
        w = np.array([rate(t, h) for t, h in zip(times, ref_y[:, 1])])
        np.testing.assert_allclose(log.base_w[:, 2], w, rtol=0, atol=1e-8 * scale)
        np.testing.assert_allclose(log.base_yaw, ref_y[:, 0], rtol=0, atol=1e-8 * max(10.0 * scale, 1.0))


def test_drift_free_simulation_is_unchanged(cepheus):
    t = np.linspace(0, 5, 35)
    a = simulate(cepheus, cepheus.true_values, motion, t, H)
    b = simulate(cepheus, cepheus.true_values, motion, t, H, drift={"viscous": 0.0})
    assert np.array_equal(a.base_quat, b.base_quat) and np.array_equal(a.base_w, b.base_w) and a.meta == b.meta


def test_coulomb_stiction_is_an_error(cepheus):
    with pytest.raises(spaceid.SpaceidError, match="stiction"):
        simulate(cepheus, cepheus.true_values, motion, TIMES, H, drift={"coulomb": 1.0})


@robots(4, fast=1)
@given(seed=st.integers(0, 2**31 - 1), planar=st.booleans(), viscous=st.sampled_from([1e-4, 0.5, -0.05]),
       torque=st.floats(-0.01, 0.01), coulomb=st.sampled_from([0.0, 0.003]))
def test_smooth_drift_against_an_ode_solver_on_random_robots(seed, planar, viscous, torque, coulomb, tmp_path):
    """The base motion of a random robot under a torque and viscous friction (weak; strong, the momentum changing
    many-fold over the motion; negative, as an estimate may be), spatial with Coulomb friction too (smooth while the
    base turns), on a motion nobody designed, against DOP853 on the same equations with the base rate solved from
    the momentum at every evaluation (no interpolated joint motion, no quadrature, no collocation): planar, the
    momentum's linear equation as a quadrature; spatial, the attitude's collocation carrying the momentum."""
    from scipy.integrate import solve_ivp

    from spaceid.data import quat_to_matrix
    from spaceid.studies import attitude_error_angle

    model, param, rng, trajectory = _random_flight(seed, planar, tmp_path)
    pi, times = param.true_values, sample_times(10.0, 101)
    h0 = np.array([0.0, 0.0, rng.uniform(-0.5, 0.5)]) if planar else rng.uniform(-0.5, 0.5, 3)
    tau = np.array([0.0, 0.0, torque]) if planar else torque * rng.standard_normal(3)
    quat0 = np.array([1.0, 0.0, 0.0, 0.0]) if planar else rng.standard_normal(4) / 2
    quat0 /= np.linalg.norm(quat0)
    coulomb = 0.0 if planar else coulomb  # (planar: sign changes, test_coulomb_friction_against_an_ode_solver)
    with stage("simulate smooth drift", seed=seed, planar=planar, viscous=viscous, torque=torque, coulomb=coulomb):
        log = simulate(param, pi, trajectory, times, h0, initial_quat=quat0,
                       drift={"torque": tau[2] if planar else tau, "viscous": viscous, "coulomb": coulomb})

        def rate(t, y):  # the base rate in base axes, from the state [quat, inertial momentum]
            q, qd, _ = trajectory.evaluate(np.atleast_1d(t))
            rot = quat_to_matrix(y[:4] / np.linalg.norm(y[:4]))
            return rot, base_rate(param, pi, q, qd, rot.T @ y[4:])[0]

        def rhs(t, y):
            rot, w = rate(t, y)
            if planar:
                w[:2] = 0.0
            p = y[:4]
            turn = 0.5 * np.array([-p[1:] @ w, *(p[0] * w + np.cross(p[1:], w))])
            wi = rot @ w
            return np.concatenate([turn, tau - viscous * wi - coulomb * wi / np.linalg.norm(wi)])

        ref = solve_ivp(rhs, (0.0, 10.0), np.r_[quat0, h0], method="DOP853", t_eval=times, rtol=1e-12, atol=1e-13)
        w = np.array([rate(t, y)[1] for t, y in zip(times, ref.y.T)])
        scale = np.abs(w).max()
        np.testing.assert_allclose(log.base_w, w * ([0, 0, 1] if planar else 1), rtol=0, atol=1e-9 * scale)
        turned = attitude_error_angle(log.base_quat, ref.y[:4].T / np.linalg.norm(ref.y[:4], axis=0)[:, None])
        assert turned.max() <= 1e-9 * max(10.0 * scale, 1.0)
        momentum = np.abs(ref.y[4:]).max()
        np.testing.assert_allclose(log.meta["momentum_end"], ref.y[4:, -1], rtol=0, atol=1e-9 * momentum)


@pytest.fixture(scope="module")
def spatial_log():
    model = spaceid.load_model(PRESETS / "satellite-7dof.urdf")
    param = minimal_parameters(model)
    rng = np.random.default_rng(0)
    traj = FourierTrajectory(model.joints, 20, rng.uniform(-0.3, 0.3, (model.n_joints, 6)),
                             rng.uniform(-0.3, 0.3, (model.n_joints, 6)))
    quat0 = np.array([0.9, 0.1, 0.3, 0.3]) / np.linalg.norm([0.9, 0.1, 0.3, 0.3])
    drift = {"torque": [1e-3, -2e-3, 5e-4], "viscous": 0.05, "coulomb": 3e-3}
    h0 = np.array([1.0, -2.0, 3.0])
    log = simulate(param, param.true_values, lambda t: traj.evaluate(t)[:2], np.linspace(0, 20, 2001), h0,
                   initial_quat=quat0, model=model, drift=drift)
    return param, log, h0, drift


@pytest.mark.parametrize("n", [1, 2, 3, 7, 8, 40])
def test_sample_integral_is_exact_for_polynomials_of_its_degree(n):
    """Each interval is integrated through eight samples (all of a shorter log): exact to round-off for a
    polynomial of degree 7 (of n - 1 on n < 8 samples: the trapezoid rule on two) on uneven times."""
    from spaceid.estimation._drift import _sample_integral

    rng = np.random.default_rng(n)
    t = np.sort(rng.uniform(0.0, 3.0, n)) + np.arange(n) * 0.05
    degree = min(n, 8) - 1
    c = rng.standard_normal((degree + 1, 2))
    powers = np.arange(degree + 1)
    f, F = t[:, None] ** powers @ c, t[:, None] ** (powers + 1) / (powers + 1) @ c
    assert np.allclose(_sample_integral(t, f), F - F[0], rtol=0, atol=1e-11 * np.abs(F).max())
    if n >= 8:  # one degree more is not exact: the test can fail
        assert not np.allclose(_sample_integral(t, t[:, None] ** 8), (t[:, None] ** 9 - t[0] ** 9) / 9, rtol=1e-9)


def test_sample_integral_converges_at_eighth_order():
    """Halving the spacing divides the error on a smooth signal by about 2^8 (a sixth-order rule: 2^6)."""
    from spaceid.estimation._drift import _sample_integral

    errors = []
    for rate in (4.0, 8.0):
        t = np.arange(0.0, 10.0, 1 / rate)
        f = np.sin(1.3 * t + 0.2)[:, None]
        exact = (np.cos(0.2) - np.cos(1.3 * t + 0.2)) / 1.3
        errors.append(np.abs(_sample_integral(t, f)[:, 0] - exact).max())
    assert errors[0] / errors[1] > 2**8


@pytest.mark.slow
def test_spatial_noise_free_recovers_pi_and_drift(spatial_log):
    param, log, h0, drift = spatial_log
    assert log.meta["momentum_rel_error"] < 1e-12 and log.meta["momentum_balance_error"] < 1e-9
    ident = identify(param, log, h0, drift=tuple(drift), estimator="ols")
    y = param.regressor(log.q, log.qd, log.base_w).reshape(-1, param.n_params)
    err = np.abs(ident.values - param.true_values) * np.linalg.norm(y, axis=0) / (np.linalg.norm(h0) * np.sqrt(len(y)))
    assert err.max() < 1e-8  # as momentum explained (parameters near zero stay meaningful)
    assert np.median(np.abs(ident.values / param.true_values - 1)) < 1e-8
    expected = dict(zip(("torque_x", "torque_y", "torque_z"), drift["torque"]), viscous=drift["viscous"],
                    coulomb=drift["coulomb"])
    for name, v in values(ident).items():
        assert v == pytest.approx(expected[name], rel=1e-8)
    names, _ = cramer_rao(param, log, h0, Noise(1e-4, 1e-4, 1e-4, 1e-4), drift=drift)
    assert names[-5:] == ["torque_x", "torque_y", "torque_z", "viscous", "coulomb"]


@pytest.mark.slow
def test_noisy_drift_coefficients_within_their_predicted_spread(cepheus):
    kinds = ("torque", "viscous", "coulomb")
    clean = drifting(cepheus, kinds, np.linspace(0, 5, 501))
    noise = Noise(angle=1e-4, rate=1e-3, base_rate=1e-3)
    truth = {"torque_z": DRIFT["torque"], "viscous": DRIFT["viscous"], "coulomb": DRIFT["coulomb"]}
    z = []
    for seed in range(20):
        log = add_noise(clean, angle=noise.angle, rate=noise.rate, seed=seed)
        ident = identify(cepheus, log, H, drift=kinds, noise=noise)
        z.append([(d["value"] - truth[d["name"]]) / d["std"] for d in ident.drift])
    z = np.array(z)
    # 20 draws: the sample RMS of a unit normal is within [0.6, 1.45] with probability > 0.99
    assert np.all((0.6 < np.sqrt(np.mean(z**2, 0))) & (np.sqrt(np.mean(z**2, 0)) < 1.45)), z
    assert np.all(np.abs(z.mean(0)) < 3 / np.sqrt(len(z)))
    _, crb = cramer_rao(cepheus, clean, H, noise, drift={k: DRIFT[k] for k in kinds})
    np.testing.assert_allclose(np.sqrt(np.diag(crb))[-3:], [d["std"] for d in ident.drift],
                               rtol=0.2)


@pytest.mark.slow
def test_residual_test_silent_on_clean_logs_and_fires_on_drift(cepheus):
    t = np.linspace(0, 5, 501)
    clean = simulate(cepheus, cepheus.true_values, motion, t, H)
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # any warning fails
        ident = identify(cepheus, clean, H)
        assert ident.diagnostics.drift_test.drift is False
        fired = 0
        for seed in range(20):
            log = add_noise(clean, angle=1e-4, rate=1e-3, seed=seed)
            fired += identify(cepheus, log, H).diagnostics.drift_test.p_value < 1e-3
        assert fired == 0  # at alpha = 1e-3, 20 clean logs fire with probability 2 %
    drift = simulate(cepheus, cepheus.true_values, motion, t, H, drift={"viscous": 5e-4})  # 1 % of h
    with pytest.warns(UserWarning, match="`drift`"):
        ident = identify(cepheus, add_noise(drift, angle=1e-4, rate=1e-3, seed=0), H)
    test = ident.diagnostics.drift_test
    assert test.drift and test.p_value < 1e-3 and test.terms == ("torque_z", "viscous")
    assert test.alpha == 1e-3 and test.durbin_watson < 1.8  # white: 2 +- 0.09


@pytest.mark.parametrize("estimator", ["ols", "ml"])
def test_no_drift_alarm_at_zero_momentum_where_the_allowance_is_not_determined(estimator, tmp_path):
    """Planar random robot 12 released at rest, one parameter anchored, 1e-4 on every signal: one direction the data do
    not determine. The allowance for the regressor noise's pull moves with the estimate's coordinate along it, and the
    drift coefficients came out 24 times the allowance at the estimate (p 4.9e-22 with ``ols``, 4.3e-55 with ``ml``,
    first-order variance shares 0.0087 and 0.0038): the test now says the log cannot decide."""
    from test_random_pipeline import flown_at_rest

    flown, anchor = flown_at_rest(12, True, tmp_path)
    param, log = flown.param, flown.log
    noise = Noise(angle=1e-4, rate=1e-4, base_rate=1e-4, attitude=1e-4)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        ident = identify(param, add_noise(log, angle=1e-4, rate=1e-4, seed=12), np.zeros(3), known=anchor,
                         estimator=estimator, noise=noise)  # fmt: skip
    test = ident.diagnostics.drift_test
    assert ident.diagnostics.undetermined and test.p_value < 1e-3 and test.confounded > 0.9 and not test.drift, test


@pytest.mark.slow
def test_residual_test_decides_at_zero_momentum_where_the_data_determine_the_parameters(cepheus):
    """Cepheus released at rest, the base's mass-like parameter anchored: silent on 10 clean noisy logs and firing on
    a viscous drift (what the allowance's spread leaves to the test where every direction is determined)."""
    t = np.linspace(0, 5, 501)
    anchor = {cepheus.names[0]: float(cepheus.true_values[0])}
    zero = np.zeros(3)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        clean = simulate(cepheus, cepheus.true_values, motion, t, zero)
        tests = [identify(cepheus, add_noise(clean, angle=1e-4, rate=1e-3, seed=s), zero, known=anchor)
                 .diagnostics.drift_test for s in range(10)]  # fmt: skip
        drift = simulate(cepheus, cepheus.true_values, motion, t, zero, drift={"viscous": 5e-3})
        fired = identify(cepheus, add_noise(drift, angle=1e-4, rate=1e-3, seed=0), zero, known=anchor)
    assert not any(test.drift for test in tests) and max(test.confounded for test in tests) < 0.01
    assert fired.diagnostics.drift_test.drift, fired.diagnostics.drift_test


@pytest.mark.slow
def test_residual_test_keeps_its_level_on_short_clean_logs(cepheus):
    """400 clean 35-sample logs (tests/test_simulate_estimate.py's, measured rates, levels estimated):
    each sample's own fit shrinks its residual, which made White's covariance of the plain
    residuals with the chi-square reference fire 6, 16 and 42 times at 1e-3, 0.01 and 0.05
    (0.4, 4 and 20 expected). With the leverage-scaled residuals (HC3) and the F reference: 1, 4, 15
    (on 2,000 such logs 3, 15, 69). The bounds fail with probability below 1 % each at the stated levels."""
    log = simulate(cepheus, cepheus.true_values, motion, np.linspace(0, 5, 35), H_SIMULATE, model=cepheus.model)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        p = np.array([identify(cepheus, add_noise(log, angle=1e-4, rate=1e-4, seed=s), H_SIMULATE)
                      .diagnostics.drift_test.p_value for s in range(400)])  # fmt: skip
    assert np.sum(p < 1e-3) <= 3 and np.sum(p < 1e-2) <= 9 and np.sum(p < 0.05) <= 30, np.sort(p)[:30]


def test_result_round_trip_and_validation_with_the_identified_drift(cepheus, tmp_path):
    kinds = ("torque", "viscous")
    log = drifting(cepheus, kinds, np.linspace(0, 5, 201))
    ident = identify(cepheus, log, H, drift=kinds)
    record = ident.to_dict()
    assert [d["name"] for d in record["drift"]] == ["torque_z", "viscous"]
    assert {d["unit"] for d in record["drift"]} == {"N m", "N m s/rad"}
    (tmp_path / "r.json").write_text(json.dumps(record))
    back = load_result(tmp_path / "r.json")
    assert back.drift == ident.drift and back.drift_terms().keys() == {"torque", "viscous"}
    assert Identification.from_dict({k: v for k, v in record.items() if k != "drift"}).drift == ()
    metrics = validate(back, log).metrics  # the identified drift is used
    assert metrics["base_w_nrms"] < 1e-8
    without = validate(back, log, drift={"torque": 0.0, "viscous": 0.0}).metrics  # override
    assert without["base_w_nrms"] > 1e-3


def test_report_lists_the_drift_terms(cepheus, tmp_path):
    from spaceid.studies import write_markdown_report

    log = drifting(cepheus, ("torque",), np.linspace(0, 5, 201))
    report = write_markdown_report(tmp_path, title="t", result=identify(cepheus, log, H, drift=("torque",)),
                                   settings={}, figures={}).read_text()
    assert "| torque\\_z | N m | 0.001 |" in report


@pytest.mark.slow
def test_cli_drift_through_files(tmp_path, capsys):
    log, result = tmp_path / "log.csv", tmp_path / "r.json"
    assert main(["simulate", "cepheus", "--trajectory", "paper-table2", "--momentum", "0.02", "--rate", "200",
                 "--drift", "torque=1e-3,viscous=5e-3", "-o", str(log)]) == 0
    assert main(["identify", "cepheus", str(log), "--momentum", "0.02", "--drift", "torque,viscous",
                 "--estimator", "ols", "-o", str(result)]) == 0
    printed = capsys.readouterr().out
    assert "drift: torque_z = 0.001" in printed and "drift: viscous = 0.005" in printed
    drift = {d["name"]: d["value"] for d in json.loads(result.read_text())["drift"]}
    assert drift["torque_z"] == pytest.approx(1e-3, rel=1e-6) and drift["viscous"] == pytest.approx(5e-3, rel=1e-6)
    assert main(["validate", str(result), str(log), "--momentum", "0.02", "-o", str(tmp_path / "v")]) == 0
    metrics = json.loads((tmp_path / "v" / "metrics.json").read_text())
    assert metrics["base_w_nrms"] < 1e-5


@pytest.mark.parametrize("args, message", [
    (["identify", "cepheus", "LOG", "--momentum", "0.02", "--drift", "torque,friction"], "--drift: 'friction' is not"),
    (["identify", "cepheus", "LOG", "--momentum", "0.02", "--drift", "viscous=1"], "--drift: 'viscous=1' gives"),
    (["simulate", "cepheus", "--trajectory", "paper-table2", "--momentum", "0.02", "--drift", "viscous=abc"],
     "--drift: 'viscous=abc' is not KIND=VALUE"),
    (["simulate", "cepheus", "--trajectory", "paper-table2", "--momentum", "0.02", "--drift", "viscous=-1"],
     "--drift: viscous = -1 must be >= 0"),
    (["simulate", "cepheus", "--trajectory", "paper-table2", "--momentum", "0.02", "--drift", "spin=1"],
     "--drift: 'spin' is not a drift term"),
    (["experiment", "--drift", "viscous,spin"], "--drift: 'spin' is not a drift kind"),
])
def test_cli_bad_drift_is_one_line_exit_2(tmp_path, capsys, args, message):
    log = tmp_path / "log.csv"
    if "identify" in args:
        assert main(["simulate", "cepheus", "--trajectory", "paper-table2", "--momentum", "0.02", "--samples", "40",
                     "-o", str(log)]) == 0
        capsys.readouterr()
    out = ["--out", str(tmp_path / "out")] if args[0] == "experiment" else ["-o", str(tmp_path / "out")]
    args = [str(log) if a == "LOG" else a for a in args] + out
    assert main(args) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("error: " + message) and "\n" not in err


def test_drift_terms_the_log_cannot_tell_apart(cepheus):
    h = np.array([0.0, 0.0, 0.4934])  # the base turns one way only
    log = simulate(cepheus, cepheus.true_values, motion, np.linspace(0, 5, 501), h, drift={"torque": 1e-3})
    with pytest.raises(spaceid.SpaceidError, match=r"not excited: .*coulomb.*drop one of the drift terms"):
        identify(cepheus, log, h, drift=("torque", "coulomb"))
    with pytest.warns(UserWarning, match="torque_z and viscous are nearly indistinguishable"):
        ident = identify(cepheus, add_noise(log, angle=1e-4, rate=1e-3, seed=0), h, drift=("torque", "viscous"))
    assert ident.diagnostics.drift_correlation > 0.99


@pytest.mark.slow
def test_experiment_with_friction_warns_and_drift_terms_reduce_the_error(tmp_path):
    from spaceid.data import read_bag_log
    from spaceid.twin import TwinSettings

    res = spaceid.run_experiment(seed=0, out=tmp_path, drift=("viscous",))
    assert res.settings["drift terms"] == "viscous" and [d["name"] for d in res.ident.drift] == ["viscous"]
    assert res.ident.settings["history"]["start"] == 0.0
    # seed 0 without drift terms: 36.5 %; with the bearing friction off: 3.7 % (measured)
    assert np.max(np.abs(res.ident.values - res.true) / np.abs(res.true)) < 0.15
    assert "| viscous | N m s/rad |" in (tmp_path / "report.md").read_text()
    # the recorded bag read from rest, identified as 'spaceid identify' would, without --drift
    model = spaceid.load_model("cepheus-rw")
    log = read_bag_log(tmp_path / "run.bag", joints=model.joints, planar=True, wheels=model.wheels,
                       joint_rates="differentiate", pose_latency=TwinSettings().mocap.latency)
    with pytest.warns(UserWarning, match="model it with `drift`"):
        ident = identify(minimal_parameters(model), log, np.zeros(3))
    assert ident.diagnostics.drift_test.p_value < 1e-10


def test_drift_integrated_over_a_history(cepheus):
    kinds = ("torque", "viscous")
    full = drifting(cepheus, kinds, np.linspace(0, 5, 501))
    later = full.select(np.flatnonzero(full.t >= 2.0)[::10])  # a sparse part of the record, after t = 2 s
    ident = identify(cepheus, later, H, drift=kinds, history=full, estimator="ols")
    np.testing.assert_allclose(ident.values, cepheus.true_values, rtol=1e-9)
    assert values(ident)["viscous"] == pytest.approx(DRIFT["viscous"], rel=1e-9)
    h_later = angular_momentum(cepheus.model, later.q[:1], later.qd[:1], later.base_w[:1], later.base_quat[:1])[0]
    np.testing.assert_allclose(ident.momentum, h_later, atol=1e-12)  # the momentum at the log's first sample
    assert ident.settings["history"]["start"] == 0.0 and ident.settings["history"]["momentum"] == H.tolist()
    with pytest.raises(spaceid.SpaceidError, match="does not span the log"):
        identify(cepheus, full, H, drift=kinds, history=later)


def test_sparse_samples_of_a_drift_warn(cepheus):
    with pytest.warns(UserWarning, match="too sparse to integrate the drift"):
        log = drifting(cepheus, ("coulomb",), np.linspace(0, 5, 29))
    assert log.meta["momentum_balance_error"] > 1e-6


@pytest.mark.slow  # fast representative: test_drift_test_from_the_estimates_gram_matrix_equals_the_whole_refit
def test_sketched_leverages_agree_with_the_exact_ones():
    """The drift test's leverages of a fit with more than 256 unknowns come from a 32-column sketch of the
    inverse Gram matrix's root: the leverage-adjusted residuals' adjustment within 45 % of the exact one
    (the sketch's error is about 25 % of each leverage), and exact above LEVERAGE_EXACT."""
    from spaceid.estimation._linalg import _column_scale, _solve_factor, _triangular_factor
    from spaceid.estimation._residuals import _leverage_adjusted, _leverage_root

    rng = np.random.default_rng(0)
    n, rows, c = 6000, 3, 300  # leverages about 0.05 a sample, below LEVERAGE_EXACT
    M = rng.standard_normal((n, rows, c))
    M[:5] *= 20  # a few samples of high leverage: recomputed exactly
    r = rng.standard_normal((n, rows))
    A = M.reshape(-1, c)
    scale = _column_scale(A)
    factor = (scale, _triangular_factor(A, np.zeros(len(A)), scale))
    ginv = _solve_factor(*factor[::-1])[1]
    root = _leverage_root(factor)
    assert not root[1]  # sketched
    exact = _leverage_adjusted(M, (np.linalg.cholesky(ginv), True), ginv, r)  # ginv = B B^T, exactly
    sketched = _leverage_adjusted(M, root, ginv, r)
    # the sketch's error a part of the adjustment itself (measured 0.36; 64 columns: 0.25, 16: 0.50, 8: 0.72)
    assert np.linalg.norm(sketched[5:] - exact[5:]) <= 0.45 * np.linalg.norm(exact[5:] - r[5:])
    assert np.allclose(sketched[:5], exact[:5], rtol=1e-8)



def test_drift_test_given_what_identify_formed_is_the_same_test():
    """``identify`` forms the candidates' basis once (for the noise Gram matrix and the test) and ``ols``'s residuals
    once (for its covariance and the test): given them, the test's record is the one it forms itself, bit for bit,
    and the least-squares solution alone (taken before the inverse Gram matrix) is ``_solve_factor``'s."""
    from conftest import random_states, random_tree

    from spaceid.dynamics import base_rate
    from spaceid.estimation._equations import equation_residuals
    from spaceid.estimation._identify import _prepared
    from spaceid.estimation._linalg import _factor_solution, _solve_factor
    from spaceid.estimation._residuals import candidate_basis, drift_test

    model = random_tree(np.random.default_rng(8), [0, 1, 2], planar=False)
    param = minimal_parameters(model)
    q, qd, _ = random_states(np.random.default_rng(9), model, 300)
    h = np.array([0.3, -0.2, 0.5])
    w = base_rate(param, param.true_values, q, qd, h)
    log = add_noise(spaceid.data.Log(np.arange(len(q)) * 0.01, model.joints, q, qd, np.tile([1.0, 0, 0, 0], (len(q), 1)),
                                     w, False), angle=1e-3, rate=1e-3, seed=3)  # fmt: skip
    prep = _prepared(param, log, h, estimator="ols", known=None, noise=Noise(1e-3, 1e-3, 1e-3), where="log",
                     cond_limit=1e10)  # fmt: skip
    theta = _factor_solution(*prep.factor[::-1])
    np.testing.assert_array_equal(theta, _solve_factor(*prep.factor[::-1])[0])
    args = (prep.eq, prep.x, prep.phi, prep.sigma, theta, "ols", log)
    own = drift_test(*args)
    given = drift_test(*args, basis=candidate_basis(log), residuals=equation_residuals(prep.phi, theta))
    assert own["wald"] > 0 and own == given


def test_leverage_adjustment_is_the_pseudo_inverse_even_where_a_sample_is_fitted_exactly():
    """``(I - H_n)^+ r_n`` for every sample: solved where ``I - H_n`` is well conditioned, by the
    pseudo-inverse where it is (nearly) singular; a sample with a unit leverage (its own unknown) is not
    infinite, and the others agree with the pseudo-inverse formed for all to 1e-12."""
    from spaceid.estimation._residuals import _leverage_adjusted

    rng = np.random.default_rng(1)
    n, rows, c = 40, 3, 12
    M = rng.standard_normal((n, rows, c))
    M[0, :, -1], M[1:, :, -1] = [1.0, 0.0, 0.0], 0.0  # the last unknown in sample 0's first row alone
    A = M.reshape(-1, c)
    ginv = np.linalg.inv(A.T @ A)
    r = rng.standard_normal((n, rows))
    got = _leverage_adjusted(M, (np.linalg.cholesky(ginv), True), ginv, r)
    H = np.einsum("nrp,pq,nsq->nrs", M, ginv, M)
    assert np.linalg.det(np.eye(rows) - H[0]) < 1e-12  # sample 0 fitted exactly along its first row
    want = np.einsum("nrs,ns->nr", np.linalg.pinv(np.eye(rows) - H), r)
    assert np.all(np.isfinite(got)) and np.allclose(got, want, rtol=1e-12, atol=1e-12 * np.abs(want).max())

@pytest.mark.parametrize("estimator", ["ols", "ml"])
def test_drift_test_from_the_estimates_gram_matrix_equals_the_whole_refit(monkeypatch, estimator):
    """``identify`` completes the drift test's refit Gram matrix from the estimate's own factor (ols: the
    excitation check's; ml: its bread's, at its whitener) by the candidate columns alone, and takes ML's
    undetermined directions from that factor: the record agrees with the refit formed whole (Wald, fitted
    drift to 1e-7, as the streamed test's) and the directions with those of the whitened regressor's own
    factor."""
    from conftest import random_states, random_tree
    from spaceid.dynamics import base_rate
    from spaceid.estimation import _identify
    from test_stream import _same_drift_test

    model = random_tree(np.random.default_rng(4), [0, 1, 1], planar=False)
    param = minimal_parameters(model)
    q, qd, _ = random_states(np.random.default_rng(5), model, 600)
    q, qd = 0.05 * q, 0.05 * qd  # small motions: two directions undetermined at this noise (scaled cond 5e4)
    h = np.array([0.3, -0.2, 0.5])
    w = base_rate(param, param.true_values, q, qd, h)
    log = add_noise(spaceid.data.Log(np.arange(len(q)) * 0.01, model.joints, q, qd, np.tile([1.0, 0, 0, 0], (len(q), 1)),
                                     w, False), angle=1e-3, rate=1e-3, seed=3)  # fmt: skip
    noise = Noise(angle=1e-3, rate=1e-3, base_rate=1e-3)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        reused = identify(param, log, h, estimator=estimator, noise=noise)
        monkeypatch.setattr(_identify, "_factor_gram", lambda factor: None)  # the refit's Gram matrix whole
        monkeypatch.setattr(_identify, "_whitened_factor", lambda factor: None)  # the directions' own factor
        whole = identify(param, log, h, estimator=estimator, noise=noise)
    assert reused.diagnostics.drift_test.run and reused.diagnostics.drift_test.to_dict()["wald"] > 0
    _same_drift_test(reused, whole)
    assert len(reused.diagnostics.undetermined) == 2 and [d["parameters"] for d in reused.diagnostics.undetermined] == [
        d["parameters"] for d in whole.diagnostics.undetermined]
    np.testing.assert_allclose([d["noise_to_signal"] for d in reused.diagnostics.undetermined],
                               [d["noise_to_signal"] for d in whole.diagnostics.undetermined], rtol=1e-6)


def test_errors_in_variables_allowance_holds_an_anchors_noise():
    """A drift refit on a regressor whose columns share one noisy signal, one parameter anchored (its column moved
    into ``b`` with its noise): over 300 seeds the drift coefficient's mean is the allowance with the right-hand
    side's noise, ``-[G^-1 N [theta; 0; 1]]_d`` (0.244 and 0.242 when written); without that column the allowance
    was 0.021, a tenth of it."""
    from spaceid.estimation._residuals import _errors_in_variables

    rng = np.random.default_rng(3)
    m, p, sigma, anchor = 1000, 3, 0.2, 4.0
    t = np.linspace(0.0, 1.0, m)
    U = rng.standard_normal((m, p + 1)) + [1.0, 0.5, -1.0, 1.0]  # each column's factor of the signal; anchor's last
    s0 = 1.0 + 0.5 * np.sin(6 * t)
    theta = np.array([1.0, -0.5, 0.8])
    C = 0.3 * U[:, :1] + t[:, None]  # a noise-free candidate, correlated with the columns
    h = (U @ np.append(theta, anchor)) * s0  # exact at the truth
    g = np.hstack([U[:, :p], np.zeros((m, 1)), U[:, -1:] * anchor])  # d[A | C | -b]/ds of each sample
    N = sigma**2 * g.T @ g
    fitted, allowed = [], []
    for seed in range(300):
        A = U * (s0 + sigma * np.random.default_rng(seed).standard_normal(m))[:, None]
        b = h - A[:, -1] * anchor
        estimate = np.linalg.lstsq(A[:, :p], b, rcond=None)[0]
        M = np.hstack([A[:, :p], C])
        fitted.append(np.linalg.lstsq(M, b, rcond=None)[0][p:])
        allowed.append(_errors_in_variables(N, np.linalg.inv(M.T @ M), estimate, p)[0])
    mean, spread = np.mean(fitted, 0), np.std(fitted, 0) / np.sqrt(len(fitted))
    assert np.all(np.abs(mean) > 20 * spread)
    np.testing.assert_array_less(np.abs(mean - np.mean(allowed, 0)), 4 * spread + 0.1 * np.abs(mean))
