"""A recording's streams on one time base: the conversion from a bag's recording to a log.

:func:`to_log` removes the motion-capture latency, finds the span every stream covers, checks
each stream for gaps (counting dropped frames), chooses the time base (the joint stamps or a
uniform grid), differentiates and interpolates the base attitude (its rate as the slope) and
the joint angles, and checks the columns' units as the CSV reader does.
"""

from __future__ import annotations

import contextlib
import math

import numpy as np

from .._constants import BASE_RATES, JOINT_RATE_POLICY, JOINT_RATES
from .._errors import SpaceidError
from ._bag_format import _check_recording
from ._recording import Recording
from ._signals import _sign_continuous, differentiate, differentiate_quaternion
from .._memory import require_memory
from ._tables import _check_angles, _check_rates, _Table
from ._timeseries import Log, quat_to_yaw, yaw_to_quat

__all__ = ["JOINT_RATE_POLICY", "MAX_GAP", "MAX_TILT", "to_log"]

MAX_GAP = 0.1
"""Default longest time without a message that :func:`to_log` interpolates across [s]."""

MAX_TILT = 0.1
"""Default largest tilt of the base z axis from the capture frame's z in planar mode [rad]."""

# JOINT_RATES, the joint-rate sources, and JOINT_RATE_POLICY, the default (the encoder angles,
# differentiated), are defined in spaceid._constants


