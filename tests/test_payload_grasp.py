"""The payload after a grasp (spaceid.identified._grasp, 'spaceid payload --grasp'): the servicer's
momentum over the hold and its error carried into the payload's, a payload that moved at the grasp
and the error of the configuration that places it."""

import json
import warnings
from dataclasses import replace

import numpy as np
import pytest
from scipy.spatial.transform import Rotation
from click.testing import CliRunner
import spaceid
from spaceid.cli import app
from spaceid.data import Log, differentiate_log, write_log, yaw_to_quat
from spaceid.dynamics import body_states, system_com
from spaceid.estimation._uncertainty import correlation_length
from spaceid.identified import GraspMotion, hold_momentum, identify_payload, payload_after_grasp, payload_map
from spaceid.identified._grasp import _before_grasp, _configuration_at, _hold
from spaceid.models import inertial_vector
from spaceid.motion import FourierTrajectory, add_noise

PAYLOAD = (0.3, [0.05, 0.01], 7.8e-4)  # on Cepheus' end effector: mass, CoM in link2's frame, Izz about the CoM
TRUTH = np.array([PAYLOAD[0], *PAYLOAD[1], PAYLOAD[2]])
VELOCITY, RATE = np.array([0.04, -0.03, 0.0]), np.array([0.0, 0.0, 0.5])  # the payload's before the grasp


def _theta(mass, com, izz):
    c = np.asarray(com)
    return np.array([mass, *(mass * c), izz + mass * c @ c])


def _motion(pmap, duration, harmonics) -> FourierTrajectory:
    """A random excitation of the servicer's joints (seed 1, amplitudes up to 0.3 rad)."""
    rng = np.random.default_rng(1)
    shape = (pmap.param.model.n_joints, harmonics)
    return FourierTrajectory(pmap.param.model.joints, duration, rng.uniform(-0.3, 0.3, shape),
                             rng.uniform(-0.3, 0.3, shape))  # fmt: skip


@pytest.fixture(scope="module")
def cepheus():
    pmap = payload_map("cepheus", "link2")
    return pmap, _motion(pmap, 20.0, 3)


def _brought_by_sums(model, body, q, velocity, rate, mass, com, inertia):
    """The payload's momentum about the combined CoM, summed body by body (an independent check of
    the reduced-mass form): the servicer at rest (base rotation identity), the payload a point mass
    with spin (CoM ``com`` (3,) and inertia ``inertia`` (3, 3) about it in ``body``'s frame), the CoM
    moving at the payload's share of its momentum."""
    states = body_states(model, q[None], np.zeros((1, len(q))), np.zeros((1, 3)))
    rot, pos = states.rotation[0, body], states.position[0, body]
    r_p = pos + rot @ np.asarray(com, float)
    c_s = system_com(model, q[None])[0]
    total = model.mass + mass
    c, c_dot = (model.mass * c_s + mass * r_p) / total, mass * velocity / total
    spin = rot @ np.asarray(inertia, float) @ rot.T @ rate
    return spin + mass * np.cross(r_p - c, velocity - c_dot) + model.mass * np.cross(c_s - c, -c_dot)


def _planar_brought(pmap, q, velocity=VELOCITY):
    """:func:`_brought_by_sums` of ``PAYLOAD`` on Cepheus' link2 (its frame the body's)."""
    mass, com, izz = PAYLOAD
    return _brought_by_sums(pmap.param.model, pmap.body, q, velocity, RATE, mass, [*com, 0.0], np.diag([0, 0, izz]))


def test_hold_momentum_covariance_against_monte_carlo(cepheus):
    """The servicer's mean momentum over a few held samples: its covariance from the angle noise
    carried through the differentiator (errors correlated over the window: a few samples average
    little) against the spread over seeded noisy recordings."""
    pmap, traj = cepheus
    t = np.linspace(0, 4.0, 201)
    log = spaceid.simulate(pmap.param, pmap.pi(np.zeros(pmap.n)), traj, t, np.array([0, 0, 0.05]))
    middle = np.arange(95, 105)
    means, covs = [], []
    for seed in range(150):
        noisy = differentiate_log(add_noise(log, angle=1e-3, seed=seed), method="savgol", window=21, order=3)
        h, cov = hold_momentum(pmap, noisy.select(middle), spaceid.Noise())
        means.append(h[2])
        covs.append(cov[2, 2])
    ratio = np.std(means) / np.sqrt(np.median(covs))
    assert 0.85 < ratio < 1.15, ratio  # the std of a std over 150 seeds: ~6 %
    assert abs(np.mean(means) - 0.05) < 4 * np.std(means) / np.sqrt(150)
    # measured (white) rates: the noise model's levels, averaged over the samples
    white = add_noise(log, rate=1e-3, seed=0)
    h, cov = hold_momentum(pmap, white.select(middle), spaceid.Noise(rate=1e-3, base_rate=1e-3))
    spread = [hold_momentum(pmap, add_noise(log, rate=1e-3, seed=s).select(middle), spaceid.Noise())[0][2]
              for s in range(150)]  # fmt: skip
    assert 0.85 < np.std(spread) / np.sqrt(cov[2, 2]) < 1.15


