"""Figures, tables and the Markdown report: valid PNGs, complete tables, clear errors, no leaks."""

import re
import struct
from dataclasses import replace

import matplotlib as mpl
import numpy as np
import pytest
from matplotlib.container import ErrorbarContainer
from rich.console import Console

from spaceid import SpaceidError, load_model
from spaceid.data import Log, yaw_to_quat
from spaceid.dynamics import minimal_parameters
from spaceid.estimation import Identification, Noise
from spaceid.studies import (
    parameter_table,
    plot_montecarlo,
    plot_parameters,
    plot_singular_values,
    plot_tracking,
    plot_trajectory,
    plot_validation,
    run_montecarlo,
    write_markdown_report,
)
from spaceid.studies._figures import (
    _draw_montecarlo,
    draw_parameters,
    draw_singular_values,
    _draw_tracking,
    _draw_trajectory,
    _draw_validation,
)

JOINTS = ("left_shoulder", "left_elbow")
TRUE = np.array([0.007237, 0.131126, 0.004630])
REFERENCE = np.array([0.5162, 0.0432, 0.6634])  # percent, as the paper prints them
OPTIONS = [{}, {"true": TRUE}, {"true": TRUE, "reference": REFERENCE}, {"reference": REFERENCE}]


def _png_size(path):
    """(width, height) from the IHDR chunk; fails unless ``path`` is a PNG."""
    data = path.read_bytes()
    assert data[:8] == b"\x89PNG\r\n\x1a\n", f"{path} is not a PNG"
    assert data[12:16] == b"IHDR"
    return struct.unpack(">II", data[16:24])


def _assert_png(path, min_width=400):
    width, height = _png_size(path)
    assert width > min_width and height > 300, (width, height)
    assert path.stat().st_size > 10_000
    assert [p.name for p in path.parent.iterdir() if p.name.endswith(".tmp")] == []  # written atomically


def _log(planar, *, n=60, bias=0.0, rng=0):
    rng = np.random.default_rng(rng)
    t = np.linspace(0.0, 5.0, n)
    q = np.stack([0.6 * np.sin(1.2 * t), np.sin(2.1 * t + 0.3)], axis=1) + bias * rng.standard_normal((n, 2))
    qd = np.stack([0.72 * np.cos(1.2 * t), 2.1 * np.cos(2.1 * t + 0.3)], axis=1)
    w = np.zeros((n, 3))
    if planar:
        w[:, 2] = 2.8 + 0.2 * np.sin(t) + bias * rng.standard_normal(n)
        quat = yaw_to_quat(np.cumsum(w[:, 2]) * (t[1] - t[0]))
    else:
        w[:] = np.stack([0.1 * np.sin(t), 0.05 * np.cos(2 * t), 0.2 + 0.01 * t], axis=1)
        w += bias * rng.standard_normal((n, 3))
        quat = np.tile([1.0, 0.0, 0.0, 0.0], (n, 1))
    return Log(t, JOINTS, q, qd, quat, w, planar)


@pytest.fixture
def ident():
    values = TRUE * np.array([1.004, 0.9995, 1.007])
    std = np.array([3e-5, 5e-5, 2e-5])
    return Identification(
        names=("pi1", "pi5", "pi8"),
        definitions=(
            "-m_base*(cx_base - x_left_shoulder)*(cx_link1*m_link1 + m_link2*x_left_elbow)/M",
            ("Izz_base + m_base*(m_link1 + m_link2)*(cx_base**2 - 2*cx_base*x_left_shoulder + cy_base**2 "
             "- 2*cy_base*y_left_shoulder + x_left_shoulder**2 + y_left_shoulder**2)/M"),
            "Izz_link2 + cx_link2**2*m_link2*(m_base + m_link1)/M",
        ),
        values=values,
        std=std,
        cov=np.diag(std**2),
        condition_number=372.27,
        singular_values=np.array([57.1, 9.8, 0.153]),
        residual_rms=1.49e-4,
        n_samples=35,
        estimator="ols",
        momentum=np.array([0.0, 0.0, 0.4934]),
        model="cepheus",
        planar=True,
        settings={"parameterization": {"rank_tol": 1e-9}},
    )


# --- figures ----------------------------------------------------------------------------------


