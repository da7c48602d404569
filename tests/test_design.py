"""Excitation design on the Cepheus case with the closed-form regressor: reproducibility, limits
on a fine grid, improvement over the paper's Table 2, gradients, and errors; the trust-region
search on a small spatial tree; and the noise-aware criteria (whitened regressor against a
brute-force Fisher information, nested-difference gradients, crb against cond designs). No
wall-clock assertions: timings live in benchmarks/bench_design.py,
benchmarks/bench_design_spatial.py and benchmarks/bench_design_noise.py."""

import json
import re
import time
import types

import numpy as np
import pytest
from cepheus_closed_form import cepheus_regressor
from conftest import random_tree

import spaceid
from spaceid import SpaceidError
from spaceid.cli import main
from spaceid.motion._design import CRITERIA, optimize_excitation, design_excitation, whitened_regressor
from spaceid.motion._design_problem import _set_up_problem
from spaceid.motion._design_search import _linearized_surrogate
from spaceid.estimation import Noise, equation_covariance, momentum_scale, signal_jacobian, signal_sigma
from spaceid.dynamics import minimal_parameters
from spaceid.dynamics import base_rate, excitation_regressor
from spaceid.motion._trajectory import (
    FourierTrajectory,
    boundary_quintic,
    fourier_basis,
    load_trajectory,
    sample_times,
)

JOINTS = ("left_shoulder", "left_elbow")
CEPHEUS = dict(duration=5.0, harmonics=3, samples=35, q_max=1.5, qd_max=1.5, qdd_max=3.0)
LIMITS = np.array([1.5, 1.5, 3.0])


def design(**options):
    return optimize_excitation(cepheus_regressor, JOINTS, **{**CEPHEUS, "jobs": 1, **options})


def cond(traj, samples=35):
    q, qd, _ = traj.evaluate(sample_times(traj.duration, samples))
    return np.linalg.cond(cepheus_regressor(q, qd))


def peak_ratio(traj, n):
    """Largest |q|, |qd|, |qdd| over their limits on ``n`` equally spaced times."""
    return np.abs(np.stack(traj.evaluate(sample_times(traj.duration, n)))).max(axis=1).T / LIMITS


@pytest.fixture(scope="module")
def short_run():
    return design(seed=3, n_starts=8)


@pytest.mark.slow
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


def test_limits_hold_at_all_times(short_run):
    traj = short_run.trajectory
    assert peak_ratio(traj, 1001).max() <= 1 + 1e-9  # the design grid
    assert peak_ratio(traj, 20001).max() <= 1 + 1e-9  # between its points too (5e-5 over before)
    assert peak_ratio(traj, 1001).max() > 0.999  # the optimum presses on a limit


@pytest.mark.slow
def test_room_used_finds_the_peaks_between_grid_points():
    """A coarse grid (101 times, 8 a period of the top harmonic): scaled onto the limits by
    the gauge, each joint's largest room used is 1 on 200001 times, its grid values less."""
    limits = np.array([[1.5, 1.5], [1.5, 1.5], [3.0, 3.0]])
    boundary = np.zeros((6, 2))
    boundary[0], boundary[3] = [0.3, -0.2], [-0.1, 0.4]  # q0, qf: rooms of both signs differ
    problem = _set_up_problem(cepheus_regressor, "cond", duration=5.0, harmonics=12, samples=35,
                              limits=limits, boundary=boundary, n_grid=101)  # fmt: skip
    z = problem.scale_onto_limits(problem.random_inside_limits(np.random.default_rng(0), 1)[0])
    t = sample_times(5.0, 200001)
    fourier = np.einsum("dtk,jk->dtj", fourier_basis(t, duration=5.0, harmonics=12), problem.coefficients(z))
    p = boundary_quintic(t, duration=5.0, boundary=boundary)
    used = np.where(fourier > 0, fourier / (limits[:, None] - p), -fourier / (limits[:, None] + p))
    assert np.all(np.abs(used.max(axis=(0, 1)) - 1) < 1e-7)  # 200001 times miss up to 2e-8
    A, up, down = problem.grid_room_terms
    v = np.einsum("rjk,jk->rj", A, z.reshape(problem.S.shape))
    on_grid = np.where(v > 0, v * up, -v * down).max(0)
    assert np.all(on_grid < 1 - 1e-4)  # the grid alone would miss the peaks


