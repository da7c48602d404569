"""The inertial parameters of a payload rigidly held by a known servicer: :func:`identify_payload`
(docs/theory/payload.md).

With the servicer known, the momentum equations of a log after the capture have the payload's
standard parameters ``theta`` on its link as their only unknowns (with the momentum and drift
terms when those are estimated). They are not linear in ``theta``: zero linear momentum brings in
the lumped products ``theta_a theta_b / M`` whose total mass ``M`` holds the payload's. The
minimal parameters ``pi(theta) = P [theta_all, phi(theta_all)]`` of the whole system are smooth in
``theta``, so Gauss-Newton on ``Y pi(theta) = R0^T h`` (whitened by the errors-in-variables
covariance of each sample) starts from the payload-free linearisation (its first step solves the
first-order problem) and converges in a few steps. The known servicer fixes the scale: no anchor
is needed and a capture from rest works. A payload that moved at the grasp brings its own
momentum, a function of ``theta`` given its velocity and rate (:class:`GraspMotion`).

Planar motion sees only the mass, the in-plane CoM and the moment about the CoM's vertical axis.
An estimate that is not physically consistent (pseudo-inertia not positive definite) is projected
to the nearest consistent one in the metric of its covariance (a convex program, Clarabel); one
beyond the noise's reach of any (the data contradict a payload) has the step added to its
covariance.
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass, field, replace
from functools import partial

import numpy as np

from .._distributions import chi2_isf
from .._errors import SpaceidError
from .._threads import one_blas_thread
from ..data import Log, log_fingerprint, quat_to_matrix, read_json
from ..dynamics import (
    Parameterization,
    body_states,
    full_parameter_names,
    full_values,
    full_values_jacobian,
    minimal_parameters,
    system_com,
)
from ..estimation import Noise, drift_names, equation_covariance, noise_from_log, signal_sigma
from ..estimation.internal import (
    CONTRADICTED,
    SIGNIFICANCE,
    Equations,
    check_drift_kinds,
    check_excitation,
    correlation_length,
    at_given_levels,
    differentiated_series,
    drift_basis_at,
    larger_of,
    newey_west_covariance,
    noise_model_warning,
    propagated_covariance,
    WIDENED,
    ratios_of_columns,
    residual_checks,
    signal_levels,
    undetermined,
    undetermined_warning,
    widened,
)
from ..models import INERTIAL_NAMES, Model, link_frame, load_model
from ..models.internal import add_to_body, symbol_suffix
from ..models.internal import (CLARABEL_TOLERANCES, MARGIN, cone, conic_solution, inertial_from_pseudo, pseudo_inertia,
                               triangle)

__all__ = ["GraspMotion", "PayloadMap", "PayloadEstimate", "payload_map", "identify_payload", "project_consistent",
           "nominal_payload", "payload_units"]

SPATIAL_NAMES = ("m", "cx", "cy", "cz", "Ixx", "Ixy", "Iyy", "Ixz", "Iyz", "Izz")
"""The payload's physical parameters: mass [kg], CoM in LINK's frame [m], inertia about the CoM
in LINK's axes [kg m^2] (``INERTIAL_NAMES`` order)."""
PLANAR_NAMES = ("m", "cx", "cy", "Izz")
PLANAR_SLOTS = (0, 1, 2, 9)
"""Entries of the standard vector ``[m, mcx, mcy, mcz, Ixx, Ixy, Iyy, Ixz, Iyz, Izz]`` that a
planar motion sees (the z row of the momentum)."""
NOT_PLANAR = ("cz", "Ixx", "Ixy", "Iyy", "Ixz", "Iyz")


def payload_units(names) -> tuple:
    """The unit of each payload parameter of ``names`` (of ``SPATIAL_NAMES``): ``kg`` for the
    mass ``m``, ``m`` for the CoM ``cx, cy, cz``, ``kg m^2`` for the inertia."""
    return tuple("kg" if n == "m" else "m" if n in ("cx", "cy", "cz") else "kg m^2" for n in names)


COLLINEAR = 0.9
"""An estimated momentum whose correlation with a payload parameter exceeds this brings a warning:
that parameter's standard error is then over twice what a known momentum gives (``1 / sqrt(1 -
0.9^2)``), and the rates' systematic errors are amplified alike (on the Cepheus twin, at 0.94, the
mass came out 1 % low, 1.5 standard errors)."""
MAX_STEPS = 50
STEP_TOL = 1e-12
"""Relative change within round-off: Gauss-Newton stops when a step moves the column-scaled unknowns by less, or
lowers the cost by less (no progress); a step that raises the cost by less is still taken."""


# ---------------------------------------------------------------- the link and the map --------


def _frame_transform(rotation, translation) -> np.ndarray:
    """Map ``(10, 10)`` of standard parameters about a frame to those about the body frame that
    holds it at ``(rotation, translation)``: pseudo-inertias transform as ``X J X^T``."""
    x = np.eye(4)
    x[:3, :3], x[:3, 3] = rotation, translation
    return np.stack([inertial_from_pseudo(x @ pseudo_inertia(e) @ x.T) for e in np.eye(10)], -1)


@dataclass(frozen=True)
class PayloadMap:
    """How the payload's parameters enter the servicer's minimal parameters.

    Attributes
    ----------
    param : Parameterization
        Minimal set of the servicer (its holding body's declared zeros cleared: the payload has
        none).
    link : str
        The link that holds the payload.
    body : int
        Index of the servicer body that carries ``link``.
    transform : ndarray of shape (10, n)
        The body's standard parameters (about its frame origin) per unit of the unknowns: the
        payload's standard parameters in ``link``'s frame, all ten (spatial) or ``m, mcx, mcy,
        Izz`` about the link origin (planar).
    """

    param: Parameterization
    link: str
    body: int
    transform: np.ndarray
    _columns: np.ndarray = field(repr=False, default=None)

    @property
    def planar(self) -> bool:
        return self.param.model.planar

    @property
    def n(self) -> int:
        return self.transform.shape[1]

    def model(self, theta) -> Model:
        """The servicer holding the payload ``theta (n,)`` (zero too: no payload)."""
        return add_to_body(self.param.model, self.body, self.transform @ np.asarray(theta, float))

    def pi(self, theta) -> np.ndarray:
        """Minimal parameters ``(k,)`` of the servicer holding the payload ``theta``."""
        return self.param.projection @ full_values(self.model(theta))

    def columns(self, theta) -> np.ndarray:
        """``d pi / d theta`` ``(k, n)`` at ``theta``."""
        return self.param.projection @ (full_values_jacobian(self.model(theta))[:, self._columns] @ self.transform)

    def standard(self, theta) -> np.ndarray:
        """The payload's ten standard parameters in ``link``'s frame (planar: zeros where unseen)."""
        out = np.zeros(10)
        out[list(PLANAR_SLOTS) if self.planar else slice(None)] = theta
        return out


