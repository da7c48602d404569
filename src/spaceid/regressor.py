"""Momentum regressor ``h = Y(q, qd, w0) pi`` and its minimal parameter set, for any tree.

The full regressor (MATH.md sec. 4) is linear in the standard inertial parameters ``theta``
of every body and in the lumped products ``phi_ab = theta_a theta_b / M`` of the first-order
ones (masses and first moments), once zero linear momentum has eliminated the base velocity:

    h = sum_i [ I_i w_i + m_i s_i x u_i ] - (1/M) (sum_i m_i s_i) x (sum_j m_j u_j)

The minimal set ``pi = P @ [theta, phi]`` is found numerically from the regressor stacked at
seeded random states, with a recorded rank tolerance. Two bases are offered for it:

* ``planar``: for planar trees of revolute joints, the coefficients of the body-pair functions
  ``w_b``, ``cos(D_ab) (w_a + w_b)`` and ``sin(D_ab) (w_a + w_b)`` (``D_ab`` the angle of body b
  relative to body a). For Cepheus these are exactly the paper's 8 parameters (Appendix B).
* ``columns``: otherwise, the independent columns of the full regressor taken greedily in a
  fixed order (a QR without pivoting on unit-norm columns), each absorbing the dependent ones.

Both are the same engine: the planar basis is only a change of coordinates on the z row of the
spatial regressor, fitted and checked at the random states.

References
----------
.. [1] Papadopoulos et al., Eq. 2 and Eq. 9-10 (minimum parameter set), Appendix B.
"""

from __future__ import annotations

import functools
import re
from dataclasses import dataclass, field, replace

import numpy as np
from scipy.linalg import solve_triangular

from ._errors import SpaceidError
from .kinematics import body_states, skew
from .model import INERTIAL_NAMES, Model

__all__ = [
    "Parameterization",
    "minimal_parameters",
    "full_regressor",
    "energy_regressor",
    "full_parameter_names",
    "full_values",
    "identifiability",
]

RANK_TOL = 1e-9
"""Default rank tolerance: a column (or basis row) is dependent when the part of it that the
previous ones do not explain is below this fraction of its norm (unit-norm columns)."""


# Khalil's names of the standard parameters (about the body frame origin), as in the literature
KHALIL = dict(zip(INERTIAL_NAMES, ("M", "MX", "MY", "MZ", "XX", "XY", "YY", "XZ", "YZ", "ZZ")))


def _layout(model: Model):
    """Index tables of the full parameter vector ``[theta, phi]`` (declared zeros left out).

    Returns ``theta`` as (body, parameter index) pairs, ``first`` as (body, component) pairs of
    the first-order parameters (mass and first moments), and ``pairs`` as index pairs into
    ``first`` (a <= c), one lumped product ``first[a] * first[c] / M`` each.
    """
    theta = [(i, k) for i, b in enumerate(model.bodies) for k, n in enumerate(INERTIAL_NAMES) if n not in b.known_zero]
    first = [(i, k) for i, k in theta if k < 4]
    pairs = [(a, c) for a in range(len(first)) for c in range(a, len(first))]
    return theta, first, pairs


def full_parameter_names(model: Model) -> list:
    """Names of the full parameter vector ``[theta, phi]``, valid SymPy expressions.

    Standard parameters in Khalil's notation, ``M_link1``, ``MX_link1`` .. ``ZZ_link1`` (mass,
    first moments, inertia about the body frame origin); lumped products ``M_base*MX_link1/M``
    with ``M`` the total mass.
    """
    theta, first, pairs = _layout(model)
    ident = [re.sub(r"\W", "_", b.name) for b in model.bodies]
    names = [f"{KHALIL[INERTIAL_NAMES[k]]}_{ident[i]}" for i, k in theta]
    return names + [f"{names[theta.index(first[a])]}*{names[theta.index(first[c])]}/M" for a, c in pairs]


def full_values(model: Model) -> np.ndarray:
    """Values of the full parameter vector, shape ``(n_full,)``, order of ``full_parameter_names``."""
    theta, first, pairs = _layout(model)
    values = [model.bodies[i].inertial[k] for i, k in theta]
    f = [model.bodies[i].inertial[k] for i, k in first]
    return np.array(values + [f[a] * f[c] / model.mass for a, c in pairs])