@pytest.mark.slow
def test_same_seed_same_result_in_one_or_two_processes(short_run):
    again = design(seed=3, n_starts=8, jobs=2)
    assert again.trajectory == short_run.trajectory and again.value == short_run.value
    other = design(seed=4, n_starts=8)
    assert other.trajectory != short_run.trajectory


@pytest.mark.slow
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
    assert peak_ratio(traj, 20001).max() <= 1 + 1e-9
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
    problem = _set_up_problem(cepheus_regressor, criterion, duration=5.0, harmonics=3, samples=35,
                              limits=limits, boundary=np.zeros((6, 2)), n_grid=201)  # fmt: skip
    rng = np.random.default_rng(0)
    z, d, h = problem.random_inside_limits(rng, 1)[0], rng.standard_normal(problem.n), 1e-5
    value, jac = problem.linearize_criterion(z)

    def pieces(s):  # the criterion's pieces along z + s d
        return CRITERIA[criterion].pieces(problem.stacked_regressor((z + s * d)[None])[0])

    np.testing.assert_allclose(value, pieces(0.0), rtol=1e-12)
    np.testing.assert_allclose(jac @ d, (pieces(h) - pieces(-h)) / (2 * h), rtol=1e-5, atol=1e-8)


def test_progress_and_time_budget():
    calls, lines = [], []
    result = design(seed=0, n_starts=40, time_budget=1e-3, progress=lambda *a: calls.append(a), status=lines.append)
    assert 1 <= result.n_starts < 40  # the budget stops it after the first task
    assert calls[-1] == (result.n_starts, 40)
    assert result.trajectory.meta["stop"] == "budget"
    assert lines[-1].startswith(f"start {result.n_starts}/40, best cond ")
    assert peak_ratio(result.trajectory, 1001).max() <= 1 + 1e-9


def test_budget_stops_a_search_inside_its_iterations(monkeypatch):
    """A fake clock that ticks one second at every look: a budget of 30 ticks ends the
    search inside the first local searches' iterations (a search looks hundreds of times); the
    result is inside the limits and says the budget ended it."""
    import spaceid.motion._design_problem as problem_module
    import spaceid.motion._design_search as search_module

    class Clock:
        now = 0.0
        perf_counter = staticmethod(time.perf_counter)

        @classmethod
        def time(cls):  # the deadline's clock
            cls.now += 1.0
            return cls.now

    for module in (problem_module, search_module):
        monkeypatch.setattr(module, "time", Clock)
    result = design(seed=0, n_starts=40, time_budget=30.0)
    assert result.trajectory.meta["stop"] == "budget" and 1 <= result.n_starts < 40
    assert Clock.now < 60  # the searches and the polish stopped soon after the end
    assert peak_ratio(result.trajectory, 1001).max() <= 1 + 1e-9
    assert result.value == pytest.approx(cond(result.trajectory), rel=1e-9)


def test_step_budget_gives_the_same_design_on_any_machine(monkeypatch):
    """``max_steps``: each SLSQP search and polish stops after that many linearisations, whatever the
    machine's speed (a clock that jumps a second at every look changes nothing), in one process or
    two, bit for bit; it binds (fewer steps, another trajectory) and is recorded."""
    import spaceid.motion._design_problem as problem_module
    import spaceid.motion._design_search as search_module

    first = design(seed=0, n_starts=3, max_steps=6)
    assert first.trajectory.meta["max_steps"] == 6 and first.trajectory.meta["time_budget"] is None
    assert design(seed=0, n_starts=3, max_steps=6, jobs=2).trajectory == first.trajectory

    class Clock:  # a loaded machine: every look at the clock a second later
        now = 0.0
        perf_counter = staticmethod(time.perf_counter)

        @classmethod
        def time(cls):
            cls.now += 1.0
            return cls.now

    for module in (problem_module, search_module):
        monkeypatch.setattr(module, "time", Clock)
    again = design(seed=0, n_starts=3, max_steps=6)
    assert np.array_equal(again.trajectory.a, first.trajectory.a) and np.array_equal(again.trajectory.b,
                                                                                      first.trajectory.b)
    assert again.value == first.value
    monkeypatch.undo()
    assert design(seed=0, n_starts=3, max_steps=3).value != first.value  # the budget binds
    assert design(seed=0, n_starts=3).value < first.value  # unbounded: SLSQP to its tolerance