def payload_map(model, link: str, *, seed: int = 0) -> PayloadMap:
    """The :class:`PayloadMap` of a payload on ``link`` of the servicer ``model``.

    Parameters
    ----------
    model : Model or str or Path
        The known servicer (a preset, URDF or YAML).
    link : str
        A body of the model, or (URDF models) a link on fixed joints below one.
    seed : int
        Seed of the minimal set's random states (``minimal_parameters``).

    Raises
    ------
    SpaceidError
        ``link`` is not a link of the model, or (planar) its z axis is not the base z axis.
    """
    model = load_model(model)
    body, rotation, translation = link_frame(model, link, "`link`")
    if model.planar and not abs(rotation[2, 2] - 1) < 1e-9:
        raise SpaceidError(f"`link`: the frame of '{link}' is tilted out of the plane: a planar payload needs its z "
                           "axis along the base z axis (identify it with the spatial model)")
    bodies = list(model.bodies)
    bodies[body] = replace(bodies[body], known_zero=frozenset())  # the payload's moments are not zero
    model = replace(model, bodies=tuple(bodies))
    transform = _frame_transform(rotation, translation)
    if model.planar:
        transform = transform[:, list(PLANAR_SLOTS)]
    names = full_parameter_names(model)
    suffix = symbol_suffix(model.bodies[body].name)
    columns = np.array([names.index(f"{n}_{suffix}") for n in INERTIAL_NAMES])
    return PayloadMap(minimal_parameters(model, seed=seed), link, body, transform, columns)


# ---------------------------------------------------------------- physical parameters ----------


def _physical(theta, planar: bool) -> np.ndarray:
    """Mass, CoM and inertia about the CoM (``SPATIAL_NAMES`` or ``PLANAR_NAMES``) of standard
    parameters about the link origin."""
    theta = np.asarray(theta, float)
    m, h = theta[0], theta[1:3] if planar else theta[1:4]
    c = h / m
    if planar:
        return np.array([m, *c, theta[3] - m * (c @ c)])
    inertia = np.array([[theta[4], theta[5], theta[7]], [theta[5], theta[6], theta[8]], [theta[7], theta[8], theta[9]]])
    i_com = inertia - m * (c @ c * np.eye(3) - np.outer(c, c))
    return np.array([m, *c, i_com[0, 0], i_com[0, 1], i_com[1, 1], i_com[0, 2], i_com[1, 2], i_com[2, 2]])


def _physical_jacobian(theta, planar: bool) -> np.ndarray:
    """``d _physical / d theta`` (:func:`_central_jacobian`)."""
    return _central_jacobian(lambda t: _physical(t, planar), theta)


def _central_jacobian(f, theta) -> np.ndarray:
    """``d f / d theta`` ``(m, n)`` of a smooth ``f: (n,) -> (m,)`` by central differences of step 1e-6
    of each entry's scale (the payload's maps are rational and smooth away from zero mass: errors
    ~1e-10 relative), 1e-6 where ``theta`` is zero."""
    theta = np.asarray(theta, float)
    step = 1e-6 * np.maximum(np.abs(theta), 1e-6 * np.abs(theta).max())
    step[step == 0] = 1e-6  # at zero (the payload fit's start) an absolute step
    cols = [(f(theta + s * e) - f(theta - s * e)) / (2 * s) for s, e in zip(step, np.eye(len(theta)))]
    return np.stack(cols, -1)


def _matrix(six) -> list:
    """The symmetric 3 x 3 matrix of ``[xx, xy, yy, xz, yz, zz]``."""
    xx, xy, yy, xz, yz, zz = six
    return [[xx, xy, xz], [xy, yy, yz], [xz, yz, zz]]


def _lmi(theta, planar: bool):
    """The matrix that is positive definite exactly when ``theta`` is consistent: the
    pseudo-inertia (spatial) or, planar,
    ``[[m, mcx, mcy], [mcx, Izz, 0], [mcy, 0, Izz]]`` (positive mass, ``Izz`` about the CoM
    positive)."""
    if planar:
        return [[theta[0], theta[1], theta[2]], [theta[1], theta[3], 0], [theta[2], 0, theta[3]]]
    return pseudo_inertia(theta)


def _lmi_basis(planar: bool, n: int) -> np.ndarray:
    """``_lmi`` of the unit vectors, ``(n, d, d)``: it is linear in ``theta``."""
    return np.array([np.array(_lmi(e, planar), float) for e in np.eye(n)])


def project_consistent(theta, cov, planar: bool) -> tuple:
    """The physically consistent standard parameters nearest to ``theta`` in the metric of ``cov``.

    Minimises ``(t - theta)^T cov^-1 (t - theta)`` over ``t`` whose pseudo-inertia (spatial; planar:
    ``[[m, mcx, mcy], [mcx, Izz, 0], [mcy, 0, Izz]]``) is positive semidefinite with a margin of
    ``MARGIN`` times its largest eigenvalue at ``theta`` (Clarabel).

    Parameters
    ----------
    theta : array_like of shape (n,)
        Standard parameters about the link origin: all ten (spatial) or ``m, mcx, mcy, Izz``.
    cov : array_like of shape (n, n)
        Their covariance (a singular one is floored at 1e-12 of its largest eigenvalue).
    planar : bool

    Returns
    -------
    (ndarray of shape (n,), float)
        The consistent parameters (``theta`` itself when already consistent) and the Mahalanobis
        distance moved.
    """
    theta = np.asarray(theta, float)
    basis = _lmi_basis(planar, len(theta))
    lmi = np.einsum("i,ijk->jk", theta, basis)
    eig = np.linalg.eigvalsh(lmi)
    margin = MARGIN * max(abs(eig).max(), np.finfo(float).tiny)
    if eig[0] >= margin:
        return theta, 0.0
    with one_blas_thread():
        w, v = np.linalg.eigh(np.asarray(cov, float))
    top = max(w.max(), np.finfo(float).tiny)
    # a covariance spanning many decades can defeat the solver: its smallest directions floored higher,
    # then Clarabel's default tolerances (the tight ones first)
    for floor, options in ((1e-12, CLARABEL_TOLERANCES), (1e-12, {}), (1e-8, CLARABEL_TOLERANCES), (1e-8, {})):
        root = v * np.sqrt(np.maximum(w, floor * top) / top)  # cov / top = root root^T: a scale leaves the nearest
        # whitened step z: t = theta + root z, so the objective is |z|^2 (times top), and the LMI is affine in z
        z, status = _least_step_inside(lmi - margin * np.eye(len(lmi)), np.einsum("ij,ikl->jkl", root, basis), options)
        if z is not None:
            break
    else:
        raise SpaceidError(f"payload: the consistency projection failed ({status}): check the log and `link`")
    return theta + root @ z, float(np.linalg.norm(z) / np.sqrt(top))


def _least_step_inside(offset, directions, options: dict) -> tuple:
    """``(z, status)``: the ``z (k,)`` of least norm with ``offset + sum_j z_j directions[j]`` positive semidefinite
    (``offset (d, d)``, ``directions (k, d, d)``, symmetric), or None when Clarabel found none, and its status in
    words; ``options`` its settings (:func:`~spaceid.models._conic.conic_solution`: through cvxpy the projection
    took a second more, the import of cvxpy's atoms, SciPy's statistics among them, on every payload that needed
    it)."""
    d, k = len(offset), len(directions)
    i, j, weight = triangle(d)
    # min z^T z (Clarabel's 1/2 x^T P x) subject to s = b - A z in the cone: A = -directions, b = offset
    return conic_solution(2.0 * np.eye(k), np.zeros(k), [(-(directions[:, i, j] * weight).T, offset[i, j] * weight,
                                                          cone("psd", d))], options)  # fmt: skip