def _body_angular(r, w):
    """Body-axes angular velocity and the map ``I6 -> I @ w_body`` of the inertia entries."""
    wb = np.einsum("...ji,...j->...i", r, w)
    zero = np.zeros(wb.shape[:-1])
    wx, wy, wz = wb[..., 0], wb[..., 1], wb[..., 2]
    lw = np.stack(  # I @ wb as a linear map of [Ixx, Ixy, Iyy, Ixz, Iyz, Izz]
        [
            np.stack([wx, wy, zero, wz, zero, zero], -1),
            np.stack([zero, wx, wy, zero, wz, zero], -1),
            np.stack([zero, zero, zero, wx, wy, wz], -1),
        ],
        -2,
    )
    return wb, lw


def _plan(model: Model, columns):
    """Where each requested column comes from: per body, (output position, block index) of
    its standard parameters; for lumped products the output positions, factor indices into
    the first-order parameters and the weight 1/2 for a product with itself."""
    theta, first, pairs = _layout(model)
    cols = np.arange(len(theta) + len(pairs)) if columns is None else np.asarray(columns, dtype=int)
    per_body: dict = {}
    for n, c in enumerate(cols):
        if c < len(theta):
            per_body.setdefault(theta[c][0], ([], []))
            per_body[theta[c][0]][0].append(n)
            per_body[theta[c][0]][1].append(theta[c][1])
    lumped = np.flatnonzero(cols >= len(theta))
    a, b = (np.array([pairs[cols[n] - len(theta)] for n in lumped], dtype=int).reshape(-1, 2).T)
    if len(lumped) and np.array_equal(lumped, np.arange(lumped[0], lumped[0] + len(lumped))):
        lumped = slice(lumped[0], lumped[0] + len(lumped))  # the usual case: a slice writes faster
    body, comp = np.array(first, dtype=int).reshape(-1, 2).T
    return len(cols), per_body, (lumped, a, b, np.where(a == b, 0.5, 1.0), body, comp)


def _regressor(model: Model, q, qd, w0, columns, *, energy: bool, chunk: int = 512):
    """Regressor columns over any leading shape, evaluated in chunks of samples.

    Chunks keep the temporaries of the lumped products in cache: for a 15-body tree this is
    several times faster than one pass over 10^4 samples.
    """
    q, qd, w0 = (np.asarray(a, dtype=float) for a in (q, qd, w0))
    lead = np.broadcast_shapes(q.shape[:-1], qd.shape[:-1], w0.shape[:-1])
    flat = [np.broadcast_to(a, lead + a.shape[-1:]).reshape(-1, a.shape[-1]) for a in (q, qd, w0)]
    plan = _plan(model, columns)
    n = flat[0].shape[0]
    y = np.concatenate(
        [_regressor_chunk(model, *(a[i : i + chunk] for a in flat), plan, energy=energy) for i in range(0, max(n, 1), chunk)]
    )
    return y.reshape(lead + y.shape[1:])


