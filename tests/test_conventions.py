"""One name, one thing (docs/api/conventions.md): an argument name means one concept across the
public API, renamed keywords keep working for one release with a DeprecationWarning, and
``load_result`` is the same function everywhere."""

import importlib
import inspect
import warnings

import numpy as np
import pytest

import spaceid
from spaceid._deprecation import deprecated_alias
from spaceid.estimation import identify
from spaceid.identified import identified_model, parameterization_of
from spaceid.motion import load_trajectory, simulate
from spaceid.studies import drift_lines, parameter_table, plot_trajectory, predict

PACKAGES = ["spaceid"] + [f"spaceid.{p}" for p in
                          ("models", "data", "dynamics", "estimation", "identified", "motion", "twin", "studies")]
# old name -> the one the public API uses for the concept
RETIRED = {"ident": "result", "folder": "out", "n_jobs": "jobs"}
# (module, function) -> {old keyword: new keyword}, each kept for one release
RENAMED = {
    ("spaceid.studies", "predict"): {"ident": "result"},
    ("spaceid.studies", "validate"): {"ident": "result"},
    ("spaceid.studies", "plot_parameters"): {"ident": "result"},
    ("spaceid.studies", "plot_singular_values"): {"ident": "result"},
    ("spaceid.studies", "parameter_table"): {"ident": "result"},
    ("spaceid.studies", "drift_lines"): {"ident": "result"},
    ("spaceid.studies", "write_markdown_report"): {"ident": "result", "folder": "out"},
    ("spaceid.studies", "run_montecarlo"): {"folder": "out"},
    ("spaceid.studies", "write_montecarlo"): {"folder": "out"},
    ("spaceid.studies", "run_sweep"): {"folder": "out"},
    ("spaceid.studies", "write_sweep"): {"folder": "out"},
    ("spaceid.studies", "write_servicing"): {"folder": "out"},
    ("spaceid.studies", "plot_trajectory"): {"samples": "times"},
    ("spaceid.studies", "plot_tracking"): {"samples": "times"},
    ("spaceid.identified", "identified_model"): {"ident": "result"},
    ("spaceid.identified", "parameterization_of"): {"ident": "result"},
    ("spaceid.motion", "optimize_excitation"): {"n_jobs": "jobs"},
    ("spaceid.motion", "design_excitation"): {"n_jobs": "jobs"},
    ("spaceid.estimation", "monitor"): {"samples": "log"},
    ("spaceid.estimation", "log_chunks"): {"samples": "log"},
}


def _public_functions():
    for package in PACKAGES:
        module = importlib.import_module(package)
        for name in module.__all__:
            obj = getattr(module, name)
            if inspect.isfunction(obj):
                yield f"{package}.{name}", obj


def test_retired_argument_names_are_gone_from_the_public_api():
    found = [f"{name}({arg})" for name, function in _public_functions()
             for arg in inspect.signature(function).parameters if arg in RETIRED]
    assert not found, f"use {RETIRED}: {found}"


def test_renamed_keywords_are_recorded_and_the_new_ones_are_the_arguments():
    for (package, name), renames in RENAMED.items():
        function = getattr(importlib.import_module(package), name)
        assert function.renamed == renames, name
        parameters = inspect.signature(function).parameters
        assert all(new in parameters or "options" in parameters for new in renames.values()), name


@pytest.fixture(scope="module")
def result():
    param = spaceid.minimal_parameters(spaceid.load_model("cepheus"))
    traj = load_trajectory("paper-table2")
    log = simulate(param, param.true_values, lambda t: traj.evaluate(t)[:2], np.linspace(0, 5, 51), [0, 0, 0.4934])
    return identify(param, log, [0, 0, 0.4934], estimator="ols"), log


def test_old_keywords_still_work_with_a_deprecation_warning(result, tmp_path):
    ident, log = result
    with pytest.warns(DeprecationWarning, match=r"parameter_table\(\): `ident` is now called `result`"):
        old = parameter_table(ident=ident)
    assert str(old.renderables[0].title) == str(parameter_table(result=ident).renderables[0].title)
    with pytest.warns(DeprecationWarning, match="`ident` is now called `result`"):
        assert drift_lines(ident=ident) == drift_lines(ident)
    with pytest.warns(DeprecationWarning):
        assert parameterization_of(ident=ident).names == ident.names
    with pytest.warns(DeprecationWarning):
        assert identified_model(ident=ident).joints == log.joints
    with pytest.warns(DeprecationWarning):
        predicted = predict(ident=ident, t=log.t, q=log.q, qd=log.qd)
    np.testing.assert_allclose(predicted.base_w, log.base_w, atol=1e-9)
    t = np.linspace(0, 1, 11)
    q = np.zeros((11, 2))
    with pytest.warns(DeprecationWarning, match="`samples` is now called `times`"):  # drawn, not written: no path
        plot_trajectory(t, q, q, q, ("a", "b"), samples=t[::5])
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        plot_trajectory(t, q, q, q, ("a", "b"), times=t[::5])  # the new name: silent


def test_an_argument_and_its_old_name_together_are_refused():
    @deprecated_alias(old="folder", new="out")
    def write(result, out=None):
        return out

    assert write(1, out="a") == "a" and write(1, "b") == "b"
    with pytest.warns(DeprecationWarning):
        assert write(1, folder="c") == "c"
    with pytest.raises(TypeError, match="`out` and its old name `folder`"):
        write(1, out="a", folder="c")


def test_load_result_is_one_function_everywhere():
    from spaceid.estimation import load_result
    from spaceid.identified import load_identified

    assert spaceid.load_result is load_result and spaceid.load_identified is load_identified
    assert inspect.signature(load_result).return_annotation in ("Identification", spaceid.Identification)
