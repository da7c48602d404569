"""The covariance of estimates from differentiated rates: the angle noise carried through the
differentiator's filters (spaceid.estimation._differentiated) against the brute-force impulse
responses of the differentiator itself, on a whole log and on a window cut from a longer record."""

import dataclasses

import numpy as np
import pytest

import spaceid
from spaceid.data import differentiate, differentiate_log
from spaceid.dynamics import minimal_parameters
from spaceid.estimation._differentiated import differentiated_series, propagated_covariance
from spaceid.motion import add_noise, load_trajectory, simulate

H = np.array([0.0, 0.0, 0.4934])


@pytest.fixture(scope="module")
def record():
    """A Cepheus log at 100 Hz whose rates are differentiated from noisy angles (fixed windows),
    and the noise-free stamps."""
    param = minimal_parameters(spaceid.load_model("cepheus"))
    t = np.arange(0, 1.5001, 0.01)
    log = simulate(param, param.true_values, lambda s: load_trajectory("paper-table2").evaluate(s)[:2], t, H)
    noisy = add_noise(log, angle=1e-4, seed=0)
    noisy = dataclasses.replace(noisy, base_quat=add_noise(log, angle=1e-3, seed=1).base_quat)
    return differentiate_log(noisy, window=21, order=3)


def _brute_force(log, M, J, sigma_white):
    """``sum_s sigma_s^2 K_s^T K_s`` from the impulse responses of ``differentiate`` itself: each raw
    sample's unit error, differentiated with the recorded window and order, through ``J`` and ``M``."""
    info, n, nj = log.meta["differentiation"], log.n_samples, len(log.joints)
    U = np.einsum("nrp,nrc->ncp", M, J)
    omega = 0.0
    joints = info["joints"]
    for j in range(nj):
        value, rate, _ = differentiate(log.t, np.eye(n), window=joints["window"][j], order=joints["order"][j])
        K = value.T @ U[:, j] + rate.T @ U[:, nj + j]  # (raw samples, p)
        omega = omega + joints["noise"][j] ** 2 * K.T @ K
    base = info["base"]
    _, rate, _ = differentiate(log.t, np.eye(n), window=base["window"][0], order=base["order"][0])
    K = rate.T @ U[:, 2 * nj]
    return omega + base["noise"][0] ** 2 * K.T @ K


def test_propagated_covariance_is_the_differentiators_own(record):
    """Random estimator weights and signal derivatives: the propagated score covariance equals the
    brute-force one from the differentiator's impulse responses to round-off."""
    rng = np.random.default_rng(3)
    n, p = record.n_samples, 5
    n_x = 2 * len(record.joints) + 1
    M, J = rng.standard_normal((n, 1, p)), rng.standard_normal((n, 1, n_x))
    series = differentiated_series(record)
    assert len(series) == len(record.joints) + 1  # every joint, and the base yaw
    got = propagated_covariance(series, record.t, [(slice(None), M, J)], np.eye(p), np.zeros(n_x))
    want = _brute_force(record, M, J, None)
    assert np.allclose(got, want, rtol=1e-10, atol=1e-12 * np.abs(want).max())


@pytest.mark.parametrize("chunk", [2, 7, 20])
def test_propagated_covariance_in_chunks_is_the_whole_logs(record, chunk):
    """Chunks shorter than the filters' windows (and not dividing the log): the rows of the windows that
    straddle a chunk's end are carried over, and the covariance is that of the log at once to round-off."""
    rng = np.random.default_rng(5)
    n, p = record.n_samples, 4
    n_x = 2 * len(record.joints) + 1
    M, J = rng.standard_normal((n, 2, p)), rng.standard_normal((n, 2, n_x))
    sigma = np.where(np.arange(n_x) == 1, 0.3, 0.0)  # one signal white: the uncovered terms too
    series = differentiated_series(record)[1:]  # the first joint's angle and rate left to sigma
    assert record.n_samples % chunk and chunk < min(s[0]["window"] for s in series)
    whole = propagated_covariance(series, record.t, [(slice(None), M, J)], np.eye(p), sigma)
    parts = [(sl, M[sl], J[sl]) for sl in (slice(s, min(s + chunk, n)) for s in range(0, n, chunk))]
    got = propagated_covariance(series, record.t, parts, np.eye(p), sigma)
    assert np.abs(got - whole).max() <= 1e-13 * np.abs(whole).max()


def test_a_window_cut_from_a_longer_record_takes_centred_filters(record):
    """A log cut from the middle of the differentiated record (the excitation of a bag): its
    samples' filters reach beyond it, and the propagated covariance is that of the whole record's
    filters restricted to the window's rows."""
    rng = np.random.default_rng(4)
    p, n_x = 3, 2 * len(record.joints) + 1
    rows = np.arange(40, 110)
    M, J = np.zeros((record.n_samples, 1, p)), np.zeros((record.n_samples, 1, n_x))
    M[rows], J[rows] = rng.standard_normal((len(rows), 1, p)), rng.standard_normal((len(rows), 1, n_x))
    whole = _brute_force(record, M, J, None)
    cut = record.select(rows)
    got = propagated_covariance(differentiated_series(cut), cut.t, [(slice(None), M[rows], J[rows])], np.eye(p),
                                np.zeros(n_x))
    assert np.allclose(got, whole, rtol=1e-10, atol=1e-12 * np.abs(whole).max())


def test_rates_without_a_savgol_record_are_not_propagated(record):
    """Spline differentiators, and logs whose rates were measured, keep the residual-based covariance."""
    assert differentiated_series(dataclasses.replace(record, meta={})) is None
    spline = differentiate_log(record, method="spline")
    assert differentiated_series(spline) is None
