"""Errors for the caller who made the mistake: a library message names the Python argument in
backquotes, never a command-line option; the command line shows each such name as an option
that exists (``spaceid.cli.for_the_command_line``, ``OPTION_OF``)."""

import ast
import functools
import re
from pathlib import Path

import click
import numpy as np
import pytest

import spaceid
from spaceid import SpaceidError
from spaceid import cli
from spaceid._atomic import check_output_folder
from spaceid._campaign import resolve_scheduler, run_campaign
from spaceid.data import bag_chunks, differentiate, follow_log
from spaceid.estimation import Noise, cramer_rao, cramer_rao_angles, identify, parse_drift, parse_known
from spaceid.estimation import parse_momentum
from spaceid.identified import export_model, identified_model, identify_payload, payload_after_grasp, payload_map
from spaceid.identified import write_export
from spaceid.motion import add_noise, design_excitation, load_trajectory, simulate
from spaceid.studies import run_experiment, run_montecarlo, run_sweep, validate_torques
from spaceid.twin import run_twin

SRC = Path(spaceid.__file__).parent
FLAG = re.compile(r"(?<![\w-])--[a-z]")  # a command-line option
ARGUMENT = re.compile(r"(?<![`\w:])`([A-Za-z_][A-Za-z0-9_]*(?:\.[A-Za-z_][A-Za-z0-9_]*)*)`(?!`)")
H = np.array([0.0, 0.0, 0.4934])
TRAJ = load_trajectory("paper-table2")


@pytest.fixture(scope="module")
def case():
    """Cepheus, a short noise-free log of the paper's trajectory, its identification and payload map."""
    param = spaceid.minimal_parameters(spaceid.load_model("cepheus"))
    log = simulate(param, param.true_values, lambda t: TRAJ.evaluate(t)[:2], np.linspace(0, 5, 51), H)
    dense = simulate(param, param.true_values, lambda t: TRAJ.evaluate(t)[:2], np.linspace(0, 5, 201), H)
    result = identify(param, log, H, estimator="ols")
    return {"param": param, "log": log, "dense": dense, "result": result, "pmap": payload_map("cepheus", "link2")}


def _foreign_folder(tmp_path):
    (tmp_path / "theirs.txt").write_text("not spaceid's")
    return tmp_path


def _follow(tmp_path):
    return next(follow_log(tmp_path / "never.csv", joints=("a",), planar=True, timeout=0.01))


MONTECARLO = dict(samples=35, momentum=H, noise=Noise(angle=1e-4, rate=1e-4), runs=4, estimators=("ols",), jobs=1)
SWEEP = dict(momentum=H, durations=[5.0], harmonics=[3], samples=[30], jobs=1)
DESIGN = dict(duration=5.0, harmonics=3, samples=35, momentum=H)

