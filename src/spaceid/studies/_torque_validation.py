"""Validation at the torque level: the identified model driven by the measured joint torques.

From the measured state at the start of each window of ``horizon`` seconds, the joint dynamics of
the identified model (:meth:`spaceid.identified.IdentifiedModel.forward_dynamics`, momentum
conserved, linear momentum zero) are integrated under the logged efforts ``tau_J`` (linear between
samples, or held from each to the next), with the base attitude following the base rate that
momentum implies (classical Runge-Kutta, every window at once). The predicted joint angles and
rates and base motion are compared with the measured ones. Restarting every window keeps the
comparison about the model rather than the growth of an open-loop error over long times.
"""

from __future__ import annotations

import numpy as np

from .._errors import SpaceidError
from ..data import Log, quat_to_yaw, yaw_to_quat

__all__ = ["TORQUE_METRIC_LABELS", "TORQUE_VALIDATION_TITLE", "torque_metrics", "validate_torques"]

TORQUE_VALIDATION_TITLE = ("Torque-level validation: measured motion vs the identified model driven by the "
                           "measured torques")

TORQUE_METRIC_LABELS = {
    "torque_q_rms": "torque-driven joint angles, RMS error [rad]",
    "torque_q_max": "torque-driven joint angles, largest error [rad]",
    "torque_qd_rms": "torque-driven joint rates, RMS error [rad/s]",
    "torque_qd_nrms": "torque-driven joint rates, RMS error / RMS value",
    "torque_base_w_rms": "torque-driven base angular velocity, RMS error [rad/s]",
    "torque_base_yaw_rms": "torque-driven base yaw, RMS error [rad]",
    "torque_attitude_rms": "torque-driven base attitude, RMS error angle [rad]",
    "horizon": "horizon of each window [s]",
    "windows": "windows (restarts from the measured state)",
}


def _quat_rate(quat, w):
    """``dq/dt = q (x) [0, w] / 2`` for body-axes rates ``w``; shapes ``(..., 4)``, ``(..., 3)``."""
    s, v = quat[..., :1], quat[..., 1:]
    return 0.5 * np.concatenate([-np.sum(v * w, -1, keepdims=True), s * w + np.cross(v, w)], -1)


def _unit(quat):
    return quat / np.linalg.norm(quat, axis=-1, keepdims=True)


def _integrate(model: IdentifiedModel, log: Log, windows, momentum, max_step, hold):
    """States ``[q, qd, yaw or quaternion]`` at every sample of ``windows`` (index arrays), each from
    its first sample: classical Runge-Kutta, all windows at once (the dynamics are batched), each
    sample interval in equal steps of at most ``max_step`` over which the torque is linear (``hold``
    "linear") or that of the interval's first sample ("zero")."""
    n, planar = model.geometry.n_joints, model.geometry.planar
    length = max(len(w) for w in windows)
    index = np.array([np.r_[w, np.full(length - len(w), w[-1])] for w in windows])  # (B, L), the ends held
    t, tau = log.t[index], log.tau[index]
    first = index[:, 0]
    y = np.column_stack([log.q[first], log.qd[first], log.base_yaw[first] if planar else log.base_quat[first]])

    def rhs(y, torque):
        q, qd = y[:, :n], y[:, n : 2 * n]
        quat = yaw_to_quat(y[:, 2 * n]) if planar else _unit(y[:, 2 * n :])
        w0 = model.base_rate(q, qd, momentum, quat)
        attitude = w0[:, 2:] if planar else _quat_rate(quat, w0)
        return np.column_stack([qd, model.forward_dynamics(q, qd, torque, momentum, quat), attitude])

    out = [y]
    for i in range(length - 1):
        dt = t[:, i + 1] - t[:, i]
        m = max(1, int(np.ceil(dt.max() / max_step - 1e-9)))
        h = (dt / m)[:, None]
        for k in range(m):
            slope = 0.0 if hold == "zero" else tau[:, i + 1] - tau[:, i]
            torque = [tau[:, i] + slope * (k + a) / m for a in (0.0, 0.5, 1.0)]
            k1 = rhs(y, torque[0])
            k2 = rhs(y + h / 2 * k1, torque[1])
            k3 = rhs(y + h / 2 * k2, torque[1])
            k4 = rhs(y + h * k3, torque[2])
            y = y + h / 6 * (k1 + 2 * k2 + 2 * k3 + k4)
        if not planar:
            y[:, 2 * n :] = _unit(y[:, 2 * n :])
        out.append(y)
    states = np.stack(out, 1)  # (B, L, state)
    if not np.isfinite(states).all():
        raise SpaceidError("torque validation: the predicted motion diverged: shorten the `horizon` or check the "
                           "log's efforts (columns tau_J, N m)")
    return np.concatenate([states[b, : len(w)] for b, w in enumerate(windows)])