def test_step_budget_counts_linearisations(monkeypatch):
    """An SLSQP search spends at most ``max_steps`` linearisations, a polish as many again."""
    import spaceid.motion._design_problem as problem_module

    calls = []
    original = problem_module._ExcitationProblem.linearize_criterion
    monkeypatch.setattr(problem_module._ExcitationProblem, "linearize_criterion",
                        lambda self, *a, **k: calls.append(1) or original(self, *a, **k))
    design(seed=0, n_starts=2, max_steps=5)
    assert 0 < len(calls) <= 5 * (2 + 2)  # two searches, two polishes


@pytest.mark.slow  # fast representative: test_convergence_takes_results_in_start_order
def test_convergence_stops_the_search():
    """patience=2: the search stops at the first start after which two starts in a row gained
    less than 1e-3 in log cond, and records why; with fewer starts than the patience every
    start runs."""
    result = design(seed=0, n_starts=40, patience=2)
    assert result.trajectory.meta["stop"] == "converged" and 3 <= result.n_starts < 40
    every = design(seed=0, n_starts=4)  # default patience: 8
    assert every.trajectory.meta["stop"] == "starts" and every.n_starts == 4


def test_convergence_takes_results_in_start_order():
    """Results arriving out of order are taken in start order, so the convergence test and the
    best do not depend on timing; those after convergence are left out."""
    from spaceid.motion._design_search import _Tally

    z = np.zeros(1)
    values = {0: 5.0, 1: 3.0, 2: 3.0005, 3: 2.9999, 4: 1.0, 5: 4.0}
    for order in ([0, 1, 2, 3, 4, 5], [4, 2, 0, 5, 3, 1]):
        tally = _Tally(np.exp, 0.0, None, patience=2)
        tally.add([(i, (z, values[i])) for i in order], 6)
        assert tally.stop == "converged" and [c[1] for c in tally.found] == [0, 1, 2, 3]
        assert tally.best[:2] == (2.9999, 3)  # start 4 (1.0) completes after convergence: left out


def test_unpicklable_regressor_runs_in_this_process():
    result = optimize_excitation(lambda q, qd: cepheus_regressor(q, qd), JOINTS, **CEPHEUS,
                               n_starts=4, jobs=2)  # fmt: skip
    assert result.value < 100