def to_log(
    recording: Recording,
    *,
    joints,
    planar,
    wheels=(),
    rate=None,
    pose_latency=0.0,
    max_gap=MAX_GAP,
    max_tilt=MAX_TILT,
    joint_rates=JOINT_RATE_POLICY,
    base_rate="attitude",
    method="auto",
    window=None,
    order=None,
    smoothing=None,
    quantum=None,
) -> Log:
    """A :class:`~spaceid.data.Log` from a recording: common time base and rates.

    1. The pose stamps are shifted back by ``pose_latency``; the time span common to the pose
       and every selected joint is the overlap.
    2. Time base: the joint-state stamps in the overlap at which every selected joint was
       measured, or, with ``rate``, a uniform grid from the start of the overlap.
    3. Dropped messages: each stream is checked for steps longer than ``max_gap`` inside the
       overlap (an error); shorter gaps are bridged, as the differentiators work on the
       actual, uneven stamps. Dropped frames (steps above 1.5 median steps) are counted.
    4. Base: the attitude is smoothed and differentiated on the pose stamps with
       :func:`~spaceid.data.differentiate_quaternion` (body rate, base axes), then
       interpolated to the time base: the attitude by cubic Hermite interpolation with the
       rate as slope (planar: of the unwrapped yaw; spatial: of the sign-continuous quaternion,
       slopes ``q (x) [0, w] / 2``, renormalised), the rate by a cubic spline. Both are
       O(h^4) in the pose step h: slerp and linear rates, O(h^2), erred by ~1e-5 rad/s on
       Cepheus-like motion at 100 Hz, against ~1e-9 for these. Planar mode keeps the yaw (a
       pure-yaw quaternion) and rejects tilts above ``max_tilt``. With ``base_rate="gyro"`` the
       rate is the one the pose messages measured (an Odometry's twist, an IMU's angular velocity:
       the gyro's, base axes), linearly interpolated (a spline would amplify its noise), and the
       attitude is interpolated with it as slope, unsmoothed.
    5. Joints: the positions are smoothed and differentiated with
       :func:`~spaceid.data.differentiate` on that joint's stamps (the default,
       :data:`JOINT_RATE_POLICY`), or the rates are the JointState velocities when every message
       of that joint carries one (``joint_rates="auto"``). Off the joint stamps
       (``rate`` given, or joints published separately) positions are cubic Hermite
       interpolated (rates as slopes) and rates by a cubic spline. Reaction-wheel angles are
       unwrapped (velocity-aided when velocities are measured, so that a wheel turning more
       than pi per sample, e.g. 170 rad/s at 50 Hz, is not aliased).

    Parameters
    ----------
    recording : Recording
        From :func:`read_recording` or a simulation; names are model joint names.
    joints : sequence of str
        Model joints, the column order of ``q`` and ``qd``.
    planar : bool
        Planar log (pure-yaw attitude, ``base_w = [0, 0, wz]``) or spatial.
    wheels : sequence of str
        Reaction-wheel joints (continuous, possibly wrapped to +-pi; exempt from the check for
        angles in degrees).
    rate : float, optional
        Uniform time base [Hz] instead of the joint stamps.
    pose_latency : float
        Delay [s] from the instant the base pose describes to its header stamp (a capture
        pipeline that stamps on arrival); subtracted from the pose stamps.
    max_gap : float
        Longest time [s] without a message that is interpolated across (default
        :data:`MAX_GAP`).
    max_tilt : float
        Planar mode: largest tilt [rad] of the base z axis from the capture frame's z.
    joint_rates : {"differentiate", "auto", "velocity"}
        Joint rates never from the messages' velocities ("differentiate", the default
        :data:`JOINT_RATE_POLICY`), when every sample has one ("auto"), or always ("velocity":
        an error if some are missing).
    base_rate : {"attitude", "gyro"}
        The base rate differentiated from the attitude (the default) or the one the pose messages
        measured (``recording.base.rate``: an error when they carry none, PoseStamped).
    method, window, order, smoothing
        Differentiator settings, as in :func:`spaceid.data.differentiate` (automatic by
        default), for the attitude and the differentiated joints.
    quantum : float, optional
        Encoder resolution [rad per count] of the differentiated joints.

    Returns
    -------
    Log
        ``t`` (n,) [s, after the recording's time origin]; ``q``, ``qd`` (n, n_joints);
        ``base_quat`` (n, 4); ``base_w`` (n, 3) [rad/s] in base axes; ``base_position`` (n, 3) [m]
        (the poses' positions, cubic spline); ``tau`` (n, n_joints) [N m or N] when every message
        of the selected joints carries efforts (linear interpolation), else None. ``meta``: the recording's
        meta plus ``time_base``, ``pose_latency``, ``streams`` (rates, dropped frames, largest
        gaps, pose frame and tilt), ``joint_rate_policy`` (the ``joint_rates`` given),
        ``joint_rates`` (per joint ``"velocity"`` or ``"differentiated"``), ``base_rate`` (as given),
        ``interpolation`` and ``differentiation`` (``base``, unless the rate was measured; ``joints``).

    Raises
    ------
    SpaceidError
        A model joint missing from the recording (the names present are listed); streams that
        do not overlap; a gap longer than ``max_gap``; a tilted base in planar mode; no stamp
        with every joint (give ``rate``); missing velocities with ``joint_rates="velocity"``;
        too few samples for the differentiator; angles apparently in degrees; bad options.
    """
    meta = dict(recording.meta)
    where = meta.get("source", "recording")
    jtopic, ptopic = meta.get("joint_topic", "joint states"), meta.get("pose_topic", "base poses")
    joints, wheels = tuple(joints), tuple(wheels)
    _check_options(where, rate, pose_latency, max_gap, max_tilt, joint_rates, base_rate)
    _check_recording(recording, where, writing=False)
    js, base = recording.joints, recording.base
    columns = _joint_columns(js.names, joints, where, jtopic)
    valid = np.isfinite(js.position[:, columns])
    t_pose = base.t - pose_latency  # the instants the poses describe

    start, end = _overlap(js.t, valid, t_pose, joints, where, jtopic, ptopic)
    streams = {"pose": _gaps(t_pose, start, end, max_gap, f"{where}: {ptopic}")}
    streams["pose"]["frame"] = base.frame
    t, time_base = _time_base(js.t, valid, start, end, rate, joints, where, jtopic)

    options = dict(method=method, window=window, order=order, smoothing=smoothing)
    measured = _measured_base_rate(base, base_rate, f"{where}: {ptopic}")
    base_quat, base_w, info_base, tilt = _base(t_pose, base.quat, t, planar, max_tilt, f"{where}: {ptopic}", options,
                                               measured)
    if planar:
        streams["pose"]["max_tilt_rad"] = tilt
    q, qd, sources, infos, streams["joints"] = _joints(
        js, columns, valid, t, (start, end), joints, wheels, max_gap=max_gap, joint_rates=joint_rates,
        options=options | {"quantum": quantum}, label=f"{where}: {jtopic}",
    )

    table, values, base_rates = _log_columns(where, joints, q, qd, base_quat, base_w, planar)
    # called here, not in a helper: the rate warnings' stacklevel names the caller of to_log
    _check_angles(table, values, ("base_yaw", *(f"q_{j}" for j in joints if j not in wheels)))
    _check_rates(table, values, base_rates, joints, wheels)
    meta.update(
        time_base=time_base,
        pose_latency=float(pose_latency),
        max_gap=float(max_gap),
        streams=streams,
        joint_rate_policy=joint_rates,
        joint_rates=sources,
        base_rate=base_rate,
        interpolation="cubic Hermite for angles and attitude (rates as slopes), cubic spline for rates; "
        "base on the pose stamps, joints on theirs (none when the time base is the joint stamps)",
        differentiation={**({} if measured is not None else {"base": info_base}), "joints": infos or None},
    )
    return Log(t=t, joints=joints, q=q, qd=qd, base_quat=base_quat, base_w=base_w, planar=bool(planar), meta=meta,
               **_position_and_efforts(js, columns, valid, t_pose, base.position, t, planar))


