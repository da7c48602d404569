"""The stacked momentum equations of a log (the paper's Eq. 4) and the anchors of their scale.

The momentum equations of sample n, ``Y(x_n) pi = R0(x_n)^T h``, are built from measured
signals ``x_n = [q, qd, w0, attitude]``: an errors-in-variables problem (docs/theory/noise.md).

Scale. A known nonzero momentum fixes pi absolutely. With zero or unknown momentum (its inertial
components then estimated with pi) the equations are homogeneous and need an anchor: known
parameter values (``known=``), or the spin momentum of reaction wheels, whose rotor-inertia
parameter the model gives (CAD) and whose columns therefore move to the right-hand side
(:func:`resolve_anchors`).
"""

from __future__ import annotations

import re
from dataclasses import dataclass, replace

import numpy as np

from .._errors import SpaceidError
from ..data import Log, quat_to_matrix
from ..dynamics import Parameterization, skew
from ._drift import drift_basis, drift_names
from ._noise import FD_STEP, signal_jacobian

__all__ = ["resolve_anchors"]


def _symbols(definition: str) -> set:
    return set(re.findall(r"[A-Za-z_][A-Za-z_0-9]*", definition))


def resolve_anchors(param: Parameterization, known: dict, where: str) -> dict:
    """The known minimal parameters that anchor the scale of the momentum equations.

    Reaction-wheel rotor inertias come from the model (CAD) first; the ``known`` values then add
    to them or override them, each named by its minimal-parameter name or by the physical
    parameter that a minimal parameter equals alone (e.g. ``Iczz_wheel``).

    Parameters
    ----------
    param : Parameterization
        Minimal parameter set of the model; its ``true_values`` give the rotor inertias.
    known : dict of str to float
        Known values ``{name: value}``, in the SI units of each parameter.
    where : str
        Name of the data source, for error messages.

    Returns
    -------
    dict of int to tuple of (float, str)
        ``{index: (value, source)}``: index into ``param.names``, source ``"given"`` or
        ``"reaction wheel JOINT (model)"``.

    Raises
    ------
    SpaceidError
        A name in ``known`` is neither a minimal parameter nor a physical parameter that one
        equals alone (the message lists those that are), or two names set the same parameter.
    """
    out = {}
    for joint in param.model.wheels:
        body = next(b.name for b in param.model.bodies if b.joint == joint)
        for i, d in enumerate(param.definitions):
            if all(s.endswith(f"_{body}") for s in _symbols(d)):
                out[i] = (float(param.true_values[i]), f"reaction wheel {joint} (model)")
    given = {}  # index: the name it was given by
    alone = {d.strip(): i for i, d in enumerate(param.definitions) if re.fullmatch(r"\s*[A-Za-z_][A-Za-z_0-9]*\s*", d)}
    for name, value in known.items():
        i = param.names.index(name) if name in param.names else alone.get(name)
        if i is None:
            hint = ", ".join(f"{param.names[j]} = {d}" for d, j in alone.items()) or "none"
            raise SpaceidError(
                f"{where}: `known` {name}: not a minimal parameter ({param.names[0]}..{param.names[-1]}) nor a "
                f"physical parameter that one equals alone (those are: {hint}); the definitions: param.definitions, "
                "or 'spaceid model'"
            )
        if i in given:
            raise SpaceidError(f"{where}: `known` {given[i]} and `known` {name} both set {param.names[i]} "
                               f"(= {param.definitions[i].strip()}): give it once")
        given[i] = name
        out[i] = (float(value), "given")
    return out


def _rotvec_matrix(v):
    """Rotation matrices ``(n, 3, 3)`` of rotation vectors ``(n, 3)`` (Rodrigues)."""
    angle = np.linalg.norm(v, axis=-1)[:, None, None]
    k = skew(v)
    a = np.where(angle > 1e-8, np.sin(angle) / np.where(angle > 0, angle, 1), 1 - angle**2 / 6)
    b = np.where(angle > 1e-8, (1 - np.cos(angle)) / np.where(angle > 0, angle, 1) ** 2, 0.5 - angle**2 / 24)
    return np.eye(3) + a * k + b * (k @ k)


