"""The paper's simulation study: the demo's numbers and its report."""

import json

import numpy as np
import pytest

from spaceid.cli import main
from spaceid.studies import PAPER_TABLE3, run_demo


def test_paper_trajectory_noise_free():
    res = run_demo(trajectory="paper-table2")
    rel = np.abs(res.ident.values / res.true - 1) * 100
    assert rel.max() < 1e-6  # percent
    assert res.ident.condition_number == pytest.approx(360, rel=0.01)  # docs/theory/excitation.md
    # our exact truth against the paper's rounded Table 3 'true values' (docs/theory/cepheus.md: within 2.2 %)
    assert np.abs(res.true / PAPER_TABLE3["true"] - 1).max() < 0.025


def test_noise_reproduces_the_papers_error_size():
    """docs/theory/cepheus.md: noise of about 1e-4 on the rates gives errors of the paper's size."""
    a = run_demo(trajectory="paper-table2", noise_angle=1e-4, noise_rate=1e-4, seed=4)
    b = run_demo(trajectory="paper-table2", noise_angle=1e-4, noise_rate=1e-4, seed=4)
    np.testing.assert_array_equal(a.ident.values, b.ident.values)  # seeded
    rel = np.abs(a.ident.values / a.true - 1) * 100
    assert 0.05 < rel.max() < 5 and a.ident.settings["seed"] == 4
    # the errors are consistent with the predicted standard errors
    assert np.all(np.abs(a.ident.values - a.true) < 5 * a.ident.std)


@pytest.mark.slow
def test_designed_demo_writes_report(tmp_path, capsys, monkeypatch):
    from spaceid.dynamics import _regressor
    from spaceid.estimation import cusum_threshold
    from spaceid.models import PRESETS, load_model

    monkeypatch.setenv("SPACEID_CACHE_DIR", str(tmp_path / "cache"))
    _regressor._minimal_cached.cache_clear()
    cusum_threshold.cache_clear()  # as in a fresh process: a threshold an earlier test computed is not remembered
    assert main(["demo", "--seed", "1", "--out", str(tmp_path / "rep"), "--json"]) == 0
    # the install step: every preset's minimal set is cached, so no first command derives one
    _regressor._minimal_cached.cache_clear()
    monkeypatch.setattr(_regressor, "_derive_minimal", lambda *a: pytest.fail("derived although the demo warmed it"))
    monkeypatch.setattr(_regressor, "_no_effect", lambda *a: pytest.fail("formed although the demo warmed it"))
    for name in PRESETS:  # and the parameters without effect on the momentum (the export's)
        param = _regressor.minimal_parameters(load_model(name))
        assert param.n_params
        _regressor.no_effect_parameters(param)  # read from the cache: forming them fails the test
    _regressor._minimal_cached.cache_clear()
    # and the monitor's default threshold for planar and spatial equations (one row, three)
    assert len(list((tmp_path / "cache" / "cusum-threshold").glob("*.npz"))) == 2
    out = json.loads(capsys.readouterr().out)
    assert out["condition_number"] < 37.8  # the design target (best known about 36)
    for p in out["parameters"]:
        assert {"name", "definition", "true", "estimate", "relative_error_percent"} <= set(p)
        assert abs(p["relative_error_percent"]) < 1e-6
    files = {p.name for p in (tmp_path / "rep").iterdir()}
    assert {"report.md", "result.json", "log.csv", "trajectory.json", "validation.png", "parameters.png",
            "singular_values.png", "trajectory.png"} <= files
    report = (tmp_path / "rep" / "report.md").read_text()
    assert "pi8" in report and "![" in report


WARM_CHECK = """
import numpy as np
import spaceid
from spaceid.dynamics import _kernels
from spaceid.dynamics import momentum_jacobian
from spaceid.dynamics._regressor import _random_states
from spaceid.motion import _attitude, simulate
from spaceid.studies import predict, warm_spatial_kernels

kernels = (_kernels._momentum_of_states, _kernels._tangent_columns,
           _attitude.collocation_steps,  # (its stage rate inlined)
           _kernels._contracted_rows, _kernels._joint_jacobian, _kernels._body_features, _kernels._subtree_sums)
assert not any(k.signatures for k in kernels)
warm_spatial_kernels()
warmed = [list(k.signatures) for k in kernels]
# what the commands call: another spatial robot's simulation and prediction, the linearised regressor
param = spaceid.minimal_parameters(spaceid.load_model("satellite-7dof"))
q, qd, w0 = _random_states(param.model, 40, seed=1)
log = simulate(param, param.true_values, lambda t: (np.sin(t)[:, None] * np.ones(7), np.cos(t)[:, None] * np.ones(7)),
               np.linspace(0, 2, 40), np.array([0.5, 0.1, -0.2]), model=param.model)
predict("satellite-7dof", log.t, log.q, log.qd, momentum=np.array([0.5, 0.1, -0.2]))
param.linearized_regressor(q, qd, w0, (qd, q, w0), step=1e-6, primal=False)
# ml's: the weights' derivative along signals sliced out of a wider array (as the equations unpack them), the Jacobian
x = np.hstack([q, qd, w0])
param.contracted_tangent(q, qd, w0, (x[:, :7], x[:, 7:14], x[:, 14:]), x[:, :3], step=1e-6)
momentum_jacobian(param, q, qd, w0, param.true_values)
assert [list(k.signatures) for k in kernels] == warmed and all(len(s) == 1 for s in warmed), warmed
print("ok")
"""


def test_demo_warms_the_spatial_kernels_with_the_signatures_the_commands_use():
    """``warm_spatial_kernels`` (the end of ``spaceid demo``, the install step) runs the kernels only spatial
    robots' commands call (the momentum, the attitude's collocation steps, the linearised regressor, its contracted
    derivative and the momentum's Jacobian),
    each with the one signature that a spatial simulation, prediction and linearisation then use: a fresh
    process compiles nothing more after it (another signature would compile the kernel again, seconds)."""
    import os
    import subprocess
    import sys
    from pathlib import Path

    src = str(Path(__file__).resolve().parents[1] / "src")
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([src, os.environ.get("PYTHONPATH", "")])}
    done = subprocess.run([sys.executable, "-c", WARM_CHECK], env=env, capture_output=True, text=True, timeout=600)
    assert done.returncode == 0 and done.stdout.strip() == "ok", done.stderr[-2000:]
