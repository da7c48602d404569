"""Reading ROS bags into recordings, and the mapping file of topics and joint names.

:func:`read_recording` reads the ``sensor_msgs/JointState`` and ``geometry_msgs/PoseStamped``
messages of a bag (the layout is in :mod:`spaceid.data._bag_format`) and merges the joint
messages of several publishers by name; :func:`read_mapping` reads the YAML file that names a
bag's topics and joints and sets the alignment options of :func:`~spaceid.data.to_log`.
"""

from __future__ import annotations

import contextlib
import difflib
import math
import struct
from pathlib import Path
from types import SimpleNamespace
from typing import NamedTuple

import numpy as np

from .._constants import BASE_RATES
from .._errors import SpaceidError, shown
from .._yaml import parse_yaml
from ._bag_format import (
    _BAG_SUFFIXES, _NS, DEFAULT_JOINT_TOPIC, DEFAULT_POSE_TOPIC, JOINT_STATE, POSE_TYPES, _check_origin_ns,
    _rosbags_errors, _text,
)
from ._recording import JointStates, Poses, Recording
from ._tables import _QUAT_FAIL, _read_text
from ._timeseries import first_unordered

__all__ = ["read_recording", "read_mapping"]

MAPPING_KEYS = {
    "joint_topic": "a topic name",
    "pose_topic": "a topic name",
    "joints": "a mapping {name in the bag: model joint name}",
    "rate": "a sample rate [Hz] > 0",
    "pose_latency": "a latency [s]",
    "max_gap": "a time [s] > 0",
    "max_tilt": "an angle [rad] > 0",
    "base_rate": "attitude or gyro",
}
_SUFFIX_HINT = "give a .bag file (ROS 1), a ROS 2 bag folder (with metadata.yaml) or a .mcap file"


def read_recording(
    path, *, joint_topic=DEFAULT_JOINT_TOPIC, pose_topic=DEFAULT_POSE_TOPIC, rename=None, time_origin_ns=None
) -> Recording:
    """Read the joint states and base poses of a ROS 1 bag, ROS 2 bag folder or MCAP file.

    Joint messages are merged by joint name: each message may carry any subset of the joints,
    in any order, and several publishers may share the topic. The rows of the result are the
    distinct header stamps; a joint that no message carries at a stamp is NaN there (the
    joints of one ``joint_state_controller`` share every stamp, so there are no NaN). A NaN
    velocity or effort in a message means "not measured" (some drivers publish it so).

    Parameters
    ----------
    path : str or Path
        ``.bag`` (ROS 1), a ROS 2 bag folder with ``metadata.yaml`` (sqlite3 or MCAP storage),
        or a ``.mcap`` / ``.db3`` file. It is only read.
    joint_topic, pose_topic : str
        Topics of the ``sensor_msgs/JointState`` and the base attitude's ``geometry_msgs/PoseStamped``,
        ``nav_msgs/Odometry`` or ``sensor_msgs/Imu`` messages.
    rename : mapping of str to str, optional
        Joint names in the bag to model joint names, e.g. ``{"shoulder": "left_shoulder"}``;
        joints not listed keep their names.
    time_origin_ns : int, optional
        Stamps are returned in seconds after this time [ns since the epoch]. Default: the
        whole second at or before the earliest stamp of the two topics.

    Returns
    -------
    Recording
        ``joints``: ``t`` (n,) [s], ``names`` (renamed), ``position`` (n, n_joints),
        ``velocity`` and ``effort`` (n, n_joints) or None when no message carries them.
        ``base``: ``t`` (m,) [s], ``position`` (m, 3) [m], ``quat`` (m, 4) ``[w, x, y, z]`` as
        published (not renormalised), ``frame``, ``rate`` (m, 3) [rad/s] the Odometry's or Imu's angular
        velocity (None for PoseStamped). ``meta``: ``source``, ``format``, topics,
        ``rename``, ``time_origin_ns``, message and publisher counts.

    Raises
    ------
    SpaceidError
        A missing or unreadable bag; a missing or empty topic (the topics present are listed);
        a topic with another message type; a message whose arrays do not match its names; NaN
        positions or poses; header stamps that repeat or go back (per joint, per topic); a
        changing pose ``frame_id``; a quaternion far from unit norm; a ``rename`` key that is
        not in the bag or two names renamed to one.
    """
    path = Path(path)
    joint_msgs, pose_msgs, joint_publishers = _read_messages(path, joint_topic, pose_topic)
    return _recording(path, joint_msgs, pose_msgs, joint_publishers, joint_topic, pose_topic, rename, time_origin_ns)


