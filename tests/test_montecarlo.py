"""Monte Carlo studies: reproducibility, independence of the worker count, statistics that agree
with the Cramer-Rao bound within bands computed from the number of runs, the noise model of
differentiated rates, and the command line."""

import json

import numpy as np
import pytest
from scipy.stats import chi2, norm

import spaceid
from spaceid import SpaceidError
from spaceid.cli import main
from spaceid.studies import DEFAULT_NOISE, differentiated_noise, run_montecarlo
from spaceid.estimation import Noise
from spaceid.dynamics import minimal_parameters
from spaceid.data import differentiate
from spaceid.data import Log, yaw_to_quat

H = [0.0, 0.0, 0.4934]


@pytest.fixture(scope="module")
def param():
    return minimal_parameters(spaceid.load_model("cepheus"))


def study(param, **kw):
    options = dict(samples=35, momentum=H, noise=DEFAULT_NOISE, runs=6, estimators=("ml",), seed=7, jobs=1)
    return run_montecarlo(param, "paper-table2", **{**options, **kw})


def test_same_seed_same_numbers_other_seed_other_numbers(param):
    a, b, c = study(param), study(param), study(param, seed=8)
    np.testing.assert_array_equal(a.estimates["ml"], b.estimates["ml"])
    assert np.all(a.estimates["ml"] != c.estimates["ml"])
    assert a.settings["seed"] == 7 and "SeedSequence" in a.settings["run_seeds"]
    # run i's noise depends on (seed, i) only: a longer study starts with the same runs
    longer = study(param, runs=9)
    np.testing.assert_array_equal(longer.estimates["ml"][:6], a.estimates["ml"])


def test_the_table_lists_the_first_rows_of_each_estimator(param):
    from rich.console import Console

    from spaceid.studies import montecarlo_table

    console = Console(record=True, width=100)
    console.print(montecarlo_table(study(param, runs=3, estimators=("ml", "ols")), rows=3, rest="--all lists them"))
    text = console.export_text()
    assert text.count("│ pi3 ") == 2 and "pi4" not in text  # ML and OLS
    assert text.rstrip().splitlines()[-1] == "the first 3 of 8 parameters listed per estimator, 5 more: --all lists them"


# fast representatives: test_same_seed_same_numbers_other_seed_other_numbers,
# test_estimators.py::test_ml_on_threads_equals_serial
@pytest.mark.slow
def test_two_workers_give_the_numbers_of_one(param):
    one = study(param, runs=8, estimators=("ml", "ols"), jobs=1)
    two = study(param, runs=8, estimators=("ml", "ols"), jobs=2)
    for e in ("ml", "ols"):
        np.testing.assert_array_equal(one.estimates[e], two.estimates[e])
        np.testing.assert_array_equal(one.predicted_std[e], two.predicted_std[e])
    np.testing.assert_array_equal(one.crb_std, two.crb_std)


def test_ml_is_efficient_within_the_band_of_the_run_count(param):
    """At 1e-4 noise the ML estimate is unbiased and at the CRB to first order, so each
    parameter's n RMSE^2 / CRB^2 is chi-square with n degrees of freedom and bias / std is
    normal with variance 1/n; the bands hold all k parameters with probability 0.999
    (Bonferroni), so a wrong bound (e.g. a noise level off by 30 %) or a biased estimator fails."""
    n = 60
    res = study(param, runs=n, estimators=("ml",), seed=11)
    s = res.stats["ml"]
    k = len(res.names)
    alpha = 1e-3 / (2 * k)  # two-sided, two statistics per parameter
    low, high = np.sqrt(chi2.ppf([alpha / 2, 1 - alpha / 2], n) / n)
    assert np.all((low < s["rmse_crb"]) & (s["rmse_crb"] < high)), (low, high, s["rmse_crb"])
    assert np.all(np.abs(s["bias_std"]) < norm.ppf(1 - alpha / 2) / np.sqrt(n - 1)), s["bias_std"]
    # the standard errors ML predicts are the bound itself, to first order in the noise
    np.testing.assert_allclose(s["predicted_std"], res.crb_std, rtol=0.02)
    assert res.failures == () and res.settings["failures"]["count"] == 0


def test_statistics_follow_from_the_runs(param):
    res = study(param, runs=10, estimators=("ml", "ols"))
    for e in res.estimators:
        x, s = res.estimates[e], res.stats[e]
        err = x - res.true
        np.testing.assert_allclose(s["bias"], err.mean(0), rtol=1e-9, atol=1e-15)
        np.testing.assert_allclose(s["std"], x.std(0, ddof=1), rtol=1e-12)
        np.testing.assert_allclose(s["rmse"] ** 2, s["bias"] ** 2 + s["std"] ** 2 * 9 / 10, rtol=1e-9)
        np.testing.assert_allclose(s["rmse_crb"], s["rmse"] / res.crb_std, rtol=1e-12)
        np.testing.assert_allclose(s["relative_rmse"], s["rmse"] / np.abs(res.true), rtol=1e-12)
    data = res.to_dict()
    assert data["estimators"]["ols"]["parameters"][3]["rmse"] == pytest.approx(res.stats["ols"]["rmse"][3])
    assert np.shape(data["runs"]["ml"]["estimates"]) == (10, len(res.names))