# ---------------------------------------------------------------- the estimate ------------------


@dataclass(frozen=True)
class PayloadEstimate:
    """The payload's identified inertial parameters (PAYLOAD.json, docs/formats/payload-json.md).

    Attributes
    ----------
    link : str
        The link that holds the payload; ``com`` and ``inertia`` are in its frame.
    names : tuple of str
        The identified physical parameters, ``SPATIAL_NAMES`` or ``PLANAR_NAMES``.
    values, std : ndarray of shape (n,)
        Their (consistent) estimates and standard errors [kg, m, kg m^2].
    cov : ndarray of shape (n, n)
        Their covariance (of the unconstrained estimate, to first order; with the consistency
        projection's step added where that estimate lay beyond the noise's reach of any physical
        payload).
    standard : ndarray of shape (10,)
        The estimate's standard parameters about the link origin (planar: zeros where unseen).
    not_identifiable : tuple of str
        Physical parameters the motion cannot see (planar: ``NOT_PLANAR``).
    momentum : ndarray of shape (3,)
        Inertial momentum [N m s] (estimated when not given; at the first sample with drift).
    drift : tuple of dict
        Drift coefficients ``{name, value, std, unit}`` estimated with the payload.
    settings : dict
        Estimator, noise model, convergence, consistency projection, seed, log provenance.
    """

    link: str
    names: tuple
    values: np.ndarray
    std: np.ndarray
    cov: np.ndarray
    standard: np.ndarray
    not_identifiable: tuple
    momentum: np.ndarray
    drift: tuple
    settings: dict

    @property
    def mass(self) -> float:
        return float(self.values[0])

    @property
    def com(self) -> np.ndarray:
        """CoM [m] in the link frame (planar: z NaN, not identifiable)."""
        return np.array([*self.values[1:3], np.nan]) if len(self.names) == 4 else self.values[1:4].copy()

    @property
    def inertia(self) -> np.ndarray:
        """Inertia about the CoM, link axes [kg m^2], ``(3, 3)`` (planar: Izz only, the rest NaN)."""
        if len(self.names) == 4:
            out = np.full((3, 3), np.nan)
            out[2, 2] = self.values[3]
            return out
        return np.array(_matrix(self.values[4:]))

    def plot(self, fig=None, *, true=None):
        """Draw the estimate with one standard error, a panel per parameter, against ``true`` when
        given (:func:`spaceid.studies.plot_payload`), and return the :class:`matplotlib.figure.Figure`.

        Parameters
        ----------
        fig : matplotlib.figure.Figure or SubFigure, optional
            Draw into it (one row of panels); default: a new figure.
        true : dict or array_like, optional
            The true values [kg, m, kg m^2], by name (``{"m": 0.5, ...}``) or in ``names`` order:
            drawn as lines, with the z-scores in the panels' titles.
        """
        from ._plots import draw_payload, _rows

        return draw_payload(_rows(self, true), self.link, fig)

    def to_dict(self) -> dict:
        """The PAYLOAD.json object."""
        std = dict(zip(self.names, self.std))
        planar = len(self.names) == 4
        return {
            "link": self.link,
            "mass": self.mass,
            "com": self.com.tolist(),
            "inertia": self.inertia.tolist(),
            "std": {"mass": std["m"], "com": [std["cx"], std["cy"], None if planar else std["cz"]],
                    "inertia": [[None] * 3, [None] * 3, [None, None, std["Izz"]]] if planar else
                    _matrix([std[n] for n in SPATIAL_NAMES[4:]])},
            "covariance": {"names": list(self.names), "matrix": self.cov.tolist()},
            "standard_parameters": dict(zip(INERTIAL_NAMES, self.standard.tolist())),
            "not_identifiable": list(self.not_identifiable),
            "planar": planar,
            "momentum": self.momentum.tolist(),
            "drift": list(self.drift),
            "units": {"mass": "kg", "com": "m", "inertia": "kg m^2", "momentum": "N m s",
                      "standard_parameters": "kg, kg m, kg m^2 (about the link origin, link axes)"},
            "settings": self.settings,
        }


@dataclass(frozen=True)
class GraspMotion:
    """How a payload moved just before the grasp, and where the servicer was then: with them the
    momentum that the payload brings is a function of its parameters (docs/theory/payload.md).

    Attributes
    ----------
    velocity : ndarray of shape (3,)
        Velocity of the payload's CoM relative to the servicer's CoM (the servicer's linear momentum
        is zero), inertial axes [m/s].
    rate : ndarray of shape (3,)
        The payload's angular velocity, inertial axes [rad/s].
    q : ndarray of shape (n_joints,)
        The servicer's joint positions at the grasp [rad or m].
    rotation : ndarray of shape (3, 3)
        Its base-to-inertial rotation at the grasp.
    cov : ndarray of shape (n_c, n_c), optional
        Covariance of the configuration's error ``c = [q, phi]`` [rad^2 or m^2], ``phi`` a small
        rotation in base axes (``rotation exp([phi]x)``; planar: its z component, the yaw), so
        ``n_c = n_joints + 3`` (planar ``n_joints + 1``): carried into the payload's covariance
        through the momentum it brings.
    momentum_cross : ndarray of shape (3, n_c), optional
        Covariance of the given momentum's error (``momentum_cov`` of
        :func:`identify_payload`) with the configuration's: both from the samples before the grasp.
    """

    velocity: np.ndarray
    rate: np.ndarray
    q: np.ndarray
    rotation: np.ndarray
    cov: np.ndarray | None = None
    momentum_cross: np.ndarray | None = None


def _brought_momentum(pmap: PayloadMap, motion: GraspMotion):
    """``theta -> (3,)``: the inertial angular momentum [N m s] about the combined CoM that the
    payload ``theta`` brings when it moves as ``motion``: its spin ``R I_c R^T w`` about its CoM
    and the orbital ``mu (r_p - c_s) x v`` of the two CoMs (``mu = m_s m / (m_s + m)`` the reduced
    mass, ``r_p - c_s`` from the servicer's CoM to the payload's)."""
    model = pmap.param.model
    q = np.asarray(motion.q, float)[None]
    states = body_states(model, q, np.zeros_like(q), np.zeros((1, 3)))
    rot = motion.rotation @ states.rotation[0, pmap.body]  # holding body to inertial
    origin = motion.rotation @ (states.position[0, pmap.body] - system_com(model, q)[0])  # from the servicer's CoM
    m_s = model.mass
    velocity, rate = np.asarray(motion.velocity, float), np.asarray(motion.rate, float)

    def brought(theta):
        body = pmap.transform @ theta  # standard parameters about the holding body's frame
        m, h = body[0], body[1:4]  # h = m c: no division at zero mass (the fit starts there)
        shift = (h @ h * np.eye(3) - np.outer(h, h)) / m if m != 0 else 0.0  # parallel axes, second order in h
        i_com = np.array(_matrix(body[4:])) - shift
        return rot @ i_com @ rot.T @ rate + m_s / (m_s + m) * np.cross(m * origin + rot @ h, velocity)

    return brought


