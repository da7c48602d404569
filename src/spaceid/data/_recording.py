"""Raw sensor streams as a lab records them, before alignment: the contract between the
digital twin (:mod:`spaceid.twin`), ROS bags (:mod:`spaceid.data`) and identification.

A recording holds what ROS topics carry: joint states (encoders, the reaction wheel among them)
and the motion-capture pose of the base, each stream on its own clock. Turning it into a
:class:`~spaceid.data.Log` (common time base, rates) is :func:`spaceid.data.to_log`'s job.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

__all__ = ["JointStates", "Poses", "Recording"]


@dataclass(frozen=True)
class JointStates:
    """``sensor_msgs/JointState`` messages of one topic.

    Attributes
    ----------
    t : ndarray of shape (n,)
        Header stamps [s].
    names : tuple of str
        Joint names, the column order.
    position : ndarray of shape (n, n_joints)
        [rad or m]. NaN where a joint is absent from every message at that stamp (arm and
        wheel published separately on one topic).
    velocity : ndarray of shape (n, n_joints) or None
        [rad/s or m/s]; None when the messages carry no velocities, NaN where not measured.
    effort : ndarray of shape (n, n_joints) or None
        [N m or N].
    """

    t: np.ndarray
    names: tuple
    position: np.ndarray
    velocity: np.ndarray | None = None
    effort: np.ndarray | None = None


@dataclass(frozen=True)
class Poses:
    """Base attitude messages of one topic: ``geometry_msgs/PoseStamped`` (motion capture), ``nav_msgs/Odometry`` or
    ``sensor_msgs/Imu`` (a spacecraft's attitude and gyro).

    Attributes
    ----------
    t : ndarray of shape (m,)
        Header stamps [s].
    position : ndarray of shape (m, 3)
        [m], in ``frame``.
    quat : ndarray of shape (m, 4)
        Scalar-first quaternion ``[w, x, y, z]``, base to ``frame``, as published (not
        renormalised).
    frame : str
        ``header.frame_id``.
    rate : ndarray of shape (m, 3) or None
        The base's measured angular velocity [rad/s] in its own axes, a gyro's (an Odometry's twist, an IMU's
        ``angular_velocity``), or None (PoseStamped: none measured).
    """

    t: np.ndarray
    position: np.ndarray
    quat: np.ndarray
    frame: str = "world"
    rate: np.ndarray | None = None


@dataclass(frozen=True)
class Recording:
    """One run: joint states and base poses, with provenance in ``meta`` (seeds, settings)."""

    joints: JointStates
    base: Poses
    meta: dict = field(default_factory=dict, compare=False)
