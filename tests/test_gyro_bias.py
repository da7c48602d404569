"""Each sensor's noise model (add_noise, simulate) and the gyro bias estimated with the parameters
(identify gyro_bias=True): known truth noise-free and noisy, the diagnosis of a bias not estimated,
RESULT.json, the command line."""

import dataclasses
import json
import warnings

import numpy as np
import pytest
from click.testing import CliRunner
from hypothesis import given
from hypothesis import strategies as st
from random_robots import random_robot
from robot_tally import robots, stage
from test_simulate_estimate import motion

import spaceid
from spaceid import SpaceidError
from spaceid.cli import app
from spaceid.data import differentiate_log, read_log, write_log
from spaceid.dynamics import minimal_parameters
from spaceid.estimation import Identification, Noise, identify
from spaceid.estimation._gyro_bias import attitude_information
from spaceid.motion import add_noise, sample_times, simulate

H = np.array([0.0, 0.0, 0.4934])
H_SPATIAL = np.array([0.3, -0.2, 0.5])
BIAS = 3e-4  # [rad/s], a MEMS-class gyro's
SPATIAL_BIAS = np.array([3e-4, -2e-4, 1e-4])
SENSORS = Noise(angle=1e-4, rate=1e-3, base_rate=1e-5, attitude=5e-5)  # encoders, joint rates, gyro, star tracker


@pytest.fixture(scope="module")
def cepheus():
    param = minimal_parameters(spaceid.load_model("cepheus"))
    return param, simulate(param, param.true_values, motion, np.linspace(0, 20, 1001), H, model=param.model)


def _random(seed, planar, folder):
    return _flown(random_robot(seed, planar=planar, max_arms=2, max_joints=2).load(folder), seed)


def _flown(model, seed):
    """``model``'s parameters, momentum and noise-free log of a sum of three sines per joint (20 s, 50 Hz)."""
    param = minimal_parameters(model)
    planar = model.planar
    h = H if planar else H_SPATIAL
    rng = np.random.default_rng(seed)
    n = len(model.joints)
    amp, freq, phase = rng.uniform(0.3, 0.8, (3, n)), rng.uniform(0.4, 2.0, (3, n)), rng.uniform(0, 6, (3, n))

    def moves(t):
        t = np.asarray(t, float)[:, None, None]
        q = (amp * np.sin(freq * t + phase)).sum(1)
        qd = (amp * freq * np.cos(freq * t + phase)).sum(1)
        return q, qd

    log = simulate(param, param.true_values, moves, sample_times(20.0, 1001), h, model=model,
                   initial_quat=None if planar else [0.8, 0.6, 0, 0])
    return param, h, log


# --- the sensors ---------------------------------------------------------------------------------


def test_each_sensor_has_its_own_noise(cepheus):
    _, clean = cepheus
    log = add_noise(clean, noise=SENSORS, quantum=1e-3, gyro_bias=BIAS, seed=4)
    assert np.all(np.abs(log.q / 1e-3 - np.round(log.q / 1e-3)) < 1e-9)  # on the encoder's grid
    error = log.q - clean.q  # noise then quantisation: variance sigma^2 + quantum^2 / 12
    assert np.std(error) == pytest.approx(np.sqrt(1e-4**2 + 1e-3**2 / 12), rel=0.1)
    assert np.std(log.qd - clean.qd) == pytest.approx(1e-3, rel=0.1)
    gyro = log.base_w[:, 2] - clean.base_w[:, 2]
    assert np.mean(gyro) == pytest.approx(BIAS, abs=5 * 1e-5 / np.sqrt(len(gyro)))
    assert np.std(gyro) == pytest.approx(1e-5, rel=0.1)
    assert np.std(log.base_yaw - clean.base_yaw) == pytest.approx(5e-5, rel=0.1)
    assert log.meta["gyro_bias"] == [0.0, 0.0, BIAS] and log.meta["encoder_quantum"] == 1e-3
    assert (log.meta["noise_angle"], log.meta["noise_rate"], log.meta["noise_base_rate"],
            log.meta["noise_attitude"], log.meta["noise_seed"]) == (1e-4, 1e-3, 1e-5, 5e-5, 4)


