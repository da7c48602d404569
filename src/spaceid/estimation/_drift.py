"""External torques on the base: the drift of the momentum that the equations otherwise take as
constant (docs/theory/drift.md).

On an air-bearing table (or a spacecraft with a residual disturbance) the momentum of the whole
system changes by the external torque's integral, ``h(t) = h0 + sum_k d_k g_k(t)``, with ``h0``
the momentum at the log's first sample, ``d_k`` unknown coefficients and ``g_k(t)`` the
momentum change per unit coefficient, inertial axes [N m s per unit]:

``torque``
    a constant torque ``tau`` [N m] (per inertial axis; z only for planar systems):
    ``g = (t - t0) e_axis``.
``viscous``
    base friction ``-c w0`` [c in N m s/rad], isotropic: ``g = -int R0 w0 dt``; planar, the
    change of the unwrapped yaw (exact, no quadrature); spatial, a local polynomial quadrature of
    the samples (eighth order).
``coulomb``
    base friction of constant magnitude ``mu`` [N m] against the rotation,
    ``-mu w0 / |w0|`` (planar ``-mu sign(w0z)``): ``g = -int R0 w0 / |w0| dt``; planar, from the
    samples' signs, each sign change located between its two samples by one-sided cubic fits
    (fourth order); spatial, the local polynomial quadrature.

The coefficients are estimated with the parameters; ``g_k`` are computed once from the log (time,
attitude, base rate) and treated as exogenous (noise-free) by every estimator.
"""

from __future__ import annotations

import numpy as np

from .._constants import DRIFT_KINDS
from .._errors import SpaceidError
from ..data import Log, quat_to_matrix

__all__ = ["DRIFT_KINDS", "drift_names", "drift_basis", "drift_terms", "drift_vector"]

_UNITS = {"torque": "N m", "viscous": "N m s/rad", "coulomb": "N m"}


def check_drift_kinds(drift) -> tuple:
    """The drift kinds of ``drift`` (an iterable of names, or a ``"a,b"`` string) in
    ``DRIFT_KINDS`` order, each once; raises naming ``drift`` for an unknown one."""
    items = drift.split(",") if isinstance(drift, str) else list(drift or ())
    kinds = [str(k).strip().lower() for k in items if str(k).strip()]
    bad = [k for k in kinds if k not in DRIFT_KINDS]
    if bad:
        raise SpaceidError(f"`drift`: '{bad[0]}' is not a drift kind: name any of {', '.join(DRIFT_KINDS)} "
                           "(several: a list, or comma-separated)")
    return tuple(k for k in DRIFT_KINDS if k in kinds)


def _axes(planar):
    return [2] if planar else [0, 1, 2]


def drift_names(kinds, planar: bool) -> tuple:
    """Names ``(n_d,)`` of the drift coefficients and their units: ``torque_x``.. (``torque_z``
    only for planar systems), ``viscous``, ``coulomb``."""
    names, units = [], []
    for kind in check_drift_kinds(kinds):
        parts = [f"torque_{'xyz'[a]}" for a in _axes(planar)] if kind == "torque" else [kind]
        names += parts
        units += [_UNITS[kind]] * len(parts)
    return tuple(names), tuple(units)


INTEGRAL_NODES = 8
"""Samples through which :func:`_sample_integral` interpolates each interval: degree 7, eighth order
(a quintic spline, sixth order, left 6e-7 at 10 Hz on a 3 rad/s sine where these leave 6e-8; the
trapezoid rule's second order left 1e-4 relative errors in the drift coefficients at 100 Hz)."""


