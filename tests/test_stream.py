"""Streaming identification (``identify(..., chunk=N)``): the same result as in memory, a chunk at a time."""

import dataclasses
import re
import warnings

import numpy as np
import pytest

import spaceid
from spaceid import SpaceidError, add_noise
from spaceid.data import Log, differentiate_log
from spaceid.dynamics import base_rate, minimal_parameters
from spaceid.estimation import Noise, identify
from spaceid.estimation._equations import Equations
from spaceid.motion import load_trajectory, simulate

from conftest import random_states, random_tree

NOISE = Noise(angle=1e-3, rate=1e-3, base_rate=1e-3)


@pytest.fixture(scope="module")
def planar():
    param = minimal_parameters(spaceid.load_model("cepheus"))
    trajectory = load_trajectory("paper-table2")
    h = np.array([0.0, 0.0, 0.4934])
    log = simulate(param, param.true_values, lambda t: trajectory.evaluate(t)[:2], np.linspace(0, 5, 1201), h)
    return param, log, h


@pytest.fixture(scope="module")
def spatial():
    model = random_tree(np.random.default_rng(4), [0, 1, 1], planar=False)
    param = minimal_parameters(model)
    q, qd, _ = random_states(np.random.default_rng(5), model, 1500)
    h = np.array([0.3, -0.2, 0.5])
    w = base_rate(param, param.true_values, q, qd, h)
    log = Log(np.arange(len(q)) * 0.01, model.joints, q, qd, np.tile([1.0, 0, 0, 0], (len(q), 1)), w, False)
    return param, log, h


def _both(param, log, h, estimator, noise, chunk):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # the same warnings either way: compared through the settings
        return (identify(param, log, h, estimator=estimator, noise=noise),
                identify(param, log, h, estimator=estimator, noise=noise, chunk=chunk))


SLOW = pytest.mark.slow  # seconds each: the spatial noise model's Jacobian


@pytest.mark.parametrize("system, estimator", [("planar", "ols"), ("planar", "wls"), ("planar", "iv"), ("planar", "ml"),
                                               ("spatial", "ols"), pytest.param("spatial", "wls", marks=SLOW),
                                               pytest.param("spatial", "iv", marks=SLOW), ("spatial", "ml")])
@pytest.mark.parametrize("noisy", [False, True])
def test_streamed_equals_in_memory(request, system, estimator, noisy):
    """Every streamed estimator, planar and spatial, noise-free and noisy, in chunks that do not
    divide the log: the estimate to 1e-12 of the largest parameter (the truth to round-off when
    noise-free), the covariance to the accuracy of the in-memory one (eps cond^2: 1e-9) and the
    same covariance choice and residual checks."""
    param, log, h = request.getfixturevalue(system)
    log = add_noise(log, angle=1e-3, rate=1e-3, seed=3) if noisy else log
    memory, streamed = _both(param, log, h, estimator, NOISE, chunk=337)
    size = np.abs(memory.values).max()
    assert np.abs(streamed.values - memory.values).max() <= 1e-12 * size
    if not noisy:
        assert np.abs(streamed.values - param.true_values).max() <= 1e-11 * size
        return  # the covariance of round-off residuals is round-off
    assert streamed.std == pytest.approx(memory.std, rel=1e-9)
    for key in ("covariance_method", "covariance", "covariance_from_residuals"):
        assert getattr(streamed.diagnostics, key) == getattr(memory.diagnostics, key)
    assert streamed.residual_rms == pytest.approx(memory.residual_rms, rel=1e-9)
    assert streamed.diagnostics.estimator_info["chunk"] == 337
    if estimator == "ml":
        assert streamed.diagnostics.estimator_info["iterations"] == memory.diagnostics.estimator_info["iterations"]
        assert streamed.diagnostics.estimator_info["converged"] and memory.diagnostics.estimator_info["converged"]
    if estimator != "ols":
        assert streamed.diagnostics.chi2_dof == pytest.approx(memory.diagnostics.chi2_dof, rel=1e-9)
    _same_drift_test(streamed, memory)


