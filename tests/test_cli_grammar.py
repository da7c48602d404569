"""One command-line grammar (issue 25, item 7): the library's constants behind the options, files
with -o/--output and folders with --out, one --drift grammar, one rate-source choice for CSV and
bag logs, --format only where it means an output format, and the old spellings kept one release
with a one-line deprecation warning."""

import ast
import inspect
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
    from spaceid.estimation import ESTIMATORS, KNOT_SPACING, identify
    from spaceid.estimation._monitor import CHANGE_RATIO, FALSE_ALARM_RATE
    from spaceid.identified import FORMATS as EXPORT_FORMATS
    from spaceid.motion._criteria import CRITERIA

    assert tuple(_option("identify", "estimator").type.choices) == ESTIMATORS
    assert tuple(_option("experiment", "estimator").type.choices) == ESTIMATORS
    assert tuple(_option("monitor", "estimator").type.choices) == tuple(e for e in ESTIMATORS if e != "angles")
    # None: the library's choice per log (KNOT_SPACING planar, from the joint samples spatial)
    assert _option("identify", "knot_spacing").default is inspect.signature(identify).parameters["knot_spacing"].default
    assert f"Default: {KNOT_SPACING:g} s for a planar log" in _option("identify", "knot_spacing").help
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
                # a second file beside -o's: the model's definitions, the HTML report
                assert p.opts in (["-o", "--output"], ["--definitions"], ["--report"]), (name, p.opts)


# fast representatives: test_files_are_o_output_and_folders_out,
# test_every_old_spelling_is_a_hidden_deprecated_option
@pytest.mark.slow
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
    assert err[-1] == (f"error: -o/--output (deprecated) and --out {tmp_path / 'b'} contradict each other: give --out "
                       "alone")
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


# fast representatives: test_a_command_that_sets_the_drift_refuses_a_bare_kind,
# test_monitor_drift.py::test_cli_monitor_with_drift
@pytest.mark.slow
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


# --- one rate source for CSV and bag logs --------------------------------------------------------


def _identify(log, out, *options):
    return main(["identify", "cepheus", str(log), "--momentum", H, *options, "-o", str(out)])


def _without(columns, source, target):
    """``source`` (a log CSV) without the columns named in ``columns``, written to ``target``."""
    import numpy as np

    header = source.read_text().splitlines()[0].split(",")
    keep = [i for i, name in enumerate(header) if name not in columns]
    values = np.loadtxt(source, delimiter=",", skiprows=1)[:, keep]
    np.savetxt(target, values, delimiter=",", header=",".join(header[i] for i in keep), comments="", fmt="%.17g")
    return target


def test_csv_rates_differentiated_with_joint_rates_and_differentiate_is_deprecated(files, tmp_path, capsys):
    log = files / "log.csv"
    assert _identify(log, tmp_path / "new.json", "--joint-rates", "differentiate", "--window", "11") == 0
    assert not _warnings(capsys.readouterr().err)
    new = json.loads((tmp_path / "new.json").read_text())
    assert new["settings"]["log"]["differentiation"]["joints"]["window"] == [11, 11]  # per joint
    assert _identify(log, tmp_path / "old.json", "--differentiate", "--window", "11") == 0
    assert _warnings(capsys.readouterr().err) == ["warning: --differentiate is deprecated: use --joint-rates "
                                                  "differentiate; it will be removed in the next release"]
    assert json.loads((tmp_path / "old.json").read_text()) == new
    assert _identify(log, tmp_path / "x.json", "--differentiate", "--joint-rates", "velocity") == 2
    assert capsys.readouterr().err.splitlines()[-1] == ("error: --differentiate (deprecated) and --joint-rates "
                                                        "velocity contradict each other: give --joint-rates alone")


def test_csv_measured_rates_take_no_differentiator_options(files, tmp_path, capsys):
    log = files / "log.csv"
    for options in (["--window", "11"], ["--joint-rates", "measured", "--quantum", "1e-6"]):
        assert _identify(log, tmp_path / "r.json", *options) == 2
        option = options[-2]
        assert capsys.readouterr().err == (f"error: {option}: {log}'s rates are its rate columns (--joint-rates "
                                           f"measured), none is differentiated: add --joint-rates differentiate, or "
                                           f"drop {option}\n")
    for rates in ("measured", "velocity", "auto"):  # a CSV with every rate column: the columns
        assert _identify(log, tmp_path / f"{rates}.json", "--joint-rates", rates) == 0
        assert "differentiation" not in json.loads((tmp_path / f"{rates}.json").read_text())["settings"]["log"]


