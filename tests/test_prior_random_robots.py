"""The CAD prior (``identify(..., prior=...)``) on robots nobody on the project designed: random planar
and spatial trees (``random_robots``) on designed and undesigned motions (``test_random_pipeline``),
noise-free and noisy, with a CAD prior 20 % / 1 cm off (``perturbed_prior``).

Noise-free, the data determine some directions to round-off and say nothing about the rest: the MAP
must give the truth along the first (the log's momentum to round-off), the prior's values along the
rest (no further from the prior than the truth, which fits the data as well), and standard errors
that cover the error."""

import warnings

import numpy as np
import pytest
from hypothesis import example, given
from hypothesis import strategies as st
from random_robots import perturbed_prior
from robot_tally import robots, stage
from test_random_pipeline import NOISE, Flown, _flown, _undesigned

from spaceid.dynamics import full_values
from spaceid.estimation import Noise, identify
from spaceid.identified import unphysical_bodies
from spaceid.models.internal import with_theta
from spaceid.motion import add_noise

SEEDS = st.integers(0, 2**31 - 1)
ROUND_OFF = 1e-13
"""Errors below this fraction of the largest parameter are round-off: a standard error need not cover
them (the posterior's can be smaller: structural relations of the minimal parameters)."""


def _with_prior(flown: Flown, noisy: bool):
    """The MAP under a prior 20 % / 1 cm off, from the noise-free log or one with 1e-4 of noise."""
    log, options = flown.log, {}
    if noisy:
        log = add_noise(log, angle=NOISE, rate=NOISE, seed=flown.case["seed"])
        options["noise"] = Noise(angle=NOISE, rate=NOISE, base_rate=NOISE, attitude=NOISE)
    prior = perturbed_prior(flown.model, flown.case["seed"] + 1)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        return prior, identify(flown.param, log, flown.momentum, prior=prior, prior_std=0.2, **options)


def _momentum_misfit(flown: Flown, values) -> float:
    """``|Y (values - truth)| / |Y truth|`` over the log's samples: the error along the directions the
    log determines."""
    log, true = flown.log, flown.param.true_values
    y = flown.param.regressor(log.q, log.qd, log.base_w).reshape(-1, len(true))
    return float(np.linalg.norm(y @ (values - true)) / np.linalg.norm(y @ true))


def check_prior(flown: Flown, noisy: bool):
    """One robot and motion through the MAP (see the module docstring); noisy: within 5 standard
    errors and closer to the log's momentum than the prior."""
    param, model, true = flown.param, flown.model, flown.param.true_values
    with stage("prior noisy" if noisy else "prior noise-free", **flown.case):
        prior, result = _with_prior(flown, noisy)
        record = result.prior
        theta, theta0, s = (np.array(record.theta[key]) for key in ("map", "prior", "prior_std"))
        assert not unphysical_bodies(with_theta(prior, theta))
        misfit, prior_misfit = _momentum_misfit(flown, result.values), _momentum_misfit(flown, record.prior_values)
        error = np.abs(result.values - true)
        free = result.std > 0
        if noisy:
            assert misfit < prior_misfit, (misfit, prior_misfit)
            assert (error / result.std)[free].max() < 5
            return
        assert misfit < 1e-10, f"momentum misfit {misfit:.3g} (the prior's {prior_misfit:.3g})"
        beyond = np.clip(error - ROUND_OFF * np.abs(true).max(), 0, None)
        assert (beyond / result.std)[free].max() < 4, f"max |z| {(beyond / result.std)[free].max():.3g}"
        # the prior's values along the rest: the truth fits the data as well, so the MAP is no further from the prior
        distance, truth = (np.sum(((x - theta0) / s) ** 2) for x in (theta, full_values(model)[: len(theta)]))
        assert distance <= truth + 1e-6, (distance, truth)
        log = flown.log
        rank = np.linalg.matrix_rank(param.regressor(log.q, log.qd, log.base_w).reshape(-1, len(true)))
        assert record.n_data <= rank  # the data set no direction the log does not determine


@robots(1)
@given(seed=SEEDS, planar=st.booleans(), noisy=st.booleans())
def test_prior_on_random_robots_and_undesigned_motions(seed, planar, noisy, tmp_path):
    check_prior(_undesigned(seed, planar, tmp_path), noisy)


@pytest.mark.slow
@robots(10)
@given(seed=SEEDS, planar=st.booleans(), noisy=st.booleans())
# noise-free: the convex step did not solve (data 3.7e17 times as informative as the prior) and a bare
# LinAlgError: Singular matrix (the posterior's information formed in double precision)
@example(seed=392, planar=False, noisy=False)
@example(seed=8352, planar=True, noisy=False)
def test_prior_on_more_random_robots_and_undesigned_motions(seed, planar, noisy, tmp_path):
    check_prior(_undesigned(seed, planar, tmp_path), noisy)


@pytest.mark.slow
@robots(6)
@given(seed=SEEDS, planar=st.booleans(), noisy=st.booleans())
# noise-free: directions of round-off (a singular value 2e-13 of the largest, above a relative cut of 1e-13)
# asked the first convex step to move 1e9 prior deviations, and Clarabel called it infeasible
@example(seed=1473772, planar=False, noisy=False)
def test_prior_on_random_robots_and_designed_motions(seed, planar, noisy, tmp_path):
    check_prior(_flown(seed, planar, tmp_path), noisy)
