"""Momentum regressor ``h = Y(q, qd, w0) pi`` and its minimal parameter set, for any tree.

The full regressor (docs/theory/general-tree.md) is linear in the standard inertial parameters ``theta``
of every body and in the lumped products ``phi_ab = theta_a theta_b / M`` of the first-order
ones (masses and first moments), once zero linear momentum has eliminated the base velocity:

    h = sum_i [ I_i w_i + m_i s_i x u_i ] - (1/M) (sum_i m_i s_i) x (sum_j m_j u_j)

Every column is a sum of two cross products of rows of the kinematics (body origins, axes,
their rates, and the axes times the body-axes rates for the inertias), formed sample by sample
by a compiled kernel from the sample's kinematics held in cache, and written straight into the
time-first output (:class:`_Plan`, :func:`_columns_of_states`).

The minimal set ``pi = P @ [theta, phi]`` is found numerically from the regressor stacked at
seeded random states, with a recorded rank tolerance. Two bases are offered for it:

* ``planar``: for planar trees of revolute joints, the coefficients of the body-pair functions
  ``w_b``, ``cos(D_ab) (w_a + w_b)`` and ``sin(D_ab) (w_a + w_b)`` (``D_ab`` the angle of body b
  relative to body a). For Cepheus these are exactly the paper's 8 parameters (Appendix B).
* ``columns``: otherwise, the independent columns of the full regressor taken greedily in a
  fixed order (a QR without pivoting on unit-norm columns, the weakly independent ones last),
  each absorbing the dependent ones.

Both are the same engine: the planar basis is only a change of coordinates on the z row of the
spatial regressor, fitted and checked at the random states.

References
----------
.. [1] The Cepheus paper (NTUA Control Systems Lab; see docs/citing.md), Eq. 2 and Eq. 9-10
   (minimum parameter set), Appendix B.
"""

from __future__ import annotations

import contextlib
import functools
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np
from scipy.linalg import solve_triangular

from .._cache import cache_key, read_cached, source_digest, stored_strings, stored_text, write_cached
from .._errors import SpaceidError
from .._svd import svd
from .._threads import one_blas_thread, threads_for
from ._definitions import column_definitions, planar_definitions
from ._kernels import _columns_of_states, _contracted_rows, _momentum_of_states, _tangent_columns
from ._kinematics import FrameTable, _flatten_states, _Geometry, _joint_arrays, body_states, frame_table
from ..models import INERTIAL_NAMES, Model
from ..models.internal import symbol_suffix, zero_rotations

__all__ = [
    "Parameterization",
    "minimal_parameters",
    "full_regressor",
    "energy_regressor",
    "full_parameter_names",
    "full_values",
    "full_values_jacobian",
    "Identifiability",
    "no_effect_parameters",
    "identifiability",
]

RANK_TOL = 1e-9
"""Default rank tolerance: a column (or basis row) is dependent when the part of it that the
previous ones do not explain is below this fraction of its norm (unit-norm columns)."""

MAX_SET_BYTES = 2 << 30
"""Most memory the minimal-set derivation may take [bytes]: the full regressor at twice as many
equations as full parameters, ~48 n_full^2 bytes spatial (the full set grows as 8 n_bodies^2: a
28-body spatial chain fits, a 100-body chain would take ~100 GiB). Larger trees are refused
before anything is allocated."""

PLANAR_SYMBOLIC_BODIES = 6
"""Largest planar tree given the planar basis with SymPy definitions [bodies]: the factoring
grows steeply (3.5 s for a 6-body chain, 24 s for 8, 33 s for 11); larger planar trees get the
columns basis, whose definitions are written without SymPy."""

ROUND_OFF = 1e-12
"""A dependency coefficient ``beta_id`` (dependent column ``d`` in the independent ones) is
round-off, set to zero, when its term is below this fraction of column ``d``:
``|beta_id| |y_i| < ROUND_OFF |y_d|`` (norms at the sample states). Structural zeros come out at
1e-14 and below for the presets, their true coefficients at 1e-3 and above."""