def test_csv_missing_rates(files, tmp_path, capsys):
    """Some rate columns missing: refused unless differentiated (auto differentiates); none at all:
    differentiated by default, refused when measured rates are asked for."""
    partial = _without({"qd_left_elbow"}, files / "log.csv", tmp_path / "partial.csv")
    assert _identify(partial, tmp_path / "r.json") == 2
    assert capsys.readouterr().err == (f"error: {partial}: rate column(s) qd_left_elbow missing: add them, or pass "
                                       "--joint-rates differentiate to compute every rate from the angles\n")
    assert _identify(partial, tmp_path / "auto.json", "--joint-rates", "auto") == 0
    assert "differentiation" in json.loads((tmp_path / "auto.json").read_text())["settings"]["log"]
    header = (files / "log.csv").read_text().splitlines()[0].split(",")
    angles = _without({n for n in header if n.startswith(("qd_", "base_w"))}, files / "log.csv", tmp_path / "a.csv")
    assert _identify(angles, tmp_path / "default.json") == 0
    assert "differentiation" in json.loads((tmp_path / "default.json").read_text())["settings"]["log"]
    capsys.readouterr()
    assert _identify(angles, tmp_path / "m.json", "--joint-rates", "measured") == 2
    assert "missing: add them, or pass --joint-rates differentiate" in capsys.readouterr().err


def test_monitor_follow_takes_no_differentiation(files, tmp_path, capsys):
    args = ["monitor", "cepheus", str(files / "log.csv"), "--momentum", H, "--follow", "-o", str(tmp_path / "e.json")]
    assert main([*args, "--joint-rates", "differentiate", "--window", "11"]) == 2
    assert capsys.readouterr().err == ("error: --joint-rates differentiate and --window: --follow reads the rows as "
                                       "they are written, with their rate columns: differentiate once the log is "
                                       "closed (monitor it without --follow)\n")


@pytest.fixture(scope="module")
def bag(tmp_path_factory):
    """A noise-free Cepheus bag (MCAP; joint states with velocities at 100 Hz, poses at 100 Hz)."""
    import numpy as np

    from spaceid.data import JointStates, Poses, Recording, write_bag
    from spaceid.dynamics import minimal_parameters
    from spaceid.motion import load_trajectory, simulate

    model = spaceid.load_model("cepheus")
    param = minimal_parameters(model)
    traj = load_trajectory("paper-table2")
    t = np.arange(501) / 100
    log = simulate(param, param.true_values, lambda s: traj.evaluate(s)[:2], t, [0, 0, float(H)], model=model)
    path = tmp_path_factory.mktemp("bag") / "run.mcap"
    write_bag(path, Recording(JointStates(t, log.joints, log.q, log.qd), Poses(t, np.zeros((501, 3)), log.base_quat)))
    return path


# fast representatives: test_csv_rates_differentiated_with_joint_rates_and_differentiate_is_deprecated,
# test_monitor.py::test_monitor_on_a_bag_reads_it_in_parts
@pytest.mark.slow
def test_bag_rates_from_the_same_options(bag, tmp_path, capsys):
    """measured is the published velocities (the bag reader's 'velocity'); differentiate with a
    window and a quantum; --differentiate the deprecated spelling of the latter."""
    assert _identify(bag, tmp_path / "m.json", "--joint-rates", "measured") == 0
    assert "joint rates: 'velocity'" in capsys.readouterr().out
    measured = json.loads((tmp_path / "m.json").read_text())
    assert set(measured["settings"]["log"]["joint_rates"].values()) == {"velocity"}
    assert _identify(bag, tmp_path / "v.json", "--joint-rates", "velocity") == 0
    assert json.loads((tmp_path / "v.json").read_text()) == measured
    assert _identify(bag, tmp_path / "d.json", "--joint-rates", "differentiate", "--window", "21") == 0
    differentiated = json.loads((tmp_path / "d.json").read_text())["settings"]["log"]
    assert set(differentiated["joint_rates"].values()) == {"differentiated"}
    assert [d["window"] for d in differentiated["differentiation"]["joints"].values()] == [[21], [21]]
    capsys.readouterr()
    assert _identify(bag, tmp_path / "old.json", "--differentiate", "--window", "21") == 0
    assert len(_warnings(capsys.readouterr().err)) == 1
    assert json.loads((tmp_path / "old.json").read_text())["settings"]["log"] == differentiated