def _position_and_efforts(js, columns, valid, t_pose, position, t, planar) -> dict:
    """``base_position`` (n, 3) [m] at ``t``, a cubic spline through the poses (capture frame; planar:
    z zero), and ``tau`` (n, n_joints), the messages' efforts linearly interpolated on each joint's
    stamps (exact on them), or None when some message of a selected joint lacks one."""
    from scipy.interpolate import CubicSpline
    base_position = CubicSpline(t_pose, np.asarray(position, float), axis=0)(t)
    if planar:
        base_position[:, 2] = 0.0
    tau = None
    if js.effort is not None and np.isfinite(js.effort[:, columns][valid]).all():
        tau = np.column_stack([np.interp(t, js.t[valid[:, c]], js.effort[valid[:, c], col])
                               for c, col in enumerate(columns)]) if len(columns) else np.empty((t.size, 0))
    return {"base_position": base_position, "tau": tau}


def _joint_columns(names, joints, where, topic):
    """Columns of the model ``joints`` among the recording's joint ``names``, or a SpaceidError."""
    missing = [j for j in joints if j not in names]
    if missing:
        raise SpaceidError(
            f"{where}: model joint '{missing[0]}' is not on {topic} (joints there: {', '.join(names)}): "
            f"map the bag's name to it (mapping file 'joints: {{bag_name: {missing[0]}}}')"
        )
    return [names.index(j) for j in joints]


def _overlap(t_joints, valid, t_pose, joints, where, jtopic, ptopic):
    """(start, end) [s] of the time span common to the poses and every joint's samples.

    ``valid`` (n, n_joints) marks the joint-state rows that measure each joint.
    """
    spans = {f"{ptopic} (pose)": (t_pose[0], t_pose[-1])}
    for c, j in enumerate(joints):
        tj = t_joints[valid[:, c]]
        if tj.size < 2:
            raise SpaceidError(f"{where}: {jtopic}: joint '{j}' has {tj.size} message(s): at least 2 are needed")
        spans[f"{jtopic} {j}"] = (tj[0], tj[-1])
    start, end = max(s for s, _ in spans.values()), min(e for _, e in spans.values())
    if not start < end:
        listed = "; ".join(f"{k} {a:.6g} to {b:.6g} s" for k, (a, b) in spans.items())
        raise SpaceidError(
            f"{where}: the streams do not overlap in time ({listed}): check the clocks of the recording computers "
            "and pose_latency (mapping file key 'pose_latency')"
        )
    return start, end


