"""The monitor on robots nobody on the project designed (issue 26): random planar and spatial URDF
trees (``random_robots``) in a smooth three-harmonic motion grasp a 0.9 kg point payload on a
random link at a random time, noise-free or with 1e-4 rad and rad/s of noise, the rates measured
or differentiated: the grasp is reported within 0.25 s of it, and logs without a change raise no
more false alarms than the stated rate predicts. The seeds of failures found this way are kept
as ``@example`` regression cases.

A grasp is required to be found after the first warm-up (on the changeless log: the monitor
lengthens it until its samples determine the parameters; before, a change is taken in by the
estimate's undetermined directions, or made up by them, and a change within it makes its
estimate, and the determinacy judged at it, a blend of the two systems; the grasp of the issue,
within the first warm-up of estimated noise levels, is ``test_the_grasp_of_issue_26``; after a false alarm,
allowed once, after the warm-up of the segment it starts) and when
it is observable within 0.25 s: the momentum error it makes in the model before
it, summed in squares over those samples in units of the noise's, at least ``OBSERVABLE`` (the
CUSUM needs about a third of that to cross its threshold in 13 samples; a payload near a joint
axis of a link that barely moves may make less)."""

import dataclasses
import warnings

import numpy as np
import pytest
from hypothesis import Phase, assume, example, given
from hypothesis import strategies as st
from random_robots import random_robot
from robot_tally import robots, stage
from scipy.stats import binom

from spaceid.data import Log, differentiate_log
from spaceid.dynamics import angular_momentum, minimal_parameters
from spaceid.estimation import Noise, monitor
from spaceid.estimation._monitor import NOISE_SAMPLES
from spaceid.models._model import inertial_vector
from spaceid.motion import add_noise, simulate

RATE = 50.0  # [Hz]
MASS = 0.9  # [kg], the payload
WITHIN = 0.25  # [s]: the grasp is reported within this of it
WINDOW = 11  # differentiator window [samples] (0.2 s): short against the motion, as for monitoring
LEVEL = 1e-4  # noise [rad, rad/s]
OBSERVABLE = 200.0
P_FALSE = 1e-3  # the binomial tail that the false alarms may reach
SEEDS = st.integers(0, 2**31 - 1)
# no shrinking: an example takes seconds, and the seed of a failure is what is kept
PHASES = [Phase.explicit, Phase.reuse, Phase.generate]
FAST = robots(1, phases=PHASES)
SLOW = robots(30, phases=PHASES)


@dataclasses.dataclass(frozen=True)
class Robot:
    model: object
    param: object
    momentum: np.ndarray
    motion: object
    rng: np.random.Generator


def _robot(seed: int, planar: bool, folder, **size) -> Robot:
    """A random robot and a smooth motion of each joint: three harmonics of 0.2 to 0.6 Hz, 0.1 to
    0.4 rad each (prismatic joints 0.3 m per rad)."""
    model = random_robot(seed, planar=planar, **size).load(folder)
    rng = np.random.default_rng(seed)
    nj = model.n_joints
    freq, phase = rng.uniform(0.2, 0.6, (3, nj)), rng.uniform(0, 2 * np.pi, (3, nj))
    amp = rng.uniform(0.1, 0.4, (3, nj))
    amp = amp * np.array([0.3 if b.joint_type == "prismatic" else 1.0 for b in model.bodies[1:]])

    def motion(t):
        arg = 2 * np.pi * freq[None] * np.asarray(t)[:, None, None] + phase[None]
        return (amp * np.sin(arg)).sum(1), (amp * 2 * np.pi * freq * np.cos(arg)).sum(1)

    h = np.array([0.0, 0.0, 0.3]) if planar else np.array([0.3, -0.2, 0.1])
    return Robot(model, minimal_parameters(model), h, motion, rng)