@dataclass(frozen=True)
class Equations:
    """The momentum equations of a log as ``Phi_n(x) [theta; 1] = 0``, sample by sample.

    ``theta`` holds the free minimal parameters, then, when the momentum is unknown, its inertial
    components at the first sample (z only for planar systems), then with ``bias`` a correction
    ``db`` of the gyro bias already subtracted from the measured base rate (per base axis; z only for
    planar systems; :mod:`spaceid.estimation._gyro_bias`), then the drift coefficients
    (:mod:`spaceid.estimation._drift`): the momentum at sample n is ``h0 + sum_k d_k g_k(t_n)``.
    ``x (n, n_x)`` are the signals
    ``[q, qd, w0 (z only if planar), dtheta (spatial)]``, ``dtheta`` a small rotation of the
    measured attitude in base axes (``R0 = R0_meas exp([dtheta]x)``).
    """

    param: Parameterization
    rot: np.ndarray  # (n, 3, 3) measured base-to-inertial rotations
    free: np.ndarray  # indices of the estimated minimal parameters
    known: np.ndarray  # indices of the known ones ...
    known_values: np.ndarray  # ... and their values
    momentum: np.ndarray | None  # (3,) inertial [N m s] at the first sample, None when estimated
    drift: tuple = ()  # names of the drift coefficients (torque_z, viscous, ...)
    basis: np.ndarray | None = None  # (n, n_d, 3) their momentum change per unit, inertial axes
    bias: np.ndarray | None = None  # (n, rows, n_b) the columns of db: minus the locked inertia, base rate -> momentum

    @property
    def planar(self):
        return self.param.model.planar

    @property
    def axes(self):
        return [2] if self.planar else [0, 1, 2]

    @property
    def n_h(self):
        return 0 if self.momentum is not None else len(self.axes)

    @property
    def n_b(self):
        return 0 if self.bias is None else self.bias.shape[-1]

    @property
    def p(self):
        return len(self.free) + self.n_h + self.n_b + len(self.drift)

    def names(self):
        h = [f"h_{'xyz'[a]}" for a in self.axes] if self.n_h else []
        b = [f"gyro_bias_{'xyz'[a]}" for a in self.axes] if self.n_b else []
        return [self.param.names[i] for i in self.free] + h + b + list(self.drift)

    @property
    def rate_channels(self) -> slice:
        """The rates' columns of the signals ``x``: joint rates, then the base rate's (the equations are linear in them)."""
        nj = len(self.param.model.joints)
        return slice(nj, 2 * nj + len(self.axes))

    def bias_values(self, theta):
        """The gyro-bias correction ``db (n_b,)`` of ``theta`` [rad/s] (empty without ``bias``)."""
        start = len(self.free) + self.n_h
        return np.asarray(theta[start : start + self.n_b], float)

    def signals(self, log: Log) -> np.ndarray:
        att = np.zeros((log.n_samples, 0 if self.planar else 3))
        return np.hstack([log.q, log.qd, log.base_w[:, self.axes], att])

    def unpack(self, x):
        nj = len(self.param.model.joints)
        w = np.zeros((len(x), 3))
        w[:, self.axes] = x[:, 2 * nj : 2 * nj + len(self.axes)]
        turn = x[:, 2 * nj + 3 :]  # none when the attitude is not corrected (no attitude noise): R0 as measured
        rot = self.rot if self.planar or not turn.any() else self.rot @ _rotvec_matrix(turn)
        return x[:, :nj], x[:, nj : 2 * nj], w, rot

    def full(self, theta):
        """All minimal parameters ``(k,)`` and the inertial momentum ``(3,)`` of ``theta``."""
        pi = np.empty(self.param.n_params)
        pi[self.known], pi[self.free] = self.known_values, theta[: len(self.free)]
        h = self.momentum
        if h is None:
            h = np.zeros(3)
            h[self.axes] = theta[len(self.free) : len(self.free) + self.n_h]
        return pi, h

    def drift_values(self, theta):
        """The drift coefficients ``(n_d,)`` of ``theta``."""
        return np.asarray(theta[len(theta) - len(self.drift) :], float)

    def base_momentum(self, theta, rot=None):
        """The momentum of ``theta`` in base axes at every sample, ``(n, 3)`` [N m s]:
        ``R0^T (h0 + sum_k d_k g_k(t_n))``, with the rotations ``rot`` (default: the measured)."""
        rot = self.rot if rot is None else rot
        h = self.full(theta)[1]
        if not self.drift:
            return np.einsum("nji,j->ni", rot, h)
        return np.einsum("nji,nj->ni", rot, h + np.einsum("nki,k->ni", self.basis, self.drift_values(theta)))

    def phi(self, x) -> np.ndarray:
        """``[A | -b]`` of every sample: ``(n, rows, p + 1)``."""
        q, qd, w, rot = self.unpack(x)
        return self._stack(lambda out: self.param.regressor(q, qd, w, out=out), np.swapaxes(rot, -1, -2))

    def _stack(self, regressor, rot_t, primal=True) -> np.ndarray:
        """``[A | -b]`` from the regressor, ``regressor(out)`` of shape ``(n, rows, k)`` (written
        into ``out`` when that is not None), and the transposed base rotations ``rot_t (n, 3, 3)``:
        linear in the pair, so derivatives of both give that of :meth:`phi` (``primal`` False: the
        gyro-bias columns, fixed, have none)."""
        rot_t = rot_t[:, 2:3] if self.planar else rot_t  # R0^T, the rows of the equations
        out = np.empty((len(rot_t), self.param.rows, self.p + 1))
        if not len(self.known):  # every parameter free: the regressor is written in place
            y, at = regressor(out[..., : self.param.n_params]), self.param.n_params
        else:  # the free columns as contiguous runs: slice copies, several times faster than a gather
            y, at = regressor(None), 0
            for run in np.split(self.free, np.flatnonzero(np.diff(self.free) > 1) + 1):
                out[..., at : at + len(run)] = y[..., run[0] : run[-1] + 1]
                at += len(run)
        b = -(y[..., self.known] @ self.known_values)
        if self.momentum is not None:
            b = b + rot_t @ self.momentum
        out[..., at:-1] = self._attitude_columns(rot_t, primal)
        out[..., -1] = -b
        return out

    def _attitude_columns(self, rot_t, primal=True):
        """The columns of the unknown momentum, the gyro-bias correction and the drift, ``(n, rows,
        n_h + n_b + n_d)``, from the rows ``rot_t`` of ``R0^T``: minus the momentum's components in
        base axes, per unit; the bias columns as given (zero when not ``primal``: a derivative)."""
        columns = [-rot_t[..., self.axes]] if self.momentum is None else []
        if self.n_b:
            columns.append(self.bias if primal else np.zeros_like(self.bias))
        if self.drift:  # the momentum change, in base axes, per unit drift coefficient
            columns.append(-np.einsum("nri,nki->nrk", rot_t, self.basis))
        return np.concatenate(columns, -1) if columns else np.zeros(rot_t.shape[:-1] + (0,))

    def _rotation_derivative(self, x, v):
        """Derivative of ``R0^T (n, 3, 3)`` along ``v``: central differences of step ``FD_STEP``
        in the largest component of each sample's ``v`` (zero for planar systems)."""
        if self.planar:
            return np.zeros_like(self.rot)
        scale = np.max(np.abs(v), axis=1)
        step = FD_STEP / np.where(scale > 0, scale, 1.0)
        turned = [self.unpack(x + sign * step[:, None] * v)[3] for sign in (1, -1)]
        return np.swapaxes(turned[0] - turned[1], -1, -2) / (2 * step[:, None, None])

    def linearized(self, x, v, *, primal=True) -> np.ndarray:
        """:meth:`phi` linearised at ``x`` and evaluated at ``x + v`` (``v (n, n_x)``), or without
        ``primal`` its directional derivative along ``v``: the regressor's by
        :meth:`~spaceid.dynamics.Parameterization.linearized_regressor`, the attitude's by central
        differences, each of step ``FD_STEP`` in the largest component of a sample's ``v``."""
        q, qd, w, rot = self.unpack(x)
        direction = self.unpack(v)[:3]

        def regressor(out):
            return self.param.linearized_regressor(q, qd, w, direction, step=FD_STEP, primal=primal, out=out)

        d_rot_t = self._rotation_derivative(x, v)
        return self._stack(regressor, np.swapaxes(rot, -1, -2) + d_rot_t if primal else d_rot_t, primal)

    def dphi(self, x, v) -> np.ndarray:
        """Directional derivative of :meth:`phi` along ``v (n, n_x)`` (:meth:`linearized`)."""
        return self.linearized(x, v, primal=False)

    def contracted_dphi(self, x, v, u) -> np.ndarray:
        """``sum_n u_n^T dA_n[v_n]``, shape ``(p,)``: the derivative along ``v (n, n_x)`` of the
        columns ``A`` of :meth:`phi`, contracted with ``u (n, rows)``, without forming it
        (:meth:`~spaceid.dynamics.Parameterization.contracted_tangent`)."""
        q, qd, w, _ = self.unpack(x)
        y = self.param.contracted_tangent(q, qd, w, self.unpack(v)[:3], u, step=FD_STEP)
        d_rot_t = self._rotation_derivative(x, v)
        extra = self._attitude_columns(d_rot_t[:, 2:3] if self.planar else d_rot_t, primal=False)
        return np.concatenate([y[self.free], np.einsum("nrk,nr->k", extra, u)])

    def jacobian(self, x, theta) -> np.ndarray:
        """``d(Phi theta_bar)/dx``: ``(n, rows, n_x)`` (see :func:`spaceid.estimation.signal_jacobian`)."""
        q, qd, w, rot = self.unpack(x)
        return signal_jacobian(self.param, self.full(theta)[0], q, qd, w, self.base_momentum(theta, rot))

    def error(self, x, theta, jac) -> np.ndarray:
        """``Phi(x) [theta; 1]``, the equation error of every sample ``(n, rows)`` [N m s], from the
        signal Jacobian ``jac = self.jacobian(x, theta)`` and without the regressor: the momentum is
        linear in the rates, so the rate columns of ``jac`` times the rates are the momentum."""
        rates = self.rate_channels
        h = self.base_momentum(theta, self.unpack(x)[3])
        error = np.einsum("nrx,nx->nr", jac[..., rates], x[:, rates]) - (h[:, 2:3] if self.planar else h)
        return error + self.bias @ self.bias_values(theta) if self.n_b else error

    def select(self, rows: slice) -> "Equations":
        """The equations of the samples ``rows`` (their attitudes and drift basis)."""
        return replace(self, rot=self.rot[rows], basis=None if self.basis is None else self.basis[rows],
                       bias=None if self.bias is None else self.bias[rows])


