"""The payload from a log cut at a grasp: :func:`payload_after_grasp` ('spaceid payload --grasp'
and the servicing study, docs/theory/capture.md).

The samples just after the grasp are left out: the rates jump at the impact, and a centred
differentiator spreads the jump over the samples whose window holds it. The momentum after the
grasp is given (zero: a capture from rest), estimated with the payload (a payload that moved:
its momentum joined the servicer's), or the servicer's own, averaged over a hold before the
grasp (the payload at rest carries none): its error, from the angle noise carried through the
differentiators (or the white noise of measured rates), then joins the payload's covariance. A
payload that moved adds its own momentum: given its velocity and rate, a function of its
parameters (:class:`~spaceid.identified.GraspMotion`) and of the servicer's configuration at the
grasp, whose error (from the same samples before the grasp as the hold's) joins it alike.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from .._errors import SpaceidError
from ..data import Log, quat_to_matrix
from ..estimation import Noise, noise_from_log, signal_sigma
from ..estimation.internal import correlation_length, differentiated_series, propagated_covariance, window_spans
from ._payload import (
    GraspMotion,
    PayloadEstimate,
    PayloadMap,
    _attitude_axes,
    _central_jacobian,
    _equations,
    identify_payload,
    payload_map,
)

__all__ = ["HOLD", "GraspEstimate", "hold_momentum", "mean_momentum", "payload_after_grasp"]

HOLD = 1.0
"""How long [s] before the grasp the servicer holds still (the study's arm at the end of the
held-out phase): the samples the momentum before the grasp is averaged over."""
HOLD_SAMPLES = 5
"""Fewest samples of the hold that the momentum before the grasp is averaged over."""


def mean_momentum(param, values, log: Log) -> np.ndarray:
    """The inertial angular momentum [N m s] (3,) of the parameters ``values`` of ``param`` over
    ``log``, the mean of its samples (from the measured joint and base rates)."""
    h_base = np.zeros((log.n_samples, 3))
    h_base[:, [2] if param.model.planar else [0, 1, 2]] = param.momentum(log.q, log.qd, log.base_w, values)
    return np.einsum("nij,nj->ni", quat_to_matrix(log.base_quat), h_base).mean(axis=0)


def hold_momentum(pmap: PayloadMap, still: Log, noise: Noise) -> tuple:
    """The servicer's momentum over the samples ``still`` (no payload yet) and its covariance.

    The mean's error is ``(1/N) sum_n R0_n e_n``, ``e_n`` the equation error of sample ``n`` at the
    mean (base axes): first order in the signals' noise. Rates differentiated by Savitzky-Golay
    carry the angle noise of the series behind them (:mod:`spaceid.estimation._differentiated`:
    their errors are correlated over the window, so a few held samples average little of it);
    every other signal is white at its ``noise`` level.

    Parameters
    ----------
    pmap : PayloadMap
        The servicer (its parameters without the payload).
    still : Log
        The hold's samples (cut from a longer record: its differentiation record is the record's).
    noise : Noise
        White noise levels of the signals not differentiated.

    Returns
    -------
    (ndarray of shape (3,), ndarray of shape (3, 3))
        Inertial momentum [N m s] and its covariance [(N m s)^2] (zero off the planar z axis).
    """
    h, gain = _hold_gain(pmap, still)
    return h, _signal_covariance(pmap, still, gain, noise)


def _hold_gain(pmap: PayloadMap, still: Log) -> tuple:
    """The servicer's mean momentum over ``still`` (inertial, (3,)) and its first-order error as a
    linear map ``(n, 3, n_x)`` of each sample's signal errors (:func:`_signal_covariance`): the mean
    of ``R0_n e_n``, ``e_n = J_n dx_n`` the equation error at the mean (zero rows off the planar z)."""
    h = mean_momentum(pmap.param, pmap.pi(np.zeros(pmap.n)), still)
    eq = _equations(pmap, still, h, (), "hold")
    x = eq.signals(still)
    jac = eq.jacobian(x, np.zeros(0))
    gain = np.zeros((still.n_samples, 3, _n_signals(pmap)))
    gain[:, eq.axes, : x.shape[1]] = np.einsum("nar,nrx->nax", eq.rot[:, eq.axes][:, :, eq.axes], jac)
    return h, gain / still.n_samples


def _n_signals(pmap: PayloadMap) -> int:
    """Columns of the signals ``[q, qd, w0, attitude]`` of :func:`_signal_covariance`."""
    return 2 * pmap.param.model.n_joints + 2 * len(_attitude_axes(pmap.planar))


def _signal_covariance(pmap: PayloadMap, log: Log, gain, noise: Noise) -> np.ndarray:
    """Covariance ``(d, d)`` of an error ``sum_n G_n dx_n`` linear in the signal errors ``dx_n`` of
    the samples of ``log`` (consecutive, cut from a record), ``G = gain (n, d, n_x)``.

    The signals are the equations' ``x = [q, qd, w0, phi]`` (``phi`` a small rotation of the
    attitude), the yaw appended for planar ones. Savitzky-Golay series carry their raw angle noise
    through the filters (:mod:`spaceid.estimation._differentiated`: smoothed angle and rate from the
    same samples); every other signal is white at its ``noise`` level.
    """
    nj = pmap.param.model.n_joints
    series = [(record, 2 * nj + 1 if value is None else value, rate)  # the smoothed yaw: the planar column appended
              for record, value, rate in differentiated_series(log) or []]  # fmt: skip
    sigma = np.r_[signal_sigma(pmap.param, noise), [noise.attitude] * pmap.planar]
    eye = np.broadcast_to(np.eye(sigma.size), (log.n_samples, sigma.size, sigma.size))
    return propagated_covariance(series, log.t, [(slice(None), np.swapaxes(gain, 1, 2), eye)], np.eye(gain.shape[1]),
                                 sigma)  # fmt: skip


@dataclass(frozen=True)
class GraspEstimate:
    """The payload identified from a log cut at a grasp (:func:`payload_after_grasp`).

    Attributes
    ----------
    estimate : PayloadEstimate
        The payload; its ``settings["grasp"]`` (:attr:`grasp`) records the cut.
    window : Log
        The samples of the log it was identified from.
    """

    estimate: PayloadEstimate
    window: Log

    @property
    def grasp(self) -> dict:
        """The record of the cut: ``time``, ``window``, ``window_start_after_grasp`` [s], ``hold`` (None unless
        the momentum was the hold's) and, for a payload that moved, ``payload_motion``
        (docs/formats/payload-json.md)."""
        return self.estimate.settings["grasp"]

    def to_dict(self) -> dict:
        """JSON-ready: the estimate's PAYLOAD.json object (its ``settings.grasp`` holds the window's ends)."""
        return self.estimate.to_dict()


def payload_after_grasp(model, log: Log, link: str, grasp: float, momentum, *, payload_motion=None,
                        end: float | None = None, noise: Noise | None = None, drift=(), seed: int = 0,
                        where: str = "log") -> GraspEstimate:
    """The payload identified from the samples of ``log`` after a grasp at ``grasp`` [s].

    The window runs from half the longest differentiator window after the grasp to ``end``.

    Parameters
    ----------
    model : Model or str or Path or PayloadMap
        The known servicer without the payload.
    log : Log
        A record that spans the grasp (with ``momentum`` "hold": and the hold before it).
    link : str
        The link that holds the payload.
    grasp : float
        The grasp instant [s], on ``log``'s clock.
    momentum : array_like of shape (3,) or None or "hold"
        The inertial momentum after the grasp [N m s] (given: zero for a capture from rest), None
        (estimated with the payload: nearly collinear with it when the base turns steadily, so a
        payload that moved is better given by ``payload_motion``), or "hold": the servicer's
        over ``HOLD`` s before the grasp (:func:`hold_momentum`; a payload at rest), with its
        covariance carried into the payload's; with ``drift`` the drift is integrated from there.
    payload_motion : tuple of two array_like of shape (3,), optional
        A payload that moved before the grasp: the velocity of its CoM [m/s] and its angular
        velocity [rad/s], inertial axes (:class:`~spaceid.identified.GraspMotion`, the servicer's
        configuration at the grasp instant from ``log``'s angles and rates before it, its
        covariance, with the hold's momentum's, carried into the payload's); ``momentum`` is then
        the servicer's alone.
    end : float, optional
        Last instant of the window [s] (default: the end of ``log``).
    noise, drift, seed, where
        As :func:`spaceid.identified.identify_payload` (``noise`` omitted: estimated from the window;
        the hold's from ``log``).

    Returns
    -------
    GraspEstimate
        The estimate (``settings["grasp"]`` records the window, the hold and the payload's motion
        with the configuration's standard errors) and its window of ``log``.

    Raises
    ------
    SpaceidError
        The grasp outside the log, too few samples after it, or no hold before it.
    """
    if not log.t[0] < grasp < log.t[-1]:
        raise SpaceidError(f"`grasp`: {grasp:g} s is not inside {where} ({log.t[0]:.6g}..{log.t[-1]:.6g} s): give "
                           "the grasp instant on the log's clock")
    pmap = model if isinstance(model, PayloadMap) else payload_map(model, link, seed=seed)
    margin = correlation_length(log) / 2 * float(np.median(np.diff(log.t)))
    end = log.t[-1] if end is None else end
    after = (log.t > grasp + margin + 1e-9) & (log.t <= end + 1e-9)
    if after.sum() < 2:
        raise SpaceidError(f"`grasp`: {where} has no samples from {grasp + margin:.6g} s (the grasp plus half the "
                           "differentiator's window) on: record longer after the grasp")
    window = replace(log.select(after), meta=dict(log.meta, window=[grasp + margin, float(end)]))
    record = {"time": float(grasp), "window": [float(window.t[0]), float(window.t[-1])],
              "window_start_after_grasp": float(window.t[0] - grasp), "hold": None}  # fmt: skip
    if isinstance(momentum, str) and momentum != "hold":
        raise SpaceidError(f"`momentum`: {momentum!r} is not a value, None (unknown) or 'hold'")
    hold = _hold(log, grasp, margin, where) if isinstance(momentum, str) else None
    config = None if payload_motion is None else _configuration_at(log, grasp, pmap.planar)
    history, cov, motion = None, None, None
    if hold is not None or config is not None:
        h, joint = _before_grasp(pmap, log, hold, config, noise_from_log(log) if noise is None else noise)
    if hold is not None:
        momentum, cov, still = h, joint[:3, :3], log.t[hold]
        history = log.select((log.t >= still[len(still) // 2]) & (log.t <= window.t[-1] + 1e-9)) if drift else None
        record["hold"] = {"from": float(still[0]), "to": float(still[-1]), "samples": int(hold.size),
                          "momentum": momentum.tolist(), "momentum_std": np.sqrt(np.diag(cov)).tolist(),
                          "drift_from": None if history is None else float(history.t[0])}  # fmt: skip
    if config is not None:
        q, rotation, rows, _ = config
        motion = GraspMotion(*(np.asarray(v, float).reshape(3) for v in payload_motion), q, rotation, joint[3:, 3:],
                             None if hold is None else joint[:3, 3:])  # fmt: skip
        record["payload_motion"] = {"velocity": motion.velocity.tolist(), "rate": motion.rate.tolist(),
                                    "configuration_at": float(grasp),  # from the joints' samples, the attitude's:
                                    "configuration_from": log.t[rows[: q.size + 1]].tolist(),
                                    "configuration_std": np.sqrt(np.diag(motion.cov)).tolist()}  # fmt: skip
    estimate = identify_payload(pmap, window, link, momentum, grasp_motion=motion, momentum_cov=cov, noise=noise,
                                drift=drift, history=history, seed=seed, where=where)  # fmt: skip
    return GraspEstimate(replace(estimate, settings=estimate.settings | {"grasp": record}), window)


def _configuration_at(log: Log, t: float, planar: bool) -> tuple:
    """The servicer's configuration at the grasp instant ``t`` [s]: each angle (and the attitude)
    from its last sample whose differentiator window ends before ``t``, carried to ``t`` by its
    rate there (``planar``: the model's; the attitude's error is then the yaw's).

    The grasp's jump in the rates is a kink in the angles, which the differentiators smooth over
    their windows (on the Cepheus twin the arm's angles at the grasp by 0.02 rad, the attitude by
    3e-3 rad: the moving payload's mass 0.4 standard errors low); the sample before the grasp,
    up to a sample step early, misses the base's turn since (1.9 rad/s there: 0.04 rad, the mass
    0.4 % low). The rates before the grasp carry the angles across without either error.

    Returns
    -------
    q : ndarray of shape (n_joints,)
        Joint positions [rad or m].
    rotation : ndarray of shape (3, 3)
        Base-to-inertial rotation.
    rows : ndarray of shape (n_c,)
        The sample each component of the configuration ``[q, phi]`` was taken from.
    gain : ndarray of shape (n_c, n_x)
        The configuration's first-order error ``[dq, phi]`` (:class:`~spaceid.identified.GraspMotion`)
        as a map of the signal errors (:func:`_signal_covariance`) at its samples: a joint's
        ``dq_j + dqd_j dt_j``, the attitude's ``phi`` that of its small rotation and base rate.
    """
    from scipy.spatial.transform import Rotation
    info = log.meta.get("differentiation") or {}
    joints = info.get("joints") or {}
    if joints.get("window_s") is not None:  # one record, a window per joint (differentiate_log)
        spans = np.broadcast_to(np.asarray(joints["window_s"], float), len(log.joints)).tolist()
    else:  # a record per joint (the bag reader), or none
        spans = [max(window_spans(joints.get(name)), default=0.0) for name in log.joints]
    spans.append(max(window_spans(info.get("base")), default=0.0))
    at = [max(int(np.searchsorted(log.t, t - span / 2 + 1e-9, side="right")) - 1, 0) for span in spans]
    nj, k = len(log.joints), at[-1]
    j, dt = np.arange(nj), t - log.t[at]
    q = log.q[at[:-1], j] + log.qd[at[:-1], j] * dt[:-1]
    w = log.base_w[k]
    turn = Rotation.from_rotvec(w * dt[-1]).as_matrix()  # body rate: base axes

    def phi(z):  # the rotation's error in base axes at t from the base rate's (z[:3]) and the attitude's (z[3:])
        moved = Rotation.from_rotvec(z[3:]).as_matrix() @ Rotation.from_rotvec((w + z[:3]) * dt[-1]).as_matrix()
        return Rotation.from_matrix(turn.T @ moved).as_rotvec()

    axes = _attitude_axes(planar)
    gain = np.zeros((nj + len(axes), 2 * nj + 2 * len(axes)))
    gain[j, j], gain[j, nj + j] = 1.0, dt[:-1]
    gain[nj:, 2 * nj :] = _central_jacobian(phi, np.zeros(6))[np.ix_(axes, [*axes, *(a + 3 for a in axes)])]
    return q, quat_to_matrix(log.base_quat[k]) @ turn, np.r_[at[:-1], [k] * len(axes)], gain


def _before_grasp(pmap: PayloadMap, log: Log, hold, config, noise: Noise) -> tuple:
    """The servicer's mean momentum over the samples ``hold`` of ``log`` (None: none taken) and
    the covariance ``(3 + n_c, 3 + n_c)`` of its error and the configuration's (``config`` from
    :func:`_configuration_at`, or None: ``n_c = 0``). Both come from the samples before the grasp
    (the attitude's sample is near the hold's end, and their differentiator windows overlap), so
    one map of the signal errors carries both (:func:`_signal_covariance`)."""
    rows, gain = (np.zeros(0, int), np.zeros((0, _n_signals(pmap)))) if config is None else config[2:]
    samples = np.r_[[] if hold is None else hold, rows].astype(int)
    first = samples.min()
    gains = np.zeros((samples.max() - first + 1, 3 + len(rows), _n_signals(pmap)))
    h = None
    if hold is not None:
        h, gains[hold - first, :3] = _hold_gain(pmap, log.select(hold))
    gains[rows - first, 3 + np.arange(len(rows))] = gain
    return h, _signal_covariance(pmap, log.select(np.arange(first, first + len(gains))), gains, noise)


def _hold(log: Log, grasp: float, margin: float, where: str) -> np.ndarray:
    """The samples (indices) of the hold before the grasp whose rates the grasp does not reach: at
    least ``HOLD_SAMPLES`` (a differentiator window about as long as the hold: its middle samples)."""
    hold = np.flatnonzero((log.t > grasp - HOLD + margin) & (log.t < grasp - margin))
    if hold.size < HOLD_SAMPLES:
        hold = np.sort(np.argsort(np.abs(log.t - (grasp - HOLD / 2)))[:HOLD_SAMPLES])
    if log.t[hold[0]] < grasp - HOLD - 1e-9 or log.t[0] > grasp - HOLD:
        raise SpaceidError(f"`momentum` 'hold': {where} does not hold {HOLD:g} s before the grasp at {grasp:g} s: "
                           "give the momentum after the grasp, or leave it unknown")
    return hold