@pytest.mark.parametrize(
    "options, match",
    [
        ({"criterion": "aopt"}, "`criterion` must be one of cond, logdet"),
        ({"samples": 7}, "at least 8 samples"),
        ({"harmonics": 0}, "harmonics"),
        ({"q_max": [1.5, 1.5, 1.5]}, "q_max"),
        ({"qdd_max": -1}, "qdd_max"),
        ({"boundary": {"q0": [2.0, 0.0]}}, "boundary"),
        ({"boundary": {"q_start": [0.0, 0.0]}}, "q_start"),
        ({"time_budget": 0}, "time_budget"),
        ({"initial": load_trajectory("paper-table2"), "harmonics": 4}, "initial"),
        ({"method": "newton"}, "`method` must be one of auto, slsqp, trust-region"),
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
        optimize_excitation(duplicated, JOINTS, **CEPHEUS, n_starts=2, jobs=1)


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
               "n_screen": 16, "jobs": 1, **options}  # fmt: skip
    return optimize_excitation(regressor, joints, **SPATIAL, **options)


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


@pytest.mark.slow
def test_trust_region_improves_on_random_feasible_starts(chain, spatial_run):
    joints, regressor = chain
    traj = spatial_run.trajectory
    assert spatial_run.value == pytest.approx(spatial_cond(regressor, traj), rel=1e-9)
    assert traj.meta["method"] == "trust-region" and spatial_run.n_starts == 2
    # 5.9e3 from 1.5e4 in 8 steps (16 steps: 5.4e3); 5.5e3 from 1.8e4 on earlier NumPy and SciPy (1.17.1 now)
    assert spatial_run.value < traj.meta["start_value"] / 2.5
    # random feasible trajectories, each joint's Fourier part scaled onto its limits
    rng, random, tf = np.random.default_rng(0), [], SPATIAL["duration"]
    for _ in range(16):
        a, b = rng.standard_normal((2, len(joints), SPATIAL["harmonics"]))
        s = spatial_peaks(FourierTrajectory(joints, tf, a, b), 501).max(1)[:, None]
        random.append(spatial_cond(regressor, FourierTrajectory(joints, tf, a / s, b / s)))
    assert spatial_run.value < np.median(random) / 4  # median about 3.7e4


def test_trust_region_keeps_the_limits_at_all_times(spatial_run):
    traj = spatial_run.trajectory
    assert spatial_peaks(traj, 501).max() <= 1 + 1e-9  # the design grid
    assert spatial_peaks(traj, 20001).max() <= 1 + 1e-9  # between its points too (8e-5 over before)
    assert np.all(spatial_peaks(traj, 501).max(1) > 0.95)  # every joint on (or near) its limits


@pytest.mark.slow
def test_trust_region_is_reproducible(chain, spatial_run):
    again = spatial_design(chain, jobs=2)
    assert again.trajectory == spatial_run.trajectory and again.value == spatial_run.value
    assert spatial_design(chain, seed=1).trajectory != spatial_run.trajectory


@pytest.mark.parametrize("criterion", CRITERIA)
def test_trust_region_model_gradient_matches_finite_differences(chain, criterion):
    joints, regressor = chain
    limits = np.array([[1.5] * 3, [0.8] * 3, [1.0] * 3])
    problem = _set_up_problem(regressor, criterion, duration=10.0, harmonics=3, samples=30,
                              limits=limits, boundary=np.zeros((6, 3)), n_grid=501)  # fmt: skip
    rng = np.random.default_rng(0)
    z = problem.map_onto_limits(problem.random_on_limits(rng, 1)[0])[0]
    assert problem.signals_over_limits(z).max() <= 1  # the smooth gauge keeps the limits
    Y0, Gt = problem.linearize_regressor(z)
    # at the linearisation point the model is the surrogate of the regressor itself
    f0 = _linearized_surrogate(problem, z, z, Y0, Gt, 8.0)[0]
    assert f0 == pytest.approx(problem.smooth_objective(z[None], 8.0)[0], rel=1e-12)
    y, d, h = z + 0.01 * rng.standard_normal(z.size), rng.standard_normal(z.size), 1e-6
    value, grad = _linearized_surrogate(problem, y, z, Y0, Gt, 8.0)
    ahead, behind = (_linearized_surrogate(problem, y + s * h * d, z, Y0, Gt, 8.0)[0] for s in (1, -1))
    fd = (ahead - behind) / (2 * h)
    assert grad @ d == pytest.approx(fd, rel=1e-5, abs=1e-8)


def test_trust_region_progress_and_time_budget(chain):
    calls = []
    result = spatial_design(chain, n_starts=3, time_budget=1e-3, progress=lambda *a: calls.append(a))
    assert 1 <= result.n_starts < 3  # the budget stops it after the first search
    assert result.trajectory.meta["stop"] == "budget"
    assert calls[-1][1] == 1  # the budget affords one search a worker: no second round
    assert spatial_peaks(result.trajectory, 501).max() <= 1 + 1e-9


# -- noise-aware criteria --------------------------------------------------------------------------

NOISE = Noise(angle=1e-4, rate=1e-4, base_rate=1e-4)
H = np.array([0.0, 0.0, 0.4934])  # [N m s]
NOISY = dict(duration=5.0, harmonics=3, samples=35, momentum=H, seed=0, noise=NOISE, n_starts=4,
             jobs=1)  # fmt: skip


@pytest.fixture(scope="module")
def cepheus():
    return minimal_parameters(spaceid.load_model("cepheus"))


def test_whitened_gram_is_the_fisher_information(cepheus):
    """Brute force on Cepheus: S_n from central differences of g = Y(q, qd, w0) pi in each of
    the five signals (q1, q2, qd1, qd2, w0z), then sum_n Y_n^T Y_n / S_n."""
    pi = cepheus.true_values
    q, qd, _ = load_trajectory("paper-table2").evaluate(sample_times(5.0, 35))
    w0 = base_rate(cepheus, pi, q, qd, H)
    Y = cepheus.regressor(q, qd, w0)[:, 0]  # (35, 8): the z row

    def g(x):
        wz = np.pad(x[:, 4:], ((0, 0), (2, 0)))
        return cepheus.regressor(x[:, :2], x[:, 2:4], wz)[:, 0] @ pi

    x, h = np.concatenate([q, qd, w0[:, 2:]], 1), 1e-6
    J = np.stack([(g(x + h * e) - g(x - h * e)) / (2 * h) for e in np.eye(5)], -1)
    S = (J**2) @ np.full(5, 1e-4) ** 2
    fisher = (Y / S[:, None]).T @ Y
    Yw = whitened_regressor(cepheus, pi, H, NOISE, relative=False)(q, qd)
    assert np.abs(Yw.T @ Yw - fisher).max() < 1e-7 * np.abs(fisher).max()
    relative = whitened_regressor(cepheus, pi, H, NOISE)
    np.testing.assert_allclose(relative(q, qd), Yw * np.abs(pi), rtol=1e-12)
    crb = np.linalg.inv(fisher) / np.outer(pi, pi)
    np.testing.assert_allclose(relative.crb(q, qd), crb, rtol=1e-6)


def test_whitened_gram_on_a_spatial_tree(chain):
    """Three equations a sample: the Cholesky whitening against ``sum Y_n^T S_n^-1 Y_n``, with
    attitude noise (the momentum enters S_n through it) and a batch of two motions."""
    joints, plain = chain
    param, pi = plain.param, plain.pi
    noise = Noise(angle=1e-3, rate=2e-3, base_rate=1e-3, attitude=3e-3)
    rng = np.random.default_rng(1)
    q, qd = rng.uniform(-1, 1, (2, 2, 30, len(joints)))
    Yw = whitened_regressor(param, pi, plain.momentum, noise, relative=False)(q, qd)
    assert Yw.shape == (2, 90, len(pi))
    for b in range(2):
        w0 = base_rate(param, pi, q[b], qd[b], plain.momentum)
        Y = param.regressor(q[b], qd[b], w0)  # (30, 3, k)
        jac = signal_jacobian(param, pi, q[b], qd[b], w0, np.broadcast_to(plain.momentum, (30, 3)))
        S = equation_covariance(jac, signal_sigma(param, noise))
        fisher = np.einsum("nri,nrs,nsj->ij", Y, np.linalg.inv(S), Y)
        assert np.abs(Yw[b].T @ Yw[b] - fisher).max() < 1e-9 * np.abs(fisher).max()


def test_cond_surrogate_at_p2_is_exact_on_an_ill_conditioned_regressor():
    """At p = 2 the surrogate comes from a QR (traces of G and G^-1), not an SVD: on a
    regressor of cond 1e10 its value and gradient match the power-mean formula from the exact
    singular values, along the largest singular values too (where ``Y G^-2`` formed as
    ``Y (G^-1 G^-1)`` is off by a factor 400 with the wrong sign)."""
    rng = np.random.default_rng(0)
    s = np.logspace(0, -10, 30)
    U, V = np.linalg.qr(rng.standard_normal((80, 30)))[0], np.linalg.qr(rng.standard_normal((30, 30)))[0]
    Y = (U * s) @ V.T
    g = s / np.sum(s**2) - s**-3 / np.sum(s**-2.0)  # d surrogate / d s_i
    value = (np.log(np.sum(s**2)) + np.log(np.sum(s**-2.0))) / 2 - np.log(len(s))
    f, W = CRITERIA["cond"].smoothed(Y, 2.0)
    assert f == pytest.approx(value, abs=1e-6)
    assert np.abs(W - (U * g) @ V.T).max() < 1e-6 * np.abs(g).max()
    np.testing.assert_allclose(np.diag(U.T @ W @ V)[:3], g[:3], rtol=1e-6)
    np.testing.assert_allclose(CRITERIA["cond"].smoothed_value(np.stack([Y, 3 * Y]), 2.0), [f, f], rtol=1e-9)


@pytest.mark.parametrize("criterion", CRITERIA)
def test_directional_pieces_agree_with_the_adjoint(criterion):
    rng = np.random.default_rng(0)
    Y, dY = rng.standard_normal((40, 6)), rng.standard_normal((3, 40, 6))
    crit = CRITERIA[criterion]
    value, jac = crit.pieces(Y, dY)
    pieces, W = crit.adjoint(Y)
    np.testing.assert_allclose(value, pieces, rtol=1e-12)
    np.testing.assert_allclose(jac, np.tensordot(W, dY, ((1, 2), (1, 2))), rtol=1e-9, atol=1e-12)


@pytest.mark.parametrize("criterion", ["dopt", "crb"])
def test_nested_differences_give_accurate_gradients(cepheus, criterion):
    """The whitened regressor holds central differences in q (noise.FD_STEP); the design
    differentiates it again, at the step it asks for. Checked against 5-point differences of
    step 1e-3 (their error is about 1e-8): the design's default step 1e-6 is 100 times off."""
    regressor = whitened_regressor(cepheus, cepheus.true_values, H, NOISE)
    limits = np.array([[1.5, 1.5], [1.5, 1.5], [3.0, 3.0]])
    problem = _set_up_problem(regressor, criterion, duration=5.0, harmonics=3, samples=35,
                              limits=limits, boundary=np.zeros((6, 2)), n_grid=201)  # fmt: skip
    assert problem.step == regressor.fd_step == 1e-4
    rng = np.random.default_rng(0)
    z, d = problem.random_inside_limits(rng, 1)[0], rng.standard_normal(problem.n)
    Y, Gt = problem.linearize_regressor(z)
    q, qd = np.einsum("dtk,jk->dtj", problem.B_samples, problem.coefficients(z)) + problem.P_samples
    h, ref = 1e-3, []
    for signal in range(2):
        for j in range(2):
            e = np.zeros_like(q)
            e[:, j] = h

            def f(s):
                return regressor(q + s * e, qd) if signal == 0 else regressor(q, qd + s * e)

            ref.append((f(-2) - 8 * f(-1) + 8 * f(1) - f(2)) / (12 * h))
    ref = np.stack(ref, 1)  # (35, 4, 8): sample t's rows along (q|qd)_j
    assert np.abs(Gt - ref).max() < 1e-6 * np.abs(ref).max()

    def piece(s):
        return CRITERIA[criterion].pieces(problem.stacked_regressor((z + s * d)[None])[0])[0]

    fd = (piece(-2 * h) - 8 * piece(-h) + 8 * piece(h) - piece(2 * h)) / (12 * h)
    assert problem.linearize_criterion(z)[1][0] @ d == pytest.approx(fd, rel=1e-6)


@pytest.fixture(scope="module")
def noisy_designs(cepheus):
    return {c: design_excitation(cepheus, criterion=c, **NOISY) for c in ("cond", "dopt", "crb")}


@pytest.mark.slow
def test_crb_design_predicts_a_smaller_error_than_the_cond_design(cepheus, noisy_designs):
    bound = whitened_regressor(cepheus, cepheus.true_values, H, NOISE)

    def crb(criterion):
        q, qd, _ = noisy_designs[criterion].trajectory.evaluate(sample_times(5.0, 35))
        return bound.crb(q, qd)

    trace = {c: np.trace(crb(c)) for c in noisy_designs}
    assert noisy_designs["crb"].value == pytest.approx(trace["crb"], rel=1e-9)
    assert trace["crb"] < 0.9 * trace["cond"]  # 1.21e-5 against 1.43e-5 (seed 0, 4 starts)
    logdet = {c: np.linalg.slogdet(np.linalg.inv(crb(c)))[1] for c in noisy_designs}
    assert noisy_designs["dopt"].value == pytest.approx(logdet["dopt"], rel=1e-9)
    assert logdet["dopt"] > logdet["cond"] + 1  # about 127.2 against 125.1


def test_noise_and_predicted_bound_are_recorded(cepheus, noisy_designs):
    pi = cepheus.true_values
    for criterion, result in noisy_designs.items():
        meta = result.trajectory.meta
        assert result.noise == NOISE and result.to_dict()["noise"] == NOISE.to_dict()
        assert meta["criterion"] == criterion and meta["value"] == result.value
        assert meta["seed"] == 0 and meta["noise"] == NOISE.to_dict()
        q, qd, _ = result.trajectory.evaluate(sample_times(5.0, 35))
        rel = np.sqrt(np.diag(whitened_regressor(cepheus, pi, H, NOISE).crb(q, qd)))
        np.testing.assert_allclose(list(meta["crb_relative_std"].values()), rel, rtol=1e-9)
        np.testing.assert_allclose(list(meta["crb_std"].values()), rel * np.abs(pi), rtol=1e-9)
        w0 = excitation_regressor(cepheus, pi, H).with_rate(q, qd)[1]  # the nominal base rate
        scale = momentum_scale(cepheus, q, qd, w0)
        assert meta["momentum_scale"] == scale.to_dict()
        np.testing.assert_allclose(list(meta["crb_scaled_std"].values()), rel * np.abs(pi) * scale.per_unit, rtol=1e-9)
    json.dumps(result.to_dict())  # JSON-ready


@pytest.mark.parametrize("noise", [None, Noise()])
def test_noise_aware_criteria_need_the_noise(cepheus, noise):
    with pytest.raises(SpaceidError, match="give `noise.angle`, `noise.rate`, `noise.base_rate`"):
        design_excitation(cepheus, **{**NOISY, "criterion": "crb", "noise": noise})


def test_whitened_regressor_errors(cepheus):
    with pytest.raises(SpaceidError, match="every standard deviation is zero"):
        whitened_regressor(cepheus, cepheus.true_values, H, Noise())
    pi = cepheus.true_values.copy()
    pi[1] = 0.0
    with pytest.raises(SpaceidError, match="nominal value zero for pi2"):
        whitened_regressor(cepheus, pi, H, NOISE)
    whitened_regressor(cepheus, pi, H, NOISE, relative=False)  # absolute: fine


@pytest.mark.slow
def test_cli_design_with_noise(tmp_path, capsys):
    args = ["design", "cepheus", "--duration", "5", "--harmonics", "3", "--samples", "35",
            "--momentum", "0.4934", "--starts", "2", "--criterion", "crb"]  # fmt: skip
    assert main([*args, "-o", str(tmp_path / "none.json")]) == 2
    assert "give --noise-angle" in capsys.readouterr().err
    assert not (tmp_path / "none.json").exists()
    noise = ["--noise-angle", "1e-4", "--noise-rate", "1e-4", "--noise-attitude", "0"]  # (the base rate's: the rate's)
    assert main([*args, *noise, "-o", str(tmp_path / "traj.json")]) == 0
    line = " ".join(capsys.readouterr().err.split())  # rich wraps at the terminal's width
    assert re.search(r"predicted CRB: worst std \S+ % of the momentum scale \(pi\d\); worst relative std of "
                     r"the 8 large parameters \S+ % \(pi\d\)", line), line
    meta = load_trajectory(tmp_path / "traj.json").meta
    assert meta["criterion"] == "crb" and meta["noise"] == NOISE.to_dict()


def test_cli_design_step_budget(tmp_path, capsys):
    args = ["design", "cepheus", "--duration", "5", "--harmonics", "3", "--samples", "35", "--momentum", "0.4934",
            "--starts", "2", "--max-steps", "4"]  # fmt: skip
    assert main([*args, "-o", str(tmp_path / "a.json")]) == 0 and main([*args, "-o", str(tmp_path / "b.json")]) == 0
    first, again = load_trajectory(tmp_path / "a.json"), load_trajectory(tmp_path / "b.json")
    assert first.meta["max_steps"] == 4 and np.array_equal(first.a, again.a) and np.array_equal(first.b, again.b)
    assert main([*args[:-1], "0", "-o", str(tmp_path / "c.json")]) == 2
    assert "--max-steps" in capsys.readouterr().err


# fast representatives: test_progress_and_time_budget, test_last_status_line_reports_the_result_value,
# test_cli_design_step_budget
@pytest.mark.slow
def test_cli_design_prints_progress_lines_when_not_on_a_terminal(tmp_path, capsys):
    args = ["design", "cepheus", "--duration", "5", "--harmonics", "3", "--samples", "35",
            "--momentum", "0.4934", "--starts", "3", "-o", str(tmp_path / "traj.json")]  # fmt: skip
    assert main(args) == 0  # pytest's captured stderr is not a terminal
    err = capsys.readouterr().err
    assert err.startswith("design: start 1/3, best cond ")  # the first at once, then one every 5 s
    assert "3 starts, stopped: starts" in " ".join(err.split())  # rich wraps long lines
    assert load_trajectory(tmp_path / "traj.json").meta["stop"] == "starts"


def test_last_status_line_reports_the_result_value():
    """The polish after the SLSQP searches changes the best: a status line says so, and the last
    line reports the value the result reports (issue 29: "best cond 279.1", then "cond = 222.577")."""
    lines = []
    result = design(seed=0, n_starts=3, status=lines.append)
    assert lines[-1].startswith("polished the best ")
    assert float(re.search(r"best cond (\S+),", lines[-1]).group(1)) == float(f"{result.value:.6g}")


@pytest.mark.slow  # fast representatives: test_last_status_line_reports_the_result_value, test_cli_design_step_budget
def test_cli_design_last_progress_line_agrees_with_the_result(tmp_path, capsys, monkeypatch):
    """The progress lines are held back to one every 5 s, but the last one is printed before the
    result line, and both give the same value (a clock that stands still holds every line after
    the first)."""
    monkeypatch.setattr(spaceid.cli, "time", types.SimpleNamespace(monotonic=lambda: 0.0))
    args = ["design", "cepheus", "--duration", "5", "--harmonics", "3", "--samples", "35",
            "--momentum", "0.4934", "--starts", "3", "-o", str(tmp_path / "traj.json")]  # fmt: skip
    assert main(args) == 0
    err = " ".join(capsys.readouterr().err.split())  # rich wraps long lines
    progress = re.findall(r"design: (.*?), best cond (\S+), \d+ s", err)
    assert len(progress) == 2 and progress[0][0] == "start 1/3" and progress[1][0].startswith("polished")
    assert float(progress[-1][1]) == float(re.search(r"cond = (\S+) \(seed", err).group(1))


def test_results_done_after_the_budget_ran_out_are_taken():
    """Start 1 completes before start 0 and the budget ends the search meanwhile: start 0's
    result, done later, is still taken (a search that ran is never lost)."""
    from spaceid.motion._design_search import _Tally

    tally, z = _Tally(np.exp, 0.0, None, patience=8), np.zeros(1)
    tally.add([(1, (z, 2.0))], 2)
    tally.stop = "budget"
    tally.add([(0, (z, 3.0))], 2)
    assert [c[1] for c in tally.found] == [0, 1] and tally.best[:2] == (2.0, 1)


def test_rank_check_passes_on_the_first_start_of_full_rank_and_fails_when_none_has_it():
    """The design's rank check tries the starts in turn: one of full rank among deficient ones passes (the
    later ones not needed), none raises the error that says what to change."""
    from spaceid.motion._design_problem import _check_rank

    rng = np.random.default_rng(0)
    full, deficient = rng.standard_normal((30, 6)), rng.standard_normal((30, 5)) @ rng.standard_normal((5, 6))
    _check_rank(types.SimpleNamespace(stacked_regressor=lambda Z: np.stack([deficient, full, deficient])), None)
    with pytest.raises(SpaceidError, match="rank deficient on random start trajectories"):
        _check_rank(types.SimpleNamespace(stacked_regressor=lambda Z: np.stack([deficient, deficient])), None)