def test_shared_levels_are_the_old_draws(cepheus):
    """``angle``/``rate`` set joints and base alike, as before the sensors had their own levels."""
    _, clean = cepheus
    old, new = add_noise(clean, angle=1e-3, rate=2e-3, seed=7), add_noise(clean, noise=Noise(1e-3, 2e-3, 2e-3, 1e-3),
                                                                       seed=7)
    for field in ("q", "qd", "base_w", "base_quat"):
        np.testing.assert_array_equal(getattr(old, field), getattr(new, field))


def test_a_log_without_joint_rate_sensors(cepheus, tmp_path):
    param, clean = cepheus
    log = add_noise(clean, angle=1e-4, rate=1e-5, joint_rate_sensors=False, seed=1)
    assert np.isnan(log.qd).all() and not np.isnan(log.base_w).any()
    write_log(tmp_path / "log.csv", log)
    header = (tmp_path / "log.csv").read_text().splitlines()[0].split(",")
    assert not [c for c in header if c.startswith("qd_")] and "base_wz" in header
    back = read_log(tmp_path / "log.csv", joints=param.model.joints, planar=True, require_rates=False)
    assert back.meta["missing_rates"] == [f"qd_{j}" for j in param.model.joints]


@pytest.mark.parametrize("kwargs, message", [
    ({"gyro_bias": [1e-4, 0, 0]}, "yaw rate only"),
    ({"gyro_bias": [1e-4, 2e-4]}, "is not a gyro bias"),
    ({"gyro_bias": "abc"}, "is not a gyro bias"),
    ({"quantum": -1.0}, "`quantum`"),
    ({"angle": 1e-4, "noise": Noise()}, "not both"),
    ({"angle": -1.0}, "`angle`"),
])
def test_bad_sensor_values(cepheus, kwargs, message):
    with pytest.raises(SpaceidError, match=message):
        add_noise(cepheus[1], **kwargs)


def test_spatial_bias_needs_three_components(tmp_path):
    _, _, log = _random(1, False, tmp_path)
    with pytest.raises(SpaceidError, match="3 components"):
        add_noise(log, gyro_bias=1e-4)


# --- the bias estimated: known truth ---------------------------------------------------------------


@pytest.mark.parametrize("estimator", ["ols", "wls", "ml"])
def test_noise_free_recovery_planar(cepheus, estimator):
    param, clean = cepheus
    log = add_noise(clean, gyro_bias=BIAS)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # chi2 of a noise-free log
        res = identify(param, log, H, estimator=estimator, gyro_bias=True,
                       noise=None if estimator == "ols" else Noise())
    true = param.true_values
    assert np.abs(res.values - true).max() <= 1e-12 * res.condition_number * np.abs(true).max()
    (b,) = res.gyro_bias
    assert b["name"] == "gyro_bias_z" and b["unit"] == "rad/s"
    assert abs(b["value"] - BIAS) <= 1e-14 * res.condition_number
    assert res.settings["gyro_bias"]["passes"] <= 5


@pytest.mark.slow
def test_noise_free_recovery_spatial_preset():
    param, h, clean = _flown(spaceid.load_model("satellite-7dof"), 0)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        res = identify(param, add_noise(clean, gyro_bias=SPATIAL_BIAS), h, estimator="ols", gyro_bias=True)
    true = param.true_values
    assert np.abs(res.values - true).max() <= 1e-12 * res.condition_number * np.abs(true).max()
    assert np.abs([d["value"] for d in res.gyro_bias] - SPATIAL_BIAS).max() <= 1e-14 * res.condition_number


