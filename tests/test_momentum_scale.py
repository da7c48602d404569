"""The momentum scale: errors and standard deviations as the momentum they cause over a log, so that
near-zero parameters do not dominate; in RESULT.json, the tables, the design's summary and a
parameter figure of fixed size at 150 parameters."""

import json

import numpy as np
import pytest
from rich.console import Console

import spaceid
from spaceid._figure_style import RANKED_SIZE
from spaceid.dynamics import minimal_parameters
from spaceid.estimation import (
    LARGE_SHARE,
    Identification,
    MomentumScale,
    log_momentum_scale,
    momentum_scale,
)
from spaceid.motion import FourierTrajectory, bound_summary, simulate
from spaceid.studies import parameter_table, plot_parameters


@pytest.fixture(scope="module")
def satellite():
    model = spaceid.load_model("satellite-7dof")
    param = minimal_parameters(model)
    rng = np.random.default_rng(3)
    shape = (model.n_joints, 3)
    traj = FourierTrajectory(model.joints, 10.0, rng.uniform(-0.3, 0.3, shape), rng.uniform(-0.3, 0.3, shape))
    log = simulate(param, param.true_values, traj, np.linspace(0, 10, 201), [0.1, 0.0, 0.0])
    return param, log


def test_scale_is_the_momentum_an_error_causes(satellite):
    """Constructed: the scaled value of an error e in pi_k is RMS |h(e unit_k)| / H, the momentum it
    alone causes (from param.momentum, not the regressor's columns); H the root-sum-square of the
    nominal contributions; a single nominal parameter has share 1; the scale does not change when
    every rate doubles (momentum and H double alike)."""
    param, log = satellite
    scale = log_momentum_scale(param, log)
    pi0 = param.true_values
    caused = []
    for k in range(param.n_params):
        unit = np.zeros(param.n_params)
        unit[k] = 1.0
        h = param.momentum(log.q, log.qd, log.base_w, pi=unit)
        caused.append(np.sqrt(np.mean(np.sum(h**2, axis=-1))))
    caused = np.array(caused)
    total = np.sqrt(np.sum((caused * pi0) ** 2))
    np.testing.assert_allclose(scale.momentum, total, rtol=1e-10)
    np.testing.assert_allclose(scale.scaled(np.full(param.n_params, 0.5)), 0.5 * caused / total, rtol=1e-10)
    np.testing.assert_allclose(scale.share, caused * np.abs(pi0) / total, rtol=1e-10)
    one = np.zeros(param.n_params)
    one[4] = 2.0
    single = momentum_scale(param, log.q, log.qd, log.base_w, one)
    assert single.share[4] == pytest.approx(1.0) and single.scaled(one)[4] == pytest.approx(1.0)
    doubled = momentum_scale(param, log.q, 2 * log.qd, 2 * log.base_w)
    np.testing.assert_allclose(doubled.per_unit, scale.per_unit, rtol=1e-10)


def test_near_zero_parameters_do_not_dominate(satellite):
    """A parameter whose nominal value is 1e-8 of the largest has a relative std ~1e8 times larger
    than its scaled one; it is not large, and the design summary names the worst scaled std and the
    worst relative std among the large parameters only."""
    param, log = satellite
    scale = log_momentum_scale(param, log)
    std = 1e-3 * np.ones(param.n_params)
    small = int(np.argmin(np.abs(param.true_values)))
    relative = std / np.abs(param.true_values)
    assert relative[small] > 1e3 * relative.min() and not scale.large[small]
    assert np.all(scale.scaled(std) < 1)  # a 1e-3 std moves the momentum by far less than its scale
    names = param.names
    meta = {"crb_scaled_std": dict(zip(names, scale.scaled(std).tolist())), "momentum_scale": scale.to_dict(),
            "crb_relative_std": dict(zip(names, relative.tolist()))}
    line = bound_summary(meta)
    worst = names[int(np.argmax(scale.scaled(std)))]
    top = max((n for n, big in zip(names, scale.large) if big), key=lambda n: meta["crb_relative_std"][n])
    assert f"({worst});" in line and f"of the {int(scale.large.sum())} large parameters" in line
    assert line.endswith(f"({top})") and names[small] not in line.split(";")[1]
    assert bound_summary({"crb_relative_std": meta["crb_relative_std"]}) is None  # no scale: nothing to say