def _time_base(t_joints, valid, start, end, rate, joints, where, topic):
    """The log's stamps (n,) [s] within [start, end] and their ``meta["time_base"]`` record: the
    joint stamps that measure every joint, or with ``rate`` [Hz] a uniform grid from ``start``."""
    if rate is None:
        rows = valid.all(axis=1) & (t_joints >= start) & (t_joints <= end)
        if rows.sum() < 2:
            raise SpaceidError(
                f"{where}: {topic}: fewer than 2 stamps carry all of {', '.join(joints)} within the overlap "
                "(publishers stamp them separately): give a rate (mapping file key 'rate') to resample on a "
                "uniform time base"
            )
        t = t_joints[rows]
        time_base = {"kind": "joint stamps", "topic": topic}
    else:
        n = math.floor((end - start) * rate + 1e-9) + 1
        # a few float columns a joint and the attitude's, and the interpolants' work arrays
        require_memory(n * 8.0 * 8 * (2 * len(joints) + 16), f"{where}: mapping key 'rate' {rate:g} Hz over "
                       f"{end - start:.6g} s: {n:.3g} samples", "give the rate of the log to write, in Hz (e.g. 100)")
        t = np.minimum(start + np.arange(n) / rate, end)
        time_base = {"kind": "uniform", "rate_hz": float(rate)}
    time_base.update(start=float(t[0]), end=float(t[-1]), n_samples=int(t.size))
    return t, time_base


def _measured_base_rate(base, base_rate, label):
    """The measured base rate ``(m, 3)`` [rad/s] of the poses ``base`` when ``base_rate`` is ``"gyro"``, else None."""
    if base_rate != "gyro":
        return None
    if base.rate is None:
        raise SpaceidError(f"{label}: `base_rate` gyro: the pose messages carry no angular velocity "
                           "(geometry_msgs/PoseStamped): publish nav_msgs/Odometry or sensor_msgs/Imu there, or take "
                           "the base rate from the attitude (`base_rate` attitude)")
    return np.asarray(base.rate, float)


def _base(t_pose, quat, t, planar, max_tilt, label, options, measured=None):
    """Base attitude (n, 4) and body rate (n, 3) [rad/s] at ``t``, the differentiator record (None when
    ``measured``), and the largest tilt [rad] (planar; else None), from the poses' quaternions (m, 4) at ``t_pose``
    and their ``measured`` rates (m, 3) if given.

    The attitude is differentiated on the pose stamps, then interpolated by cubic Hermite with the
    rate as slope (planar: the unwrapped yaw), the rate by a cubic spline; or, ``measured``, the attitude as
    published interpolated with the measured rate as slope, the rate linearly.
    """
    from scipy.interpolate import CubicHermiteSpline, CubicSpline
    quat = quat / np.linalg.norm(quat, axis=1, keepdims=True)
    tilt = None
    if planar:
        quat, tilt = _pure_yaw(t_pose, quat, max_tilt, label)
    if measured is None:
        with _prefix(label):
            smooth, w_body, info = differentiate_quaternion(t_pose, quat, **options)
        w = CubicSpline(t_pose, w_body, axis=0)(t)
    else:
        (smooth, _), w_body, info = _sign_continuous(quat), measured, None
        w = np.column_stack([np.interp(t, t_pose, w_body[:, k]) for k in range(3)])
    if planar:
        w[:, :2] = 0.0
        yaw = CubicHermiteSpline(t_pose, np.unwrap(quat_to_yaw(smooth)), w_body[:, 2])(t)
        return yaw_to_quat(yaw), w, info, tilt
    return _hermite_attitude(t_pose, smooth, w_body, t), w, info, tilt


def _pure_yaw(t_pose, quat, max_tilt, label):
    """Pure-yaw quaternions (m, 4) of unit ``quat`` and their largest tilt [rad] of the base z axis
    from the frame's z; a SpaceidError beyond ``max_tilt``."""
    cos_tilt = 1 - 2 * (quat[:, 1] ** 2 + quat[:, 2] ** 2)  # base z axis against the frame's z
    tilts = np.arccos(np.clip(cos_tilt, -1.0, 1.0))
    tilt = float(tilts.max())
    if tilt > max_tilt:
        k = int(np.argmax(tilts))
        raise SpaceidError(
            f"{label}: the base tilts {tilt:.3g} rad from the frame's z axis (first worst at "
            f"t = {t_pose[k]:.6g} s), beyond max_tilt = {max_tilt:g} rad for a planar model: check the "
            "capture frame is z-up and the rigid body's axes, raise max_tilt (mapping file), or use a spatial model"
        )
    return yaw_to_quat(quat_to_yaw(quat)), tilt