def _attitude_axes(planar: bool) -> list:
    """Components of the attitude's small rotation that the configuration carries: the yaw (planar)."""
    return [2] if planar else [0, 1, 2]


def _configuration_sensitivity(pmap: PayloadMap, motion: GraspMotion, theta) -> np.ndarray:
    """``d(brought momentum)/dc`` ``(3, n_c)`` [N m s per rad or m] of the payload ``theta`` in the
    configuration ``c = [q, phi]`` of ``motion`` (see :class:`GraspMotion`), by central differences."""
    from scipy.spatial.transform import Rotation
    nj, axes = len(motion.q), _attitude_axes(pmap.planar)

    def brought(c):
        phi = np.zeros(3)
        phi[axes] = c[nj:]
        moved = replace(motion, q=motion.q + c[:nj], rotation=motion.rotation @ Rotation.from_rotvec(phi).as_matrix())
        return _brought_momentum(pmap, moved)(theta)

    return _central_jacobian(brought, np.zeros(nj + len(axes)))


def _given_covariance(pmap: PayloadMap, motion, momentum_cov, theta) -> tuple:
    """The covariance ``(3, 3)`` of the momentum that the fit takes as given: the servicer's
    (``momentum_cov``) plus what a moving payload brings, through its configuration's error
    (``motion.cov``, correlated with the momentum's by ``motion.momentum_cross``), at the payload
    ``theta``; and the configuration's share alone (None without one). None when neither."""
    if motion is None or motion.cov is None:
        return momentum_cov, None
    g = _configuration_sensitivity(pmap, motion, theta)
    share = g @ motion.cov @ g.T
    given = share if momentum_cov is None else momentum_cov + share
    if motion.momentum_cross is not None:
        cross = motion.momentum_cross @ g.T
        given = given + cross + cross.T
    return given, share


def _equations(pmap: PayloadMap, log: Log, momentum, drift, where, history=None) -> Equations:
    """The servicer's momentum equations of ``log`` with every minimal parameter known (their
    values, the payload's, set per step), the momentum and drift as the other unknowns (the drift
    integrated over ``history`` when given)."""
    names = drift_names(drift, pmap.planar)[0]
    k = pmap.param.n_params
    basis = drift_basis_at(log, drift, history, where) if names else None
    return Equations(pmap.param, quat_to_matrix(log.base_quat), np.array([], int), np.arange(k),
                      pmap.pi(np.zeros(pmap.n)), momentum, names, basis)


def _affine_momentum(eq: Equations, p: int, brought=None) -> tuple:
    """The right-hand side ``R0^T h`` of every sample as ``b0 (n, rows) + C (n, rows, p) theta``
    in the momentum and drift unknowns ``theta`` (``base_momentum`` is affine in them), and
    ``brought``: None, or the momentum ``(3,)`` that a moving payload brings, a function of its
    parameters (:func:`_brought_momentum`)."""
    axes = eq.axes
    b0 = eq.base_momentum(np.zeros(p))[:, axes]
    c = [eq.base_momentum(e)[:, axes] - b0 for e in np.eye(p)]
    return b0, np.stack(c, -1) if c else np.zeros(b0.shape + (0,)), brought


def _signal_jacobian(pmap, eq, x, theta, brought) -> np.ndarray:
    """The equations' signal Jacobian ``(n, rows, n_x)`` at ``theta = [payload, momentum, drift]``
    (the momentum a moving payload ``brought`` added to the given one)."""
    if brought is not None:
        eq = replace(eq, momentum=eq.momentum + brought(theta[: pmap.n]))
    return replace(eq, known_values=pmap.pi(theta[: pmap.n])).jacobian(x, theta[pmap.n :])


def _whitener(pmap, eq, x, sigma, theta, brought=None) -> tuple:
    """Cholesky factors ``(n, rows, rows)`` of the equation-error covariances at ``theta`` and the
    signal Jacobian (:func:`_signal_jacobian`)."""
    jac = _signal_jacobian(pmap, eq, x, theta, brought)
    try:
        return np.linalg.cholesky(equation_covariance(jac, sigma)), jac
    except np.linalg.LinAlgError:
        raise SpaceidError("`noise`: the equation-error covariance is singular at some sample: give a nonzero "
                           "`noise.base_rate`, or no noise levels at all (estimated from the log)") from None


def _whitened(pmap, eq, x, y, rhs, sigma, theta):
    """Residuals ``(n, rows)`` and Jacobian ``(n, rows, p)`` of ``theta = [payload, momentum,
    drift]``, whitened by the equation-error covariance at ``theta`` when ``sigma`` is given, and its Cholesky
    factors ``(n, rows, rows)`` (None unweighted). The Jacobian is that of the residuals at these weights: the
    weights' own change with ``theta`` is :func:`_weights_derivative`'s."""
    n_p = pmap.n
    b0, c, brought = rhs
    r = y @ pmap.pi(theta[:n_p]) - b0 - c @ theta[n_p:]
    a = np.concatenate([y @ pmap.columns(theta[:n_p]), -c], -1)
    if brought is not None:  # the moving payload's momentum, in base axes: R0^T h(theta)
        rows = np.swapaxes(eq.rot, -1, -2)[:, eq.axes]
        r = r - rows @ brought(theta[:n_p])
        a[..., :n_p] -= rows @ _central_jacobian(brought, theta[:n_p])
    if sigma is None:
        return r, a, None
    chol = _whitener(pmap, eq, x, sigma, theta, brought)[0]
    return np.linalg.solve(chol, r[..., None])[..., 0], np.linalg.solve(chol, a), chol


WEIGHT_STEP = 1e-6
"""Forward-difference step of :func:`_forward_differences` in the unknowns, relative to an unknown's value or, when
larger, to its scale (the inverse norm of its whitened column)."""


def _forward_differences(f, at: np.ndarray, theta, scale) -> np.ndarray:
    """``(..., p)``: forward differences of ``f(theta)`` (an array, ``at`` its value at ``theta``) in each unknown of
    ``theta (p,)``, of step :data:`WEIGHT_STEP` times ``max(|theta_j|, 1 / scale_j)``."""
    out = np.empty(at.shape + (len(theta),))
    for j in range(len(theta)):
        moved = theta.copy()
        moved[j] += (step := WEIGHT_STEP * max(abs(theta[j]), 1.0 / scale[j]))
        out[..., j] = (f(moved) - at) / step
    return out


def _weights_derivative(pmap, eq, x, sigma, theta, r, chol, scale, brought) -> np.ndarray:
    """``(n, rows, p)``: how the whitened residuals ``r (n, rows)`` move with each unknown of ``theta`` through their
    weights alone (the Cholesky factors ``chol`` at ``theta``, the residuals held): forward differences of the
    whitener (:func:`_forward_differences`)."""
    errors = (chol @ r[..., None])[..., 0]
    return _forward_differences(
        lambda moved: np.linalg.solve(_whitener(pmap, eq, x, sigma, moved, brought)[0], errors[..., None])[..., 0],
        r, theta, scale)