def _errorbars(ax, label):
    """``(x, centre, half)`` of the one error-bar series of ``ax`` whose label contains ``label``."""
    (bars,) = [c for c in ax.containers if isinstance(c, ErrorbarContainer) and label in (c.get_label() or "")]
    seg = np.array(bars.lines[2][0].get_segments())  # (n, 2 ends, (x, y))
    return seg[:, 0, 0], seg[:, :, 1].mean(1), np.diff(seg[:, :, 1], axis=1)[:, 0] / 2


def _line(ax, label):
    (line,) = [ln for ln in ax.get_lines() if label in ln.get_label()]
    return line


def _legend_labels(fig):
    return [t.get_text() for legend in fig.legends for t in legend.get_texts()]


def _assert_titled_and_labelled(fig):
    """A figure title, a unit in brackets on every axis label (parameter names and indices are
    categories), and at least one labelled x and y axis."""
    assert fig.get_suptitle() or all(ax.get_title(loc="left") or ax.get_title() for ax in fig.axes)
    ylabels = [ax.get_ylabel() for ax in fig.axes if ax.get_ylabel()]
    xlabels = [ax.get_xlabel() for ax in fig.axes if ax.get_xlabel()]
    assert ylabels and xlabels
    assert all(re.search(r"\[.+\]", y) for y in ylabels), ylabels
    assert all(re.search(r"\[.+\]|parameter|index", x) for x in xlabels), xlabels


@pytest.mark.slow
@pytest.mark.parametrize("planar", [True, False])
def test_validation_figure_is_a_png(tmp_path, planar):
    out = tmp_path / "validation.png"
    fig = plot_validation(_log(planar), _log(planar, bias=1e-3), out, title="Validation")
    assert fig.get_suptitle() == "Validation"
    _assert_png(out, min_width=900)


@pytest.mark.parametrize("planar", [True, pytest.param(False, marks=pytest.mark.slow)])
def test_validation_figure_is_titled_and_labelled(planar):
    fig = _draw_validation(_log(planar), _log(planar, bias=1e-3))
    _assert_titled_and_labelled(fig)
    assert "identified model" in fig.get_suptitle()  # a default title: 'spaceid validate' gives none
    assert _legend_labels(fig) == ["measured", "identified model (predicted)", "residual"]
    assert {ax.get_ylabel().split("[")[1] for ax in fig.axes} == {"rad]", "rad/s]"}
    assert [ax.get_xlabel() for ax in fig.axes if ax.get_xlabel()] == ["time $t$ [s]"] * (2 if planar else 4)
    # no offset text ('+1.7e2' of a spinning wheel's rate) to collide with the panel titles
    assert not any(ax.yaxis.get_major_formatter().get_useOffset() for ax in fig.axes)
    assert _draw_validation(_log(planar), _log(planar), title="Fig. 6").get_suptitle() == "Fig. 6"


def _turning(log, rate):
    """``log`` with its base turned about a tilted axis at ``rate`` [rad/s] (a spatial attitude)."""
    axis = np.array([0.6, 0.0, 0.8])
    half = 0.5 * rate * log.t[:, None]
    return replace(log, base_quat=np.hstack([np.cos(half), np.sin(half) * axis]))