def _regressor_chunk(model: Model, q, qd, w0, plan, *, energy: bool):
    """Momentum (``(n, 3, n_cols)``) or kinetic-energy (``(n, n_cols)``) regressor columns.

    Per body, relative to the base origin (velocities without the base origin's motion):
    momentum ``m p x v + (p x (w x R mc) + R mc x v) + R I w_b`` and energy
    ``m |v|^2 / 2 + v . (w x R mc) + w_b . I w_b / 2``. Zero linear momentum subtracts
    ``(sum m s) x (sum m u) / M`` and ``|sum m u|^2 / (2 M)`` respectively, whose factors are
    linear in the first-order parameters: ``sum m s = sum A a``, ``sum m u = sum B a``.
    """
    n_cols, per_body, (lumped, a, b, half, body, comp) = plan
    st = body_states(model, q, qd, w0)
    rot, pos, omg, vel = st.rotation, st.position, st.omega, st.velocity
    out = np.empty((len(q),) + (() if energy else (3,)) + (n_cols,))
    for i, (where, which) in per_body.items():
        r, p, w, v = rot[:, i], pos[:, i], omg[:, i], vel[:, i]
        wb, lw = _body_angular(r, w)
        if energy:
            block = np.concatenate(
                [0.5 * (v * v).sum(-1)[..., None], np.einsum("...j,...jk->...k", np.cross(v, w), r),
                 0.5 * np.einsum("...j,...jk->...k", wb, lw)], -1
            )
        else:
            block = np.concatenate([np.cross(p, v)[..., None], (skew(p) @ skew(w) - skew(v)) @ r, r @ lw], -1)
        out[..., where] = block[..., which]
    if len(a):
        # A, B columns of every first-order parameter: p, R e_k and their derivatives v, w x R e_k
        first_a = np.concatenate([pos[..., None], rot], -1)  # (n, bodies, 3, 4)
        first_b = np.concatenate([vel[..., None], skew(omg) @ rot], -1)
        # adjacent advanced indices keep the sample axis in place: (n, n_first, 3)
        first_a = np.swapaxes(first_a, -1, -2)[:, body, comp, :]
        first_b = np.swapaxes(first_b, -1, -2)[:, body, comp, :]
        ub, ua = np.moveaxis(first_b[:, b], -1, 0), np.moveaxis(first_b[:, a], -1, 0)  # (3, n, n_pairs)
        if energy:
            out[..., lumped] = -half * (ua[0] * ub[0] + ua[1] * ub[1] + ua[2] * ub[2])
        else:
            sa, sb = np.moveaxis(first_a[:, a], -1, 0), np.moveaxis(first_a[:, b], -1, 0)
            for k, (i, j) in enumerate(((1, 2), (2, 0), (0, 1))):  # cross products, component k
                out[:, k, lumped] = -half * (sa[i] * ub[j] - sa[j] * ub[i] + sb[i] * ua[j] - sb[j] * ua[i])
    return out


def full_regressor(model: Model, q, qd, w0, *, columns=None) -> np.ndarray:
    """Full momentum regressor in base axes.

    Parameters
    ----------
    model : Model
    q, qd : array_like of shape (..., n_joints)
    w0 : array_like of shape (..., 3)
        Base angular velocity in base axes [rad/s].
    columns : sequence of int, optional
        Compute only these columns (indices into ``full_parameter_names``).

    Returns
    -------
    ndarray of shape (..., 3, n_columns)
        ``Y`` with ``Y @ full_values(model)`` the angular momentum about the system CM, base axes.
    """
    return _regressor(model, q, qd, w0, columns, energy=False)


def energy_regressor(model: Model, q, qd, w0, *, columns=None) -> np.ndarray:
    """Kinetic-energy regressor with zero linear momentum, shape ``(..., n_columns)``.

    ``energy_regressor(...) @ full_values(model)`` is the kinetic energy [J] of the system
    moving with zero linear momentum: the reduced dynamics that model-based control needs.
    """
    return _regressor(model, q, qd, w0, columns, energy=True)


# ------------------------------------------------------------------ random states -------------


def _random_states(model: Model, n: int, seed: int):
    """Seeded random states covering the joint space, for rank decisions and fits."""
    rng = np.random.default_rng(seed)
    nj = model.n_joints
    q = np.empty((n, nj))
    for j, b in enumerate(model.bodies[1:]):
        if b.joint_type == "revolute":
            q[:, j] = rng.uniform(-np.pi, np.pi, n)
        else:
            lo, hi = b.limits.get("lower", -0.5), b.limits.get("upper", 0.5)
            q[:, j] = rng.uniform(lo, hi, n)
    qd = rng.standard_normal((n, nj))
    w0 = rng.standard_normal((n, 3))
    if model.planar:
        w0[:, :2] = 0.0
    return q, qd, w0


