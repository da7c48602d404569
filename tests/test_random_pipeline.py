"""The pipeline on robots nobody on the project designed (``random_robots``): design with a short
step budget (the same design on any machine), simulate (momentum conserved by the rigid-body
definitions, independently of the parameters), identify noise-free (recovery to round-off times the conditioning) and noisy
(errors against the standard errors), export the noisy estimate from a prior 20 % / 1 cm off, predict, a random
payload on a random link, the monitor finding a grasp of one, and a Monte Carlo study of the robot's motion."""

import dataclasses
import tempfile
import warnings
from io import BytesIO
from pathlib import Path

import numpy as np
import pytest
from scipy.stats import chi2
from hypothesis import example, given
from hypothesis import strategies as st
from conftest import random_inertia
from random_robots import perturbed_prior, random_robot
from robot_tally import robots, stage
from test_monitor_random_robots import Robot, check_grasp, robot_grasp_run
from test_random_robots import check_noisy_export

from spaceid import SpaceidError
from spaceid.dynamics import minimal_parameters
from spaceid.estimation import Noise, identify
from spaceid.identified import identify_payload
from spaceid.models import inertial_vector
from spaceid.motion import FourierTrajectory, add_noise, design_excitation, sample_times, simulate
from spaceid.studies import predict, run_montecarlo

SEEDS = st.integers(0, 2**31 - 1)
NOISE = 1e-4  # [rad, rad/s] on every signal of the noisy logs
FAST = robots(1)
SLOW = robots(8)


@dataclasses.dataclass(frozen=True)
class Flown:
    """A random robot (``case``: how it was drawn), a motion designed for it, its noise-free log."""

    case: dict
    model: object
    param: object
    momentum: np.ndarray
    trajectory: object
    log: object


DESIGN_STEPS = 60
"""Linearisations a local search of the test's design makes: a budget that gives the same design on any
machine (a wall-clock budget of 2 s gave seed 110 a max |z| of 2.1, cut to 0.2 s by a loaded machine 22)."""


def _design(param, h, samples, seed):
    """The test's design: one start, at most :data:`DESIGN_STEPS` linearisations, no wall-clock budget."""
    return design_excitation(param, duration=10.0, harmonics=3, samples=samples, momentum=h, seed=seed % 2**32,
                             n_starts=1, max_steps=DESIGN_STEPS, jobs=1, q_max=1.0, qd_max=1.0, qdd_max=1.0)


@pytest.mark.slow  # fast representative: test_design.py::test_step_budget_gives_the_same_design_on_any_machine
def test_the_design_is_the_same_on_any_machine(tmp_path):
    """Seed 110 (66 parameters, the trust region) twice: the bit-identical design, its budget recorded."""
    model = random_robot(110, planar=False, max_arms=2, max_joints=2).load(tmp_path)
    param, h = minimal_parameters(model), np.array([0.3, -0.2, 0.1])
    first, again = (_design(param, h, 66, 110).trajectory for _ in range(2))
    assert np.array_equal(first.a, again.a) and np.array_equal(first.b, again.b)
    assert first.meta["max_steps"] == DESIGN_STEPS and first.meta["time_budget"] is None


