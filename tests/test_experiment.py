"""The Cepheus experiment on the twin, end to end through a ROS bag."""

import numpy as np
import pytest

from spaceid import SpaceidError, load_model
from spaceid.cli import main
from spaceid.motion import load_trajectory
from spaceid.studies import run_experiment
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
    # the identified model re-simulates the measured base rate to a fraction of a percent
    assert res.metrics["base_w_nrms"] < 0.01


def test_report_folder(ideal):
    names = {p.name for p in ideal.folder.iterdir()}
    assert {"run.mcap", "log.csv", "truth.csv", "result.json", "result_all_samples.json", "experiment.json",
            "validation.png", "parameters.png", "tracking.png", "report.md"} <= names  # fmt: skip
    text = (ideal.folder / "report.md").read_text()
    assert "Cepheus experiment" in text and "excitation window" in text
    assert "cond(Y) designed / executed, N samples" in text and "tracking RMS, encoders vs design" in text
    assert "left\\_shoulder 0.0" in text and "(tracking.png)" in text


def test_cli_rejects_bad_options(tmp_path):
    assert main(["experiment", "--samples", "5", "--out", str(tmp_path / "x")]) == 2
    assert not (tmp_path / "x").exists()


# --- the excitation as executed: feed-forward and rehearsals ---------------------------------------


@pytest.fixture(scope="module")
def designed():
    """The default experiment on the designed excitation (feed-forward from the prior model)."""
    return run_experiment(seed=0)


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
    published = run_experiment(trajectory=designed.trajectory, seed=0, feedforward=False)
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
    with pytest.raises(SpaceidError, match="--rehearsals -1"):
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
