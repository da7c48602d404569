"""The ``spaceid`` command: thin commands, each one library call.

Bad input raises :class:`spaceid.SpaceidError` in the library; here, and only here (``_Group``),
it becomes a one-line ``error: ...`` on stderr and exit code 2; any other exception is an internal
error (exit code 1), an interrupt ends the command with exit code 130 (SIGINT) or 143 (SIGTERM).
Before a command starts, ``_Command`` checks that no output goes over an input and that output
folders are spaceid's (``spaceid._atomic``). The consoles never read user text as markup.
"""

from __future__ import annotations

import atexit
import contextlib
import dataclasses
import functools
import json
import os
import re
import signal
import sys
import threading
import traceback
import time
import warnings
from pathlib import Path
import click
import numpy as np
from rich.console import Console
from rich.progress import BarColumn, Progress, TextColumn, TimeElapsedColumn

from ._constants import (BAG_FORMATS, BASE_RATES, CHANGE_RATIO, DEFAULT_JOINT_TOPIC, DEFAULT_POSE_TOPIC,
                         DESIGN_CRITERIA, ESTIMATORS, EXPORT_FORMATS, FALSE_ALARM_RATE, JOINT_RATES, KNOT_SPACING,
                         WARMUP)
from ._errors import SpaceidError, one_line, shown_name

# No markup, no emoji codes: file, joint and topic names like 'a[/b].csv' print as they are
out = Console(markup=False, emoji=False)
err = Console(stderr=True, markup=False, emoji=False)
ISSUES = "the spaceid issue tracker"  # where internal errors are to be reported (the project publishes no URL yet)


class _Number(click.ParamType):
    """A number option checked before any work starts: finite (no nan, inf), an integer when
    ``integer`` (``1e3`` is accepted as 1000), at least ``minimum``, above ``above``, at most
    ``maximum``. A bad value raises :class:`spaceid.SpaceidError` naming the option and ``fix``
    (one ``error:`` line, exit code 2), like the library's own checks."""

    def __init__(self, *, integer=False, minimum=None, above=None, maximum=None, fix=""):
        self.integer, self.minimum, self.above, self.maximum, self.fix = integer, minimum, above, maximum, fix
        self.name = "integer" if integer else "float"

    def _expected(self):
        bounds = [f">= {self.minimum:.12g}" if self.minimum is not None else "",
                  f"> {self.above:.12g}" if self.above is not None else "",
                  f"<= {self.maximum:.12g}" if self.maximum is not None else ""]
        return " and ".join(filter(None, [" ".join(["an integer" if self.integer else "a finite number",
                                                        bounds[0] or bounds[1]]).strip(), bounds[2]]))

    def convert(self, value, param, ctx):
        if isinstance(value, (int, float)) and not isinstance(value, bool):
            number = value
        else:
            try:
                number = float(str(value).strip())
            except ValueError:
                number = None
        ok = number is not None and np.isfinite(number) and (not self.integer or float(number).is_integer())
        ok = ok and (self.minimum is None or number >= self.minimum) and (self.above is None or number > self.above)
        if not ok or self.maximum is not None and number > self.maximum:
            option = param.opts[-1] if param is not None else "value"
            raise SpaceidError(f"{option}: {value} is not {self._expected()}: {self.fix}".rstrip(": "))
        return int(number) if self.integer else float(number)


SEED_VALUE = _Number(integer=True, minimum=0, maximum=2**32 - 1, fix="give a non-negative integer (below 2^32)")
NOISE_LEVEL = _Number(minimum=0, fix="give a standard deviation >= 0 (0: no noise)")
RATE = _Number(above=0, fix="give a sample rate in Hz (e.g. 100)")
SAMPLES = _Number(integer=True, minimum=2, fix="give 2 or more samples")
SECONDS = _Number(above=0, fix="give a positive time in seconds")
POSITIVE = _Number(above=0, fix="give a positive number")
FINITE = _Number(fix="give a finite number")
HARMONICS = _Number(integer=True, minimum=1, maximum=50, fix="give 1 to 50 Fourier harmonics (3-5 are usual)")
STARTS = _Number(integer=True, minimum=1, maximum=10_000, fix="give 1 to 10000 starts")
RUNS = _Number(integer=True, minimum=2, maximum=100_000,
               fix="give 2 to 100000 noise draws (200 or more for stable statistics)")
JOBS = _Number(integer=True, minimum=1, maximum=1024, fix="give 1 or more worker processes")
PROBABILITY = _Number(above=0, maximum=0.999999, fix="give a probability between 0 and 1, e.g. 0.95")
RATIO = _Number(above=1, fix="give a variance ratio above 1, e.g. 4")
FORGETTING = _Number(above=0, maximum=1, fix="give a forgetting factor in (0, 1], e.g. 0.999 (1: none)")

MODEL = click.argument("model_src", metavar="MODEL")
PLANAR = click.option("--planar/--spatial", default=None,
                      help="Force planar (x, y, yaw) or spatial mode; default: the model's.")
MOMENTUM_METAVAR = "H|HX,HY,HZ"
MOMENTUM = click.option("--momentum", required=True, metavar=MOMENTUM_METAVAR, help="Angular momentum of the whole "
                        "system [N m s]: h (planar) or hx,hy,hz (inertial axes); 0 if it started at rest.")
SEED = click.option("--seed", type=SEED_VALUE, default=0, show_default=True,
                    help="Seed of every random choice (recorded in the output).")
SCHEDULER = click.option("--scheduler", metavar="SCHEDULER", help="Where the tasks run: processes (a local process "
                         "pool of --jobs), dask (a Dask LocalCluster of --jobs workers) or tcp://HOST:PORT (a running "
                         "'dask scheduler' and its workers); the numbers do not depend on it [default: "
                         "DASK_SCHEDULER_ADDRESS if set, else processes].")
RESUME = click.option("--resume", is_flag=True, help="Keep the task results an interrupted run of the same settings "
                      "left beside --out (in .FOLDER.tasks/) and run only the others (without it they are removed).")
NOISE = [
    click.option("--noise-angle", type=NOISE_LEVEL, default=0.0, help="White noise on angles [rad]."),
    click.option("--noise-rate", type=NOISE_LEVEL, default=0.0, help="White noise on rates [rad/s]."),
]

SENSORS = [
    click.option("--noise-attitude", type=NOISE_LEVEL, help="Star-tracker noise, a small rotation per base axis "
                 "[rad] (planar: the yaw) [default: --noise-angle]."),
    click.option("--noise-base-rate", type=NOISE_LEVEL, help="Gyro white noise per axis [rad/s] "
                 "[default: --noise-rate]."),
    click.option("--quantum", type=POSITIVE, metavar="RAD", help="Encoder resolution [rad or m per count]: the joint "
                 "angles are rounded to it after the noise."),
    click.option("--gyro-bias", metavar="B|BX,BY,BZ", help="Constant gyro bias added to the measured base rate "
                 "[rad/s]: about z (planar) or base axes (spatial); 'identify --gyro-bias' estimates it."),
    click.option("--joint-rate-sensors/--no-joint-rate-sensors", default=True, show_default=True,
                 help="Whether the joints have rate sensors; without, the log has no joint-rate columns (identify "
                 "differentiates the angles or uses --estimator angles)."),
]


def _gyro_bias(value) -> list:
    """``--gyro-bias B|BX,BY,BZ`` as a list of numbers (checked against the model by ``add_noise``)."""
    try:
        return [float(v) for v in value.split(",")]
    except ValueError:
        raise SpaceidError(f"`gyro_bias`: {value!r} is not a number or three comma-separated numbers [rad/s]") from None


def drift_option(help_text, *, values):
    """The ``--drift`` option, one grammar in every command: a comma list where a bare ``KIND``
    estimates that drift term and ``KIND=VALUE`` sets it (``none``: no drift terms), read by
    :func:`spaceid.estimation.parse_drift` (:func:`_drift`); ``values``: the command sets terms
    (``simulate``, ``predict``, ``validate``), else it estimates them, and the help says so."""
    if values:
        metavar, grammar = "KIND=VALUE[,...]", ("KIND=VALUE sets a term ('none': none); a bare KIND, a term to "
                                                "estimate, is for identify, payload, monitor and experiment.")
    else:
        metavar, grammar = "KIND[,KIND...]", ("A bare KIND estimates a term ('none': none); KIND=VALUE, a term held at "
                                              "a value, is for simulate, predict and validate.")
    return click.option("--drift", metavar=metavar, help=f"{help_text} {grammar}")


def _drift(value, planar, *, values):
    """``--drift`` of the running command (:func:`drift_option`): its kinds, or with ``values`` its
    terms; the other form refused naming the command."""
    from .estimation import parse_drift

    return parse_drift(value, planar=planar, values=values, command=click.get_current_context().info_name)


DRIFT_VALUES = drift_option("External torque on the base, so that the momentum drifts from its --momentum value at "
                            "t0: torque=TAU (constant torque [N m], about z for planar, TX:TY:TZ inertial axes for "
                            "spatial; or torque_x=.. per axis), viscous=C (friction -C w0, [N m s/rad]), coulomb=MU "
                            "(friction -MU w0/norm(w0), [N m]); e.g. --drift torque=1e-4,viscous=5e-5.", values=True)
ESTIMATOR_HELP = ("ml: maximum likelihood, errors in variables (unbiased, efficient); wls: weighted least squares "
                  "(noise-model weights, small bias); iv: instrumental variables (signals free of the measurement "
                  "noise as instruments); tls: total least squares (for comparison with the literature); ols: "
                  "ordinary least squares, the paper's Eq. 11 (fast, no noise model, biased by noise); angles: maximum "
                  "likelihood on the joint angles and base attitude alone, no rates (>= 40 Hz).")


class _OutputPath(click.Path):
    """The type of an option naming an output, a file or (``folder``) a report folder: the
    command checks it against its inputs before it starts (:meth:`_Command.invoke`)."""

    def __init__(self, folder: bool = False):
        super().__init__(path_type=Path)
        self.folder = folder


def output(help_text):
    """The required ``-o/--output`` option: the file the command writes (``help_text`` says what)."""
    return click.option("-o", "--output", type=_OutputPath(), required=True, metavar="PATH", help=help_text)


def out_folder(help_text, **kwargs):
    """The ``--out DIR`` option: the report folder the command writes (``help_text`` says what),
    handed to the command as ``folder``; ``kwargs``: its default, or ``required=True``."""
    return click.option("--out", "folder", type=_OutputPath(folder=True), metavar="DIR", help=help_text, **kwargs)


def report_option(what):
    """The ``--report PATH`` option: the interactive HTML report written beside the command's
    ``-o`` file (docs/formats/report-html.md)."""
    return click.option("--report", type=_OutputPath(), metavar="PATH", help=f"Interactive HTML report of {what} "
                        "(self-contained: opens offline) [default: -o's name with .html].")


def _report_path(report, output):
    """``--report``, or ``output`` with the suffix .html: checked like an output (never -o itself)."""
    from ._atomic import check_output_file

    path = Path(report) if report is not None else Path(output).with_suffix(".html")
    if os.path.abspath(path) == os.path.abspath(output):
        raise SpaceidError(f"--report {shown_name(path)} is the -o file: give another name")
    if report is None:
        check_output_file(path, "--report", click.get_current_context().meta.get("spaceid.inputs", ()))
    return path


OVERWRITE = click.option("--overwrite", is_flag=True, help="Write into an output folder that holds files spaceid did "
                         "not write (beside them; same names replaced); without it such a folder is refused.")
REMOVED_IN = "the next release"  # when the deprecated spellings (_Deprecated) go


class _Deprecated(click.Option):
    """An old spelling kept for one release: hidden from the help; when given, one line on stderr,
    ``warning: OPTION is deprecated: use INSTEAD; it will be removed in the next release``
    (``instead`` may quote the value given as ``{value}``). With ``into`` (the name of the option
    that replaces it) the value given, or ``value`` for a flag, is handed to that option as if it
    had been given (the same checks, the same messages); an old and a new spelling of different
    values are refused. Without ``into`` the command receives it as its own argument."""

    def __init__(self, *decls, instead, into=None, value=None, **kwargs):
        kwargs.setdefault("help", f"Deprecated: use {instead}.")
        super().__init__(*decls, hidden=True, expose_value=into is None, **kwargs)
        self.instead, self.into, self.into_value = instead, into, value

    def handle_parse_result(self, ctx, opts, args):
        given = self.name in opts and not ctx.resilient_parsing
        if given:
            raw = opts[self.name]
            spelling = "/".join(self.opts)
            print(f"warning: {spelling} is deprecated: use {self.instead.format(value=raw)}; it will be removed in "
                  f"{REMOVED_IN}", file=sys.stderr)
            if self.into is not None:
                new = self.into_value if self.into_value is not None else raw
                if self.into in opts and opts[self.into] != new:
                    option = min(next(p for p in ctx.command.params if p.name == self.into).opts, key=len)
                    raise SpaceidError(f"{spelling} (deprecated) and {option} {opts[self.into]} contradict each other: "
                                       f"give {option} alone")
                opts[self.into] = new  # parsed before the option it stands for (click parses given options first)
        return super().handle_parse_result(ctx, opts, args)


class _Command(click.Command):
    """A command whose usage line also lists its required options (click leaves them in [OPTIONS]),
    and whose outputs are checked before it starts: never over an input, never into a folder of
    someone else's files (unless --overwrite), never into a read-only place."""

    def collect_usage_pieces(self, ctx):
        required = [f"{p.opts[-1]} {p.make_metavar(ctx)}" for p in self.get_params(ctx)
                    if isinstance(p, click.Option) and p.required]
        return super().collect_usage_pieces(ctx) + required

    def invoke(self, ctx):
        """Check the outputs against the inputs (recorded in ``ctx.meta``), then run the command."""
        from ._atomic import check_output_file, check_output_folder

        outputs = [p for p in self.get_params(ctx) if isinstance(p.type, _OutputPath) and ctx.params.get(p.name)]
        inputs = [(_label(p), Path(v)) for p in self.get_params(ctx) if p not in outputs
                  for v in _values(ctx.params.get(p.name)) if os.path.exists(v)]
        ctx.meta["spaceid.inputs"] = inputs
        for p in outputs:
            option = min(p.opts, key=len)
            if p.type.folder:
                check_output_folder(ctx.params[p.name], option, overwrite=ctx.params.get("overwrite", False),
                                    inputs=inputs)
            else:
                check_output_file(ctx.params[p.name], option, inputs)
        return super().invoke(ctx)