@pytest.mark.slow  # fast representative: test_hold_momentum_covariance_against_monte_carlo
def test_spatial_hold_momentum_covariance_against_monte_carlo():
    """Spatial: the attitude's noise turns the momentum too (``R0 e_n`` in inertial axes)."""
    pmap = payload_map("satellite-7dof", "arm_ee")
    traj = _motion(pmap, 10.0, 2)
    h0 = np.array([0.5, -1.0, 2.0])
    log = spaceid.simulate(pmap.param, pmap.pi(np.zeros(pmap.n)), traj, np.linspace(0, 10, 101), h0)
    middle = np.arange(40, 50)
    noise = spaceid.Noise(angle=1e-3, rate=1e-3, base_rate=1e-3, attitude=1e-3)
    cov = hold_momentum(pmap, add_noise(log, angle=1e-3, rate=1e-3, seed=0).select(middle), noise)[1]
    spread = np.array([hold_momentum(pmap, add_noise(log, angle=1e-3, rate=1e-3, seed=s).select(middle), noise)[0]
                       for s in range(200)])  # fmt: skip
    ratio = spread.std(0) / np.sqrt(np.diag(cov))
    assert np.all((ratio > 0.85) & (ratio < 1.2)), ratio  # measured 1.03, 1.10, 1.07
    assert np.all(np.abs(spread.mean(0) - h0) < 4 * spread.std(0) / np.sqrt(200))


def _configuration_spread(pmap, log, grasp, noisy, noise, seeds=150) -> tuple:
    """Over seeded recordings ``noisy(seed)`` of ``log``: the configuration at ``grasp`` ``[q, phi]``
    (``phi`` the attitude's error, base axes; planar the yaw's) and the hold's momentum, their
    spread ``(seeds, 3 + n_c)`` and the median of their predicted covariance."""
    values, covs = [], []
    exact = _configuration_at(log, grasp, pmap.planar)[1]  # the attitude at the grasp without noise
    for seed in range(seeds):
        rec = noisy(seed)
        config = _configuration_at(rec, grasp, pmap.planar)
        hold = _hold(rec, grasp, correlation_length(rec) / 2 * np.median(np.diff(rec.t)), "log")
        h, cov = _before_grasp(pmap, rec, hold, config, noise)
        phi = Rotation.from_matrix(exact.T @ config[1]).as_rotvec()
        values.append([*h, *config[0], *(phi[2:] if pmap.planar else phi)])
        covs.append(cov)
    return np.array(values), np.median(covs, axis=0)


