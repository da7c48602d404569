"""Figures, tables and the Markdown report: valid PNGs, complete tables, clear errors, no leaks."""

import struct

import matplotlib as mpl
import numpy as np
import pytest
from rich.console import Console

from spaceid import SpaceidError
from spaceid.estimation import Identification
from spaceid.studies import (
    parameter_table,
    plot_parameters,
    plot_singular_values,
    plot_trajectory,
    plot_validation,
    write_markdown_report,
)
from spaceid.data import Log, yaw_to_quat

JOINTS = ("left_shoulder", "left_elbow")
TRUE = np.array([0.007237, 0.131126, 0.004630])
REFERENCE = np.array([0.5162, 0.0432, 0.6634])  # percent, as the paper prints them


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
            "Izz_base + m_base*(m_link1 + m_link2)*(cx_base**2 - 2*cx_base*x_left_shoulder + cy_base**2 "
            "- 2*cy_base*y_left_shoulder + x_left_shoulder**2 + y_left_shoulder**2)/M",
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


@pytest.mark.parametrize("planar", [True, False])
def test_validation_figure_is_a_png(tmp_path, planar):
    out = plot_validation(_log(planar), _log(planar, bias=1e-3), tmp_path / "validation.png", title="Validation")
    assert out == tmp_path / "validation.png"
    _assert_png(out, min_width=900)


def test_validation_needs_matching_logs(tmp_path):
    measured = _log(True)
    with pytest.raises(SpaceidError, match="time stamps"):
        plot_validation(measured, measured.select(slice(0, 30)), tmp_path / "v.png")
    with pytest.raises(SpaceidError, match="joints"):
        plot_validation(measured, _log(False), tmp_path / "v.png")
    assert not list(tmp_path.iterdir())


@pytest.mark.parametrize("options", [{}, {"true": TRUE}, {"true": TRUE, "reference": REFERENCE}, {"reference": REFERENCE}])
def test_parameter_figure_is_a_png(tmp_path, ident, options):
    _assert_png(plot_parameters(ident, tmp_path / "parameters.png", **options))


def test_parameter_figure_checks_lengths(tmp_path, ident):
    with pytest.raises(SpaceidError, match=r"true: expected one value per parameter \(3"):
        plot_parameters(ident, tmp_path / "p.png", true=TRUE[:2])


def test_singular_value_figure(tmp_path, ident):
    _assert_png(plot_singular_values(ident, tmp_path / "sv.png"))
    empty = Identification(**{**ident.__dict__, "singular_values": np.array([])})
    with pytest.raises(SpaceidError, match="no singular values"):
        plot_singular_values(empty, tmp_path / "sv2.png")


def test_trajectory_figure(tmp_path):
    t = np.linspace(0, 5, 301)
    q = np.stack([0.6 * np.sin(t), np.sin(2 * t)], axis=1)
    qd = np.stack([0.6 * np.cos(t), 2 * np.cos(2 * t)], axis=1)
    qdd = np.stack([-0.6 * np.sin(t), -4 * np.sin(2 * t)], axis=1)
    limits = {"q": [0.66, 1.36], "qd": np.array([[-1.0, 1.0], [-2.5, np.nan]]), "qdd": 5.0}
    out = plot_trajectory(t, q, qd, qdd, JOINTS, tmp_path / "trajectory.png", limits=limits, samples=np.linspace(0, 5, 35))
    _assert_png(out, min_width=900)
    with pytest.raises(SpaceidError, match="unknown limit kinds"):
        plot_trajectory(t, q, qd, qdd, JOINTS, tmp_path / "t2.png", limits={"velocity": 1.0})
    with pytest.raises(SpaceidError, match=r"limits\['q'\]"):
        plot_trajectory(t, q, qd, qdd, JOINTS, tmp_path / "t2.png", limits={"q": [1.0, 2.0, 3.0]})


def test_figures_leave_global_matplotlib_state_alone(tmp_path, ident):
    before = dict(mpl.rcParams)
    plot_singular_values(ident, tmp_path / "sv.png")
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
    from dataclasses import replace

    from spaceid.studies._tables import DEFINITIONS_SHOWN

    k = DEFINITIONS_SHOWN + 1
    big = replace(ident, names=tuple(f"pi{i + 1}" for i in range(k)), definitions=("M_link1*MX_link2/M",) * k,
                  values=np.ones(k), std=np.ones(k), cov=np.eye(k))
    console = Console(record=True, width=100)
    console.print(parameter_table(big))
    text = console.export_text()
    assert f"pi{k}" in text and "M_link1*MX_link2/M" not in text
    assert f"{k} parameters: their definitions are in the result file and in 'spaceid model" in text


def test_markdown_report(tmp_path, ident):
    plot_parameters(ident, tmp_path / "parameters.png", true=TRUE)
    (tmp_path / "figs").mkdir()
    sv = plot_singular_values(ident, tmp_path / "figs" / "sv.png")
    settings = {"model": "cepheus", "trajectory": "paper_table2", "noise rate [rad/s]": 1e-4, "seed": 0}
    metrics = {"base_w_rms": 4.6e-4, "custom_metric": 1.5}
    out = write_markdown_report(
        tmp_path, title="Cepheus identification", ident=ident, settings=settings,
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
        write_markdown_report(tmp_path, title="t", ident=ident, settings={}, figures={"Validation": "validation.png"})
    assert not (tmp_path / "report.md").exists()