def _sample_integral(t, f):
    """``int_{t0}^{t_i} f dt`` at every sample time ``t (n,)`` of samples ``f (n, c)``: each interval's
    integral that of the polynomial through the :data:`INTEGRAL_NODES` samples around it (those at
    the log's ends shifted inwards; all of them on a shorter log: two, the trapezoid rule), summed.
    A local rule, not a spline: an interval's error stays where the signal is rough (a Coulomb
    column's reversal), and SciPy's splines cost their import, 0.14 s of a first ``identify``."""
    n = len(t)
    k = min(INTEGRAL_NODES, n)
    if n < 2:
        return np.zeros((n, f.shape[1]))
    start = np.clip(np.arange(n - 1) - (k // 2 - 1), 0, n - k)
    nodes = start[:, None] + np.arange(k)  # (n - 1, k)
    h = np.diff(t)
    # each interval at [-a, a] (a = 1 / k) and its nodes about it: Vandermonde's condition stays small
    s = ((t[nodes] - t[:-1, None]) / h[:, None] - 0.5) * (2 / k)
    powers = np.arange(k)
    a = 1 / k
    moments = (a ** (powers + 1) - (-a) ** (powers + 1)) / (powers + 1) * (k / 2)  # of s^p over the unit interval
    V = np.empty((n - 1, k, k))  # (interval, power, node): products, not powers (a sixth of the time)
    V[:, 0] = 1.0
    for p in range(1, k):
        V[:, p] = V[:, p - 1] * s
    weights = np.linalg.solve(V, np.broadcast_to(moments, (n - 1, k))[..., None])[..., 0]
    pieces = h[:, None] * np.einsum("ij,ijc->ic", weights, f[nodes])
    return np.concatenate([np.zeros((1, f.shape[1])), np.cumsum(pieces, 0)])


def _crossing(t, w, i):
    """Where the base rate crosses zero between samples ``i`` and ``i + 1``: the mean of the roots
    in that interval of the cubics through the four samples on either side (each side is smooth up
    to the crossing, where a Coulomb torque puts a kink: one-sided fits keep fourth order), or of
    the straight line between the two samples when neither cubic has a root there."""
    lo, hi = t[i], t[i + 1]
    roots = []
    for side in (slice(max(i - 3, 0), i + 1), slice(i + 1, i + 5)):
        ts, ws = t[side], w[side]
        if len(ts) == 4:
            r = np.roots(np.polyfit(ts - lo, ws, 3)) + lo
            r = r[(np.abs(r.imag) < 1e-12 * (hi - lo)) & (r.real >= lo) & (r.real <= hi)].real
            roots += [r[np.argmin(np.abs(r - (lo + hi) / 2))]] if len(r) else []
    return float(np.mean(roots)) if roots else lo + (hi - lo) * w[i] / (w[i] - w[i + 1])


def _sign_integral(t, w):
    """``int_{t0}^{t_n} sign(w) dt`` of samples ``w (n,)``: the sign of the samples between them,
    and where it changes the crossing of :func:`_crossing`."""
    part = np.sign(w[:-1]) * np.diff(t)
    for i in np.flatnonzero(w[:-1] * w[1:] < 0):
        root = _crossing(t, w, i)
        part[i] = np.sign(w[i]) * (root - t[i]) + np.sign(w[i + 1]) * (t[i + 1] - root)
    part = np.where((w[:-1] == 0), np.sign(w[1:]) * np.diff(t), part)
    return np.concatenate([[0.0], np.cumsum(part)])


def drift_basis(log: Log, kinds) -> np.ndarray:
    """The momentum change per unit drift coefficient at every sample of ``log``.

    Parameters
    ----------
    log : Log
        Measured motion (time, base attitude, base angular velocity are used).
    kinds : iterable of str
        Drift kinds (see :data:`DRIFT_KINDS`).

    Returns
    -------
    ndarray of shape (n_samples, n_d, 3)
        ``g_k(t_n)`` in inertial axes [N m s per unit of the coefficient], columns ordered as
        :func:`drift_names`; zero at the first sample.
    """
    kinds = check_drift_kinds(kinds)
    t = np.asarray(log.t, float)
    n = len(t)
    cols = []
    for kind in kinds:
        if kind == "torque":
            for a in _axes(log.planar):
                g = np.zeros((n, 3))
                g[:, a] = t - t[0]
                cols.append(g)
            continue
        g = np.zeros((n, 3))
        if log.planar:
            wz = log.base_w[:, 2]
            g[:, 2] = -(log.base_yaw - log.base_yaw[0]) if kind == "viscous" else -_sign_integral(t, wz)
        else:
            w = np.einsum("nij,nj->ni", quat_to_matrix(log.base_quat), log.base_w)  # inertial axes
            if kind == "coulomb":
                norm = np.linalg.norm(w, axis=1, keepdims=True)
                w = np.divide(w, norm, out=np.zeros_like(w), where=norm > 0)
            g = -_sample_integral(t, w)
        cols.append(g)
    return np.stack(cols, 1) if cols else np.zeros((n, 0, 3))


def drift_terms(values: dict, planar: bool, where: str = "`drift`", *, physical: bool = True) -> dict:
    """Drift coefficients as the ``{"torque": (3,), "viscous": c, "coulomb": mu}`` that
    :func:`spaceid.motion.simulate` takes, from a dict keyed by kind (``torque`` a number for
    planar systems or 3 numbers) or by coefficient name (``torque_x``, ``torque_y``,
    ``torque_z``, ``viscous``, ``coulomb``); the terms given are kept, zeros included (an
    override), absent ones left out. ``physical``: friction coefficients must be >= 0 (an
    estimate may come out slightly negative: ``physical=False`` takes it as it is)."""
    torque = np.zeros(3)
    out, torque_given = {}, False
    for key, value in dict(values or {}).items():
        name = str(key).strip().lower()
        v = np.asarray(value, float).reshape(-1)
        if not np.all(np.isfinite(v)):
            raise SpaceidError(f"{where}: {name} = {value!r} is not finite")
        if name.startswith("torque"):
            torque_given = True
        if name == "torque":
            if v.size == 1 and planar:
                torque[2] = v[0]
            elif v.size == 3:
                torque = v.copy()
            else:
                raise SpaceidError(f"{where}: torque expects {'one number (about z) or ' if planar else ''}"
                                   f"3 numbers tx:ty:tz [N m], got {value!r}")
        elif name in ("torque_x", "torque_y", "torque_z"):
            torque["xyz".index(name[-1])] = float(v[0]) if v.size == 1 else np.nan
        elif name in ("viscous", "coulomb") and v.size == 1:
            if physical and v[0] < 0:
                raise SpaceidError(f"{where}: {name} = {v[0]:g} must be >= 0 (a friction coefficient)")
            out[name] = float(v[0])
        else:
            raise SpaceidError(f"{where}: '{key}' is not a drift term: use torque, torque_x, torque_y, torque_z, "
                               "viscous or coulomb with one value each")
    if not np.all(np.isfinite(torque)):
        raise SpaceidError(f"{where}: torque_x/torque_y/torque_z take one number each")
    if planar and np.any(torque[:2]):
        raise SpaceidError(f"{where}: a planar system takes a torque about z only, got {torque.tolist()}")
    if torque_given:
        out["torque"] = torque
    return out


def drift_vector(terms: dict, kinds, planar: bool) -> np.ndarray:
    """The coefficients ``(n_d,)`` in :func:`drift_names` order of ``kinds`` from the
    :func:`drift_terms` dict ``terms`` (absent terms zero)."""
    terms, out = drift_terms(terms, planar, where="`drift`", physical=False), []
    for kind in check_drift_kinds(kinds):
        if kind == "torque":
            out += list(np.asarray(terms.get("torque", np.zeros(3)), float)[_axes(planar)])
        else:
            out.append(float(terms.get(kind, 0.0)))
    return np.array(out, float)
