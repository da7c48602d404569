"""The sensors of the Cepheus twin: joint encoders with ``/joint_states``, and motion capture.

At every control tick the encoders are read (positions quantised to ``2 pi / counts_per_rev``,
rounded to the nearest count, zero at the joint zero: the joints are homed) and the hardware
interface forms joint velocities as the finite difference of two successive encoder readings
(what a typical ros_control ``RobotHW`` reports); the controllers use these readings.
``/joint_states`` is published at ``Encoders.rate`` (50 Hz) from the tick at or after each
multiple of its period; its stamp is the tick time, its velocity the hardware finite difference
(or None, see ``Encoders.velocity``), its effort the applied effort. Motion capture samples the
true base pose at multiples of ``1 / MotionCapture.rate``, adds Gaussian noise, drops frames with
probability ``drop_probability`` and stamps each frame ``latency`` seconds *after* its capture
(the driver stamps on arrival): the pose stamped ``t`` was true at ``t - latency``. Poses carry
``(x, y, 0)`` and the quaternion of the yaw, wrapped so that ``w >= 0``. Only the motion capture
is random; it draws from ``numpy.random.default_rng(seed)`` (noise and drops from independent
child streams). Both streams are stamped on absolute time grids in ``[t0, t_end)`` of a phase,
so consecutive phases continue the same grids.
"""

from __future__ import annotations

import math

import numpy as np

from .._errors import SpaceidError
from ..data import JointStates, Poses, quat_multiply, yaw_to_quat
from ..motion import hermite_motion
from ._settings import Encoders, MotionCapture

__all__: list = []


# ------------------------------------------------------------------ encoders ------------------


def _encoder_resolution(encoders: Encoders, joints) -> np.ndarray:
    """Count size per joint (n,) [rad]: ``2 pi / counts_per_rev``, 0 where the reading is exact."""
    counts = encoders.counts_per_rev
    return np.array([2 * math.pi / counts[j] if counts.get(j) else 0.0 for j in joints])


def _check_publish_rate(encoders: Encoders, control_rate):
    """``/joint_states`` cannot be published faster than the hardware loop (``control_rate`` [Hz])."""
    if encoders.rate > control_rate * (1 + 1e-12):
        raise SpaceidError(
            f"encoders.rate = {encoders.rate:g} Hz exceeds controllers.rate = {control_rate:g} Hz: "
            "joint states cannot be published faster than the hardware loop; lower encoders.rate"
        )


def _quantise(q, resolution):
    """Encoder readings: ``round(q / r) r`` where ``r > 0``; exact where ``r == 0`` (the same
    arithmetic as :func:`_encoder_reader`)."""
    r = np.where(resolution > 0, resolution, 1.0)
    return np.where(resolution > 0, np.round(q * (1.0 / r)) * r, q)


def _encoder_reader(resolution):
    """The encoder reading of one tick: a function ``q (list of n) [rad] -> readings (list of n)``,
    rounded to the nearest count."""
    res = resolution.tolist()
    inv_r = [1.0 / r if r > 0 else 0.0 for r in res]
    joints_idx = range(len(res))

    def read(q):
        return [round(q[j] * inv_r[j]) * res[j] if inv_r[j] else q[j] for j in joints_idx]

    return read


def _hardware_rates(readings, previous, dt) -> np.ndarray:
    """Joint rates (n_t, n) [rad/s] as the hardware interface forms them: the difference of
    successive ``readings`` (n_t, n) over ``dt`` [s], ``previous`` (n,) the reading before the first."""
    return (readings - np.vstack([previous, readings[:-1]])) * (1.0 / dt)


def _publish_joint_states(encoders: Encoders, joints, times, dt, readings, rates, efforts) -> JointStates:
    """``/joint_states`` of a phase from the per-tick ``readings``, ``rates`` and ``efforts`` (n_t, n).

    Tick k publishes when a multiple of the publish period falls in ``(t_k - dt, t_k]`` (absolute
    time, so phases continue the grid); the message is stamped with the tick time.
    """
    count = np.floor(np.r_[times[0] - dt, times[:-1]] * encoders.rate + 1e-6)
    ticks = np.flatnonzero(np.diff(count) > 0)
    return JointStates(
        t=times[ticks],
        names=tuple(joints),
        position=readings[ticks],
        velocity=rates[ticks] if encoders.velocity == "difference" else None,
        effort=efforts[ticks],
    )


# ------------------------------------------------------------------ motion capture ------------


def _grid(t0, t_end, period):
    """Multiples of ``period`` in ``[t0, t_end)`` (tolerant to round-off at the ends)."""
    eps = 1e-9 * period
    first = math.ceil((t0 - eps) / period)
    last = math.ceil((t_end - eps) / period) - 1
    return np.arange(first, last + 1) * period


def _base_path(times, Q, V, jump):
    """The base pose ``[x, y, yaw]`` between the ticks, ``f(t) -> (n, 3)``: the cubic Hermite of
    ``Q`` and ``V``, in two pieces at a grasp ``jump = (k, v_after)`` (the rates jump there)."""
    if jump is None:
        return lambda t: hermite_motion(times, Q[:, :3], V[:, :3])(t)[0]
    k, v_after = jump
    before = hermite_motion(times[: k + 1], Q[: k + 1, :3], V[: k + 1, :3]) if k else None
    after = hermite_motion(times[k:], Q[k:, :3], np.vstack([v_after[:3], V[k + 1 :, :3]]))

    def pose(t):
        late = t >= times[k]
        out = np.empty((len(t), 3))
        out[late] = after(t[late])[0]
        if before is not None:
            out[~late] = before(t[~late])[0]
        return out

    return pose