@pytest.mark.slow  # fast representatives: test_noise_free_recovery_any_random_robot, test_noise_free_recovery_planar
@pytest.mark.parametrize("planar", [False, True])
def test_noise_free_recovery_random_robots(planar, tmp_path):
    for seed in (3, 11):
        param, h, clean = _random(seed, planar, tmp_path)
        bias = BIAS if planar else SPATIAL_BIAS
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            res = identify(param, add_noise(clean, gyro_bias=bias), h, estimator="ols", gyro_bias=True)
        true = param.true_values
        assert np.abs(res.values - true).max() <= 1e-11 * res.condition_number * np.abs(true).max()
        values = np.array([d["value"] for d in res.gyro_bias])
        assert np.abs(values - np.atleast_1d(bias)).max() <= 1e-14 * res.condition_number


@robots(1)
@given(seed=st.integers(0, 2**31 - 1), planar=st.booleans())
def test_noise_free_recovery_any_random_robot(seed, planar, tmp_path):
    with stage("identify gyro bias noise-free", seed=seed, planar=planar, motion="harmonic"):
        param, h, clean = _random(seed, planar, tmp_path)
        bias = BIAS if planar else SPATIAL_BIAS
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            res = identify(param, add_noise(clean, gyro_bias=bias), h, estimator="ols", gyro_bias=True,
                           cond_limit=1e12)  # fmt: skip
        true = param.true_values
        assert np.abs(res.values - true).max() <= 1e-10 * res.condition_number * np.abs(true).max()
        assert np.abs([d["value"] for d in res.gyro_bias] - np.atleast_1d(bias)).max() <= 1e-13 * res.condition_number


def test_the_attitude_alone_gives_the_bias(tmp_path):
    """The Kalman filter on the attitude samples: the bias to within its standard error, noise-free
    (its quadrature error covered) and noisy."""
    _, _, clean = _random(3, False, tmp_path)
    exact = attitude_information(add_noise(clean, gyro_bias=SPATIAL_BIAS), Noise())
    assert np.all(np.abs(exact["value"] - SPATIAL_BIAS) < 2 * np.sqrt(np.diag(exact["cov"])))
    z = [(a["value"] - SPATIAL_BIAS) / np.sqrt(np.diag(a["cov"])) for a in (
        attitude_information(add_noise(clean, noise=SENSORS, gyro_bias=SPATIAL_BIAS, seed=s), SENSORS)
        for s in range(10))]
    assert 0.6 < np.sqrt(np.mean(np.square(z))) < 1.5


def _z_scores(param, h, clean, bias, runs, estimator="ml", gyro_bias=True):
    zb, zp = [], []
    for seed in range(runs):
        log = add_noise(clean, noise=SENSORS, gyro_bias=bias, seed=seed)
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            res = identify(param, log, h, estimator=estimator, noise=SENSORS, gyro_bias=gyro_bias)
        free = res.std > 0
        zp.append((res.values - param.true_values)[free] / res.std[free])
        if gyro_bias:
            zb.append([(d["value"] - b) / d["std"] for d, b in zip(res.gyro_bias, np.atleast_1d(bias)[-len(
                res.gyro_bias):])])
    return np.array(zb), np.array(zp)


def test_noisy_bias_within_its_standard_errors(tmp_path):
    param, h, clean = _random(3, False, tmp_path)
    zb, zp = _z_scores(param, h, clean, SPATIAL_BIAS, 3)
    assert np.abs(zb).max() < 4 and np.abs(zp).max() < 4.5


@pytest.mark.slow
@pytest.mark.parametrize("planar", [True, False])
@pytest.mark.parametrize("estimator", ["ml", "wls"])
def test_noisy_z_scores_match_the_standard_errors(planar, estimator, tmp_path):
    """Over 40 seeds, the root-mean-square z of the bias and of the parameters in [0.7, 1.3]."""
    param, h, clean = _random(3, planar, tmp_path)
    zb, zp = _z_scores(param, h, clean, BIAS if planar else SPATIAL_BIAS, 40, estimator)
    rms_b, rms_p = np.sqrt(np.mean(zb**2)), np.sqrt(np.mean(zp**2))
    assert 0.7 <= rms_b <= 1.3, rms_b
    assert 0.7 <= rms_p <= 1.3, rms_p


