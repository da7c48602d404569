"""The Cepheus experiment on the twin, end to end through a ROS bag."""

import numpy as np
import pytest

from spaceid.cli import main
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
            "validation.png", "parameters.png", "report.md"} <= names  # fmt: skip
    text = (ideal.folder / "report.md").read_text()
    assert "Cepheus experiment" in text and "excitation window" in text


def test_cli_rejects_bad_options(tmp_path):
    assert main(["experiment", "--samples", "5", "--out", str(tmp_path / "x")]) == 2
    assert not (tmp_path / "x").exists()