@pytest.mark.parametrize("planar", [True, False])
def test_validation_figure_shows_base_rate_and_attitude_with_residuals(planar):
    """What the model predicts, measured against predicted, the residual below; no joint panels."""
    measured, predicted = _log(planar), _log(planar, bias=1e-3)
    if not planar:
        measured, predicted = _turning(measured, 0.2), _turning(predicted, 0.21)
    fig = _draw_validation(measured, predicted)
    top = [ax for ax in fig.axes if ax.get_title(loc="left").startswith("base")]
    bottom = [ax for ax in fig.axes if ax.get_title(loc="left").startswith("residual")]
    assert len(top) == len(bottom) == len(fig.axes) // 2 == (2 if planar else 4)
    assert not any("left_" in ax.get_title(loc="left") for ax in fig.axes)  # no joint panels
    titles = [ax.get_title(loc="left") for ax in top]
    assert titles[:-1] == (["base angular velocity"] if planar else [f"base angular velocity, {a}" for a in "xyz"])
    assert titles[-1] == ("base attitude: yaw" if planar else "base attitude: rotation angle")
    rate, attitude = top[-2], top[-1]
    np.testing.assert_array_equal(_line(rate, "measured").get_ydata(), measured.base_w[:, 2])
    np.testing.assert_array_equal(_line(rate, "identified model").get_ydata(), predicted.base_w[:, 2])
    residual = predicted.base_w[:, 2] - measured.base_w[:, 2]
    np.testing.assert_allclose(_line(bottom[-2], "residual").get_ydata(), residual)
    if planar:
        np.testing.assert_allclose(_line(attitude, "measured").get_ydata(), measured.base_yaw)
        residual = predicted.base_yaw - measured.base_yaw
    else:  # turned about one axis at 0.2 and 0.21 rad/s: angles 0.2 t and 0.21 t, error angle 0.01 t
        np.testing.assert_allclose(_line(attitude, "measured").get_ydata(), 0.2 * measured.t, atol=1e-12)
        np.testing.assert_allclose(_line(attitude, "identified model").get_ydata(), 0.21 * measured.t, atol=1e-12)
        residual = 0.01 * measured.t
    np.testing.assert_allclose(_line(bottom[-1], "residual").get_ydata(), residual, atol=1e-12)
    assert bottom[-1].get_title(loc="left") == f"residual, RMS {np.sqrt(np.mean(residual**2)):.2g} rad"
    assert bottom[-1].get_ylabel() == ("pred. $-$ meas. [rad]" if planar else "error angle [rad]")


def test_validation_needs_matching_logs(tmp_path):
    measured = _log(True)
    with pytest.raises(SpaceidError, match="time stamps"):
        plot_validation(measured, measured.select(slice(0, 30)), tmp_path / "v.png")
    with pytest.raises(SpaceidError, match="joints"):
        plot_validation(measured, _log(False), tmp_path / "v.png")
    assert not list(tmp_path.iterdir())


@pytest.mark.parametrize("options", OPTIONS)
def test_parameter_figure_is_a_png(tmp_path, ident, options):
    plot_parameters(ident, tmp_path / "parameters.png", **options)
    _assert_png(tmp_path / "parameters.png")


@pytest.mark.parametrize("options", OPTIONS)
def test_parameter_figure_is_one_linear_relative_axis(ident, options):
    fig = draw_parameters(ident, **options)
    (ax,) = fig.axes
    _assert_titled_and_labelled(fig)
    assert ax.get_yscale() == "linear" and "[%]" in ax.get_ylabel() and "SI" not in ax.get_ylabel()
    assert "estimate $\\pm 2\\sigma$" in _legend_labels(fig)[-1]
    x, centre, half = _errorbars(ax, "estimate")
    np.testing.assert_allclose(x, np.arange(3) - 0.15 * ("reference" in options))  # beside the reference
    if "true" in options:  # signed error and 2 sigma, in percent of |true|
        np.testing.assert_allclose(centre, [0.4, -0.05, 0.7], rtol=1e-9)
        np.testing.assert_allclose(half, 200 * ident.std / TRUE, rtol=1e-9)
        assert ax.get_title(loc="left").endswith("cond = 372.3, max |error| 0.7 %")
    else:  # a real recording: 2 sigma in percent of |estimate|
        np.testing.assert_allclose(centre, 0, atol=1e-12)
        np.testing.assert_allclose(half, 200 * ident.std / ident.values, rtol=1e-9)
    low, high = ax.get_ylim()
    assert low == pytest.approx(-high)  # over- and underestimates on an equal footing
    if "reference" in options:  # magnitudes, drawn at both signs beside ours
        ref = _line(ax, "paper")
        np.testing.assert_allclose(ref.get_xdata(), np.repeat(np.arange(3) + 0.15, 2))
        np.testing.assert_allclose(np.sort(ref.get_ydata()), np.sort(np.concatenate([REFERENCE, -REFERENCE])))
        assert high > REFERENCE.max()


def test_anchored_parameters_are_marked_apart(ident):
    anchors = [{"name": "pi5", "definition": ident.definitions[1], "value": TRUE[1], "source": "given"}]
    std = ident.std * np.array([1.0, 0.0, 1.0])
    fixed = replace(ident, values=np.where(std > 0, ident.values, TRUE), std=std, cov=np.diag(std**2),
                    settings={**ident.settings, "anchors": anchors})  # fmt: skip
    for options in ({"true": TRUE}, {}):
        fig = draw_parameters(fixed, **options)
        (ax,) = fig.axes
        x, _, _ = _errorbars(ax, "estimate")
        np.testing.assert_array_equal(x, [0, 2])  # not among the estimates ...
        marker = _line(ax, "anchored")  # ... but a marker of its own, explained in the legend
        np.testing.assert_array_equal(marker.get_xdata(), [1])
        np.testing.assert_allclose(marker.get_ydata(), [0.0], atol=1e-12)
        assert any("anchored" in label for label in _legend_labels(fig))
        colours = [tick.get_color() for tick in ax.get_xticklabels()]
        assert colours[1] != colours[0] == colours[2]
    assert not any("anchored" in label for label in _legend_labels(draw_parameters(ident, true=TRUE)))