def validate_torques(model, log: Log, *, horizon: float | None = None, momentum=None, max_step: float = 0.01,
                     hold: str = "linear", where: str = "result"):
    """Drive the identified model with the measured torques and compare its motion with the log.

    Parameters
    ----------
    model : IdentifiedModel or Identification
    log : Log
        With ``tau`` (CSV columns ``tau_J`` [N m or N]); the model's joints in order.
    horizon : float, optional
        Length [s] of each window integrated from the measured state (default: the whole log).
    momentum : array_like of shape (3,), optional
        Inertial angular momentum [N m s] (default: the identification's).
    hold : {"linear", "zero"}
        The torque between samples: linear interpolation, or held from each sample to the next
        (a digital controller's zero-order hold, logged at its own rate).
    max_step : float
        Largest integration step [s] (classical Runge-Kutta, the sample intervals split evenly;
        the error falls as its fourth power: on a Cepheus motion of ~1 rad/s, 8e-9 rad at 0.01 s,
        6e-11 rad at 0.0025 s; with its wheel at 170 rad/s, 1.5e-6 rad at 0.01 s, a thousandth of
        an encoder count).

    Returns
    -------
    predicted : Log
        The predicted motion at the log's stamps (``tau`` the measured one).
    metrics : dict
        :func:`torque_metrics`, plus ``horizon`` [s] and ``windows``.

    Raises
    ------
    SpaceidError
        The log has no efforts, other joints than the model, or ``horizon`` is not positive; the
        identified ``H*`` is not positive definite at some logged configuration.
    """
    from ..identified import IdentifiedModel, identified_model  # (not at import: the reports need only labels)

    model = model if isinstance(model, IdentifiedModel) else identified_model(model, where=where)
    source = log.meta.get("source", "log")
    if log.tau is None:
        raise SpaceidError(f"{source}: no joint efforts (columns {', '.join(f'tau_{j}' for j in log.joints)}): "
                           "log the joint torques to validate at the torque level, or validate the base rate only")
    if tuple(log.joints) != tuple(model.joints):
        raise SpaceidError(f"{source}: joints {list(log.joints)} differ from the model's {list(model.joints)}")
    span = float(log.t[-1] - log.t[0])
    horizon = span if horizon is None else float(horizon)
    if not horizon > 0:
        raise SpaceidError(f"`horizon`: {horizon:g} s is not positive: give a positive horizon in seconds")
    if hold not in ("linear", "zero"):
        raise SpaceidError(f"`hold`: {hold!r} is neither 'linear' nor 'zero'")
    h = model.momentum if momentum is None else np.asarray(momentum, float)
    _check_positive_inertia(model, log, where)
    count = max(1, int(np.ceil(span / horizon - 1e-9)))  # the last stamp closes the last window
    starts = np.minimum(np.floor((log.t - log.t[0]) / horizon + 1e-9).astype(int), count - 1)
    states = _integrate(model, log, [np.flatnonzero(starts == k) for k in np.unique(starts)], h, max_step, hold)
    n = model.geometry.n_joints
    q, qd = states[:, :n], states[:, n : 2 * n]
    quat = yaw_to_quat(states[:, 2 * n]) if log.planar else _unit(states[:, 2 * n :])
    w0 = model.base_rate(q, qd, h, quat)
    meta = {"source": f"{where}: driven by the torques of {source}", "horizon": horizon, "momentum": h.tolist()}
    predicted = Log(log.t, log.joints, q, qd, quat, w0, log.planar, meta, None, log.tau)
    return predicted, torque_metrics(log, predicted) | {"horizon": horizon, "windows": len(np.unique(starts))}


def _check_positive_inertia(model: IdentifiedModel, log: Log, where: str, n_checked: int = 500) -> None:
    """Raise unless ``H*`` of the identified model is positive definite at (up to ``n_checked``
    evenly spread) samples of the log: otherwise its forward dynamics run away exponentially."""
    rows = np.unique(np.linspace(0, log.n_samples - 1, min(n_checked, log.n_samples)).astype(int))
    lowest = np.linalg.eigvalsh(model.reduced_inertia(log.q[rows]))[:, 0]
    bad = lowest <= 0
    if bad.any():
        raise SpaceidError(
            f"{where}: the identified free-floating inertia H* is not positive definite at {bad.sum()} of "
            f"{len(rows)} samples checked (lowest eigenvalue {lowest.min():.3g}): these parameters are not "
            "physically consistent, so their forward dynamics diverge; identify from more samples or validate "
            "a consistent model (export_model, 'spaceid export')")


def torque_metrics(measured: Log, predicted: Log) -> dict:
    """RMS and largest errors of a torque-driven prediction (norms over joints and axes).

    Returns
    -------
    dict
        ``torque_q_rms``, ``torque_q_max`` [rad], ``torque_qd_rms`` [rad/s], ``torque_qd_nrms``
        (over the RMS of the measured rates), ``torque_base_w_rms`` [rad/s], and
        ``torque_base_yaw_rms`` [rad] (planar) or ``torque_attitude_rms`` [rad] (spatial: the angle
        of the relative rotation). Labels in :data:`TORQUE_METRIC_LABELS`.
    """
    def rms(err):
        return float(np.sqrt(np.mean(np.sum(np.square(err), axis=1))))

    dq, dqd = predicted.q - measured.q, predicted.qd - measured.qd
    out = {"torque_q_rms": rms(dq), "torque_q_max": float(np.abs(dq).max()), "torque_qd_rms": rms(dqd),
           "torque_qd_nrms": rms(dqd) / max(rms(measured.qd), 1e-300),
           "torque_base_w_rms": rms(predicted.base_w - measured.base_w)}
    if measured.planar:
        yaw = np.angle(np.exp(1j * (quat_to_yaw(predicted.base_quat) - quat_to_yaw(measured.base_quat))))
        out["torque_base_yaw_rms"] = float(np.sqrt(np.mean(yaw**2)))
    else:
        # angle of conj(measured) (x) predicted, from its vector part (arccos of the dot loses small angles)
        a, b = measured.base_quat, predicted.base_quat
        vector = a[:, :1] * b[:, 1:] - b[:, :1] * a[:, 1:] - np.cross(a[:, 1:], b[:, 1:])
        angle = 2 * np.arctan2(np.linalg.norm(vector, axis=1), np.abs(np.einsum("ij,ij->i", a, b)))
        out["torque_attitude_rms"] = float(np.sqrt(np.mean(angle**2)))
    return out
