"""The system CM from a measured base position, and the generalized Jacobian it gives.

With zero linear momentum the system CM stays put: ``r0(t) + R0(t) c(q(t)) = r_c`` (inertial
frame), with ``c(q) = W(q) phi`` the CM relative to the base origin in base axes, linear in the
barycentric terms ``phi`` (:func:`spaceid.dynamics.com_regressor`). A logged base position
``r0(t)`` therefore identifies, by linear least squares after the momentum identification,

    r0(t) = r_c - R0(t) W(q(t)) phi,

the combinations of ``phi`` that this equation sees (chosen once per model geometry by a pivoted
QR of its columns at seeded random configurations and attitudes; the others are the span of the
chosen ones) and the fixed CM ``r_c``. Planar logs use the x, y rows.

With the CM and the base rate that angular momentum implies, any frame's inertial velocity is
``J*(q) qd + drift`` (Umetani and Yoshida's generalized Jacobian; docs/theory/control.md).
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np
from scipy.linalg import qr

from .._errors import SpaceidError
from .._svd import svd
from .._threads import one_blas_thread
from ..data import Log, quat_to_matrix
from ..dynamics import body_states, com_regressor, com_terms

__all__ = ["identify_com"]

_RANK_TOL = 1e-9
"""Columns of ``W`` whose pivoted-QR diagonal is below this fraction of the largest are spans of the
others (structurally unseen)."""
_DEFINITION_TOL = 1e-9


def _rows(planar):
    return [0, 1] if planar else [0, 1, 2]


def _structural_columns(model, seed, n_configurations=None):
    """Indices of independent columns of the CM equation, and each term's combination of ``phi``
    (k, p): the identified term ``j`` is ``combination[j] @ phi``."""
    rng = np.random.default_rng(seed)
    p = len(com_terms(model)[0])
    n = n_configurations or 2 * p
    q = rng.uniform(-np.pi, np.pi, (n, model.n_joints))
    quat = rng.standard_normal((n, 4))
    if model.planar:
        quat[:, 1:3] = 0.0
    quat /= np.linalg.norm(quat, axis=1, keepdims=True)
    rows = _rows(model.planar)
    a = np.einsum("nij,njk->nik", quat_to_matrix(quat), com_regressor(model, q))[:, rows].reshape(-1, p)
    a = a.reshape(n, len(rows), p)
    a = (a - a.mean(0)).reshape(-1, p)  # r_c absorbs each component's mean
    with one_blas_thread():
        _, r, piv = qr(a, mode="economic", pivoting=True)
        diag = np.abs(np.diag(r))
        cols = np.sort(piv[: int(np.sum(diag > _RANK_TOL * diag[0]))])
        combination = np.linalg.lstsq(a[:, cols], a, rcond=None)[0]
    return cols, combination


def identify_com(model, log: Log, *, seed: int = 0):
    """Identify the system-CM terms from the logged base position (a second linear step).

    Parameters
    ----------
    model : IdentifiedModel
        The momentum identification (``spaceid.load_identified`` or
        :func:`~spaceid.identified.identified_model`).
    log : Log
        The identification's log (or any other of the same system at zero linear momentum) with
        ``base_position`` (CSV columns ``base_x, base_y`` or ``base_px, base_py, base_pz``).
    seed : int, default 0
        Seed of the random configurations that choose the identifiable combinations; recorded.

    Returns
    -------
    IdentifiedModel
        ``model`` with ``com`` set (RESULT.json field ``com``): ``names``, ``definitions`` (the
        combination of the terms ``m_i/M``, ``mc_i/M`` each estimate is), ``values`` [-, m],
        ``std``, ``covariance``, the fixed CM ``inertial_com`` [m] and its ``inertial_com_std``,
        ``residual_rms`` [m], ``n_samples``, ``seed``. Standard errors assume white residuals.

    Raises
    ------
    SpaceidError
        The log has no base position, or its motion does not excite the terms (the design
        matrix is rank deficient, e.g. a base that does not rotate).
    """
    where = log.meta.get("source", "log")
    if log.base_position is None:
        cols = "base_x, base_y" if log.planar else "base_px, base_py, base_pz"
        raise SpaceidError(f"{where}: no base position ({cols} columns): the CM terms need the measured base "
                           "position: log it (motion capture), or identify without the CM terms")
    geometry = model.geometry
    names, definitions, _ = com_terms(geometry)
    cols, combination = _structural_columns(geometry, seed)
    rows = _rows(geometry.planar)
    n, d = log.n_samples, len(rows)
    w = np.einsum("nij,njk->nik", quat_to_matrix(log.base_quat), com_regressor(geometry, log.q)[..., cols])[:, rows]
    a = np.concatenate([np.broadcast_to(np.eye(d), (n, d, d)), -w], -1).reshape(n * d, -1)
    b = log.base_position[:, rows].reshape(-1)
    with one_blas_thread():
        u, s, vt = svd(a, full_matrices=False)
    if s[-1] <= 1e-10 * s[0] or n * d <= a.shape[1]:
        raise SpaceidError(f"{where}: the motion does not excite the {len(cols)} CM terms (condition "
                           f"{s[0] / max(s[-1], 1e-300):.3g}, {n} samples): log a motion that turns the base and "
                           "every joint")
    x = vt.T @ ((u.T @ b) / s)
    residual = b - a @ x
    sigma2 = residual @ residual / (n * d - a.shape[1])
    cov = sigma2 * (vt.T / s**2) @ vt
    std = np.sqrt(np.diag(cov))
    com = {
        "names": [names[c] for c in cols],
        "definitions": [_definition(row, names, definitions) for row in combination],
        "values": x[d:].tolist(), "std": std[d:].tolist(), "covariance": cov[d:, d:].tolist(),
        "inertial_com": np.r_[x[:d], np.zeros(3 - d)].tolist(),
        "inertial_com_std": np.r_[std[:d], np.zeros(3 - d)].tolist(),
        "residual_rms": float(np.sqrt(np.mean(residual**2))), "n_samples": int(n), "seed": int(seed),
        "condition_number": float(s[0] / s[-1]),
    }
    return type(model)(replace(model.identification, com=com), model.param, model.where)


def _definition(row, names, definitions) -> str:
    """``row @ phi`` in words, e.g. ``m_link1/M + 0.3*mcx_link2/M``."""
    big = np.flatnonzero(np.abs(row) > _DEFINITION_TOL * np.abs(row).max())
    return " + ".join(definitions[i] if abs(row[i] - 1) < 1e-9 else f"{row[i]:.12g}*{definitions[i]}" for i in big)


def com_of(model):
    """``(columns, values)`` of the identified CM terms of ``model`` (indices into the columns of
    :func:`~spaceid.dynamics.com_regressor`), or None when it has none; checked against its geometry."""
    com = model.identification.com
    if com is None:
        return None
    names = com_terms(model.geometry)[0]
    unknown = [n for n in com["names"] if n not in names]
    if unknown:
        raise SpaceidError(f"{model.where}: CM term(s) {', '.join(unknown)} are not terms of model "
                           f"'{model.identification.model}': identify the CM again with this model")
    return np.array([names.index(n) for n in com["names"]]), np.asarray(com["values"], float)


def com_position(model, q) -> np.ndarray:
    """The identified system CM [m] relative to the base origin, base axes, ``(..., 3)`` (z zero for
    planar models); raises the error of ``model.requires`` without CM terms."""
    com = com_of(model)
    if com is None:
        model.requires("system_com")
    c = com_regressor(model.geometry, q)[..., com[0]] @ com[1]
    if model.geometry.planar:  # the identification sees the plane only
        c[..., 2] = 0.0
    return c


def frame_jacobians(model, q, frame: str, point=None):
    """Base-axes kinematics of a frame and of the system CM: the pieces of the generalized Jacobian.

    Returns ``(p, jp, jw, c, jc)``: the frame point relative to the base origin ``(..., 3)`` [m], its
    velocity and the frame's angular velocity per joint rate ``(..., 3, n)`` (base at rest), the
    system CM ``(..., 3)`` and its velocity per joint rate ``(..., 3, n)`` (z zero for planar models).
    """
    geometry = model.geometry
    bodies = [b.name for b in geometry.bodies]
    if frame not in bodies:
        raise SpaceidError(f"`frame` '{frame}' is not a body of model '{model.identification.model}' (bodies: "
                           f"{', '.join(bodies)}): name a body, and give a fixed child's offset as `point`")
    c = com_position(model, q)
    cols, values = com_of(model)
    q = np.asarray(q, float)
    n = geometry.n_joints
    unit = np.broadcast_to(np.eye(n), q.shape[:-1] + (n, n))
    st = body_states(geometry, q[..., None, :], unit, np.zeros(3))  # one unit joint rate a row
    b = bodies.index(frame)
    offset = np.zeros(3) if point is None else np.asarray(point, float)
    arm = st.rotation[..., 0, b, :, :] @ offset
    p = st.position[..., 0, b, :] + arm
    jw = np.swapaxes(st.omega[..., b, :], -1, -2)
    jp = np.swapaxes(st.velocity[..., b, :] + np.cross(st.omega[..., b, :], arm[..., None, :]), -1, -2)
    # W rates: base columns still, body columns [v_i, w_i x R_i e_x, ...]
    moving = np.concatenate([st.velocity[..., 1:, :, None], np.cross(st.omega[..., 1:, None, :],
                             np.swapaxes(st.rotation[..., 1:, :, :], -1, -2))
                             .swapaxes(-1, -2)], -1)  # (..., n, nb - 1, 3, 4)
    w_rate = np.concatenate([np.zeros(moving.shape[:-3] + (3, 3)),
                             np.moveaxis(moving, -3, -2).reshape(moving.shape[:-3] + (3, -1))], -1)
    jc = np.swapaxes(w_rate[..., cols] @ values, -1, -2)
    if geometry.planar:
        jc[..., 2, :] = 0.0
    return p, jp, jw, c, jc