def _independent(matrix: np.ndarray, tol: float, *, block: int = 128):
    """Columns of ``matrix`` independent of the kept columns before them, and their basis.

    Greedy in the given (fixed) order, so the choice depends only on the linear relations
    between columns, not on their magnitudes or on the sample states: each column is scaled
    to unit norm and kept when its part orthogonal to the kept ones exceeds ``tol``. Columns
    below ``tol`` times the largest column norm count as zero. Block Gram-Schmidt applied
    twice (BCGS2): blocks are projected with matrix products, columns within a block one by
    one, which keeps the cost in BLAS-3 for regressors with thousands of columns.

    Returns
    -------
    keep : ndarray of int
        Indices of the independent columns, increasing.
    basis : ndarray of shape (n_rows, len(keep))
        Orthonormal basis of their span (``basis.T @ matrix[:, keep]`` is upper triangular).
    """
    norms = np.linalg.norm(matrix, axis=0)
    nonzero = norms > tol * norms.max()
    basis = np.zeros((matrix.shape[0], min(matrix.shape)))
    keep = []
    for start in range(0, matrix.shape[1], block):
        cols = [j for j in range(start, min(start + block, matrix.shape[1])) if nonzero[j]]
        if not cols:
            continue
        b = matrix[:, cols] / norms[cols]
        for _ in range(2):  # project the block on the kept basis, twice for orthogonality
            b -= basis[:, : len(keep)] @ (basis[:, : len(keep)].T @ b)
        local = []  # kept columns of this block, orthonormal
        for k, j in enumerate(cols):
            c = b[:, k]
            for _ in range(2):
                for v in (basis[:, : len(keep)], np.column_stack(local) if local else None):
                    if v is not None and v.size:
                        c = c - v @ (v.T @ c)
            if np.linalg.norm(c) > tol:
                local.append(c / np.linalg.norm(c))
                keep.append(j)
                basis[:, len(keep) - 1] = local[-1]
    return np.array(keep, dtype=int), basis[:, : len(keep)]


# ------------------------------------------------------------------ planar basis --------------


def _planar_pairs(n_bodies):
    """Body-pair basis in the paper's order: base-link cos, base-link sin, base, link-link
    cos and sin, links."""
    base_pairs = [(0, b) for b in range(1, n_bodies)]
    link_pairs = [(a, b) for a in range(1, n_bodies) for b in range(a + 1, n_bodies)]
    return (
        [("cos", a, b) for a, b in base_pairs]
        + [("sin", a, b) for a, b in base_pairs]
        + [("spin", 0, 0)]
        + [(kind, a, b) for a, b in link_pairs for kind in ("cos", "sin")]
        + [("spin", b, b) for b in range(1, n_bodies)]
    )


def _planar_functions(model: Model, terms, q, qd, w0):
    """Body-pair functions at the states, shape ``(..., n_terms)``."""
    st = body_states(model, q, qd, w0)
    rot, wz = st.rotation, st.omega[..., 2]
    cols = []
    for kind, a, b in terms:
        if kind == "spin":
            cols.append(wz[..., a])
            continue
        # entries (0, 0) and (1, 0) of R_a^T R_b: cos and sin of the angle of b relative to a
        axis = 0 if kind == "cos" else 1
        trig = (rot[..., a, :, axis] * rot[..., b, :, 0]).sum(-1)
        cols.append(trig * (wz[..., a] + wz[..., b]))
    return np.stack(cols, -1)


# ------------------------------------------------------------------ the minimal set -----------


