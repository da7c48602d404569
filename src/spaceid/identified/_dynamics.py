"""Controller-ready dynamics of an identified model, from the minimal parameters ``pi`` alone.

With zero linear momentum the kinetic energy is a quadratic form in ``x = [qd, w0]`` (joint
rates, then the base angular velocity in base axes: its z component only for planar systems),

    T = 1/2 x^T M(q) x,

and its regressor lies in the row space of the minimal set's projection ``P``
(:func:`spaceid.dynamics.identifiability`, ``determines_dynamics``): ``E(q, x) = c(q, x) P``.
So ``c = E[:, J] P[:, J]^-1`` for any ``k`` columns ``J`` with ``P[:, J]`` invertible, and
``T = E[:, J] P[:, J]^-1 pi`` is linear in ``pi``; ``M(q)`` follows by polarisation of ``T``.
Eliminating the base rate by the conserved angular momentum gives the free-floating joint
inertia ``H* = A - B D^-1 B^T`` (blocks of ``M``: joints ``A``, coupling ``B``, locked base
``D``) and the joint dynamics (docs/theory/control.md).

``M(q)`` has degree two in ``cos q_k, sin q_k`` (revolute joint k) or in ``q_k`` (prismatic):
every body velocity is linear in them. Its configuration derivative (applied to a velocity,
``dM/dq_k x``, all the dynamics need) is therefore exact from five equally spaced angles (a
discrete Fourier series of degree two) or a central difference.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass, replace

import numpy as np
from scipy.linalg import qr

from .._deprecation import deprecated_alias
from .._errors import SpaceidError
from .._svd import svd
from .._threads import one_blas_thread
from ..data import quat_to_matrix
from ..dynamics import Parameterization, base_rate, body_states, energy_regressor, full_values, identifiability, skew
from ..dynamics import minimal_parameters
from ..estimation import Identification, load_result
from ..models import INERTIAL_NAMES, load_model
from ._com import com_of, com_position, frame_jacobians

__all__ = ["IdentifiedModel", "identified_model", "load_identified", "parameterization_of"]

_FIXES = {
    "total_mass": "a weighing of the whole system, or a thruster test with a known force",
    "system_com": "the total mass (pi fixes the rest), or the base position logged over a motion "
                  "(spaceid.identified.identify_com; 'spaceid identify' runs it on request)",
    "linear_velocity": "the system centre of mass (see 'system_com'): zero linear momentum fixes the base "
                       "linear velocity, hence any point's, relative to it",
    "base_force_response": "the total mass and the system centre of mass: a force on the base changes the "
                           "linear momentum, which the identification held at zero",
    "body_parameters": "each body's own mass, CoM and inertia: pi fixes only combinations of them "
                       "(spaceid.dynamics.identifiability lists which)",
}
_FIXED_TOL = 1e-5
"""A physical quantity counts as fixed by ``pi`` when the part of its gradient outside the row space
of ``d pi / d theta`` is below this fraction of it: below 3e-9 (round-off of the differences) for the
mass and CM of the satellite-7dof preset, 3e-3 to 3e-2 for the CM of the planar presets (their total
mass: all of it)."""

# revolute joints: M(q_k + a) is a trigonometric polynomial of degree 2 in a, so its derivative
# at a = 0 is sum_j f(a_j) (2/5) (sin a_j + 2 sin 2 a_j) over a_j = 2 pi j / 5 (j = 0 drops out)
_ANGLES = 2 * np.pi * np.arange(1, 5) / 5
_ANGLE_WEIGHTS = 0.4 * (np.sin(_ANGLES) + 2 * np.sin(2 * _ANGLES))
_SLIDE = 0.1
"""Step [m] of the central difference for prismatic joints: exact for a quadratic, any step."""


@deprecated_alias(old="ident", new="result")
def parameterization_of(result, *, where: str = "result") -> Parameterization:
    """Rebuild the minimal parameter set that ``result`` (an :class:`~spaceid.estimation.Identification`
    or :class:`IdentifiedModel`) was identified with, and check it against the result's names."""
    if isinstance(result, IdentifiedModel):
        return result.param
    settings = result.settings.get("parameterization", {})
    model = load_model(result.model, planar=result.planar)
    param = minimal_parameters(model, tol=settings.get("rank_tol", 1e-9), seed=settings.get("seed", 0))
    if param.names != result.names or param.definitions != result.definitions:
        raise SpaceidError(
            f"{where}: its parameters do not match model '{result.model}' as loaded now "
            f"({len(result.names)} vs {param.n_params}): identify again with this model"
        )
    return param