def _recording(path, joint_msgs, pose_msgs, joint_publishers, joint_topic, pose_topic, rename, time_origin_ns):
    """The :class:`Recording` of a bag's deserialised JointState and base attitude messages (all of
    them, or a block of a bag read in parts), as :func:`read_recording` returns it."""
    where = str(path)
    kind = "ros1" if path.suffix.lower() == ".bag" else _ros2_format(path)
    joint_ns, names, position, velocity, effort = _merge_joint_states(joint_msgs, f"{where}: {joint_topic}")
    pose_ns, pose_position, quat, frame, rate = _poses(pose_msgs, f"{where}: {pose_topic}")
    if time_origin_ns is None:
        time_origin_ns = int(min(joint_ns[0], pose_ns[0]) // _NS * _NS)
    else:
        _check_origin_ns(time_origin_ns, where)
    names = _rename(names, rename, f"{where}: {joint_topic}")
    meta = {
        "source": where,
        "format": kind,
        "joint_topic": joint_topic,
        "pose_topic": pose_topic,
        "rename": dict(rename or {}),
        "time_origin_ns": int(time_origin_ns),
        "joint_messages": len(joint_msgs),
        "joint_publishers": joint_publishers,
        "pose_messages": len(pose_msgs),
    }
    origin = np.int64(time_origin_ns)
    return Recording(
        joints=JointStates(t=(joint_ns - origin) / 1e9, names=names, position=position, velocity=velocity,
                           effort=effort),
        base=Poses(t=(pose_ns - origin) / 1e9, position=pose_position, quat=quat, frame=frame, rate=rate),
        meta=meta,
    )


def _read_messages(path, joint_topic, pose_topic):
    """The deserialised JointState and base attitude messages of a bag, in bag order, and the
    number of publishers (connections) of the joint topic."""
    joint_msgs, pose_msgs = [], []
    with _bag_messages(path, joint_topic, pose_topic) as (messages, publishers):
        for topic, msg in messages:
            (joint_msgs if topic == joint_topic else pose_msgs).append(msg)
    return joint_msgs, pose_msgs, publishers


@contextlib.contextmanager
def _bag_messages(path, joint_topic, pose_topic):
    """``(messages, publishers)``: an iterator over the ``(topic, message)`` pairs of the joint
    and pose topics, deserialised one at a time in bag order, and the number of publishers of the
    joint topic."""
    where = str(path)
    with _open_bag(path) as reader:
        connections = {
            topic: _topic_connections(reader, where, topic, msgtype, option)
            for topic, msgtype, option in (
                (joint_topic, JOINT_STATE, "`joint_topic`"),
                (pose_topic, POSE_TYPES, "`pose_topic`"),
            )
        }

        def messages():
            try:
                for connection, _, raw in reader.messages(connections=[c for cs in connections.values() for c in cs]):
                    yield connection.topic, reader.deserialize(raw, connection.msgtype)
            except _damaged() as err:
                raise SpaceidError(
                    f"{where}: cannot read the messages ({_text(err)}): the bag is damaged; re-record or repair it"
                ) from None

        yield messages(), len(connections[joint_topic])


def _ros2_format(path):
    """``"ros2-sqlite3"``, ``"ros2-mcap"`` or ``"mcap"`` (single file) for a ROS 2 bag path."""
    if path.is_dir():
        try:
            info = _ros2_metadata(path)
            return f"ros2-{info['rosbag2_bagfile_information']['storage_identifier']}"
        except (SpaceidError, KeyError, TypeError):
            return "ros2"
    return "mcap" if path.suffix.lower() == ".mcap" else "ros2-sqlite3"


def _ros2_metadata(path):
    """The parsed ``metadata.yaml`` of a ROS 2 bag folder, read as model files are (bounded, no
    aliases), before rosbags reads it: a hostile metadata file is refused, not expanded."""
    where = path / "metadata.yaml"
    return parse_yaml(_read_text(where, "ROS 2 bag metadata file"), str(where), "fix or rebuild it (ros2 bag reindex)")


@contextlib.contextmanager
def _open_bag(path):
    """An open ``rosbags`` AnyReader on ``path``, with its failures as one-line SpaceidErrors."""
    from rosbags.highlevel import AnyReader, AnyReaderError

    if not path.exists():
        raise SpaceidError(f"{path}: no such file or folder (expected a ROS bag): check the path")
    if path.is_dir() and not (path / "metadata.yaml").is_file():
        raise SpaceidError(f"{path}: a folder without metadata.yaml is not a ROS 2 bag: {_SUFFIX_HINT}")
    if not path.is_dir() and path.suffix.lower() not in _BAG_SUFFIXES:
        raise SpaceidError(f"{path}: not a bag name: {_SUFFIX_HINT}")
    if path.is_dir() and not isinstance(_ros2_metadata(path), dict):
        raise SpaceidError(
            f"{path / 'metadata.yaml'}: not a rosbag2 metadata mapping: fix or rebuild it (ros2 bag reindex)"
        )
    try:
        reader = AnyReader([path])
        reader.open()
    except (AnyReaderError, OSError, *_damaged()) as err:
        raise SpaceidError(
            f"{path}: not a readable ROS bag ({_text(err)}): {_SUFFIX_HINT}, written completely"
        ) from None
    try:
        yield reader
    finally:
        reader.close()


def _damaged():
    """What rosbags raises on a damaged bag: its own errors, and (found by fuzzing: a size field
    overwritten, a truncated record, a zeroed schema) what its parsers let through."""
    return (*_rosbags_errors(), ValueError, KeyError, IndexError, TypeError, OverflowError, MemoryError, EOFError,
            struct.error)


def _topic_connections(reader, where, topic, msgtype, option):
    """The connections of ``topic``, checked to exist, carry ``msgtype`` (a type, or a tuple of the types it may
    carry) and hold messages."""
    topics = reader.topics
    if topic not in topics:
        present = ", ".join(f"{name} ({info.msgtype})" for name, info in sorted(topics.items())) or "none"
        raise SpaceidError(f"{where}: no topic '{topic}' in the bag (topics: {present}): set {option} to one of them")
    info = topics[topic]
    if info.msgtype not in ((msgtype,) if isinstance(msgtype, str) else msgtype):
        types = info.msgtype or ", ".join(sorted({c.msgtype for c in info.connections}))
        expected = msgtype if isinstance(msgtype, str) else " or ".join(msgtype)
        raise SpaceidError(
            f"{where}: topic '{topic}' carries {types}, expected {expected}: set {option} to the topic with {expected}"
        )
    if not info.msgcount:
        raise SpaceidError(
            f"{where}: topic '{topic}' holds no messages: record it, or set {option} to a topic that has them"
        )
    return info.connections


class _JointEntry(NamedTuple):
    """A ``sensor_msgs/JointState`` message's fields, checked (:func:`_joint_entry`): a reader that
    meets the same message again (the live aligner's context) does not convert it again."""

    stamp: int
    names: tuple
    position: np.ndarray
    velocity: np.ndarray
    effort: np.ndarray


class _PoseEntry(NamedTuple):
    """A base attitude message's fields (:func:`_pose_entry`)."""

    stamp: int
    position: tuple
    quat: tuple
    frame: str
    rate: tuple | None = None


def _stamp(msg):
    """A message's (or a converted one's) header stamp [ns]."""
    if isinstance(msg, (_JointEntry, _PoseEntry)):
        return msg.stamp
    return msg.header.stamp.sec * _NS + msg.header.stamp.nanosec


def _joint_entry(msg, label, k) -> _JointEntry:
    """The checked fields of the JointState ``msg`` (message ``k`` of ``label``); NaN for the
    velocities or efforts it lacks."""
    if isinstance(msg, _JointEntry):
        return msg
    stamp, names = _stamp(msg), tuple(msg.name)
    at = f"{label}: message {k} (stamp {stamp / 1e9:.9f} s)"
    position = np.asarray(msg.position, dtype=float)
    if len(set(names)) != len(names):
        twice = next(n for n in names if names.count(n) > 1)
        raise SpaceidError(f"{at} names joint '{twice}' twice: fix the publisher")
    if position.size != len(names):
        raise SpaceidError(
            f"{at} has {len(names)} names but {position.size} positions: "
            "every JointState needs one position per name"
        )
    bad = np.flatnonzero(~np.isfinite(position))
    if bad.size:
        raise SpaceidError(
            f"{at}: position of joint '{names[bad[0]]}' is {position[bad[0]]}: "
            "give finite positions (drop the messages of a faulty encoder)"
        )
    return _JointEntry(stamp, names, position, *(_optional_array(msg, field, len(names), at)
                                                 for field in ("velocity", "effort")))  # fmt: skip


def _pose_entry(msg) -> _PoseEntry:
    """The fields of the base attitude ``msg`` (:data:`~spaceid.data._bag_format.POSE_TYPES`, told apart by their
    fields, as rosbags deserialises them or rclpy receives them): stamp [ns], position, scalar-first quaternion,
    frame and measured angular velocity [rad/s, base axes] (an Odometry's twist, child frame; an IMU's, at the
    origin; a PoseStamped's: None)."""
    if isinstance(msg, _PoseEntry):
        return msg
    rate = None
    if hasattr(msg, "twist"):  # nav_msgs/Odometry
        pose, rate = msg.pose.pose, msg.twist.twist.angular
        p, q = pose.position, pose.orientation
    elif hasattr(msg, "angular_velocity"):  # sensor_msgs/Imu
        p, q, rate = SimpleNamespace(x=0.0, y=0.0, z=0.0), msg.orientation, msg.angular_velocity
    else:
        p, q = msg.pose.position, msg.pose.orientation
    return _PoseEntry(_stamp(msg), (p.x, p.y, p.z), (q.w, q.x, q.y, q.z), msg.header.frame_id,  # ROS (x, y, z, w)
                      None if rate is None else (rate.x, rate.y, rate.z))


def _converted(msgs: list, joints: bool, label: str) -> list:
    """``msgs`` with each message replaced by its converted fields (:func:`_joint_entry`,
    :func:`_pose_entry`) in place, for a reader that holds messages across parts (and appends
    the new ones: those after the last converted are converted)."""
    kind = _JointEntry if joints else _PoseEntry
    start = len(msgs)
    while start and not isinstance(msgs[start - 1], kind):  # those held before are converted already
        start -= 1
    for k in range(start, len(msgs)):
        msgs[k] = _joint_entry(msgs[k], label, k) if joints else _pose_entry(msgs[k])
    return msgs


def _merge_joint_states(msgs, label):
    """Stamps (n,) [ns], names, position, velocity, effort (n, n_joints) from JointState messages.

    The rows are the distinct stamps of all messages; a joint no message carries at a stamp is
    NaN there; velocity (effort) is None when no message carries one.
    """
    entries = [_joint_entry(msg, label, k) for k, msg in enumerate(msgs)]
    if entries and entries[0].names and all(e.names == entries[0].names for e in entries):
        return _same_joints(entries, label)  # every message names every joint, in one order
    per_joint = _samples_by_joint(entries)
    if not per_joint:
        raise SpaceidError(f"{label}: no message names any joint: record the joint states with their names")
    for name, samples in per_joint.items():
        stamps = np.array([s[0] for s in samples], dtype=np.int64)
        _check_stamps(stamps, [s[1] for s in samples], f"{label}: joint '{name}'")
    all_stamps = np.unique(np.concatenate([np.array([s[0] for s in v], np.int64) for v in per_joint.values()]))
    names = tuple(per_joint)
    arrays = np.full((3, all_stamps.size, len(names)), np.nan)
    for c, samples in enumerate(per_joint.values()):
        rows = np.searchsorted(all_stamps, [s[0] for s in samples])
        arrays[:, rows, c] = np.array([s[2:] for s in samples]).T
    return _without_empty(all_stamps, names, *arrays)


def _same_joints(entries, label):
    """:func:`_merge_joint_states` of messages that all name the same joints in the same order:
    their rows as they are (the stamps checked once, as those of the first joint)."""
    stamps = np.array([e.stamp for e in entries], dtype=np.int64)
    _check_stamps(stamps, range(len(entries)), f"{label}: joint '{entries[0].names[0]}'")
    return _without_empty(stamps, entries[0].names, *(np.array([getattr(e, f) for e in entries])
                                                      for f in ("position", "velocity", "effort")))  # fmt: skip


def _without_empty(stamps, names, position, velocity, effort):
    """The merged joint states, velocity (effort) None when no message carries one."""
    return (
        stamps,
        names,
        position,
        None if np.isnan(velocity).all() else velocity,
        None if np.isnan(effort).all() else effort,
    )


def _samples_by_joint(entries):
    """Per joint name, in order of first appearance, its samples (stamp [ns], message index,
    position, velocity, effort) from the messages' checked fields ``entries`` (:func:`_joint_entry`)."""
    per_joint = {}
    for k, e in enumerate(entries):
        for i, name in enumerate(e.names):
            per_joint.setdefault(name, []).append((e.stamp, k, e.position[i], e.velocity[i], e.effort[i]))
    return per_joint


def _optional_array(msg, field, n, at):
    values = np.asarray(getattr(msg, field), dtype=float)
    if values.size == 0:
        return np.full(n, np.nan)
    if values.size != n:
        raise SpaceidError(
            f"{at} has {n} names but {values.size} {field} values: "
            f"give one per name or none"
        )
    return values


def _poses(msgs, label):
    """Stamps (m,) [ns], positions (m, 3), scalar-first quaternions (m, 4), frame and measured angular velocities
    (m, 3) [rad/s] (None when the messages carry none) of base attitude messages."""
    entries = [_pose_entry(m) for m in msgs]
    stamps = np.array([e.stamp for e in entries], dtype=np.int64)
    position = np.array([e.position for e in entries], dtype=float).reshape(-1, 3)
    quat = np.array([e.quat for e in entries], dtype=float).reshape(-1, 4)
    rate = None if any(e.rate is None for e in entries) else np.array([e.rate for e in entries], float).reshape(-1, 3)
    frames = [e.frame for e in entries]
    changed = next((k for k, f in enumerate(frames) if f != frames[0]), None)
    if changed is not None:
        raise SpaceidError(
            f"{label}: frame_id changes from '{frames[0]}' to '{frames[changed]}' at message {changed}: "
            "record the base pose in one frame"
        )
    _check_pose_values(stamps, position if rate is None else np.hstack([position, rate]), quat, label)
    _check_stamps(stamps, range(len(stamps)), label)
    return stamps, position, quat, frames[0], rate


def _check_pose_values(stamps, position, quat, label):
    """Poses must be finite and their quaternions of unit norm (lost-tracking frames are not)."""
    bad = np.flatnonzero(~np.isfinite(np.hstack([position, quat])).all(axis=1))
    if bad.size:
        k = bad[0]
        raise SpaceidError(
            f"{label}: message {k} (stamp {stamps[k] / 1e9:.9f} s) holds NaN or infinite pose values "
            f"({bad.size} such message(s)); lost-tracking frames must be dropped from the bag before use"
        )
    norm = np.linalg.norm(quat, axis=1)
    bad = np.flatnonzero(np.abs(norm - 1) > _QUAT_FAIL)
    if bad.size:
        k = bad[0]
        raise SpaceidError(
            f"{label}: message {k} (stamp {stamps[k] / 1e9:.9f} s): orientation has norm {norm[k]:.6g}, expected 1 "
            f"({bad.size} such message(s)): drop lost-tracking frames; the pose must be a unit quaternion"
        )


def _check_stamps(stamps, messages, label):
    """Header stamps [ns] must increase; the error names both messages (indices ``messages``)."""
    unordered = first_unordered(stamps)
    if unordered:
        i, count, kind = unordered
        raise SpaceidError(
            f"{label}: stamp {stamps[i] / 1e9:.9f} s in message {messages[i]} {kind} {stamps[i - 1] / 1e9:.9f} s in "
            f"message {messages[i - 1]} ({count} such step(s)): header stamps must increase; re-stamp the messages "
            "or drop the repeated ones"
        )


def _rename(names, rename, label):
    if not rename:
        return names
    unknown = [n for n in rename if n not in names]
    if unknown:
        raise SpaceidError(
            f"{label}: the joint mapping names '{unknown[0]}', which is not in the bag (joints: {', '.join(names)}): "
            "correct the mapping's left-hand names"
        )
    renamed = tuple(rename.get(n, n) for n in names)
    twice = next((n for n in renamed if renamed.count(n) > 1), None)
    if twice is not None:
        raise SpaceidError(f"{label}: the joint mapping gives two joints the name '{twice}': map each to its own name")
    return renamed


# --- mapping file ----------------------------------------------------------------------------


def read_mapping(path) -> dict:
    """Read a mapping file: topics, joint names and alignment settings for a bag (YAML).

    Example::

        joint_topic: /joint_states
        pose_topic: /vrpn_client_node/cepheus/pose
        joints: {shoulder: left_shoulder, elbow: left_elbow, wheel: reaction_wheel_joint}
        rate: 50          # optional: uniform time base [Hz] (default: the joint stamps)
        pose_latency: 0.0 # optional [s], see to_log
        max_gap: 0.1      # optional [s]
        max_tilt: 0.1     # optional [rad], planar models
        base_rate: gyro   # optional: the pose topic's measured angular velocity (Odometry, Imu), see to_log

    Every key is optional; ``joints`` maps names in the bag to model joint names.

    Returns
    -------
    dict
        The keys given, validated.

    Raises
    ------
    SpaceidError
        A missing or unreadable file, invalid YAML, not a mapping, an unknown key (the known
        ones are listed) or a value of the wrong type.
    """
    text = _read_text(path, "bag mapping file")
    data = parse_yaml(text, str(path), "fix the mapping file")
    if data is None:
        data = {}
    if not isinstance(data, dict):
        raise SpaceidError(f"{path}: expected a mapping of keys ({', '.join(MAPPING_KEYS)}), got {type(data).__name__}")
    for key, value in data.items():
        if key not in MAPPING_KEYS:
            close = difflib.get_close_matches(str(key), MAPPING_KEYS, n=1)
            hint = f"did you mean '{close[0]}'? " if close else ""
            raise SpaceidError(f"{path}: unknown key {shown(key)}: {hint}the keys are {', '.join(MAPPING_KEYS)}")
        if key.endswith("topic"):
            ok = isinstance(value, str) and value.strip() != ""
        elif key == "base_rate":
            ok = value in BASE_RATES
        elif key == "joints":
            ok = isinstance(value, dict) and all(isinstance(a, str) and isinstance(b, str) for a, b in value.items())
        else:
            ok = isinstance(value, (int, float)) and not isinstance(value, bool) and math.isfinite(value)
            ok = ok and (value > 0 or key == "pose_latency")
        if not ok:
            raise SpaceidError(f"{path}: '{key}' is {shown(value)}: expected {MAPPING_KEYS[key]}")
    return data