# fast representatives: test_hold_momentum_covariance_against_monte_carlo,
# test_configuration_covariance_is_carried_through_the_fit
@pytest.mark.slow
@pytest.mark.parametrize("differentiated", [True, False])
def test_configuration_at_the_grasp_covariance_against_monte_carlo(cepheus, differentiated):
    """The configuration that places a moving payload, each angle and the yaw from its last sample
    clear of the grasp carried by its rate there, and the hold's momentum: their covariance from
    the angle noise through the differentiators (the smoothed angle and rate of one sample; the
    yaw's rate shares its raw samples with the hold's base rates, so the two errors correlate)
    against the spread over seeded recordings; and with measured (white) rates."""
    pmap, traj = cepheus
    log = spaceid.simulate(pmap.param, pmap.pi(np.zeros(pmap.n)), traj, np.linspace(0, 20, 401), np.array([0, 0, 0.3]))
    grasp, z = 10.013, [2, 3, 4, 5]  # the momentum's z, the two joints, the yaw
    noise = spaceid.Noise() if differentiated else spaceid.Noise(angle=1e-3, rate=2e-3, base_rate=2e-3, attitude=1e-3)

    def noisy(seed):
        if differentiated:  # the rates from the angles: the filters' noise, no white level
            return differentiate_log(add_noise(log, angle=1e-3, seed=seed), method="savgol", window=21, order=3)
        return add_noise(log, angle=1e-3, rate=2e-3, seed=seed)

    values, cov = _configuration_spread(pmap, log, grasp, noisy, noise)
    cov = cov[np.ix_(z, z)]
    spread = np.cov(values[:, z].T)
    ratio = np.sqrt(np.diag(spread) / np.diag(cov))
    assert np.all((ratio > 0.85) & (ratio < 1.15)), ratio  # the std of a std over 150 seeds: ~6 %; 0.95 to 1.04
    fisher = lambda c: np.arctanh(c[0, 3] / np.sqrt(c[0, 0] * c[3, 3]))  # noqa: E731  the momentum's with the yaw's
    assert abs(fisher(spread) - fisher(cov)) < 3 / np.sqrt(147), (spread, cov)  # differentiated: 0.88 (both)
    rec = noisy(0)  # the joint covariance's momentum block is the hold's alone
    hold = _hold(rec, grasp, 0.0, "log")
    np.testing.assert_allclose(_before_grasp(pmap, rec, hold, _configuration_at(rec, grasp, True), noise)[1][:3, :3],
                               hold_momentum(pmap, rec.select(hold), noise)[1], rtol=1e-12, atol=1e-20)  # fmt: skip


# fast representatives: test_hold_momentum_covariance_against_monte_carlo,
# test_configuration_covariance_is_carried_through_the_fit
@pytest.mark.slow
def test_spatial_configuration_at_the_grasp_covariance_against_monte_carlo():
    """Spatial, measured rates: the attitude's error (a small rotation, base axes) from the
    attitude's and the base rate's noise carried over a step to the grasp."""
    pmap = payload_map("satellite-7dof", "arm_ee")
    log = spaceid.simulate(pmap.param, pmap.pi(np.zeros(pmap.n)), _motion(pmap, 10.0, 2), np.linspace(0, 10, 101),
                           np.array([0.5, -1.0, 2.0]))  # fmt: skip
    noise = spaceid.Noise(angle=1e-3, rate=5e-3, base_rate=5e-3, attitude=1e-3)
    values, cov = _configuration_spread(pmap, log, 5.099, lambda s: add_noise(log, angle=1e-3, rate=5e-3, seed=s),
                                        noise, seeds=200)  # fmt: skip
    ratio = values[:, 3:].std(0) / np.sqrt(np.diag(cov)[3:])
    assert np.all((ratio > 0.85) & (ratio < 1.15)), ratio


def test_given_momentum_covariance_is_carried_through_the_fit(cepheus):
    """The covariance added for a given momentum's error is ``g sigma^2 g^T``, ``g`` the estimate's
    derivative in the momentum: checked against central differences of whole fits."""
    pmap, traj = cepheus
    theta, h = _theta(*PAYLOAD), np.array([0, 0, 0.05])
    log = spaceid.simulate(pmap.param, pmap.pi(theta), traj, np.linspace(0, 20, 200), h, model=pmap.model(theta))
    noise = spaceid.Noise(angle=1e-5, rate=1e-5, base_rate=1e-5)
    step = 1e-6
    g = (identify_payload(pmap, log, "link2", h + [0, 0, step], noise=noise).values
         - identify_payload(pmap, log, "link2", h - [0, 0, step], noise=noise).values) / (2 * step)
    plain = identify_payload(pmap, log, "link2", h, noise=noise)
    sigma = 2e-4
    carried = identify_payload(pmap, log, "link2", h, noise=noise, momentum_cov=np.diag([0, 0, sigma**2]))
    np.testing.assert_allclose(carried.cov - plain.cov, sigma**2 * np.outer(g, g), rtol=1e-4,
                               atol=1e-6 * np.abs(np.outer(g, g)).max() * sigma**2)  # fmt: skip
    assert carried.settings["momentum_std"] == pytest.approx([sigma])
    assert np.all(carried.std > plain.std)


