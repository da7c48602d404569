"""The Cepheus experiment on the twin, end to end through a ROS bag."""

import json
import warnings
from dataclasses import replace

import numpy as np
import pytest

from spaceid import SpaceidError, load_model
from spaceid.cli import main
from spaceid.data import JOINT_RATE_POLICY, read_log
from spaceid.dynamics import minimal_parameters
from spaceid.estimation import identify
from spaceid.motion import load_trajectory
from spaceid.studies import run_experiment, validate
from spaceid.twin import TwinSettings


@pytest.fixture(scope="module")
def ideal(tmp_path_factory):
    folder = tmp_path_factory.mktemp("experiment")
    return run_experiment(trajectory="paper-table2", settings=TwinSettings().without_effects(), bag_format="mcap",
                          seed=3, out=folder)  # fmt: skip


@pytest.mark.slow
def test_identification_from_the_twin_bag_is_within_its_uncertainty(ideal):
    res = ideal
    known = res.ident.std == 0
    assert res.ident.settings["anchors"][0]["definition"] == "Iczz_wheel"
    assert np.all(res.ident.values[known] == res.true[known])
    z = (res.ident.values - res.true)[~known] / res.ident.std[~known]
    assert np.abs(z).max() < 4, z
    # the momentum the wheel leaves the rest of the system is the paper's I_rw w_rw
    assert res.settings["momentum of the rest, I_rw w_rw [N m s]"] == pytest.approx(0.3355, abs=1e-4)
    # N = 29 samples of the 5 s excitation, and all samples of it from the 50 Hz joint states
    assert res.ident.n_samples == 29 and res.ident_all.n_samples == 251
    # the identified model re-simulates the measured base rate to a few percent of its RMS: the measured rate is
    # differentiated from the attitude with the window chosen for the estimate (less bias, more noise: 1.6 %)
    assert res.metrics["base_w_nrms"] < 0.03


def test_report_folder(ideal):
    names = {p.name for p in ideal.folder.iterdir()}
    assert {"run.mcap", "log.csv", "truth.csv", "result.json", "result_all_samples.json", "experiment.json",
            "validation.png", "parameters.png", "tracking.png", "report.md", "validation.mcap", "validation_log.csv",
            "validation_truth.csv", "validation_trajectory.json", "mapping.yaml"} <= names  # fmt: skip
    text = (ideal.folder / "report.md").read_text()
    assert "Cepheus experiment" in text and "excitation window" in text
    assert "cond(Y) designed / executed, N samples" in text and "tracking RMS, encoders vs design" in text
    assert "left\\_shoulder 0.0" in text and "(tracking.png)" in text
    assert "held-out motion (designed): base angular velocity" in text and "fitting log (checks the fit" in text
    saved = json.loads((ideal.folder / "experiment.json").read_text())
    assert saved["validation"] == ideal.metrics and saved["validation_fit_log"] == ideal.fit_metrics


def _nrms(pi, res, log):
    """Base-rate NRMS of the model ``pi`` re-simulated on ``log`` of the experiment ``res``."""
    return validate(replace(res.ident, values=pi), log, momentum=np.zeros(3)).metrics["base_w_nrms"]


@pytest.mark.slow
def test_validation_is_on_a_held_out_motion(ideal):
    res, s = ideal, ideal.settings
    # paper-table2 identifies, so a designed trajectory (seed + 1) is held out, run after the excitation
    assert s["trajectory"] == "paper-table2" and s["validation trajectory"] == "designed"
    assert s["validation trajectory seed"] == res.validation_trajectory.meta["seed"] == 4
    assert s["validation phase seed"] == 6 and res.validation_trajectory != res.trajectory
    assert s["validation window [s]"][0] == pytest.approx(s["excitation window [s]"][1] + 1)  # after its hold
    assert res.validation_log.n_samples == s["validation samples"] == 251
    # the held-out metrics are not those of the fitting log, and report the re-simulated held-out motion
    assert res.metrics != res.fit_metrics  # the spline through the held-out samples gives them back to round-off
    assert np.abs(res.predicted.q - res.validation_log.q).max() <= 1e-14 * np.abs(res.validation_log.q).max()
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # the experiment never validates on a fitting log itself
        kinematic = validate(res.ident, res.validation_log, momentum=np.zeros(3)).metrics
    assert kinematic == {k: v for k, v in res.metrics.items() if k in kinematic}  # beside them: the torque level


