"""Excitation design on the Cepheus case with the closed-form regressor: reproducibility, limits
on a fine grid, improvement over the paper's Table 2, gradients, and errors. No wall-clock
assertions: timings live in benchmarks/bench_design.py."""

import numpy as np
import pytest
from cepheus_closed_form import cepheus_regressor

from spaceid import SpaceidError
from spaceid.design import CRITERIA, _problem, design_excitation
from spaceid.trajectory import load_trajectory, sample_times

JOINTS = ("left_shoulder", "left_elbow")
CEPHEUS = dict(duration=5.0, harmonics=3, samples=35, q_max=1.5, qd_max=1.5, qdd_max=3.0)
LIMITS = np.array([1.5, 1.5, 3.0])


def design(**options):
    return design_excitation(cepheus_regressor, JOINTS, **{**CEPHEUS, "n_jobs": 1, **options})


def cond(traj, samples=35):
    q, qd, _ = traj.evaluate(sample_times(traj.duration, samples))
    return np.linalg.cond(cepheus_regressor(q, qd))


def peak_ratio(traj, n):
    """Largest |q|, |qd|, |qdd| over their limits on ``n`` equally spaced times."""
    return np.abs(np.stack(traj.evaluate(sample_times(traj.duration, n)))).max(axis=1).T / LIMITS


@pytest.fixture(scope="module")
def short_run():
    return design(seed=3, n_starts=8)


def test_short_run_beats_the_paper_by_a_large_factor(short_run):
    paper = cond(load_trajectory("paper-table2"))
    assert short_run.value == pytest.approx(cond(short_run.trajectory), rel=1e-9)
    assert short_run.value < paper / 6  # about 36 to 45 against 360
    assert short_run.n_starts == 8 and short_run.seed == 3
    meta = short_run.trajectory.meta
    assert meta["criterion"] == "cond" and meta["seed"] == 3 and meta["value"] == short_run.value
    times, values = np.array(short_run.history).T
    assert np.all(np.diff(times) >= 0) and np.all(np.diff(values) < 0)
    assert values[-1] == short_run.value


def test_limits_hold_on_a_fine_grid(short_run):
    traj = short_run.trajectory
    assert peak_ratio(traj, 1001).max() <= 1 + 1e-9  # the design grid: exact
    assert peak_ratio(traj, 8001).max() <= 1 + 1e-3  # between its points: curvature only
    assert peak_ratio(traj, 1001).max() > 0.999  # the optimum presses on a limit


def test_same_seed_same_result_in_one_or_two_processes(short_run):
    again = design(seed=3, n_starts=8, n_jobs=2)
    assert again.trajectory == short_run.trajectory and again.value == short_run.value
    other = design(seed=4, n_starts=8)
    assert other.trajectory != short_run.trajectory


def test_boundary_values_and_limits_are_kept():
    boundary = {"q0": [0.3, -0.2], "qf": [-0.1, 0.4], "qd0": [0.2, 0.0], "qddf": [0.0, 0.5]}
    result = design(seed=0, n_starts=4, boundary=boundary)
    traj = result.trajectory
    q, qd, qdd = traj.evaluate([0.0, traj.duration])
    np.testing.assert_allclose(q[0], boundary["q0"], atol=1e-12)
    np.testing.assert_allclose(q[1], boundary["qf"], atol=1e-12)
    np.testing.assert_allclose(qd[0], boundary["qd0"], atol=1e-12)
    np.testing.assert_allclose(qdd[1], boundary["qddf"], atol=1e-12)
    np.testing.assert_allclose([qd[1], qdd[0]], 0, atol=1e-12)
    assert peak_ratio(traj, 1001).max() <= 1 + 1e-9
    assert result.value == pytest.approx(cond(traj), rel=1e-9)


def test_warm_start_from_the_paper_improves_on_it():
    paper = load_trajectory("paper-table2")
    result = design(seed=0, n_starts=1, initial=paper)
    assert result.value < cond(paper)


def test_logdet_criterion_beats_the_paper():
    result = design(seed=0, n_starts=4, criterion="logdet")

    def logdet(traj):
        q, qd, _ = traj.evaluate(sample_times(5.0, 35))
        Y = cepheus_regressor(q, qd)
        return np.linalg.slogdet(Y.T @ Y / np.outer(*2 * [np.linalg.norm(Y, axis=0)]))[1]

    assert result.value == pytest.approx(logdet(result.trajectory), rel=1e-9)
    assert result.value > logdet(load_trajectory("paper-table2")) + 5


@pytest.mark.parametrize("criterion", CRITERIA)
def test_gradients_match_finite_differences(criterion):
    limits = np.array([[1.5, 1.5], [1.5, 1.5], [3.0, 3.0]])
    problem = _problem(cepheus_regressor, criterion, duration=5.0, harmonics=3, samples=35,
                       limits=limits, boundary=np.zeros((6, 2)), n_grid=201)  # fmt: skip
    rng = np.random.default_rng(0)
    z, d, h = problem.starts(rng, 1)[0], rng.standard_normal(problem.n), 1e-5
    value, jac = problem.linearize(z)

    def pieces(s):  # the criterion's pieces along z + s d
        return CRITERIA[criterion].pieces(problem.stacked((z + s * d)[None])[0])

    np.testing.assert_allclose(value, pieces(0.0), rtol=1e-12)
    np.testing.assert_allclose(jac @ d, (pieces(h) - pieces(-h)) / (2 * h), rtol=1e-5, atol=1e-8)


def test_progress_and_time_budget():
    calls = []
    result = design(seed=0, n_starts=40, time_budget=1e-3, progress=lambda *a: calls.append(a))
    assert 1 <= result.n_starts < 40  # the budget stops it after the first task
    assert calls[-1] == (result.n_starts, 40)
    assert peak_ratio(result.trajectory, 1001).max() <= 1 + 1e-9


def test_unpicklable_regressor_runs_in_this_process():
    result = design_excitation(lambda q, qd: cepheus_regressor(q, qd), JOINTS, **CEPHEUS,
                               n_starts=4, n_jobs=2)  # fmt: skip
    assert result.value < 100


@pytest.mark.parametrize(
    "options, match",
    [
        ({"criterion": "aopt"}, "criterion must be one of cond, logdet"),
        ({"samples": 7}, "at least 8 samples"),
        ({"harmonics": 0}, "harmonics"),
        ({"q_max": [1.5, 1.5, 1.5]}, "q_max"),
        ({"qdd_max": -1}, "qdd_max"),
        ({"boundary": {"q0": [2.0, 0.0]}}, "boundary"),
        ({"boundary": {"q_start": [0.0, 0.0]}}, "q_start"),
        ({"time_budget": 0}, "time_budget"),
        ({"initial": load_trajectory("paper-table2"), "harmonics": 4}, "initial"),
    ],
)
def test_bad_options(options, match):
    with pytest.raises(SpaceidError, match=match):
        design(n_starts=1, **options)


def test_rank_deficient_regressor():
    def duplicated(q, qd):
        Y = cepheus_regressor(q, qd)
        return np.concatenate([Y, Y[..., :1]], axis=-1)

    with pytest.raises(SpaceidError, match="rank deficient"):
        design_excitation(duplicated, JOINTS, **CEPHEUS, n_starts=2, n_jobs=1)