def test_the_bias_grows_the_parameters_standard_errors(tmp_path):
    """The coupling with the bias is in the parameters' covariance: larger than with the bias known."""
    param, h, clean = _random(3, False, tmp_path)
    log = add_noise(clean, noise=SENSORS, gyro_bias=SPATIAL_BIAS, seed=0)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        joint = identify(param, log, h, noise=SENSORS, gyro_bias=True)
        known = identify(param, dataclasses.replace(log, base_w=log.base_w - SPATIAL_BIAS), h, noise=SENSORS)
    # larger in every direction (Loewner order; the same log, linearised alike) and by more than round-off;
    # little here, as the star tracker pins the bias (4.6e-7 rad/s)
    scale = np.outer(known.std, known.std)
    assert np.linalg.eigvalsh((joint.cov - known.cov) / scale).min() > -1e-3
    assert np.max(joint.std / known.std) > 1.001


@pytest.mark.parametrize("estimator", ["iv", "tls", "angles"])
def test_other_estimators_refused(cepheus, estimator):
    with pytest.raises(SpaceidError, match=f"`gyro_bias`: not available with `estimator` {estimator}"):
        identify(cepheus[0], cepheus[1], H, estimator=estimator, gyro_bias=True)


def test_refused_without_a_gyro(cepheus):
    log = differentiate_log(add_noise(cepheus[1], angle=1e-5, seed=1), window=11)
    with pytest.raises(SpaceidError, match="not a gyro's"):
        identify(cepheus[0], log, H, gyro_bias=True)
    with pytest.raises(SpaceidError, match="in memory only"):
        identify(cepheus[0], cepheus[1], H, gyro_bias=True, chunk=100)


def test_differentiated_joint_rates_with_the_gyro(cepheus):
    """No joint-rate sensors: the joint angles differentiated, the gyro kept, its bias estimated."""
    param, clean = cepheus
    log = add_noise(clean, noise=SENSORS, gyro_bias=BIAS, joint_rate_sensors=False, seed=2)
    log = differentiate_log(log, window=21, base=False)
    assert "base" not in log.meta["differentiation"]
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        res = identify(param, log, H, estimator="wls", gyro_bias=True)
    (b,) = res.gyro_bias
    assert abs(b["value"] - BIAS) < 4 * b["std"] and b["std"] < 1e-5


@pytest.mark.parametrize("estimator", ["ols", "wls"])
def test_least_squares_without_levels_judges_a_noisy_gyro_by_the_logs_own(estimator, tmp_path):
    """Least squares given no levels on differentiated encoders and a measured gyro, no bias: its checks and its
    covariance take the log's own levels, the gyro's among them (ols left it at zero: a random robot's white gyro
    noise was called a bias), and its standard errors hold the bias the gyro's noise gives it (8.6 and 8.7 of them
    without)."""
    param, h, clean = _random(3, False, tmp_path)
    sensors = Noise(angle=1e-4, rate=0.0, base_rate=1e-3, attitude=5e-5)
    log = differentiate_log(add_noise(clean, noise=sensors, joint_rate_sensors=False, seed=1), base=False)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        res = identify(param, log, h, estimator=estimator)
    text = " ".join(str(w.message) for w in caught)
    assert "gyro bias" not in text and f"the regressor's noise biases the {estimator} estimate by up to" in text
    assert "widened by the first-order bias" in res.diagnostics.covariance
    noise = res.settings["noise"]
    assert noise["source"].startswith("estimated from the log") and noise["base_rate"] == pytest.approx(1e-3, rel=0.3)
    z = (res.values - param.true_values) / np.sqrt(np.diag(res.cov))
    assert np.abs(z).max() < 4.5