@pytest.fixture(scope="module")
def spatial_motion():
    """A smooth spatial motion (the spatial model on sinusoidal joint paths), 6 s at 100 Hz."""
    model = random_tree(np.random.default_rng(4), [0, 1, 1], planar=False)
    param = minimal_parameters(model)
    amp, freq = np.array([0.8, 0.6, 0.7]), np.array([1.1, 1.7, 2.3])
    h = np.array([0.3, -0.2, 0.5])
    motion = lambda t: (amp * np.sin(np.outer(t, freq)), amp * freq * np.cos(np.outer(t, freq)))  # noqa: E731
    return param, simulate(param, param.true_values, motion, np.arange(0, 6, 0.01), h), h


def _differentiated(system, planar, spatial_motion):
    """The log with rates differentiated from noisy angles: planar, joints and base yaw (window 201); spatial,
    the joints only (window 41; the base rate measured: a differentiated quaternion is not propagated)."""
    if system == "planar":
        param, log, h = planar
        return param, differentiate_log(add_noise(log, angle=1e-4, seed=1), window=201, order=5), h
    param, log, h = spatial_motion
    noisy = add_noise(log, angle=1e-4, rate=1e-3, seed=1)
    joints = differentiate_log(noisy, window=41, order=3)
    meta = dict(noisy.meta, differentiation={"joints": joints.meta["differentiation"]["joints"]})
    return param, dataclasses.replace(noisy, q=joints.q, qd=joints.qd, meta=meta), h


def _same_drift_test(streamed, memory):
    """The drift test's records agree: the Wald statistic, the fitted drift (of its largest entry) and its size to
    1e-7, the p-value's
    logarithm to 1e-6 (see :func:`test_streamed_differentiated_rates_equal_in_memory`), the residuals' whiteness
    figures to 1e-10."""
    got, want = streamed.diagnostics.drift_test.to_dict(), memory.diagnostics.drift_test.to_dict()
    assert got["run"] and want["run"] and got.keys() == want.keys()
    for key, value in want.items():
        if key in ("wald", "relative_drift"):
            assert got[key] == pytest.approx(value, rel=1e-7)
        elif key == "p_value":  # far in the tail its relative change is the Wald's times the Wald
            assert np.log(got[key]) == pytest.approx(np.log(value), rel=1e-6, abs=1e-6)
        elif key == "confounded":  # a share from the eigenvectors of Gram matrices summed in another order
            assert got[key] == pytest.approx(value, rel=1e-6, abs=1e-9)
        elif key in ("trend", "gyro_bias", "errors_in_variables"):  # of the largest entry, as the covariance: a
            trend = np.array(list(value.values()) if key == "trend" else value)  # small entry carries the others' rounding
            other = np.array(list(got[key].values()) if key == "trend" else got[key])
            assert np.abs(other - trend).max() <= 1e-7 * np.abs(trend).max()
        elif isinstance(value, float):
            assert got[key] == pytest.approx(value, rel=1e-10, abs=1e-14)
        else:
            assert got[key] == value


# fast: one (the whitened spatial fit streamed in the fast subset: test_streamed_equals_in_memory)
@pytest.mark.parametrize("system, estimator", [
    ("planar", "ols"),
    *(pytest.param(system, estimator, marks=SLOW) for system, estimator in
      [("planar", "wls"), ("planar", "iv"), ("planar", "ml"), ("spatial", "ols"), ("spatial", "wls"),
       ("spatial", "iv"), ("spatial", "ml")])])