# (what is wrong, the call, the argument its message must name)
CASES = [
    # estimation
    ("unknown estimator", lambda c, p: identify(c["param"], c["log"], H, estimator="lsq"), "estimator"),
    ("unknown drift kind", lambda c, p: identify(c["param"], c["log"], H, drift=["wind"]), "drift"),
    ("drift with the angles estimator",
     lambda c, p: identify(c["param"], c["log"], H, estimator="angles", drift=["viscous"]), "drift"),
    ("no scale anchor", lambda c, p: identify(c["param"], c["log"], np.zeros(3)), "known"),
    ("anchor of no parameter", lambda c, p: identify(c["param"], c["log"], H, known={"m_base": 1.0}), "known"),
    ("zero chunk", lambda c, p: identify(c["param"], c["log"], H, chunk=0), "chunk"),
    ("chunk of an in-memory estimator", lambda c, p: identify(c["param"], c["log"], H, estimator="tls", chunk=100),
     "chunk"),
    ("negative noise level", lambda c, p: Noise(angle=-1.0), "noise.angle"),
    ("bound with an unknown drift kind",
     lambda c, p: cramer_rao(c["param"], c["log"], H, Noise(rate=1e-3), drift={"wind": 1e-4}), "drift"),
    ("angles bound without angle noise", lambda c, p: cramer_rao_angles(c["param"], c["dense"], H, Noise(rate=1e-3)),
     "noise.angle"),
    ("momentum not a number", lambda c, p: parse_momentum("abc", planar=True), "momentum"),
    ("planar momentum out of the plane", lambda c, p: parse_momentum("1,2,0.5", planar=True), "momentum"),
    ("known without a value", lambda c, p: parse_known(["Iczz_wheel"]), "known"),
    ("drift values where kinds are wanted", lambda c, p: parse_drift("viscous=1", planar=True, values=False), "drift"),
    ("drift value not a number", lambda c, p: parse_drift("viscous=abc", planar=True, values=True), "drift"),
    # identified
    ("region not a probability", lambda c, p: export_model(c["result"], "cepheus", region=1.5), "region"),
    ("unknown export format", lambda c, p: write_export(None, p / "x.step", fmt="step"), "fmt"),
    ("payload link not a body", lambda c, p: payload_map("cepheus", "gripper"), "link"),
    ("payload map of another link", lambda c, p: identify_payload(c["pmap"], c["log"], "link1", H), "link"),
    ("held momentum without the grasp", lambda c, p: identify_payload(c["pmap"], c["log"], "link2", "hold"),
     "momentum"),
    ("grasp outside the log", lambda c, p: payload_after_grasp(c["pmap"], c["log"], "link2", 99.0, H), "grasp"),
    ("momentum word not known", lambda c, p: payload_after_grasp(c["pmap"], c["log"], "link2", 2.5, "spin"),
     "momentum"),
    ("identified values of another shape", lambda c, p: identified_model(c["result"]).with_values(np.ones(2)), "pi"),
    # studies
    ("Monte Carlo without noise", lambda c, p: run_montecarlo(c["param"], TRAJ, **{**MONTECARLO, "noise": Noise()}),
     "noise"),
    ("one Monte Carlo run", lambda c, p: run_montecarlo(c["param"], TRAJ, **{**MONTECARLO, "runs": 1}), "runs"),
    ("no estimator", lambda c, p: run_montecarlo(c["param"], TRAJ, **{**MONTECARLO, "estimators": ()}), "estimators"),
    ("samples and times", lambda c, p: run_montecarlo(c["param"], TRAJ, **MONTECARLO, times=[0.0, 1.0]), "samples"),
    ("duration beyond the trajectory",
     lambda c, p: run_montecarlo(c["param"], TRAJ, **MONTECARLO, duration=50.0), "duration"),
    ("designed trajectory without its duration",
     lambda c, p: run_montecarlo(c["param"], "designed", **MONTECARLO), "trajectory"),
    ("unknown scheduler", lambda c, p: run_montecarlo(c["param"], TRAJ, **MONTECARLO, scheduler="threads"),
     "scheduler"),
    ("resume without a folder", lambda c, p: run_montecarlo(c["param"], TRAJ, **MONTECARLO, resume=True), "resume"),
    ("empty sweep grid", lambda c, p: run_sweep(c["param"], **{**SWEEP, "durations": []}), "durations"),
    ("one sweep sample", lambda c, p: run_sweep(c["param"], **{**SWEEP, "samples": [1]}), "samples"),
    ("no local search", lambda c, p: run_sweep(c["param"], **SWEEP, n_starts=0), "n_starts"),
    ("no worker", lambda c, p: run_sweep(c["param"], **{**SWEEP, "jobs": 0}), "jobs"),
    ("unknown bag format", lambda c, p: run_experiment(bag_format="zip"), "bag_format"),
    ("too few experiment samples", lambda c, p: run_experiment(samples=5), "samples"),
    ("negative rehearsals", lambda c, p: run_experiment(rehearsals=-1), "rehearsals"),
    ("torque validation without efforts", lambda c, p: validate_torques(c["result"], c["log"], horizon=-1.0), None),
    # motion
    ("noise-aware design without noise", lambda c, p: design_excitation(c["param"], **DESIGN, criterion="crb"),
     "noise.angle"),
    ("unknown design criterion", lambda c, p: design_excitation(c["param"], **DESIGN, criterion="aopt"), "criterion"),
    ("design noise of another type", lambda c, p: design_excitation(c["param"], **DESIGN, criterion="crb", noise=1e-3),
     "noise"),
    ("negative added noise", lambda c, p: add_noise(c["log"], angle=-1.0), "angle"),
    ("unknown simulated drift term",
     lambda c, p: simulate(c["param"], c["param"].true_values, lambda t: TRAJ.evaluate(t)[:2], [0.0, 1.0], H,
                           drift={"wind": 1e-4}), "drift"),
    # data, models, twin
    ("even differentiator window", lambda c, p: differentiate(np.linspace(0, 1, 50), np.ones(50), window=4), "window"),
    ("twin effort not callable", lambda c, p: run_twin(None, duration=0.01, effort=np.zeros(2)), "effort"),
    ("negative twin duration", lambda c, p: run_twin(None, duration=-1.0), "duration"),
    ("no bag block", lambda c, p: next(bag_chunks(p / "r.bag", joints=("a",), planar=True, block=0)), "block"),
    ("log never written", lambda c, p: _follow(p), "timeout"),
    ("planar mode of a spatial robot", lambda c, p: spaceid.load_model("satellite-7dof", planar=True), "planar"),
    # campaigns, output folders
    ("scheduler name", lambda c, p: resolve_scheduler("threads"), "scheduler"),
    ("resume without a study folder", lambda c, p: run_campaign(print, None, {}, resume=True), "resume"),
    ("folder of someone else's files", lambda c, p: check_output_folder(_foreign_folder(p), "`out`"), "overwrite"),
]