@robots(2, fast=1)
@given(seed=st.integers(0, 2**31 - 1), planar=st.booleans(), estimator=st.sampled_from(["ols", "wls"]))
def test_least_squares_standard_errors_hold_a_noisy_gyros_bias_on_any_random_robot(seed, planar, estimator, tmp_path):
    """A servicer's sensors (encoders differentiated, a MEMS-class gyro of 1e-3 rad/s white noise kept, a star
    tracker), levels estimated: least squares' errors within its standard errors, its errors-in-variables bias
    among them (on 28 random robots, 0.3 to 3.2 of them at most over the large parameters, as ``ml``'s)."""
    with stage(f"identify {estimator}: a noisy gyro's bias in the standard errors", seed=seed, planar=planar,
               motion="harmonic"):
        param, h, clean = _random(seed, planar, tmp_path)
        sensors = Noise(angle=1e-4, rate=0.0, base_rate=1e-3, attitude=5e-5)
        log = differentiate_log(add_noise(clean, noise=sensors, joint_rate_sensors=False, seed=1), base=False)
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            res = identify(param, log, h, estimator=estimator)
        large = np.abs(param.true_values) >= 1e-3 * np.abs(param.true_values).max()
        assert np.abs((res.values - param.true_values) / res.std)[large].max() < 4.5


# --- a bias not estimated: named, not taken for a drift ---------------------------------------------


def test_a_bias_not_estimated_is_named(tmp_path):
    param, h, clean = _random(3, False, tmp_path)
    log = add_noise(clean, noise=SENSORS, gyro_bias=SPATIAL_BIAS, seed=0)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        res = identify(param, log, h, noise=SENSORS)
    text = " ".join(str(w.message) for w in caught)
    assert "a gyro bias of about" in text and "identify with `gyro_bias`" in text
    assert "external torque or base friction" not in text
    found = np.array(res.diagnostics.drift_test.gyro_bias)
    assert np.abs(found - SPATIAL_BIAS).max() < 0.2 * np.abs(SPATIAL_BIAS).max()
    assert Identification.from_dict(json.loads(json.dumps(res.to_dict()))).diagnostics.drift_test.gyro_bias == \
        res.diagnostics.drift_test.gyro_bias


def test_a_real_drift_is_not_called_a_bias(cepheus):
    param, _ = cepheus
    log = simulate(param, param.true_values, motion, np.linspace(0, 20, 1001), H, model=param.model,
                   drift={"torque": 2e-4})
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        res = identify(param, add_noise(log, noise=SENSORS, seed=0), H, noise=SENSORS)
    text = " ".join(str(w.message) for w in caught)
    assert "external torque or base friction" in text and "gyro bias" not in text
    assert res.diagnostics.drift_test.gyro_bias == ()


def test_no_bias_no_warning(cepheus):
    param, clean = cepheus
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        identify(param, add_noise(clean, noise=SENSORS, seed=3), H, noise=SENSORS)
    assert not [w for w in caught if "gyro bias" in str(w.message)]


# --- the record -------------------------------------------------------------------------------------


def test_result_json_round_trip_report_and_old_files(cepheus, tmp_path):
    param, clean = cepheus
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        res = identify(param, add_noise(clean, noise=SENSORS, gyro_bias=BIAS, seed=1), H, noise=SENSORS,
                       gyro_bias=True)
    data = json.loads(json.dumps(res.to_dict()))
    assert data["gyro_bias"][0]["name"] == "gyro_bias_z" and data["settings"]["gyro_bias"]["passes"] >= 1
    back = Identification.from_dict(data)
    assert back.gyro_bias == res.gyro_bias
    del data["gyro_bias"]
    assert Identification.from_dict(data).gyro_bias == ()
    from spaceid.studies import write_markdown_report

    text = write_markdown_report(tmp_path, title="t", result=res, settings={}, figures={}).read_text()
    assert "| gyro_bias_z | rad/s |" in text.replace("\\_", "_")