def test_configuration_covariance_is_carried_through_the_fit(cepheus):
    """A moving payload's configuration error moves the momentum it brings: the covariance added is
    ``G C G^T`` plus the cross terms with the given momentum's error, ``G`` the estimate's
    derivative in the configuration, checked against central differences of whole fits; a payload
    at rest brings no momentum, and its configuration's error adds nothing."""
    pmap, traj = cepheus
    theta, h = _theta(*PAYLOAD), np.array([0, 0, 0.02])
    q0 = traj.evaluate(np.zeros(1))[0][0]
    log = spaceid.simulate(pmap.param, pmap.pi(theta), traj, np.linspace(0, 20, 200), h + _planar_brought(pmap, q0),
                           model=pmap.model(theta))  # fmt: skip
    noise = spaceid.Noise(angle=1e-5, rate=1e-5, base_rate=1e-5)
    motion = GraspMotion(VELOCITY, RATE, q0, np.eye(3))

    def fit(dh=0.0, dc=np.zeros(3), momentum_cov=None, **kwargs):
        moved = replace(motion, q=q0 + dc[:2], rotation=Rotation.from_rotvec([0, 0, dc[2]]).as_matrix(), **kwargs)
        return identify_payload(pmap, log, "link2", h + [0, 0, dh], grasp_motion=moved, noise=noise,
                                momentum_cov=momentum_cov)  # fmt: skip

    step = 1e-6
    g = np.stack([(fit(dc=step * e).values - fit(dc=-step * e).values) / (2 * step) for e in np.eye(3)], -1)
    g_h = (fit(dh=step).values - fit(dh=-step).values) / (2 * step)
    c = np.diag([1e-6, 4e-6, 9e-6]) + 1e-6  # the joints' and the yaw's [rad^2]
    cross = np.array([[0, 0, 0], [0, 0, 0], [1e-7, -2e-7, 1.5e-7]])  # the momentum's z with them [N m s rad]
    given = np.diag([0, 0, 4e-8])  # the momentum's [(N m s)^2]
    plain, carried = fit(momentum_cov=given), fit(momentum_cov=given, cov=c, momentum_cross=cross)
    both = np.column_stack([g_h, g])
    joint = np.block([[np.array([[4e-8]]), cross[2:]], [cross[2:].T, c]])
    expected = both @ joint @ both.T - 4e-8 * np.outer(g_h, g_h)
    np.testing.assert_allclose(carried.cov - plain.cov, expected, rtol=1e-4, atol=1e-6 * np.abs(expected).max())
    assert plain.settings["payload_momentum_std"] is None and carried.settings["payload_momentum_std"][2] > 0
    # at rest: the configuration does not enter
    rest = [identify_payload(pmap, log, "link2", h, noise=noise, grasp_motion=GraspMotion(np.zeros(3), np.zeros(3), q0,
                                                                                          np.eye(3), cov))
            for cov in (None, c)]  # fmt: skip
    np.testing.assert_array_equal(rest[1].cov, rest[0].cov)
    with pytest.raises(spaceid.SpaceidError, match=r"`grasp_motion.cov`: shape \(2, 2\), expected \(3, 3\)"):
        fit(cov=np.eye(2))


def test_moving_payload_recovered_noise_free_with_its_momentum(cepheus):
    """A payload that moved at the grasp: its momentum joins the servicer's. Given its velocity and
    rate it is a function of its parameters (recovered to 1e-8); unknown, it is estimated with
    them, here identifiable (the known servicer fixes the scale)."""
    pmap, traj = cepheus
    theta = _theta(*PAYLOAD)
    q0 = traj.evaluate(np.zeros(1))[0][0]
    h_servicer = np.array([0, 0, 0.02])
    brought = _planar_brought(pmap, q0)
    log = spaceid.simulate(pmap.param, pmap.pi(theta), traj, np.linspace(0, 20, 200), h_servicer + brought,
                           model=pmap.model(theta))  # fmt: skip
    motion = GraspMotion(VELOCITY, RATE, q0, np.eye(3))
    est = identify_payload(pmap, log, "link2", h_servicer, grasp_motion=motion, noise=spaceid.Noise())
    np.testing.assert_allclose(est.values, TRUTH, rtol=1e-8, atol=1e-12)
    np.testing.assert_allclose(est.settings["payload_momentum"], brought, rtol=1e-8, atol=1e-12)
    # the motion ignored: the fit is off (the test can fail; its estimate, far off, is projected inexactly)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", UserWarning)
        off = identify_payload(pmap, log, "link2", h_servicer, noise=spaceid.Noise())
    assert abs(off.mass - PAYLOAD[0]) > 1e-3
    unknown = identify_payload(pmap, log, "link2", None, noise=spaceid.Noise())
    np.testing.assert_allclose(unknown.values, TRUTH, rtol=1e-8, atol=1e-12)
    np.testing.assert_allclose(unknown.momentum, h_servicer + brought, rtol=1e-8, atol=1e-14)
    assert 0 < unknown.settings["momentum_payload_correlation"] < 1
    with pytest.raises(spaceid.SpaceidError, match="estimated with the payload"):
        identify_payload(pmap, log, "link2", None, grasp_motion=motion)