def _capture_poses(mocap: MotionCapture, times, Q, V, seed, jump=None):
    """Motion-capture frames of a phase from the true base motion.

    Parameters
    ----------
    mocap : MotionCapture
    times : ndarray of shape (n_t,)
        Control ticks of the phase [s].
    Q, V : ndarray of shape (n_t, 3 + n)
        True ``q_pin`` and ``v_pin`` at the ticks (the pose between ticks is their cubic Hermite).
    seed : int
        Seed of the noise and the dropped frames.
    jump : tuple (k, v_after) or None
        A grasp at tick ``k``: ``V[k]`` holds the rates just before it, ``v_after`` (3 + n,)
        those just after, which start the next step.

    Returns
    -------
    poses : Poses
        The frames received, stamped on arrival.
    n_frames, n_dropped : int
        Frames captured and lost.
    """
    capture = _grid(times[0], times[-1], 1.0 / mocap.rate)
    pose = _base_path(times, Q, V, jump)(capture)
    noise_rng, drop_rng = (np.random.default_rng(s) for s in np.random.SeedSequence(seed).spawn(2))
    sigma = [mocap.position_noise, mocap.position_noise, mocap.attitude_noise]
    noise = noise_rng.standard_normal((len(capture), 3)) * sigma
    keep = drop_rng.random(len(capture)) >= mocap.drop_probability
    measured = (pose + noise)[keep]
    quat = yaw_to_quat(measured[:, 2])
    quat[quat[:, 0] < 0] *= -1  # a yaw in (-pi, pi], as a motion-capture system reports it
    poses = Poses(
        t=capture[keep] + mocap.latency,
        position=np.column_stack([measured[:, :2], np.zeros(len(measured))]),
        quat=quat,
        frame=mocap.frame,
    )
    return poses, len(capture), int((~keep).sum())


# ------------------------------------------------------------------ the servicer's sensors ----


def _rotation_quats(v) -> np.ndarray:
    """Quaternions ``[w, x, y, z]`` (n, 4) of the rotations ``exp([v]x)``, ``v`` (n, 3) [rad]."""
    angle = np.linalg.norm(v, axis=1, keepdims=True)
    return np.hstack([np.cos(angle / 2), np.sinc(angle / (2 * np.pi)) * v / 2])


def _every(times, rate, where) -> np.ndarray:
    """Indices of the ticks ``times`` (a uniform grid) that fall on multiples of ``1 / rate``;
    the tick period must divide the sensor's, or a SpaceidError naming ``where``."""
    dt = times[1] - times[0]
    ratio = 1.0 / (rate * dt)
    if abs(ratio - round(ratio)) > 1e-9 * ratio or round(ratio) < 1:
        raise SpaceidError(f"{where} = {rate:g} Hz must divide the control rate ({1 / dt:g} Hz): choose a rate "
                           "that does")  # fmt: skip
    stride = int(round(ratio))
    first = int(np.argmax(np.abs(np.round(times / (stride * dt)) * stride * dt - times) < 1e-6 * dt))
    return np.arange(first, len(times), stride)


def _star_tracker_frames(tracker, times, quat, seed) -> tuple:
    """Star-tracker frames of a phase: ``(poses, n_frames, n_dropped)``.

    ``times`` (n_t,) are the control ticks [s], ``quat`` (n_t, 4) the true base attitude there
    (``[w, x, y, z]``); frames are captured on the ticks at multiples of ``1 / tracker.rate`` in
    ``[t0, t_end)``, turned by the noise rotation, thinned by the drops and stamped on arrival.
    The base position is not measured: the poses carry zeros. ``seed`` seeds the noise and the
    drops (independent child streams)."""
    ticks = _every(times, tracker.rate, "star_tracker.rate")
    ticks = ticks[times[ticks] < times[-1] - 1e-9 * (times[1] - times[0])]
    noise_rng, drop_rng = (np.random.default_rng(s) for s in np.random.SeedSequence(seed).spawn(2))
    turned = quat_multiply(quat[ticks], _rotation_quats(tracker.noise * noise_rng.standard_normal((len(ticks), 3))))
    keep = drop_rng.random(len(ticks)) >= tracker.drop_probability
    poses = Poses(t=times[ticks][keep] + tracker.latency, position=np.zeros((int(keep.sum()), 3)),
                  quat=turned[keep], frame="inertial")  # fmt: skip
    return poses, len(ticks), int((~keep).sum())


def _gyro_samples(gyro, times, w, seed, walk0=None) -> tuple:
    """Gyro samples ``(w_measured (n, 3), walk (n, 3))`` [rad/s] at the ticks ``times`` (n,) [s]
    from the true rates ``w`` (n, 3) (base axes): bias, random walk started at ``walk0`` (3,)
    (default zero), white noise; ``seed`` seeds the walk and the noise."""
    walk_rng, noise_rng = (np.random.default_rng(s) for s in np.random.SeedSequence(seed).spawn(2))
    steps = np.sqrt(np.diff(times, prepend=times[0]))[:, None] * walk_rng.standard_normal((len(times), 3))
    walk = (np.zeros(3) if walk0 is None else np.asarray(walk0, float)) + gyro.walk * np.cumsum(steps, axis=0)
    return w + np.asarray(gyro.bias) + walk + gyro.noise * noise_rng.standard_normal((len(times), 3)), walk