@dataclass(frozen=True)
class Parameterization:
    """The minimal (identifiable) parameter set of a model and its regressor.

    Attributes
    ----------
    model : Model
        The model the set was derived for (its geometry enters the regressor; its inertial
        values only give the ``true_values``).
    names : tuple of str
        ``pi1 .. pik``.
    definitions : tuple of str
        Each parameter in physical terms (symbolic, SymPy syntax).
    projection : ndarray of shape (k, n_full)
        ``pi = projection @ [theta, phi]`` (see ``full_parameter_names``).
    basis : {"planar", "columns"}
    rank_tol : float
        Rank tolerance used (see ``RANK_TOL``).
    seed : int
        Seed of the random states used for rank decisions and fits.
    n_states : int
    """

    model: Model
    names: tuple
    definitions: tuple
    projection: np.ndarray
    basis: str
    rank_tol: float
    seed: int
    n_states: int
    _eval: tuple = field(repr=False, compare=False, default=())

    @property
    def n_params(self) -> int:
        return len(self.names)

    @property
    def rows(self) -> int:
        """Equations per sample: 1 (z) for planar systems, 3 for spatial ones."""
        return 1 if self.model.planar else 3

    @functools.cached_property
    def true_values(self) -> np.ndarray:
        """``pi`` of the model's own inertial parameters, shape ``(k,)``."""
        return self.projection @ full_values(self.model)

    def regressor(self, q, qd, w0) -> np.ndarray:
        """Minimal regressor in base axes, shape ``(..., rows, k)``.

        ``regressor(q, qd, w0) @ pi`` is the angular momentum about the system CM in base axes
        (its z component only, for planar systems).
        """
        kind, data, weights = self._eval
        if kind == "planar":
            return (_planar_functions(self.model, data, q, qd, w0) @ weights)[..., None, :]
        y = full_regressor(self.model, q, qd, w0, columns=data)  # the independent columns
        return y[..., 2:3, :] if self.model.planar else y

    def to_dict(self) -> dict:
        return {
            "basis": self.basis,
            "rank_tol": self.rank_tol,
            "seed": self.seed,
            "n_states": self.n_states,
            "parameters": [{"name": n, "definition": d} for n, d in zip(self.names, self.definitions)],
        }


def minimal_parameters(model: Model, *, tol: float = RANK_TOL, seed: int = 0) -> Parameterization:
    """Derive the minimal parameter set of ``model`` and its regressor.

    The set depends on the geometry only (kinematic tree, joint placements and axes, declared
    zeros, planar flag), not on the inertial values: it is cached by geometry, so a model whose
    masses changed (fuel use, a captured payload on a fixed joint) reuses it at once.

    Parameters
    ----------
    model : Model
    tol : float
        Rank tolerance, relative (see ``RANK_TOL``); recorded in the result.
    seed : int
        Seed of the random states; the result does not depend on it (tested), it is recorded.

    Returns
    -------
    Parameterization
    """
    return replace(_minimal_cached(_Geometry(model), tol, seed), model=model)


class _Geometry:
    """Hashable view of what the minimal set depends on (everything but inertial values)."""

    def __init__(self, model: Model):
        self.model = model
        self.key = (model.planar, tuple(
            (b.parent, b.joint_type, b.joint, b.name, b.known_zero, b.axis.tobytes(), b.rotation.tobytes(), b.translation.tobytes())
            for b in model.bodies
        ))

    def __hash__(self):
        return hash(self.key)

    def __eq__(self, other):
        return self.key == other.key