@deprecated_alias(old="ident", new="result")
def identified_model(result: Identification, *, where: str = "result") -> IdentifiedModel:
    """The controller-ready model of an identification (its parameter set rebuilt and checked)."""
    return IdentifiedModel(result, parameterization_of(result, where=where), where)


def load_identified(path) -> IdentifiedModel:
    """An identification saved as RESULT.json, as a controller-ready :class:`IdentifiedModel`.

    This is ``spaceid.load_identified``; ``spaceid.load_result`` (that is,
    :func:`spaceid.estimation.load_result`) gives the :class:`~spaceid.estimation.Identification`
    record alone, and :func:`identified_model` turns one into this model.

    Parameters
    ----------
    path : str or Path
        The JSON file written by ``spaceid identify``.

    Raises
    ------
    SpaceidError
        The file is missing or not a result, or its parameters do not match its model.
    """
    return identified_model(load_result(path), where=str(path))


def _polarization_rates(d: int) -> np.ndarray:
    """Generalized velocities ``e_i`` then ``e_i + e_j`` (i < j), shape ``(d (d + 1) / 2, d)``."""
    i, j = np.triu_indices(d, 1)
    pairs = np.zeros((len(i), d))
    pairs[np.arange(len(i)), i] = pairs[np.arange(len(i)), j] = 1.0
    return np.vstack([np.eye(d), pairs])


def _polarize(t: np.ndarray, d: int) -> np.ndarray:
    """``M (..., d, d)`` of the energies ``t (..., d (d + 1) / 2)`` at :func:`_polarization_rates`."""
    i, j = np.triu_indices(d, 1)
    m = np.empty(t.shape[:-1] + (d, d))
    m[..., np.arange(d), np.arange(d)] = 2 * t[..., :d]
    m[..., i, j] = m[..., j, i] = t[..., d:] - t[..., i] - t[..., j]
    return m


