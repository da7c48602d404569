"""Typed records: every result is a frozen dataclass with a JSON form (``to_dict``), and reads back
from it; RESULT.json files from before ``diagnostics`` still load."""

import copy
import dataclasses
import json
import warnings

import numpy as np
import pytest

import spaceid
from spaceid.data import write_json
from spaceid.dynamics import minimal_parameters
from spaceid.estimation import Diagnostics, DriftTest, Identification, ResidualChecks, identify, load_result
from spaceid.motion import add_noise, load_trajectory, simulate

H = np.array([0.0, 0.0, 0.4934])


@pytest.fixture(scope="module")
def cepheus():
    param = minimal_parameters(spaceid.load_model("cepheus"))
    traj = load_trajectory("paper-table2")
    clean = simulate(param, param.true_values, lambda t: traj.evaluate(t)[:2], np.linspace(0, 5, 201), H)
    log = add_noise(clean, angle=1e-4, rate=1e-4, seed=1)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        return param, log, identify(param, log, H)


def _same(a: Identification, b: Identification):
    for name in ("values", "std", "cov", "momentum", "singular_values"):
        np.testing.assert_array_equal(getattr(a, name), getattr(b, name))
    assert a.diagnostics == b.diagnostics and a.settings == b.settings


def _old_format(data: dict) -> dict:
    """A RESULT.json as written before ``diagnostics``: its keys and ``momentum_std`` inside ``settings``
    (``covariance_method`` did not exist; ``drift_correlation`` was written only when there was one)."""
    old = copy.deepcopy(data)
    diagnostics = old.pop("diagnostics")
    diagnostics.pop("covariance_method")
    if diagnostics["drift_correlation"] is None:
        del diagnostics["drift_correlation"]
    old["settings"] |= diagnostics | {"momentum_std": old.pop("momentum_std")}
    return old


def test_diagnostics_are_apart_from_the_settings(cepheus):
    _, log, ident = cepheus
    d = ident.diagnostics
    assert isinstance(d, Diagnostics) and isinstance(d.residual_checks, ResidualChecks)
    assert isinstance(d.drift_test, DriftTest) and d.drift_test.run and not d.drift_test.drift
    assert 0.1 < d.chi2_dof < 10 and d.covariance_method in spaceid.estimation.COVARIANCE_METHODS
    assert d.plausibility == "no inertia-like parameter negative" and d.estimator_info["converged"]
    assert not set(Diagnostics.KEYS) & set(ident.settings)  # provenance only
    assert {"parameterization", "log", "log_fingerprint", "anchors", "noise"} <= set(ident.settings)
    np.testing.assert_array_equal(ident.momentum_std, np.zeros(3))
    with pytest.raises(AttributeError):
        d.chi2_dof = 1.0  # frozen


def test_result_json_round_trip(cepheus, tmp_path):
    _, _, ident = cepheus
    data = ident.to_dict()
    assert set(data["diagnostics"]) == set(Diagnostics.KEYS) and data["momentum_std"] == [0.0, 0.0, 0.0]
    write_json(tmp_path / "r.json", data)
    back = load_result(tmp_path / "r.json")
    _same(back, ident)
    assert json.loads(json.dumps(back.to_dict())) == json.loads(json.dumps(data))


def test_an_older_result_json_still_loads(cepheus, tmp_path):
    """Diagnostics inside ``settings`` (as the code before them wrote): moved over on reading."""
    _, _, ident = cepheus
    old = _old_format(ident.to_dict())
    assert "diagnostics" not in old and "chi2_dof" in old["settings"]
    write_json(tmp_path / "old.json", old)
    back = load_result(tmp_path / "old.json")
    assert back.diagnostics == dataclasses.replace(ident.diagnostics, covariance_method=None)
    assert back.settings == ident.settings
    np.testing.assert_array_equal(back.momentum_std, ident.momentum_std)
    model = spaceid.load_result(tmp_path / "old.json")  # the controller-ready model too
    assert model.diagnostics.chi2_dof == ident.diagnostics.chi2_dof


def test_diagnostics_of_skipped_tests_and_the_angles_estimator(cepheus):
    param, log, _ = cepheus
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        drift = identify(param, log, H, drift=("viscous",), estimator="wls")
    assert drift.diagnostics.drift_test == DriftTest(False, "drift terms modelled: viscous")
    assert drift.diagnostics.drift_test.to_dict() == {"run": False, "reason": "drift terms modelled: viscous"}
    back = Identification.from_dict(json.loads(json.dumps(drift.to_dict())))
    assert back.diagnostics == drift.diagnostics
    assert Diagnostics.from_dict({}) == Diagnostics()  # a file with neither: the defaults


def test_comparison_record(cepheus):
    from spaceid.estimation import Comparison, compare

    param, log, ident = cepheus
    moved = dataclasses.replace(ident, values=ident.values + np.where(np.arange(len(ident.values)) == 2, 10 * ident.std,
                                                                      0.0))
    diff = compare(ident, moved)
    assert isinstance(diff, Comparison) and diff.names == ident.names
    assert diff.changed() == (ident.names[2],) and diff.z[2] == pytest.approx(10 / np.sqrt(2))
    rows = json.loads(json.dumps(diff.to_dict()))["parameters"]  # spaceid compare --json
    assert [r["name"] for r in rows] == list(ident.names) and rows[2]["change"] == pytest.approx(10 * ident.std[2])
    assert set(rows[0]) == {"name", "definition", "before", "after", "change", "relative_change", "z"}


def test_identifiability_record():
    from spaceid.dynamics import Identifiability, identifiability

    report = identifiability(minimal_parameters(spaceid.load_model("cepheus")))
    assert isinstance(report, Identifiability) and report.determines_dynamics
    data = json.loads(json.dumps(report.to_dict()))
    assert data["no_effect"] == list(report.no_effect) and data["determines_dynamics"] is True
    assert set(data) == {"no_effect", "individually_identifiable", "in_combinations", "determines_dynamics",
                         "energy_residual"}


def test_validation_record(cepheus):
    from spaceid.studies import Validation, validate

    param, log, ident = cepheus
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # the fitting log
        check = validate(ident, log, momentum=H)
    assert isinstance(check, Validation) and check.measured is log and check.predicted.n_samples == log.n_samples
    data = json.loads(json.dumps(check.to_dict()))
    assert data["metrics"] == pytest.approx(check.metrics) and data["n_samples"] == log.n_samples
    assert data["planar"] is True and data["joints"] == list(log.joints) and data["end"] == pytest.approx(5.0)