def test_spatial_moving_payload_recovered_noise_free_with_its_momentum():
    """A payload moving in 3D (velocity off the plane, rate about a tilted axis) grasped by a spatial
    servicer: recovered to 1e-8, its momentum the body-by-body sum's."""
    pmap = payload_map("satellite-7dof", "arm_link7")
    traj = _motion(pmap, 15.0, 3)
    mass, com = 20.0, np.array([0.05, -0.03, 0.3])
    inertia = np.diag([2.0, 2.5, 1.5]) + 0.1 * np.ones((3, 3))
    velocity, rate = np.array([0.04, -0.03, 0.02]), np.array([0.1, -0.2, 0.3])
    q0 = traj.evaluate(np.zeros(1))[0][0]
    h_servicer = np.array([0.5, -1.0, 2.0])
    brought = _brought_by_sums(pmap.param.model, pmap.body, q0, velocity, rate, mass, com, inertia)
    theta = inertial_vector(mass, com, inertia)
    log = spaceid.simulate(pmap.param, pmap.pi(theta), traj, np.linspace(0, 15, 120), h_servicer + brought,
                           model=pmap.model(theta))  # fmt: skip
    est = identify_payload(pmap, log, "arm_link7", h_servicer, grasp_motion=GraspMotion(velocity, rate, q0, np.eye(3)),
                           noise=spaceid.Noise())  # fmt: skip
    assert est.mass == pytest.approx(mass, rel=1e-8)
    np.testing.assert_allclose(est.com, com, atol=1e-8)
    np.testing.assert_allclose(est.inertia, inertia, atol=1e-8 * np.abs(inertia).max())
    np.testing.assert_allclose(est.settings["payload_momentum"], brought, rtol=1e-8, atol=1e-10)
    with warnings.catch_warnings():  # the motion ignored: the fit is off (its estimate projected inexactly)
        warnings.simplefilter("ignore", UserWarning)
        off = identify_payload(pmap, log, "arm_link7", h_servicer, noise=spaceid.Noise())
    assert abs(off.mass - mass) > 1e-3 * mass


