"""Simulation conserves momentum; identification recovers known truth; errors match prediction."""

import numpy as np
import pytest
from conftest import random_tree

import spaceid
from spaceid.estimation import identify
from spaceid.dynamics import angular_momentum
from spaceid.dynamics import minimal_parameters
from spaceid.dynamics import base_rate
from spaceid.motion import add_noise, simulate
from spaceid.studies import validate

H = np.array([0.0, 0.0, 0.4934])


def motion(t):
    """A smooth, exciting two-joint motion (not optimised)."""
    t = np.asarray(t, float)
    q = np.stack([0.8 * np.sin(1.3 * t) + 0.3 * np.sin(3.1 * t), np.sin(2.1 * t + 0.4) * np.sin(0.7 * t)], -1)
    qd = np.stack([1.04 * np.cos(1.3 * t) + 0.93 * np.cos(3.1 * t),
                   2.1 * np.cos(2.1 * t + 0.4) * np.sin(0.7 * t) + 0.7 * np.sin(2.1 * t + 0.4) * np.cos(0.7 * t)], -1)
    return q, qd


@pytest.fixture(scope="module")
def cepheus():
    param = minimal_parameters(spaceid.load_model("cepheus"))
    return param, simulate(param, param.true_values, motion, np.linspace(0, 5, 35), H, model=param.model)


def test_simulation_conserves_momentum(cepheus):
    param, log = cepheus
    assert log.meta["momentum_rel_error"] < 1e-10
    # base yaw is the integral of the base rate: compare with an independent fine quadrature
    t = np.linspace(0, 5, 20001)
    w = base_rate(param, param.true_values, *motion(t), H)[:, 2]
    yaw = np.concatenate([[0], np.cumsum((w[1:] + w[:-1]) / 2 * np.diff(t))])
    assert np.interp(log.t, t, yaw) == pytest.approx(log.base_yaw, abs=1e-7)


def test_spatial_simulation_keeps_unit_quaternion_and_momentum(rng):
    model = random_tree(rng, [0, 1], planar=False)
    param = minimal_parameters(model)
    h = np.array([0.3, -0.2, 0.5])
    log = simulate(param, param.true_values, motion, np.linspace(0, 5, 51), h, initial_quat=[0.8, 0.6, 0, 0], model=model)
    assert np.abs(np.linalg.norm(log.base_quat, axis=1) - 1).max() < 1e-12
    assert log.meta["momentum_rel_error"] < 1e-9
    direct = angular_momentum(model, log.q, log.qd, log.base_w, log.base_quat)
    assert np.abs(direct - h).max() < 1e-9 * np.linalg.norm(h)


@pytest.mark.slow
def test_spatial_attitude_does_not_depend_on_the_span(rng):
    """The attitude at a sample is the same whatever the log's end: 50 Hz samples up to 13.92 s,
    whose times fell a rounding error (1e-15 s) from nodes of the dense spline grid at 5.22, 8.7
    and 10.44 s, had single-sample attitude jumps of up to 4e-8 rad there (rates differentiated
    from them: 1e-6 rad/s, false alarms of the monitor on a noise-free log)."""
    model = random_tree(rng, [0, 1], planar=False)
    param = minimal_parameters(model)
    h = np.array([0.3, -0.2, 0.5])
    t = np.arange(1000) / 50.0
    whole, part = (simulate(param, param.true_values, motion, times, h) for times in (t, t[t <= 13.92]))
    assert np.abs(part.base_quat - whole.base_quat[: part.n_samples]).max() < 1e-10


def test_noise_free_identification_recovers_pi(cepheus):
    param, log = cepheus
    ident = identify(param, log, H)
    np.testing.assert_allclose(ident.values, param.true_values, rtol=1e-9)
    assert ident.residual_rms < 1e-14 and ident.n_samples == 35


@pytest.mark.slow
def test_noisy_spread_matches_predicted_std(cepheus):
    """OLS with noisy regressors: the empirical spread over 400 noise draws agrees with the
    predicted standard error (the bias stays a small fraction of it at this noise level)."""
    param, log = cepheus
    runs = [identify(param, add_noise(log, angle=1e-4, rate=1e-4, seed=s), H) for s in range(400)]
    est = np.array([r.values for r in runs])
    predicted = np.mean([r.std for r in runs], axis=0)
    ratio = est.std(axis=0) / predicted
    assert np.all((ratio > 0.8) & (ratio < 1.25)), ratio
    bias = np.abs(est.mean(axis=0) - param.true_values) / est.std(axis=0)
    assert np.all(bias < 0.3), bias


def test_validation_of_the_true_model_is_exact(cepheus):
    param, log = cepheus
    ident = identify(param, log, H)
    with pytest.warns(UserWarning, match="validation on the fitting log cannot fail"):
        metrics = validate(ident, log, momentum=H).metrics
    # rates match at the samples; the yaw integrates Hermite-interpolated joints between 35 samples
    assert metrics["base_w_nrms"] < 1e-12 and metrics["base_yaw_max"] < 1e-4


@pytest.mark.parametrize(
    "kind, message",
    [("few", "samples give"), ("zero", "homogeneous"), ("still", "rank-deficient")],
)
def test_ill_posed_identification_is_refused(cepheus, kind, message):
    param, log = cepheus
    if kind == "few":
        log, h = log.select(slice(0, 5)), H
    elif kind == "zero":
        h = np.zeros(3)
    else:  # the elbow does not move: its parameters cannot be separated
        q = log.q.copy()
        q[:, 1] = 0.2
        qd = log.qd.copy()
        qd[:, 1] = 0
        log, h = log.__class__(log.t, log.joints, q, qd, log.base_quat, log.base_w, True), H
    with pytest.raises(spaceid.SpaceidError, match=message):
        identify(param, log, h)


def test_hermite_motion_is_the_cubic_hermite_spline():
    """``hermite_motion`` (validate's and predict's joint motion) is SciPy's cubic Hermite spline through the
    samples' angles and rates, to round-off: inside every interval, at the samples themselves, past both ends
    (the end cubics), at a scalar time and for one joint; it refuses times that do not increase."""
    from scipy.interpolate import CubicHermiteSpline

    from spaceid.motion import hermite_motion

    rng = np.random.default_rng(7)
    t = np.cumsum(rng.uniform(0.005, 0.1, 40))
    q, qd = rng.standard_normal((40, 5)), 10 * rng.standard_normal((40, 5))
    spline = CubicHermiteSpline(t, q, qd, axis=0)
    times = np.concatenate([np.linspace(t[0] - 0.3, t[-1] + 0.3, 997), t])
    angles, rates = hermite_motion(t, q, qd)(times)
    np.testing.assert_allclose(angles, spline(times), rtol=0, atol=1e-13 * np.abs(angles).max())
    np.testing.assert_allclose(rates, spline.derivative()(times), rtol=0, atol=1e-13 * np.abs(rates).max())
    one, rate = hermite_motion(t, q[:, 2], qd[:, 2])(t[5] + 0.004)
    assert np.shape(one) == () and one == pytest.approx(spline(t[5] + 0.004)[2], rel=1e-13)
    assert rate == pytest.approx(spline.derivative()(t[5] + 0.004)[2], rel=1e-12)
    with pytest.raises(ValueError, match="strictly increasing"):
        hermite_motion(t[::-1], q, qd)