# --- capture settings, --format ------------------------------------------------------------------


@pytest.fixture
def experiment_settings(monkeypatch):
    """The keywords 'spaceid experiment' hands to run_experiment (which is stopped there)."""
    import spaceid.studies

    seen = []

    def stop(**kwargs):
        seen.append(kwargs)
        raise spaceid.SpaceidError("stop here")

    monkeypatch.setattr(spaceid.studies, "run_experiment", stop)
    return seen


def test_capture_mass_is_deprecated_for_the_settings_file(tmp_path, capsys, experiment_settings):
    settings = tmp_path / "capture.yaml"
    settings.write_text("mass: 0.6\n")
    out = ["--out", str(tmp_path / "x")]
    assert main(["experiment", "--capture", "--capture-settings", str(settings), *out]) == 2
    assert not _warnings(capsys.readouterr().err)
    assert main(["experiment", "--capture", "--capture-mass", "0.6", *out]) == 2
    assert _warnings(capsys.readouterr().err) == ["warning: --capture-mass is deprecated: use --capture-settings FILE "
                                                  "holding 'mass: 0.6'; it will be removed in the next release"]
    new, old = (s["capture"] for s in experiment_settings)
    assert new.payload.mass == old.payload.mass == 0.6 and new.offset == old.offset and new.yaw == old.yaw
    assert "--capture-mass" not in CliRunner().invoke(app, ["experiment", "--help"]).output


def test_format_is_only_an_output_format(tmp_path, capsys, experiment_settings):
    """export --format urdf|yaml; the experiment's bag format is --bag-format (--format deprecated)."""
    shown = {name for name, command in app.commands.items() for p in command.params
             if isinstance(p, click.Option) and not p.hidden and "--format" in p.opts}
    assert shown == {"export"}
    out = ["--out", str(tmp_path / "x")]
    assert main(["experiment", "--bag-format", "mcap", *out]) == 2
    assert not _warnings(capsys.readouterr().err)
    assert main(["experiment", "--format", "mcap", *out]) == 2
    assert _warnings(capsys.readouterr().err) == ["warning: --format is deprecated: use --bag-format mcap; it will be "
                                                  "removed in the next release"]
    assert [s["bag_format"] for s in experiment_settings] == ["mcap", "mcap"]
    assert main(["experiment", "--format", "bag", *out]) == 2  # the new option's check
    assert "Invalid value for '--bag-format': 'bag' is not one of 'ros1', 'ros2', 'mcap'" in capsys.readouterr().err


# --- the deprecated spellings, all of them ---------------------------------------------------------

DEPRECATED_SPELLINGS = {("validate", "-o/--output"), ("identify", "--differentiate"), ("payload", "--differentiate"),
                        ("validate", "--differentiate"), ("monitor", "--differentiate"), ("experiment", "--format"),
                        ("experiment", "--capture-mass")}


def test_every_old_spelling_is_a_hidden_deprecated_option():
    """The hidden options are exactly the old spellings tested above, each one _Deprecated (one
    warning line, see _Deprecated), with a help line naming its replacement (sphinx-click and
    --help leave it out)."""
    hidden = {(name, "/".join(p.opts)) for name, command in app.commands.items() for p in command.params
              if getattr(p, "hidden", False)}
    assert hidden == DEPRECATED_SPELLINGS
    for name, spelling in hidden:
        p = next(p for p in app.commands[name].params if "/".join(p.opts) == spelling)
        assert isinstance(p, spaceid.cli._Deprecated) and p.help.startswith("Deprecated: use ")
        assert spelling.split("/")[-1] not in CliRunner().invoke(app, [name, "--help"]).output