def test_parameter_units_label_the_ticks(ident):
    """Results that carry their parameters' units (``ident.units``) get them under the names, or
    once on the axis when they are all the same."""
    ax = draw_parameters(replace(ident, units=("kg m^2", "kg m^2", "kg m")), true=TRUE).axes[0]
    assert [t.get_text() for t in ax.get_xticklabels()] == ["$\\pi_{1}$\n[kg m$^{2}$]", "$\\pi_{5}$\n[kg m$^{2}$]",
                                                            "$\\pi_{8}$\n[kg m]"]  # fmt: skip
    assert ax.get_xlabel() == "minimal parameter [unit]"
    ax = draw_parameters(replace(ident, units=("kg m^2",) * 3), true=TRUE).axes[0]
    assert [t.get_text() for t in ax.get_xticklabels()] == ["$\\pi_{1}$", "$\\pi_{5}$", "$\\pi_{8}$"]
    assert ax.get_xlabel() == "minimal parameter (all in kg m$^{2}$)"
    assert draw_parameters(ident).axes[0].get_xlabel() == "minimal parameter"  # a result without units
    with pytest.raises(SpaceidError, match="2 units for 3 parameters"):
        draw_parameters(replace(ident, units=("kg m^2",) * 2))


def test_parameter_figure_checks_lengths(tmp_path, ident):
    with pytest.raises(SpaceidError, match=r"`true`: expected one value per parameter \(3"):
        plot_parameters(ident, tmp_path / "p.png", true=TRUE[:2])


def test_singular_value_figure(tmp_path, ident):
    plot_singular_values(ident, tmp_path / "sv.png")
    _assert_png(tmp_path / "sv.png")
    fig = draw_singular_values(ident)
    _assert_titled_and_labelled(fig)
    (ax,) = fig.axes
    assert "372.3" in ax.get_title() and ax.get_yscale() == "log"
    # relative to the largest: the columns' units differ, the ratios do not
    np.testing.assert_allclose(ax.get_lines()[0].get_ydata(), ident.singular_values / 57.1)
    empty = Identification(**{**ident.__dict__, "singular_values": np.array([])})
    with pytest.raises(SpaceidError, match="no singular values"):
        plot_singular_values(empty, tmp_path / "sv2.png")


def test_singular_value_figure_of_many_parameters(ident):
    """496 singular values (the servicer's): integer ticks matplotlib spaces, not one per index, which overlapped."""
    many = Identification(**{**ident.__dict__, "singular_values": np.geomspace(57.1, 1e-3, 496)})
    (ax,) = draw_singular_values(many).axes
    ticks = [t for t in ax.get_xticks() if 1 <= t <= 496]
    assert 3 <= len(ticks) <= 12 and all(float(t).is_integer() for t in ticks)
    assert len(ax.get_lines()[0].get_xdata()) == 496