def _hermite_attitude(t_pose, quat, w_body, t):
    """Unit quaternions (n, 4) at ``t``: the cubic Hermite interpolant of sign-continuous ``quat``
    (m, 4) whose slopes are the kinematics ``qdot = q (x) [0, w] / 2`` of the body rates (m, 3)."""
    from scipy.interpolate import CubicHermiteSpline
    s, v = quat[:, :1], quat[:, 1:]
    slope = 0.5 * np.column_stack([-np.einsum("ij,ij->i", v, w_body), s * w_body + np.cross(v, w_body)])
    out = CubicHermiteSpline(t_pose, quat, slope, axis=0)(t)
    return out / np.linalg.norm(out, axis=1, keepdims=True)


def _joints(js, columns, valid, t, span, joints, wheels, *, max_gap, joint_rates, options, label):
    """Joint angles and rates (n, n_joints) at ``t``, with per joint the rate source, the
    differentiator record (differentiated joints only) and the stream statistics of :func:`_gaps`.

    ``columns`` are the joints' columns in the joint states ``js``, ``valid`` (n_rows, n_joints)
    the rows that measure each; ``span`` the overlap (start, end) [s]; ``options`` the
    :func:`~spaceid.data.differentiate` keywords.
    """
    q, qd = np.empty((t.size, len(joints))), np.empty((t.size, len(joints)))
    sources, infos, streams = {}, {}, {}
    for c, j in enumerate(joints):
        rows = valid[:, c]
        tj, qj = js.t[rows], js.position[rows, columns[c]]
        vj = None if js.velocity is None else js.velocity[rows, columns[c]]
        streams[j] = _gaps(tj, *span, max_gap, f"{label}: joint '{j}'")
        qj, vj, sources[j], info = _joint_rate(tj, qj, vj, j, j in wheels, joint_rates, options, label)
        if info is not None:
            infos[j] = info
        q[:, c], qd[:, c] = _on_time_base(tj, qj, vj, t)
    return q, qd, sources, infos, streams


def _joint_rate(t, angle, rate, joint, wheel, joint_rates, options, label):
    """One joint's angles (m,) and rates (m,) on its own stamps ``t``, the source of the rates
    (``"velocity"`` or ``"differentiated"``) and the differentiator record (None when measured).

    ``rate`` is the messages' velocity (None or NaN where not measured). A wheel's angles are
    unwrapped: by the measured rate when there is one (no aliasing), else by the differentiator.
    """
    has_rate = rate is not None and np.isfinite(rate).all()
    measured = joint_rates != "differentiate" and has_rate
    if joint_rates == "velocity" and not measured:
        raise SpaceidError(
            f"{label}: joint '{joint}' lacks a velocity in some messages: use joint_rates='auto' "
            "to differentiate its positions"
        )
    if wheel and has_rate:  # a fast wheel turns more than pi a message: unwrap by its rate
        angle = _unwrap_with_rate(t, angle, rate)
    if measured:
        return angle, rate, "velocity", None
    # without a rate, unwrap only angles that are wrapped (within +-pi) at all
    wrap = wheel and not has_rate and np.abs(angle).max() <= np.pi + 1e-9
    with _prefix(label):
        angle, rate, info = differentiate(t, angle, wrap=wrap, name=f"q_{joint}", **options)
    return angle, rate, "differentiated", info