def test_moving_payload_placed_at_the_grasp_instant_of_a_turning_base(cepheus):
    """The servicer spins before the grasp (joints still, base turning) and the grasp falls between
    samples: the configuration that places the moving payload is the one at the grasp instant,
    from the last samples that the differentiators' smear of the grasp does not reach, carried to
    it by their rates. The sample before it, 0.03 s earlier with the base at 1.7 rad/s, turned the
    lever arm: the mass 0.6 % off, Izz 6 %."""
    pmap, traj = cepheus
    theta, h_servicer = _theta(*PAYLOAD), np.array([0, 0, 0.3])
    q0 = traj.evaluate(np.zeros(1))[0][0]
    spin = pmap.param.momentum(q0[None], np.zeros((1, q0.size)), np.array([[0, 0, 1.0]]), pmap.pi(np.zeros(4)))
    w0 = h_servicer[2] / spin.item()  # the servicer turning rigidly with its momentum
    after = spaceid.simulate(pmap.param, pmap.pi(theta), traj, np.r_[0, 0.002 + 0.05 * np.arange(100)],
                             h_servicer + _planar_brought(pmap, q0), model=pmap.model(theta))  # fmt: skip
    grasp = 1.0
    before = grasp - 0.03 - 0.05 * np.arange(20)[::-1]  # the grasp 0.03 s after the last sample before it
    n = before.size
    log = Log(np.r_[before, grasp + after.t[1:]], after.joints, np.r_[np.repeat(q0[None], n, 0), after.q[1:]],
              np.r_[np.zeros((n, q0.size)), after.qd[1:]],
              np.r_[yaw_to_quat(w0 * (before - grasp)), after.base_quat[1:]],
              np.r_[np.tile([0, 0, w0], (n, 1)), after.base_w[1:]], planar=True)  # fmt: skip
    est = payload_after_grasp(pmap, log, "link2", grasp, h_servicer, payload_motion=(VELOCITY, RATE),
                              noise=spaceid.Noise()).estimate  # fmt: skip
    np.testing.assert_allclose(est.values, TRUTH, rtol=1e-8)  # 0.6 % and 6 % off from the sample before
    assert est.settings["grasp"]["payload_motion"]["configuration_from"] == pytest.approx([0.97] * (q0.size + 1))
    # differentiated: the samples whose windows (joints 0.1 s, base 0.3 s) hold the grasp are smeared
    near = lambda half: (log.t > grasp - half) & (log.t < grasp)  # noqa: E731
    smeared = replace(log, q=log.q + 0.01 * near(0.05)[:, None],
                      base_quat=np.where(near(0.15)[:, None], yaw_to_quat(np.full(n + 100, 0.5)), log.base_quat))
    per_joint = {j: {"method": "savgol", "window_s": [0.1]} for j in log.joints}  # a bag's; differentiate_log's:
    for joints in (per_joint, {"method": "savgol", "window_s": [0.1] * q0.size}):
        meta = {"differentiation": {"base": {"method": "savgol", "window_s": [0.3]}, "joints": joints}}
        est = payload_after_grasp(pmap, replace(smeared, meta=meta), "link2", grasp, h_servicer,
                                  payload_motion=(VELOCITY, RATE), noise=spaceid.Noise()).estimate  # fmt: skip
        np.testing.assert_allclose(est.values, TRUTH, rtol=1e-6)
        assert est.settings["grasp"]["payload_motion"]["configuration_from"] == pytest.approx([0.92] * q0.size + [0.82])


def test_an_estimated_momentum_collinear_with_the_payload_warns(cepheus):
    """A base that turns steadily (a large momentum) makes the payload's own momentum nearly a
    constant: estimated, the momentum trades off with the payload, and the fit says so."""
    pmap, traj = cepheus
    theta = _theta(*PAYLOAD)
    for h, collinear in ((0.5, True), (0.02, False)):
        log = spaceid.simulate(pmap.param, pmap.pi(theta), traj, np.linspace(0, 20, 200), np.array([0, 0, h]),
                               model=pmap.model(theta))  # fmt: skip
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            est = identify_payload(pmap, add_noise(log, angle=1e-4, rate=1e-4, seed=0), "link2", None)
        said = [str(w.message) for w in caught if "correlates with it" in str(w.message)]
        assert (est.settings["momentum_payload_correlation"] > 0.9) == collinear == bool(said), said


def _grasp_log(pmap, traj, hold: float, momentum_after, theta) -> tuple:
    """A servicer still for ``hold`` s (its momentum zero), then holding ``theta`` through ``traj``
    with ``momentum_after``; the grasp time."""
    after = spaceid.simulate(pmap.param, pmap.pi(theta), traj, np.linspace(0, 10, 201), momentum_after,
                             model=pmap.model(theta))  # fmt: skip
    n = int(hold / 0.05)
    t = np.r_[np.arange(n) * 0.05, n * 0.05 + after.t]
    still = lambda a: np.repeat(a[:1] * 0, n, 0)  # noqa: E731
    log = Log(t, after.joints, np.r_[np.repeat(after.q[:1], n, 0), after.q], np.r_[still(after.qd), after.qd],
              np.r_[np.repeat(after.base_quat[:1], n, 0), after.base_quat], np.r_[still(after.base_w), after.base_w],
              planar=True)  # fmt: skip
    return log, n * 0.05 - 0.01