@pytest.mark.parametrize("call, argument", [c[1:] for c in CASES], ids=[c[0] for c in CASES])
def test_a_library_error_names_the_argument_not_an_option(case, tmp_path, call, argument):
    with pytest.raises(SpaceidError) as info:
        call(case, tmp_path)
    message = str(info.value)
    assert not FLAG.search(message), message
    assert argument is None or f"`{argument}`" in message, message


def test_cases_span_the_library():
    assert len({c[0] for c in CASES}) == len(CASES) >= 25


def test_warnings_name_the_argument(case):
    drifting = simulate(case["param"], case["param"].true_values, lambda t: TRAJ.evaluate(t)[:2],
                        np.linspace(0, 5, 101), H, drift={"viscous": 5e-4})
    with pytest.warns(UserWarning) as caught:
        identify(case["param"], add_noise(drifting, angle=1e-4, rate=1e-3, seed=0), H)
    messages = [str(w.message) for w in caught]
    assert any("model it with `drift`" in m for m in messages), messages
    assert not any(FLAG.search(m) for m in messages), messages


@functools.cache  # two tests scan every module: parsed once
def _message_strings(path):
    """The string constants of a module that are not docstrings (a statement of its own)."""
    tree = ast.parse(path.read_text(encoding="utf-8"))
    docs = {id(n.value) for n in ast.walk(tree) if isinstance(n, ast.Expr) and isinstance(n.value, ast.Constant)}
    return [n for n in ast.walk(tree) if isinstance(n, ast.Constant) and isinstance(n.value, str) and id(n) not in docs]


def _library_modules():
    return [p for p in sorted(SRC.rglob("*.py")) if p.name != "cli.py"]


def test_no_library_string_names_a_command_line_option():
    built = re.compile(r"\s--$")  # an f-string's text before an option built from a value: "give --{key}"
    found = [f"{p.relative_to(SRC)}:{s.lineno}: {s.value[:60]!r}" for p in _library_modules()
             for s in _message_strings(p) if FLAG.search(s.value) or built.search(s.value)]
    assert not found, "\n".join(found)