def test_streamed_differentiated_rates_equal_in_memory(system, estimator, planar, spatial_motion):
    """Rates differentiated from noisy angles, levels estimated from the log, in chunks of 29 samples (shorter
    than the filters' windows, not dividing the log): the angle noise propagated through the filters, whose
    windows straddle the chunks' ends, and its larger-of with Newey-West over the half window (longer than a
    chunk) give the in-memory covariance, and the drift test its record.

    Achieved agreement: the estimate to 20 eps cond (spatial ml 12.8: the signal Jacobian's products round the
    samples at a chunk's end otherwise than mid-chunk, and the iteration carries it; 4.7 before its kernels were
    compiled), the covariance to 10 eps cond^2 of its largest entry (cond the scaled condition number: 320 planar,
    9,700 spatial), the drift test's statistic and fitted drift to 1e-7 (measured: 7e-9 at most). Both sides invert Gram matrices summed in other orders (by chunks, by blocks of
    rows), which leaves eps cond^2 in the inverses, and the drift test's refit is the Gram matrix's solution for
    its correction to the estimate, eps cond^2 of that correction: the in-memory figures themselves move as much
    when every factor is taken by QR instead (covariance 3e-12 to 2e-11 planar, 7e-9 spatial; Wald 1e-9 to 4e-9)."""
    param, log, h = _differentiated(system, planar, spatial_motion)
    memory, streamed = _both(param, log, h, estimator, None, chunk=29)
    assert log.n_samples % 29 and "propagated" in memory.diagnostics.covariance
    larger = re.search(r"in (\d+) of (\d+) directions", memory.diagnostics.covariance)
    assert larger is None or larger[1] != larger[2]  # the propagated covariance counts somewhere
    assert streamed.diagnostics.covariance == memory.diagnostics.covariance
    eps = np.finfo(float).eps
    cond = memory.diagnostics.condition_number_scaled
    assert np.abs(streamed.values - memory.values).max() <= 20 * eps * cond * np.abs(memory.values).max()
    assert np.abs(streamed.cov - memory.cov).max() <= 10 * eps * cond**2 * np.abs(memory.cov).max()
    _same_drift_test(streamed, memory)


@pytest.mark.parametrize("estimator", ["ols", "ml"])
def test_the_regressor_is_never_built_for_more_than_a_chunk(spatial, monkeypatch, estimator):
    """Neither the equations nor their linearisation, whose columns are the regressor's."""
    param, log, h = spatial
    sizes = []
    for name in ("phi", "linearized"):
        built = getattr(Equations, name)
        monkeypatch.setattr(Equations, name, lambda self, x, *a, _built=built, **k: sizes.append(len(x))
                            or _built(self, x, *a, **k))  # fmt: skip
    noisy = add_noise(log, angle=1e-3, rate=1e-3, seed=2)
    streamed = identify(param, noisy, h, estimator=estimator, noise=NOISE, chunk=200)
    assert sizes and max(sizes) <= 200 and streamed.estimator == estimator
    sizes.clear()
    identify(param, noisy, h, estimator=estimator, noise=NOISE)
    assert max(sizes) == log.n_samples  # in memory: all at once


@pytest.mark.parametrize("estimator, chunk, match", [("angles", 100, "in memory only"), ("tls", 100, "in memory only"),
                                                      ("ols", 0, "positive whole number"),
                                                      ("ols", 2.5, "positive whole number")])
def test_bad_chunk_is_refused(spatial, estimator, chunk, match):
    param, log, h = spatial
    with pytest.raises(SpaceidError, match=f"`chunk`: .*{match}"):
        identify(param, log, h, estimator=estimator, noise=NOISE, chunk=chunk)


def test_cli_identify_streamed(tmp_path, capsys):
    """``spaceid identify --chunk`` (the default estimator, ml) writes the in-memory result (to round-off); a bad
    chunk is a one-line error."""
    import json

    from spaceid.cli import main

    log = tmp_path / "log.csv"
    assert main(["simulate", "cepheus", "--trajectory", "paper-table2", "--momentum", "0.4934", "--samples", "300",
                 "--noise-angle", "1e-4", "--noise-rate", "1e-4", "-o", str(log)]) == 0  # fmt: skip
    results = []
    for extra in ([], ["--chunk", "64"]):
        out = tmp_path / f"r{len(extra)}.json"
        assert main(["identify", "cepheus", str(log), "--momentum", "0.4934", "-o", str(out), *extra]) == 0
        results.append(json.loads(out.read_text()))
    values = [np.array([p["value"] for p in r["parameters"]]) for r in results]
    assert np.abs(values[1] - values[0]).max() <= 1e-12 * np.abs(values[0]).max()
    capsys.readouterr()
    assert main(["identify", "cepheus", str(log), "--momentum", "0.4934", "--estimator", "tls", "--chunk", "64", "-o",
                 str(tmp_path / "x.json")]) == 2  # fmt: skip
    assert "error: --chunk: estimator 'tls' runs in memory only" in capsys.readouterr().err