@pytest.mark.slow
def test_held_out_validation_detects_wrong_models(ideal):
    """Every parameter 30 % off: the held-out error is several times the true model's (2.3x at least
    measured, 3.9 to 130x for all but one parameter). A model off by 30 % along the direction the fitting
    data determine worst fits its own log about as well as the true model (1.07x measured) but the held-out
    motion clearly worse (1.5x): this fails if validation re-uses the fitting log. The held-out motion is
    designed, a local optimum that moves with round-off; on another (cond 32.0 against 33.2, a third
    less noise in the true model's error) these were 3.4x and 3.2x."""
    res = ideal
    true = _nrms(res.true, res, res.validation_log)
    for i in range(len(res.true)):
        pi = res.true.copy()
        pi[i] *= 1.3
        assert _nrms(pi, res, res.validation_log) > 2 * true, res.ident.names[i]
    scale = np.abs(res.true)
    _, vectors = np.linalg.eigh(res.ident.cov / np.outer(scale, scale))
    weakest = vectors[:, -1]  # largest relative variance
    pi = res.true + scale * weakest * 0.3 / np.abs(weakest).max()
    own = _nrms(pi, res, res.log) / _nrms(res.true, res, res.log)
    assert own < 1.2 and _nrms(pi, res, res.validation_log) / true > 1.3 * own


@pytest.mark.slow
def test_bag_identify_reads_the_bag_as_the_experiment(ideal, tmp_path, capsys):
    """Same bag, same samples, same estimate: 'spaceid identify' and the experiment read bags with
    one joint-rate policy by default (mapping.yaml carries the motion-capture latency)."""
    res, folder = ideal, ideal.folder
    model = load_model("cepheus-rw")
    param = minimal_parameters(model)
    bag, mapping = folder / "run.mcap", folder / "mapping.yaml"
    full = read_log(bag, joints=model.joints, planar=True, wheels=model.wheels, require_rates=False,
                    bag_options={"mapping": mapping})  # as 'spaceid identify' reads it
    log = full.select(np.isin(full.t, res.log.t))
    assert log.n_samples == res.log.n_samples and res.settings["joint rates"] == JOINT_RATE_POLICY
    for name in ("q", "qd", "base_w", "base_quat"):
        np.testing.assert_array_equal(getattr(log, name), getattr(res.log, name))
    again = identify(param, log, np.zeros(3))
    np.testing.assert_allclose(again.values, res.ident_all.values, rtol=1e-12, atol=0)

    capsys.readouterr()
    assert main(["identify", "cepheus-rw", str(bag), "--momentum", "0", "--mapping", str(mapping),
                 "-o", str(tmp_path / "r.json")]) == 0
    assert "joint rates: 'differentiate' (default)" in capsys.readouterr().out
    result = json.loads((tmp_path / "r.json").read_text())
    assert result["settings"]["log"]["joint_rate_policy"] == res.log.meta["joint_rate_policy"] == "differentiate"
    values = np.array([p["value"] for p in result["parameters"]])
    np.testing.assert_allclose(values, identify(param, full, np.zeros(3)).values, rtol=1e-12, atol=0)
    # the other policy on request: the published one-tick velocities
    assert main(["identify", "cepheus-rw", str(bag), "--momentum", "0", "--mapping", str(mapping),
                 "--joint-rates", "velocity", "-o", str(tmp_path / "v.json")]) == 0
    assert "joint rates: 'velocity':" in capsys.readouterr().out
    log_settings = json.loads((tmp_path / "v.json").read_text())["settings"]["log"]
    assert log_settings["joint_rate_policy"] == "velocity" and set(log_settings["joint_rates"].values()) == {"velocity"}
    # validating the whole-bag result on its own bag warns; on the held-out bag it does not
    for validation_bag, warned in ((bag, True), (folder / "validation.mcap", False)):
        assert main(["validate", str(tmp_path / "r.json"), str(validation_bag), "--momentum", "0", "--mapping",
                     str(mapping), "-o", str(tmp_path / validation_bag.stem)]) == 0
        assert ("validation on the fitting log cannot fail" in " ".join(capsys.readouterr().err.split())) == warned


def test_cli_rejects_bad_options(tmp_path):
    assert main(["experiment", "--samples", "5", "--out", str(tmp_path / "x")]) == 2
    assert not (tmp_path / "x").exists()


# --- the excitation as executed: feed-forward and rehearsals ---------------------------------------


@pytest.fixture(scope="module")
def designed():
    """The default experiment on the designed excitation (feed-forward from the prior model)."""
    return run_experiment(seed=0, drift=())  # the arm motion alone: cond(Y) without a drift column


@pytest.mark.slow
def test_executed_motion_is_as_exciting_as_designed(designed):
    s = designed.settings
    for label in ("N samples", "all samples"):
        cond_designed, cond_executed = s[f"cond(Y) designed / executed, {label}"]
        assert abs(cond_executed / cond_designed - 1) < 0.2, (label, cond_designed, cond_executed)
    # the executed condition number is the identification's own
    assert s["cond(Y) designed / executed, N samples"][1] == designed.ident.condition_number
    assert s["cond(Y) designed / executed, all samples"][1] == designed.ident_all.condition_number