def test_trajectory_figure(tmp_path):
    t = np.linspace(0, 5, 301)
    q = np.stack([0.6 * np.sin(t), np.sin(2 * t)], axis=1)
    qd = np.stack([0.6 * np.cos(t), 2 * np.cos(2 * t)], axis=1)
    qdd = np.stack([-0.6 * np.sin(t), -4 * np.sin(2 * t)], axis=1)
    limits = {"q": [0.66, 1.36], "qd": np.array([[-1.0, 1.0], [-2.5, np.nan]]), "qdd": 5.0}
    samples = np.linspace(0, 5, 35)
    plot_trajectory(t, q, qd, qdd, JOINTS, tmp_path / "trajectory.png", limits=limits, times=samples)
    _assert_png(tmp_path / "trajectory.png", min_width=900)
    fig = _draw_trajectory(t, q, qd, qdd, JOINTS, limits=limits, samples=samples)
    _assert_titled_and_labelled(fig)
    assert "5 s" in fig.get_suptitle()
    assert _legend_labels(fig) == ["trajectory", "limit", "sample instants (N = 35)"]
    limits_drawn = [sorted(ln.get_ydata()[0] for ln in ax.get_lines() if ln.get_label() == "limit") for ax in fig.axes]
    assert limits_drawn[2:4] == [[-1.0, 1.0], [-2.5]]  # the rates' pairs; NaN: no upper limit
    with pytest.raises(SpaceidError, match="unknown limit kinds"):
        plot_trajectory(t, q, qd, qdd, JOINTS, tmp_path / "t2.png", limits={"velocity": 1.0})
    with pytest.raises(SpaceidError, match=r"limits\['q'\]"):
        plot_trajectory(t, q, qd, qdd, JOINTS, tmp_path / "t2.png", limits={"q": [1.0, 2.0, 3.0]})


@pytest.mark.slow  # fast representative: test_trajectory_figure
def test_tracking_figure(tmp_path):
    t = np.linspace(0, 5, 251)
    designed = np.stack([0.6 * np.sin(t), np.sin(2 * t)], axis=1)
    executed = designed + np.stack([0.01 * np.ones_like(t), -0.002 * np.ones_like(t)], axis=1)
    samples = np.linspace(0, 5, 29)
    plot_tracking(t, designed, executed, JOINTS, tmp_path / "tracking.png", times=samples)
    _assert_png(tmp_path / "tracking.png", min_width=900)
    fig = _draw_tracking(t, designed, executed, JOINTS, samples=samples, title="cond(Y) designed 76.6, executed 82.1")
    _assert_titled_and_labelled(fig)
    assert fig.get_suptitle() == "cond(Y) designed 76.6, executed 82.1"
    assert _legend_labels(fig) == ["designed (commanded)", "executed (encoders)", "identification samples (N = 29)",
                                   "executed - designed"]  # fmt: skip
    assert [ax.get_title(loc="right") for ax in fig.axes[2:]] == ["RMS 10 mrad", "RMS 2 mrad"]  # the error row
    with pytest.raises(SpaceidError, match="one column per joint"):
        plot_tracking(t, designed[:, :1], executed, JOINTS, tmp_path / "t2.png")


@pytest.fixture(scope="module")
def montecarlo():
    """A small study, then one OLS run marked failed: 4 runs for ML, 3 for OLS."""
    param = minimal_parameters(load_model("cepheus"))
    noise = Noise(2e-4, 1e-4, 1e-4, 1e-4, source="test")
    res = run_montecarlo(param, "paper-table2", samples=35, momentum=[0.0, 0.0, 0.4934], noise=noise, runs=4,
                         estimators=("ml", "ols"), seed=5, jobs=1)  # fmt: skip
    ols = res.estimates["ols"].copy()
    ols[2] = np.nan
    return replace(res, estimates={**res.estimates, "ols": ols})


@pytest.mark.slow
def test_montecarlo_figure(tmp_path, montecarlo):
    plot_montecarlo(montecarlo, tmp_path / "montecarlo.png")
    _assert_png(tmp_path / "montecarlo.png", min_width=900)
    fig = _draw_montecarlo(montecarlo)
    _assert_titled_and_labelled(fig)
    title = fig.get_suptitle()
    assert "4 runs" in title and "N = 35" in title
    assert "angle 2e-4 rad, rate 1e-4 rad/s, base rate 1e-4 rad/s, attitude 1e-4 rad" in title
    (bars,) = [ax for ax in fig.axes if ax.get_xlabel() == "minimal parameter"]
    assert bars.get_ylabel() == "RMSE / CRB [-]"
    # no internal target: no line or label of one, nothing at 1.2
    lines = [ln for ax in fig.axes for ln in ax.get_lines()]
    assert not any("target" in text.lower() for text in _legend_labels(fig) + [ln.get_label() for ln in lines])
    assert not any(np.allclose(ln.get_ydata(), 1.2) for ln in bars.get_lines())
    labelled = [ln.get_label() for ln in bars.get_lines() if not ln.get_label().startswith("_")]
    assert labelled == ["RMSE = CRB (efficient)"]
    # the Monte Carlo uncertainty of every ratio: +-2 relative standard errors 1 / sqrt(2 R), R the runs that succeeded
    x, centre, half = _errorbars(bars, "s.e.")
    k = len(montecarlo.names)
    assert x.size == 2 * k
    for j, (e, runs_ok) in enumerate([("ml", 4), ("ols", 3)]):
        ratio = montecarlo.stats[e]["rmse_crb"]
        np.testing.assert_allclose(centre[j * k : (j + 1) * k], ratio, rtol=1e-9)
        np.testing.assert_allclose(half[j * k : (j + 1) * k], 2 * ratio / np.sqrt(2 * runs_ok), rtol=1e-9)
    labels = _legend_labels(fig)
    assert any("s.e." in label and "sqrt{2R}" in label for label in labels)
    assert {"ML (R = 4 runs)", "OLS (R = 3 runs)", "CRB $\\pm 2\\sigma$"} <= set(labels)
    assert bars.get_ylim()[1] >= np.nanmax(centre + half)