def _with_payload(model, rng) -> tuple:
    """``(captured, link)``: ``model`` with ``MASS`` at a random point within 0.1 m of the origin of a random link,
    ``link``."""
    body = model.bodies[rng.integers(1, len(model.bodies))].name
    point = rng.uniform(-0.1, 0.1, 3) * (np.r_[1.0, 1.0, 0.0] if model.planar else 1.0)
    return dataclasses.replace(model, bodies=tuple(
        dataclasses.replace(b, inertial=b.inertial + inertial_vector(MASS, point, np.zeros((3, 3))))
        if b.name == body else b for b in model.bodies)), body  # fmt: skip


def _simulate(robot: Robot, t, grasp=None, captured=None):
    """The noise-free log over ``t``; with a ``grasp`` time, the ``captured`` model from it on
    (the momentum carried over, the attitude continued)."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # the 3D momentum of a planar robot with tilted inertia axes
        if grasp is None:
            return simulate(robot.param, robot.param.true_values, robot.motion, t, robot.momentum, model=robot.model)
        before = simulate(robot.param, robot.param.true_values, robot.motion, t[t <= grasp], robot.momentum,
                          model=robot.model)  # fmt: skip
        after = simulate(robot.param, minimal_parameters(captured).true_values, robot.motion, t[t >= grasp],
                         robot.momentum, initial_quat=before.base_quat[-1])  # fmt: skip
    a = before.select(slice(0, -1))
    return Log(np.r_[a.t, after.t], a.joints, np.r_[a.q, after.q], np.r_[a.qd, after.qd],
               np.r_[a.base_quat, after.base_quat], np.r_[a.base_w, after.base_w], planar=a.planar)  # fmt: skip


def _measured(log, noisy: bool, differentiated: bool, seed: int):
    """The log as monitored: noise on the angles and rates, the rates differentiated from the angles."""
    if noisy:
        log = add_noise(log, angle=LEVEL, rate=LEVEL, seed=seed)
    return differentiate_log(log, window=WINDOW) if differentiated else log


def _noise(noisy: bool, differentiated: bool, estimated: bool):
    """The levels given to the monitor: None (estimated from the log), or the added ones; for a
    noise-free log 1e-9, and 1e-7 when its rates were differentiated: its errors are then the
    differentiator's truncation errors, smooth, up to 6e-9 rad/s here, which the levels must bound
    well (the log's own estimate finds less; with 21-sample windows they reached 2e-6 rad/s)."""
    if estimated and not (differentiated and not noisy):
        return None
    level = LEVEL if noisy else 1e-7 if differentiated else 1e-9
    return Noise(angle=level, rate=level, base_rate=level, attitude=level)


def _momentum_error(model, log, h):
    """The momentum ``model`` gives ``log`` less the true one ``h`` [N m s] (the z row of a planar robot)."""
    e = angular_momentum(model, log.q, log.qd, log.base_w, log.base_quat) - h
    return e[:, 2:] if model.planar else e


def _monitored(robot: Robot, log, noise, **options):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        return monitor(robot.param, log, robot.momentum, noise=noise, **options)


@dataclasses.dataclass(frozen=True)
class GraspRun:
    """A changeless log's monitoring (``quiet``) and the same log's with a grasp at ``grasp`` [s]
    (``record``); ``grasp`` and ``record`` None when the last warm-up left no time for a grasp, or
    the grasp is not observable within ``WITHIN`` (module docstring). ``clean``: the noise-free log, with the grasp
    when there is one; ``link``: the link that grasps."""

    quiet: object
    grasp: float | None = None
    record: object = None
    clean: Log | None = None
    link: str | None = None

    @property
    def found(self) -> list:
        """The events whose change time is within ``WITHIN`` of the grasp (up to the event's lead after it)."""
        return [e for e in self.record.events if e.time - WITHIN <= self.grasp <= e.time + e.lead + WITHIN]

    @property
    def early(self) -> list:
        """The events before the grasp could show: false alarms."""
        return [e for e in self.record.events if e.time + e.lead + WITHIN < self.grasp]

    @property
    def delay(self) -> float | None:
        """From the grasp to the first event that found it [s]; None: missed."""
        return self.found[0].detected_at - self.grasp if self.found else None


def grasp_run(seed, planar, noisy, differentiated, estimated, fraction, folder, duration, after="end",
              **size) -> GraspRun:  # fmt: skip
    """A random robot's changeless log first: its false alarms, and where the test begins. Then the
    same log with a grasp at a random time (``fraction`` of the time left) after its last warm-up (the first,
    unless a false alarm started another) (``after``: ``"end"``, its end; ``"tested"``, its first tested sample: a grasp in the samples it
    was lengthened by, before they determine the parameters, is found, but not always within
    ``WITHIN``)."""
    return robot_grasp_run(_robot(seed, planar, folder, **size), seed, noisy, differentiated, estimated, fraction,
                           duration, after)  # fmt: skip


def robot_grasp_run(robot: Robot, seed, noisy, differentiated, estimated, fraction, duration,
                    after="end") -> GraspRun:  # fmt: skip
    """:func:`grasp_run` for ``robot`` in its motion, over ``duration`` [s], the noise drawn from ``seed``."""
    t = np.arange(int(duration * RATE)) / RATE
    noise = _noise(noisy, differentiated, estimated)
    still = _simulate(robot, t)
    steady = _measured(still, noisy, differentiated, seed)
    quiet = _monitored(robot, steady, noise)
    # after the last warm-up (a false alarm, allowed once, starts a segment: a grasp in its warm-up cannot show)
    warm_up = quiet.segments[-1].warm_up  # None: the motion never determined the parameters
    start = None if warm_up is None else warm_up["tested_from" if after == "tested" else "end"]
    if start is not None and noise is None:  # levels estimated from the first samples: a grasp among them enters them
        start = max(start, NOISE_SAMPLES / RATE)
    if start is None or start + 0.5 >= duration - 2.0:  # no time for a grasp after it
        return GraspRun(quiet, clean=still)
    grasp = float(np.round((start + 0.5 + fraction * (duration - 2.5 - start)) * RATE) / RATE)
    captured, link = _with_payload(robot.model, robot.rng)
    clean = _simulate(robot, t, grasp, captured)
    log = _measured(clean, noisy, differentiated, seed)
    if noisy:  # the grasp's momentum error in the model before it, against the noise's in the changeless log
        moved = _momentum_error(robot.model, clean.select((clean.t >= grasp) & (clean.t < grasp + WITHIN)),
                                robot.momentum)  # fmt: skip
        spread = np.mean(_momentum_error(robot.model, steady, robot.momentum) ** 2, axis=0)
        if np.sum(moved**2 / spread) < OBSERVABLE:
            return GraspRun(quiet, clean=still)
    return GraspRun(quiet, grasp, _monitored(robot, log, noise), clean, link)


def check_grasp(run: GraspRun):
    """The grasp of ``run`` reported within ``WITHIN``; the changeless log and the time before the
    grasp raise at most one false alarm (at 1e-5 per sample, a few hundred tested samples make 2 a
    1e-5 event). The grasp's log is the changeless one up to the grasp: an alarm both raise is one alarm."""
    alarms = {(e.time, e.detected_at) for e in (*run.quiet.events, *run.early)}
    assert len(alarms) <= 1, (run.quiet.events, run.early, run.grasp)
    assert run.delay is not None and run.delay <= WITHIN, (
        [(e.time, e.detected_at) for e in run.record.events], run.grasp)


def _grasp_found(seed, planar, noisy, differentiated, estimated, fraction, *args, **kwargs):
    case = {"seed": seed, "planar": planar, "motion": "harmonic", "noisy": noisy, "differentiated": differentiated,
            "estimated": estimated, "fraction": fraction}
    with stage("monitor changeless", **case):
        run = grasp_run(seed, planar, noisy, differentiated, estimated, fraction, *args, **kwargs)
        assert len(run.quiet.events) <= 1, run.quiet.events
    assume(run.grasp is not None)
    with stage("monitor", **case):
        check_grasp(run)


CASES = {"seed": SEEDS, "planar": st.booleans(), "noisy": st.booleans(), "differentiated": st.booleans(),
         "estimated": st.booleans(), "fraction": st.floats(0, 1)}


@FAST
@given(**CASES)
def test_a_grasp_is_found_on_a_random_robot(seed, planar, noisy, differentiated, estimated, fraction, tmp_path):
    _grasp_found(seed, planar, noisy, differentiated, estimated, fraction, tmp_path, 12.0, max_arms=2, max_joints=2)


@pytest.mark.soak
@pytest.mark.slow
@SLOW
@given(**CASES)
# issue 26: a 4-joint planar tree, 25 parameters, false alarms from a 4 s warm-up its motion leaves
# undetermined (the regressor noise's errors in variables), noise-free and with 1e-4 noise
@example(seed=0, planar=True, noisy=True, differentiated=False, estimated=False, fraction=0.3)
@example(seed=0, planar=True, noisy=False, differentiated=False, estimated=True, fraction=0.3)
@example(seed=5, planar=True, noisy=True, differentiated=False, estimated=True, fraction=0.6)
@example(seed=4, planar=False, noisy=True, differentiated=False, estimated=False, fraction=0.5)  # 105 parameters
# noise-free with rates differentiated: the filter fitted to residuals far below the noise model
@example(seed=9, planar=True, noisy=False, differentiated=True, estimated=False, fraction=0.5)
@example(seed=0, planar=False, noisy=False, differentiated=True, estimated=False, fraction=0.0)
# the differentiator's noise in the regressor: its smoothed levels, not the given rate level
@example(seed=9, planar=True, noisy=True, differentiated=True, estimated=False, fraction=0.5)
# a grasp among the samples the levels are estimated from (no longer drawn): missed
@example(seed=13859, planar=False, noisy=True, differentiated=False, estimated=True, fraction=0.16)
def test_a_grasp_is_found_on_larger_random_robots(seed, planar, noisy, differentiated, estimated, fraction, tmp_path):
    _grasp_found(seed, planar, noisy, differentiated, estimated, fraction, tmp_path, 20.0, max_arms=2, max_joints=3)


@pytest.mark.slow
@pytest.mark.parametrize("planar, seed", [(True, 5), (False, 4)])
def test_grasps_on_rates_differentiated_over_a_given_window(planar, seed, tmp_path):
    """Two grasps of ``benchmarks/bench_monitor.py --parts g`` (noisy, rates differentiated over 11
    samples): with the order chosen for an estimate over the record (quintics on a joint) they were
    seen 1.8 s (planar, 7 s after the warm-up) and 3.1 s (spatial, inside the warm-up's extension)
    late; with it chosen for the rates' own error, within 0.1 s."""
    run = grasp_run(seed, planar, True, True, False, (seed * 0.37) % 1, tmp_path, 20.0, after="tested", max_arms=2,
                    max_joints=3)  # fmt: skip
    check_grasp(run)


def changeless_alarms(seed, logs, folder, duration, rate=1e-3, **size) -> tuple:
    """The alarms and tested samples of ``logs`` changeless logs of random robots (planar and
    spatial in turn, noisy, the rates measured or differentiated, the levels given or estimated)
    at ``rate`` false alarms per sample."""
    rng = np.random.default_rng(seed)
    alarms = tested = 0
    t = np.arange(int(duration * RATE)) / RATE
    for k in range(logs):
        robot_seed = int(rng.integers(2**31))
        robot = _robot(robot_seed, k % 2 == 0, folder, **size)
        differentiated, estimated = bool(rng.integers(2)), bool(rng.integers(2))
        with stage("monitor false-alarm rate", seed=robot_seed, planar=k % 2 == 0, motion="harmonic", noisy=True,
                   differentiated=differentiated, estimated=estimated):  # fmt: skip
            log = _measured(_simulate(robot, t), True, differentiated, int(rng.integers(2**31)))
            record = _monitored(robot, log, _noise(True, differentiated, estimated), false_alarm_rate=rate)
        alarms, tested = alarms + len(record.events), tested + record.n_tested
    return alarms, tested


def _as_stated(alarms: int, tested: int, rate: float = 1e-3):
    """``alarms`` in ``tested`` samples no more than a ``P_FALSE`` event at ``rate`` per sample (binomial)."""
    assert binom.sf(alarms - 1, tested, rate) >= P_FALSE, (alarms, rate * tested)


@FAST
@given(seed=SEEDS)
def test_false_alarms_on_random_robots_as_stated(seed, tmp_path):
    _as_stated(*changeless_alarms(seed, 1, tmp_path, 12.0, max_arms=2, max_joints=2))


@pytest.mark.soak
@pytest.mark.slow
def test_false_alarms_on_larger_random_robots_as_stated(tmp_path):
    """24 changeless 20 s logs of random trees of up to 2 arms of 3 joints at 1e-3 false alarms per
    sample (binomial); and seed 13, two planar trees that raised false alarms when 4 s warm-ups left
    their parameters undetermined."""
    _as_stated(*changeless_alarms(2026, 24, tmp_path, 20.0, max_arms=2, max_joints=3))
    _as_stated(*changeless_alarms(13, 2, tmp_path, 12.0, max_arms=2, max_joints=3))


@pytest.mark.slow
def test_a_noise_free_spatial_log_up_to_a_grasp_is_smooth(tmp_path):
    """Noise-free, rates differentiated, levels 1e-7: false alarms at 5.16, 8.64 and 10.38 s in the
    log with the grasp (at 13.92 s) that the changeless log, the same before the grasp, did not
    raise. The log before the grasp, simulated up to 13.92 s, had single-sample attitude jumps of
    up to 4e-8 rad at 5.22, 8.7 and 10.44 s (spline nodes a rounding error apart), 1e-6 rad/s in
    the rates differentiated from it: changes of the data the monitor was right to report."""
    _grasp_found(18800167, False, False, True, True, 0.6948161718260787, tmp_path, 20.0, after="tested", max_arms=2,
                 max_joints=3)


@pytest.mark.slow  # fast representative: test_a_grasp_is_found_on_a_random_robot
@pytest.mark.parametrize("noisy", [False, True])
def test_the_grasp_of_issue_26(noisy, tmp_path):
    """Issue 26: a 4-joint planar tree in a slow motion (three harmonics of 0.1 to 0.5 Hz) grasps
    0.9 kg at 9.3 s of a 20 s log at 50 Hz, the rates measured, monitored as ``spaceid monitor
    ROBOT LOG --planar --momentum 0.3`` does (the noise levels estimated from the first 500
    samples: its first warm-up, which holds the grasp). Before, it was reported at 10.38 s
    (detected at 10.50 s) with a change that did not happen at 14.38 s, noise-free, and at 10.40,
    14.40 and 18.42 s with 1e-4 noise: the first warm-up was not tested, and the 4 s warm-ups
    after it left the 25 parameters undetermined. Now exactly once, at the grasp."""
    model = random_robot(0, planar=True, max_arms=2, max_joints=3).load(tmp_path)
    assert model.n_joints == 4
    rng = np.random.default_rng(0)
    freq, phase = rng.uniform(0.1, 0.5, (3, 4)), rng.uniform(0, 2 * np.pi, (3, 4))
    amp = rng.uniform(0.1, 0.4, (3, 4))

    def motion(t):
        arg = 2 * np.pi * freq[None] * np.asarray(t)[:, None, None] + phase[None]
        return (amp * np.sin(arg)).sum(1), (amp * 2 * np.pi * freq * np.cos(arg)).sum(1)

    robot = Robot(model, minimal_parameters(model), np.array([0.0, 0.0, 0.3]), motion, rng)
    t = np.arange(1000) / RATE
    log = _measured(_simulate(robot, t, 9.3, _with_payload(model, rng)[0]), noisy, False, 0)
    (event,) = _monitored(robot, log, None).events
    assert abs(event.time - 9.3) <= WITHIN and event.detected_at - 9.3 <= WITHIN, event


@pytest.mark.slow
def test_a_noise_free_log_with_differentiated_rates_keeps_the_filter_definite(tmp_path):
    """A noise-free planar tree of 33 parameters (three prismatic joints), its rates differentiated
    over 11 samples, grasping at 12.5 s: the warm-up after the alarm has a factor of scaled
    condition about 1e8, whose prior for the differentiator's whitening came out indefinite by
    rounding (-4e3 beside 1e10); the filter's innovation variances then turned negative and the
    monitor stopped with a linear-algebra error. Its negative directions are zero now."""
    robot = _robot(7, True, tmp_path, max_arms=2, max_joints=3)
    t = np.arange(1000) / RATE
    log = _measured(_simulate(robot, t, 12.5, _with_payload(robot.model, robot.rng)[0]), False, True, 7)
    (event,) = _monitored(robot, log, _noise(False, True, False)).events
    assert event.time <= 12.5 <= event.time + event.lead + 2 / RATE and event.detected_at - 12.5 <= WITHIN


@pytest.mark.slow
def test_the_warm_up_screen_decides_as_the_monitors_estimate(tmp_path, monkeypatch):
    """The monitor's screen (a lengthened warm-up far from determined at its weighted
    least-squares estimate waits for more samples without the maximum-likelihood fit) decides as
    the fits alone: on a random planar tree (seed 4, noisy, rates differentiated) whose first
    warm-up is lengthened to 750 samples, the record is the same with and without it, and it
    spared fits. (At the bound itself, ``SCREEN_MARGIN`` 1, the screen's figures had lengthened it
    to 800 when the 11-sample windows took quintics on a joint; with their order chosen for the
    rates' own error it decides as the fits at margin 1 too, on this tree and seeds 0 to 7.)"""
    from spaceid.estimation import _monitor

    robot = _robot(4, True, tmp_path, max_arms=2, max_joints=3)
    log = _measured(_simulate(robot, np.arange(int(20.0 * RATE)) / RATE), True, True, 4)
    fits, identify = [], _monitor.Monitor._identify

    def counted(self, rows, label, history):
        fits.append(self.estimator)
        return identify(self, rows, label, history)

    monkeypatch.setattr(_monitor.Monitor, "_identify", counted)
    screened = _monitored(robot, log, _noise(True, True, False))
    with_screen, fits[:] = list(fits), []
    monkeypatch.setattr(_monitor.Monitor, "_screen", lambda self, rows, label: None)
    alone = _monitored(robot, log, _noise(True, True, False))
    assert screened.segments[0].warm_up["n_samples"] == 750
    assert screened.to_dict() == alone.to_dict()
    assert with_screen.count("ml") < fits.count("ml"), (with_screen, fits)


LIVE_Z = 4.5
"""Most standard errors a payload the live engine publishes may lie from ``MASS`` (a 7e-6 two-sided tail)."""


def live_monitoring(robot: Robot, run: GraspRun, noisy: bool, differentiated: bool, batch: int, seed: int,
                    folder, gyro: bool = False) -> tuple:
    """``run``'s log with its grasp as a bag of joint states (angles and rates) and base poses (without a base rate:
    the reader differentiates the attitude; with a ``gyro``, Odometry whose twist is the log's base rate, which the
    reader takes), 1e-4 rad and rad/s of noise or none, the joint rates measured or
    ``differentiated`` by the reader over ``WINDOW`` samples (the levels given are 1e-4 whether the noise was added
    or not: the live engine's cubic differentiators, :data:`~spaceid.ros.LIVE_ORDER`, leave truncation errors of up
    to 6e-5 rad/s on a noise-free log of these motions, 3e-3 in its first and last half window, which
    :func:`_noise`'s 1e-7 would call changes); its messages fed to
    :class:`~spaceid.ros.LiveMonitor` ``batch`` at a time, each arriving at its own stamp (no processing time),
    the payload on ``run.link`` asked for after each batch. Returns ``(outputs, record, expected, span, live)``:
    what it published, its record, the record of the bag read in parts (:func:`~spaceid.data.bag_chunks`, the same
    block, context and differentiators) and monitored, the longest span of stamps in a batch [s], and the engine."""
    from test_ros import _bag_messages, _stamp_s

    from spaceid.data import bag_chunks, write_bag
    from spaceid.ros import LIVE_BLOCK, LIVE_CONTEXT, LIVE_ORDER, LiveMonitor, recording_of_log

    robot_log = add_noise(run.clean, angle=LEVEL, rate=LEVEL, seed=seed) if noisy else run.clean
    bag = folder / "live.mcap"
    write_bag(bag, recording_of_log(robot_log, gyro=gyro), format="mcap")
    noise = Noise(angle=LEVEL, rate=LEVEL, base_rate=LEVEL, attitude=LEVEL)  # the sensors' rating, noise or none
    reading = {"window": WINDOW, "joint_rates": "differentiate" if differentiated else "velocity",
               "base_rate": "gyro" if gyro else "attitude"}
    model, param = robot.model, robot.param
    now, outputs, span = [0.0], [], 0.0
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        live = LiveMonitor(param, robot.momentum, link=run.link, reading=reading, noise=noise, clock=lambda: now[0])
        messages = [(topic, msg, _stamp_s(msg)) for topic, msg in _bag_messages(bag)]
        for k in range(0, len(messages), batch):
            part = messages[k : k + batch]
            now[0], span = part[-1][2], max(span, part[-1][2] - part[0][2])
            outputs += live.add_batch(part)
            outputs += [p for p in [live.payload()] if p is not None]
        rest, record = live.finish()
        chunks = bag_chunks(bag, joints=model.joints, planar=model.planar, wheels=model.wheels, block=LIVE_BLOCK,
                            context=LIVE_CONTEXT, window=WINDOW, order=LIVE_ORDER,
                            joint_rates=reading["joint_rates"], base_rate=reading["base_rate"])  # fmt: skip
        expected = monitor(param, chunks, robot.momentum, noise=noise)
    return outputs + rest, record, expected, span, live


def check_live(robot: Robot, run: GraspRun, noisy: bool, differentiated: bool, batch: int, seed: int, folder,
               gyro: bool = False):
    """The live engine on ``run``'s log (:func:`live_monitoring`) is the bag reader and the monitor: the same
    alarms at the same samples, statistics to round-off, as many samples tested. Each alarm is published once, as
    its part raises it (stage "detected", at most a block, two joint messages and a batch of data after the message
    that completed its sample, or its warm-up's last sample when its segment's warm-up was lengthened past it),
    before its event (stage "compared"). After an alarm that found the grasp (:attr:`GraspRun.found`; its rates
    differentiated, up to half a window before it), every payload published is fitted from samples after the grasp,
    the first from at least a quarter warm-up of them, each mass within ``LIVE_Z`` of its standard errors of
    ``MASS``; and one is published once a warm-up of samples after it came (the log's tail, which the reader may
    leave unaligned, aside)."""
    from spaceid.ros import LIVE_BLOCK

    outputs, record, expected, span, live = live_monitoring(robot, run, noisy, differentiated, batch, seed, folder,
                                                            gyro)
    if gyro:  # the gyro's rate, not the attitude's derivative: measured, as the monitor then models it
        assert live.aligner.base_rate == "gyro" and live._recent
        assert all(p.meta["base_rate"] == "gyro" and "base" not in p.meta["differentiation"] for p in live._recent)
    assert [(e.time, e.detected_at) for e in record.events] == [(e.time, e.detected_at) for e in expected.events]
    assert np.allclose([e.statistic for e in record.events], [e.statistic for e in expected.events], rtol=1e-8)
    assert record.n_tested == expected.n_tested
    events = [o.data for o in outputs if o.kind == "event"]
    detected = [e for e in events if e["stage"] == "detected"]
    compared = [e for e in events if e["stage"] == "compared"]
    assert [e["time"] for e in detected] == [e["time"] for e in compared] == [e.time for e in record.events]
    assert all(events.index(a) < events.index(c) for a, c in zip(detected, compared))
    # an alarm among the samples a warm-up was lengthened by is raised once the warm-up determines the parameters
    warm_up_end = {s.end: s.warm_up["end"] for s in record.segments if s.warm_up is not None}
    for a in detected:
        waited = max(0.0, warm_up_end.get(a["time"], 0.0) - a["detected_at"])
        # two joint messages past the block, where the Cepheus twin's bag needs one (tests/test_ros.py): planar robot
        # 891341114, one message at a time, published 0.14 s after the joint state that settled its sample (open)
        assert 0 <= a["latency_s"] <= waited + LIVE_BLOCK + 2 / RATE + span + 1e-6, (a, waited, span)
    if run.grasp is None:
        return
    for event in dataclasses.replace(run, record=record).found:
        payloads = [o.data for o in outputs if o.kind == "payload" and o.data["event"] == event.index]
        masses = [p for p in payloads if "mass" in p]
        assert all(p["time"] >= run.grasp - 1e-9 for p in payloads), (run.grasp, payloads)
        assert not masses or masses[0]["n_samples"] >= live.monitor.warmup // 4
        assert all(abs(p["mass"] - MASS) <= LIVE_Z * p["std"]["mass"] for p in masses), masses
        after = np.sum(run.clean.t > event.detected_at + event.lead)
        assert payloads or after < live.monitor.warmup + WINDOW, (after, live.monitor.warmup)


@pytest.mark.slow  # a random robot's grasp run, then its bag fed to the live engine and read by the bag reader
@robots(6, phases=PHASES)
@given(**CASES, batch=st.integers(1, 60), gyro=st.booleans())
# an alarm published two joint messages past the block (the latency's bound in check_live)
@example(seed=891341114, planar=True, noisy=True, differentiated=False, estimated=False, fraction=0.0, batch=1,
         gyro=False)
def test_the_live_engine_on_a_random_robot(seed, planar, noisy, differentiated, estimated, fraction, batch, gyro,
                                           tmp_path):
    """The live node's engine (:class:`~spaceid.ros.LiveMonitor`, without ROS) on random robots grasping a payload,
    the base rate differentiated from the attitude or a ``gyro``'s (the pose topic's Odometry): :func:`check_live`
    (the Cepheus twin's bag: ``tests/test_ros.py``). ``estimated`` only places the grasp (the changeless log's
    monitoring, :func:`grasp_run`): the live engine is given the noise levels."""
    case = {"seed": seed, "planar": planar, "motion": "harmonic", "noisy": noisy, "differentiated": differentiated,
            "batch": batch, "gyro": gyro}
    robot = _robot(seed, planar, tmp_path, max_arms=2, max_joints=2)
    run = robot_grasp_run(robot, seed, noisy, differentiated, estimated, fraction, 12.0)
    with stage("live monitor", **case):
        check_live(robot, run, noisy, differentiated, batch, seed, tmp_path, gyro)