def _split(phi):
    """``A (n rows, p)`` and ``b (n rows,)`` of stacked ``[A | -b]``."""
    flat = phi.reshape(-1, phi.shape[-1])
    return flat[:, :-1], -flat[:, -1]


def equation_residuals(phi, theta, rhs: float = 1.0) -> np.ndarray:
    """``A theta - rhs b`` ``(n, rows)`` of stacked ``phi = [A | -b] (n, rows, p + 1)`` (the residuals of
    ``theta``; ``rhs`` 0: ``A theta`` alone): one product of the rows (a product per sample, as ``phi @ v``
    forms it, took three times longer)."""
    return (phi.reshape(-1, phi.shape[-1]) @ np.append(theta, rhs)).reshape(phi.shape[:2])


def drift_basis_at(log, drift, history, where):
    """:func:`drift_basis` of ``log``, or integrated over ``history`` and taken at ``log``'s stamps."""
    if history is None:
        return drift_basis(log, drift)
    if not (history.t[0] <= log.t[0] and log.t[-1] <= history.t[-1] + 1e-9):
        raise SpaceidError(f"{where}: the history ({history.t[0]:.6g}..{history.t[-1]:.6g} s) does not span the log "
                           f"({log.t[0]:.6g}..{log.t[-1]:.6g} s): give the record the log was cut from")
    g = drift_basis(history, drift)
    return np.stack([np.stack([np.interp(log.t, history.t, g[:, k, i]) for i in range(3)], -1)
                     for k in range(g.shape[1])], 1)