def _many_parameter_study(k=150, runs=6, seed=0):
    """A Monte Carlo result of ``k`` parameters, two estimators and ``runs`` runs (OLS's first failed), its statistics
    those of its estimates: every record field as a study of a large robot fills it."""
    from spaceid.studies import MonteCarloResult
    from spaceid.studies._montecarlo_stats import _statistics

    rng = np.random.default_rng(seed)
    true, crb = rng.uniform(0.5, 2.0, k), rng.uniform(0.01, 0.05, k)
    spread = {"ml": rng.uniform(0.8, 1.5, k), "ols": rng.uniform(0.8, 40.0, k)}
    estimates = {e: true + spread[e] * crb * rng.standard_normal((runs, k)) for e in spread}
    estimates["ols"][0] = np.nan
    predicted = {e: np.tile(crb, (runs, 1)) for e in spread}
    stats = {e: _statistics(estimates[e], predicted[e], true, crb) for e in spread}
    names = tuple(f"pi{i + 1}" for i in range(k))
    return MonteCarloResult(names, names, true, ("ml", "ols"), estimates, predicted, np.diag(crb**2), crb, stats,
                            settings={"runs": runs, "n_samples": 400, "seed": seed,
                                      "noise": {"angle": 1e-3, "rate": 1e-3, "base_rate": 1e-3, "attitude": 1e-3}})


def test_montecarlo_figure_ranks_many_parameters(tmp_path):
    """150 parameters: the efficiency panel ranks them at a fixed width (it had a bar and a tick each: the servicer's
    496 drew 37,575 pixels wide in 9 s), every estimator at the ranks of the first's ratios, the worst named."""
    study = _many_parameter_study()
    fig = _draw_montecarlo(study)
    _assert_titled_and_labelled(fig)
    assert fig.get_size_inches()[0] <= 9.0
    (panel,) = [ax for ax in fig.axes if "ranked" in ax.get_title(loc="left")]
    assert "rank of the 150 minimal parameters by ML's RMSE / CRB" in panel.get_xlabel() and not panel.get_xticklabels()[0].get_text().startswith("$")
    order = np.argsort(-study.stats["ml"]["rmse_crb"])
    for e, runs_ok in (("ml", 6), ("ols", 5)):
        ratio = study.stats[e]["rmse_crb"][order]
        line = _line(panel, f"{e.upper()} (R = {runs_ok} runs)")
        np.testing.assert_array_equal(line.get_xdata(), np.arange(1, 151))
        np.testing.assert_allclose(line.get_ydata(), ratio, rtol=1e-12)
    assert panel.get_yscale() == "log"  # OLS's ratios reach 40: a linear axis would flatten ML's
    (box,) = [t.get_text() for t in panel.texts if t.get_text().startswith("worst")]
    assert box.split("\n")[1:] == [f"$\\pi_{{{i + 1}}}$: {study.stats['ml']['rmse_crb'][i]:.3g}" for i in order[:8]]
    plot_montecarlo(study, tmp_path / "mc.png")
    width, height = _png_size(tmp_path / "mc.png")
    assert width <= 1350 and height <= 1500, (width, height)


def test_figures_leave_global_matplotlib_state_alone(tmp_path, ident):
    before = dict(mpl.rcParams)
    plot_singular_values(ident, tmp_path / "sv.png")
    plot_parameters(ident, tmp_path / "p.png", true=TRUE)
    assert dict(mpl.rcParams) == before


# --- tables and report -------------------------------------------------------------------------