UNITS = ("kg", "kg m", "kg m^2")
"""Unit of a parameter with ``p`` powers of length, ``UNITS[p]``: masses, first moments, inertias
(and lumped products ``theta_a theta_b / M``, with the units of ``theta_a theta_b`` over kg)."""


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

    Standard parameters as in the YAML ``known_zero`` (``INERTIAL_NAMES``, Pinocchio's order)
    with the body after an underscore: ``m_link1`` [kg], ``mcx_link1`` .. ``mcz_link1`` first
    moments [kg m], ``Ixx_link1`` .. ``Izz_link1`` inertia about the body frame origin
    [kg m^2]; lumped products ``m_base*mcx_link1/M`` with ``M`` the total mass.
    """
    theta, first, pairs = _layout(model)
    names = [f"{INERTIAL_NAMES[k]}_{symbol_suffix(model.bodies[i].name)}" for i, k in theta]
    lead = [names[theta.index(f)] for f in first]  # once each: a look-up per pair took 30 ms on the servicer
    return names + [f"{lead[a]}*{lead[c]}/M" for a, c in pairs]


def _length_powers(model: Model) -> np.ndarray:
    """Powers of length in the unit of each full parameter (kg m^p), shape ``(n_full,)``."""
    theta, first, pairs = _layout(model)
    power = [0 if k == 0 else 1 if k < 4 else 2 for _, k in theta]
    first_power = [power[theta.index(f)] for f in first]
    return np.array(power + [first_power[a] + first_power[c] for a, c in pairs], dtype=int)


def full_values(model: Model) -> np.ndarray:
    """Values of the full parameter vector, shape ``(n_full,)``, order of ``full_parameter_names``."""
    theta, first, pairs = _layout(model)
    values = [model.bodies[i].inertial[k] for i, k in theta]
    f, total = [model.bodies[i].inertial[k] for i, k in first], model.mass
    return np.array(values + [f[a] * f[c] / total for a, c in pairs])


def full_values_jacobian(model: Model) -> np.ndarray:
    """Derivative of ``full_values`` with respect to the standard parameters ``theta`` (the first
    entries of ``full_parameter_names``), at the model's values, shape ``(n_full, n_theta)``.

    The lumped products ``theta_a theta_c / M`` are homogeneous of degree one in ``theta`` (``M``
    is the sum of the masses), so ``full_values_jacobian(model) @ theta == full_values(model)``.
    """
    theta, first, pairs = _layout(model)
    n = len(theta)
    f = np.array([model.bodies[i].inertial[k] for i, k in first])
    at = np.array([theta.index(x) for x in first], dtype=int)  # first-order parameters in theta
    a, c = np.array(pairs, dtype=int).reshape(-1, 2).T
    rows = np.arange(len(pairs))
    lumped = np.zeros((len(pairs), n))
    np.add.at(lumped, (rows, at[a]), f[c] / model.mass)
    np.add.at(lumped, (rows, at[c]), f[a] / model.mass)
    lumped -= np.outer(f[a] * f[c] / model.mass**2, [k == 0 for _, k in theta])  # through M
    return np.vstack([np.eye(n), lumped])


# entries (m1, m2) of the inertia parameters [Ixx, Ixy, Iyy, Ixz, Iyz, Izz]
_INERTIA_ENTRIES = ((0, 0), (0, 1), (1, 1), (0, 2), (1, 2), (2, 2))


@dataclass(frozen=True)
class _Plan:
    """How to evaluate a set of columns of the full regressor from a :class:`FrameTable`.

    Per body, relative to the base origin (velocities without the base origin's motion), the
    momentum is ``m p x v + p x (w x R mc) + R mc x v + R I wb`` and the energy
    ``m |v|^2 / 2 + v . (w x R mc) + wb . I wb / 2``. Zero linear momentum subtracts
    ``(sum m s) x (sum m u) / M`` and ``|sum m u|^2 / (2 M)``, whose factors are linear in the
    first-order parameters: ``sum m s = sum_a S_a theta_a``, ``sum m u = sum_a U_a theta_a``
    with ``S_a`` the body origin ``p`` (a mass) or axis ``R e_k`` (a first moment) and ``U_a``
    its rate. So every column is a symmetric bilinear form of two rows of the pose (``S``) and
    rate (``U``) tables, row ``4 b + f`` for body b (``f = 0`` the origin, ``1..3`` the axes):

    * first-order columns, rows ``a, c`` and weight ``w``: momentum ``w (S_a x U_c + S_c x U_a)``,
      energy ``w U_a . U_c``. A standard mass or first-moment column
      pairs the body's origin with itself or one of its axes (``w`` 1/2 or 1); a lumped product
      ``theta_a theta_c / M`` has ``w`` -1/2 (``a == c``) or -1.
    * inertia columns of body b, entry (m1, m2) of the inertia: momentum
      ``R e_m1 wb_m2 + R e_m2 wb_m1``, energy ``wb_m1 wb_m2``, halved on the diagonal (``wb``
      the body-axes angular velocity; on the diagonal the momentum's second term is dropped).

    The momentum of every column is evaluated as ``X1 x Y1 + X2 x Y2``, rows of the extended
    table (:func:`_sample_extended`): the weights are folded into the choice of rows
    (``U x S = -S x U``; ``|w| = 1/2`` only when ``a == c``, where the second term is the first
    one again and is replaced by the zero row, the base origin), and an inertia term
    ``R e_m wb_n`` is ``R e_(m+1) x (R e_(m+2) wb_n)`` (a rotation's axes are right-handed), the
    second factor a row ``R e_k wb_n`` that the extended table appends.
    """

    n_cols: int
    rows: np.ndarray  # (n_cols, 4): extended-table rows of X1, Y1, X2, Y2
    pair_at: np.ndarray  # output positions of the first-order columns
    pair_rows: np.ndarray  # (2, n_pair): rows a, c of the pose (or rate) table
    pair_weight: np.ndarray  # (n_pair,): w
    inertia_at: np.ndarray  # output positions of the inertia columns
    inertia: np.ndarray  # (4, n_inertia): pose rows of R e_m1, R e_m2 (or zero); wb rows m1, m2
    columns: np.ndarray  # the full-regressor columns evaluated, in output order


def _plan(model: Model, columns) -> _Plan:
    """Evaluation plan of the requested columns (indices into ``full_parameter_names``,
    default all), kept per geometry and columns: the forward dynamics ask for the energy's at every
    step (forming it took 0.2 ms, five times the energy of a few Cepheus states)."""
    return _plan_of(_Geometry(model), None if columns is None else np.asarray(columns, dtype=np.int64).tobytes())


@functools.lru_cache(maxsize=64)
def _plan_of(geometry: _Geometry, columns: bytes | None) -> _Plan:
    """:func:`_plan` of ``geometry``'s model, ``columns`` the bytes of the indices (None: all)."""
    model = geometry.model
    theta, first, pairs = _layout(model)
    cols = np.arange(len(theta) + len(pairs)) if columns is None else np.frombuffer(columns, np.int64).astype(int)
    nb = len(model.bodies)
    pair, pair_at, inertia, inertia_at = [], [], [], []
    for n, c in enumerate(cols):
        if c >= len(theta):
            (b1, f1), (b2, f2) = first[pairs[c - len(theta)][0]], first[pairs[c - len(theta)][1]]
            pair.append((4 * b1 + f1, 4 * b2 + f2, -0.5 if (b1, f1) == (b2, f2) else -1.0))
            pair_at.append(n)
        elif theta[c][1] < 4:  # mass: p x v (origin with itself); first moment: origin with an axis
            b, f = theta[c]
            pair.append((4 * b, 4 * b + f, 0.5 if f == 0 else 1.0))
            pair_at.append(n)
        else:
            inertia.append((theta[c][0], *_INERTIA_ENTRIES[theta[c][1] - 4]))
            inertia_at.append(n)
    zero, rate = 0, 4 * nb  # row 0 is the base origin, p = v = 0
    rows = np.full((4, len(cols)), zero)
    for (a, c, w), n in zip(pair, pair_at):
        x1, y1, x2, y2 = (a, rate + c, c, rate + a) if w > 0 else (rate + c, a, rate + a, c)
        rows[:, n] = (x1, y1, x2, y2) if a != c else (x1, y1, zero, zero)
    body, m1, m2 = np.array(inertia, dtype=int).reshape(-1, 3).T

    def axis(m):  # the pose row R e_m
        return 4 * body + 1 + m % 3

    def spun(k, m):  # the extended row R e_k wb_m
        return 8 * nb + 9 * body + 3 * (k % 3) + m

    diagonal = m1 == m2
    rows[:, inertia_at] = [axis(m1 + 1), spun(m1 + 2, m2), np.where(diagonal, zero, axis(m2 + 1)),
                           np.where(diagonal, zero, spun(m2 + 2, m1))]  # fmt: skip
    a, c, w = np.array(pair, dtype=float).reshape(-1, 3).T
    inertia = np.array([axis(m1), np.where(diagonal, zero, axis(m2)), m1 * nb + body, m2 * nb + body])
    return _Plan(len(cols), np.ascontiguousarray(rows.T, dtype=np.int64), np.array(pair_at, dtype=int),
                 np.array([a, c], dtype=int), w, np.array(inertia_at, dtype=int), inertia, cols)


_GROUP = 256
"""Samples per task of a thread (and per kinematics call of the energy and the tangent, whose
NumPy tables stay in cache at this size)."""
_THREADED_WORK = 1_000_000
"""Samples times columns from which the compiled kernels' groups go to threads: below it a pool costs more than
it saves (the servicer's 496 columns: 0.78 against 1.33 ms at 300 samples, equal at 1,000, 11.3 against 7.0 ms at
3,000; Cepheus's 8 columns gain nothing at 3,000)."""


def _regressor(model: Model, q, qd, w0, plan: _Plan, *, energy: bool, weights=None, direction=None, step=None,
               primal=True, out=None):  # fmt: skip
    """Regressor columns over any leading shape: ``(..., 3, n_cols)`` or, for the energy,
    ``(..., n_cols)``; with ``weights (n_cols,)`` their weighted sum, ``(..., 3)`` or ``(...)``
    (the momentum columns are then never stored). With ``direction`` ``(dq, dqd, dw0)``
    (momentum only, no weights), the columns' derivative along it, plus the columns when
    ``primal`` (:func:`_tangent_columns`, central differences of step ``step``). ``out`` (a view
    is fine) receives the result, shape ``(n_samples, 3, n_cols)`` for the columns.

    Groups of ``_GROUP`` samples go to threads when the work is large (:data:`_THREADED_WORK`; the kernels
    release the GIL), each writing its own rows of ``out``; the energy's groups run in turn (their short NumPy
    operations hold the GIL between them: on two threads the energy took 1.2 to 4.5 times as long)."""
    lead, flat = _flatten_states(q, qd, w0)
    if direction is not None:
        flat += [np.broadcast_to(np.asarray(a, float), lead + b.shape[-1:]).reshape(b.shape)
                 for a, b in zip(direction, flat)]  # fmt: skip
    n = len(flat[0])
    if out is None:
        out = np.empty((n,) + (() if energy else (3,)) + (() if weights is not None else (plan.n_cols,)))
    joints = _joint_arrays(_Geometry(model))
    weights = None if weights is None else np.require(weights, float, "CW")
    wide = _wider_rows(out)

    def run(start):
        states = [np.require(a[start : start + _GROUP], float, "CW") for a in flat]  # the kernels' one layout
        part = out[start : start + _GROUP]
        if energy:
            columns = _energy_columns(frame_table(model, *states, len(states[0])), plan)
            part[...] = (columns if weights is None else weights @ columns).T
            return
        # a strided view of ``out`` is written through a contiguous block (the rows of the array it is the
        # first columns of, or a copy): an output of another layout would compile the kernel a second
        # time (1 to 2 s in a command's first run)
        block = part if part.flags.c_contiguous else wide[start : start + _GROUP] if wide is not None else np.empty(
            part.shape)
        if direction is not None:
            _tangent_columns(*joints, *states, _steps(states[3:], step), primal, plan.rows, block)
        elif weights is None:
            _columns_of_states(*joints, *states, plan.rows, block)
        else:
            _momentum_of_states(*joints, *states, plan.rows, weights, block)
        if block is not part and wide is None:
            part[...] = block

    starts = range(0, n, _GROUP)
    threads = 1 if energy or n * plan.n_cols < _THREADED_WORK else threads_for(len(starts))
    if threads > 1:  # a pool per call: no idle threads left behind for forked workers to inherit
        with ThreadPoolExecutor(threads) as pool:
            list(pool.map(run, starts))
    else:
        for start in starts:
            run(start)
    return out.reshape(lead + out.shape[1:])


def _wider_rows(out):
    """The C-contiguous array ``(n, 3, m)`` whose first columns ``out (n, 3, k)`` (``k <= m``) is, or None: the
    kernels write ``out``'s columns through its rows in place (they write the first ``k`` columns of each row
    only), with no contiguous copy of the regressor to move into it (an equations' ``[A | -b]`` holds it so:
    0.1 s of 10,000 servicer samples)."""
    base = None if out is None or out.flags.c_contiguous else out.base
    if (isinstance(base, np.ndarray) and base.flags.c_contiguous and base.ndim == 3 == out.ndim
            and base.shape[:2] == out.shape[:2] and base.strides == out.strides
            and base.ctypes.data == out.ctypes.data):
        return base
    return None


def _steps(direction, step: float) -> np.ndarray:
    """Central-difference steps along each sample's direction ``(dq, dqd, dw0)`` (leading shape
    ``(...)``): ``step`` over the direction's largest component (over 1 where it is zero)."""
    size = np.max([np.abs(a).max(-1) for a in direction], axis=0)
    return step / np.where(size > 0, size, 1.0)


def _contracted_frames(model: Model, states, weights, step: float) -> tuple:
    """:func:`~spaceid.dynamics._kernels._contracted_rows` of ``states = [q, qd, w0, dq, dqd, dw0]`` (each ``(m,
    .)``) and ``weights (m, 3)``, the central differences' steps from :func:`_steps`: ``(d_table, crossed, tu, dtu,
    spin, d_spin)``."""
    m, nb = len(states[0]), len(model.bodies)
    out = [np.empty((3, 8 * nb, m)), np.empty((3, 8 * nb, m)), np.empty((8 * nb, m)), np.empty((8 * nb, m)),
           np.empty((3, nb, m)), np.empty((3, nb, m))]  # fmt: skip
    _contracted_rows(*_joint_arrays(_Geometry(model)), *(np.ascontiguousarray(a, float) for a in states),
                     _steps(states[3:], step), np.ascontiguousarray(weights, float), *out)
    return tuple(out)


def _contracted_tangent(model: Model, plan: _Plan, q, qd, w0, direction, weights, step: float, group: int = 1024):
    """``sum_n weights_n . d(columns)(x_n)[direction_n]``, shape ``(n_cols,)``, without the columns.

    A pair column is ``T_i x T_j`` summed over two pairs of table rows, so its contracted
    derivative is ``G_ij - G_ji`` with ``G = sum_n dT (T x u)^T`` over components and samples
    (``u`` the weights, ``u . (dT_i x T_j) = dT_i . (T_j x u)``): one matrix product over all the
    samples for every column. An inertia column ``T_a wb_s`` (plus its mirror) contracts to
    ``sum_n (u . dT_a) wb_s + (u . T_a) dwb_s``, two more products.

    Parameters
    ----------
    q, qd, w0 : ndarray of shape (n, .)
    direction : tuple of ndarray
        ``(dq, dqd, dw0)``, shaped as the states.
    weights : ndarray of shape (n, 3)
    """
    nb = len(model.bodies)
    G, P = np.zeros((8 * nb, 8 * nb)), np.zeros((8 * nb, 3 * nb))
    with one_blas_thread():  # small products: threads only wait on busy cores
        for start in range(0, len(q), group):
            part = slice(start, start + group)
            states = [np.asarray(a, float)[part] for a in (q, qd, w0, *direction)]
            m = len(states[0])
            dt, crossed, tu, dtu, spin, d_spin = _contracted_frames(model, states, np.asarray(weights)[part], step)
            for r in range(3):
                G += dt[r] @ crossed[r].T  # dT . (T x u)
            P += dtu @ spin.reshape(3 * nb, m).T
            P += tu @ d_spin.reshape(3 * nb, m).T
    rows = plan.rows[plan.pair_at].T  # the table rows of X1, Y1, X2, Y2
    out = np.empty(plan.n_cols)
    out[plan.pair_at] = (G - G.T)[rows[0], rows[1]] + (G - G.T)[rows[2], rows[3]]
    axis1, axis2, spin1, spin2 = plan.inertia
    out[plan.inertia_at] = P[axis1, spin2] + P[axis2, spin1]
    return out


def _energy_columns(frames: FrameTable, plan: _Plan) -> np.ndarray:
    """Energy columns of a frame table of one block of ``m`` samples: ``(n_cols, m)``."""
    rate = frames.table[0, :, 1].reshape(3, -1, frames.table.shape[-1])
    a, c = plan.pair_rows
    y = np.empty((plan.n_cols, rate.shape[-1]))
    y[plan.pair_at] = plan.pair_weight[:, None] * np.einsum("rkc,rkc->kc", rate[:, a], rate[:, c])
    if len(plan.inertia_at):
        _, _, spin1, spin2 = plan.inertia
        spin = frames.omega_body[0].reshape(-1, rate.shape[-1])
        y[plan.inertia_at] = np.where(spin1 == spin2, 0.5, 1.0)[:, None] * spin[spin1] * spin[spin2]
    return y


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
    return _regressor(model, q, qd, w0, _plan(model, columns), energy=False)


def energy_regressor(model: Model, q, qd, w0, *, columns=None, weights=None) -> np.ndarray:
    """Kinetic-energy regressor with zero linear momentum, shape ``(..., n_columns)``.

    ``energy_regressor(...) @ full_values(model)`` is the kinetic energy [J] of the system
    moving with zero linear momentum: the reduced dynamics that model-based control needs.
    With ``weights`` of shape ``(n_columns,)``, the product ``regressor @ weights``, shape
    ``(...)``, formed without storing the columns.
    """
    weights = None if weights is None else np.asarray(weights, float)
    return _regressor(model, q, qd, w0, _plan(model, columns), energy=True, weights=weights)


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


def _nonzero(norms: np.ndarray, tol: float) -> np.ndarray:
    """Columns that count as nonzero: norm above ``tol`` times the largest one."""
    return norms > tol * norms.max()


def _independent(matrix: np.ndarray, tol: float, *, block: int = 128):
    """Columns of ``matrix`` independent of the kept columns before them, and their basis.

    Greedy in the given (fixed) order, so the choice depends only on the linear relations
    between columns, not on their magnitudes or on the sample states: each column is scaled
    to unit norm and kept when its part orthogonal to the kept ones exceeds ``tol``. Columns
    below ``tol`` times the largest column norm count as zero. Block Gram-Schmidt applied
    twice (BCGS2): blocks are projected with matrix products, columns within a block one by
    one, which keeps the cost in BLAS-3 for regressors with thousands of columns.

    A column whose orthogonal part is below ``sqrt(tol)`` is only weakly independent (a
    near-degenerate geometry) and is taken at the end, unless the columns after it have covered
    its direction. Taken at once, it would make the basis ill-conditioned (condition ~1/its
    part): the round-off of later dependent columns (machine epsilon times the condition) could
    pass ``tol``, keeping them wrongly, and the dependency coefficients would grow to ~1/its part
    (parts of 8e-7: 57 columns kept for a rank of 55, momentum off by 5e-9 of itself, for the
    random tree ``parents=[0, 1, 2, 3]``, prismatic joint 1, seed 212293424).

    Returns
    -------
    keep : ndarray of int
        Indices of the independent columns in the order taken: increasing, then the weakly
        independent ones, increasing.
    basis : ndarray of shape (n_rows, len(keep))
        Orthonormal basis of their span (``basis.T @ matrix[:, keep]`` is upper triangular).
    """
    norms = np.linalg.norm(matrix, axis=0)
    nonzero = _nonzero(norms, tol)
    basis = np.zeros((matrix.shape[0], min(matrix.shape)))
    keep, weak = [], []
    for start in range(0, matrix.shape[1], block):
        cols = [j for j in range(start, min(start + block, matrix.shape[1])) if nonzero[j]]
        weak += _take_columns(matrix[:, cols] / norms[cols], cols, basis, keep, tol, np.sqrt(tol))
    _take_columns(matrix[:, weak] / norms[weak], weak, basis, keep, tol, tol)
    return np.array(keep, dtype=int), basis[:, : len(keep)]


def _take_columns(b: np.ndarray, cols: list, basis: np.ndarray, keep: list, tol: float, strong: float) -> list:
    """One block of :func:`_independent`: orthogonalise the unit columns ``b`` (indices ``cols``)
    against ``basis[:, :len(keep)]`` and take, in order, those whose orthogonal part exceeds
    ``strong`` (appended to ``keep``, their unit parts to ``basis``, both in place).

    Returns the indices of the weakly independent columns: parts between ``tol`` and ``strong``.
    """
    if not cols:
        return []
    for _ in range(2):  # project the block on the kept basis, twice for orthogonality
        b -= basis[:, : len(keep)] @ (basis[:, : len(keep)].T @ b)
    first = len(keep)  # then each column on the columns kept from this block, twice
    weak = []
    for k, j in enumerate(cols):
        c = b[:, k]
        for _ in range(2):
            local = basis[:, first : len(keep)]
            c = c - local @ (local.T @ c)
        norm = np.linalg.norm(c)
        if norm > strong:
            basis[:, len(keep)] = c / norm
            keep.append(j)
        elif norm > tol:
            weak.append(j)
    return weak


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


@dataclass(frozen=True)
class _PlanarTurns:
    """The body-pair functions of a planar tree of revolute joints in closed form.

    Every joint axis is the base z axis (up to sign), so the rotations along a path commute: body
    b's rotation is ``Rz(turns_b . q) R_b(0)`` and its spin ``w0_z + turns_b . qd``. The entry of
    ``R_a^T R_b`` a term reads is then ``c cos(d) + s sin(d) + k`` with ``d = (turns_b - turns_a) . q``.
    A spin term is ``k = 1/2`` over the pair (b, b), exactly ``w_z`` of b.

    Attributes
    ----------
    turns : ndarray of shape (n_bodies, n_joints)
        Signed path matrix: +1 or -1 where a joint (axis along +z or -z) is on the body's path.
    relative : ndarray of shape (n_terms, n_joints)
        ``turns_b - turns_a`` of each term.
    trig : ndarray of shape (3, n_terms)
        ``c, s, k`` of each term.
    first, second : ndarray of shape (n_terms,)
        The bodies a and b of each term.
    """

    turns: np.ndarray
    relative: np.ndarray
    trig: np.ndarray
    first: np.ndarray
    second: np.ndarray


def _planar_turns(model: Model, terms) -> _PlanarTurns | None:
    """The closed form of ``terms`` on ``model`` (:class:`_PlanarTurns`), or None when an axis is tilted off z
    by more than round-off (planar mode allows 1e-9: the general kinematics then decide)."""
    if not model.planar or any(b.joint_type != "revolute" for b in model.bodies[1:]):
        return None
    rot, turns = zero_rotations(model), np.zeros((len(model.bodies), len(model.bodies) - 1))
    for j, b in enumerate(model.bodies[1:]):
        axis = rot[j + 1] @ b.axis
        if np.abs(axis[:2]).max() > 1e-12:
            return None
        turns[j + 1] = turns[b.parent]
        turns[j + 1, j] = np.sign(axis[2])
    first = np.array([a for _, a, _ in terms], int)
    second = np.array([b for _, _, b in terms], int)
    trig = np.zeros((3, len(terms)))
    for i, (kind, a, b) in enumerate(terms):
        if kind == "spin":
            trig[2, i] = 0.5
            continue
        v, u = rot[a][:, 0 if kind == "cos" else 1], rot[b][:, 0]
        trig[:, i] = v[0] * u[0] + v[1] * u[1], v[1] * u[0] - v[0] * u[1], v[2] * u[2]
    return _PlanarTurns(turns, turns[second] - turns[first], trig, first, second)


def _planar_functions(model: Model, terms, q, qd, w0, closed: _PlanarTurns | None = None):
    """Body-pair functions at the states, shape ``(..., n_terms)``: from ``closed`` (the terms' closed form,
    :func:`_planar_turns`) when given, else from the kinematics."""
    if closed is not None:
        q, qd, w0 = (np.asarray(a, float) for a in (q, qd, w0))
        # einsum's own loops, not BLAS, here and in the products with the basis's weights: a sample's sums in one
        # order whatever the batch (a BLAS product's kernel depends on its rows: one sample alone and in a batch of
        # 29 differed by an ulp), as the spatial kernels give
        d = np.einsum("...j,kj->...k", q, closed.relative)
        wz = w0[..., 2:3] + np.einsum("...j,kj->...k", qd, closed.turns)
        c, s, k = closed.trig
        return (c * np.cos(d) + s * np.sin(d) + k) * (wz[..., closed.first] + wz[..., closed.second])
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


def _into(out, y):
    """``y``, copied into ``out`` when one is given."""
    if out is None:
        return y
    out[...] = y
    return out


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
    units : tuple of str
        Each parameter's unit (``UNITS``): that of its leading full parameter (columns basis),
        kg m^2 for every planar-basis parameter (``h`` [N m s] = ``Y`` [1/s] ``pi``).
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
    units: tuple
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
    def _full_momentum(self) -> tuple:
        """The plan of all full columns and ``pinv(projection)`` (planar basis): its momentum is
        the full columns' weighted by ``pinv(projection) @ pi``
        (:func:`~spaceid.dynamics._momentum_jacobian._weights`, once per sample block of the monitor)."""
        return _plan(self.model, None), np.linalg.pinv(self.projection)

    @functools.cached_property
    def _closed_form(self) -> _PlanarTurns | None:
        """The planar basis's functions in closed form (:func:`_planar_turns`); None for the columns basis."""
        kind, data, _ = self._eval
        return _planar_turns(self.model, data) if kind == "planar" else None

    @functools.cached_property
    def true_values(self) -> np.ndarray:
        """``pi`` of the model's own inertial parameters, shape ``(k,)``."""
        return self.projection @ full_values(self.model)

    def regressor(self, q, qd, w0, *, out=None) -> np.ndarray:
        """Minimal regressor in base axes, shape ``(..., rows, k)``.

        ``regressor(q, qd, w0) @ pi`` is the angular momentum about the system CM in base axes
        (its z component only, for planar systems). ``out`` (a view is fine), of shape
        ``(n_samples, rows, k)`` for states ``(n_samples, .)``, receives it (spatial systems
        write into it directly: no copy of the largest array of an identification).
        """
        kind, data, weights = self._eval
        if kind == "planar":
            f = _planar_functions(self.model, data, q, qd, w0, self._closed_form)
            # einsum, not BLAS: batch-independent (_planar_functions)
            return _into(out, np.einsum("...m,mk->...k", f, weights)[..., None, :])
        if not self.model.planar:
            return _regressor(self.model, q, qd, w0, data, energy=False, out=out)  # the independent columns
        return _into(out, _regressor(self.model, q, qd, w0, data, energy=False)[..., 2:3, :])

    def linearized_regressor(self, q, qd, w0, direction, *, step: float, primal: bool = True, out=None) -> np.ndarray:
        """``regressor(x) + d regressor(x)[direction]`` (or the derivative alone, without
        ``primal``), shape ``(..., rows, k)``: the regressor linearised at ``x = (q, qd, w0)``.

        Parameters
        ----------
        q, qd, w0 : array_like
            As for :meth:`regressor`.
        direction : tuple of array_like
            ``(dq, dqd, dw0)``, shaped as ``(q, qd, w0)``.
        step : float
            Central differences of the kinematics of this step in the largest component of each
            sample's direction (the columns are bilinear in the kinematics, so they are formed
            once, not differenced; the planar basis differences its functions).
        out : ndarray, optional
            As for :meth:`regressor`.
        """
        kind, data, _ = self._eval
        if kind == "planar":
            x, d = [np.asarray(a, float) for a in (q, qd, w0)], [np.asarray(a, float) for a in direction]
            eps = _steps(d, step)[..., None]
            plus, minus = (self.regressor(*(a + sign * eps * b for a, b in zip(x, d))) for sign in (1, -1))
            tangent = (plus - minus) / (2 * eps[..., None])
            return _into(out, tangent + self.regressor(*x) if primal else tangent)
        args = dict(energy=False, direction=direction, step=step, primal=primal)
        if not self.model.planar:
            return _regressor(self.model, q, qd, w0, data, out=out, **args)
        return _into(out, _regressor(self.model, q, qd, w0, data, **args)[..., 2:3, :])

    def contracted_tangent(self, q, qd, w0, direction, weights, *, step: float) -> np.ndarray:
        """``sum_n weights_n . d regressor(x_n)[direction_n]``, shape ``(k,)``: the derivative of
        :meth:`linearized_regressor` contracted with ``weights (n, rows)`` over the samples and
        rows, formed without the derivative (spatial trees: a few matrix products over the
        samples; the planar basis contracts its differenced functions). States ``(n, .)``."""
        kind, data, _ = self._eval
        if kind == "planar":
            tangent = self.linearized_regressor(q, qd, w0, direction, step=step, primal=False)
            return np.einsum("nrk,nr->k", tangent, weights)
        u = np.zeros((len(weights), 3))
        u[:, slice(2, 3) if self.model.planar else slice(None)] = np.asarray(weights, float).reshape(len(u), -1)
        return _contracted_tangent(self.model, data, q, qd, w0, direction, u, step)

    def momentum(self, q, qd, w0, pi) -> np.ndarray:
        """``regressor(q, qd, w0) @ pi`` without storing the regressor: the angular momentum
        about the system CM in base axes [N m s], shape ``(..., rows)``. Faster than the product
        (each sample's columns are summed as they are formed)."""
        kind, data, weights = self._eval
        pi = np.asarray(pi, float)
        if kind == "planar":
            f = _planar_functions(self.model, data, q, qd, w0, self._closed_form)
            return np.einsum("...m,m->...", f, weights @ pi)[..., None]
        h = _regressor(self.model, q, qd, w0, data, energy=False, weights=pi)
        return h[..., 2:3] if self.model.planar else h

    def to_dict(self) -> dict:
        return {
            "basis": self.basis,
            "rank_tol": self.rank_tol,
            "seed": self.seed,
            "n_states": self.n_states,
            "parameters": [{"name": n, "definition": d, "unit": u}
                           for n, d, u in zip(self.names, self.definitions, self.units)],
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
    _check_set_size(model)
    return replace(_minimal_cached(_Geometry(model), tol, seed), model=model)


@functools.lru_cache(maxsize=16)
def _minimal_cached(geometry: _Geometry, tol: float, seed: int) -> Parameterization:
    """The minimal set of ``geometry``: from the on-disk cache (:mod:`spaceid._cache`) when it holds
    it, else derived and stored there. The derivation takes seconds for the servicer (2.3 s of
    a 2.5 s first call, measured), a cached read milliseconds."""
    key = _set_key(geometry, tol, seed)
    stored = read_cached(_CACHE_KIND, key)
    if stored is not None:
        with contextlib.suppress(KeyError, ValueError, IndexError):  # an entry of another layout: derive again
            return _from_stored(geometry.model, stored)
    param = _derive_minimal(geometry, tol, seed)
    write_cached(_CACHE_KIND, key, _to_stored(param))
    return param


_CACHE_KIND = "minimal-set"
_DERIVATION_SOURCES = ("_regressor.py", "_definitions.py", "_kinematics.py", "_kernels.py")


@functools.cache
def _derivation_digest() -> str:
    """Hash of the code the derivation runs: a changed derivation makes old cache entries stale."""
    return source_digest(*(Path(__file__).parent / name for name in _DERIVATION_SOURCES))


def _set_key(geometry: _Geometry, tol: float, seed: int) -> str:
    """Cache key of a minimal set: the geometry (known zeros sorted: a set's order varies from run
    to run), the rank tolerance, the seed and the derivation code."""
    planar, bodies = geometry.key
    bodies = tuple(b[:4] + (tuple(sorted(b[4])),) + b[5:] for b in bodies)
    return cache_key(planar, bodies, float(tol), int(seed), np.__version__, _derivation_digest())


def _to_stored(param: Parameterization) -> dict:
    """The arrays that rebuild ``param`` (:func:`_from_stored`)."""
    kind, data, weights = param._eval
    out = {"names": stored_text(param.names), "definitions": stored_text(param.definitions),
           "units": stored_text(param.units),
           "projection_at": np.array(np.nonzero(param.projection)), "projection_values": param.projection[
               np.nonzero(param.projection)], "projection_shape": np.array(param.projection.shape), "basis": np.array(
               param.basis),  # the projection sparse: 18 MB dense for the servicer, 98 % zeros
           "numbers": np.array([param.rank_tol, param.seed, param.n_states], float)}  # fmt: skip
    if kind == "planar":
        out |= {"term_kinds": np.array([t[0] for t in data]), "term_bodies": np.array([t[1:] for t in data], int),
                "weights": weights}  # fmt: skip
    else:
        out["columns"] = data.columns
    return out


def _from_stored(model: Model, stored: dict) -> Parameterization:
    """The :class:`Parameterization` of ``model`` from :func:`_to_stored`'s arrays."""
    basis = str(stored["basis"])
    projection = np.zeros(stored["projection_shape"])
    projection[tuple(stored["projection_at"])] = stored["projection_values"]
    if projection.shape[1] != len(full_parameter_names(model)):
        raise ValueError("a minimal set of another layout")
    if basis == "planar":
        terms = [(str(k), int(a), int(b)) for k, (a, b) in zip(stored["term_kinds"], stored["term_bodies"])]
        evaluation = ("planar", terms, stored["weights"])
    else:
        evaluation = ("columns", _plan(model, stored["columns"]), None)
    tol, seed, n_states = stored["numbers"]
    return Parameterization(model, stored_strings(stored["names"]), stored_strings(stored["definitions"]),
                            stored_strings(stored["units"]), projection, basis, float(tol), int(seed), int(n_states),
                            evaluation)  # fmt: skip


def _derive_minimal(geometry: _Geometry, tol: float, seed: int) -> Parameterization:
    """The minimal set of ``geometry`` from the full regressor at seeded random states."""
    model = geometry.model
    names = full_parameter_names(model)
    rows = slice(2, 3) if model.planar else slice(None)
    n_rows = 1 if model.planar else 3
    n_states = _n_states(len(names), n_rows)
    q, qd, w0 = _random_states(model, n_states, seed)
    y_full = full_regressor(model, q, qd, w0)[:, rows, :].reshape(-1, len(names))
    with one_blas_thread():  # its products and factorisations: on busy cores threaded BLAS took 1.5 to 2 times as long
        indep, basis = _independent(y_full, tol)
    rank = len(indep)
    if rank == 0:
        raise SpaceidError(f"{model.source or model.name}: the momentum does not depend on any parameter "
                           "(no moving body?)")
    symbolic = len(model.bodies) <= PLANAR_SYMBOLIC_BODIES
    if model.planar and symbolic and all(b.joint_type == "revolute" for b in model.bodies[1:]):
        terms = _planar_pairs(len(model.bodies))
        f = _planar_functions(model, terms, q, qd, w0, _planar_turns(model, terms))
        with one_blas_thread():
            coef, *_ = np.linalg.lstsq(f, y_full, rcond=None)
        scale = np.abs(y_full).max()
        if np.abs(f @ coef - y_full).max() <= 1e-9 * scale:
            # rows of coef that are independent (and not structurally zero), in the paper's order
            sel = np.sort(_independent(coef.T, tol)[0])
            if len(sel) != rank:
                raise AssertionError(f"planar basis rank {len(sel)} != regressor rank {rank}")
            proj = coef[sel]
            weights = coef @ np.linalg.pinv(proj)  # coef = weights @ proj
            used = [s for s in range(len(terms)) if np.abs(weights[s]).max() > 0]
            return Parameterization(
                model,
                tuple(f"pi{i + 1}" for i in range(rank)),
                tuple(planar_definitions(model, [terms[s] for s in sel])),
                (UNITS[2],) * rank,
                proj,
                "planar",
                tol,
                seed,
                n_states,
                ("planar", [terms[s] for s in used], weights[used]),
            )
    # columns basis: pi_i = theta_i + sum_d beta_id theta_d over the dependent columns d
    dep = np.setdiff1d(np.arange(len(names)), indep)
    with one_blas_thread():
        beta = _dependency_coefficients(y_full, indep, dep, basis, tol)
    order = np.argsort(indep)  # the weakly independent columns were taken last
    indep, beta = indep[order], beta[order]
    proj = np.zeros((rank, len(names)))
    proj[np.arange(rank), indep] = 1.0
    proj[:, dep] = beta
    return Parameterization(
        model,
        tuple(f"pi{i + 1}" for i in range(rank)),
        tuple(column_definitions(names, proj)),
        tuple(UNITS[p] for p in _length_powers(model)[indep]),
        proj,
        "columns",
        tol,
        seed,
        n_states,
        ("columns", _plan(model, indep), None),
    )


def _n_states(n_full: int, n_rows: int) -> int:
    """Random states of the minimal-set derivation: twice as many equations as unknowns."""
    return max(64, -(-2 * n_full // n_rows))


def _check_set_size(model: Model):
    """Refuse a tree whose minimal-set derivation needs more than ``MAX_SET_BYTES``, counted
    before anything is built: the full regressor (3 rows a state) and the basis of its rows used
    (1 planar, 3 spatial), 8 bytes a value."""
    n_theta = sum(len(INERTIAL_NAMES) - len(b.known_zero) for b in model.bodies)
    n_first = sum(1 for b in model.bodies for n in INERTIAL_NAMES[:4] if n not in b.known_zero)
    n_full = n_theta + n_first * (n_first + 1) // 2
    n_rows = 1 if model.planar else 3
    need = 8 * _n_states(n_full, n_rows) * n_full * (3 + 2 * n_rows)
    if need > MAX_SET_BYTES:
        raise SpaceidError(
            f"{model.source or model.name}: {len(model.bodies)} bodies give {n_full} full parameters, whose "
            f"minimal set would take {need / 2**30:.3g} GiB (at most {MAX_SET_BYTES / 2**30:.3g} GiB): split the "
            "tree, lock joints that do not move (fixed joints), or declare known zeros"
        )


def _dependency_coefficients(y: np.ndarray, indep, dep, basis: np.ndarray, tol: float) -> np.ndarray:
    """``beta`` with ``y[:, dep] = y[:, indep] @ beta``, shape ``(len(indep), len(dep))``, its
    round-off set to zero (``ROUND_OFF``); ``basis`` from :func:`_independent` with ``tol``.

    Round-off is judged by each term's share of its own dependent column, not by the size of the
    coefficient against the largest one: near-degenerate geometry gives some relations
    coefficients of 1e4 and more (a joint axis at ``e`` from the x-y plane of its frame writes the
    link's dependent mcz in the columns before it through ~1/e), and a threshold scaled by them
    zeroed true coefficients (momentum off by 1e-5 of itself for the random tree
    ``parents=[0, 0]``, seed 14151224). The round-off of ill-conditioned relations may exceed
    ``ROUND_OFF`` and is then kept: it is as accurate as the fit.
    """
    # solved through the basis: y_indep = basis @ r with r triangular
    beta = solve_triangular(basis.T @ y[:, indep], basis.T @ y[:, dep])
    norms = np.linalg.norm(y, axis=0)
    live = _nonzero(norms, tol)[dep]  # the columns that count as zero absorb nothing
    beta[:, ~live] = 0.0
    share = np.abs(beta[:, live]) * norms[indep, None] / norms[dep][live]
    beta[:, live] = np.where(share < ROUND_OFF, 0.0, beta[:, live])
    return beta


@dataclass(frozen=True)
class Identifiability:
    """What a minimal set says about the physical parameters and the dynamics (:func:`identifiability`).

    Attributes
    ----------
    no_effect : tuple of str
        Standard parameters that do not enter the momentum at all.
    individually_identifiable : tuple of str
        Standard parameters fixed by ``pi`` on their own.
    in_combinations : tuple of str
        The rest: identifiable only through the combinations ``pi``.
    determines_dynamics : bool
        Whether ``pi`` fixes the kinetic energy with zero linear momentum for every state (its
        regressor lies in the row space of the momentum regressor, docs/theory/general-tree.md), hence
        the reduced inertia matrix that model-based control and the Generalized Jacobian need.
    energy_residual : float
        The relative size of the part of the energy regressor outside that row space.
    """

    no_effect: tuple
    individually_identifiable: tuple
    in_combinations: tuple
    determines_dynamics: bool
    energy_residual: float

    def to_dict(self) -> dict:
        """JSON-ready (``spaceid model --json``'s ``identifiability``): the attributes by name, lists for tuples."""
        return {"no_effect": list(self.no_effect), "individually_identifiable": list(self.individually_identifiable),
                "in_combinations": list(self.in_combinations), "determines_dynamics": self.determines_dynamics,
                "energy_residual": self.energy_residual}


def no_effect_parameters(param: Parameterization, *, tol: float | None = None) -> tuple:
    """The standard parameters that do not enter the momentum at all (:func:`identifiability`'s
    ``no_effect``, without its energy and row-space tests: the export needs only these). Kept in the
    on-disk cache beside the minimal set (:mod:`spaceid._cache`): on the servicer the regressor they
    come from cost an export 0.45 s of its 2.5 to 3 s, most of it the compiled kernels' first load.

    Parameters
    ----------
    param : Parameterization
    tol : float, optional
        Relative tolerance on a regressor column's norm (default: the rank tolerance of ``param``).

    Returns
    -------
    tuple of str
        Their names, in :func:`full_parameter_names`' order.
    """
    tol = param.rank_tol if tol is None else float(tol)
    key = cache_key(_set_key(_Geometry(param.model), param.rank_tol, param.seed), param.n_states, tol)
    stored = read_cached(_NO_EFFECT_KIND, key)
    if stored is not None and "names" in stored:
        return stored_strings(stored["names"])
    names = _no_effect(param, tol)
    write_cached(_NO_EFFECT_KIND, key, {"names": stored_text(names)})
    return names


_NO_EFFECT_KIND = "no-effect"


def _no_effect(param: Parameterization, tol: float) -> tuple:
    """:func:`no_effect_parameters`, from the full regressor at seeded random states."""
    model = param.model
    names = full_parameter_names(model)
    q, qd, w0 = _random_states(model, param.n_states, param.seed + 1)  # fresh states for the tests
    y = full_regressor(model, q, qd, w0)[:, slice(2, 3) if model.planar else slice(None), :].reshape(-1, len(names))
    # a standard parameter acts through its own column and through the lumped products with it
    theta, first, pairs = _layout(model)
    norms = np.sqrt(np.einsum("ij,ij->j", y, y))  # no squared copy: a first touch of its pages takes 0.3 s here
    acts = norms[: len(theta)] > tol * norms.max()
    for c, (a, b) in enumerate(pairs):
        if norms[len(theta) + c] > tol * norms.max():
            acts[theta.index(first[a])] = acts[theta.index(first[b])] = True
            acts[[k == 0 for _, k in theta]] = True  # every mass acts through M = sum of masses
    return tuple(n for n, a in zip(names, acts) if not a)


def identifiability(param: Parameterization, *, tol: float | None = None) -> Identifiability:
    """What the minimal set says about the physical parameters and the dynamics.

    Parameters
    ----------
    param : Parameterization
    tol : float, optional
        Relative tolerance of the subspace tests (default: the rank tolerance of ``param``).

    Returns
    -------
    Identifiability
        ``no_effect``: standard parameters that do not enter the momentum at all;
        ``individually_identifiable``: standard parameters fixed by ``pi`` on their own;
        ``in_combinations``: the rest (identifiable only through the combinations ``pi``);
        ``determines_dynamics``: whether ``pi`` fixes the kinetic energy with zero linear
        momentum for every state (its regressor lies in the row space of the momentum
        regressor, docs/theory/general-tree.md), hence the reduced inertia matrix that model-based control
        and the Generalized Jacobian need; ``energy_residual``: the relative size of the part
        of the energy regressor outside that row space.
    """
    tol = param.rank_tol if tol is None else tol
    model = param.model
    names = full_parameter_names(model)
    n_theta = len(_layout(model)[0])
    no_effect = no_effect_parameters(param, tol=tol)
    q, qd, w0 = _random_states(model, param.n_states, param.seed + 1)
    energy = energy_regressor(model, q, qd, w0)
    with one_blas_thread():  # threaded, on busy cores, this SVD of the servicer's 496 x 1,980 took 35 s (measured)
        rowspace = svd(param.projection, full_matrices=False)[2]  # orthonormal rows, (k, n_full)
        outside = energy - (energy @ rowspace.T) @ rowspace
    energy_residual = float(np.linalg.norm(outside) / np.linalg.norm(energy))
    alone = [n for j, n in enumerate(names[:n_theta])
             if n not in no_effect and 1 - rowspace[:, j] @ rowspace[:, j] < tol]
    return Identifiability(
        no_effect=tuple(no_effect),
        individually_identifiable=tuple(alone),
        in_combinations=tuple(n for n in names[:n_theta] if n not in no_effect and n not in alone),
        determines_dynamics=bool(energy_residual < 1e3 * tol),
        energy_residual=energy_residual,
    )