@functools.lru_cache(maxsize=16)
def _minimal_cached(geometry: _Geometry, tol: float, seed: int) -> Parameterization:
    model = geometry.model
    names = full_parameter_names(model)
    rows = slice(2, 3) if model.planar else slice(None)
    n_rows = 1 if model.planar else 3
    n_states = max(64, -(-2 * len(names) // n_rows))  # twice as many equations as unknowns
    q, qd, w0 = _random_states(model, n_states, seed)
    y_full = full_regressor(model, q, qd, w0)[:, rows, :].reshape(-1, len(names))
    indep, basis = _independent(y_full, tol)
    rank = len(indep)
    if rank == 0:
        raise SpaceidError(f"{model.source or model.name}: the momentum does not depend on any parameter (no moving body?)")
    if model.planar and all(b.joint_type == "revolute" for b in model.bodies[1:]):
        terms = _planar_pairs(len(model.bodies))
        f = _planar_functions(model, terms, q, qd, w0)
        coef, *_ = np.linalg.lstsq(f, y_full, rcond=None)
        scale = np.abs(y_full).max()
        if np.abs(f @ coef - y_full).max() <= 1e-9 * scale:
            # rows of coef that are independent (and not structurally zero), in the paper's order
            sel, _ = _independent(coef.T, tol)
            if len(sel) != rank:
                raise AssertionError(f"planar basis rank {len(sel)} != regressor rank {rank}")
            proj = coef[sel]
            weights = coef @ np.linalg.pinv(proj)  # coef = weights @ proj
            used = [s for s in range(len(terms)) if np.abs(weights[s]).max() > 0]
            from ._definitions import planar_definitions

            return Parameterization(
                model,
                tuple(f"pi{i + 1}" for i in range(rank)),
                tuple(planar_definitions(model, [terms[s] for s in sel])),
                proj,
                "planar",
                tol,
                seed,
                n_states,
                ("planar", [terms[s] for s in used], weights[used]),
            )
    # columns basis: pi_i = theta_i + sum_d beta_id theta_d over the dependent columns d
    dep = np.setdiff1d(np.arange(len(names)), indep)
    # y_dep = y_indep @ beta, solved through the basis: y_indep = basis @ r with r triangular
    r = basis.T @ y_full[:, indep]
    beta = solve_triangular(r, basis.T @ y_full[:, dep])
    beta[np.abs(beta) < tol * max(1.0, np.abs(beta).max())] = 0.0
    proj = np.zeros((rank, len(names)))
    proj[np.arange(rank), indep] = 1.0
    proj[:, dep] = beta
    from ._definitions import column_definitions

    return Parameterization(
        model,
        tuple(f"pi{i + 1}" for i in range(rank)),
        tuple(column_definitions(names, proj)),
        proj,
        "columns",
        tol,
        seed,
        n_states,
        ("columns", indep, None),
    )


def identifiability(param: Parameterization, *, tol: float | None = None) -> dict:
    """What the minimal set says about the physical parameters and the dynamics.

    Parameters
    ----------
    param : Parameterization
    tol : float, optional
        Relative tolerance of the subspace tests (default: the rank tolerance of ``param``).

    Returns
    -------
    dict
        ``no_effect``: standard parameters that do not enter the momentum at all;
        ``individually_identifiable``: standard parameters fixed by ``pi`` on their own;
        ``in_combinations``: the rest (identifiable only through the combinations ``pi``);
        ``determines_dynamics``: whether ``pi`` fixes the kinetic energy with zero linear
        momentum for every state (its regressor lies in the row space of the momentum
        regressor, MATH.md sec. 4), hence the reduced inertia matrix that model-based control
        and the Generalized Jacobian need; ``energy_residual``: the relative size of the part
        of the energy regressor outside that row space.
    """
    tol = param.rank_tol if tol is None else tol
    model = param.model
    names = full_parameter_names(model)
    n_theta = len(_layout(model)[0])
    q, qd, w0 = _random_states(model, param.n_states, param.seed + 1)  # fresh states for the tests
    y = full_regressor(model, q, qd, w0)[:, slice(2, 3) if model.planar else slice(None), :].reshape(-1, len(names))
    energy = energy_regressor(model, q, qd, w0)
    rowspace = np.linalg.svd(param.projection, full_matrices=False)[2]  # orthonormal rows, (k, n_full)
    outside = energy - (energy @ rowspace.T) @ rowspace
    energy_residual = float(np.linalg.norm(outside) / np.linalg.norm(energy))
    # a standard parameter acts through its own column and through the lumped products with it
    theta, first, pairs = _layout(model)
    norms = np.linalg.norm(y, axis=0)
    acts = norms[:n_theta] > tol * norms.max()
    for c, (a, b) in enumerate(pairs):
        if norms[n_theta + c] > tol * norms.max():
            acts[theta.index(first[a])] = acts[theta.index(first[b])] = True
            acts[[k == 0 for _, k in theta]] = True  # every mass acts through M = sum of masses
    no_effect = [n for n, a in zip(names, acts) if not a]
    alone = [n for j, n in enumerate(names[:n_theta]) if n not in no_effect and 1 - rowspace[:, j] @ rowspace[:, j] < tol]
    return {
        "no_effect": no_effect,
        "individually_identifiable": alone,
        "in_combinations": [n for n in names[:n_theta] if n not in no_effect and n not in alone],
        "determines_dynamics": energy_residual < 1e3 * tol,
        "energy_residual": energy_residual,
    }