def _label(param) -> str:
    """How messages name a parameter: an argument by its metavar (LOG), an option by its long flag."""
    if isinstance(param, click.Argument):
        return (param.metavar or param.name.upper()).strip("[]")
    return max(param.opts, key=len)


def _values(value) -> list:
    """The strings among a parameter's value(s) that may name a file."""
    values = value if isinstance(value, (tuple, list)) else [value]
    return [str(v) for v in values if isinstance(v, (str, Path)) and str(v)]


@contextlib.contextmanager
def _report_folder(folder, overwrite):
    """The temporary folder to write the command's report into; on success it becomes ``folder``
    (``spaceid._atomic.atomic_folder``), on an error or interrupt it is removed."""
    from ._atomic import atomic_folder

    ctx = click.get_current_context()
    with atomic_folder(folder, command=ctx.command_path, overwrite=overwrite,
                       inputs=ctx.meta.get("spaceid.inputs", ())) as tmp:
        yield tmp


class _Terminated(BaseException):
    """SIGTERM, raised in the main thread so that the command unwinds (outputs removed, workers stopped)."""


def _on_sigterm(signum, frame):
    raise _Terminated


class _Group(click.Group):
    """The command group; every exception escaping a command ends in :meth:`invoke`."""

    command_class = _Command

    def invoke(self, ctx):
        """Run the command; turn what escapes it into one line on stderr and an exit code:
        ``error: ...`` (2) for a SpaceidError, a numerical failure or a file-system error,
        ``interrupted`` (130 for SIGINT, 143 for SIGTERM), ``internal error: ...`` (1) for
        anything else; ``--debug`` prints the traceback first."""
        try:
            return super().invoke(ctx)
        except (click.ClickException, click.exceptions.Exit, click.Abort):
            raise
        except BaseException as exc:  # noqa: B036 -- the one place that ends every command
            if ctx.params.get("debug"):
                traceback.print_exc()
            line, code = _failure(exc, ctx)
            print(one_line(line), file=sys.stderr)  # one line, never wrapped
            raise click.exceptions.Exit(code) from None


# Python argument -> the option that sets it, where the option is not the argument's name with
# dashes (``drift`` -> ``--drift``, ``noise.base_rate`` -> ``--noise-base-rate``). The one place
# where library messages meet the CLI's grammar.
OPTION_OF = {
    "noise": "--noise-*",
    "estimators": "--estimator",
    "n_starts": "--starts",
    "fmt": "--format",
    "timeout": "--follow-timeout",
    "payload_motion": "--payload-velocity, --payload-rate",
}
_ARGUMENT = re.compile(r"`([A-Za-z_][A-Za-z0-9_]*(?:\.[A-Za-z_][A-Za-z0-9_]*)*)`")


def for_the_command_line(text) -> str:
    r"""A library message as the command line shows it: one line, each Python argument named in
    backquotes (``\`drift\```, or a field of one, ``\`noise.angle\```) shown as its option
    (``--drift``, ``--noise-angle``; see ``OPTION_OF``)."""
    option = lambda m: OPTION_OF.get(m[1], "--" + re.sub(r"[_.]", "-", m[1]))  # noqa: E731
    return one_line(_ARGUMENT.sub(option, str(text)))


def _failure(exc, ctx) -> tuple:
    """The line and exit code of an exception that escaped a command (see :meth:`_Group.invoke`)."""
    if isinstance(exc, KeyboardInterrupt):
        return "interrupted", 130
    if isinstance(exc, _Terminated):
        return "interrupted", 143
    if isinstance(exc, SpaceidError):
        return f"error: {for_the_command_line(exc)}", 2
    if isinstance(exc, np.linalg.LinAlgError):  # NumPy's and SciPy's: an ill-conditioned input, not a bug
        inputs = ctx.meta.get("spaceid.inputs", [])  # click shares meta between a group and its command
        inputs = ", ".join(f"{label} {shown_name(path)}" for label, path in inputs) or "the input"
        return (f"error: numerical failure on {inputs} ({exc}): the data are too ill-conditioned for this "
                "computation: check their excitation, noise and units"), 2
    if isinstance(exc, OSError) and exc.strerror:
        where = f"{shown_name(exc.filename)}: " if exc.filename else ""
        return f"error: {where}{exc.strerror}: check the path, its permissions and the free space", 2
    if isinstance(exc, Exception):
        return (f"internal error: {type(exc).__name__}: {exc} (please report this at {ISSUES}; rerun with --debug "
                "for the traceback)"), 1
    raise exc


def sensor_levels(angle, rate, base_rate, attitude) -> dict:
    """The noise levels of the ``--noise-*`` options as :class:`spaceid.estimation.Noise`'s fields, the same in
    every command: an unset ``--noise-base-rate`` is ``--noise-rate`` and an unset ``--noise-attitude`` is
    ``--noise-angle`` (one level for joints and base alike, as ``simulate`` draws them), the others unset 0."""
    angle, rate = angle or 0.0, rate or 0.0
    return {"angle": angle, "rate": rate, "base_rate": rate if base_rate is None else base_rate,
            "attitude": angle if attitude is None else attitude}


def noise_options(f):
    """Options ``--noise-angle``, ``--noise-rate``, ``--noise-base-rate``, ``--noise-attitude``
    (standard deviations of the measured signals), handed to the command as one ``noise``
    argument: a :class:`spaceid.estimation.Noise` of :func:`sensor_levels`, or None when none is given."""
    names = ("angle", "rate", "base_rate", "attitude")

    @functools.wraps(f)
    def command(*args, **kwargs):
        values = {n: kwargs.pop(f"noise_{n}") for n in names}
        noise = None
        if any(v is not None for v in values.values()):
            from .estimation import Noise

            noise = Noise(**sensor_levels(**values))
        return f(*args, noise=noise, **kwargs)

    return _options(
        click.option("--noise-angle", type=NOISE_LEVEL, help="Noise std of the joint angles [rad]."),
        click.option("--noise-rate", type=NOISE_LEVEL, help="Noise std of the joint rates [rad/s]."),
        click.option("--noise-base-rate", type=NOISE_LEVEL,
                     help="Noise std of the base angular velocity, per axis [rad/s] [default: --noise-rate]."),
        click.option("--noise-attitude", type=NOISE_LEVEL,
                     help="Noise std of the base attitude, per axis [rad] (planar: the yaw) [default: "
                     "--noise-angle]."),
    )(command)


def _options(*decorators):
    def apply(f):
        for d in reversed(decorators):
            f = d(f)
        return f

    return apply


RATE_SOURCES = ("measured", *JOINT_RATES[::-1])
"""``--joint-rates``: the log's own rates (a CSV's rate columns, a bag's published velocities; also
spelled ``velocity``, the bag reader's word), the angles differentiated, or ``auto``: the log's own
where it has them all (a bag: per joint, where every message has one), else differentiated."""
BAG_ONLY = {"joint_topic": "--joint-topic", "pose_topic": "--pose-topic", "mapping": "--mapping",
            "base_rate": "--base-rate"}


def log_options(f):
    """Options of how a LOG is read, handed to the command as one ``reading`` argument (a dict,
    see :func:`_measured_log`): a bag's ``--joint-topic``, ``--pose-topic``, ``--mapping``, ``--base-rate``, and
    for a CSV and a bag alike where the rates come from and how they are differentiated,
    ``--joint-rates``, ``--window``, ``--quantum`` (``--differentiate``: the deprecated spelling
    of ``--joint-rates differentiate``)."""
    keys = (*BAG_ONLY, "joint_rates", "window", "quantum")

    @functools.wraps(f)
    def command(*args, **kwargs):
        return f(*args, reading={k: kwargs.pop(k) for k in keys}, **kwargs)

    return _options(
        click.option("--joint-topic", help="Bag logs (.bag, .mcap, ROS 2 bag folder): sensor_msgs/JointState topic "
                     f"[default: {DEFAULT_JOINT_TOPIC}]."),
        click.option("--pose-topic", help="Bag logs: the base's attitude topic, geometry_msgs/PoseStamped, "
                     f"nav_msgs/Odometry or sensor_msgs/Imu [default: {DEFAULT_POSE_TOPIC}]."),
        click.option("--mapping", type=click.Path(path_type=Path), help="Bag logs: YAML file with joint_topic, "
                     "pose_topic, joints {bag name: model name}, rate, pose_latency, max_gap, max_tilt, base_rate."),
        click.option("--base-rate", type=click.Choice(BASE_RATES), help="Bag logs: the base rate from the attitude "
                     "differentiated, or the gyro's: the angular velocity the pose topic's Odometry (twist) or Imu "
                     "messages carry, in base axes [default: attitude]."),
        click.option("--joint-rates", type=click.Choice(RATE_SOURCES), help="Where the rates come from, CSV and bag "
                     "logs alike: measured (a CSV's rate columns, base_w* included; a bag's published joint "
                     "velocities; 'velocity' is the same), differentiate (the angles, and the base attitude where a "
                     "CSV has no base-rate column: a gyro's rate is kept; Savitzky-Golay), auto (measured where the log has them: a CSV with every rate column, a bag's "
                     "joints whose every message has one; else differentiated). [default: a CSV's rate columns, "
                     "differentiated when it has none; a bag's angles differentiated (as 'spaceid experiment' reads "
                     "its bag: one-tick encoder velocities gave 6-17 times larger errors there); a bag's base rate "
                     "always comes from its poses]"),
        click.option("--window", type=click.IntRange(min=3), metavar="SAMPLES", help="Savitzky-Golay window of every "
                     "differentiated series [samples, odd; default: chosen per series for the least error it leaves in the estimate]. A "
                     "shorter one than the default lowers the smoothing bias that raises change alarms during fast "
                     "motion ('spaceid monitor'), at more noise."),
        click.option("--quantum", type=POSITIVE, metavar="RAD", help="Encoder resolution of the differentiated joint "
                     "angles [rad per count]."),
        click.option("--differentiate", cls=_Deprecated, is_flag=True, instead="--joint-rates differentiate",
                     into="joint_rates", value="differentiate"),
    )(command)


@click.group(cls=_Group, context_settings={"help_option_names": ["-h", "--help"]})
@click.option("--debug", is_flag=True, help="Print the traceback of an error (for a report).")
def app(debug):
    """Identify free-floating space manipulators from angular-momentum conservation."""


@contextlib.contextmanager
def _warnings_to_stderr():
    """Show the library's warnings from the block as ``warning: ...`` lines on stderr, every one."""
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        yield
    for w in caught:
        err.print(f"warning: {for_the_command_line(w.message)}", highlight=False, soft_wrap=True)  # one line each


def _print_joint_rates(log) -> None:
    """One line naming where a bag log's joint rates and base rate came from (nothing for a CSV log)."""
    from .data import JOINT_RATE_POLICY

    policy = log.meta.get("joint_rate_policy")
    if policy is None:
        return
    other = "velocity" if policy == "differentiate" else "differentiate"
    sources = ", ".join(f"{joint} {source}" for joint, source in log.meta["joint_rates"].items())
    base = log.meta.get("base_rate", "attitude")
    out.print(f"joint rates: '{policy}'{' (default)' if policy == JOINT_RATE_POLICY else ''}: {sources}; "
              f"--joint-rates {other} for the other; base rate: {base}"
              + (" (default: differentiated; --base-rate gyro for an odometry's or IMU's)" if base == "attitude"
                 else " (the pose messages' angular velocity)"), highlight=False)