def _identification(param, values, std, scale):
    k = param.n_params
    return Identification(param.names, param.definitions, values, std, np.diag(std**2), 100.0, np.ones(k), 1e-6, 200,
                          "ml", np.array([0.1, 0, 0]), param.model.name, param.model.planar, units=param.units,
                          scale=scale)  # fmt: skip


def test_result_json_carries_the_scale_and_old_files_load():
    model = spaceid.load_model("cepheus")
    param = minimal_parameters(model)
    traj = spaceid.load_trajectory("paper-table2", joints=model.joints)
    log = simulate(param, param.true_values, traj, spaceid.sample_times(traj.duration, 60), [0, 0, 0.4934])
    result = spaceid.identify(param, log, [0, 0, 0.4934], estimator="ols")
    expected = log_momentum_scale(param, log)
    np.testing.assert_array_equal(result.scale.per_unit, expected.per_unit)
    data = json.loads(json.dumps(result.to_dict()))
    assert data["momentum_scale"]["momentum"] == pytest.approx(expected.momentum)
    assert [p["scaled_std"] for p in data["parameters"]] == pytest.approx(result.std * expected.per_unit)
    back = Identification.from_dict(data)
    np.testing.assert_array_equal(back.scale.share, expected.share)
    del data["momentum_scale"]
    for p in data["parameters"]:
        del p["scaled_std"]
    old = Identification.from_dict(data)  # a file written before the scale
    assert old.scale is None and old.scaled_std is None and "momentum_scale" not in old.to_dict()


def test_table_shows_relative_errors_of_large_parameters_only(satellite):
    param, log = satellite
    scale = log_momentum_scale(param, log)
    std = 1e-3 * np.abs(param.true_values).max() * np.ones(param.n_params)
    ident = _identification(param, param.true_values + std, std, scale)
    console = Console(record=True, width=80)
    console.print(parameter_table(ident, true=param.true_values))
    lines = console.export_text().splitlines()
    assert max(map(len, lines)) <= 80 and not any("…" in line for line in lines)
    rows = {line.split()[1]: line for line in lines if line.startswith("│ pi")}
    assert all((" - " in rows[n]) != big for n, big in zip(param.names, scale.large))
    assert "err%H" in lines[2] and f"{100 * LARGE_SHARE:g} %" in " ".join(" ".join(lines).split())


@pytest.mark.slow  # fast representative: test_report.py::test_parameter_figure_is_a_png
def test_parameter_figure_at_150_parameters_keeps_its_size(satellite, tmp_path):
    """153 parameters: a ranked figure of RANKED_SIZE (1200 x 930 pixels), with and without the truth,
    with and without a scale (an old result); 8 parameters keep one tick each."""
    from PIL import Image

    param, log = satellite
    scale = log_momentum_scale(param, log)
    std = 1e-3 * np.ones(param.n_params)
    rng = np.random.default_rng(0)
    ident = _identification(param, param.true_values + std * rng.standard_normal(param.n_params), std, scale)
    for name, result, true in (("truth", ident, param.true_values), ("none", ident, None),
                               ("old", _identification(param, ident.values, std, None), param.true_values)):
        fig = plot_parameters(result, tmp_path / f"{name}.png", true=true)
        assert fig.get_size_inches()[0] == RANKED_SIZE[0]
        width, height = Image.open(tmp_path / f"{name}.png").size
        assert width == 1200 and height <= 930
    labels = [t.get_text() for t in fig.axes[0].texts]
    assert any(t.startswith("worst") for t in labels)
    small = minimal_parameters(spaceid.load_model("cepheus"))
    fig = plot_parameters(_identification(small, small.true_values, np.full(8, 1e-6), None), true=small.true_values)
    assert len(fig.axes[0].get_xticks()) == 8


def test_momentum_scale_record_round_trip():
    scale = MomentumScale(np.array([1.0, 2.0]), 3.0, np.array([0.5, 0.001]))
    back = MomentumScale.from_dict(json.loads(json.dumps(scale.to_dict())))
    assert back.momentum == 3.0 and back.per_unit.tolist() == [1.0, 2.0] and back.share.tolist() == [0.5, 0.001]
    assert scale.large.tolist() == [True, False]