HALVINGS = 6
"""Most halvings of a Gauss-Newton step that raises the cost; when none lowers it, the fit stops at the estimate
before the step. Kept whole, such a step was reported: on undesigned random spatial robot 98697 (one joint) the
first step raised the cost, chi-squared per degree of freedom 161."""
STEP_STD = 1e-2
"""A weighted Gauss-Newton fit has also converged when a step moves no unknown by more than this share of its
standard error (on robot 98697 the estimates were then within 1e-3 standard errors of those at 1e-3, in 9 to 21
steps against 17 to 31)."""


def _gauss_newton(pmap, eq, x, y, rhs, sigma, p, where) -> tuple:
    """The ``theta (p,)`` that minimises the sum of squares of the whitened residuals, from zero (no payload: the
    first step solves the first-order problem), the whitened residuals and their Jacobian at its weights there (the
    Fisher information's: the weights' derivative moved the standard errors by 0.1 % on robot 98697 below), and the
    steps taken.

    Weighted fits: the weights (the equation errors' covariance) move with ``theta``. The steps first hold them
    (iteratively reweighted least squares, each step solving the problem weighted at the current estimate), then take
    their derivative too (:func:`_weights_derivative`) from that fixed point, which is not the minimum: on undesigned
    random spatial robot 98697 (one joint, a 1.75 kg payload, 1e-4 noise) its mass was -18.7 kg on average over 8
    noise draws (spread 1.9 kg), chi-squared per degree of freedom 3.2, where the cost at the truth was 1.0 per
    equation; the minimum's is 2.8 kg (spread 1.9 kg, standard error 3.1 kg), chi-squared 1.0. The derivative is
    proportional to the residuals, and taken from the start, with the payload's momentum in them (1,000 times the
    noise), it threw the steps off: robot 131073's mass went to -2,183 kg, chi-squared 3,000 (3.9 +- 0.4 kg at the
    fixed point, chi-squared 0.99; true 3.5)."""
    theta = np.zeros(p)
    r, a, chol = _whitened(pmap, eq, x, y, rhs, sigma, theta)
    taken = 0
    for whole in (False, True) if sigma is not None else (False,):
        theta, r, a, chol, steps = _steps(pmap, eq, x, y, rhs, sigma, (theta, r, a, chol), whole, where)
        taken += steps
    return theta, r, a, taken


def _steps(pmap, eq, x, y, rhs, sigma, start, whole: bool, where) -> tuple:
    """:func:`_gauss_newton`'s steps from ``start``, ``(theta, r, a, chol)`` as :func:`_whitened` gives them at
    ``theta``, with the weights' derivative when ``whole``: the same four at the last estimate and the steps taken.
    A step that raises the cost is halved (:data:`HALVINGS`)."""
    theta, r, a, chol = start
    p, cost = len(theta), r.ravel() @ r.ravel()
    for step in range(1, MAX_STEPS + 1):
        scale = np.linalg.norm(a.reshape(-1, p), axis=0)
        scale[scale == 0] = 1.0
        weights = _weights_derivative(pmap, eq, x, sigma, theta, r, chol, scale, rhs[2]) if whole else 0.0
        flat = (a + weights).reshape(-1, p) / scale
        with one_blas_thread():
            delta = np.linalg.lstsq(flat, -r.ravel(), rcond=None)[0] / scale
            std = np.sqrt(np.maximum(np.diag(np.linalg.pinv(flat.T @ flat)), 0)) / scale
        if not np.all(np.isfinite(theta + delta)):
            raise SpaceidError(f"{where}: the payload fit diverged: check `link`, `momentum` and the log")
        for halving in range(HALVINGS + 1):
            trial = theta + delta / 2**halving
            r_new, a_new, chol_new = _whitened(pmap, eq, x, y, rhs, sigma, trial)
            if (new_cost := r_new.ravel() @ r_new.ravel()) <= cost * (1 + STEP_TOL):  # (round-off at the optimum:
                break  # taken, and the fit stops)
        else:  # no progress: at the optimum (e.g. no payload at all)
            return theta, r, a, chol, step
        small = np.linalg.norm((trial - theta) * scale) <= STEP_TOL * max(np.linalg.norm(trial * scale), 1e-300) or (
            chol is not None and np.all(np.abs(trial - theta) <= STEP_STD * std))  # (unweighted: std has no unit)
        progress = new_cost < cost * (1 - STEP_TOL)
        theta, r, a, chol, cost = trial, r_new, a_new, chol_new, new_cost
        if small or not progress:
            return theta, r, a, chol, step
    raise SpaceidError(f"{where}: the payload fit did not converge in {MAX_STEPS} Gauss-Newton steps: check `link` "
                       "and `momentum`, or design an exciting motion for the payload (design_excitation, 'spaceid "
                       "design', with `payload_link`)")