@contextlib.contextmanager
def _progress(label: str, enabled: bool = True):
    """A rich progress bar fed through a ``progress(done, total)`` callback; when stderr is not a
    terminal (a log), a plain line at every tenth of the work instead."""
    if not enabled:
        yield None
        return
    if not err.is_terminal:
        printed = [None]

        def line(done, total):
            step = (10 * done // total, done == total) if total else None
            if step != printed[0]:
                printed[0] = step
                print(f"{label}: {done}/{total}" if total else f"{label}: {done}", file=sys.stderr, flush=True)

        yield line
        return
    columns = (TextColumn(label), BarColumn(), TextColumn("{task.percentage:>3.0f}%"), TimeElapsedColumn())
    with Progress(*columns, console=err, transient=True) as bar:
        task = bar.add_task(label, total=None)
        yield lambda done, total: bar.update(task, completed=done, total=total)


@contextlib.contextmanager
def _every(seconds, call):
    """``call`` that lets through its first call and then at most one every ``seconds`` [s]; on
    leaving the context, the last call held back, so that the last line shown is the last made
    (a progress line that agrees with the result printed after it)."""
    last, held = [-float("inf")], [None]

    def throttled(*args):
        now = time.monotonic()
        held[0] = args
        if now - last[0] >= seconds:
            last[0], held[0] = now, None
            call(*args)

    yield throttled
    if held[0] is not None:
        call(*held[0])


def _param(model_src, planar):
    from .models import load_model
    from .dynamics import minimal_parameters

    return minimal_parameters(load_model(model_src, planar=planar))


def _momentum(value, planar, *, allow_unknown=False):
    from .estimation import parse_momentum

    h = parse_momentum(value, planar=planar)
    if h is None and not allow_unknown:
        raise SpaceidError("--momentum unknown: only 'spaceid identify' estimates the momentum; give its value here")
    return h


SUMMARY_ROWS = 20
"""``spaceid model`` lists this many parameters (definitions cut to a line) and this many names
per identifiability list unless ``--all``: the servicer's 496 definitions fill thousands of lines;
``spaceid identify`` lists this many estimates and ``spaceid montecarlo`` this many parameters per
estimator unless ``--all``."""


@app.command(short_help="Identifiability report: bodies, joints, standard and minimal parameters.")
@MODEL
@PLANAR
@click.option("--json", "as_json", is_flag=True, help="Print JSON (every parameter, with its value and unit) "
              "instead of tables.")
@click.option("--all", "show_all", is_flag=True, help=f"Every parameter and definition in full (default: a summary, "
              f"the first {SUMMARY_ROWS} cut to a line).")
@click.option("--definitions", "definitions_file", type=_OutputPath(), metavar="FILE",
              help="Also write every definition to FILE, one 'name = definition  # [unit]' line each.")
def model(model_src, planar, as_json, show_all, definitions_file):
    """Identifiability report: bodies, joints, standard and minimal parameters."""
    from .dynamics import full_parameter_names, identifiability

    param = _param(model_src, planar)
    m = param.model
    ident = identifiability(param)
    description = param.to_dict()
    description["parameters"] = [{**p, "value": float(v)} for p, v in zip(description["parameters"], param.true_values)]
    info = {
        "model": m.name,
        "source": m.source,
        "planar": m.planar,
        "mass": m.mass,
        "bodies": [{"name": b.name, "parent": m.bodies[b.parent].name if b.parent >= 0 else None, "joint": b.joint,
                    "type": b.joint_type, "mass": b.mass} for b in m.bodies],
        "n_standard_parameters": 10 * len(m.bodies),
        "n_full_parameters": len(full_parameter_names(m)),
        "n_minimal_parameters": param.n_params,
        **description,
        "identifiability": ident.to_dict(),
    }
    if definitions_file is not None:
        _write_definitions(definitions_file, info, model_src)
    if as_json:
        print(json.dumps(info, indent=2))
        return
    _print_model(info, show_all)
    if definitions_file is not None:
        err.print(f"{param.n_params} definitions written to {shown_name(definitions_file)}")


def _print_model(info, show_all):
    """The terminal report of ``spaceid model``: ``info`` is its JSON, summarised unless ``show_all``."""
    from rich.table import Table
    from rich.text import Text

    out.print(Text.assemble((info["model"], "bold"), f"  ({info['source']}), "
                            f"{'planar' if info['planar'] else 'spatial'}, total mass {info['mass']:.6g} kg"))
    bodies = Table("body", "parent", "joint", "type", "mass [kg]", title="Bodies")
    for b in info["bodies"]:
        bodies.add_row(b["name"], b["parent"] or "-", b["joint"] or "(floating base)", b["type"], f"{b['mass']:.6g}")
    out.print(bodies)
    out.print(Text.assemble(
        f"standard parameters: {info['n_standard_parameters']} (10 per body); with lumped products: "
        f"{info['n_full_parameters']}; minimal identifiable set: ", (str(info["n_minimal_parameters"]), "bold"),
        f" (basis '{info['basis']}', rank tolerance {info['rank_tol']:g}, seed {info['seed']})"))
    params = info["parameters"]
    cut = not show_all and len(params) > SUMMARY_ROWS
    table = Table("", "unit", "value", "definition", title="Minimal parameters (model values)")
    table.columns[3].overflow = "fold"
    for p in params[:SUMMARY_ROWS] if cut else params:
        definition = Text(p["definition"], no_wrap=True, overflow="ellipsis") if cut else p["definition"]
        table.add_row(p["name"], p["unit"], f"{p['value']:.6g}", definition)
    out.print(table)
    if cut:
        out.print(f"the first {SUMMARY_ROWS} of {len(params)} parameters, definitions cut to a line: --all lists "
                  "them in full, --definitions FILE writes them to a file, --json prints everything")
    ident = info["identifiability"]
    verdict = "determines" if ident["determines_dynamics"] else "does NOT determine"
    out.print(f"The identified set {verdict} the reduced dynamics (kinetic energy with zero linear momentum; "
              f"residual {ident['energy_residual']:.1e}).")
    for key, label in [("no_effect", "no effect on the momentum (not identifiable)"),
                       ("individually_identifiable", "identifiable on their own"),
                       ("in_combinations", "identifiable only in the combinations above")]:
        names = ident[key]
        shown = names if show_all or len(names) <= SUMMARY_ROWS else names[:SUMMARY_ROWS] + [
            f"... {len(names) - SUMMARY_ROWS} more (--all)"]
        out.print(f"{label} ({len(names)}): {', '.join(shown) or 'none'}", highlight=False)


def _write_definitions(path, info, model_src):
    """The minimal parameters' definitions as text at ``path`` (atomically; never over the model
    file: ``_Command`` checks)."""
    from ._atomic import write_text_atomic

    lines = [f"# minimal parameters of {info['model']} ({info['source']}): name = definition  # [unit], model value"]
    lines += [f"{p['name']} = {p['definition']}  # [{p['unit']}], {p['value']:.6g}" for p in info["parameters"]]
    write_text_atomic(path, "\n".join(lines) + "\n")



def limit_options(f):
    """The design's joint limits: ``--q-max``, ``--qd-max``, ``--qdd-max`` (``design``, and
    ``experiment`` with a spatial model)."""
    for option in reversed((
        click.option("--q-max", type=POSITIVE, help="Joint angle limit, largest abs(q) [rad] (default: model limits)."),
        click.option("--qd-max", type=POSITIVE, help="Joint rate limit, largest abs(qd) [rad/s] (default: model "
                     "limits)."),
        click.option("--qdd-max", type=POSITIVE,
                     help="Joint acceleration limit, largest abs(qdd) [rad/s^2] (default: model limits)."),
    )):  # fmt: skip
        f = option(f)
    return f

@app.command(short_help="Optimal exciting trajectory (min cond(Y) or predicted error) under joint limits.")
@MODEL
@PLANAR
@click.option("--duration", type=SECONDS, required=True, metavar="TF", help="Trajectory duration tf [s].")
@click.option("--harmonics", type=HARMONICS, required=True, metavar="NF", help="Fourier harmonics Nf.")
@click.option("--samples", type=SAMPLES, required=True, metavar="N", help="Samples N, equally spaced over [0, tf].")
@click.option("--momentum", required=True, metavar=MOMENTUM_METAVAR, help="Angular momentum of the whole system "
              "[N m s]: h (planar) or hx,hy,hz (inertial axes); nonzero (with zero momentum Y pi = 0: no "
              "condition number to minimise).")
@SEED
@click.option("--criterion", type=click.Choice(DESIGN_CRITERIA), default="cond", show_default=True,
              help="cond (condition number), logdet (scaled columns), or with the --noise-* options: dopt (max "
              "log det of the Fisher information), crb (min trace of the relative Cramer-Rao bound).")
@noise_options
@limit_options
@click.option("--starts", type=STARTS, help="Local starts of the global search [default: by the problem's size, 64 for "
              "cepheus]; the search also stops once half of them (at least 8) in a row improve the best by under "
              "0.1 %.")
@click.option("--time-budget", type=SECONDS, help="Hard limit on the search's wall time [s]: the best trajectory "
              "so far is returned (then the result also depends on the machine's speed).")
@click.option("--max-steps", type=click.IntRange(min=1), metavar="N", help="Most linearisations of the regressor a "
              "local search makes (and each polish, for small regressors): a budget that gives the same trajectory "
              "on any machine [default: to convergence for small regressors, 40 for large ones].")
@click.option("--payload-link", metavar="LINK", help="Design for the parameters of a payload held by LINK (see "
              "'spaceid payload') instead of the minimal parameters (--momentum 0 allowed: the known servicer "
              "fixes the scale); with the --noise-* options the trajectory records the payload's predicted "
              "Cramer-Rao standard deviations.")
@click.option("--payload-nominal", type=click.Path(path_type=Path), metavar="PAYLOAD.json", help="With "
              "--payload-link: the nominal payload (a 'spaceid payload' output; default none, zero mass).")
@click.option("--jobs", type=JOBS, help="Worker processes [default: one per core].")
@SCHEDULER
@output("Trajectory JSON to write (for simulate, predict, identify --instruments).")
def design(model_src, planar, duration, harmonics, samples, momentum, seed, criterion, noise, q_max, qd_max, qdd_max,
           starts, time_budget, max_steps, payload_link, payload_nominal, jobs, scheduler, output):
    """Optimal exciting trajectory (Eq. 12): minimal condition number of the regressor, or, given
    the noise, minimal predicted estimation error; the noise and the predicted Cramer-Rao
    standard deviations are recorded in the trajectory."""
    from .motion import bound_summary, design_excitation

    param = _param(model_src, planar)
    h = _momentum(momentum, param.model.planar)
    if payload_nominal is not None and payload_link is None:
        raise SpaceidError("--payload-nominal needs --payload-link: name the link that holds the payload")
    nominal = None
    if payload_nominal is not None:
        from .identified import nominal_payload

        nominal = nominal_payload(payload_nominal, planar=param.model.planar)
    _require_sample_memory(f"--samples {samples}", samples, param.model)
    line = lambda text: err.print(f"design: {text}", highlight=False)  # noqa: E731
    with (_progress("designing", enabled=err.is_terminal) as progress,
          _every(5.0, line) if not err.is_terminal else contextlib.nullcontext() as status):
        res = design_excitation(param, duration=duration, harmonics=harmonics, samples=samples, momentum=h, seed=seed,
                         progress=progress, q_max=q_max, qd_max=qd_max, qdd_max=qdd_max, criterion=criterion,
                         noise=noise, n_starts=starts, time_budget=time_budget, max_steps=max_steps,
                         payload_link=payload_link,
                         payload=nominal, jobs=jobs, scheduler=scheduler, status=status)
    res.trajectory.save(output)
    err.print(f"{criterion} = {res.value:.6g} (seed {seed}, {res.n_starts} starts, stopped: "
              f"{res.trajectory.meta['stop']}); trajectory written to {shown_name(output)}")
    if payload_link is not None:
        bound = res.trajectory.meta.get("payload_crb_std")
        if bound:
            err.print("predicted payload CRB std: " + ", ".join(f"{k} {v:.3g}" for k, v in bound.items()),
                      highlight=False)
    elif bound_summary(res.trajectory.meta):
        err.print(bound_summary(res.trajectory.meta), highlight=False)


@app.command(short_help="Free-floating motion for a prescribed joint motion, as a log CSV.")
@MODEL
@PLANAR
@click.option("--trajectory", required=True, help="File from 'design' or a named trajectory (paper-table2).")
@MOMENTUM
@click.option("--samples", type=SAMPLES, help="N samples equally spaced over [0, tf] [default: the design's N].")
@click.option("--rate", type=RATE, help="Sample rate [Hz] (instead of --samples).")
@_options(*NOISE, *SENSORS)
@DRIFT_VALUES
@click.option("--base-position", is_flag=True, help="Also write the base position (base_x, base_y or base_px, "
              "base_py, base_pz [m]; system CM at the origin), which 'identify --com' needs.")
@SEED
@output("Log CSV to write.")
def simulate(model_src, planar, trajectory, momentum, samples, rate, noise_angle, noise_rate, noise_attitude,
             noise_base_rate, quantum, gyro_bias, joint_rate_sensors, drift, base_position, seed, output):
    """Free-floating motion for a prescribed joint motion and momentum, as a log CSV."""
    from .data import write_log
    from .motion import add_noise, simulate as run
    from .motion import load_trajectory

    param = _param(model_src, planar)
    h = _momentum(momentum, param.model.planar)
    terms = _drift(drift, param.model.planar, values=True)
    traj = load_trajectory(trajectory, joints=param.model.joints)
    times = _trajectory_times(traj, samples, rate, "simulate", param.model)
    log = run(param, param.true_values, lambda t: traj.evaluate(t)[:2], times, h, model=param.model, drift=terms,
              base_position=base_position)
    log.meta.update(trajectory=trajectory, seed=seed)
    sensors = {"angle": noise_angle, "rate": noise_rate, "attitude": noise_attitude, "base_rate": noise_base_rate}
    if any(v for v in sensors.values()) or quantum or gyro_bias is not None or not joint_rate_sensors:
        from .estimation import Noise

        sensors = Noise(**sensor_levels(**sensors))
        bias = None if gyro_bias is None else _gyro_bias(gyro_bias)
        log = add_noise(log, noise=sensors, quantum=quantum or 0.0, gyro_bias=bias, seed=seed,
                        joint_rate_sensors=joint_rate_sensors)
    write_log(output, log)
    balance = log.meta.get("momentum_balance_error")
    balance = "" if balance is None else f", momentum balance with the drift {balance:.1e}"
    err.print(f"{log.n_samples} samples written to {shown_name(output)} (momentum error "
              f"{log.meta['momentum_rel_error']:.1e} "
              f"relative{balance})")


@app.command(short_help="Estimate the minimal parameters from a log.")
@MODEL
@click.argument("log_path", metavar="LOG", type=click.Path(path_type=Path))
@PLANAR
@click.option("--momentum", required=True, metavar=MOMENTUM_METAVAR + "|unknown", help="Angular momentum of the "
              "whole system [N m s]: h (planar) or hx,hy,hz (inertial axes); 0 if it started at rest; 'unknown' to "
              "estimate it (both need an anchor, --known or a reaction wheel, or a --prior).")
@click.option("--estimator", type=click.Choice(ESTIMATORS), help=ESTIMATOR_HELP + " [default: angles for a CSV log "
              "without joint-rate columns (spatial: nor base-rate columns), sampled densely enough for its knots (and no "
              "--joint-rates or --gyro-bias), else ml; a spatial angles fit that does not converge reports ml on the "
              "differentiated rates, with a warning]")
@click.option("--known", multiple=True, metavar="NAME=VALUE", help="A known parameter (minimal name, or the physical "
              "parameter one equals alone, e.g. Iczz_wheel=0.00197): anchors the scale; repeatable.")
@click.option("--instruments", type=click.Path(path_type=Path), help="Commanded trajectory (the JSON 'spaceid "
              "design' writes) for --estimator iv; default: measured joints with the predicted base rate.")
@noise_options
@click.option("--knot-spacing", type=SECONDS, default=None,
              help=f"--estimator angles: knot spacing of the joint-path splines [s]; at least two samples per span. "
              f"Default: {KNOT_SPACING:g} s for a planar log; for a spatial log the coarsest of {KNOT_SPACING:g}, "
              f"{2 * KNOT_SPACING:g}, ... {32 * KNOT_SPACING:g} s at which the splines fit the joint samples to their "
              "noise level.")
@drift_option("External torques that change the momentum during the log, "
              "estimated with the parameters: torque (constant torque [N m]), viscous (base friction -c w0, c in "
              "N m s/rad), coulomb (base friction -mu w0/norm(w0), mu in N m); e.g. --drift viscous on an air-bearing "
              "table (terms that move alike are confounded: start with one). --momentum is then the momentum at the "
              "first sample ('unknown' when the log does not start at rest). Without it, a residual test warns when "
              "the data show a drift.", values=False)
@click.option("--com", "with_com", is_flag=True, help="Also identify the system-CM terms from the log's base position "
              "(base_x, base_y or base_px, base_py, base_pz [m]; zero linear momentum): RESULT.json field 'com'.")
@click.option("--chunk", type=int, help="Stream the identification (--estimator ml, wls, iv or ols): build the "
              "equations this many samples at a time, so that memory does not grow with the regressor (e.g. 4096 for "
              "long logs of large robots); the result agrees with the in-memory one to round-off, the drift residual "
              "test and the covariance of differentiated rates included.")
@click.option("--prior", "prior_src", metavar="MODEL", help="A CAD model of the robot (URDF, YAML or preset; same "
              "joints and geometry): the estimate is then the maximum a posteriori over physically consistent models, "
              "on any motion; RESULT.json field 'prior' says per direction whether the data or the prior set it. "
              "--known may then also give a body mass (m_base=180) or the total mass (m_total=...).")
@click.option("--prior-std", type=float, default=0.2, show_default=True, metavar="REL", help="--prior: relative "
              "standard deviation of its masses and principal moments; its CoMs' is REL times each body's radius of "
              "gyration.")
@click.option("--gyro-bias", "gyro_bias", is_flag=True, help="Estimate a constant gyro bias (base axes [rad/s]) "
              "with the parameters, from the momentum equations and the attitude samples (--estimator ml, wls or "
              "ols); the base rate must be the gyro's (a CSV without joint-rate columns: the joint angles alone are "
              "differentiated).")
@log_options
@output("RESULT.json to write.")
@report_option("the identification: diagnostics, sortable parameter table, figures")
@click.option("--all", "show_all", is_flag=True, help=f"List every estimate in the terminal (default: the first "
              f"{SUMMARY_ROWS}; RESULT.json and the report hold every one).")
def identify(model_src, log_path, planar, momentum, estimator, known, instruments, noise, knot_spacing, drift,
             with_com, chunk, prior_src, prior_std, gyro_bias, output, report, reading, show_all):
    """Estimate the minimal parameters from a log (LOG.csv, or a ROS bag).

    Noise levels not given are estimated from the log. Reaction wheels of the model (known rotor
    inertia) move their spin momentum to the right-hand side.
    """
    from .estimation import identify as run
    from .estimation import parse_known
    from .data import write_json
    from .studies import drift_lines, parameter_table

    known = parse_known(known)  # option values first: before the model and the log are read
    report = _report_path(report, output)
    param = _param(model_src, planar)
    h = _momentum(momentum, param.model.planar, allow_unknown=True)
    kinds = _drift(drift, param.model.planar, values=False)
    log = _measured_log(param.model, log_path, reading, angles_only=estimator in ("angles", None))
    if estimator is None:
        estimator = _default_estimator(param.model, log, reading, knot_spacing, gyro_bias)
        if estimator == "ml" and "joint_rates" not in log.meta:  # a CSV (a bag's rates are set when read)
            log = _csv_rates(log, log_path, reading)
    angles_only = estimator == "angles"  # uses the angles alone: rates neither needed nor differentiated
    reference = None
    if instruments is not None:
        if estimator != "iv":
            raise SpaceidError("--instruments is for --estimator iv")
        from .motion import load_trajectory

        traj = load_trajectory(instruments)
        if tuple(traj.joints) != tuple(param.model.joints):
            raise SpaceidError(f"{instruments}: joints {list(traj.joints)} differ from the model's "
                               f"{list(param.model.joints)}: give the trajectory that was commanded on this model")
        reference = traj.evaluate(log.t - log.t[0])[:2]
    with _warnings_to_stderr():
        ident = run(param, log, h, estimator=estimator, known=known, noise=noise, instruments=reference,
                    where=str(log_path), knot_spacing=knot_spacing, drift=kinds, chunk=chunk, prior=prior_src,
                    prior_std=prior_std, gyro_bias=gyro_bias)
    if with_com:
        ident = _identify_com(ident, log)
    write_json(output, ident.to_dict())
    _identification_html(ident, report, f"spaceid identify: {shown_name(log_path)}")
    out.print(parameter_table(ident, rows=None if show_all else SUMMARY_ROWS, rest=f"--all lists them; "
                              f"{shown_name(output)} and {shown_name(report)} hold every one"))
    s = ident.settings
    units = dict(zip(ident.names, ident.units))
    for a in s["anchors"]:
        out.print(f"anchor: {a['name']} = {a['definition']} = {a['value']:.6g} {units.get(a['name'], '')} "
                  f"({a['source']})", highlight=False)
    if s["momentum_estimated"]:
        axes = [2] if ident.planar else [0, 1, 2]
        out.print("momentum (estimated): " + ", ".join(
            f"h_{'xyz'[i]} = {ident.momentum[i]:.6g} +/- {ident.momentum_std[i]:.2g}" for i in axes) + " N m s")
    for line in drift_lines(ident):
        out.print(line, highlight=False)
    if ident.prior is not None:
        out.print(ident.prior.summary(), highlight=False)
    for d in ident.gyro_bias:
        out.print(f"gyro bias: {d['name']} = {d['value']:.6g} +/- {d['std']:.2g} {d['unit']}", highlight=False)
    chi2_dof = ident.diagnostics.chi2_dof
    chi2 = "" if chi2_dof is None else f"chi2/dof = {chi2_dof:.3g} "
    out.print(f"estimator {estimator}; cond(Y) = {ident.condition_number:.4g}; residual RMS = {ident.residual_rms:.3g} "
              f"{'rad' if angles_only else 'N m s'}; {chi2}(noise {s['noise']['source']}); {ident.n_samples} samples; "
              f"result written to {shown_name(output)}, report to {shown_name(report)}")


def _identification_html(ident, path, title):
    """``identify``'s HTML report at ``path``: the identification's diagnostics, parameters and figures."""
    from .studies import write_html_report

    settings = {"model": ident.model, "estimator": ident.estimator, "samples": ident.n_samples}
    write_html_report(path.parent, title=title, result=ident, settings=settings, figures={}, name=path.name)


def _measured_log(model, log_path, reading, *, angles_only=False):
    """The log at ``log_path`` for ``model``, read as ``reading`` (:func:`log_options`) says. A bag:
    as its reader aligns and differentiates it (``measured``: the published joint velocities); the
    joint rates' sources are printed. A CSV: its rate columns (``measured``, the default), or its
    angles and attitude differentiated (``differentiate``; by default when it has no rate column;
    ``auto`` when some are missing), with ``--window`` and ``--quantum``; ``angles_only``: left as
    read (the angles estimator uses no rates)."""
    from .data import is_bag, read_log

    if is_bag(log_path):
        log = read_log(log_path, joints=model.joints, planar=model.planar, wheels=model.wheels,
                       bag_options=_bag_reading(reading))
        _print_joint_rates(log)
        return log
    log = read_log(log_path, joints=model.joints, planar=model.planar, wheels=model.wheels, require_rates=False,
                   bag_options={k: reading[k] for k in BAG_ONLY})  # topics or a mapping: refused for a CSV
    return log if angles_only else _csv_rates(log, log_path, reading)


def _csv_rates(log, log_path, reading):
    """A CSV ``log`` with its rates as ``reading`` says (:func:`_measured_log`): its rate columns, or
    its angles differentiated, and its attitude where it has no base-rate columns: a measured base
    rate (a gyro's) is kept, far better than the star tracker's attitude differentiated (1e-5 rad/s
    against about 1e-3 on a servicer's log)."""
    from .data import differentiate_log

    rates = reading["joint_rates"]
    missing = log.meta.get("missing_rates", [])
    no_rates = all(f"qd_{j}" in missing for j in log.joints)  # joint encoders without joint-rate sensors
    if not (rates == "differentiate" or rates == "auto" and missing or rates is None and no_rates):
        if missing:
            raise SpaceidError(f"{log_path}: rate column(s) {', '.join(missing)} missing: add them, or pass "
                               "--joint-rates differentiate to compute every rate from the angles")
        given = " and ".join(o for o in ("--window", "--quantum") if reading[o[2:]] is not None)
        if given:
            raise SpaceidError(f"{given}: {log_path}'s rates are its rate columns (--joint-rates "
                               f"{rates or 'measured'}), none is differentiated: add --joint-rates differentiate, or "
                               f"drop {given}")
        return log
    return differentiate_log(log, window=reading["window"], quantum=reading["quantum"], base=not _gyro(log))


def _gyro(log) -> bool:
    """Whether ``log`` has base-rate samples (a gyro's): no NaN in its base-rate columns."""
    return not np.isnan(log.base_w[:, [2] if log.planar else [0, 1, 2]]).any()


def _default_estimator(model, log, reading, knot_spacing, gyro_bias) -> str:
    """``identify``'s estimator when none is given: ``angles`` where no rate was measured (nothing to
    differentiate; planar: base-rate columns, if any, unused; spatial: no gyro either, whose rates are worth more
    than the star tracker's angles) and the log is dense enough for the knots, else ``ml`` (the rates
    differentiated where missing). docs/theory/angles.md, "The default"."""
    from .estimation.internal import enough_samples_for_knots

    spacing = knot_spacing or (KNOT_SPACING if model.planar else None)  # spatial None: the automatic choice's
    angles = (not gyro_bias and _without_joint_rates(model, log, reading) and (model.planar or not _gyro(log))
              and enough_samples_for_knots(log.t, spacing))  # fmt: skip
    return "angles" if angles else "ml"


def _without_joint_rates(model, log, reading) -> bool:
    """Whether ``log`` is a CSV log without any joint-rate column (``qd_*`` of the non-wheel joints)
    read without ``--joint-rates``: ``identify``'s estimator is then ``angles`` by default."""
    missing = set(log.meta.get("missing_rates", ()))
    joints = [j for j in model.joints if j not in model.wheels]
    return reading["joint_rates"] is None and "joint_rates" not in log.meta and all(f"qd_{j}" in missing
                                                                                      for j in joints)  # fmt: skip


def _bag_reading(reading) -> dict:
    """``reading`` (:func:`log_options`) as the keywords of a bag reader (``read_bag_log``)."""
    return dict(reading, joint_rates={"measured": "velocity"}.get(reading["joint_rates"], reading["joint_rates"]))


def _identify_com(ident, log):
    """``ident`` with the CM terms of the log's base position (``--com``), and a summary line."""
    from .identified import identified_model, identify_com

    com = identify_com(identified_model(ident, where=str(log.meta.get("source", "result"))), log).identification.com
    err.print(f"CM terms: {len(com['names'])} from {com['n_samples']} base positions, residual RMS "
              f"{com['residual_rms']:.3g} m; system CM at {', '.join(f'{x:.4g}' for x in com['inertial_com'])} m",
              highlight=False)
    return dataclasses.replace(ident, com=com)


@app.command(short_help="Base motion of an identified model, or of a model as it is, for a joint motion.")
@click.argument("result", metavar="RESULT.json|MODEL", type=click.Path(path_type=Path))
@click.argument("trajectory", metavar="TRAJ", type=click.Path(path_type=Path))
@PLANAR
@MOMENTUM
@click.option("--samples", type=SAMPLES, help="TRAJ from 'design': N samples equally spaced over [0, tf] [default: "
              "the design's N].")
@click.option("--rate", type=RATE, help="TRAJ from 'design': sample rate [Hz] (instead of --samples).")
@click.option("--initial-yaw", type=FINITE, help="Base yaw at t0 [rad] (planar; default 0).")
@click.option("--initial-quat", help="Base attitude at t0 as w,x,y,z (spatial; default 1,0,0,0).")
@drift_option("Drift terms replacing those of RESULT.json (used by default): torque=TAU, viscous=C, coulomb=MU, "
              "as for 'spaceid simulate'.", values=True)
@output("Predicted log CSV to write.")
def predict(result, trajectory, planar, momentum, samples, rate, initial_yaw, initial_quat, drift, output):
    """Base motion of an identified model (RESULT.json) or of a model as it is (MODEL: a preset,
    URDF or YAML file, with its standard parameters) for a joint motion TRAJ: a joint-trajectory
    CSV (columns t, q_J, qd_J) or a trajectory from 'design' (JSON, or a named one such as
    paper-table2), sampled like 'simulate' does."""
    from .data import read_joint_trajectory, write_log
    from .data import yaw_to_quat
    from .studies import predict as run

    source = _predictor(result, planar)
    model = source.param.model
    h = _momentum(momentum, model.planar)
    terms = _drift(drift, model.planar, values=True)
    joints = model.joints
    if trajectory.suffix.lower() == ".csv":
        if samples is not None or rate is not None:
            raise SpaceidError(f"{trajectory}: a CSV gives its own samples: --samples and --rate are for a "
                               "trajectory from 'design'")
        t, q, qd = read_joint_trajectory(trajectory, joints=joints)
    else:
        from .motion import load_trajectory

        traj = load_trajectory(trajectory, joints=joints)
        t = _trajectory_times(traj, samples, rate, "predict", model)
        q, qd, _ = traj.evaluate(t)
    if initial_quat is not None and initial_yaw is not None:
        raise SpaceidError("--initial-yaw and --initial-quat both give the initial attitude: give one")
    if initial_quat is not None:
        try:
            quat0 = np.array([float(v) for v in initial_quat.split(",")])
        except ValueError:
            quat0 = np.zeros(0)
        if quat0.shape != (4,) or not abs(np.linalg.norm(quat0) - 1) < 1e-6:
            raise SpaceidError(f"--initial-quat: expected a unit quaternion w,x,y,z, got '{initial_quat}'")
    else:
        quat0 = yaw_to_quat(initial_yaw or 0.0)
    log = run(source, t, q, qd, momentum=h, initial_quat=quat0, drift=terms)
    write_log(output, log)
    err.print(f"{log.n_samples} predicted samples written to {shown_name(output)} (by the {source.label})",
              highlight=False)


def _predictor(result, planar):
    """``predict``/``validate``'s RESULT.json|MODEL as a :class:`spaceid.studies.Predictor`; --planar
    is for a model (a result records its mode)."""
    from .studies import predictor

    source = predictor(result, planar=planar, where=str(result))
    if source.kind == "identification" and planar is not None:
        raise SpaceidError(f"--planar/--spatial: {result} is a result, which records its mode: drop the option")
    return source


def _trajectory_times(traj, samples, rate, command, model):
    """Sample times [s] of a designed trajectory: ``--samples N`` or ``--rate HZ``, else the N it
    was designed with; shape (n,). Refused when ``model``'s simulation of them would not fit in
    memory."""
    from .motion import sample_times

    if samples is not None and rate is not None:
        raise SpaceidError(f"{command}: give one of --samples N or --rate HZ, not both")
    if samples is None and rate is None:
        samples = traj.meta.get("samples")
        if samples is None:
            raise SpaceidError(f"{command}: the trajectory records no sample count: give --samples N or --rate HZ")
    if rate is not None:
        n = np.floor(traj.duration * rate * (1 + 1e-12)) + 1  # as np.arange below, without allocating first
        if n < 2:
            raise SpaceidError(f"--rate {rate:g}: 1 sample over the trajectory's {traj.duration:g} s: give a rate "
                               f"above {1 / traj.duration:.3g} Hz")
        _require_sample_memory(f"--rate {rate:g}: {n:.3g} samples", n, model)
        return np.arange(0, traj.duration + 1e-12, 1 / rate)
    _require_sample_memory(f"--samples {samples}", samples, model)
    return sample_times(traj.duration, samples)


def _require_sample_memory(what, n, model):
    """Refuse ``n`` samples of ``model`` that would not fit in the available memory, before any
    work: a bound of 8 x 8 x (joints + 6) x (full parameters) bytes a sample (the regressor of every
    full parameter on a grid 8 times denser than the samples; cepheus: 15 kB). Simulation, which
    evaluates it in blocks, takes far less (cepheus: 1.5 kB a sample, measured)."""
    from ._memory import require_memory
    from .dynamics import full_parameter_names

    per_sample = 8 * 8 * (len(model.joints) + 6) * len(full_parameter_names(model))
    require_memory(float(n) * per_sample, what, "give fewer samples" + (" or a lower --rate" if "rate" in what else ""))


@app.command(short_help="Re-simulate an identified model, or a model as it is, against a log: metrics and plots.")
@click.argument("result", metavar="RESULT.json|MODEL", type=click.Path(path_type=Path))
@click.argument("log_path", metavar="LOG", type=click.Path(path_type=Path))
@PLANAR
@MOMENTUM
@drift_option("Drift terms replacing those of RESULT.json (used by default): torque=TAU, viscous=C, coulomb=MU, "
              "as for 'spaceid simulate'; --momentum is the momentum at the log's first sample.", values=True)
@click.option("--torques", is_flag=True, help="Also drive the identified model's forward dynamics with the log's "
              "joint torques (columns tau_J [N m]) and compare the motion: torque_*.csv/json (and png with --png).")
@click.option("--horizon", type=SECONDS, metavar="SECONDS", help="With --torques: restart from the measured state "
              "every SECONDS [s] (default: one run over the whole log).")
@click.option("--png", is_flag=True, help="Also write the figures as 150 dpi images, validation.png (the paper's "
              "Fig. 6) and with --torques torque_validation.png; report.html draws the same figures either way.")
@log_options
@out_folder("Report folder to write predicted.csv, metrics.json and report.html (interactive figures) into, and "
            "validation.png with --png.", required=True)
@click.option("-o", "--output", cls=_Deprecated, instead="--out DIR (-o/--output names a file, --out a folder)",
              into="folder")
@OVERWRITE
def validate(result, log_path, planar, momentum, drift, torques, horizon, png, folder, overwrite, reading):
    """Re-simulate an identified model (RESULT.json) or a model as it is (MODEL: a preset, URDF or
    YAML file, with its standard parameters) against a measured log: metrics and Fig. 6 plots
    (report.html; the PNG with --png: drawing it took longer than the validation itself)."""
    if horizon is not None and not torques:
        raise SpaceidError("--horizon applies to --torques: add --torques or drop --horizon")
    from .studies import plot_validation, write_validation_html
    from .data import write_json, write_log
    from .studies import metric_label
    from .studies import validate as run

    source = _predictor(result, planar)
    if torques and source.identification is None:
        raise SpaceidError(f"--torques: {result} is a model; the torque-level validation takes a RESULT.json")
    ident, model = source.identification, source.param.model  # its wheels are exempt from the degrees check
    h = _momentum(momentum, model.planar)
    terms = _drift(drift, model.planar, values=True)
    log = _measured_log(model, log_path, reading)
    with _warnings_to_stderr():  # e.g. that LOG is the log RESULT was fitted to
        check = run(source, log, momentum=h, where=str(result), drift=terms)
    predicted, metrics = check.predicted, check.metrics
    with _report_folder(folder, overwrite) as tmp:
        write_log(tmp / "predicted.csv", predicted)
        write_json(tmp / "metrics.json", {**metrics, "predicted_by": check.predicted_by})
        if png:
            plot_validation(log, predicted, tmp / "validation.png")
        predictions, torque_metrics = [(predicted, None)], None
        if torques:
            torque_metrics, torque_predicted, torque_title = _validate_torques(ident, log, h, horizon, tmp, str(result),
                                                                               png)
            predictions.append((torque_predicted, torque_title.replace("\n", " ")))
        write_validation_html(tmp / "report.html", log, predictions, metrics, torque_metrics=torque_metrics,
                              title=f"spaceid validate: {shown_name(result)} on {shown_name(log_path)}",
                              source=f"the {check.predicted_by}")
    out.print(f"predicted by the {check.predicted_by}", highlight=False)
    for key, value in metrics.items():
        out.print(f"{metric_label(key)} = {value:.4g}", highlight=False)
    if torques:
        from .studies import TORQUE_METRIC_LABELS

        for key, value in torque_metrics.items():
            out.print(f"{TORQUE_METRIC_LABELS[key]} = {value:.4g}", highlight=False)
    err.print(f"plots, metrics and report.html written to {shown_name(folder)}/")


def _validate_torques(ident, log, h, horizon, output, where, png=False):
    """``validate --torques``: the torque-driven prediction, its metrics and (with ``png``) figure in ``output``;
    returns the metrics, the predicted log and the figure's title."""
    from .data import write_json, write_log
    from .studies import TORQUE_VALIDATION_TITLE, plot_validation, validate_torques

    predicted, metrics = validate_torques(ident, log, horizon=horizon, momentum=h, where=where)
    write_log(output / "torque_predicted.csv", predicted)
    write_json(output / "torque_metrics.json", metrics)
    restarts = f"(restarted from the measured state every {metrics['horizon']:.3g} s)"
    title = f"{TORQUE_VALIDATION_TITLE}\n{restarts}"
    if png:
        plot_validation(log, predicted, output / "torque_validation.png", title=title)
    return metrics, predicted, title


@app.command(short_help="The paper's simulation study on the built-in Cepheus model.")
@click.option("--trajectory", default="designed", show_default=True,
              help="designed, paper-table2 or a file from 'design'.")
@_options(*NOISE)
@SEED
@out_folder("Report folder.", default="spaceid-report", show_default=True)
@OVERWRITE
@click.option("--json", "as_json", is_flag=True, help="Print one JSON object instead of tables.")
def demo(trajectory, noise_angle, noise_rate, seed, folder, overwrite, as_json):
    """The paper's simulation study on the built-in Cepheus model (Tables 1-3)."""
    from .studies import PAPER_TABLE3, run_demo, warm_preset_sets, warm_spatial_kernels
    from .studies import parameter_table

    with (_progress("designing the exciting trajectory", enabled=not as_json and trajectory == "designed") as progress,
          _report_folder(folder, overwrite) as tmp):
        res = run_demo(trajectory=trajectory, noise_angle=noise_angle, noise_rate=noise_rate, seed=seed, out=tmp,
                       progress=progress)
    warm_spatial_kernels()  # the install step (docs/getting-started.md): spatial robots' first commands start warm
    warm_preset_sets()  # and no preset's first command derives its minimal set
    res = dataclasses.replace(res, folder=folder)  # where the report now is
    if as_json:
        print(json.dumps(res.to_dict(), indent=2))
        return
    out.print(parameter_table(res.ident, true=res.true, reference=PAPER_TABLE3["relative_error_percent"],
                              reference_true=PAPER_TABLE3["true"]))
    out.print(
        f"trajectory {res.ident.settings['trajectory']}: cond(Y) = {res.ident.condition_number:.4g} "
        f"with N = {res.ident.n_samples}; validation base-rate RMS error {res.metrics['base_w_rms']:.3g} rad/s "
        f"({100 * res.metrics['base_w_nrms']:.3g} %)"
    )
    out.print(f"report written to {shown_name(folder)}/report.md")


@app.command(short_help="The paper's Cepheus experiment on the digital twin, through a ROS bag.")
@click.argument("model_src", metavar="[MODEL]", default="cepheus")
@click.option("--trajectory", default="designed", show_default=True,
              help="designed, paper-table2 or a file from 'design'.")
@click.option("--wheel-speed", type=FINITE, default=170.0, show_default=True,
              help="Wheel speed relative to the base [rad/s].")
@click.option("--samples", type=SAMPLES, default=29, show_default=True, help="N, the samples identification uses.")
@click.option("--bag-format", type=click.Choice(BAG_FORMATS), default="ros1", show_default=True,
              help="Bag the twin records: ros1 (ROS 1 .bag file), ros2 (ROS 2 bag folder, sqlite3 storage), mcap "
              "(ROS 2 bag folder, MCAP storage).")
@click.option("--format", "old_bag_format", cls=_Deprecated, instead="--bag-format {value}", into="bag_format")
@click.option("--estimator", type=click.Choice(ESTIMATORS), default="ml", show_default=True, help=ESTIMATOR_HELP)
@click.option("--ideal", is_flag=True, help="Switch off friction, torque limits, thrusters and tank drain.")
@click.option("--validation", help="Held-out motion, run after the excitation, that the model is validated on: "
              "paper-table2, designed (seed + 1) or a file from 'design' [default: paper-table2; designed when "
              "--trajectory is paper-table2].")
@drift_option("Drift terms to identify with the parameters (torque, "
              "viscous, coulomb; see 'spaceid identify --drift'): the table's friction, integrated from the rest "
              "at the bag's start. Default: viscous while the table's friction acts, none with --ideal; "
              "--drift none: no drift terms.", values=False)
@click.option("--feedforward/--no-feedforward", default=True, show_default=True,
              help="Add the arm's inverse dynamics planned from the prior model to the PD loops (after holding the "
              "start pose); --no-feedforward: the published PD loops alone.")
@click.option("--rehearsals", type=click.IntRange(min=0), default=0, show_default=True,
              help="Rehearsals of the excitation at most, each refining the arm's reference by the encoder error "
              "(iterative learning control); they stop at 5 mrad RMS.")
@click.option("--capture", is_flag=True, help="After the held-out motion, grasp a free-floating payload and run the "
              "servicing sequence: post-capture excitation, change detection over the recording, the payload "
              "identified with the twin's servicer and scored against the truth.")
@click.option("--capture-settings", type=click.Path(path_type=Path), metavar="FILE", help="With --capture: a YAML "
              "or JSON file of the payload: mass [kg], com, inertia, velocity, rate, link, offset, yaw, each optional "
              "(default: a 0.5 kg cylinder at rest held by link2; docs: theory/capture).")
@click.option("--capture-mass", cls=_Deprecated, type=float, instead="--capture-settings FILE holding 'mass: {value}'")
@click.option("--capture-trajectory", default="same", show_default=True, help="With --capture: the post-capture "
              "excitation: same (the identification excitation), designed (for the payload) or a file from 'design'.")
@click.option("--duration", type=SECONDS, help="Spatial MODEL: the designed excitation's length [s] [default: 120].")
@click.option("--time-budget", type=SECONDS, help="Spatial MODEL: wall time of the design's search [s] [default: 30; "
              "the held-out motion's design a third of it].")
@click.option("--max-steps", type=click.IntRange(min=1), metavar="N", help="Spatial MODEL: each design's budget in "
              "linearisations of the regressor (a design that does not depend on the machine's speed; see 'spaceid "
              "design --max-steps').")
@click.option("--no-prior", is_flag=True, help="Spatial MODEL: identify from the data alone, not with the CAD model as "
              "the prior.")
@limit_options
@SEED
@out_folder("Report folder (bag, logs, results, figures, report.md).", default="spaceid-experiment",
            show_default=True)
@OVERWRITE
def experiment(model_src, trajectory, wheel_speed, samples, bag_format, estimator, ideal, validation, drift,
               feedforward, rehearsals, capture, capture_mass, capture_settings, capture_trajectory, duration,
               time_budget, max_steps, no_prior, q_max, qd_max, qdd_max, seed, folder, overwrite):
    """Rest, wheel spin-up, exciting trajectory and a second, held-out motion on the Cepheus twin;
    identify from the recorded bag (N samples and all of the excitation), validate the identified
    model on the held-out motion (Fig. 6).

    MODEL is the twin's model, cepheus (with its reaction wheel: cepheus-rw) by default. A spatial
    MODEL (e.g. servicer-dual, or a URDF) runs the spatial protocol on the servicer twin instead:
    design with a CAD model 15 % off (--samples: the design's N, default 600), fly under computed
    torque, identify from all the encoder, star tracker and gyro samples with the CAD model as the
    prior (--no-prior: the data alone), predict a held-out motion against the CAD prior (--ideal:
    exact sensors; docs: theory/twin-spatial).
    """
    from .models import load_model
    from .studies import capture_protocol, run_experiment
    from .studies import parameter_table
    from .twin import TwinSettings

    model = {"cepheus": "cepheus-rw"}.get(model_src, model_src)
    loaded = load_model(model)
    if not loaded.planar:
        return _spatial_experiment(loaded, click.get_current_context(), samples=samples, estimator=estimator,
                                   ideal=ideal, trajectory=trajectory, duration=duration, time_budget=time_budget,
                                   max_steps=max_steps, prior=not no_prior, seed=seed, folder=folder,
                                   overwrite=overwrite, limits={"q_max": q_max, "qd_max": qd_max, "qdd_max": qdd_max})
    if duration is not None or time_budget is not None or max_steps is not None or no_prior or (q_max, qd_max,
                                                                                                 qdd_max) != (None,) * 3:
        raise SpaceidError("--duration, --time-budget, --max-steps, --no-prior and the limits (--q-max, --qd-max, "
                           "--qdd-max) are options of the spatial protocol: give a spatial MODEL (e.g. servicer-dual), "
                           "or drop them")  # fmt: skip
    settings = TwinSettings(model=model)
    settings = settings.without_effects() if ideal else settings
    if not capture and (capture_mass is not None or capture_settings is not None or capture_trajectory != "same"):
        raise SpaceidError("--capture-mass, --capture-settings and --capture-trajectory need --capture")
    protocol = capture_protocol(capture_settings, mass=capture_mass) if capture else None
    with (_progress("designing the exciting trajectory", enabled=trajectory == "designed") as progress,
          _report_folder(folder, overwrite) as tmp):
        res = run_experiment(trajectory=trajectory, wheel_speed=wheel_speed, samples=samples, settings=settings,
                             bag_format=bag_format, estimator=estimator, validation=validation, seed=seed, out=tmp,
                             out_name=folder, progress=progress,
                             drift=None if drift is None else _drift(drift, True, values=False),
                             feedforward=feedforward, rehearsals=rehearsals, capture=protocol,
                             capture_trajectory=capture_trajectory)
    out.print(parameter_table(res.ident, true=res.true))
    track = res.settings["tracking RMS, encoders vs design [rad]"]
    out.print(f"tracking RMS (encoders vs design): {', '.join(f'{j} {v:.3g}' for j, v in track.items())} rad")
    designed = res.settings["cond(Y) designed / executed, N samples"][0]
    worst = float(np.max(np.abs(res.ident_all.values - res.true) / np.abs(res.true)))
    out.print(f"N = {res.ident.n_samples}: cond(Y) = {res.ident.condition_number:.4g} (designed motion: "
              f"{designed:.4g}); all {res.ident_all.n_samples} "
              f"samples: worst relative error {100 * worst:.3g} %")
    out.print(f"validation on the held-out motion ({res.settings['validation trajectory']}): base-rate RMS error "
              f"{res.metrics['base_w_rms']:.3g} rad/s ({100 * res.metrics['base_w_nrms']:.3g} %); on the fitting "
              f"log, which checks only the fit: {100 * res.fit_metrics['base_w_nrms']:.3g} %", highlight=False)
    if res.servicing is not None:
        _print_servicing(res.servicing.scores)
    out.print(f"report written to {shown_name(folder)}/report.md")


_PLANAR_ONLY = ("wheel_speed", "bag_format", "old_bag_format", "validation", "drift", "feedforward", "rehearsals",
                "capture", "capture_mass", "capture_settings", "capture_trajectory")


def _spatial_experiment(model, ctx, *, samples, estimator, ideal, trajectory, duration, time_budget, max_steps, prior,
                        seed, folder, overwrite, limits) -> None:
    """``spaceid experiment`` with a spatial model: the protocol on the servicer twin
    (:func:`spaceid.studies.run_spatial_experiment`), its scores printed."""
    from click.core import ParameterSource

    from .studies import run_spatial_experiment
    from .twin import ServicerSettings

    given = [p.opts[0] for p in ctx.command.params if p.name in _PLANAR_ONLY
             and ctx.get_parameter_source(p.name) not in (ParameterSource.DEFAULT, None)]  # fmt: skip
    if given:
        raise SpaceidError(f"{', '.join(given)}: options of the Cepheus experiment; {model.name} is spatial (the "
                           "servicer twin): drop them")  # fmt: skip
    settings = ServicerSettings(model=model)
    settings = settings.without_noise() if ideal else settings
    default_samples = ctx.get_parameter_source("samples") == ParameterSource.DEFAULT
    options = dict(samples=600 if default_samples else samples, estimator=estimator, trajectory=trajectory, seed=seed,
                   prior=prior)
    options |= {k: v for k, v in (("duration", duration), ("time_budget", time_budget), ("max_steps", max_steps))
                if v is not None}
    options["limits"] = {k: v for k, v in limits.items() if v is not None} or None
    with (_progress("designing the exciting trajectory", enabled=trajectory == "designed") as progress,
          _report_folder(folder, overwrite) as tmp):
        res = run_spatial_experiment(settings=settings, out=tmp, out_name=folder, progress=progress, **options)
    c, m = res.metrics["coverage"], res.metrics
    ident, prior = m["held-out attitude error, identified [rad]"], m["held-out attitude error, CAD prior [rad]"]
    record = res.ident.prior
    out.print(f"{res.ident.n_samples} samples, " + ("the data alone" if record is None else
              f"with the CAD prior (the data set {record.n_data} of {len(record.directions)} directions)") +
              f": cond(Y) = {res.ident.condition_number:.4g}; {c['n_large']} large "
              f"parameters: {100 * c['within_2_sigma']:.1f} % within 2 sigma, max |z| {c['max_abs_z']:.3g}, RMS z "
              f"{c['rms_z']:.3g}", highlight=False)  # fmt: skip
    shown = [f"{e['max']:.3g} rad" if e else f"none ({m['not predicted'][k]})" for e, k in
             ((ident, "identified"), (prior, "CAD prior"))]  # fmt: skip
    ratio = m["CAD prior / identified, largest attitude error"]
    out.print(f"held-out motion ({res.settings['held-out duration [s]']:g} s): largest attitude error {shown[0]} "
              f"identified, {shown[1]} CAD prior" + (f" (x {ratio:.3g})" if ratio else ""), highlight=False)
    drift = max(m["momentum drift relative to the joints' momentum"])
    out.print(f"momentum of the true states: largest change {drift:.2g} of the joints' momentum", highlight=False)
    out.print(f"report written to {shown_name(folder)}/report.md")


def _print_servicing(scores) -> None:
    """The payload against its truth and the detected change against the grasp (a
    :class:`~spaceid.studies.ServicingScores`), as printed."""
    for p in scores.payload:
        z = "" if p.z is None else f", z = {p.z:+.2f}"
        out.print(f"payload {p.name:>3s} = {p.estimate:.5g} +/- {p.std:.2g} (truth {p.true:.5g}{z})",
                  highlight=False)
    if scores.detected_change_time is None:
        out.print(f"change detection: no change found near the grasp ({scores.events} events)")
        return
    lead = scores.change_time_lead
    out.print(f"change detected {scores.change_time_error:+.3g} s from the grasp "
              f"({scores.change_time_error_samples:+g} samples; the differentiated rates show it up to "
              f"{lead:.3g} s early), alarm at "
              f"{scores.alarm_time_from_grasp:+.3g} s from it; "
              f"{scores.false_alarms} false alarms before it", highlight=False)


@app.command(short_help="How the parameters changed between two identifications.")
@click.argument("before", metavar="BEFORE.json", type=click.Path(path_type=Path))
@click.argument("after", metavar="AFTER.json", type=click.Path(path_type=Path))
@click.option("--json", "as_json", is_flag=True, help="Print JSON instead of a table.")
@click.option("--all", "show_all", is_flag=True,
              help="List every parameter, not only those that changed (z-score above 3 in magnitude).")
def compare(before, after, as_json, show_all):
    """Compare two identifications of the same structure, e.g. before and after a capture."""
    from rich.table import Table

    from .estimation import compare as run
    from .estimation import load_result

    first = load_result(before)
    res = run(first, load_result(after), where=f"{before}, {after}").to_dict()
    if as_json:
        print(json.dumps(res, indent=2))
        return
    params = res["parameters"]
    rows = [p for p in params if show_all or abs(p["z"]) > 3]
    if not rows:
        out.print(f"no parameter changed beyond 3 standard errors ({len(params)} compared; --all lists them)")
        return
    units = dict(zip(first.names, first.units))
    table = Table(title=f"{len(rows)} of {len(params)} parameters" + ("" if show_all else ", |z| > 3"),
                  caption="z: change / combined standard error")
    for name in ("", "unit", "before", "after", "change [%]", "z"):
        table.add_column(name, justify="left" if name in ("", "unit") else "right", no_wrap=True)
    for p in rows:
        table.add_row(p["name"], units.get(p["name"], ""), f"{p['before']:.6g}", f"{p['after']:.6g}",
                      f"{100 * p['relative_change']:.3g}", f"{p['z']:.3g}")
    out.print(table)


@app.command(short_help="Monte Carlo study of the estimators: bias, RMSE, RMSE / Cramer-Rao bound.")
@MODEL
@PLANAR
@click.option("--trajectory", default="paper-table2", show_default=True, help="File from 'design', a named "
              "trajectory (paper-table2), or 'designed' (designed now: --duration, --samples, --harmonics, "
              "--criterion, --seed).")
@click.option("--duration", type=SECONDS, help="Sampled span [s] (default: the trajectory's; required for 'designed').")
@click.option("--samples", type=SAMPLES, default=35, show_default=True,
              help="N samples equally spaced over the duration (501 over 5 s is 100 Hz, e.g. for --angles-only).")
@click.option("--harmonics", type=HARMONICS, default=3, show_default=True,
              help="Fourier harmonics of a 'designed' trajectory.")
@click.option("--criterion", default="cond", show_default=True, help="Design criterion of a 'designed' trajectory "
              f"({', '.join(DESIGN_CRITERIA)}; see 'spaceid design').")
@MOMENTUM
@click.option("--runs", type=RUNS, default=200, show_default=True, help="Noise draws.")
@click.option("--estimator", "estimators", multiple=True, metavar="[" + "|".join(ESTIMATORS) + "]",
              help="Estimator to study, repeatable [default: ml and ols]. " + ESTIMATOR_HELP)
@noise_options
@click.option("--angles-only", is_flag=True, help="Noise on joint angles and base attitude only, rates differentiated "
              "from them (Savitzky-Golay, automatic window).")
@SEED
@click.option("--jobs", type=JOBS, help="Worker processes [default: all cores].")
@SCHEDULER
@out_folder("Folder for table.txt, montecarlo.json, montecarlo.png and report.html (each chunk of runs kept beside "
            "it in .FOLDER.tasks/ as it completes, for --resume, until they are written).")
@RESUME
@OVERWRITE
@click.option("--all", "show_all", is_flag=True, help=f"List every parameter in the terminal (default: the first "
              f"{SUMMARY_ROWS} of each estimator; --out's table.txt, montecarlo.json and report.html hold every one).")
def montecarlo(model_src, planar, trajectory, duration, samples, harmonics, criterion, momentum, runs, estimators,
               noise, angles_only, seed, jobs, scheduler, folder, resume, overwrite, show_all):
    """Monte Carlo study: simulate once, identify under fresh noise RUNS times, and report per
    estimator and parameter the bias, RMSE, predicted vs actual spread and RMSE / CRB. The
    momentum of the simulated motion (--momentum) is required. Noise levels default to 1e-4
    (rad, rad/s) on every signal when no --noise-* option is given (otherwise the ones not
    given are zero)."""
    from ._campaign import discard_tasks
    from .studies import DEFAULT_NOISE, run_montecarlo, write_montecarlo
    from .studies import montecarlo_table

    param = _param(model_src, planar)
    h = _momentum(momentum, param.model.planar)
    _require_sample_memory(f"--samples {samples}", samples, param.model)
    with _progress("designing, then runs" if trajectory == "designed" else "runs") as progress:
        res = run_montecarlo(param, trajectory, momentum=h, noise=noise or DEFAULT_NOISE, duration=duration,
                             samples=samples, runs=runs, estimators=estimators or ("ml", "ols"), seed=seed, jobs=jobs,
                             progress=progress, angles_only=angles_only, scheduler=scheduler, out=folder,
                             resume=resume, design={"harmonics": harmonics, "criterion": criterion})
    held = "" if folder is None else f"; {shown_name(folder)}/table.txt, montecarlo.json and report.html hold every one"
    out.print(montecarlo_table(res, rows=None if show_all else SUMMARY_ROWS, rest=f"--all lists them{held}"))
    for e in res.estimators:
        w = res.summary(e)
        out.print(f"{e.upper()}, worst over parameters: RMSE {100 * w['relative_rmse']:.3g} %, "
                  f"RMSE/CRB{'*' * angles_only} {w['rmse_crb']:.2f}, |bias|/std {w['abs_bias_std']:.2f}; "
                  f"{w['runs_ok']}/{res.runs} runs",
                  highlight=False)
    if folder is not None:
        with _report_folder(folder, overwrite) as tmp:
            write_montecarlo(res, tmp)
        discard_tasks(folder)
        err.print(f"table, JSON, figure and report.html written to {shown_name(folder)}/ "
                  f"({res.settings['wall_time_s']:.1f} s)")


@app.command(short_help="A physically consistent URDF of an identified model, closest to a prior.")
@click.argument("result", metavar="RESULT.json", type=click.Path(path_type=Path))
@click.option("--prior", "prior_src", required=True, metavar="MODEL", help="Prior model (preset, URDF or YAML) with "
              "the identified model's joints: it gives the output's kinematics, names, limits and visuals, and the "
              "guess the data refine (masses, CoMs, inertias).")
@click.option("--region", type=PROBABILITY, metavar="P", help="Search the P confidence ellipsoid of the identified "
              "parameters (e.g. 0.95; anchored ones stay exact) instead of reproducing them exactly: for noisy "
              "results that no physical model reproduces.")
@click.option("--format", "fmt", type=click.Choice(EXPORT_FORMATS), default="urdf", show_default=True,
              help="Output format: urdf (a URDF prior keeps its file but the <inertial> elements; a YAML prior is "
              "written out as URDF) or yaml (spaceid's YAML model: keeps the planar flag, reaction wheels and "
              "declared zeros, no visuals) or mjcf (a free-floating MuJoCo model: a free joint on the base, or an air "
              "bearing's x, y and yaw for a planar model; zero gravity; no geometry).")
@output("File to write (never over RESULT.json or the prior).")
def export(result, prior_src, region, fmt, output):
    """Standard inertial parameters of every body (mass, CoM, inertia) that reproduce the identified
    parameters (or lie within their --region P ellipsoid), with every body's pseudo-inertia positive
    definite, closest to the prior in the log-det divergence; written as URDF (or YAML). Prints per
    body what changed and which standard parameters the data set."""
    from rich.table import Table

    from .estimation import load_result
    from .identified import export_model, write_export

    ident = load_result(result)
    res = export_model(ident, prior_src, region=region, where=str(result), prior_name=str(prior_src))
    write_export(res, output, fmt=fmt, inputs=(result, prior_src),
                 note=f"inertial parameters identified by spaceid export from {Path(result).name}, prior {prior_src}")
    table = Table("body", "mass [kg]", "dm [%]", "dCoM [mm]", "dI [%]",
                  "set by the data", title="Exported inertials against the prior",
                  caption="dI: change of the inertia about the CoM (relative Frobenius norm)")
    for c in res.changes():
        seen = "all" if len(c["seen"]) == 10 else " ".join(c["seen"]) or "none"
        table.add_row(c["body"], f"{c['mass']:.6g}", f"{100 * (c['mass'] / c['mass_prior'] - 1):+.2f}",
                      f"{1e3 * c['com_shift']:.2f}", f"{100 * c['inertia_change']:.2f}", seen)
    out.print(table)
    if res.region is not None:  # given, or taken because no physical model reproduces the estimate
        fit = f"within the {res.region:g} ellipsoid (distance^2 {res.mahalanobis:.4g} <= {res.bound:.4g})"
    else:
        error = np.abs(res.values - ident.values) / np.maximum(np.abs(ident.values), 1e-300)
        fit = f"exact (largest relative error {error.max():.1e})"
    out.print(f"fit {fit}; log-det divergence from the prior {res.divergence:.4g}; {res.steps} convex "
              f"step{'s' * (res.steps != 1)}; written to {shown_name(output)}", highlight=False)


@app.command(short_help="Mass, CoM and inertia of a payload held by a known servicer, from a log.")
@MODEL
@click.argument("log_path", metavar="LOG", type=click.Path(path_type=Path))
@PLANAR
@click.option("--link", required=True, metavar="LINK", help="The link that holds the payload: a body of MODEL, or a "
              "URDF link on fixed joints below one (a tool link); the CoM and inertia are in its frame.")
@click.option("--momentum", required=True, metavar=MOMENTUM_METAVAR + "|unknown|hold", help="Angular momentum of "
              "the whole system after the capture [N m s]: h (planar) or hx,hy,hz (inertial axes); 0 if it started at "
              "rest; with --payload-velocity/--payload-rate the servicer's alone. 'hold' (with --grasp): the "
              "servicer's over the 1 s before the grasp, its error carried into the payload's. 'unknown': estimated "
              "with the payload (the known servicer fixes the scale; a base that turns steadily makes it nearly "
              "collinear with the payload, and a warning says so).")
@click.option("--grasp", type=float, metavar="T", help="The grasp instant [s] on the log's clock: the payload is "
              "identified from T plus half the longest differentiator window (the rates blend the impact before) to "
              "the end; with --momentum hold the servicer's momentum is averaged over the hold before T, and the "
              "drift integrated from there (as 'spaceid experiment --capture' does).")
@click.option("--payload-velocity", metavar="VX,VY[,VZ]", help="With --grasp, a payload that moved before the grasp: "
              "the velocity of its CoM [m/s], inertial axes (relative to the servicer's CoM); its momentum, a "
              "function of its parameters, joins the servicer's --momentum.")
@click.option("--payload-rate", metavar="W|WX,WY,WZ", help="With --grasp: the payload's angular velocity before the "
              "grasp [rad/s], about the vertical (planar) or inertial axes.")
@noise_options
@drift_option("External torques that change the momentum during the log, estimated with the payload: torque, "
              "viscous, coulomb (as for 'spaceid identify').", values=False)
@SEED
@log_options
@output("PAYLOAD.json to write.")
def payload(model_src, log_path, planar, link, momentum, grasp, payload_velocity, payload_rate, noise, drift, seed,
            output, reading):
    """Identify the payload that LINK of the known servicer MODEL holds rigidly, from a LOG recorded
    after the capture (or, with --grasp, from the part of it after the grasp): its mass, centre of
    mass and inertia about the centre of mass (planar motion: mass, CoM x and y, Izz), physically
    consistent, with standard errors. Noise levels not given are estimated from the log; with
    every one zero the fit is unweighted."""
    from .data import write_json
    from .identified import identify_payload, payload_after_grasp, payload_units
    from .models import load_model

    model = load_model(model_src, planar=planar)
    if momentum.strip().lower() == "hold" and grasp is None:
        raise SpaceidError("--momentum hold needs --grasp T: the hold is the second of the log before the grasp")
    h = "hold" if momentum.strip().lower() == "hold" else _momentum(momentum, model.planar, allow_unknown=True)
    motion = _payload_motion(payload_velocity, payload_rate, grasp, h)
    kinds = _drift(drift, model.planar, values=False)
    log = _measured_log(model, log_path, reading)
    with _warnings_to_stderr():
        if grasp is None:
            res = identify_payload(model, log, link, h, noise=noise, drift=kinds, seed=seed, where=str(log_path))
        else:
            res = payload_after_grasp(model, log, link, grasp, h, payload_motion=motion, noise=noise, drift=kinds,
                                      seed=seed, where=str(log_path)).estimate  # fmt: skip
    write_json(output, res.to_dict())
    for name, value, std, unit in zip(res.names, res.values, res.std, payload_units(res.names)):
        out.print(f"{name:>4s} = {value:12.6g} +/- {std:.3g} {unit}", highlight=False)
    if res.not_identifiable:
        out.print(f"not identifiable from planar motion: {', '.join(res.not_identifiable)}", highlight=False)
    s = res.settings
    if grasp is not None:
        g, hold = s["grasp"], s["grasp"]["hold"]
        held = "" if hold is None else (f"; the servicer's momentum over {hold['from']:.6g}..{hold['to']:.6g} s "
                                        f"({hold['samples']} samples)")
        out.print(f"window {g['window'][0]:.6g}..{g['window'][1]:.6g} s after the grasp at {grasp:g} s{held}",
                  highlight=False)
    projected = " (projected to the nearest consistent estimate)" if s["consistency"]["projected"] else ""
    chi2 = "" if s["chi2_dof"] is None else f"chi2/dof = {s['chi2_dof']:.3g}; "
    out.print(f"{s['estimator']}: {s['gauss_newton_steps']} steps; residual RMS {s['residual_rms']:.3g} N m s; {chi2}"
              f"{s['n_samples']} samples{projected}; written to {output}", highlight=False)


def _payload_motion(velocity, rate, grasp, momentum) -> tuple | None:
    """``(velocity (3,), rate (3,))`` of --payload-velocity and --payload-rate, or None when neither."""
    if velocity is None and rate is None:
        return None
    if grasp is None or momentum is None:
        raise SpaceidError("--payload-velocity/--payload-rate need --grasp T and the servicer's --momentum (a value or "
                           "'hold'): the payload's momentum is added to the servicer's at the grasp")
    v = _number_list(velocity or "0,0", "--payload-velocity", float)
    w = _number_list(rate or "0", "--payload-rate", float)
    if len(v) not in (2, 3) or len(w) not in (1, 3) or not np.all(np.isfinite(v + w)):
        raise SpaceidError(f"--payload-velocity needs 2 or 3 finite numbers [m/s] and --payload-rate 1 or 3 [rad/s], "
                           f"got {velocity!r} and {rate!r}")
    return np.array([*v, 0.0][:3]), np.array(w if len(w) == 3 else [0.0, 0.0, *w])


def _number_list(value, option, kind):
    """A comma-separated list of numbers of ``kind``, e.g. ``5,10,20``."""
    try:
        return [kind(v) for v in value.split(",") if v.strip()]
    except ValueError:
        raise SpaceidError(f"{option}: {value!r} is not a comma-separated list of {kind.__name__} values, "
                           f"e.g. {option} {'5,10' if kind is float else '2,3'}") from None


@app.command(short_help="Design study: cond(Y) and predicted relative CRB over durations, harmonics and samples.")
@MODEL
@PLANAR
@MOMENTUM
@click.option("--durations", required=True, metavar="TF[,TF...]", help="Trajectory durations [s], comma-separated.")
@click.option("--harmonics", required=True, metavar="NF[,NF...]", help="Fourier harmonics, comma-separated.")
@click.option("--samples", required=True, metavar="N[,N...]", help="Samples over each duration, comma-separated.")
@click.option("--criterion", type=click.Choice(DESIGN_CRITERIA), default="cond", show_default=True,
              help="Design criterion of every setting (see 'spaceid design').")
@click.option("--starts", type=STARTS, default=8, show_default=True, help="Local searches of each setting's design.")
@click.option("--max-steps", type=click.IntRange(min=1), metavar="N", help="Most linearisations of the regressor each "
              "setting's local searches make (as 'spaceid design --max-steps'): bounds a setting's work, with the same "
              "rows on any machine [default: to convergence for small regressors, 40 for large ones].")
@noise_options
@SEED
@click.option("--jobs", type=JOBS, help="Worker processes [default: all cores].")
@SCHEDULER
@out_folder("Folder for sweep.json, sweep.csv, table.txt and sweep.png (each setting kept beside it in "
            ".FOLDER.tasks/ as it completes, for --resume, until they are written).", required=True)
@RESUME
@OVERWRITE
def sweep(model_src, planar, momentum, durations, harmonics, samples, criterion, starts, max_steps, noise, seed, jobs,
          scheduler, folder, resume, overwrite):
    """Design study: an excitation designed for every setting of the grid durations x harmonics
    x samples, and per setting the condition number of its regressor and the predicted
    Cramer-Rao standard deviation relative to the nominal parameters (worst parameter), for
    the noise given (default 1e-4 rad, rad/s on every signal)."""
    from ._campaign import discard_tasks
    from .studies import DEFAULT_NOISE, run_sweep, sweep_table, write_sweep

    param = _param(model_src, planar)
    h = _momentum(momentum, param.model.planar)
    grid = {"durations": _number_list(durations, "--durations", float),
            "harmonics": _number_list(harmonics, "--harmonics", int),
            "samples": _number_list(samples, "--samples", int)}  # fmt: skip
    with _progress("settings") as progress:
        res = run_sweep(param, momentum=h, **grid, noise=noise or DEFAULT_NOISE, criterion=criterion, n_starts=starts,
                        max_steps=max_steps, seed=seed, scheduler=scheduler, jobs=jobs, out=folder, resume=resume,
                        progress=progress)
    out.print(sweep_table(res))
    with _report_folder(folder, overwrite) as tmp:
        write_sweep(res, tmp)
    discard_tasks(folder)
    err.print(f"sweep.json, sweep.csv, table and figure written to {shown_name(folder)}/ "
              f"({res.settings['wall_time_s']:.1f} s)")


@app.command(short_help="Detect parameter changes (a capture, a payload release) on a running log.")
@MODEL
@click.argument("log_path", metavar="LOG", type=click.Path(path_type=Path))
@PLANAR
@MOMENTUM
@click.option("--known", multiple=True, metavar="NAME=VALUE", help="A known parameter, as for 'spaceid identify': "
              "anchors the scale when the momentum is zero; repeatable.")
@noise_options
@drift_option("External torques that change the momentum during the log "
              "(torque, viscous, coulomb, as for 'spaceid identify'; e.g. viscous on an air-bearing table): each "
              "segment's coefficients are estimated with its parameters, the drift integrated from the segment's "
              "start, where its momentum is the segment before's; --momentum is then the momentum at the first sample.",
              values=False)
@click.option("--false-alarm-rate", type=PROBABILITY, default=FALSE_ALARM_RATE, show_default=True,
              help="False alarms per sample when nothing changes (one per 1/RATE samples on average): "
                   "sets the CUSUM threshold.")
@click.option("--change-ratio", type=RATIO, default=CHANGE_RATIO, show_default=True,
              help="Innovation variance ratio the test is tuned to "
                   "(a change that doubles the momentum residual's std is 4).")
@click.option("--forgetting", type=FORGETTING, default=1.0, show_default=True,
              help="Forgetting factor of the recursive estimate, in (0, 1]; "
                   "1: each segment's estimate is its batch weighted least squares.")
@click.option("--warmup", type=SAMPLES, help="Samples of each segment identified in batch before its test starts "
              f"[default: max({WARMUP}, 4 (p + 1) / rows)].")
@click.option("--max-segment", type=SAMPLES, default=4000, show_default=True,
              help="Samples of a segment kept for its batch identification (evenly thinned), and the longest a "
                   "warm-up waits for samples that determine the parameters.")
@click.option("--estimator", type=click.Choice([e for e in ESTIMATORS if e != "angles"]), default="ml",
              show_default=True,
              help="Estimator of the batch identifications of the segments (see 'spaceid identify').")
@click.option("--follow", is_flag=True, help="LOG is a CSV being written: keep reading appended rows until "
              "interrupted (Ctrl-C) or --follow-timeout seconds pass without a new row (a bag cannot be read until "
              "its recording closes).")
@click.option("--follow-timeout", type=SECONDS, default=10.0, show_default=True, metavar="SECONDS",
              help="With --follow: the log counts as finished after this many seconds without a new row.")
@log_options
@output("EVENTS.json to write (rewritten after each event, so that it can be read while the monitor runs).")
@report_option("the run, written at its end: events, segments, the statistic and the parameters' changes")
def monitor(model_src, log_path, planar, momentum, known, noise, drift, false_alarm_rate, change_ratio, forgetting,
            warmup, max_segment, estimator, follow, follow_timeout, output, report, reading):
    """Follow a log sample by sample (LOG.csv; a ROS bag, read part by part as its messages come;
    or with --follow a CSV being written): a recursive estimate of the parameters on the
    momentum equations and a CUSUM test on its normalised residual; each detected change is
    printed and written to EVENTS.json with its time, test statistic and the parameters that
    changed, and each segment between changes is identified in batch. Noise levels not given are
    estimated from the first samples."""
    from .data import bag_chunks, follow_log, is_bag, write_json
    from .estimation import Monitor, log_chunks, parse_known
    from .studies import write_monitor_html

    report = _report_path(report, output)
    param = _param(model_src, planar)
    h = _momentum(momentum, param.model.planar)
    m = param.model
    if follow:
        if is_bag(log_path):
            raise SpaceidError(f"{log_path}: --follow reads a CSV being written; a bag cannot be read while it "
                               "is recorded (ROS 1 writes its index, MCAP its footer and ROS 2 its metadata.yaml "
                               "when the recording closes): monitor the bag once closed, or log a CSV to follow")
        if any(reading[k] is not None for k in BAG_ONLY):
            raise SpaceidError("--follow reads a CSV being written: the bag options do not apply")
        given = ["--joint-rates differentiate"] * (reading["joint_rates"] == "differentiate") + [
            o for o in ("--window", "--quantum") if reading[o[2:]] is not None]
        if given:
            raise SpaceidError(f"{' and '.join(given)}: --follow reads the rows as they are written, with their rate "
                               "columns: differentiate once the log is closed (monitor it without --follow)")
        chunks = follow_log(log_path, joints=m.joints, planar=m.planar, wheels=m.wheels, timeout=follow_timeout)
    elif is_bag(log_path):  # read part by part: events as the messages are read, memory bounded
        chunks = bag_chunks(log_path, joints=m.joints, planar=m.planar, wheels=m.wheels, **_bag_reading(reading))
    else:
        chunks = log_chunks(_measured_log(m, log_path, reading))
    kinds = _drift(drift, m.planar, values=False)
    mon = Monitor(param, h, known=parse_known(known), noise=noise, drift=kinds, false_alarm_rate=false_alarm_rate,
                  change_ratio=change_ratio, forgetting=forgetting, warmup=warmup, max_segment=max_segment,
                  estimator=estimator, where=str(log_path))
    err.print(f"CUSUM threshold {mon.threshold:.4g} for {false_alarm_rate:g} false alarms per sample; expected "
              f"delay {mon.expected_delay:.3g} samples for a change of ratio {change_ratio:g}", highlight=False)
    with _warnings_to_stderr():
        try:
            for chunk in chunks:
                for event in mon.update(chunk):
                    _print_event(event)
                    write_json(output, mon.record().to_dict())
        except KeyboardInterrupt:
            err.print("interrupted: closing the last segment")
        printed = len(mon.events)
        record = mon.finish()
    for event in record.events[printed:]:  # a change too close to the end for the next warm-up
        _print_event(event)
    for event, change in zip(record.events, record.whole_segment_changes):
        if change is not None:
            out.print(f"change {event.index}, whole segments compared: changed "
                      f"{', '.join(change['changed']) or 'none'}", highlight=False)
    write_json(output, record.to_dict())
    write_monitor_html(record, report, source=shown_name(log_path))
    out.print(f"{len(record.events)} change(s) in {record.n_samples} samples; {len(record.segments)} "
              f"segment(s) identified; written to {output}, report to {shown_name(report)}", highlight=False)


def _print_event(event):
    """One line for a detected change."""
    from .estimation import Z_CHANGED

    changed = ", ".join(event.changed) or f"none beyond {Z_CHANGED:g} standard errors"
    lead = f" (differentiated rates: the change up to {event.lead:.3g} s later)" if event.lead else ""
    out.print(f"change {event.index} at t = {event.time:.6g} s{lead} (detected at {event.detected_at:.6g} s, "
              f"{event.delay} samples; statistic {event.statistic:.4g} > {event.threshold:.4g}); changed: {changed}",
              highlight=False)


@app.group(cls=_Group, short_help="Live on ROS 2: the monitor as a node; logs, bags and the twin published.")
def ros():
    """Live on ROS 2 (docs: live monitoring): 'ros monitor' identifies and detects changes on the
    robot's topics as the messages arrive; 'ros play' and 'ros twin' publish a recording or the
    Cepheus twin's sensors on the same topics. Needs the ros extra: pip install "spaceid[ros]"."""


ROS_JOINT_TOPIC = click.option("--joint-topic", help=f"sensor_msgs/JointState topic [default: {DEFAULT_JOINT_TOPIC}, "
                               "or the mapping's].")
ROS_POSE_TOPIC = click.option("--pose-topic", help=f"Base attitude topic [default: {DEFAULT_POSE_TOPIC}, or the "
                              "mapping's].")
RATE_FACTOR = click.option("--rate-factor", type=POSITIVE, default=1.0, show_default=True,
                           help="Speed-up over real time (the header stamps keep the recorded times).")
SUBSCRIBERS = click.option("--subscribers", type=click.IntRange(min=0), default=1, show_default=True,
                           help="Wait for this many subscribers on each topic before publishing (at most 60 s).")


@ros.command("monitor")
@MODEL
@PLANAR
@MOMENTUM
@click.option("--mapping", type=click.Path(path_type=Path), help="The bag mapping file (YAML): joint_topic, "
              "pose_topic, joints {published name: model name}, rate, pose_latency, max_gap, max_tilt.")
@ROS_JOINT_TOPIC
@ROS_POSE_TOPIC
@click.option("--pose-type", type=click.Choice(["pose", "odometry", "imu"]), default="pose", show_default=True,
              help="Message of the attitude topic: geometry_msgs/PoseStamped, nav_msgs/Odometry or sensor_msgs/Imu "
                   "(its orientation, and with --base-rate gyro its angular velocity).")
@click.option("--base-rate", type=click.Choice(BASE_RATES), help="The base rate from the attitude differentiated, or "
              "the gyro's: the angular velocity of the odometry (twist) or IMU messages, in base axes [default: the "
              "mapping's base_rate, else attitude].")
@click.option("--link", help="The link that grasps: after each change the payload it holds is identified and "
              "published on /spaceid/payload.")
@click.option("--known", multiple=True, metavar="NAME=VALUE", help="A known parameter, as for 'spaceid monitor'.")
@noise_options
@drift_option("External torques, as for 'spaceid monitor'.", values=False)
@click.option("--false-alarm-rate", type=PROBABILITY, default=FALSE_ALARM_RATE, show_default=True,
              help="False alarms per sample when nothing changes, as for 'spaceid monitor'.")
@click.option("--warmup", type=SAMPLES, help="Samples of each segment identified in batch before its test starts, "
              "as for 'spaceid monitor'.")
@click.option("--estimator", type=click.Choice([e for e in ESTIMATORS if e != "angles"]), default="ml",
              show_default=True, help="Estimator of the segments' batch identifications, as for 'spaceid monitor' "
              "(wls takes about half ml's time: benchmarks/bench_ros.py).")
@click.option("--block", type=SECONDS, default=0.1, show_default=True, metavar="SECONDS",
              help="Fewest seconds of joint states aligned at a time (the messages that arrived together are aligned "
                   "at once): a sample waits up to this long after the message that completes it.")
@click.option("--joint-rates", type=click.Choice(["differentiate", "auto", "velocity"]), default="differentiate",
              show_default=True, help="Joint rates differentiated from the angles, or the published velocities.")
@click.option("--window", type=click.IntRange(min=3), metavar="SAMPLES", help="Savitzky-Golay window of every "
              "differentiated series [samples, odd; default: chosen per aligned block, which varies from block to "
              "block: give one for a steady test].")
@click.option("--order", type=click.IntRange(min=1), help="Savitzky-Golay degree of the differentiators [default: "
              "3 with --window, else chosen per aligned block].")
@output("EVENTS.json to write: after each event and at Ctrl-C.")
@click.option("--result", type=_OutputPath(), metavar="PATH", help="RESULT.json written at Ctrl-C: the last "
              "segment's identification [default: result.json beside -o].")
def ros_monitor(model_src, planar, momentum, mapping, joint_topic, pose_topic, pose_type, base_rate, link, known, noise,
                drift, false_alarm_rate, warmup, estimator, block, joint_rates, window, order, output, result):
    """Subscribe to the robot's joint states and base attitude, align them by their header stamps
    (as a bag is read, with its mapping file), identify recursively and detect changes as the
    messages arrive: publish the estimate with its standard errors on /spaceid/estimate, one
    message per change on /spaceid/events and, with --link, the payload on /spaceid/payload
    (std_msgs/String holding JSON). Ctrl-C writes EVENTS.json and RESULT.json of what was seen."""
    from .data import write_json
    from .estimation import parse_known
    from .ros import LiveMonitor, require_rclpy, run_monitor

    require_rclpy()
    param = _param(model_src, planar)
    live = LiveMonitor(param, _momentum(momentum, param.model.planar), mapping=mapping, joint_topic=joint_topic,
                       pose_topic=pose_topic, link=link, block=block,
                       reading={"joint_rates": joint_rates, "window": window, "order": order, "base_rate": base_rate},
                       where="ros2", known=parse_known(known), noise=noise,
                       drift=_drift(drift, param.model.planar, values=False), false_alarm_rate=false_alarm_rate,
                       warmup=warmup, estimator=estimator)  # fmt: skip
    result = result or output.with_name("result.json")
    err.print(f"listening on {live.aligner.joint_topic} and {live.aligner.pose_topic}; Ctrl-C ends", highlight=False)

    def shown(item):
        d = item.data
        if item.kind == "event" and d["stage"] == "detected":
            out.print(f"change {d['index']} at t = {d['time']:.6g} s (detected at {d['detected_at']:.6g} s)",
                      highlight=False)
        elif item.kind == "event" and d["stage"] == "undetermined":
            w = d["warm_up"]
            what = ", ".join(w["undetermined"]) or f"the estimate (bias {w['bias']:.2g})" if w["error"] is None \
                else f"the parameters ({w['error']})"
            out.print(f"change {d['index']} at t = {d['time']:.6g} s: not compared yet: the {w['n_samples']} samples "
                      f"after it do not determine {what}", highlight=False)
        elif item.kind == "event":
            out.print(f"change {d['index']} at t = {d['time']:.6g} s: changed {', '.join(d['changed']) or 'none'}",
                      highlight=False)
            write_json(output, live.monitor.record().to_dict())
        elif item.kind == "payload" and "mass" in item.data:
            out.print(f"payload after change {item.data['event']}: mass {item.data['mass']:.4g} +/- "
                      f"{item.data['std']['mass']:.2g} kg", highlight=False)

    with _warnings_to_stderr():
        _, record = run_monitor(live, pose_type=pose_type, on_output=shown)
    write_json(output, record.to_dict())
    ident = live.result(record)
    if ident is not None:
        write_json(result, ident.to_dict())
    out.print(f"{len(record.events)} change(s) in {record.n_samples} samples; written to {output}"
              + (f" and {result}" if ident is not None else " (no segment identified: no RESULT.json)"),
              highlight=False)


@ros.command("play")
@click.argument("log_path", metavar="LOG|BAG", type=click.Path(path_type=Path))
@click.argument("model_src", metavar="[MODEL]", required=False)
@ROS_JOINT_TOPIC
@ROS_POSE_TOPIC
@RATE_FACTOR
@SUBSCRIBERS
def ros_play(log_path, model_src, joint_topic, pose_topic, rate_factor, subscribers):
    """Publish a recorded bag's joint states and base poses (or the angles, rates and attitude of
    a CSV log of MODEL) as sensor_msgs/JointState and geometry_msgs/PoseStamped (nav_msgs/Odometry
    with the gyro's rate when the bag's pose topic carries one), paced by their stamps."""
    from .data import is_bag, read_log, read_recording
    from .ros import recording_of_log, require_rclpy

    require_rclpy()
    if is_bag(log_path):
        rec = read_recording(log_path, **{k: v for k, v in (("joint_topic", joint_topic), ("pose_topic", pose_topic))
                                         if v is not None})  # fmt: skip
    else:
        if model_src is None:
            raise SpaceidError(f"{log_path}: a CSV log is read with its model's joints: give MODEL after it")
        m = _param(model_src, None).model
        rec = recording_of_log(read_log(log_path, joints=m.joints, planar=m.planar, wheels=m.wheels))
    _publish(rec, joint_topic, pose_topic, rate_factor, subscribers)


@ros.command("twin")
@click.option("--capture", is_flag=True, help="Grasp a free-floating payload during the motion.")
@click.option("--capture-settings", type=click.Path(path_type=Path), metavar="FILE", help="With --capture: the "
              "payload, as for 'spaceid experiment --capture-settings'.")
@click.option("--capture-time", type=SECONDS, default=4.0, show_default=True, help="With --capture: the grasp, "
              "seconds after the recording starts.")
@click.option("--duration", type=SECONDS, default=9.0, show_default=True, help="Seconds recorded.")
@click.option("--trajectory", default="paper-table2", show_default=True, help="paper-table2 or a file from 'design'.")
@click.option("--wheel-speed", type=FINITE, default=170.0, show_default=True, help="Wheel speed [rad/s].")
@click.option("--ideal", is_flag=True, help="Switch off friction, torque limits, thrusters and tank drain.")
@SEED
@ROS_JOINT_TOPIC
@ROS_POSE_TOPIC
@RATE_FACTOR
@SUBSCRIBERS
def ros_twin(capture, capture_settings, capture_time, duration, trajectory, wheel_speed, ideal, seed, joint_topic,
             pose_topic, rate_factor, subscribers):
    """Run the Cepheus twin (cepheus-rw, the wheel spun up first) and publish its encoders and
    motion capture as sensor_msgs/JointState and geometry_msgs/PoseStamped on the twin's clock;
    with --capture the grasp time is printed first."""
    from .ros import require_rclpy, twin_recording
    from .studies import capture_protocol

    require_rclpy()
    if not capture and capture_settings is not None:
        raise SpaceidError("--capture-settings needs --capture")
    protocol = capture_protocol(capture_settings) if capture else None
    with _warnings_to_stderr():
        run = twin_recording(trajectory=trajectory, duration=duration, wheel_speed=wheel_speed, capture=protocol,
                             capture_time=capture_time, ideal=ideal, seed=seed)  # fmt: skip
    if capture:
        out.print(f"grasp at {run.meta['capture']['time']:.9g} s", highlight=False)
    _publish(run.recording, joint_topic, pose_topic, rate_factor, subscribers)


def _publish(rec, joint_topic, pose_topic, rate_factor, subscribers):
    """Publish ``rec`` (:func:`spaceid.ros.play_recording`) and say how much."""
    from .ros import play_recording

    n = rec.joints.t.size + rec.base.t.size
    err.print(f"publishing {n} messages ({rec.joints.t[-1] - rec.joints.t[0]:.3g} s) at {rate_factor:g}x",
              highlight=False)
    sent = play_recording(rec, joint_topic=joint_topic or DEFAULT_JOINT_TOPIC,
                          pose_topic=pose_topic or DEFAULT_POSE_TOPIC, rate_factor=rate_factor,
                          subscribers=subscribers, wait=60.0)  # fmt: skip
    out.print(f"published {sent} messages", highlight=False)


def _result_model(ident):
    """The model an identification was made on (its joints, wheels and parameters)."""
    from .models import load_model

    return load_model(ident.model, planar=ident.planar)


def main(argv=None) -> int:
    """Entry point: run the app and return its exit code (see :meth:`_Group.invoke`); SIGTERM
    unwinds the command like Ctrl-C does."""
    warnings.simplefilter("default")
    warnings.showwarning = lambda msg, *a, **k: print(f"warning: {for_the_command_line(msg)}", file=sys.stderr)
    previous = signal.signal(signal.SIGTERM, _on_sigterm)
    try:
        code = app.main(args=argv, prog_name="spaceid", standalone_mode=False)
    except click.ClickException as exc:  # usage errors: click's own message, exit code 2
        exc.show()
        return exc.exit_code
    except click.Abort:  # an interrupt before the command started
        return 130
    finally:
        signal.signal(signal.SIGTERM, previous)
    return code if isinstance(code, int) else 0


def run(argv=None):
    """The ``spaceid`` program: :func:`main`, then the process ends with its exit code without tearing down
    the interpreter's modules (LLVM's and Numba's compiled code, Pinocchio, SciPy: 0.15 s of Cepheus's
    ``model``, 0.23 s of the servicer's ``identify``, for memory the system takes back anyway). The exit
    handlers run and the terminal streams are flushed first, and the interpreter ends as usual when another
    thread still runs (it waits for that thread)."""
    code = main(argv)
    if any(t.is_alive() and not t.daemon for t in threading.enumerate() if t is not threading.main_thread()):
        sys.exit(code)
    atexit._run_exitfuncs()
    for stream in (sys.stdout, sys.stderr):
        with contextlib.suppress(OSError, ValueError):  # a closed pipe or stream: nothing more to say
            stream.flush()
    os._exit(code)


if __name__ == "__main__":
    run()