def test_bad_options_are_named(param):
    for kw, option in [({"runs": 1}, "`runs`"), ({"estimators": ("ml", "lsq")}, "`estimators`"),
                       ({"jobs": 0}, "`jobs`"), ({"seed": -1}, "`seed`"), ({"momentum": [0, 0, 0]}, "`momentum`"),
                       ({"noise": Noise()}, "`noise`"), ({"samples": 1}, "`samples`")]:
        with pytest.raises(SpaceidError, match=option):
            study(param, **kw)


@pytest.mark.parametrize("joints, base", [
    ({"window": 21, "order": 3}, {"window": 31, "order": 5}),
    ({"method": "spline", "smoothing": 4e-4}, {"method": "spline", "smoothing": 1e-3}),
])
def test_differentiated_noise_is_the_filter_noise(joints, base):
    """The propagated levels equal the empirical spread of the errors of differentiated noisy
    ramps (which both filters reproduce exactly, so the errors are noise alone); the base's level
    comes from its own filter and its own noise estimate."""
    t = np.linspace(0.0, 2.0, 201)
    rng = np.random.default_rng(3)
    sigma = 1e-3
    x = 0.5 * t[:, None] + sigma * rng.standard_normal((t.size, 150))
    smooth, rate, info = differentiate(t, x, **joints)
    smooth, rate = smooth - 0.5 * t[:, None], rate - 0.5
    _, rate_b, _ = differentiate(t, x, **base)  # the base's filter, on the same noise
    rate_b = rate_b - 0.5
    yaw = 0.5 * t + sigma * rng.standard_normal(t.size)
    _, _, info_b = differentiate(t, yaw, **base)
    log = Log(t, ("j",), x[:, :1], x[:, :1], yaw_to_quat(yaw), np.zeros((t.size, 3)), True,
              {"differentiation": {"joints": info, "base": {**info_b, "planar": True}}})
    noise = differentiated_noise(log)
    assert noise.rate == pytest.approx(np.sqrt(np.mean(rate**2)), rel=0.05)
    assert noise.angle == pytest.approx(np.sqrt(np.mean(smooth**2)), rel=0.05)
    assert 0 < noise.angle < sigma < noise.rate
    gain = np.sqrt(np.mean(rate_b**2)) / np.sqrt(np.mean(np.square(info["noise"])))
    assert noise.base_rate == pytest.approx(info_b["noise"][0] * gain, rel=0.05)
    with pytest.raises(SpaceidError, match="differentiate_log"):
        differentiated_noise(Log(t, ("j",), x[:, :1], x[:, :1], yaw_to_quat(yaw), np.zeros((t.size, 3))))


@pytest.mark.slow
def test_angles_only_differentiates_and_records(param):
    res = study(param, runs=2, samples=201, estimators=("ml", "ols"), angles_only=True,
                noise=Noise(angle=1e-4, attitude=1e-4))
    assert np.all(np.isfinite(res.estimates["ml"]))
    d = res.settings["differentiation"]
    assert d["method"] == "savgol" and sum(c["runs"] for c in d["choices"]) == 2
    eq = d["noise_equivalent_rms"]
    assert 0 < eq["angle"] < 1e-4 < eq["rate"] and eq["base_rate"] > 0
    assert np.all(res.stats["ml"]["relative_rmse"] < 0.1)  # the pipeline works: errors of a few percent at most


@pytest.mark.slow
def test_cli_writes_table_json_and_figure(tmp_path, capsys):
    code = main(["montecarlo", "cepheus", "--momentum", "0.4934", "--runs", "4", "--estimator", "ml",
                 "--estimator", "wls", "--seed", "3", "--jobs", "1", "--noise-angle", "2e-4", "--noise-rate", "1e-4",
                 "--noise-base-rate", "1e-4", "--out", str(tmp_path / "mc")])
    assert code == 0
    printed = capsys.readouterr().out
    assert "RMSE/CRB" in printed and "WLS" in printed
    data = json.loads((tmp_path / "mc" / "montecarlo.json").read_text())
    assert data["settings"]["runs"] == 4 and data["settings"]["seed"] == 3
    assert data["settings"]["noise"]["angle"] == 2e-4 and data["settings"]["estimators"] == ["ml", "wls"]
    assert set(data["estimators"]) == {"ml", "wls"} and len(data["parameters"]) == 8
    assert "RMSE/CRB" in (tmp_path / "mc" / "table.txt").read_text()
    assert (tmp_path / "mc" / "montecarlo.png").read_bytes()[:4] == b"\x89PNG"
    assert not list((tmp_path / "mc").glob(".*.tmp"))


@pytest.mark.parametrize(
    "args, option",
    [(["--runs", "0"], "--runs"), (["--estimator", "nls"], "--estimator"), (["--jobs", "0"], "--jobs"),
     (["--trajectory", "designed"], "--duration"), (["--duration", "9"], "--duration")],
)
def test_cli_bad_options_one_line_exit_2(args, option, tmp_path, capsys):
    code = main(["montecarlo", "cepheus", "--momentum", "0.4934", *args, "--out", str(tmp_path / "mc")])
    assert code == 2
    lines = capsys.readouterr().err.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("error: ") and option in lines[0]
    assert not (tmp_path / "mc").exists()
