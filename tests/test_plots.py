"""Results that draw themselves: every record's ``.plot()`` and every ``plot_*`` return the Figure they
drew, draw on the axes or into the (sub)figure they are given, and write a file only when given a path."""

import warnings

import matplotlib as mpl
import numpy as np
import pytest
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure

import spaceid
from spaceid.dynamics import minimal_parameters
from spaceid.estimation import Noise, identify
from spaceid.identified import PayloadEstimate
from spaceid.identified._payload import PLANAR_NAMES
from spaceid.motion import add_noise, load_trajectory, simulate
from spaceid.studies import (
    plot_montecarlo,
    plot_parameters,
    plot_payload,
    plot_singular_values,
    plot_trajectory,
    plot_validation,
    run_montecarlo,
    validate,
)

H = np.array([0.0, 0.0, 0.4934])


@pytest.fixture(autouse=True)
def _agg():
    with mpl.rc_context({"backend": "Agg"}):
        yield


@pytest.fixture(scope="module")
def fitted():
    param = minimal_parameters(spaceid.load_model("cepheus"))
    traj = load_trajectory("paper-table2")
    clean = simulate(param, param.true_values, lambda t: traj.evaluate(t)[:2], np.linspace(0, 5, 101), H)
    log = add_noise(clean, angle=1e-4, rate=1e-4, seed=1)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # validation on the fitting log
        ident = identify(param, log, H)
        return param, log, ident, validate(ident, log, momentum=H)


@pytest.fixture(scope="module")
def payload():
    std = np.array([0.01, 0.002, 0.003, 1e-5])
    return PayloadEstimate("link2", PLANAR_NAMES, np.array([0.49, 0.061, 0.011, 7.9e-4]), std, np.diag(std**2),
                           np.zeros(10), ("cz",), np.zeros(3), (), {})


def _drawn(ax) -> int:
    """Artists drawn on ``ax``: lines, collections, patches, containers."""
    return len(ax.lines) + len(ax.collections) + len(ax.containers) + len(ax.patches)


def _axes_with_art(fig):
    return [ax for ax in fig.axes if _drawn(ax)]


def _user_axes():
    fig = Figure(layout="constrained")
    FigureCanvasAgg(fig)
    return fig, fig.subplots()


def test_identification_plots_itself(fitted, tmp_path):
    param, _, ident, _ = fitted
    fig = ident.plot()
    assert isinstance(fig, Figure) and len(fig.axes) == 1 and _drawn(fig.axes[0]) >= 2
    assert fig.legends and "ML estimates of the 8 minimal parameters" in fig.axes[0].get_title(loc="left")
    sv = ident.plot(kind="singular_values")
    assert len(sv.axes) == 1 and len(sv.axes[0].lines) == 1 and len(sv.axes[0].lines[0].get_xdata()) == 8
    own, ax = _user_axes()
    assert ident.plot(ax=ax, true=param.true_values) is own and own.axes == [ax] and _drawn(ax) >= 2
    assert ax.get_legend() is not None and not own.legends  # the legend on the caller's axes
    with pytest.raises(spaceid.SpaceidError, match="kind 'bars'"):
        ident.plot(kind="bars")
    assert list(tmp_path.iterdir()) == []
    model = spaceid.load_result(_written(ident, tmp_path))  # the controller-ready model draws the same
    assert len(model.plot().axes) == 1


def _written(ident, folder):
    from spaceid.data import write_json

    write_json(folder / "r.json", ident.to_dict())
    return folder / "r.json"


def test_validation_plots_itself(fitted):
    _, log, _, check = fitted
    fig = check.plot(title="held out")
    assert isinstance(fig, Figure) and len(fig.axes) == 4 and len(_axes_with_art(fig)) == 4  # rate and yaw, residuals
    assert fig.get_suptitle() == "held out"
    root = Figure(figsize=(12, 5), layout="constrained")
    left, right = root.subfigures(1, 2)
    assert check.plot(fig=left) is left and len(left.axes) == 4 and not right.axes


def test_montecarlo_result_plots_itself(tmp_path):
    param = minimal_parameters(spaceid.load_model("cepheus"))
    study = run_montecarlo(param, "paper-table2", samples=35, momentum=H, noise=Noise(1e-4, 1e-4, 1e-4, 1e-4),
                           runs=3, estimators=("ols",), seed=1, jobs=1)  # fmt: skip
    fig = study.plot(max_panels=4)
    assert isinstance(fig, Figure) and len(fig.axes) == 5 and len(_axes_with_art(fig)) == 5  # 4 panels and the bars
    into = Figure(layout="constrained")
    assert plot_montecarlo(study, fig=into) is into and len(into.axes) == 9  # 8 parameters and the bars
    assert list(tmp_path.iterdir()) == []
    plot_montecarlo(study, tmp_path / "mc.png")
    assert [p.name for p in tmp_path.iterdir()] == ["mc.png"]


def test_payload_estimate_plots_itself(payload):
    fig = payload.plot()
    assert isinstance(fig, Figure) and len(fig.axes) == 4 and len(_axes_with_art(fig)) == 4
    assert "estimate with one standard error" in fig.get_suptitle()
    assert not any(ax.get_title(loc="right") for ax in fig.axes)  # no truth, no z-scores
    truth = payload.plot(true={"m": 0.5, "cx": 0.06, "cy": 0.01, "Izz": 8e-4})
    assert truth.axes[0].get_title(loc="right") == "z = -1.00" and "against truth" in truth.get_suptitle()
    assert len(truth.axes[0].lines) > len(fig.axes[0].lines)  # the truth's line
    same = payload.plot(true=[0.5, 0.06, 0.01, 8e-4])
    assert [ax.get_title(loc="right") for ax in same.axes] == [ax.get_title(loc="right") for ax in truth.axes]


def test_plot_functions_draw_on_the_axes_given(fitted):
    _, log, ident, check = fitted
    own, ax = _user_axes()
    assert plot_parameters(ident, ax=ax) is own and own.axes == [ax] and _drawn(ax)
    own, ax = _user_axes()
    assert plot_singular_values(ident, ax=ax) is own and len(ax.lines) == 1
    into = Figure(layout="constrained")
    assert plot_validation(log, check.predicted, fig=into) is into and len(into.axes) == 4
    t = np.linspace(0, 5, 101)
    q, qd, qdd = load_trajectory("paper-table2").evaluate(t)
    into = Figure(layout="constrained")
    assert plot_trajectory(t, q, qd, qdd, log.joints, fig=into) is into and len(into.axes) == 6


def test_figures_are_written_only_when_given_a_path(fitted, payload, tmp_path):
    _, log, ident, check = fitted
    rows = [{"name": n, "estimate": v, "std": s, "true": None, "z": None}
            for n, v, s in zip(payload.names, payload.values, payload.std)]
    figures = [plot_parameters(ident), plot_singular_values(ident), plot_validation(log, check.predicted),
               plot_payload(rows, link="link2"), ident.plot(), check.plot(), payload.plot()]
    assert all(isinstance(f, Figure) for f in figures)
    assert list(tmp_path.iterdir()) == []  # nothing written without a path
    fig = plot_parameters(ident, tmp_path / "p.png")
    assert isinstance(fig, Figure) and (tmp_path / "p.png").stat().st_size > 10_000
    own, ax = _user_axes()
    plot_singular_values(ident, tmp_path / "sv.png", ax=ax)  # the caller's figure, written whole
    assert sorted(p.name for p in tmp_path.iterdir()) == ["p.png", "sv.png"]