# --- the command line -------------------------------------------------------------------------------


def _cli(*args):
    result = CliRunner().invoke(app, [str(a) for a in args])
    return result.exit_code, result.output


def test_cli_sensors_and_gyro_bias(tmp_path):
    log = tmp_path / "log.csv"
    code, _ = _cli("simulate", "cepheus", "--trajectory", "paper-table2", "--momentum", 0.4934, "--rate", 50,
                   "--noise-angle", 1e-4, "--noise-base-rate", 1e-5, "--noise-attitude", 5e-5, "--quantum", 1e-5,
                   "--gyro-bias", 3e-4, "--no-joint-rate-sensors", "--seed", 3, "-o", log)
    assert code == 0
    header = log.read_text().splitlines()[0]
    assert "qd_" not in header and "base_wz" in header
    code, output = _cli("identify", "cepheus", log, "--momentum", 0.4934, "--gyro-bias", "--estimator", "wls",
                        "-o", tmp_path / "r.json")
    assert code == 0, output
    assert "gyro bias: gyro_bias_z = " in output
    saved = json.loads((tmp_path / "r.json").read_text())
    assert abs(saved["gyro_bias"][0]["value"] - 3e-4) < 5 * saved["gyro_bias"][0]["std"]


@pytest.mark.slow  # fast representative: test_cli_sensors_and_gyro_bias
def test_cli_keeps_a_gyros_rate_when_the_joint_rates_are_differentiated(tmp_path):
    """Encoders without joint-rate sensors beside a gyro: the joint rates come from the encoders, the
    base rate stays the gyro's (its attitude differentiated instead was a hundred times noisier)."""
    log = tmp_path / "log.csv"
    assert _cli("simulate", "cepheus", "--trajectory", "paper-table2", "--momentum", 0.4934, "--rate", 50,
                "--noise-angle", 1e-4, "--noise-base-rate", 1e-5, "--noise-attitude", 5e-5, "--no-joint-rate-sensors",
                "--seed", 3, "-o", log)[0] == 0  # fmt: skip
    for extra in ([], ["--joint-rates", "differentiate"]):
        code, output = _cli("identify", "cepheus", log, "--momentum", 0.4934, "--estimator", "wls", *extra,
                            "-o", tmp_path / "r.json")
        assert code == 0, output
        differentiation = json.loads((tmp_path / "r.json").read_text())["settings"]["log"]["differentiation"]
        assert "joints" in differentiation and "base" not in differentiation


@pytest.mark.parametrize("args, message", [
    (["--gyro-bias", "1,2"], "--gyro-bias: [1.0, 2.0] is not a gyro bias"),
    (["--gyro-bias", "x"], "--gyro-bias: 'x' is not a number"),
    (["--quantum", "-1"], "--quantum: -1 is not"),
    (["--noise-attitude", "nan"], "--noise-attitude: nan is not"),
])
def test_cli_bad_sensor_values(args, message, tmp_path):
    code, output = _cli("simulate", "cepheus", "--trajectory", "paper-table2", "--momentum", 0.4934, "--rate", 50,
                        *args, "-o", tmp_path / "log.csv")
    assert code == 2 and message in output and len(output.strip().splitlines()) == 1, output


def test_cli_gyro_bias_refused_for_iv(tmp_path):
    log = tmp_path / "log.csv"
    assert _cli("simulate", "cepheus", "--trajectory", "paper-table2", "--momentum", 0.4934, "--rate", 50,
                "-o", log)[0] == 0
    code, output = _cli("identify", "cepheus", log, "--momentum", 0.4934, "--gyro-bias", "--estimator", "iv",
                        "-o", tmp_path / "r.json")
    assert code == 2 and "--gyro-bias: not available with --estimator iv" in output
    assert len(output.strip().splitlines()) == 1