def _flown(seed, planar, tmp_path) -> Flown:
    """A random robot, a motion designed for it in a short step budget, and its noise-free log."""
    case = {"seed": seed, "planar": planar, "motion": "designed"}
    with stage("design+simulate", **case):
        model = random_robot(seed, planar=planar, max_arms=2, max_joints=2).load(tmp_path)
        param = minimal_parameters(model)
        h = np.array([0.0, 0.0, 0.3]) if planar else np.array([0.3, -0.2, 0.1])
        samples = max(60, 3 * param.n_params // param.rows)
        design = _design(param, h, samples, seed)
        log = simulate(param, param.true_values, design.trajectory, sample_times(10.0, 4 * samples), h, model=model)
        assert log.meta["momentum_rel_error"] < 1e-9  # the simulation conserves the rigid-body momentum
    return Flown(case, model, param, h, design.trajectory, log)


def _undesigned(seed, planar, tmp_path) -> Flown:
    """A random robot on a random motion nobody designed (Fourier, rest to rest, 0.05 to 0.5 rad/s per
    harmonic): directions may go undetermined, and the standard errors must say so."""
    case = {"seed": seed, "planar": planar, "motion": "undesigned"}
    with stage("simulate", **case):
        model = random_robot(seed, planar=planar, max_arms=2, max_joints=2).load(tmp_path)
        param = minimal_parameters(model)
        h = np.array([0.0, 0.0, 0.3]) if planar else np.array([0.3, -0.2, 0.1])
        rng = np.random.default_rng(seed)
        a, b = 10 ** rng.uniform(-1.3, -0.3) * rng.standard_normal((2, model.n_joints, 3))
        trajectory = FourierTrajectory(model.joints, 10.0, a, b, meta={"source": f"random:{seed}"})
        samples = max(60, 3 * param.n_params // param.rows)
        log = simulate(param, param.true_values, trajectory, sample_times(10.0, 4 * samples), h, model=model)
        assert log.meta["momentum_rel_error"] < 1e-9
    return Flown(case, model, param, h, trajectory, log)


def flown_at_rest(seed, planar, folder) -> tuple:
    """``(Flown, anchor)``: a random robot released at rest (zero momentum) on a motion nobody designed, as
    :func:`_undesigned`'s, its scale anchored by one parameter of over 5 % of the largest's size, drawn at random."""
    case = {"seed": seed, "planar": planar, "motion": "undesigned", "momentum": "zero"}
    model = random_robot(seed, planar=planar, max_arms=2, max_joints=2).load(folder)
    param, rng, h = minimal_parameters(model), np.random.default_rng(seed), np.zeros(3)
    a, b = 10 ** rng.uniform(-1.3, -0.3) * rng.standard_normal((2, model.n_joints, 3))
    trajectory = FourierTrajectory(model.joints, 10.0, a, b, meta={"source": f"random:{seed}"})
    log = simulate(param, param.true_values, trajectory, sample_times(10.0, 4 * max(60, 3 * param.n_params //
                                                                                     param.rows)), h, model=model)
    true = param.true_values
    j = int(rng.choice(np.flatnonzero(np.abs(true) > 0.05 * np.abs(true).max())))
    return Flown(case, model, param, h, trajectory, log), {param.names[j]: float(true[j])}


def _check_noisy_export(flown: Flown, measured, noisy, noise) -> str:
    """The export of the noisy identification ``noisy`` (of the log ``measured``, the levels ``noise``) from a prior
    20 % / 1 cm off (:func:`check_noisy_export`): ``"exported"``; or ``"refused"`` when its covariance, widened along
    directions the data do not determine, leaves determined combinations below its round-off (checked here: its
    correlations' eigenvalues over 1e12 apart) that no physical model meets, and then the identification given that
    prior exports."""
    prior = perturbed_prior(flown.model, flown.case["seed"] + 1)
    with tempfile.TemporaryDirectory() as folder:
        try:
            check_noisy_export(noisy, flown.model, prior, Path(folder))
            return "exported"
        except SpaceidError as refusal:
            if "below its round-off" not in str(refusal):
                raise
        std = np.sqrt(np.diag(noisy.cov))
        spread = np.linalg.eigvalsh(noisy.cov / np.outer(std, std))
        assert noisy.diagnostics.undetermined and spread.min() <= 1e-12 * spread.max(), str(refusal)
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            given = identify(flown.param, measured, flown.momentum, noise=noise, prior=prior)
        check_noisy_export(given, flown.model, prior, Path(folder))
    return "refused"


def _check_pipeline(flown: Flown):
    param, h, traj, log, seed = flown.param, flown.momentum, flown.trajectory, flown.log, flown.case["seed"]
    true = param.true_values
    with stage("identify noise-free", **flown.case):
        exact = identify(param, log, h, estimator="ols")
        assert np.abs(exact.values - true).max() <= 1e-10 * exact.condition_number * np.abs(true).max()

    with stage("identify noisy", **flown.case):
        noise = Noise(angle=NOISE, rate=NOISE, base_rate=NOISE, attitude=NOISE)
        measured = add_noise(log, angle=NOISE, rate=NOISE, seed=seed)
        noisy = identify(param, measured, h, noise=noise)
        free = noisy.std > 0
        z = np.abs(noisy.values - true)[free] / noisy.std[free]
        # on any motion, also a design cut short (seed 110 with a 0.2 s wall-clock budget: 6 directions undetermined,
        # 39 of 66 parameters beyond 5 first-order standard errors, max 22; widened along those directions, max 1.5;
        # the step budget now gives every machine the same design)
        assert z.max() < 5, f"max |z| {z.max():.3g} over {free.sum()} parameters"

    with stage("export noisy", **flown.case):
        _check_noisy_export(flown, measured, noisy, noise)

    with stage("predict", **flown.case):
        held_out = sample_times(traj.duration, 200)
        q, qd, _ = traj.evaluate(held_out)
        again = simulate(param, true, traj, held_out, h)
        predicted = predict(exact, held_out, q, qd, momentum=h)
        assert np.abs(predicted.base_w - again.base_w).max() <= 1e-6 * np.abs(again.base_w).max()


def _captured(flown: Flown) -> tuple:
    """``(log, link, mass)``: the noise-free log of ``flown``'s motion with a payload of 2 to 20 % of the robot's
    mass, 5 to 30 cm across, on a random link (of ``mass`` [kg])."""
    model, h, traj, seed, planar = flown.model, flown.momentum, flown.trajectory, flown.case["seed"], flown.model.planar
    rng = np.random.default_rng(seed)
    link = model.bodies[rng.integers(1, len(model.bodies))].name
    mass = model.mass * rng.uniform(0.02, 0.2)
    com = rng.uniform(-0.2, 0.2, 3) * (np.r_[1.0, 1.0, 0.0] if planar else 1.0)
    payload = inertial_vector(mass, com, mass * rng.uniform(0.05, 0.3) ** 2 * random_inertia(rng))
    held = dataclasses.replace(model, bodies=tuple(dataclasses.replace(b, inertial=b.inertial + payload)
                                                   if b.name == link else b for b in model.bodies))
    captured = minimal_parameters(held)
    return simulate(captured, captured.true_values, traj, sample_times(traj.duration, 400), h, model=held), link, mass


def _noisy_payload(flown: Flown, log, link):
    """The payload on ``link`` identified from ``log`` with 1e-4 noise (the servicer known)."""
    return identify_payload(flown.model, add_noise(log, angle=NOISE, rate=NOISE, seed=flown.case["seed"]), link,
                            flown.momentum, noise=Noise(angle=NOISE, rate=NOISE, base_rate=NOISE, attitude=NOISE))


def _check_payload(flown: Flown):
    """The payload of :func:`_captured`, identified from the noise-free log after the capture (the servicer known)
    to round-off, and from a noisy one within 5 sigma."""
    log, link, mass = _captured(flown)
    with stage("payload noise-free", **flown.case):
        exact = identify_payload(flown.model, log, link, flown.momentum, noise=Noise())
        assert abs(exact.values[0] - mass) <= 1e-6 * mass
    with stage("payload noisy", **flown.case):
        noisy = _noisy_payload(flown, log, link)
        assert abs(noisy.values[0] - mass) < 5 * noisy.std[0]


@pytest.mark.slow  # two random robots' ML, twice each (seconds)
@pytest.mark.parametrize("seed, flight, planar, taken", [(2, _flown, True, ["accepted"] * 2),
                                                         (36, _undesigned, False, ["refused"] * 3)])
def test_ml_preconditioned_in_single_precision_on_random_robots(seed, flight, planar, taken, monkeypatch, tmp_path):
    """ML's preconditioners in single precision (``SINGLE_COLUMNS`` patched to one: random robots have fewer
    unknowns than it) on a designed planar robot, whose equations allow it (both preconditioners in single), and an
    undesigned spatial one, whose three fits (one direction held, and the fit at the model's own values) refuse it on
    their conditioning and form their preconditioners in double: the same fixed point (measured: 2.4e-10 standard
    errors, and bit for bit when refused) and standard errors to 1e-6."""
    from spaceid.estimation import _estimators as estimate

    flown = flight(seed, planar, tmp_path)
    noise = Noise(angle=NOISE, rate=NOISE, base_rate=NOISE, attitude=NOISE)
    measured = add_noise(flown.log, angle=NOISE, rate=NOISE, seed=seed)
    double = identify(flown.param, measured, flown.momentum, noise=noise)
    formed, factor = [], estimate._gram_matrix_factor

    def spied(G, refine=None, limit=None):
        out = factor(G, refine, limit)
        if limit is not None:
            formed.append("refused" if out is None else "accepted")
        return out

    monkeypatch.setattr(estimate, "_gram_matrix_factor", spied)
    monkeypatch.setattr(estimate, "SINGLE_COLUMNS", 1)
    single = identify(flown.param, measured, flown.momentum, noise=noise)
    assert formed == taken
    assert (np.abs(single.values - double.values) / double.std).max() < 1e-5
    np.testing.assert_allclose(single.std, double.std, rtol=1e-6)


@pytest.mark.slow  # a random robot's flight and a payload fit (seconds)
@pytest.mark.parametrize("seed", [98697, 131073])
def test_the_payload_fit_minimises_its_cost_on_an_undesigned_motion(seed, tmp_path):
    """Undesigned spatial robots with a payload on a random link (robot 98697: one joint, 1.75 kg; robot 131073: three
    joints, 3.5 kg), 1e-4 noise. On 98697 the payload fit's first Gauss-Newton step raised its cost, and the fit
    stopped there and reported it (chi-squared per degree of freedom 161, the mass projected to 121 kg with a standard
    error of 0.47). With that step halved, the steps at frozen weights went on to chi-squared 3.3 and stopped where
    the cost at the truth was lower: the mass 8.9 +- 1.5 kg, 4.8 standard errors off. With the weights' derivative in
    the steps from there, the fit reaches the cost's minimum: chi-squared 0.97 in 33 steps, the mass 3.8 +- 3.0 kg,
    0.69 standard errors off. Taken from the first step instead, that derivative threw robot 131073's fit off to
    -2,183 kg (chi-squared 3,000); from the frozen weights' fixed point, 3.9 +- 0.4 kg (1.1 off), chi-squared 0.99.
    Robot 98697's motion leaves two directions of the payload's inertia undetermined (noise-to-signal ratios 0.89 and
    0.73), which the fit says, widening its covariance along them; 131073's none."""
    flown = _undesigned(seed, False, tmp_path)
    log, link, mass = _captured(flown)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # (the projection's solver: "may be inaccurate")
        noisy = _noisy_payload(flown, log, link)
    assert noisy.settings["gauss_newton_steps"] > 2 and noisy.settings["chi2_dof"] < 1.2
    assert abs(noisy.values[0] - mass) < 2 * noisy.std[0]
    # robot 98697's motion leaves two directions of its payload's inertia undetermined (ratios 0.89 and 0.73): said
    assert [len(d["parameters"]) for d in noisy.settings["undetermined"]] == ([3, 3] if seed == 98697 else [])


def _monitored_grasp(flown: Flown):
    """:func:`_check_monitor`'s run of ``flown`` and whether its rates were differentiated."""
    model, param, h, traj, seed = flown.model, flown.param, flown.momentum, flown.trajectory, flown.case["seed"]
    rng = np.random.default_rng(seed)

    def twice(t):
        q, qd, _ = traj.evaluate(np.mod(t, traj.duration))
        return q, qd

    differentiated = bool(rng.integers(2))
    return robot_grasp_run(Robot(model, param, h, twice, rng), seed, True, differentiated, False, rng.uniform(),
                           2 * traj.duration), differentiated


def _check_monitor(flown: Flown):
    """The monitor on the designed motion played twice (rest to rest: smooth), 20 s: a 0.9 kg
    payload grasped on a random link at a random time after the first tested sample, 1e-4 rad and
    rad/s of noise, the rates measured or differentiated (``test_monitor_random_robots``): reported
    within 0.25 s, no more than one false alarm on the changeless log and before the grasp."""
    run, differentiated = _monitored_grasp(flown)
    if run.grasp is not None:  # None: too weak a grasp to show within 0.25 s, or the last warm-up left no time
        with stage("monitor", **flown.case, noisy=True, differentiated=differentiated):
            check_grasp(run)  # (a 66-parameter spatial tree, rates differentiated, was not determined in 20 s)


@pytest.mark.slow  # a random robot's flight and three monitored logs (seconds)
def test_one_grasp_is_one_event_when_its_time_is_estimated_early(tmp_path):
    """Undesigned planar robot 362, its rates differentiated: the grasp at 13.76 s raised an alarm at 13.68 s (its
    rates hold the angles up to half a window later) whose change time was estimated at 13.30 s, earlier than the
    lead (0.1 s) allows. The next segment started a window after that time, took samples from before the grasp into
    its warm-up, and the grasp raised a second alarm at 14.06 s. Started a window after the alarm's own sample, the
    segment holds the new parameters alone: one event. (The estimated time itself stays 0.01 s outside what the
    property test accepts, open: ``_check_monitor`` counts the event as a false alarm. The innovations were up from
    13.30 s, 13 samples before the grasp could show, by chance (the quiet log holds the same samples): the statistic
    had climbed to 6 of its threshold of 9.3 when the grasp came, and the estimate, the start of the likeliest
    inflated tail, is that climb's start.)"""
    run, differentiated = _monitored_grasp(_undesigned(362, True, tmp_path))
    assert differentiated and run.grasp == 13.76 and run.quiet.events == ()
    [event] = run.record.events
    assert event.detected_at < run.grasp <= event.detected_at + event.lead and event.time < run.grasp - event.lead


RUNS = 8
"""Noise draws of the property tests' Monte Carlo studies."""


def _check_montecarlo(flown: Flown):
    """A Monte Carlo study of the robot's motion (``RUNS`` draws of 1e-4 on every signal, ML and OLS, the log's sample
    times). Its runs are the first of a longer study of the same seed (run i's noise depends on the seed and i only,
    bit for bit). ML's errors are within 5 of the standard errors it predicted in every run, designed motion or not
    (until the twenty-eighth round the first only on an undesigned one: undesigned spatial robot 36's run 1 was 5.72
    of them off, :func:`test_every_run_of_a_held_fit_within_its_standard_errors`; over 200 undesigned robots, 8 runs
    each, the largest is now 3.83). Unless a run said that the data leave a direction undetermined (then ML's
    estimate is pulled towards zero there, 4 times the CRB on undesigned planar robot 0), ML's RMSE of every
    parameter is within the band that ``RUNS`` draws allow around the Cramer-Rao bound (chi-square, Bonferroni, 1e-5
    in all: a property run draws some 200 robots, and at 1e-3 a robot one run in five failed by chance; seed 3203's
    designed planar robot 1656091195 had 2.19 times the bound in its first 8 runs, above 2.09, and 0.85 to 1.14 over
    60, ML's standard errors the same), nor where a run's ML fell back to WLS (designed spatial robot 9152, seed 3602:
    runs 5 and 7 reported WLS, biased by up to 3.4 of its standard errors, which it widens, and the RMSE of one
    parameter came to 2.64 times the bound over 8 runs, above 2.48; 1.50 over 60, within 1.51). Both figures draw, the PNG's (its ranked efficiency beyond 40 parameters) and
    the page's (valid for Plotly)."""
    import plotly.graph_objects as go

    from spaceid.studies._html_figures import montecarlo_figures

    noise = Noise(angle=NOISE, rate=NOISE, base_rate=NOISE, attitude=NOISE)
    options = dict(momentum=flown.momentum, noise=noise, times=flown.log.t, estimators=("ml", "ols"),
                   seed=flown.case["seed"], jobs=1)  # fmt: skip
    with stage("montecarlo", **flown.case), warnings.catch_warnings():
        warnings.simplefilter("ignore")
        study = run_montecarlo(flown.param, flown.trajectory, runs=RUNS, **options)
        shorter = run_montecarlo(flown.param, flown.trajectory, runs=2, **options)
        assert study.failures == () and study.settings["seed"] == flown.case["seed"]
        for e in study.estimators:
            np.testing.assert_array_equal(shorter.estimates[e], study.estimates[e][:2])
        z = np.abs(study.estimates["ml"] - study.true) / study.predicted_std["ml"]
        assert z.max() < 5, f"max |z| {z.max():.3g} in run {np.argmax(z.max(1))}"
        # the bound is an efficient estimator's: not where ML said the data leave a direction undetermined, nor where
        # it fell back to WLS, whose errors-in-variables bias its standard errors are widened by (z above)
        ml_warned = [w["warning"] for w in study.warnings if w["estimator"] == "ml"]
        if not any("not determined" in w or "maximum likelihood failed" in w for w in ml_warned):
            k = len(study.names)
            low, high = np.sqrt(chi2.ppf([0.25e-5 / k, 1 - 0.25e-5 / k], RUNS) / RUNS)
            ratio = study.stats["ml"]["rmse_crb"]
            assert low < ratio.min() and ratio.max() < high, (low, ratio.min(), ratio.max(), high)
    with stage("montecarlo figures", **flown.case):
        study.plot().savefig(BytesIO(), format="png", dpi=40)
        for figure, _ in montecarlo_figures(study):
            go.Figure(figure)  # raises on a property Plotly does not know


@FAST
@given(seed=SEEDS, planar=st.booleans())
def test_montecarlo_on_random_robots_and_undesigned_motions(seed, planar, tmp_path):
    """(Designed motions: the slow tests of more random robots below.)"""
    _check_montecarlo(_undesigned(seed, planar, tmp_path))


@pytest.mark.slow  # fast representative: test_montecarlo_on_random_robots_and_undesigned_motions
def test_every_run_on_an_undesigned_motion_within_its_standard_errors(tmp_path):
    """Undesigned planar robot 338: ML's errors within 5 of its standard errors in every one of 8 draws. Before ML's
    spread was scaled by ``sqrt(1 + mu) / (1 - mu)`` along each direction, run 7's were 5.6 of them along one
    direction (the whole estimate shifted along it: 17 of 25 parameters beyond 4) and it said nothing: four of the
    eight runs report that direction undetermined (mu 0.51 to 0.55) and widen it, run 7's ratio was 0.43. Now 2.8."""
    _check_montecarlo(_undesigned(338, True, tmp_path))


@pytest.mark.slow  # fast representative: test_montecarlo_on_random_robots_and_undesigned_motions
def test_every_run_of_a_held_fit_within_its_standard_errors(tmp_path):
    """Undesigned spatial robot 36 (15 parameters, one direction undetermined: ML fitted over the others with it held
    at WLS's value): ML's errors within 5 of its standard errors in every one of 8 draws. Run 1's pi6 was 5.72 of them
    off: the held fit's weights, taken where the held value is attenuated, gave it a standard error of 0.39, where the
    fit held at the model's own values gives 1.53 (its own error 3.8; ML over every direction from the truth lands
    there too, within 2.6 of its standard errors). Reported with at least that fit's covariance: 2.16."""
    _check_montecarlo(_undesigned(36, False, tmp_path))


@pytest.mark.slow  # two random robots' ML and their exports (seconds)
@pytest.mark.parametrize("seed, flight, how", [(1, _flown, "exported"), (3657496, _undesigned, "refused")])
def test_export_of_noisy_estimates_of_random_robots(seed, flight, how, tmp_path):
    """The two robots that the pipeline's export stage refused when it was added (of 24 drawn):

    - spatial robot 1 on its designed motion (28 parameters, every one within 1.4 of its standard error): the steps
      within each ellipsoid ended outside it by their conditions' second-order terms (within the 0.999 one, distance
      squared 95 against 56.9), and now one projection moves them in;
    - spatial robot 3657496 on an undesigned motion (45 parameters; ML held 8 directions, every parameter within 0.07
      of its standard error, estimates up to 960 against a largest true parameter of 68): its covariance's
      eigenvalues span 1e-9 to 1e9 once widened along the undetermined directions, 14 determined combinations were
      kept exactly as if of zero variance, and no physical model met them. Now the refusal names that cause, and
      given the prior, the identification exports."""
    flown = flight(seed, False, tmp_path)
    noise = Noise(angle=NOISE, rate=NOISE, base_rate=NOISE, attitude=NOISE)
    measured = add_noise(flown.log, angle=NOISE, rate=NOISE, seed=seed)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        noisy = identify(flown.param, measured, flown.momentum, noise=noise)
    assert _check_noisy_export(flown, measured, noisy, noise) == how


@FAST
@given(seed=SEEDS, planar=st.booleans())
def test_pipeline_on_random_robots(seed, planar, tmp_path):
    _check_pipeline(_flown(seed, planar, tmp_path))


@FAST
@given(seed=SEEDS, planar=st.booleans())
def test_pipeline_on_random_robots_and_undesigned_motions(seed, planar, tmp_path):
    _check_pipeline(_undesigned(seed, planar, tmp_path))


@FAST
@given(seed=SEEDS, planar=st.booleans())
@example(seed=83, planar=True)  # ML converged to impossible values; its fallback, WLS's, was 71 of its errors off
@example(seed=729, planar=False)  # ML stalled at the start; WLS's pi2 6.85 off, outside its undetermined directions
def test_random_robots_released_at_rest_with_an_anchor(seed, planar, tmp_path):
    """Zero momentum, the scale from one known parameter: recovered to round-off from the noise-free log; from a noisy
    one (1e-4 on every signal, rates measured) ``ml``'s standard errors hold the error (spatial robot 33485 was 17 of
    them off: ML's fallback at degenerate weights, :func:`test_ml_holds_the_undetermined_at_the_models_own_values`;
    planar robot 83 71 and spatial robot 729 6.85: ML's estimate impossible or stalled, its fallback WLS's with
    standard errors at WLS's degenerate weights, now widened by OLS's),
    and the drift test raises no alarm beyond its level on the conserved log with either estimator (it fired on 3 of
    24 such robots, p down to 4e-55: the errors-in-variables allowance was not determined). ``ols``'s standard
    errors are not asserted: its first-order bias understates the attenuation at zero momentum (theory/noise, "What
    the standard errors mean")."""
    flown, anchor = flown_at_rest(seed, planar, tmp_path)
    param, h, log, true = flown.param, flown.momentum, flown.log, flown.param.true_values
    with stage("identify noise-free", **flown.case):
        exact = identify(param, log, h, known=anchor, estimator="ols")
        assert np.abs(exact.values - true).max() <= 1e-10 * exact.condition_number * np.abs(true).max()
    noise = Noise(angle=NOISE, rate=NOISE, base_rate=NOISE, attitude=NOISE)
    noisy = add_noise(log, angle=NOISE, rate=NOISE, seed=seed)
    for estimator in ("ml", "ols"):
        with stage(f"identify noisy {estimator}", **flown.case):
            with warnings.catch_warnings():
                warnings.simplefilter("ignore")
                ident = identify(param, noisy, h, known=anchor, estimator=estimator, noise=noise)
            test = ident.diagnostics.drift_test
            # a conserved log fires at the test's level (1e-3) by design: one log is held to alarms it does not explain
            assert not (test.drift and test.p_value < 1e-6), test
            if estimator == "ml":
                free = ident.std > 0
                z = np.abs(ident.values - true)[free] / ident.std[free]
                assert z.max() < 5, f"max |z| {z.max():.3g} over {free.sum()} parameters"
                if str(ident.diagnostics.estimator_info.get("fallback")).startswith("wls"):  # robots 83 and 729
                    assert "widened along the change from OLS's estimate" in ident.diagnostics.covariance


@pytest.mark.slow  # a 36-parameter robot's ML, held twice (seconds)
def test_ml_holds_the_undetermined_at_the_models_own_values(tmp_path):
    """Spatial random robot 33485 released at rest (36 parameters, one direction the data do not determine), its model's
    bodies 20 % off the truth: OLS's and WLS's estimates attenuate its inertias until the equations' error covariance
    is nearly singular there, ML did not converge over every direction nor with that direction held at WLS's value,
    and its fallback, WLS's estimate, was 17 standard errors off (chi2/dof 426). Held at the model's own values, the
    others converge and the errors are within their standard errors."""
    flown, anchor = flown_at_rest(33485, False, tmp_path)
    rng = np.random.default_rng(1)
    model = dataclasses.replace(flown.model, bodies=tuple(
        dataclasses.replace(b, inertial=b.inertial * (1 + 0.2 * rng.choice([-1.0, 1.0]))) for b in flown.model.bodies))
    param = minimal_parameters(model)  # the same kinematics: the same minimal set, the model's values 20 % off
    true = flown.param.true_values
    assert param.names == flown.param.names and np.abs(param.true_values / true - 1).max() > 0.1
    anchor = {name: float(true[param.names.index(name)]) for name in anchor}
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        ident = identify(param, add_noise(flown.log, angle=NOISE, rate=NOISE, seed=33485), flown.momentum, known=anchor,
                         noise=Noise(angle=NOISE, rate=NOISE, base_rate=NOISE, attitude=NOISE))  # fmt: skip
    info = ident.diagnostics.estimator_info
    assert "keep the model's own values" in info.get("held", ""), info.get("fallback")
    free = ident.std > 0
    assert (np.abs(ident.values - true)[free] / ident.std[free]).max() < 3


@pytest.mark.slow
@SLOW
@given(seed=SEEDS, planar=st.booleans())
# a planar tree whose changeless log raised one false alarm (at 15.26 s, 11.6 against 8.9): the grasp's log, the
# same up to the grasp, raised it again, and it was counted twice
@example(seed=1084775, planar=True)
def test_pipeline_and_payload_on_more_random_robots_and_undesigned_motions(seed, planar, tmp_path):
    flown = _undesigned(seed, planar, tmp_path)
    _check_pipeline(flown)
    _check_payload(flown)
    _check_monitor(flown)
    _check_montecarlo(flown)


@pytest.mark.slow
@SLOW
@given(seed=SEEDS, planar=st.booleans())
@example(seed=430, planar=False)  # the payload's consistency projection: Clarabel failed at both tolerances
@example(seed=9152, planar=False)  # ML fell back to WLS in 2 of 8 Monte Carlo runs (_check_montecarlo)
def test_pipeline_and_payload_on_more_random_robots(seed, planar, tmp_path):
    flown = _flown(seed, planar, tmp_path)
    _check_pipeline(flown)
    _check_payload(flown)
    _check_monitor(flown)
    _check_montecarlo(flown)