def test_cli_grasp_cuts_the_log_and_takes_the_hold(cepheus, tmp_path):
    pmap, traj = cepheus
    theta = _theta(*PAYLOAD)
    q0 = traj.evaluate(np.zeros(1))[0][0]
    brought = _planar_brought(pmap, q0)
    log, grasp = _grasp_log(pmap, traj, 1.5, brought, theta)
    path, out = tmp_path / "servicing.csv", tmp_path / "payload.json"
    write_log(path, log)
    runner = CliRunner()
    noise = ["--noise-angle", "1e-6", "--noise-rate", "1e-6", "--noise-base-rate", "1e-6", "--noise-attitude", "2e-6"]
    args = ["payload", "cepheus", str(path), "--link", "link2", "--grasp", f"{grasp}", "--momentum", "hold",
            "--payload-velocity", "0.04,-0.03", "--payload-rate", "0.5", *noise, "-o", str(out)]
    res = runner.invoke(app, args)
    assert res.exit_code == 0, res.output
    data = json.loads(out.read_text())
    np.testing.assert_allclose([data["mass"], *data["com"][:2], data["inertia"][2][2]], TRUTH, rtol=1e-6)
    g = data["settings"]["grasp"]
    assert g["window"][0] > grasp and g["hold"]["samples"] >= 5 and g["hold"]["to"] < grasp
    assert abs(g["hold"]["momentum"][2]) < 1e-12 and g["payload_motion"]["rate"] == [0.0, 0.0, 0.5]
    assert data["settings"]["momentum_covariance"] is not None and "window" in res.output
    # measured signals: each angle (the yaw's 2e-6) and its rate's error carried 0.04 s to the grasp, white
    dt = grasp - g["payload_motion"]["configuration_from"][0]
    assert dt == pytest.approx(0.04) and g["payload_motion"]["configuration_from"] == [grasp - dt] * 3
    np.testing.assert_allclose(g["payload_motion"]["configuration_std"], 1e-6 * np.sqrt(np.r_[1, 1, 4] + dt**2))
    # the whole log without --grasp mixes the servicer alone with the payload: off
    whole = runner.invoke(app, args[:5] + ["--momentum", "0", *noise, "-o", str(tmp_path / "whole.json")])
    assert whole.exit_code == 0 and abs(json.loads((tmp_path / "whole.json").read_text())["mass"] - PAYLOAD[0]) > 1e-3
    # bad combinations: one line, exit 2
    bad = runner.invoke(app, args[:5] + ["--momentum", "hold", "-o", str(out)])
    assert bad.exit_code == 2 and "--momentum hold needs --grasp" in bad.output
    bad = runner.invoke(app, args[:7] + ["--momentum", "unknown", "--payload-rate", "1", "-o", str(out)])
    assert bad.exit_code == 2 and "need --grasp T and the servicer's --momentum" in bad.output
    bad = runner.invoke(app, args[:5] + ["--grasp", "99", "--momentum", "0", "-o", str(out)])
    assert bad.exit_code == 2 and "--grasp: 99 s is not inside" in bad.output


def test_grasp_window_leaves_out_the_differentiator_s_blend(cepheus):
    pmap, traj = cepheus
    log, grasp = _grasp_log(pmap, traj, 1.5, np.zeros(3), _theta(*PAYLOAD))
    rates = differentiate_log(add_noise(log, angle=1e-5, seed=0), method="savgol", window=11, order=3)
    cut = payload_after_grasp(pmap, rates, "link2", grasp, np.zeros(3))
    est, window = cut.estimate, cut.window
    margin = 5 * 0.05  # half the 11-sample window
    assert margin < window.t[0] - grasp <= margin + 0.05 + 1e-9
    assert cut.grasp["hold"] is None and "propagated" in est.settings["covariance"]
    assert cut.grasp["window"] == pytest.approx([window.t[0], window.t[-1]])
    assert cut.to_dict()["settings"]["grasp"] == cut.grasp
    z = (est.values - TRUTH) / est.std
    assert np.all(np.abs(z) < 4), z
    with pytest.raises(spaceid.SpaceidError, match="does not hold"):
        payload_after_grasp(pmap, rates.select(rates.t > 1.0), "link2", grasp, "hold")


def test_brought_momentum_matches_the_sums_in_a_turned_base(cepheus):
    """The reduced-mass form in a base turned about the vertical, against the body-by-body sum."""
    from spaceid.identified._payload import _brought_momentum

    pmap, traj = cepheus
    q0 = traj.evaluate(np.array([3.0]))[0][0]
    yaw = 0.7
    rot = np.array([[np.cos(yaw), -np.sin(yaw), 0], [np.sin(yaw), np.cos(yaw), 0], [0, 0, 1]])
    brought = _brought_momentum(pmap, GraspMotion(VELOCITY, RATE, q0, rot))(_theta(*PAYLOAD))
    # in base axes the payload moves with rot^T v; the spin is about the vertical either way
    expected = _planar_brought(pmap, q0, rot.T @ VELOCITY)
    np.testing.assert_allclose(brought, rot @ expected, rtol=1e-12, atol=1e-15)