def _covariance(r, a, weighted: bool, estimated: bool, window: int, differentiated=None) -> tuple:
    """Covariance of the unknowns, chi2/dof (weighted fits), how the covariance was obtained, the
    inverse Gram matrix ``(p, p)`` of the (whitened) Jacobian, for differentiated rates the
    Newey-West estimate from the residuals (None otherwise), and the tests of the whitened residuals against the
    noise model (:func:`~spaceid.estimation.internal.residual_checks`; None unweighted).

    Rates from a differentiator (``window`` > 0, its window in samples) have errors correlated
    over the window, which the noise model's independent samples understate. For Savitzky-Golay
    rates (``differentiated``: the series, the score weights ``M``, the signal Jacobian ``J``, the
    signals' white noise ``sigma`` and the stamps, see :func:`_score_weights`; each series' raw level at least the
    one given, :func:`~spaceid.estimation.internal.at_given_levels`) the covariance is the angle noise carried
    through the filters (:func:`~spaceid.estimation._differentiated.propagated_covariance`).
    The Newey-West estimate from the residuals (Bartlett weights over half the window) is returned
    beside it, not taken: a differentiated rate's error is a difference of angle noise, whose
    negative autocorrelation beyond half the window cancels much of the positive lobe in the
    score, and the Bartlett sum keeps the positive lobe alone (on the Cepheus twin it put the
    payload's RMSE/std at 0.62-0.91 against 0.79-0.99 from the filters; with a 41-sample window
    at 0.2). For other differentiators (and a spatial base's differentiated attitude) the Newey-West estimate is the
    covariance, at least the inverse Fisher information where the levels are given: its residuals on a noise-free log
    are the filters' truncation errors (random spatial robot 1839565112 in the live engine, the levels given as 1e-4:
    the payload's mass 3.6 of the Newey-West standard errors off). Otherwise the
    inverse Fisher information (given noise), scaled by chi2/dof (noise estimated from the log), or, when chi2/dof
    contradicts the noise model (two-sided at :data:`~spaceid.estimation.internal.SIGNIFICANCE`), the sandwich of the
    whitened residuals' scores (White), as ``spaceid identify`` takes it; unweighted, the sandwich of the per-sample
    residuals (heteroscedastic errors)."""
    n, rows, p = a.shape
    flat = a.reshape(-1, p)
    with one_blas_thread():
        bread = np.linalg.pinv(flat.T @ flat)
    dof = max(n * rows - p, 1)
    chi2 = float(r.ravel() @ r.ravel()) / dof if weighted else None
    checks = residual_checks(r, dof, chi2) if weighted else None
    if window:
        bandwidth = max(1, window // 2)
        newey_west = newey_west_covariance(bread, a, r, bandwidth, p)
        if differentiated is None:
            how = f"Newey-West from the residuals, Bartlett weights over {bandwidth} samples (differentiated rates)"
            cov, larger = larger_of(newey_west, bread) if weighted and not estimated else (newey_west, 0)
            if larger:
                how += f"; in {larger} of {p} directions the inverse Fisher information at the levels given"
            return cov, chi2, how, bread, newey_west, checks
        series, m, jac, sigma, t = differentiated
        how = (f"the angle noise of {len(series)} differentiated series propagated through their Savitzky-Golay "
               "filters (its correlation over the windows)")
        cov = propagated_covariance(series, t, [(slice(None), m, jac)], bread, sigma)
        return cov, chi2, how, bread, newey_west, checks
    if weighted and checks["chi2_p"] < SIGNIFICANCE:
        how = CONTRADICTED.format(chi2, checks["chi2_p"])
        return newey_west_covariance(bread, a, r, 0, p), chi2, how, bread, None, checks
    if weighted:
        return (bread * (chi2 if estimated else 1.0), chi2,
                "inverse Fisher information" + (" scaled by chi2/dof" if estimated else ""), bread, None, checks)
    return newey_west_covariance(bread, a, r, 0, p), None, "sandwich of the per-sample residuals", bread, None, None


PROPAGATED = ("the standard errors carry the angle noise through the differentiator's filters, not the residuals, "
              "and miss its truncation errors where its window is long for the motion or the log is noise-free "
              "(shorten the window, or let it be chosen)")
"""How the noise model's warning ends for Savitzky-Golay rates (:func:`_covariance`: not the residuals' spread)."""


def _score_weights(pmap, eq, x, sigma, theta, a, brought) -> tuple:
    """``M (n, rows, p)``, the estimate's first-order error being ``bread sum_n M_n^T e_n`` in the
    equation errors ``e_n`` (whitened fits: ``S_n^-1 A_n``), and the signal Jacobian ``(n, rows,
    n_x)`` of ``e_n``, at ``theta``; ``a`` the (whitened) Jacobian of the fit."""
    if sigma is None:
        return a, _signal_jacobian(pmap, eq, x, theta, brought)
    chol, jac = _whitener(pmap, eq, x, sigma, theta, brought)
    return np.linalg.solve(np.swapaxes(chol, -1, -2), a), jac


def _momentum_sensitivity(pmap, eq, x, y, sigma, theta, a, bread, brought) -> np.ndarray:
    """``d theta / d h`` ``(p, len(axes))``: how the estimate moves with the given momentum's
    components on the equations' axes (first order: ``-bread A^T dr/dh``, ``r`` the whitened
    residuals; the momentum's columns are those of the same equations with it unknown, at the
    given momentum plus what a moving payload ``brought``)."""
    free = replace(eq, momentum=None)
    n = pmap.n
    h = eq.momentum if brought is None else eq.momentum + brought(theta[:n])
    at = np.concatenate([theta[:n], h[eq.axes], theta[n:]])
    a_h = _whitened(pmap, free, x, y, _affine_momentum(free, free.p), sigma, at)[1][..., n : n + free.n_h]
    with one_blas_thread():
        return -bread @ (a.reshape(-1, a.shape[-1]).T @ a_h.reshape(-1, free.n_h))


def identify_payload(model, log: Log, link: str, momentum, *, grasp_motion: GraspMotion | None = None,
                     momentum_cov=None, noise: Noise | None = None, drift=(), history=None, seed: int = 0,
                     where: str = "log", cond_limit: float = 1e10) -> PayloadEstimate:
    """Identify the inertial parameters of a payload held rigidly by a known servicer.

    Parameters
    ----------
    model : Model or str or Path or PayloadMap
        The servicer without the payload (a preset, URDF or YAML; e.g. one 'spaceid export' wrote).
    log : Log
        Motion after the capture; joint columns in the model's joint order.
    link : str
        The link that holds the payload: a body, or (URDF) a link on fixed joints below one.
    momentum : array_like of shape (3,) or None
        Inertial angular momentum of the whole system [N m s] (zero for a capture from rest; at
        the first sample with ``drift``, or of ``history``); None: estimated with the payload (nearly
        collinear with it when the base turns steadily: a warning says so; a payload that moved at
        the grasp is better given by ``grasp_motion``).
    grasp_motion : GraspMotion, optional
        A payload that moved at the grasp: ``momentum`` is then the servicer's before the grasp,
        and the payload's own (a function of its parameters and of this motion) is added to it;
        the covariance of the configuration it is placed with (``grasp_motion.cov``) is carried into
        the payload's covariance to first order, as ``momentum_cov`` is.
    momentum_cov : array_like of shape (3, 3), optional
        Covariance of a given ``momentum`` [(N m s)^2], e.g. of the servicer's momentum estimated
        over a hold before the grasp (:func:`spaceid.identified.hold_momentum`): carried into the
        payload's covariance to first order, its error independent of the log's.
    noise : Noise, optional
        Measurement noise levels (the equations are whitened by them and the covariance is their
        Fisher information); estimated from the log when omitted; all zero: unweighted least
        squares with a residual-based (sandwich) covariance.
    drift : iterable of {"torque", "viscous", "coulomb"}
        External torques estimated with the payload (as ``spaceid.identify``).
    history : Log, optional
        With ``drift``: a record that starts before ``log`` and spans it (e.g. the same recording
        from before the grasp), over which the drift is integrated; ``momentum`` is then the
        momentum at its first sample (as ``spaceid.identify``'s ``history``).
    seed : int
        Seed of the minimal set's random states (recorded).
    where : str
        Name of the log, for error messages.
    cond_limit : float
        Largest condition number of the column-scaled first-order equations.

    Returns
    -------
    PayloadEstimate
        Mass, CoM and inertia about the CoM in ``link``'s frame, physically consistent, with
        standard errors and covariance.

    Raises
    ------
    SpaceidError
        An unknown link, too few samples, unexcited payload parameters, or a fit that does not
        converge.
    """
    pmap = model if isinstance(model, PayloadMap) else payload_map(model, link, seed=seed)
    if pmap.link != link:
        raise SpaceidError(f"`link`: '{link}' differs from the payload map's link '{pmap.link}': use one link")
    drift = check_drift_kinds(drift)
    if isinstance(momentum, str):
        raise SpaceidError(f"`momentum`: {momentum!r} is not a value: 'hold' needs the grasp instant "
                           "(payload_after_grasp, with its `grasp`)")
    momentum = None if momentum is None else np.asarray(momentum, float)
    estimated = noise is None
    noise = noise_from_log(log) if estimated else noise
    if momentum is None and (momentum_cov is not None or grasp_motion is not None):
        raise SpaceidError("`momentum`: estimated with the payload, so it takes neither a covariance nor the payload's "
                           "motion at the grasp: give the servicer's momentum")
    momentum_cov = None if momentum_cov is None else np.asarray(momentum_cov, float).reshape(3, 3)
    n_c = pmap.param.model.n_joints + len(_attitude_axes(pmap.planar))
    if grasp_motion is not None and grasp_motion.cov is not None and np.shape(grasp_motion.cov) != (n_c, n_c):
        raise SpaceidError(f"`grasp_motion.cov`: shape {np.shape(grasp_motion.cov)}, expected ({n_c}, {n_c}): the "
                           "covariance of the joint positions and the attitude at the grasp (planar: the yaw)")
    brought = None if grasp_motion is None else _brought_momentum(pmap, grasp_motion)
    fit = _fit(pmap, log, momentum, momentum_cov, grasp_motion, brought, drift, history, noise, estimated, where,
               cond_limit)
    eq, theta, cov_all = fit.equations, fit.theta, fit.cov
    n = pmap.n
    standard, cov_std = theta[:n], cov_all[:n, :n]
    consistent, moved = project_consistent(standard, cov_std, pmap.planar)
    reach = _noise_reach(n)
    beyond = moved > reach
    jac = _physical_jacobian(consistent, pmap.planar)
    values, unconstrained = _physical(consistent, pmap.planar), _physical(standard, pmap.planar)
    # no noise carries a real payload's estimate beyond its reach: the step is then error, its size too
    step = values - unconstrained if beyond else np.zeros(len(values))
    cov = jac @ cov_std @ jac.T + np.outer(step, step)
    std_all = np.sqrt(np.maximum(np.diag(cov_all), 0))
    nw = fit.newey_west
    if fit.noise_model_warning:
        warnings.warn(f"{where}: {fit.noise_model_warning}", stacklevel=2)
    if fit.undetermined:
        warnings.warn(undetermined_warning(fit.undetermined, len(theta), where, ESTIMATE_SCALE, UNDETERMINED_FIX),
                      stacklevel=2)
    if beyond:
        warnings.warn(f"{where}: the estimate lay {moved:.3g} standard errors from any physical payload, where the noise "
                      f"reaches {reach:.3g}: the data contradict a rigid payload on `link` (too few samples "
                      "after the grasp, samples from before it, or another link), and its standard errors are widened "
                      "by the step to the nearest physical one: check the grasp instant and `link`, or take more "
                      "samples after the grasp",
                      stacklevel=2)  # fmt: skip
    correlation = _largest_correlation(cov_all, n, eq.n_h) if momentum is None else None
    if correlation is not None and correlation > COLLINEAR:
        warnings.warn(f"{where}: the momentum estimated with the payload correlates with it at {correlation:.3f}: the "
                      "motion hardly tells them apart, and the rates' systematic errors move the mass along; give the "
                      "momentum (`momentum`: a value, or 'hold' with the `grasp` instant) and a moving payload's "
                      "velocity and rate (`payload_motion`)", stacklevel=2)  # fmt: skip
    units = drift_names(drift, pmap.planar)[1]
    terms = tuple({"name": nm, "value": float(v), "std": float(e), "unit": u} for nm, v, e, u in
                  zip(eq.drift, eq.drift_values(theta), std_all[len(theta) - len(eq.drift) :], units))  # fmt: skip
    physical = PLANAR_NAMES if pmap.planar else SPATIAL_NAMES
    settings = {
        "model": pmap.param.model.source or pmap.param.model.name,
        "body": pmap.param.model.bodies[pmap.body].name,
        "estimator": fit.estimator,
        "noise": noise.to_dict(),
        "covariance": fit.covariance + ("; with the step to the nearest physical payload added, the estimate lying "
                                        "beyond the noise's reach of any" if beyond else ""),
        "newey_west_std": None if nw is None else
                          np.sqrt(np.maximum(np.diag(jac @ nw[:n, :n] @ jac.T) + step**2, 0)).tolist(),
        "chi2_dof": fit.chi2_dof,
        "noise_model_warning": fit.noise_model_warning,
        "undetermined": fit.undetermined,
        "residual_rms": fit.residual_rms,
        "gauss_newton_steps": fit.steps,
        "condition_number_scaled": fit.cond,
        "consistency": {"projected": moved > 0, "mahalanobis_distance": moved, "noise_reach": reach,
                        "contradicted": bool(beyond),
                        "unconstrained": dict(zip(physical, unconstrained.tolist()))},
        "momentum_estimated": momentum is None,
        "momentum_std": std_all[n : n + eq.n_h].tolist() if momentum_cov is None else
                        np.sqrt(np.diag(momentum_cov)[eq.axes]).tolist(),
        "momentum_covariance": None if momentum_cov is None else momentum_cov.tolist(),
        "momentum_payload_correlation": correlation,
        "payload_momentum": None if brought is None else brought(standard).tolist(),
        "payload_momentum_std": None if fit.configuration_share is None else
                                np.sqrt(np.diag(fit.configuration_share)).tolist(),
        "n_samples": log.n_samples,
        "seed": pmap.param.seed,
        "minimal_set": {"basis": pmap.param.basis, "rank_tol": pmap.param.rank_tol, "n_params": pmap.param.n_params},
        "log": dict(log.meta),
        "log_fingerprint": log_fingerprint(log),
    }
    return PayloadEstimate(pmap.link, physical, values,
                           np.sqrt(np.maximum(np.diag(cov), 0)), cov, pmap.standard(consistent),
                           NOT_PLANAR if pmap.planar else (), eq.full(theta[n:])[1], terms, settings)


def _noise_reach(n: int) -> float:
    """The Mahalanobis distance that noise carries an estimate of ``n`` parameters from the truth
    with probability :data:`~spaceid.estimation.internal.SIGNIFICANCE` (the square root of the
    chi-square quantile): a real payload's estimate lies no farther from the physical set."""
    return float(np.sqrt(chi2_isf(SIGNIFICANCE, n)))


def _largest_correlation(cov, n: int, n_h: int) -> float:
    """The largest |correlation| between an estimated momentum component and a payload parameter
    (standard, about the link origin) in the covariance ``cov`` of ``[payload (n), momentum (n_h), ...]``:
    near 1, the motion hardly tells the momentum from the payload."""
    std = np.sqrt(np.maximum(np.diag(cov), np.finfo(float).tiny))
    corr = cov[:n, n : n + n_h] / np.outer(std[:n], std[n : n + n_h])
    return float(np.abs(corr).max())


@dataclass(frozen=True)
class _PayloadFit:
    """The unconstrained fit of ``[payload, momentum, drift]`` (:func:`_fit`).

    Attributes
    ----------
    equations : Equations
        The momentum equations, the payload's parameters ahead of their unknowns.
    theta : ndarray of shape (n + p,)
        The estimate: the payload's standard parameters (``n``), then the equations' unknowns.
    cov : ndarray of shape (n + p, n + p)
        Its covariance, with a given momentum's and a moving payload's configuration's carried through.
    newey_west : ndarray or None
        The Newey-West covariance of differentiated rates, for comparison; None otherwise.
    chi2_dof : float or None
        Whitened residual sum of squares per degree of freedom; None unweighted.
    steps : int
        Gauss-Newton steps.
    cond : float
        Condition number of the column-scaled first-order equations.
    residual_rms : float
        RMS of the unwhitened residuals [N m s].
    estimator, covariance : str
        The fit and how its covariance was obtained, in words.
    configuration_share : ndarray of shape (3, 3) or None
        The covariance of the momentum a moving payload brought, from its configuration's at the grasp.
    noise_model_warning : str
        What a chi2/dof far from 1 means (``spaceid identify``'s words), or ``""``.
    undetermined : list of dict
        The directions of the unknowns that the data do not determine (the regressor's noise as large as its signal:
        ``spaceid identify``'s ``undetermined``), worst first; ``cov`` is widened along them.
    """

    equations: Equations
    theta: np.ndarray
    cov: np.ndarray
    newey_west: np.ndarray | None
    chi2_dof: float | None
    steps: int
    cond: float
    residual_rms: float
    estimator: str
    covariance: str
    configuration_share: np.ndarray | None
    noise_model_warning: str = ""
    undetermined: list = field(default_factory=list)


def _fit(pmap, log, momentum, momentum_cov, motion, brought, drift, history, noise, estimated, where,
         cond_limit) -> _PayloadFit:
    """The unconstrained :class:`_PayloadFit` of ``[payload, momentum, drift]``: the equations, the estimate,
    its covariance (with that of a given momentum, ``momentum_cov``, and of a moving payload's
    configuration, ``motion.cov``, carried through) and the record of how they were obtained (see
    :func:`identify_payload`; ``brought``: :func:`_brought_momentum` of ``motion``)."""
    eq = _equations(pmap, log, momentum, drift, where, history)
    p = pmap.n + eq.p
    if log.n_samples * pmap.param.rows < p + 1:
        raise SpaceidError(f"{where}: {log.n_samples} samples give too few equations for {p} unknowns: record more")
    x = eq.signals(log)
    q, qd, w, _ = eq.unpack(x)
    y = pmap.param.regressor(q, qd, w)
    rhs = _affine_momentum(eq, eq.p, brought)
    names = list(PLANAR_NAMES if pmap.planar else INERTIAL_NAMES) + eq.names()
    r0, a0, _ = _whitened(pmap, eq, x, y, rhs, None, np.zeros(p))
    _, cond = check_excitation(np.concatenate([a0, r0[..., None]], -1), names, cond_limit, where)
    sigma = None if noise.is_zero else signal_sigma(pmap.param, noise)
    theta, r, a, steps = _gauss_newton(pmap, eq, x, y, rhs, sigma, p, where)
    window, series = correlation_length(log), differentiated_series(log)
    differentiated = None
    if window and series is not None:
        white = np.zeros(x.shape[1]) if sigma is None else sigma
        series = series if estimated or sigma is None else at_given_levels(series, noise)
        differentiated = (series, *_score_weights(pmap, eq, x, sigma, theta, a, brought), white, log.t)
    cov, chi2, how, bread, newey_west, checks = _covariance(r, a, sigma is not None, estimated, window,
                                                             differentiated)
    given, share = _given_covariance(pmap, motion, momentum_cov, theta[: pmap.n])
    if given is not None:  # the given momentum's error moves the estimate too (independent of the log's)
        d = _momentum_sensitivity(pmap, eq, x, y, sigma, theta, a, bread, brought)
        cov = cov + d @ given[np.ix_(eq.axes, eq.axes)] @ d.T
        how += "; plus the given momentum's covariance carried through d(estimate)/d(momentum)"
        how += "" if share is None else " (with the moving payload's, from its configuration's at the grasp)"
    weak = []
    if sigma is not None:  # (unweighted: noise-free, nothing to judge the regressor's noise by)
        ratios = _noise_ratios(pmap, eq, x, sigma, theta, a, brought, log)
        weak = undetermined(*ratios, names)
        if weak:  # the data hold nothing along them: their values' scale, the estimate's (the payload has no model)
            cov = widened(cov, *ratios, theta, np.zeros_like(theta))
            how += f"; {WIDENED.format(len(weak), ESTIMATE_SCALE)}"
    ending = {} if differentiated is None else {"standard_errors": PROPAGATED}  # the warning's: not the residuals
    return _PayloadFit(
        equations=eq, theta=theta, cov=cov, newey_west=newey_west, chi2_dof=chi2, steps=steps, cond=cond,
        residual_rms=float(np.sqrt(np.mean(_whitened(pmap, eq, x, y, rhs, None, theta)[0] ** 2))),
        noise_model_warning=noise_model_warning(chi2, checks, log, estimated, **ending) if checks else "",
        estimator="wls (Gauss-Newton, errors-in-variables weights)" if sigma is not None else "ols (Gauss-Newton)",
        covariance=how, configuration_share=share, undetermined=weak,
    )  # fmt: skip


ESTIMATE_SCALE = "the estimate's"
"""The scale the directions the data do not determine are widened to: the estimate's values (``spaceid identify``
adds the model's own; the payload has no model)."""
UNDETERMINED_FIX = ("excite them with a motion designed for the payload (design_excitation, 'spaceid design', with "
                    "`payload_link`)")
"""The advice that ends the payload's warning of directions the data do not determine."""


def _noise_ratios(pmap, eq, x, sigma, theta, a, brought, log) -> tuple:
    """The noise-to-signal ratios and directions ``(mu, T)`` of the fit's unknowns at ``theta``, its whitened
    Jacobian ``a (n, rows, p)`` (:func:`~spaceid.estimation.internal.ratios_of_columns`: empty when none is
    undetermined). The columns' derivatives with respect to the signals are those of the residuals' signal Jacobian
    with respect to the unknowns (:func:`_forward_differences`), whitened at ``theta``'s weights: one
    Jacobian an unknown, where forming the columns anew at each signal's step took 0.7 s of the servicer's payload.
    On undesigned random spatial robot 98697 (one joint, a 1.75 kg payload, 1e-4 noise) two directions' ratios were
    0.89 and 0.73, its mass 3.9 +- 3.0 kg; over 20 other random robots (planar and spatial, designed and undesigned
    motions) the largest was 1.1e-3."""
    chol = _whitener(pmap, eq, x, sigma, theta, brought)[0]
    scale = np.linalg.norm(a.reshape(-1, a.shape[-1]), axis=0)
    scale[scale == 0] = 1.0

    def derivatives(rows):
        part = eq.select(rows)
        jacobian = partial(_signal_jacobian, pmap, part, x[rows], brought=brought)
        out = _forward_differences(jacobian, jacobian(theta), theta, scale)
        return np.einsum("nrs,nsck->nrck", np.linalg.inv(chol[rows]), out)

    return ratios_of_columns(a, derivatives, signal_levels(pmap.param, log, sigma))


def nominal_payload(path, *, planar: bool) -> np.ndarray:
    """The standard parameters of the payload in a PAYLOAD.json (a nominal for the design): all ten
    (spatial) or ``m, mcx, mcy, Izz`` about the link origin (planar), shape ``(10,)`` or ``(4,)``.

    Raises
    ------
    SpaceidError
        The file is not a PAYLOAD.json (no ``standard_parameters``).
    """
    data = read_json(path, what="payload")
    std = data.get("standard_parameters") if isinstance(data, dict) else None
    if not isinstance(std, dict) or any(not isinstance(std.get(n), (int, float)) for n in INERTIAL_NAMES):
        raise SpaceidError(f"{path}: no standard_parameters with {', '.join(INERTIAL_NAMES)}: give a PAYLOAD.json "
                           "as 'spaceid payload' writes it (PayloadEstimate.to_dict)")
    values = np.array([std[n] for n in INERTIAL_NAMES], float)
    return values[list(PLANAR_SLOTS)] if planar else values