@dataclass(frozen=True)
class IdentifiedModel:
    """An identification made controller-ready: the free-floating dynamics its ``pi`` fixes.

    Every attribute of the :class:`~spaceid.estimation.Identification` (``std``, ``momentum``,
    ``settings``, ``to_dict`` ...) is offered as well; ``model`` is still its source string, the
    geometry is :attr:`geometry`. Arrays are batched over any leading shape ``...`` (samples);
    units SI. Base rates ``w0`` are base-axes vectors of shape ``(..., 3)`` (planar systems use
    the z component only). Quantities ``pi`` does not fix are listed in :attr:`undetermined`.

    Attributes
    ----------
    identification : Identification
    param : Parameterization
        The minimal set, rebuilt from the result.
    where : str
        Where the result came from, for error messages.
    """

    identification: Identification
    param: Parameterization
    where: str = "result"

    def __getattr__(self, name):
        if name.startswith("__") or name in ("identification", "param", "where"):
            raise AttributeError(name)
        return getattr(self.identification, name)

    @property
    def joints(self) -> tuple:
        """Joint names, in the order of the columns of ``q``."""
        return self.param.model.joints

    @property
    def names(self) -> tuple:
        return self.identification.names

    @property
    def values(self) -> np.ndarray:
        """The estimate of ``pi``, shape ``(k,)``."""
        return self.identification.values

    def with_values(self, pi) -> IdentifiedModel:
        """The same model with the minimal parameters ``pi`` (k,) in place of the estimate: e.g.
        the true values, or a CAD prior's (``minimal_parameters(cad).true_values`` for a model
        with the same joints), to compare controllers built on each."""
        pi = np.asarray(pi, float)
        if pi.shape != self.values.shape:
            raise SpaceidError(f"with_values: `pi` has shape {pi.shape}, expected {self.values.shape} "
                               f"(the parameters {', '.join(self.names)})")  # fmt: skip
        return IdentifiedModel(replace(self.identification, values=pi), self.param, self.where)

    @property
    def cov(self) -> np.ndarray:
        """Covariance of ``values``, shape ``(k, k)``."""
        return self.identification.cov

    @property
    def geometry(self):
        """The :class:`~spaceid.models.Model` (its inertial values are not the identified ones)."""
        return self.param.model

    @functools.cached_property
    def undetermined(self) -> dict:
        """Quantities ``pi`` does not fix for this model, each with the information that would.

        Decided to first order at the model file's own inertial values (a generic point): the
        total mass and the system CM (at seeded random configurations) are fixed when their
        gradients in the standard parameters lie in the row space of ``d pi / d theta``. The
        planar presets leave the total mass free, and with it the CM; the spatial presets fix
        both (docs/theory/control.md).
        """
        fixed = _fixed_by_pi(self.param)
        out = {"body_parameters": _FIXES["body_parameters"]}
        if not fixed["total_mass"]:
            out["total_mass"] = _FIXES["total_mass"]
        if not fixed["system_com"]:
            out["system_com"] = _FIXES["system_com"] if fixed["system_com_given_mass"] else (
                "the total mass and every body's first moment (mass times CoM), e.g. from a CAD model")
            out["linear_velocity"] = _FIXES["linear_velocity"]
        if self.identification.com is not None:  # identified from the base position
            out.pop("system_com", None), out.pop("linear_velocity", None)
        if len(out) > 1:
            out["base_force_response"] = _FIXES["base_force_response"]
        return out

    def requires(self, quantity: str):
        """Raise the :class:`~spaceid.SpaceidError` that says what a ``quantity`` of ``undetermined``
        needs (or, for one ``pi`` fixes, that it is not computed here)."""
        known = set(_FIXES) - {"body_parameters"}
        if quantity not in known | set(self.undetermined):
            raise SpaceidError(f"'{quantity}' is not a quantity that pi may leave free: use one of {', '.join(known)}")
        label = quantity.replace("_", " ")
        if quantity not in self.undetermined:
            raise SpaceidError(f"{self.where}: pi fixes the {label} of this model to first order, but computing it "
                               "needs a physical parameter set consistent with pi, which this model does not hold")
        raise SpaceidError(f"{self.where}: the identified parameters do not fix the {label}; it needs "
                           f"{self.undetermined[quantity]}")

    def system_com(self, q) -> np.ndarray:
        """The system CM [m] relative to the base origin in base axes, shape ``(..., 3)`` (z zero for
        planar models), from the CM terms identified from the base position (:func:`identify_com`);
        without them it raises the error of :meth:`requires`."""
        return com_position(self, q)

    def linear_velocity(self, q, qd, w0, body: str):
        """A body's linear velocity: use :meth:`frame_velocity` (it needs the CM terms); raises the
        error of :meth:`requires` without them."""
        if com_of(self) is None:
            self.requires("linear_velocity")
        raise SpaceidError("linear_velocity: use frame_velocity(q, qd, frame, momentum, attitude), which takes the "
                           "base rate from the momentum")

    # ---------------------------------------------------------------- generalized Jacobian ----

    def generalized_jacobian(self, q, frame: str, attitude=None, point=None) -> np.ndarray:
        """Umetani and Yoshida's generalized Jacobian of a frame: its twist per joint rate at zero
        linear and angular momentum, the base's motion eliminated.

        Parameters
        ----------
        q : array_like of shape (..., n_joints)
        frame : str
            A body name of the model (a fixed joint's child is merged into its parent: give its
            parent and the child's origin as ``point``).
        attitude : array_like of shape (..., 4), optional
            Base attitude ``[w, x, y, z]``; default identity (the result in base axes).
        point : array_like of shape (3,), optional
            The point of the frame whose linear velocity is wanted, in the frame's axes [m]
            (default its origin).

        Returns
        -------
        ndarray of shape (..., 6, n_joints)
            Rows: the point's linear velocity [m/s], then the frame's angular velocity [rad/s],
            inertial axes, per unit joint rate.

        Raises
        ------
        SpaceidError
            The CM terms were not identified (:func:`identify_com`), or ``frame`` is unknown.
        """
        p, jp, jw, c, jc = frame_jacobians(self, q, frame, point)
        n = self.geometry.n_joints
        q = np.asarray(q, float)
        rates = base_rate(self.param, self.values, q[..., None, :], np.eye(n), np.zeros(3))  # (..., n, 3)
        k = np.swapaxes(rates, -1, -2)
        return _to_inertial(np.concatenate([jp - jc - skew(p - c) @ k, jw + k], -2), attitude)

    def frame_velocity(self, q, qd, frame: str, momentum=None, attitude=None, point=None) -> np.ndarray:
        """Inertial twist ``[v, w]`` [m/s, rad/s] of a frame, shape ``(..., 6)``: the generalized
        Jacobian times ``qd`` plus the drift of a nonzero angular momentum (linear momentum zero).

        ``momentum``, ``attitude`` as in :meth:`base_rate` (default: the identification's momentum,
        identity attitude); ``frame``, ``point`` as in :meth:`generalized_jacobian`.
        """
        qd = np.asarray(qd, float)
        drift_rate = self.base_rate(q, np.zeros_like(qd), momentum, attitude)  # base axes
        p, _, _, c, _ = frame_jacobians(self, q, frame, point)
        drift = _to_inertial(np.concatenate([np.cross(drift_rate, p - c), drift_rate], -1)[..., None], attitude)
        return (self.generalized_jacobian(q, frame, attitude, point) @ qd[..., None] + drift)[..., 0]

    # ---------------------------------------------------------------- energy and inertia ------

    @functools.cached_property
    def _energy_map(self):
        """Columns ``J`` of the energy regressor and ``P[:, J]^-1``: ``T = E[:, J] P[:, J]^-1 pi``."""
        with one_blas_thread():  # small factorisations (see one_blas_thread)
            report = identifiability(self.param)
            proj = self.param.projection
            cols = np.sort(qr(proj, mode="r", pivoting=True)[1][: proj.shape[0]])
            inverse = np.linalg.inv(proj[:, cols])
        if not report.determines_dynamics:
            raise SpaceidError(
                f"{self.where}: the minimal set of model '{self.identification.model}' does not determine the kinetic "
                f"energy (relative residual {report.energy_residual:.2g}): no reduced dynamics from it"
            )
        return cols, inverse

    @property
    def _axes(self) -> list:
        return [2] if self.geometry.planar else [0, 1, 2]

    @property
    def _dim(self) -> int:
        return self.geometry.n_joints + len(self._axes)

    def _pi(self, pi) -> np.ndarray:
        return self.values if pi is None else np.asarray(pi, float)

    def _split(self, x):
        """``(qd, w0)`` of generalized velocities ``x = [qd, w0 components] (..., d)``."""
        n = self.geometry.n_joints
        w0 = np.zeros(x.shape[:-1] + (3,))
        w0[..., self._axes] = x[..., n:]
        return x[..., :n], w0

    def _energy(self, q, x, pi=None):
        """Kinetic energy [J] at generalized velocities ``x (..., d)``, shape ``(...)``."""
        cols, inv = self._energy_map
        return energy_regressor(self.geometry, q, *self._split(x), columns=cols, weights=inv @ self._pi(pi))

    def _energy_coefficients(self, q, x):
        """:meth:`_energy` as a linear map of ``pi``, shape ``(..., k)``."""
        cols, inv = self._energy_map
        return energy_regressor(self.geometry, q, *self._split(x), columns=cols) @ inv

    def inertia(self, q, pi=None) -> np.ndarray:
        """Generalized inertia with zero linear momentum, over ``x = [qd, w0]``.

        Parameters
        ----------
        q : array_like of shape (..., n_joints)
        pi : array_like of shape (k,), optional
            Parameters to evaluate it for (default: the estimate).

        Returns
        -------
        ndarray of shape (..., d, d)
            ``M`` with ``T = 1/2 x^T M x``; ``d = n_joints + 1`` (planar: the yaw rate) or
            ``n_joints + 3``. Rows ``n_joints:`` are the angular momentum in base axes per unit rate.
        """
        d = self._dim
        q = np.asarray(q, float)[..., None, :]
        return _polarize(self._energy(q, _polarization_rates(d), pi), d)

    def _inertia_coefficients(self, q) -> np.ndarray:
        """``inertia(q)`` as a linear map of ``pi``, shape ``(..., d, d, k)``."""
        d = self._dim
        t = self._energy_coefficients(np.asarray(q, float)[..., None, :], _polarization_rates(d))
        return np.moveaxis(_polarize(np.moveaxis(t, -1, -2), d), -3, -1)

    def kinetic_energy(self, q, qd, w0, pi=None) -> np.ndarray:
        """Kinetic energy [J] with zero linear momentum, shape ``(...)``.

        ``q, qd`` of shape ``(..., n_joints)``, ``w0`` of shape ``(..., 3)`` [rad/s] in base axes.
        """
        return self._energy(q, self._rates(qd, w0), pi)

    def kinetic_energy_cov(self, q, qd, w0) -> np.ndarray:
        """Covariance [J^2] of :meth:`kinetic_energy` from ``cov``, shape ``(N, N)`` over the
        ``N`` samples (flattened): exact, the energy is linear in ``pi``."""
        a = self._energy_coefficients(q, self._rates(qd, w0)).reshape(-1, len(self.values))
        return a @ self.cov @ a.T

    def _rates(self, qd, w0):
        """Generalized velocities ``x = [qd, w0 components]``, shape ``(..., d)``."""
        qd, w0 = np.asarray(qd, float), np.asarray(w0, float)[..., self._axes]
        lead = np.broadcast_shapes(qd.shape[:-1], w0.shape[:-1])
        return np.concatenate([np.broadcast_to(a, lead + a.shape[-1:]) for a in (qd, w0)], -1)

    def reduced_inertia(self, q, pi=None) -> np.ndarray:
        """Free-floating joint inertia ``H* = A - B D^-1 B^T`` [kg m^2, kg m, kg], shape
        ``(..., n_joints, n_joints)``: the joints' inertia with the base moving so that the
        linear and angular momentum stay zero (``T = 1/2 qd^T H* qd`` then)."""
        return _schur(self.inertia(q, pi), self.geometry.n_joints)[0]

    def reduced_inertia_cov(self, q) -> np.ndarray:
        """Covariance of :meth:`reduced_inertia` from ``cov``, first order (``H*`` is rational in
        ``pi``; ``M`` linear), shape ``(..., n, n, n, n)``: ``[..., i, j, a, b] = cov(H*_ij, H*_ab)``."""
        n = self.geometry.n_joints
        coef = self._inertia_coefficients(q)
        _, x = _schur(coef @ self.values, n)  # x = D^-1 B^T, (..., d - n, n)
        c, x = np.moveaxis(coef, -1, -3), x[..., None, :, :]  # (..., k, d, d): one matrix per pi_k
        cx = c[..., :n, n:] @ x
        jac = c[..., :n, :n] - cx - np.swapaxes(cx, -1, -2) + np.swapaxes(x, -1, -2) @ c[..., n:, n:] @ x  # dH*/dpi_k
        return np.einsum("...kij,kl,...lab->...ijab", jac, self.cov, jac)

    # ---------------------------------------------------------------- motion ------------------

    def _momentum_base(self, momentum, attitude):
        """Angular momentum in base axes, ``(..., 3)``, from the inertial one and the attitude."""
        h = self.identification.momentum if momentum is None else np.asarray(momentum, float)
        if attitude is None:
            return h
        return np.einsum("...ji,...j->...i", quat_to_matrix(attitude), h)

    def base_rate(self, q, qd, momentum=None, attitude=None) -> np.ndarray:
        """Base angular velocity [rad/s] in base axes that conservation of momentum implies.

        Parameters
        ----------
        q, qd : array_like of shape (..., n_joints)
        momentum : array_like of shape (..., 3), optional
            Inertial angular momentum [N m s] (default: the identification's).
        attitude : array_like of shape (..., 4), optional
            Base attitude ``[w, x, y, z]`` (default identity: ``momentum`` is in base axes).

        Returns
        -------
        ndarray of shape (..., 3)
            x, y zero for planar systems (the yaw rate is the z component).
        """
        return base_rate(self.param, self.values, q, qd, self._momentum_base(momentum, attitude))

    def bias_torque(self, q, qd, momentum=None, attitude=None) -> np.ndarray:
        """Velocity-product joint torques [N m or N], shape ``(..., n_joints)``: the joint
        dynamics are ``H*(q) qdd = tau - bias_torque(q, qd)`` (docs/theory/control.md).

        ``momentum``, ``attitude`` as in :meth:`base_rate`.
        """
        return self._joint_dynamics(q, qd, momentum, attitude)[1]

    def forward_dynamics(self, q, qd, tau, momentum=None, attitude=None) -> np.ndarray:
        """Joint accelerations [rad/s^2 or m/s^2] under joint torques ``tau`` (a reaction
        wheel's torque among them), momentum conserved and linear momentum zero.

        Parameters
        ----------
        q, qd, tau : array_like of shape (..., n_joints)
            ``tau`` in [N m] (revolute) or [N] (prismatic).
        momentum, attitude
            As in :meth:`base_rate`.

        Returns
        -------
        ndarray of shape (..., n_joints)
        """
        reduced, bias = self._joint_dynamics(q, qd, momentum, attitude)
        return np.linalg.solve(reduced, (np.asarray(tau, float) - bias)[..., None])[..., 0]

    def inverse_dynamics(self, q, qd, qdd, momentum=None, attitude=None) -> np.ndarray:
        """Joint torques [N m or N] that give joint accelerations ``qdd``, momentum conserved and
        linear momentum zero: ``H*(q) qdd + bias_torque(q, qd)``, shape ``(..., n_joints)`` (the
        inverse of :meth:`forward_dynamics`; e.g. a computed-torque law or its feed-forward).

        ``q, qd, qdd`` of shape ``(..., n_joints)``; ``momentum``, ``attitude`` as in :meth:`base_rate`.
        """
        reduced, bias = self._joint_dynamics(q, qd, momentum, attitude)
        return (reduced @ np.asarray(qdd, float)[..., None])[..., 0] + bias

    def _joint_dynamics(self, q, qd, momentum, attitude):
        """``(H*, bias)`` of ``H* qdd = tau - bias``: Lagrange's equations of the joints and
        Euler's of the base, the base acceleration eliminated (docs/theory/control.md)."""
        q, qd = np.asarray(q, float), np.asarray(qd, float)
        n = self.geometry.n_joints
        x = self._rates(qd, self.base_rate(q, qd, momentum, attitude))
        m, dm_x = self.inertia(q), self._inertia_derivative_times(q, x)  # dm_x: (..., n, d)
        mdot_x = np.einsum("...ka,...k->...a", dm_x, qd)
        grad = 0.5 * np.einsum("...a,...ka->...k", x, dm_x)
        c_b = mdot_x[..., n:]
        if not self.geometry.planar:  # Euler: dh/dt = h x w0 in base axes (a planar h_z stays)
            c_b = c_b - np.cross((m[..., n:, :] @ x[..., None])[..., 0], x[..., n:])
        reduced, xb = _schur(m, n)  # xb = D^-1 B^T
        return reduced, mdot_x[..., :n] - grad - (np.swapaxes(xb, -1, -2) @ c_b[..., None])[..., 0]

    def _inertia_times(self, q, x) -> np.ndarray:
        """``inertia(q) @ x``, shape ``(..., d)``, from the energies at ``x``, ``e_i`` and
        ``x + e_i`` (``2 d + 1`` of them, where the whole matrix takes ``d (d + 1) / 2``)."""
        d, x = self._dim, np.asarray(x, float)[..., None, :]
        rates = np.concatenate(np.broadcast_arrays(x, np.eye(d), x + np.eye(d)), -2)
        t = self._energy(np.asarray(q, float)[..., None, :], rates)
        return t[..., 2 * d : 3 * d] - t[..., :d] - t[..., d : 2 * d]

    def _inertia_derivative_times(self, q, x) -> np.ndarray:
        """``dM/dq_k @ x``, shape ``(..., n, d)``: exact stencils (the module docstring)."""
        n = self.geometry.n_joints
        revolute = np.array([b.joint_type == "revolute" for b in self.geometry.bodies[1:]])
        steps = np.where(revolute[:, None], _ANGLES, [_SLIDE, -_SLIDE, 0.0, 0.0])  # (n, 4)
        weights = np.where(revolute[:, None], _ANGLE_WEIGHTS, [0.5 / _SLIDE, -0.5 / _SLIDE, 0.0, 0.0])
        shifted = np.asarray(q, float)[..., None, None, :] + steps[..., None] * np.eye(n)[:, None, :]
        m_x = self._inertia_times(shifted, np.asarray(x, float)[..., None, None, :])  # (..., n, 4, d)
        return np.einsum("...kja,kj->...ka", m_x, weights)


