"""The command line as a new user meets it: usage lines that show the required options, help
for every option that says what it does, and terminal tables that fit 80 columns, with units."""

import click
import numpy as np
import pytest
from click.testing import CliRunner
from rich.console import Console

import spaceid
from spaceid.cli import app, main
from spaceid.dynamics import minimal_parameters
from spaceid.estimation import Identification

ESTIMATOR_WORDS = ("maximum likelihood", "weighted least squares", "instrumental variables", "total least squares",
                   "ordinary least squares")


def help_text(*command):
    """``spaceid COMMAND --help`` at 80 columns, whitespace collapsed (click wraps the help)."""
    result = CliRunner().invoke(app, [*command, "--help"], terminal_width=80, prog_name="spaceid")
    assert result.exit_code == 0, result.output
    return result.output


def usage(text):
    return " ".join(text.split("\n\n")[0].split())


@pytest.mark.parametrize("name", sorted(app.commands))
def test_usage_lists_required_options_and_every_option_has_help(name):
    text = help_text(name)
    for p in app.commands[name].params:
        if isinstance(p, click.Option):
            assert p.help, f"spaceid {name} {p.opts[-1]} has no help"
            if p.required:
                assert f"{p.opts[-1]} " in usage(text), f"spaceid {name}: required {p.opts[-1]} not in the usage line"


def test_montecarlo_says_the_momentum_is_required():
    text = help_text("montecarlo")
    assert "--momentum H|HX,HY,HZ" in usage(text) and "[required]" in text


def test_experiment_model_is_optional():
    assert usage(help_text("experiment")) == "Usage: spaceid experiment [OPTIONS] [MODEL]"
    assert "cepheus" in " ".join(help_text("experiment").split()[:60])


@pytest.mark.parametrize("name", ["identify", "experiment", "montecarlo"])
def test_estimator_help_says_what_each_one_does(name):
    text = " ".join(help_text(name).split())
    assert all(words in text for words in ESTIMATOR_WORDS) and "see the documentation" not in text


def test_format_and_instruments_help():
    experiment = " ".join(help_text("experiment").split())
    assert "ros2 (ROS 2 bag folder, sqlite3 storage)" in experiment and "mcap (ROS 2 bag folder, MCAP" in experiment
    identify = " ".join(help_text("identify").split())
    instruments = identify[identify.index("--instruments"):identify.index("--noise-angle")]
    assert "JSON 'spaceid design' writes" in instruments and "YAML" not in instruments


def _ident(param, estimator="ml"):
    k = param.n_params
    return Identification(param.names, param.definitions, param.true_values, np.full(k, 1e-6), np.eye(k) * 1e-12,
                          36.2, np.ones(k), 1e-6, 35, estimator, np.array([0, 0, 0.4934]), param.model.name,
                          param.model.planar, units=param.units)


def _lines(renderable, width=80):
    console = Console(record=True, width=width)
    console.print(renderable)
    return console.export_text().splitlines()


def test_parameter_table_fits_80_columns_with_its_title_on_one_line():
    from spaceid.studies import parameter_table

    param = minimal_parameters(spaceid.load_model("cepheus"))
    group = parameter_table(_ident(param))
    lines = _lines(group)
    title = group.renderables[0].title
    assert any(title in line for line in lines), lines[:3]  # not broken over two lines
    assert max(map(len, lines)) <= 80
    assert any("all in kg m^2" in line for line in lines)  # one unit for all: in the caption
    # the paper's columns, too
    lines = _lines(parameter_table(_ident(param), true=param.true_values, reference=np.ones(8),
                                   reference_true=param.true_values))
    assert max(map(len, lines)) <= 80 and not any("…" in line for line in lines)


def test_parameter_table_of_mixed_units_has_a_unit_column():
    from spaceid.studies import parameter_table

    param = minimal_parameters(spaceid.load_model("satellite-7dof"))
    lines = _lines(parameter_table(_ident(param)))
    header = next(line for line in lines if "┃" in line)
    assert "unit" in header and any("│ kg m  " in line for line in lines) and any("kg m^2" in line for line in lines)


@pytest.mark.slow
def test_montecarlo_table_fits_80_columns_with_its_title_on_one_line():
    from spaceid.studies import DEFAULT_NOISE, montecarlo_table, run_montecarlo

    param = minimal_parameters(spaceid.load_model("cepheus"))
    res = run_montecarlo(param, "paper-table2", samples=201, momentum=[0, 0, 0.4934], noise=DEFAULT_NOISE, runs=3,
                         estimators=("ols",), seed=12345, jobs=1, angles_only=True)
    group = montecarlo_table(res)
    lines = _lines(group)
    assert any(group.renderables[0].title in line for line in lines) and max(map(len, lines)) <= 80
    assert "angles only" in " ".join(" ".join(lines).split())  # moved from the title to the caption


def test_model_table_headers_keep_their_units(capsys):
    """Rich reads '[kg]' as markup and dropped it from 'mass [kg]'."""
    assert main(["model", "cepheus"]) == 0
    text = capsys.readouterr().out
    assert "mass [kg]" in text and "total mass 10.221 kg" in text and "kg m^2" in text
