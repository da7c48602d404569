"""Excitation design on the Cepheus case with the closed-form regressor: reproducibility, limits
on a fine grid, improvement over the paper's Table 2, gradients, and errors; and the trust-region
search on a small spatial tree. No wall-clock assertions: timings live in
benchmarks/bench_design.py and benchmarks/bench_design_spatial.py."""

import numpy as np
import pytest
from cepheus_closed_form import cepheus_regressor
from conftest import random_tree

from spaceid import SpaceidError
from spaceid.design import CRITERIA, _problem, design_excitation
from spaceid.regressor import minimal_parameters
from spaceid.simulate import excitation_regressor
from spaceid.trajectory import FourierTrajectory, load_trajectory, sample_times

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
    assert meta["method"] == "slsqp" and meta["start_value"] > short_run.value  # auto: 8 columns
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
        ({"method": "newton"}, "method must be one of auto, slsqp, trust-region"),
        ({"max_steps": 0}, "max_steps"),
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


# -- the trust-region search on a small spatial tree ---------------------------------------------

SPATIAL = dict(duration=10.0, harmonics=3, samples=30, q_max=1.5, qd_max=0.8, qdd_max=1.0,
               n_grid=501)
SPATIAL_LIMITS = np.array([1.5, 0.8, 1.0])


@pytest.fixture(scope="module")
def chain():
    """A random spatial 3-joint chain (45 minimal parameters) and its excitation regressor."""
    model = random_tree(np.random.default_rng(2), [0, 1, 2], planar=False)
    param = minimal_parameters(model)
    return model.joints, excitation_regressor(param, param.true_values, [1.0, -2.0, 3.0])


def spatial_design(chain, **options):
    joints, regressor = chain
    options = {"method": "trust-region", "seed": 0, "n_starts": 2, "max_steps": 8,
               "n_screen": 16, "n_jobs": 1, **options}  # fmt: skip
    return design_excitation(regressor, joints, **SPATIAL, **options)


def spatial_peaks(traj, n):
    """Largest |q|, |qd|, |qdd| over their limits on ``n`` times, per joint (n_joints, 3)."""
    signals = np.stack(traj.evaluate(sample_times(traj.duration, n)))
    return np.abs(signals).max(axis=1).T / SPATIAL_LIMITS


def spatial_cond(regressor, traj):
    q, qd, _ = traj.evaluate(sample_times(traj.duration, SPATIAL["samples"]))
    return np.linalg.cond(regressor(q[None], qd[None])[0])


@pytest.fixture(scope="module")
def spatial_run(chain):
    return spatial_design(chain)


def test_trust_region_improves_on_random_feasible_starts(chain, spatial_run):
    joints, regressor = chain
    traj = spatial_run.trajectory
    assert spatial_run.value == pytest.approx(spatial_cond(regressor, traj), rel=1e-9)
    assert traj.meta["method"] == "trust-region" and spatial_run.n_starts == 2
    assert spatial_run.value < traj.meta["start_value"] / 3  # about 5.5e3 from 1.8e4
    # random feasible trajectories, each joint's Fourier part scaled onto its limits
    rng, random, tf = np.random.default_rng(0), [], SPATIAL["duration"]
    for _ in range(16):
        a, b = rng.standard_normal((2, len(joints), SPATIAL["harmonics"]))
        s = spatial_peaks(FourierTrajectory(joints, tf, a, b), 501).max(1)[:, None]
        random.append(spatial_cond(regressor, FourierTrajectory(joints, tf, a / s, b / s)))
    assert spatial_run.value < np.median(random) / 4  # median about 3.7e4


def test_trust_region_keeps_the_limits_on_a_fine_grid(spatial_run):
    traj = spatial_run.trajectory
    assert spatial_peaks(traj, 501).max() <= 1 + 1e-9  # the design grid: exact
    assert spatial_peaks(traj, 8001).max() <= 1 + 1e-3  # between its points: curvature only
    assert np.all(spatial_peaks(traj, 501).max(1) > 0.95)  # every joint on (or near) its limits


def test_trust_region_is_reproducible(chain, spatial_run):
    again = spatial_design(chain, n_jobs=2)
    assert again.trajectory == spatial_run.trajectory and again.value == spatial_run.value
    assert spatial_design(chain, seed=1).trajectory != spatial_run.trajectory


@pytest.mark.parametrize("criterion", CRITERIA)
def test_trust_region_model_gradient_matches_finite_differences(chain, criterion):
    joints, regressor = chain
    limits = np.array([[1.5] * 3, [0.8] * 3, [1.0] * 3])
    problem = _problem(regressor, criterion, duration=10.0, harmonics=3, samples=30,
                       limits=limits, boundary=np.zeros((6, 3)), n_grid=501)  # fmt: skip
    rng = np.random.default_rng(0)
    z = problem.radial(problem.tr_starts(rng, 1)[0], problem.sharpness)[0]
    assert problem.signals(z).max() <= 1  # the smooth gauge keeps the limits
    Y0, Gt = problem.jet(z)
    # at the linearisation point the model is the surrogate of the regressor itself
    f0 = problem._model(z, z, Y0, Gt, 8.0)[0]
    assert f0 == pytest.approx(problem.smooth_objective(z[None], 8.0)[0], rel=1e-12)
    y, d, h = z + 0.01 * rng.standard_normal(z.size), rng.standard_normal(z.size), 1e-6
    value, grad = problem._model(y, z, Y0, Gt, 8.0)
    ahead, behind = (problem._model(y + s * h * d, z, Y0, Gt, 8.0)[0] for s in (1, -1))
    fd = (ahead - behind) / (2 * h)
    assert grad @ d == pytest.approx(fd, rel=1e-5, abs=1e-8)


def test_trust_region_progress_and_time_budget(chain):
    calls = []
    result = spatial_design(chain, n_starts=3, time_budget=1e-3, progress=lambda *a: calls.append(a))
    assert 1 <= result.n_starts < 3  # the budget stops it after the first search
    assert calls[-1][1] == 3 + 2  # three starts, the best two continued
    assert spatial_peaks(result.trajectory, 501).max() <= 1 + 1e-9