def _to_inertial(rows: np.ndarray, attitude) -> np.ndarray:
    """Stacked base-axes 3-vectors ``rows (..., 6, m)`` in inertial axes (identity if ``attitude`` is None)."""
    if attitude is None:
        return rows
    rot = quat_to_matrix(attitude)
    return np.concatenate([rot @ rows[..., :3, :], rot @ rows[..., 3:, :]], -2)


def _schur(m: np.ndarray, n: int):
    """``(A - B D^-1 B^T, D^-1 B^T)`` of the blocks ``A = m[:n, :n]``, ``B = m[:n, n:]``,
    ``D = m[n:, n:]`` of ``m (..., d, d)``."""
    x = np.linalg.solve(m[..., n:, n:], np.swapaxes(m[..., :n, n:], -1, -2))
    return m[..., :n, :n] - m[..., :n, n:] @ x, x


def _fixed_by_pi(param: Parameterization, n_configurations: int = 8) -> dict:
    """Whether ``pi`` fixes the total mass and the system CM (base axes, at seeded random
    configurations), to first order at the model's own inertial values; and the CM once the total
    mass is known too. Gradients by central differences (``pi`` and the CM are rational in the
    standard parameters ``theta``)."""
    model = param.model
    inertials = np.array([b.inertial for b in model.bodies])
    free = tuple(np.array([(i, k) for i, b in enumerate(model.bodies)
                           for k, n in enumerate(INERTIAL_NAMES) if n not in b.known_zero]).T)
    q = np.random.default_rng(param.seed).uniform(-1.0, 1.0, (n_configurations, model.n_joints))
    plane = slice(0, 2) if model.planar else slice(0, 3)
    st = body_states(model, q, np.zeros_like(q), np.zeros(3))

    def quantities(theta):
        values = inertials.copy()
        values[free] = theta
        first = values[:, :1] * st.position + np.einsum("...bij,bj->...bi", st.rotation, values[:, 1:4])
        mass = values[:, 0].sum()
        com = first.sum(-2)[:, plane] / mass
        return np.r_[param.projection @ full_values(model.with_inertials(values)), mass, com.ravel()]

    theta, step = inertials[free], 1e-4  # central differences: exact in all but the masses (1/M)
    jac = np.stack([quantities(theta + e) - quantities(theta - e) for e in step * np.eye(len(theta))], -1) / (2 * step)
    k = param.n_params

    def fixed(rows, grads):
        with one_blas_thread():
            _, s, vt = svd(rows, full_matrices=False)
        basis = vt[s > 1e-9 * s[0]]
        outside = grads - (grads @ basis.T) @ basis
        return bool(np.linalg.norm(outside) <= _FIXED_TOL * np.linalg.norm(grads))

    return {"total_mass": fixed(jac[:k], jac[k : k + 1]), "system_com": fixed(jac[:k], jac[k + 1 :]),
            "system_com_given_mass": fixed(jac[: k + 1], jac[k + 1 :])}
