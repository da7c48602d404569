"""One command-line grammar (issue 25, item 7): the library's constants behind the options, files
with -o/--output and folders with --out, one --drift grammar, one rate-source choice for CSV and
bag logs, --format only where it means an output format, and the old spellings kept one release
with a one-line deprecation warning."""

import ast
import json
from pathlib import Path

import click
from click.testing import CliRunner
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


# --- files with -o/--output, folders with --out --------------------------------------------------

H = "0.4934"
DEPRECATED = "it will be removed in the next release"


@pytest.fixture(scope="module")
def files(tmp_path_factory):
    """A Cepheus log (paper-table2, 40 samples, noise-free) and its identification."""
    d = tmp_path_factory.mktemp("grammar")
    assert main(["simulate", "cepheus", "--trajectory", "paper-table2", "--momentum", H, "--samples", "40",
                 "-o", str(d / "log.csv")]) == 0
    assert main(["identify", "cepheus", str(d / "log.csv"), "--momentum", H, "-o", str(d / "result.json")]) == 0
    return d


def _warnings(err):
    return [line for line in err.splitlines() if line.startswith("warning: ") and DEPRECATED in line]


@pytest.mark.parametrize("name", sorted(app.commands))
def test_files_are_o_output_and_folders_out(name):
    for p in app.commands[name].params:
        if isinstance(p.type, spaceid.cli._OutputPath) and not p.hidden:
            if p.type.folder:
                assert p.opts == ["--out"], (name, p.opts)
            else:
                assert p.opts == ["-o", "--output"] or p.opts == ["--definitions"], (name, p.opts)


def test_validate_writes_its_folder_with_out_and_o_is_deprecated(files, tmp_path, capsys):
    args = ["validate", str(files / "result.json"), str(files / "log.csv"), "--momentum", H]
    assert main([*args, "--out", str(tmp_path / "new")]) == 0
    assert not _warnings(capsys.readouterr().err)
    for spelling in ("-o", "--output"):
        assert main([*args, spelling, str(tmp_path / spelling)]) == 0
        assert _warnings(capsys.readouterr().err) == [
            "warning: -o/--output is deprecated: use --out DIR (-o/--output names a file, --out a folder); it will be "
            "removed in the next release"]
        assert (json.loads((tmp_path / spelling / "metrics.json").read_text())
                == json.loads((tmp_path / "new" / "metrics.json").read_text()))
    assert main([*args, "-o", str(tmp_path / "a"), "--out", str(tmp_path / "b")]) == 2
    err = capsys.readouterr().err.splitlines()
    assert err[-1] == f"error: -o/--output (deprecated) and --out {tmp_path / 'b'} contradict each other: give --out alone"
    assert not (tmp_path / "a").exists() and not (tmp_path / "b").exists()
    usage = " ".join(CliRunner().invoke(app, ["validate", "--help"], terminal_width=200).output.split())
    assert "--out DIR" in usage and "--output" not in usage  # the old spelling is hidden


# --- one --drift grammar -----------------------------------------------------------------------------

SETS = {"simulate": ["simulate", "cepheus", "--trajectory", "paper-table2", "--momentum", H, "--samples", "40"],
        "predict": ["predict", "RESULT", "paper-table2", "--momentum", H, "--samples", "40"],
        "validate": ["validate", "RESULT", "LOG", "--momentum", H]}
ESTIMATES = {"identify": ["identify", "cepheus", "LOG", "--momentum", H],
             "payload": ["payload", "cepheus", "LOG", "--link", "link2", "--momentum", H],
             "monitor": ["monitor", "cepheus", "LOG", "--momentum", H],
             "experiment": ["experiment"]}


def _args(args, files, out):
    args = [str(files / "result.json") if a == "RESULT" else str(files / "log.csv") if a == "LOG" else a for a in args]
    return [*args, "--out" if args[0] in ("validate", "experiment") else "-o", str(out)]


@pytest.mark.parametrize("command", SETS)
def test_a_command_that_sets_the_drift_refuses_a_bare_kind(files, tmp_path, capsys, command):
    assert main(_args([*SETS[command], "--drift", "viscous"], files, tmp_path / "out")) == 2
    assert capsys.readouterr().err == (f"error: --drift: 'viscous' gives no value: {command} needs one, e.g. --drift "
                                       "viscous=5e-4\n")
    assert not (tmp_path / "out").exists()


@pytest.mark.parametrize("command", ESTIMATES)
def test_a_command_that_estimates_the_drift_refuses_a_value(files, tmp_path, capsys, command):
    assert main(_args([*ESTIMATES[command], "--drift", "torque,viscous=5e-4"], files, tmp_path / "out")) == 2
    assert capsys.readouterr().err == (f"error: --drift: 'viscous=5e-4' gives a value: {command} estimates the drift "
                                       "terms and cannot hold them fixed: give the kind alone, e.g. --drift "
                                       "torque,viscous\n")
    assert not (tmp_path / "out").exists()


def test_both_forms_where_they_are_used(files, tmp_path, capsys):
    """simulate sets a viscous drift, identify estimates it back; 'none' is no drift in both."""
    log = tmp_path / "drifting.csv"
    assert main(_args([*SETS["simulate"], "--drift", "viscous=5e-3"], files, log)) == 0
    assert main(["identify", "cepheus", str(log), "--momentum", H, "--drift", "viscous", "-o",
                 str(tmp_path / "r.json")]) == 0
    drift = json.loads((tmp_path / "r.json").read_text())["drift"]
    assert [d["name"] for d in drift] == ["viscous"] and drift[0]["value"] == pytest.approx(5e-3, rel=1e-5)
    assert main(_args([*SETS["simulate"], "--drift", "none"], files, tmp_path / "none.csv")) == 0
    assert (tmp_path / "none.csv").read_text() == (files / "log.csv").read_text()  # the same as without --drift
    assert main(_args([*ESTIMATES["identify"], "--drift", "none"], files, tmp_path / "n.json")) == 0
    assert json.loads((tmp_path / "n.json").read_text())["drift"] == []


def test_the_parser_is_the_librarys():
    from spaceid import SpaceidError
    from spaceid.estimation import parse_drift

    assert parse_drift("viscous, torque", planar=True, values=False) == ("torque", "viscous")
    assert parse_drift("none", planar=True, values=False) == ()
    terms = parse_drift("torque=0:0:1e-4,viscous=5e-4", planar=False, values=True)
    assert terms["torque"].tolist() == [0, 0, 1e-4] and terms["viscous"] == 5e-4
    none = parse_drift("none", planar=True, values=True)
    assert none["viscous"] == none["coulomb"] == 0 and not none["torque"].any()  # replaces a result's own terms
    with pytest.raises(SpaceidError, match=r"^`drift`: 'torque' gives no value: simulate needs one, e\.g\. `drift` "
                                           r"torque=0:0:1e-4$"):
        parse_drift("torque", planar=False, values=True, command="simulate")
    for command, values in [("simulate", True), ("identify", False)]:
        metavar = _option(command, "drift").metavar
        assert metavar == ("KIND=VALUE[,...]" if values else "KIND[,KIND...]")
