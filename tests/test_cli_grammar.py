"""One command-line grammar (issue 25, item 7): the library's constants behind the options, files
with -o/--output and folders with --out, one --drift grammar, one rate-source choice for CSV and
bag logs, --format only where it means an output format, and the old spellings kept one release
with a one-line deprecation warning."""

import ast
import json
from pathlib import Path

import click
import pytest

import spaceid
import spaceid.cli
from spaceid.cli import app, main


def _option(command, name):
    return next(p for p in app.commands[command].params if p.name == name)


# --- constants: defined once, in the library -----------------------------------------------------


def test_option_choices_and_defaults_are_the_librarys():
    from spaceid.data import DEFAULT_JOINT_TOPIC, DEFAULT_POSE_TOPIC
    from spaceid.data import FORMATS as BAG_FORMATS
    from spaceid.data._bag_to_log import JOINT_RATES
    from spaceid.estimation import ESTIMATORS, KNOT_SPACING
    from spaceid.estimation._monitor import CHANGE_RATIO, FALSE_ALARM_RATE
    from spaceid.identified import FORMATS as EXPORT_FORMATS
    from spaceid.motion._criteria import CRITERIA

    assert tuple(_option("identify", "estimator").type.choices) == ESTIMATORS
    assert tuple(_option("experiment", "estimator").type.choices) == ESTIMATORS
    assert tuple(_option("monitor", "estimator").type.choices) == tuple(e for e in ESTIMATORS if e != "angles")
    assert _option("identify", "knot_spacing").default == KNOT_SPACING
    for command in ("design", "sweep"):
        assert tuple(_option(command, "criterion").type.choices) == tuple(CRITERIA)
    assert tuple(_option("experiment", "bag_format").type.choices) == BAG_FORMATS
    assert tuple(_option("export", "fmt").type.choices) == EXPORT_FORMATS
    assert set(_option("identify", "joint_rates").type.choices) - {"measured"} == set(JOINT_RATES)
    assert _option("monitor", "false_alarm_rate").default == FALSE_ALARM_RATE
    assert _option("monitor", "change_ratio").default == CHANGE_RATIO
    joint_topic = " ".join(_option("identify", "joint_topic").help.split())
    assert DEFAULT_JOINT_TOPIC in joint_topic and DEFAULT_POSE_TOPIC in " ".join(_option("identify",
                                                                                        "pose_topic").help.split())


def test_the_cli_copies_no_library_constant():
    """cli.py's module-level names are click types, options and its own settings: no tuple of
    names or number the library also defines (they are imported from spaceid._constants)."""
    import spaceid._constants as constants

    tree = ast.parse(Path(spaceid.cli.__file__).read_text())
    assigned = {t.id for node in tree.body if isinstance(node, ast.Assign) for t in node.targets
                if isinstance(t, ast.Name)}
    defined = {n for n in dir(constants) if n.isupper()}
    assert not assigned & defined
    assert not {"ESTIMATOR_CHOICES"} & assigned


def test_constants_module_imports_nothing():
    tree = ast.parse(Path(spaceid.__file__).with_name("_constants.py").read_text())
    assert not [n for n in ast.walk(tree) if isinstance(n, (ast.Import, ast.ImportFrom))]


def test_payload_units_are_derived_once():
    from spaceid.identified import payload_units
    from spaceid.identified._payload import PLANAR_NAMES, SPATIAL_NAMES

    assert payload_units(PLANAR_NAMES) == ("kg", "m", "m", "kg m^2")
    assert payload_units(SPATIAL_NAMES) == ("kg", "m", "m", "m", *["kg m^2"] * 6)