def _equations(param, log, momentum, known, where, drift=(), history=None, *, scale_free=False) -> tuple:
    """The equations of ``log`` (with the drift kinds ``drift``, integrated over ``history`` if
    given) and the anchors used, as records for the settings of a result (see
    :func:`spaceid.estimation.identify`); ``scale_free``: homogeneous equations allowed (a prior
    sets the scale)."""
    anchors = resolve_anchors(param, dict(known or {}), where)
    homogeneous = momentum is None or not np.linalg.norm(momentum) > 0
    if homogeneous and not anchors and not scale_free:
        state = "unknown" if momentum is None else "zero"
        raise SpaceidError(
            f"{where}: the momentum is {state}, so the equations are homogeneous and fix the parameters only up to "
            "scale: give the nonzero momentum of the run (`momentum`), or anchor the scale with a known parameter "
            "(`known` NAME=VALUE, e.g. a reaction-wheel rotor inertia)"
        )
    idx = np.array(sorted(anchors), int)
    free = np.setdiff1d(np.arange(param.n_params), idx)
    values = np.array([anchors[i][0] for i in idx], float)
    names = drift_names(drift, param.model.planar)[0]
    eq = Equations(param, quat_to_matrix(log.base_quat), free, idx, values, momentum, names,
                   drift_basis_at(log, drift, history, where) if names else None)
    return eq, [{"name": param.names[i], "definition": param.definitions[i], "value": anchors[i][0],
                 "source": anchors[i][1]} for i in idx]  # fmt: skip
