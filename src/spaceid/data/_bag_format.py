"""ROS bags: recordings as a lab makes them, written and read with ``rosbags`` (no ROS install).

A run is recorded on two topics with standard messages:

- ``sensor_msgs/JointState`` on ``/joint_states`` (:data:`DEFAULT_JOINT_TOPIC`): joint names,
  positions [rad or m], velocities [rad/s or m/s] and efforts [N m or N], header stamps.
  ``joint_state_controller`` publishes every joint in one message, but a bag may also hold
  several publishers on the topic (arm and wheel controllers) with subsets of the joints, in any
  order: :func:`~spaceid.data.read_recording` merges them by name.
- ``geometry_msgs/PoseStamped`` on ``/vrpn_client_node/cepheus/pose``
  (:data:`DEFAULT_POSE_TOPIC`, the topic ``vrpn_client_ros`` publishes for a rigid body named
  ``cepheus`` in an OptiTrack or Vicon system): the motion-capture pose of the base,
  ``header.frame_id`` the capture frame. ROS quaternions are ``(x, y, z, w)``; spaceid's are
  scalar first ``[w, x, y, z]``: the conversion happens in the bag writer and reader, nowhere else.

Formats (:data:`FORMATS`): ``"ros1"`` (a ``.bag`` file, ROS 1 serialisation), ``"ros2"`` (a
ROS 2 bag folder with ``metadata.yaml`` and sqlite3 storage) and ``"mcap"`` (a ROS 2 bag folder
with MCAP storage, or a single ``.mcap`` file when the path ends in ``.mcap``; rosbags reads such
a file on its own, with the message definitions it embeds). ROS 2 bags are written with metadata
version 8, the older of the two rosbags writes (9 changed the QoS serialisation); whether a given
ROS 2 distribution's ``ros2 bag`` accepts them was not tested here (rosbag2 keeps backward, not
forward, compatibility: Humble writes version 5; ``ros2 bag reindex`` rebuilds the metadata).

Time. Header stamps are integer nanoseconds. :class:`~spaceid.data.Recording` stamps are
float seconds after a time origin (``time_origin_ns``): 0 when writing unless given, and when
reading the whole second at or before the earliest stamp, so that wall-clock stamps (~1.7e9 s)
keep their nanoseconds in float64. Stamps that are whole nanoseconds read back bit for bit.

:func:`~spaceid.data.to_log` turns a recording into a :class:`~spaceid.data.Log` (common time
base, rates); :func:`~spaceid.data.read_bag_log` does both steps from a bag, with an optional
mapping file (:func:`~spaceid.data.read_mapping`) for topic and joint names.

Modules: this one holds what the others share (topics, message types, formats, nanosecond time,
rosbags' error classes, the check of a recording); ``_bag_write`` writes bags, ``_bag_read``
reads recordings and mapping files, ``_bag_to_log`` converts a recording to a log, and
``_bags`` is the entry point of the log readers (:func:`~spaceid.data.is_bag`,
:func:`~spaceid.data.read_bag_log`).
"""

from __future__ import annotations

import numpy as np

from .._constants import BAG_FORMATS as FORMATS
from .._constants import DEFAULT_JOINT_TOPIC, DEFAULT_POSE_TOPIC
from .._errors import SpaceidError
from ._tables import _QUAT_FAIL
from ._timeseries import first_unordered

__all__ = ["DEFAULT_JOINT_TOPIC", "DEFAULT_POSE_TOPIC", "FORMATS"]

# DEFAULT_JOINT_TOPIC, DEFAULT_POSE_TOPIC and FORMATS (the ``format`` values of write_bag: ROS 1
# ``.bag``, ROS 2 sqlite3 folder, ROS 2 MCAP) are defined in spaceid._constants

