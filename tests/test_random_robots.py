"""Every stage on robots nobody on the project designed: random planar and spatial URDF trees
(``random_robots``), with random CAD-like priors. The seeds of failures found this way are kept
as regression cases (in the slow suite)."""

import dataclasses
import warnings

import numpy as np
import pinocchio as pin
import pytest
from hypothesis import example, given
from hypothesis import strategies as st
from random_robots import perturbed_prior, random_robot
from robot_tally import robots, stage
from random_states import random_log
from test_export import check_export

import spaceid
from spaceid.dynamics import minimal_parameters
from spaceid.estimation import identify
from spaceid.identified import export_model, pseudo_inertia, write_export

SEEDS = st.integers(0, 2**31 - 1)
FAST = robots(1)
SLOW = robots(40)


def noise_free_identification(model, seed):
    """Least squares on 200 noise-free samples at random states: the parameters to ~1e-15, their
    round-off as an identification from a log leaves it."""
    param = minimal_parameters(model)
    h = np.array([0.0, 0.0, 0.3]) if model.planar else np.array([0.3, -0.2, 0.1])
    return identify(param, random_log(param, h, 200, np.random.default_rng(seed)), h, estimator="ols")


def _exact_export(seed, planar, tmp_path, **size):
    """Export of a noise-free identification of a random robot with a prior 20 % / 1 cm off, with
    no options: it must succeed and write a consistent model that reproduces the parameters."""
    true = random_robot(seed, planar=planar, **size).load(tmp_path)
    prior = perturbed_prior(true, seed + 1)
    res = export_model(noise_free_identification(true, seed), prior)
    check_export(true, prior, res, tmp_path, rtol=1e-7)


def _noisy_export(seed, planar, tmp_path, **size):
    """Export of a noisy identification (each parameter off by its standard error, 1e-3 of its
    size plus 1e-6 of the largest) with no options: consistent, within the region it records."""
    true = random_robot(seed, planar=planar, **size).load(tmp_path)
    exact = noise_free_identification(true, seed)
    std = 1e-3 * np.abs(exact.values) + 1e-6 * np.abs(exact.values).max()
    values = exact.values + std * np.random.default_rng(seed).standard_normal(len(std))
    noisy = dataclasses.replace(exact, values=values, std=std, cov=np.diag(std**2))
    check_noisy_export(noisy, true, perturbed_prior(true, seed + 1), tmp_path)


def check_noisy_export(ident, true, prior, folder):
    """Export of the noisy identification ``ident`` of the robot ``true`` from ``prior`` with no options: a
    consistent model (it loads in Pinocchio and spaceid, every pseudo-inertia positive definite) that reproduces
    the estimate, or lies within the region it records (warnings aside: the fall-back to a region is tested
    with the presets)."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", UserWarning)
        res = export_model(ident, prior)
    write_export(res, folder / "noisy.urdf")
    pin.buildModelFromUrdf(str(folder / "noisy.urdf"), pin.JointModelFreeFlyer())
    for b in spaceid.load_model(folder / "noisy.urdf", planar=true.planar).bodies:
        assert np.linalg.eigvalsh(pseudo_inertia(b.inertial)).min() > 0, b.name
    if res.region is None:
        np.testing.assert_allclose(res.values, ident.values, rtol=0, atol=1e-8 * np.abs(ident.values).max())
    else:
        assert res.mahalanobis <= res.bound


def _export(seed, planar, noisy, tmp_path, *, larger=False):
    size = {"max_arms": 3, "max_joints": 4} if larger else {"max_arms": 2, "max_joints": 3 if planar else 2}
    with stage("export noisy" if noisy else "export noise-free", seed=seed, planar=planar, motion="random states"):
        (_noisy_export if noisy else _exact_export)(seed, planar, tmp_path, **size)


@FAST
@given(seed=SEEDS, planar=st.booleans(), noisy=st.booleans())
def test_export_without_options(seed, planar, noisy, tmp_path):
    _export(seed, planar, noisy, tmp_path)


@pytest.mark.slow
@pytest.mark.parametrize("seed, planar, noisy", [
    # the Newton polish amplified the round-off along a Jacobian direction of singular value 3e-20: a body
    (19, True, False),  # with a negative inertia eigenvalue was written as an exact fit
    (31, True, False),
    (114, False, True),  # linearised at the prior, the 0.95 ellipsoid reached no physical model
])
def test_export_regressions(seed, planar, noisy, tmp_path):
    _export(seed, planar, noisy, tmp_path)


@pytest.mark.slow
@SLOW
@given(seed=SEEDS, planar=st.booleans(), noisy=st.booleans())
# a 1-joint spatial robot: the restoring step towards the 0.95 ellipsoid raised the violation, and
# the export gave up on every automatic region although the true robot was inside the 0.95 one
@example(seed=1527, planar=False, noisy=True)
# spatial trees of 120 and 171 parameters: their noise-free estimates are realisable to their round-off only
# (2.9e-11 and 4.2e-12 of the largest parameter; 1.2e-9 and 1.5e-9 in the prior's units, the export's bound
# 1e-9), and the export fell back to the 0.95 ellipsoid
@example(seed=139731, planar=False, noisy=False)
@example(seed=161, planar=False, noisy=False)
# planar robots of 9 parameters (8 of 9 directions undetermined by the test's log): the steps met the conditions,
# then went on and stalled, and the export fell back on the 0.95 ellipsoid, 0.096 and 0.028 off the estimate
@example(seed=331, planar=True, noisy=False)
@example(seed=676, planar=True, noisy=False)
# spatial robots of 15 and 28 parameters: the steps within the 0.95 ellipsoid came within 1.002 and 2.1 of its
# radius, then walked out to 160 and 36 times it, and the export reported the last as within it
@example(seed=13652, planar=False, noisy=True)
@example(seed=252543, planar=False, noisy=True)
# a planar robot of 13 bodies and 121 parameters, the true robot inside the ellipsoids: Clarabel stopped on every
# main program (log-det objective, its 22 cones split into 55 chordal parts) on insufficient progress, and the export
# was refused; solved again with the cones whole (models._pseudo.WHOLE_CONES), exported
@example(seed=311720, planar=True, noisy=True)
# a spatial tree whose linearised conditions (231 x 176, singular values 7.0 to 1.7e-63) LAPACK's divide-and-conquer
# SVD did not converge on: a traceback; now decomposed by QR iteration (spaceid._svd)
@example(seed=1307800870, planar=False, noisy=False)
def test_export_without_options_on_larger_robots(seed, planar, noisy, tmp_path):
    _export(seed, planar, noisy, tmp_path, larger=True)