def _on_time_base(t_samples, angle, rate, t):
    """Angles and rates (m,) at their stamps ``t_samples`` taken at ``t`` (n,): picked when every
    stamp of ``t`` is a sample's, else cubic Hermite (rates as slopes) and a cubic spline."""
    from scipy.interpolate import CubicHermiteSpline, CubicSpline
    at = np.searchsorted(t_samples, t).clip(max=t_samples.size - 1)
    if (t_samples[at] == t).all():
        return angle[at], rate[at]
    return CubicHermiteSpline(t_samples, angle, rate)(t), CubicSpline(t_samples, rate)(t)


def _log_columns(where, joints, q, qd, base_quat, base_w, planar):
    """The log's angle and rate columns by CSV name, for the unit checks shared with the CSV
    reader: an empty table naming the source, the columns, and the base-rate column names."""
    table = _Table(f"{where}", [], np.empty((0, 0)), np.empty(0, dtype=int), {})
    values = {f"q_{j}": q[:, c] for c, j in enumerate(joints)} | {f"qd_{j}": qd[:, c] for c, j in enumerate(joints)}
    base_rates = ("base_wz",) if planar else ("base_wx", "base_wy", "base_wz")
    values |= {name: base_w[:, "xyz".index(name[-1])] for name in base_rates}
    if planar:
        values["base_yaw"] = np.unwrap(quat_to_yaw(base_quat))
    return table, values, base_rates


def _unwrap_with_rate(t, angle, rate):
    """Angles made continuous using the measured rate to predict each step (aliasing-free)."""
    step = np.diff(angle) - 0.5 * (rate[1:] + rate[:-1]) * np.diff(t)
    turns = np.rint(step / (2 * np.pi))
    if not turns.any():
        return angle
    return angle - 2 * np.pi * np.r_[0.0, np.cumsum(turns)]


def _gaps(t, start, end, max_gap, label):
    """Message-rate statistics of a stream within [start, end]; an error for a gap > max_gap."""
    steps = np.diff(t)
    median = float(np.median(steps))
    inside = (t[1:] > start) & (t[:-1] < end)
    long = np.flatnonzero(inside & (steps > max_gap))
    if long.size:
        i = long[0]
        raise SpaceidError(
            f"{label}: no message for {steps[i]:.3g} s between t = {t[i]:.6g} and {t[i + 1]:.6g} s "
            f"(~{int(round(steps[i] / median)) - 1} dropped), longer than max_gap = {max_gap:g} s: "
            "raise max_gap (mapping file key 'max_gap') if the motion is slow there, or cut the record"
        )
    dropped = (steps > 1.5 * median) & inside
    return {
        "messages": int(t.size),
        "rate_hz": 1.0 / median,
        "dropped": int(np.maximum(np.rint(steps[dropped] / median) - 1, 0).sum()),
        "largest_step_s": float(steps[inside].max()),
    }


@contextlib.contextmanager
def _prefix(text):
    """Re-raise SpaceidErrors from the block with ``text: `` in front (naming file and topic)."""
    try:
        yield
    except SpaceidError as err:
        raise SpaceidError(f"{text}: {err}") from None


def _check_options(where, rate, pose_latency, max_gap, max_tilt, joint_rates, base_rate):
    def number(value):
        real = isinstance(value, (int, float, np.integer, np.floating)) and not isinstance(value, bool)
        return real and math.isfinite(value)

    if rate is not None and not (number(rate) and rate > 0):
        raise SpaceidError(f"{where}: rate={rate!r}: expected a sample rate [Hz] > 0")
    if not number(pose_latency):
        raise SpaceidError(f"{where}: pose_latency={pose_latency!r}: expected a finite latency [s]")
    if not (number(max_gap) and max_gap > 0):
        raise SpaceidError(f"{where}: max_gap={max_gap!r}: expected a time [s] > 0")
    if not (number(max_tilt) and max_tilt > 0):
        raise SpaceidError(f"{where}: max_tilt={max_tilt!r}: expected an angle [rad] > 0")
    if joint_rates not in JOINT_RATES:
        raise SpaceidError(f"{where}: joint_rates={joint_rates!r}: choose one of {', '.join(JOINT_RATES)}")
    if base_rate not in BASE_RATES:
        raise SpaceidError(f"{where}: base_rate={base_rate!r}: choose one of {', '.join(BASE_RATES)}")