# Python arguments that library messages name but no command sets, each with why the command line
# never shows them (it checks the value first, or never passes the argument).
NO_OPTION = {
    "identify_options": "run_spatial_experiment's keywords for identify: spaceid experiment passes none",
    "angle": "add_noise's angle noise: simulate checks --noise-angle before it adds noise",
    "boundary": "optimize_excitation's boundary values: the design command keeps the default",
    "initial": "optimize_excitation's warm start: the design command gives none",
    "method": "optimize_excitation's search method, differentiate's differentiator: the commands keep 'auto'",
    "smoothing": "differentiate's spline smoothing: the commands use Savitzky-Golay filters",
    "regressor": "optimize_excitation's regressor callable: design_excitation builds it",
    "n_grid": "optimize_excitation's limit-check grid: the design command keeps the default",
    "n_screen": "optimize_excitation's screened starts: the design command keeps the default",
    "patience": "optimize_excitation's patience: the design command keeps the default",
    "frame": "IdentifiedModel.frame_velocity's frame: no command computes frame velocities",
    "point": "IdentifiedModel.frame_velocity's point: no command computes frame velocities",
    "pi": "IdentifiedModel.with_values' parameters and simulate's: no command gives them as numbers",
    "grasp_motion.cov": "identify_payload's grasp motion: payload_after_grasp builds it from --payload-velocity, "
                        "--payload-rate",
    "hold": "validate_torques' effort interpolation: the validate command keeps 'linear'",
    "times": "run_montecarlo's and computed_torque's sample times: the commands give --samples",
    "effort": "run_twin's feed-forward efforts: the experiment command plans them itself",
    "controller": "run_twin's controller hook: the experiment command uses the twin's PID loops",
    "state": "run_twin's starting state: the experiment command chains the runs itself",
    "settings": "run_twin's TwinSettings: the experiment command builds them (its --capture-settings file is "
                "checked field by field, named as the file's keys)",
    "stride": "computed_torque's planning stride: no command calls it",
    "model": "simulate's physical model: the simulate command always passes its MODEL",
    "true": "the true values of parameter_table, plot_parameters, write_markdown_report: the commands know them",
    "reference": "run_twin's set points, and the reference values of parameter_table, plot_parameters, "
                 "write_markdown_report: the experiment command gives them itself",
    "reference_true": "the reference's true values in parameter_table, write_markdown_report: likewise",
}
# names that messages form at run time (``f"`{name}` must be ..."``), not visible to the scan below
DYNAMIC = ("harmonics", "samples", "n_starts", "n_grid", "seed", "max_steps", "n_screen", "patience", "q_max",
           "qd_max", "qdd_max", "window", "order")


def _commands(group):
    """Every command of ``group``, those of its subgroups (``spaceid ros ...``) too."""
    for command in group.commands.values():
        yield from _commands(command) if isinstance(command, click.Group) else [command]


def _options():
    options = set()
    for command in _commands(cli.app):
        for param in command.params:
            if isinstance(param, click.Option):
                options |= {o for o in (*param.opts, *param.secondary_opts) if o.startswith("--")}
    return options


def _exists(flag, options):
    return flag in options or flag.endswith("*") and any(o.startswith(flag[:-1]) for o in options)


def test_every_argument_a_message_names_is_an_option_of_some_command():
    names = {m[1] for p in _library_modules() for s in _message_strings(p) for m in ARGUMENT.finditer(s.value)}
    assert {"estimator", "drift", "noise.angle", "out"} <= names  # the scan finds them
    options = _options()
    missing = {}
    for name in sorted(names | set(DYNAMIC)):
        shown = cli.for_the_command_line(f"`{name}`")
        if not all(_exists(flag, options) for flag in shown.split(", ")) and name not in NO_OPTION:
            missing[name] = shown
    assert not missing, f"no command has these options (map them in cli.OPTION_OF, or allow them): {missing}"
    unused = set(NO_OPTION) - names - set(DYNAMIC)
    assert not unused, f"allowed but no longer named by any message: {unused}"
    assert all(not _exists(cli.for_the_command_line(f"`{n}`"), options) for n in NO_OPTION)  # else: not needed


def test_the_command_line_shows_options():
    show = cli.for_the_command_line
    assert show("`drift`: 'wind' is not a drift kind") == "--drift: 'wind' is not a drift kind"
    assert show("give `noise.base_rate` or `noise`") == "give --noise-base-rate or --noise-*"
    assert show("`n_starts`, `bag_format`, `estimators`") == "--starts, --bag-format, --estimator"
    assert show("`out` folder") == "--out folder"


def test_the_command_line_shows_a_library_error_with_its_options(tmp_path, capsys):
    log = tmp_path / "log.csv"
    assert cli.main(["simulate", "cepheus", "--trajectory", "paper-table2", "--momentum", "0.4934", "--samples",
                     "30", "-o", str(log)]) == 0
    capsys.readouterr()
    assert cli.main(["identify", "cepheus", str(log), "--momentum", "0.4934", "--drift", "wind",
                     "-o", str(tmp_path / "r.json")]) == 2
    assert "error: --drift: 'wind' is not a drift kind" in capsys.readouterr().err