def test_rich_table_renders_every_column(ident):
    console = Console(record=True, width=160)
    console.print(parameter_table(ident, true=TRUE, reference=REFERENCE, reference_true=[0.0074, 0.1314, 0.0046]))
    text = console.export_text()
    for name in ident.names:
        assert name in text
    assert "Izz_link2" in text and "0.00726595" in text  # definition and .6g estimate
    assert "err [%]" in text and "paper err [%]" in text and "0.1314" in text
    assert "0.7" in text  # pi8: |1.007 - 1| = 0.7 %
    assert "0.5162" in text


def test_large_systems_point_to_their_definitions(ident):
    """Past DEFINITIONS_SHOWN parameters the terminal gets the numbers, not pages of formulas."""
    from spaceid.studies._tables import DEFINITIONS_SHOWN

    k = DEFINITIONS_SHOWN + 1
    big = replace(ident, names=tuple(f"pi{i + 1}" for i in range(k)), definitions=("M_link1*MX_link2/M",) * k,
                  values=np.ones(k), std=np.ones(k), cov=np.eye(k))
    console = Console(record=True, width=100)
    console.print(parameter_table(big))
    text = console.export_text()
    assert f"pi{k}" in text and "M_link1*MX_link2/M" not in text
    assert f"{k} parameters: their definitions are in the result file and in 'spaceid model" in text


def test_rows_lists_the_first_and_says_where_the_rest_are(ident):
    k = 25  # up to DEFINITIONS_SHOWN, the definitions are listed: those of the listed parameters alone
    big = replace(ident, names=tuple(f"pi{i + 1}" for i in range(k)), values=np.ones(k), std=np.ones(k),
                  definitions=tuple(f"M_link{i + 1}" for i in range(k)), cov=np.eye(k))
    console = Console(record=True, width=100)
    console.print(parameter_table(big, rows=20, rest="--all lists them"))
    text = console.export_text()
    assert "pi20 " in text and "M_link20" in text and "pi21" not in text and "M_link21" not in text
    assert text.rstrip().splitlines()[-1] == "the first 20 of 25 parameters listed, 5 more: --all lists them"
    console.print(parameter_table(big, rows=k, rest="--all lists them"))
    text = console.export_text()
    assert "pi25 " in text and "M_link25" in text and "more" not in text


@pytest.mark.slow
def test_markdown_report(tmp_path, ident):
    plot_parameters(ident, tmp_path / "parameters.png", true=TRUE)
    (tmp_path / "figs").mkdir()
    sv = tmp_path / "figs" / "sv.png"
    plot_singular_values(ident, sv)
    settings = {"model": "cepheus", "trajectory": "paper_table2", "noise rate [rad/s]": 1e-4, "seed": 0}
    metrics = {"base_w_rms": 4.6e-4, "custom_metric": 1.5}
    out = write_markdown_report(
        tmp_path, title="Cepheus identification", result=ident, settings=settings,
        figures={"Parameter estimates": "parameters.png", "Singular values": sv.resolve()},
        true=TRUE, reference=REFERENCE, metrics=metrics,
    )
    assert out == tmp_path / "report.md"
    text = out.read_text()
    assert text.startswith("# Cepheus identification\n")
    for name, value in zip(ident.names, ident.values):
        assert f"| {name} | `" in text and f"{value:.6g}" in text
    assert "`Izz_link2 + cx_link2**2*m_link2*(m_base + m_link1)/M`" in text
    assert "![Parameter estimates](parameters.png)" in text
    assert "![Singular values](figs/sv.png)" in text  # absolute path made relative
    assert "paper\\_table2" in text and "| seed | 0 |" in text
    assert "372.3" in text and "0.000149 N m s" in text
    assert "base angular velocity, RMS error [rad/s] | 0.00046" in text and "custom\\_metric" in text
    # every table row has as many cells as its header
    table = [line for line in text.splitlines() if line.startswith("| pi")]
    assert len(table) == 3 and all(line.count(" | ") == 6 for line in table)


def test_markdown_report_refuses_missing_figures(tmp_path, ident):
    with pytest.raises(SpaceidError, match=r"figures\['Validation'\]: 'validation.png' not found"):
        write_markdown_report(tmp_path, title="t", result=ident, settings={}, figures={"Validation": "validation.png"})
    assert not (tmp_path / "report.md").exists()