@pytest.mark.slow
def test_feedforward_reduces_the_tracking_error(designed):
    published = run_experiment(trajectory=designed.trajectory, seed=0, feedforward=False, drift=())
    before = published.settings["tracking RMS, encoders vs design [rad]"]
    after = designed.settings["tracking RMS, encoders vs design [rad]"]
    assert set(after) == {"left_shoulder", "left_elbow"}
    assert max(after.values()) < 0.03 and max(after.values()) < 0.25 * max(before.values())
    ratio = published.settings["cond(Y) executed / designed, N and all samples"]
    assert max(ratio) > 1.5  # the PD loops alone: the executed motion conditions the regressor far worse
    # same design, same sample instants: the designed condition numbers agree
    assert published.settings["cond(Y) designed / executed, N samples"][0] == pytest.approx(
        designed.settings["cond(Y) designed / executed, N samples"][0], rel=1e-9)


@pytest.mark.slow
def test_options_are_recorded(designed, tmp_path):
    s = designed.settings
    assert s["feedforward"].startswith("planned from the prior model (cepheus-rw)")
    assert s["rehearsals (at most)"] == 0 and s["rehearsal runs (seed, tracking RMS [rad])"] == []
    assert designed.to_dict()["settings"]["cond(Y) executed / designed, N and all samples"] == \
        s["cond(Y) executed / designed, N and all samples"]


@pytest.mark.slow
def test_rehearsals_refine_the_reference():
    from spaceid.studies._tracking import execute_excitation

    traj = load_trajectory("paper-table2")
    settings = TwinSettings().without_effects()
    phases, record = execute_excitation(traj, settings, load_model("cepheus-rw"), feedforward=False, rehearsals=3,
                                        wheel_speed=170.0, seed=5)  # fmt: skip
    runs = record["rehearsal runs (seed, tracking RMS [rad])"]
    assert [r["seed"] for r in runs] == [8, 9, 10]  # seed + 3 + k, each recorded
    worst = [max(r["tracking RMS [rad]"].values()) for r in runs] + [max(record["tracking RMS, encoders vs design "
                                                                             "[rad]"].values())]  # fmt: skip
    assert all(b < 0.9 * a for a, b in zip(worst, worst[1:])) and worst[-1] < 0.6 * worst[0], worst
    assert [p.meta["seed"] for p in phases] == [5, 6]  # spin-up, excitation


def test_rehearsals_option_is_checked():
    with pytest.raises(SpaceidError, match="`rehearsals`: -1"):
        run_experiment(trajectory="paper-table2", rehearsals=-1)


def test_cli_parses_the_execution_options(tmp_path, monkeypatch):
    import spaceid.studies

    seen = {}

    def fake(**kwargs):
        seen.update(kwargs)
        raise SpaceidError("stop here")

    monkeypatch.setattr(spaceid.studies, "run_experiment", fake)
    out = str(tmp_path / "x")
    options = ["--trajectory", "paper-table2", "--no-feedforward", "--rehearsals", "3", "--out", out]
    assert main(["experiment", *options]) == 2
    assert seen["feedforward"] is False and seen["rehearsals"] == 3
    assert main(["experiment", "--trajectory", "paper-table2", "--out", out]) == 2
    assert seen["feedforward"] is True and seen["rehearsals"] == 0
    assert main(["experiment", "--rehearsals", "-1", "--out", out]) == 2
    assert seen["drift"] is None  # the experiment's default: drift terms while the table's friction acts
    assert main(["experiment", "--drift", "none", "--out", out]) == 2 and seen["drift"] == ()
    assert main(["experiment", "--drift", "coulomb", "--out", out]) == 2 and seen["drift"] == ("coulomb",)


def test_default_drift_terms_follow_the_table_friction():
    from spaceid.studies._experiment import EXPERIMENT_DRIFT, _experiment_drift

    assert EXPERIMENT_DRIFT and _experiment_drift(None, TwinSettings()) == EXPERIMENT_DRIFT
    assert _experiment_drift(None, TwinSettings().without_effects()) == ()  # --ideal: unchanged, no drift terms
    assert _experiment_drift((), TwinSettings()) == () and _experiment_drift(["torque"], TwinSettings()) == ("torque",)


@pytest.mark.slow
def test_realistic_experiment_error_bars_cover_the_errors_with_drift():
    """The realistic twin (air-bearing friction on): with the friction modelled as a drift term (the
    experiment's default there) the standard errors cover the actual errors (the code before drift
    terms gave |z| up to 16). Seeds 7 and 12 are those of the 20-seed benchmark
    (benchmarks/bench_experiment.py) where the Newey-West error bars of the differentiated rates fell
    shortest: |z| up to 3.6 and 11 of 16 within two standard errors; with the angle noise propagated
    through the differentiator every |z| is below 2.4 and 15 of 16 are within two (seed 0: all)."""
    z = []
    for seed in (0, 7, 12):
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            res = run_experiment(seed=seed)
        free = res.ident_all.std > 0
        z.append((res.ident_all.values[free] - res.true[free]) / res.ident_all.std[free])
        assert res.ident_all.drift[0]["name"] == "viscous" and res.ident_all.drift[0]["value"] > 0
        assert "propagated" in res.ident_all.diagnostics.covariance
    z = np.abs(np.concatenate(z))
    assert z.max() < 3.0 and np.mean(z <= 2) >= 0.9, z