JOINT_STATE = "sensor_msgs/msg/JointState"
POSE_STAMPED = "geometry_msgs/msg/PoseStamped"
ODOMETRY = "nav_msgs/msg/Odometry"
IMU = "sensor_msgs/msg/Imu"
POSE_TYPES = (POSE_STAMPED, ODOMETRY, IMU)
"""The messages a base attitude topic may carry: a pose, an odometry (its pose and its twist's angular velocity, the
gyro's) or an IMU's (its orientation and angular velocity)."""
_BAG_SUFFIXES = (".bag", ".mcap", ".db3")
_NS = 1_000_000_000


def _rosbags_errors():
    """The exception classes of rosbags' readers, writers and serialisers."""
    from rosbags.highlevel import AnyReaderError
    from rosbags.rosbag1 import ReaderError as Reader1Error, WriterError as Writer1Error
    from rosbags.rosbag2 import ReaderError as Reader2Error, WriterError as Writer2Error
    from rosbags.serde import SerdeError

    return AnyReaderError, Reader1Error, Writer1Error, Reader2Error, Writer2Error, SerdeError


def _text(err, most=200):
    """An exception's message on one line, at most ``most`` characters (rosbags quotes whole
    message definitions)."""
    text = " ".join(str(err).split()) or type(err).__name__
    return text if len(text) <= most else text[: most - 3] + "..."


def _check_origin_ns(origin, label):
    """A SpaceidError unless the time origin ``origin`` is an integer number of nanoseconds."""
    if isinstance(origin, bool) or not isinstance(origin, (int, np.integer)):
        raise SpaceidError(f"{label}: time_origin_ns={origin!r}: expected an integer number of nanoseconds")


def _check_recording(recording, where, *, writing):
    """Shapes, names, finite poses and strictly increasing stamps of a recording."""
    js, base = recording.joints, recording.base
    label = f"{where}: recording"
    names = tuple(js.names)
    if not names or not all(isinstance(n, str) and n for n in names) or len(set(names)) != len(names):
        raise SpaceidError(f"{label}.joints.names: expected distinct non-empty joint names, got {names!r}")
    for field, t in (("joints.t", js.t), ("base.t", base.t)):
        t = np.asarray(t)
        if t.ndim != 1 or t.size < (1 if writing else 2) or not np.isfinite(t).all():
            raise SpaceidError(f"{label}.{field}: expected finite stamps [s] of shape (n,), n >= {1 if writing else 2}")
        unordered = first_unordered(t)
        if unordered:
            i = unordered[0]
            raise SpaceidError(
                f"{label}.{field}: stamp {i} ({t[i]!r} s) does not follow stamp {i - 1} ({t[i - 1]!r} s): "
                "stamps must increase strictly"
            )
    n, k = js.t.size, len(names)
    for field in ("position", "velocity", "effort"):
        value = getattr(js, field)
        if (value is not None or field == "position") and np.shape(value) != (n, k):
            raise SpaceidError(f"{label}.joints.{field}: expected shape ({n}, {k}), got {np.shape(value)}")
    m = base.t.size
    for field, width in (("position", 3), ("quat", 4), ("rate", 3)):
        if getattr(base, field, None) is None and field == "rate":  # no gyro
            continue
        value = np.asarray(getattr(base, field), dtype=float)
        if value.shape != (m, width):
            raise SpaceidError(f"{label}.base.{field}: expected shape ({m}, {width}), got {value.shape}")
        if not np.isfinite(value).all():
            i = int(np.argmax(~np.isfinite(value).all(axis=1)))
            raise SpaceidError(f"{label}.base.{field}: pose {i} is not finite: drop lost-tracking frames")
    norm = np.linalg.norm(np.asarray(base.quat, dtype=float), axis=1)
    if (np.abs(norm - 1) > _QUAT_FAIL).any():
        i = int(np.argmax(np.abs(norm - 1)))
        raise SpaceidError(
            f"{label}.base.quat: pose {i} has norm {norm[i]:.6g}, expected 1: give unit quaternions [w, x, y, z]"
        )
    if not isinstance(base.frame, str):
        raise SpaceidError(f"{label}.base.frame: expected a frame name (str), got {base.frame!r}")
