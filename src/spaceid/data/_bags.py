"""ROS bags: recordings as a lab makes them, written and read with ``rosbags`` (no ROS install).

A run is recorded on two topics with standard messages:

- ``sensor_msgs/JointState`` on ``/joint_states`` (:data:`DEFAULT_JOINT_TOPIC`): joint names,
  positions [rad or m], velocities [rad/s or m/s] and efforts [N m or N], header stamps.
  ``joint_state_controller`` publishes every joint in one message, but a bag may also hold
  several publishers on the topic (arm and wheel controllers) with subsets of the joints, in any
  order: :func:`read_recording` merges them by name.
- ``geometry_msgs/PoseStamped`` on ``/vrpn_client_node/cepheus/pose``
  (:data:`DEFAULT_POSE_TOPIC`, the topic ``vrpn_client_ros`` publishes for a rigid body named
  ``cepheus`` in an OptiTrack or Vicon system): the motion-capture pose of the base,
  ``header.frame_id`` the capture frame. ROS quaternions are ``(x, y, z, w)``; spaceid's are
  scalar first ``[w, x, y, z]``: the conversion happens here and nowhere else.

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

:func:`to_log` turns a recording into a :class:`~spaceid.data.Log` (common time base,
rates); :func:`read_bag_log` does both steps from a bag, with an optional mapping file
(:func:`read_mapping`) for topic and joint names.
"""

from __future__ import annotations

import contextlib
import math
import os
import shutil
import tempfile
from pathlib import Path

import numpy as np
import yaml
from scipy.interpolate import CubicHermiteSpline, CubicSpline

from .._errors import SpaceidError
from ._tables import _QUAT_FAIL, _check_angles, _check_rates, _read_text, _Table
from .._yaml import parse_yaml
from ._recording import JointStates, Poses, Recording
from ._signals import differentiate, differentiate_quaternion
from ._timeseries import Log, first_unordered, quat_to_yaw, yaw_to_quat

__all__ = [
    "DEFAULT_JOINT_TOPIC",
    "DEFAULT_POSE_TOPIC",
    "FORMATS",
    "MAX_GAP",
    "MAX_TILT",
    "is_bag",
    "write_bag",
    "read_recording",
    "to_log",
    "read_mapping",
    "read_bag_log",
]

DEFAULT_JOINT_TOPIC = "/joint_states"
"""Topic of ``sensor_msgs/JointState`` (``joint_state_controller``'s default)."""

DEFAULT_POSE_TOPIC = "/vrpn_client_node/cepheus/pose"
"""Topic of the base's ``geometry_msgs/PoseStamped`` (``vrpn_client_ros``, rigid body ``cepheus``)."""

FORMATS = ("ros1", "ros2", "mcap")
"""``format`` values of :func:`write_bag`: ROS 1 ``.bag``, ROS 2 sqlite3 folder, ROS 2 MCAP."""

MAX_GAP = 0.1
"""Default longest time without a message that :func:`to_log` interpolates across [s]."""

MAX_TILT = 0.1
"""Default largest tilt of the base z axis from the capture frame's z in planar mode [rad]."""

JOINT_STATE = "sensor_msgs/msg/JointState"
POSE_STAMPED = "geometry_msgs/msg/PoseStamped"
JOINT_RATES = ("auto", "velocity", "differentiate")
MAPPING_KEYS = {
    "joint_topic": "a topic name",
    "pose_topic": "a topic name",
    "joints": "a mapping {name in the bag: model joint name}",
    "rate": "a sample rate [Hz] > 0",
    "pose_latency": "a latency [s]",
    "max_gap": "a time [s] > 0",
    "max_tilt": "an angle [rad] > 0",
}
_BAG_SUFFIXES = (".bag", ".mcap", ".db3")
_NS = 1_000_000_000
_SUFFIX_HINT = "give a .bag file (ROS 1), a ROS 2 bag folder (with metadata.yaml) or a .mcap file"


def is_bag(path) -> bool:
    """Whether ``path`` names a bag: a ``.bag``, ``.mcap`` or ``.db3`` name (existing or not),
    or a folder with ``metadata.yaml`` (a ROS 2 bag)."""
    path = Path(path)
    return path.suffix.lower() in _BAG_SUFFIXES or (path / "metadata.yaml").is_file()


# --- writing ---------------------------------------------------------------------------------


def write_bag(
    path,
    recording: Recording,
    *,
    format=None,
    joint_topic=DEFAULT_JOINT_TOPIC,
    pose_topic=DEFAULT_POSE_TOPIC,
    joint_groups=None,
    joint_delay=0.0,
    pose_delay=0.0,
    time_origin_ns=0,
) -> None:
    """Write ``recording`` as a ROS 1 bag, a ROS 2 bag folder (sqlite3 or MCAP) or an MCAP file.

    The output appears atomically: the bag is written into a temporary folder beside ``path``
    and renamed into place, so a failure leaves no partial bag (and an older bag at ``path``
    untouched). An existing bag at ``path`` is replaced; an existing folder that is not a ROS 2
    bag is never removed.

    Parameters
    ----------
    path : str or Path
        ``RUN.bag`` (ROS 1), a folder (ROS 2) or ``RUN.mcap`` (a single MCAP file).
    recording : Recording
        Joint states ``t`` (n,), ``position`` (n, n_joints) [rad or m], optional ``velocity``
        and ``effort`` (n, n_joints); base poses ``t`` (m,), ``position`` (m, 3) [m], ``quat``
        (m, 4) scalar first. A NaN position leaves that joint out of the message at that stamp
        (as for joints published separately); a row of NaN velocities (efforts) is written as
        an empty ``velocity`` (``effort``) array.
    format : {"ros1", "ros2", "mcap"}, optional
        Default: ``"ros1"`` for ``.bag``, ``"mcap"`` for ``.mcap``; a folder needs it given.
    joint_topic, pose_topic : str
        Topics of the ``sensor_msgs/JointState`` and ``geometry_msgs/PoseStamped`` messages.
    joint_groups : sequence of sequences of str, optional
        Publish the joints in separate messages, one per group, with the same header stamp
        (e.g. ``[["left_shoulder", "left_elbow"], ["reaction_wheel_joint"]]`` for arm and
        wheel controllers); in a ROS 1 bag each group is its own publisher (connection).
        Default: one message with every joint, like ``joint_state_controller``.
    joint_delay, pose_delay : float or array_like of shape (n,) / (m,)
        Transport delay [s] >= 0 from the header stamp to the time the recorder logged the
        message (the bag's receive time), per topic or per message.
    time_origin_ns : int
        Added to every stamp [ns since the epoch]; e.g. ``1_700_000_000 * 10**9`` for
        wall-clock stamps. Stamps are rounded to whole nanoseconds.

    Raises
    ------
    SpaceidError
        An unknown format or one that does not fit the path's suffix; a malformed recording
        (shapes, names, non-increasing stamps, NaN in the poses, stamps before 1970 or after
        2038); bad groups or delays; a path that is an existing folder but not a bag; or the
        file system refusing the write.
    """
    path = Path(path)
    kind, single_file = _output_kind(path, format)
    where = str(path)
    _check_recording(recording, where, writing=True)
    joints, base = recording.joints, recording.base
    groups = _joint_groups(joint_groups, joints.names, where)
    joint_ns = _stamps_ns(joints.t, time_origin_ns, f"{where}: recording.joints.t")
    pose_ns = _stamps_ns(base.t, time_origin_ns, f"{where}: recording.base.t")
    joint_log = joint_ns + _delays_ns(joint_delay, joints.t.size, f"{where}: joint_delay")
    pose_log = pose_ns + _delays_ns(pose_delay, base.t.size, f"{where}: pose_delay")

    ros = 1 if kind == "ros1" else 2
    store = _typestore(ros)
    serialize = store.serialize_ros1 if ros == 1 else store.serialize_cdr
    messages = []  # (log time [ns], topic order, connection key, serialized message)
    for r, stamp in enumerate(joint_ns):
        for g, columns in enumerate(groups):
            msg = _joint_message(store, ros, joints, r, columns, int(stamp))
            if msg is not None:
                messages.append((int(joint_log[r]), 0, ("joint", g), serialize(msg, JOINT_STATE)))
    for r, stamp in enumerate(pose_ns):
        msg = _pose_message(store, ros, base, r, int(stamp))
        messages.append((int(pose_log[r]), 1, ("pose", 0), serialize(msg, POSE_STAMPED)))
    messages.sort(key=lambda m: m[:3])

    with _staging(path) as stage:
        bag = stage / ("bag" if single_file else path.name)
        try:
            _write_messages(bag, kind, store, messages, joint_topic, pose_topic, len(groups))
        except OSError as err:
            raise _write_error(path, err) from None
        except _rosbags_errors() as err:
            raise SpaceidError(
                f"{path}: cannot write the bag ({_text(err)}): check the recording and the topics"
            ) from None
        product = bag / "bag.mcap" if single_file else bag
        _commit(product, path, stage)


def _output_kind(path, format):
    """(format, single MCAP file?) for an output path, or a SpaceidError."""
    suffix = path.suffix.lower()
    if format is None:
        format = {".bag": "ros1", ".mcap": "mcap"}.get(suffix)
        if format is None:
            raise SpaceidError(
                f"{path}: cannot tell the bag format from the name: give format='ros1' (a .bag file), "
                "'ros2' (a folder, sqlite3) or 'mcap' (a folder, or a .mcap file)"
            )
    if format not in FORMATS:
        raise SpaceidError(f"{path}: unknown bag format {format!r}: choose one of {', '.join(FORMATS)}")
    if (format == "ros1") != (suffix == ".bag"):
        need = "a ROS 1 bag needs the .bag suffix" if format == "ros1" else "only ROS 1 bags end in .bag"
        raise SpaceidError(f"{path}: {need} (readers go by the suffix): rename the output or change the format")
    if suffix == ".db3" or (suffix == ".mcap" and format != "mcap"):
        raise SpaceidError(
            f"{path}: a {suffix} name is a storage file, not a bag: name a folder for format='ros2' (sqlite3), "
            "or use format='mcap' for a single .mcap file"
        )
    return format, format == "mcap" and suffix == ".mcap"


def _rosbags_errors():
    """The exception classes of rosbags' readers, writers and serialisers."""
    from rosbags.highlevel import AnyReaderError
    from rosbags.rosbag1 import ReaderError as Reader1Error, WriterError as Writer1Error
    from rosbags.rosbag2 import ReaderError as Reader2Error, WriterError as Writer2Error
    from rosbags.serde import SerdeError

    return AnyReaderError, Reader1Error, Writer1Error, Reader2Error, Writer2Error, SerdeError


def _typestore(ros):
    from rosbags.typesys import Stores, get_typestore

    return get_typestore(Stores.ROS1_NOETIC if ros == 1 else Stores.ROS2_HUMBLE)


def _header(store, ros, stamp_ns, frame, seq):
    time = store.types["builtin_interfaces/msg/Time"](sec=stamp_ns // _NS, nanosec=stamp_ns % _NS)
    header = store.types["std_msgs/msg/Header"]
    if ros == 1:
        return header(seq=seq, stamp=time, frame_id=frame)
    return header(stamp=time, frame_id=frame)


def _joint_message(store, ros, joints, row, columns, stamp_ns):
    """The JointState of ``columns`` at ``row`` (joints with a NaN position left out), or None."""
    present = [c for c in columns if np.isfinite(joints.position[row, c])]
    if not present:
        return None

    def optional(values):
        if values is None or np.isnan(values[row, present]).all():
            return np.zeros(0)
        return np.array(values[row, present], dtype=float)

    return store.types[JOINT_STATE](
        header=_header(store, ros, stamp_ns, "", row),
        name=[joints.names[c] for c in present],
        position=np.array(joints.position[row, present], dtype=float),
        velocity=optional(joints.velocity),
        effort=optional(joints.effort),
    )


def _pose_message(store, ros, base, row, stamp_ns):
    types = store.types
    w, x, y, z = (float(v) for v in base.quat[row])
    pose = types["geometry_msgs/msg/Pose"](
        position=types["geometry_msgs/msg/Point"](*(float(v) for v in base.position[row])),
        orientation=types["geometry_msgs/msg/Quaternion"](x=x, y=y, z=z, w=w),  # ROS: x, y, z, w
    )
    return types[POSE_STAMPED](header=_header(store, ros, stamp_ns, base.frame, row), pose=pose)


def _write_messages(bag, kind, store, messages, joint_topic, pose_topic, n_groups):
    """Write sorted ``messages`` into a new bag at ``bag`` with rosbags' writers."""
    if kind == "ros1":
        from rosbags.rosbag1 import Writer

        writer = Writer(bag)
    else:
        from rosbags.rosbag2 import StoragePlugin, Writer

        plugin = StoragePlugin.SQLITE3 if kind == "ros2" else StoragePlugin.MCAP
        writer = Writer(bag, version=8, storage_plugin=plugin)
    with writer:
        connections = {("pose", 0): writer.add_connection(pose_topic, POSE_STAMPED, typestore=store)}
        for g in range(n_groups if kind == "ros1" else 1):
            extra = {"callerid": f"/joint_state_publisher_{g}"} if kind == "ros1" else {}
            connections["joint", g] = writer.add_connection(joint_topic, JOINT_STATE, typestore=store, **extra)
        for log_ns, _, key, data in messages:
            writer.write(connections[key if kind == "ros1" or key[0] == "pose" else ("joint", 0)], log_ns, data)


@contextlib.contextmanager
def _staging(path):
    """A fresh hidden folder beside ``path`` for writing; removed on exit, whatever happens."""
    if path.is_dir() and not (path / "metadata.yaml").is_file():
        raise SpaceidError(
            f"{path}: exists and is a folder but not a ROS 2 bag (no metadata.yaml): choose another path"
        )
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        stage = Path(tempfile.mkdtemp(prefix=f".{path.name}.", suffix=".tmp", dir=path.parent))
    except OSError as err:
        raise _write_error(path, err) from None
    try:
        yield stage
    finally:
        shutil.rmtree(stage, ignore_errors=True)


def _commit(product, path, stage):
    """Move the finished ``product`` to ``path``: one rename, or for an older bag folder two (it
    is moved into the staging folder first), so a reader may briefly find no bag, never half of one."""
    try:
        if product.is_dir() and path.is_dir():
            old = stage / "replaced"
            os.rename(path, old)
            try:
                os.rename(product, path)
            except OSError:
                os.rename(old, path)
                raise
        elif product.is_dir() != path.is_dir() and path.exists():
            what = "folder" if path.is_dir() else "file"
            raise SpaceidError(
                f"{path}: exists and is a {what}, but this format writes the other: remove it or choose another path"
            )
        else:
            os.replace(product, path)
    except OSError as err:
        raise _write_error(path, err) from None


def _write_error(path, err):
    return SpaceidError(f"{path}: cannot write the bag ({_text(err.strerror or err)}): check the path is writable")


def _text(err):
    """An exception's message on one line."""
    return " ".join(str(err).split())


def _joint_groups(groups, names, where):
    """Column indices of each group (default: one group of all joints), every joint in one."""
    if groups is None:
        return [list(range(len(names)))]
    columns, seen = [], set()
    for group in groups:
        if isinstance(group, str):
            raise SpaceidError(f"{where}: joint_groups must be a list of lists of joint names, got {group!r}")
        unknown = [j for j in group if j not in names]
        if unknown:
            raise SpaceidError(
                f"{where}: joint_groups names '{unknown[0]}', not a joint of the recording ({', '.join(names)})"
            )
        twice = [j for j in group if j in seen]
        if twice or len(set(group)) != len(group):
            name = (twice or list(group))[0]
            raise SpaceidError(f"{where}: joint_groups lists joint '{name}' twice: give each joint one group")
        seen.update(group)
        columns.append([names.index(j) for j in group])
    left = [j for j in names if j not in seen]
    if left:
        raise SpaceidError(f"{where}: joint_groups leaves out {', '.join(left)}: put every joint in one group")
    return columns


def _stamps_ns(t, origin, label):
    """Stamps [s] as int64 nanoseconds after ``origin``, checked to fit ROS time."""
    if isinstance(origin, bool) or not isinstance(origin, (int, np.integer)):
        raise SpaceidError(f"{label}: time_origin_ns={origin!r}: expected an integer number of nanoseconds")
    ns = np.rint(np.asarray(t, dtype=float) * 1e9).astype(np.int64) + np.int64(origin)
    if ns.size and (ns[0] < 0 or ns[-1] >= np.int64(2**31) * _NS):
        raise SpaceidError(
            f"{label}: stamps from {ns[0] / 1e9:.9g} to {ns[-1] / 1e9:.9g} s after 1970 do not fit ROS time "
            "(0 to 2^31 s): shift them with time_origin_ns"
        )
    unordered = first_unordered(ns)
    if unordered:
        i = unordered[0]
        raise SpaceidError(
            f"{label}: stamps {i - 1} and {i} are less than 1 ns apart: ROS time has 1 ns resolution; drop one"
        )
    return ns


def _delays_ns(delay, n, label):
    delay = np.broadcast_to(np.asarray(delay, dtype=float), (n,)) if np.ndim(delay) == 0 else np.asarray(delay, float)
    if delay.shape != (n,) or not (np.isfinite(delay).all() and (delay >= 0).all()):
        raise SpaceidError(f"{label}: expected a delay [s] >= 0, one number or one per message ({n}), finite")
    return np.rint(delay * 1e9).astype(np.int64)


# --- reading ---------------------------------------------------------------------------------


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
        Topics of the ``sensor_msgs/JointState`` and ``geometry_msgs/PoseStamped`` messages.
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
        published (not renormalised), ``frame``. ``meta``: ``source``, ``format``, topics,
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
    where = str(path)
    with _open_bag(path) as reader:
        connections = {
            topic: _topic_connections(reader, where, topic, msgtype, option)
            for topic, msgtype, option in (
                (joint_topic, JOINT_STATE, "joint_topic (--joint-topic)"),
                (pose_topic, POSE_STAMPED, "pose_topic (--pose-topic)"),
            )
        }
        joint_msgs, pose_msgs = [], []
        try:
            for connection, _, raw in reader.messages(connections=[c for cs in connections.values() for c in cs]):
                msg = reader.deserialize(raw, connection.msgtype)
                (joint_msgs if connection.topic == joint_topic else pose_msgs).append(msg)
        except _rosbags_errors() as err:
            raise SpaceidError(
                f"{where}: cannot read the messages ({_text(err)}): the bag is damaged; re-record or repair it"
            ) from None
    kind = "ros1" if path.suffix.lower() == ".bag" else _ros2_format(path)

    joint_ns, names, position, velocity, effort = _merge_joint_states(joint_msgs, f"{where}: {joint_topic}")
    pose_ns, pose_position, quat, frame = _poses(pose_msgs, f"{where}: {pose_topic}")
    if time_origin_ns is None:
        time_origin_ns = int(min(joint_ns[0], pose_ns[0]) // _NS * _NS)
    elif isinstance(time_origin_ns, bool) or not isinstance(time_origin_ns, (int, np.integer)):
        raise SpaceidError(f"{where}: time_origin_ns={time_origin_ns!r}: expected an integer number of nanoseconds")
    names = _rename(names, rename, f"{where}: {joint_topic}")
    meta = {
        "source": where,
        "format": kind,
        "joint_topic": joint_topic,
        "pose_topic": pose_topic,
        "rename": dict(rename or {}),
        "time_origin_ns": int(time_origin_ns),
        "joint_messages": len(joint_msgs),
        "joint_publishers": len(connections[joint_topic]),
        "pose_messages": len(pose_msgs),
    }
    origin = np.int64(time_origin_ns)
    return Recording(
        joints=JointStates(t=(joint_ns - origin) / 1e9, names=names, position=position, velocity=velocity,
                           effort=effort),
        base=Poses(t=(pose_ns - origin) / 1e9, position=pose_position, quat=quat, frame=frame),
        meta=meta,
    )


def _ros2_format(path):
    """``"ros2-sqlite3"``, ``"ros2-mcap"`` or ``"mcap"`` (single file) for a ROS 2 bag path."""
    if path.is_dir():
        try:
            info = yaml.safe_load((path / "metadata.yaml").read_text(encoding="utf-8"))
            return f"ros2-{info['rosbag2_bagfile_information']['storage_identifier']}"
        except (OSError, yaml.YAMLError, KeyError, TypeError):
            return "ros2"
    return "mcap" if path.suffix.lower() == ".mcap" else "ros2-sqlite3"


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
    try:
        reader = AnyReader([path])
        reader.open()
    except (AnyReaderError, OSError) as err:
        raise SpaceidError(
            f"{path}: not a readable ROS bag ({_text(err)}): {_SUFFIX_HINT}, written completely"
        ) from None
    try:
        yield reader
    finally:
        reader.close()


def _topic_connections(reader, where, topic, msgtype, option):
    """The connections of ``topic``, checked to exist, carry ``msgtype`` and hold messages."""
    topics = reader.topics
    if topic not in topics:
        present = ", ".join(f"{name} ({info.msgtype})" for name, info in sorted(topics.items())) or "none"
        raise SpaceidError(f"{where}: no topic '{topic}' in the bag (topics: {present}): set {option} to one of them")
    info = topics[topic]
    if info.msgtype != msgtype:
        types = info.msgtype or ", ".join(sorted({c.msgtype for c in info.connections}))
        raise SpaceidError(
            f"{where}: topic '{topic}' carries {types}, expected {msgtype}: set {option} to the topic with {msgtype}"
        )
    if not info.msgcount:
        raise SpaceidError(
            f"{where}: topic '{topic}' holds no messages: record it, or set {option} to a topic that has them"
        )
    return info.connections


def _stamp(msg):
    return msg.header.stamp.sec * _NS + msg.header.stamp.nanosec


def _merge_joint_states(msgs, label):
    """Stamps (n,) [ns], names, position, velocity, effort (n, n_joints) from JointState messages."""
    per_joint = {}  # name -> lists of (stamp, message index, position, velocity, effort)
    for k, msg in enumerate(msgs):
        stamp, names = _stamp(msg), list(msg.name)
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
        extras = [_optional_array(msg, field, len(names), at) for field in ("velocity", "effort")]
        for i, name in enumerate(names):
            per_joint.setdefault(name, []).append((stamp, k, position[i], extras[0][i], extras[1][i]))

    for name, samples in per_joint.items():
        stamps = np.array([s[0] for s in samples], dtype=np.int64)
        _check_stamps(stamps, [s[1] for s in samples], f"{label}: joint '{name}'")
    all_stamps = np.unique(np.concatenate([np.array([s[0] for s in v], np.int64) for v in per_joint.values()]))
    names = tuple(per_joint)
    arrays = np.full((3, all_stamps.size, len(names)), np.nan)
    for c, samples in enumerate(per_joint.values()):
        rows = np.searchsorted(all_stamps, [s[0] for s in samples])
        arrays[:, rows, c] = np.array([s[2:] for s in samples]).T
    position, velocity, effort = arrays
    return (
        all_stamps,
        names,
        position,
        None if np.isnan(velocity).all() else velocity,
        None if np.isnan(effort).all() else effort,
    )


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
    """Stamps (m,) [ns], positions (m, 3), scalar-first quaternions (m, 4), frame from PoseStamped."""
    stamps = np.array([_stamp(m) for m in msgs], dtype=np.int64)
    position = np.array([[m.pose.position.x, m.pose.position.y, m.pose.position.z] for m in msgs], dtype=float)
    o = [m.pose.orientation for m in msgs]
    quat = np.array([[q.w, q.x, q.y, q.z] for q in o], dtype=float)  # ROS (x, y, z, w) -> [w, x, y, z]
    frames = [m.header.frame_id for m in msgs]
    changed = next((k for k, f in enumerate(frames) if f != frames[0]), None)
    if changed is not None:
        raise SpaceidError(
            f"{label}: frame_id changes from '{frames[0]}' to '{frames[changed]}' at message {changed}: "
            "record the base pose in one frame"
        )
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
    _check_stamps(stamps, range(len(stamps)), label)
    return stamps, position, quat, frames[0]


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


# --- alignment ---------------------------------------------------------------------------------


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
    joint_rates="auto",
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
       pure-yaw quaternion) and rejects tilts above ``max_tilt``.
    5. Joints: rates are the JointState velocities when every message of that joint carries
       one (``joint_rates="auto"``), else the positions are smoothed and differentiated with
       :func:`~spaceid.data.differentiate` on that joint's stamps. Off the joint stamps
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
    joint_rates : {"auto", "velocity", "differentiate"}
        Joint rates from the messages' velocities when every sample has one ("auto"), always
        ("velocity": an error if some are missing) or never ("differentiate").
    method, window, order, smoothing
        Differentiator settings, as in :func:`spaceid.data.differentiate` (automatic by
        default), for the attitude and the differentiated joints.
    quantum : float, optional
        Encoder resolution [rad per count] of the differentiated joints.

    Returns
    -------
    Log
        ``t`` (n,) [s, after the recording's time origin]; ``q``, ``qd`` (n, n_joints);
        ``base_quat`` (n, 4); ``base_w`` (n, 3) [rad/s] in base axes. ``meta``: the recording's
        meta plus ``time_base``, ``pose_latency``, ``streams`` (rates, dropped frames, largest
        gaps, pose frame and tilt), ``joint_rates`` (per joint ``"velocity"`` or
        ``"differentiated"``), ``interpolation`` and ``differentiation`` (``base``, ``joints``).

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
    _check_options(where, rate, pose_latency, max_gap, max_tilt, joint_rates)
    _check_recording(recording, where, writing=False)
    js, base = recording.joints, recording.base
    missing = [j for j in joints if j not in js.names]
    if missing:
        raise SpaceidError(
            f"{where}: model joint '{missing[0]}' is not on {jtopic} (joints there: {', '.join(js.names)}): "
            f"map the bag's name to it (mapping file 'joints: {{bag_name: {missing[0]}}}')"
        )
    columns = [js.names.index(j) for j in joints]
    valid = np.isfinite(js.position[:, columns])
    t_pose = base.t - pose_latency

    spans = {f"{ptopic} (pose)": (t_pose[0], t_pose[-1])}
    for c, j in enumerate(joints):
        tj = js.t[valid[:, c]]
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
    streams = {"pose": _gaps(t_pose, start, end, max_gap, f"{where}: {ptopic}")}
    streams["pose"]["frame"] = base.frame

    if rate is None:
        rows = valid.all(axis=1) & (js.t >= start) & (js.t <= end)
        if rows.sum() < 2:
            raise SpaceidError(
                f"{where}: {jtopic}: fewer than 2 stamps carry all of {', '.join(joints)} within the overlap "
                "(publishers stamp them separately): give a rate (mapping file key 'rate') to resample on a "
                "uniform time base"
            )
        t = js.t[rows]
        time_base = {"kind": "joint stamps", "topic": jtopic}
    else:
        t = np.minimum(start + np.arange(int(math.floor((end - start) * rate + 1e-9)) + 1) / rate, end)
        time_base = {"kind": "uniform", "rate_hz": float(rate)}
    time_base.update(start=float(t[0]), end=float(t[-1]), n_samples=int(t.size))

    base_quat, base_w, info_base, tilt = _base(t_pose, base.quat, t, planar, max_tilt, where, ptopic,
                                               dict(method=method, window=window, order=order, smoothing=smoothing))
    if planar:
        streams["pose"]["max_tilt_rad"] = tilt

    q, qd = np.empty((t.size, len(joints))), np.empty((t.size, len(joints)))
    sources, infos, streams["joints"] = {}, {}, {}
    for c, j in enumerate(joints):
        rows = valid[:, c]
        tj, qj = js.t[rows], js.position[rows, columns[c]]
        vj = None if js.velocity is None else js.velocity[rows, columns[c]]
        streams["joints"][j] = _gaps(tj, start, end, max_gap, f"{where}: {jtopic}: joint '{j}'")
        measured = joint_rates != "differentiate" and vj is not None and np.isfinite(vj).all()
        if joint_rates == "velocity" and not measured:
            raise SpaceidError(
                f"{where}: {jtopic}: joint '{j}' lacks a velocity in some messages: use joint_rates='auto' "
                "to differentiate its positions"
            )
        has_rate = vj is not None and np.isfinite(vj).all()
        if j in wheels and has_rate:  # a fast wheel turns more than pi a message: unwrap by its rate
            qj = _unwrap_with_rate(tj, qj, vj)
        if measured:
            sources[j] = "velocity"
        else:
            # without a rate, unwrap only angles that are wrapped (within +-pi) at all
            wrap = j in wheels and not has_rate and np.abs(qj).max() <= np.pi + 1e-9
            with _prefix(f"{where}: {jtopic}"):
                qj, vj, infos[j] = differentiate(tj, qj, method=method, window=window, order=order,
                                                 smoothing=smoothing, quantum=quantum, wrap=wrap, name=f"q_{j}")
            sources[j] = "differentiated"
        at = np.searchsorted(tj, t).clip(max=tj.size - 1)
        if (tj[at] == t).all():
            q[:, c], qd[:, c] = qj[at], vj[at]
        else:
            q[:, c], qd[:, c] = CubicHermiteSpline(tj, qj, vj)(t), CubicSpline(tj, vj)(t)

    table = _Table(f"{where}", [], np.empty((0, 0)), [])
    values = {f"q_{j}": q[:, c] for c, j in enumerate(joints)} | {f"qd_{j}": qd[:, c] for c, j in enumerate(joints)}
    base_rates = ("base_wz",) if planar else ("base_wx", "base_wy", "base_wz")
    values |= {name: base_w[:, "xyz".index(name[-1])] for name in base_rates}
    if planar:
        values["base_yaw"] = np.unwrap(quat_to_yaw(base_quat))
    _check_angles(table, values, ("base_yaw", *(f"q_{j}" for j in joints if j not in wheels)))
    _check_rates(table, values, base_rates, joints, wheels)

    meta.update(
        time_base=time_base,
        pose_latency=float(pose_latency),
        max_gap=float(max_gap),
        streams=streams,
        joint_rates=sources,
        interpolation="cubic Hermite for angles and attitude (rates as slopes), cubic spline for rates; "
        "base on the pose stamps, joints on theirs (none when the time base is the joint stamps)",
        differentiation={"base": info_base, "joints": infos or None},
    )
    return Log(t=t, joints=joints, q=q, qd=qd, base_quat=base_quat, base_w=base_w, planar=bool(planar), meta=meta)


def _base(t_pose, quat, t, planar, max_tilt, where, topic, options):
    """Base attitude (n, 4) and body rate (n, 3) at ``t``, the differentiator record, max tilt."""
    quat = quat / np.linalg.norm(quat, axis=1, keepdims=True)
    tilt = None
    if planar:
        cos_tilt = 1 - 2 * (quat[:, 1] ** 2 + quat[:, 2] ** 2)  # base z axis against the frame's z
        tilts = np.arccos(np.clip(cos_tilt, -1.0, 1.0))
        tilt = float(tilts.max())
        if tilt > max_tilt:
            k = int(np.argmax(tilts))
            raise SpaceidError(
                f"{where}: {topic}: the base tilts {tilt:.3g} rad from the frame's z axis (first worst at "
                f"t = {t_pose[k]:.6g} s), beyond max_tilt = {max_tilt:g} rad for a planar model: check the "
                "capture frame is z-up and the rigid body's axes, raise max_tilt (mapping file), or use a spatial model"
            )
        quat = yaw_to_quat(quat_to_yaw(quat))
    with _prefix(f"{where}: {topic}"):
        smooth, w_body, info = differentiate_quaternion(t_pose, quat, **options)
    w = CubicSpline(t_pose, w_body, axis=0)(t)
    if planar:
        w[:, :2] = 0.0
        yaw = CubicHermiteSpline(t_pose, np.unwrap(quat_to_yaw(smooth)), w_body[:, 2])(t)
        return yaw_to_quat(yaw), w, info, tilt
    s, v = smooth[:, :1], smooth[:, 1:]  # qdot = q (x) [0, w] / 2, the slopes of the Hermite cubic
    slope = 0.5 * np.column_stack([-np.einsum("ij,ij->i", v, w_body), s * w_body + np.cross(v, w_body)])
    out = CubicHermiteSpline(t_pose, smooth, slope, axis=0)(t)
    return out / np.linalg.norm(out, axis=1, keepdims=True), w, info, tilt


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


def _check_options(where, rate, pose_latency, max_gap, max_tilt, joint_rates):
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
    for field, width in (("position", 3), ("quat", 4)):
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


# --- mapping file and one-call reading ----------------------------------------------------------


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
            raise SpaceidError(f"{path}: unknown key '{key}': the keys are {', '.join(MAPPING_KEYS)}")
        if key.endswith("topic"):
            ok = isinstance(value, str) and value.strip() != ""
        elif key == "joints":
            ok = isinstance(value, dict) and all(isinstance(a, str) and isinstance(b, str) for a, b in value.items())
        else:
            ok = isinstance(value, (int, float)) and not isinstance(value, bool) and math.isfinite(value)
            ok = ok and (value > 0 or key == "pose_latency")
        if not ok:
            raise SpaceidError(f"{path}: '{key}' is {value!r}: expected {MAPPING_KEYS[key]}")
    return data


def read_bag_log(path, *, joints, planar, wheels=(), mapping=None, joint_topic=None, pose_topic=None, **options) -> Log:
    """Read a bag straight into a :class:`~spaceid.data.Log`: :func:`read_recording` then
    :func:`to_log`.

    Parameters
    ----------
    path : str or Path
        The bag (see :func:`read_recording`).
    joints, planar, wheels
        As in :func:`to_log` (model joint names).
    mapping : str, Path or dict, optional
        A mapping file (:func:`read_mapping`) or its content: topics, ``joints`` (bag name to
        model name), ``rate``, ``pose_latency``, ``max_gap``, ``max_tilt``.
    joint_topic, pose_topic : str, optional
        Override the mapping's topics (default :data:`DEFAULT_JOINT_TOPIC`,
        :data:`DEFAULT_POSE_TOPIC`).
    **options
        Further :func:`to_log` keywords (None values are ignored); they override the mapping.

    Returns
    -------
    Log
        As :func:`to_log`; ``meta["mapping"]`` names the mapping file when one was given.
    """
    settings = read_mapping(mapping) if isinstance(mapping, (str, Path)) else dict(mapping or {})
    recording = read_recording(
        path,
        joint_topic=joint_topic or settings.get("joint_topic", DEFAULT_JOINT_TOPIC),
        pose_topic=pose_topic or settings.get("pose_topic", DEFAULT_POSE_TOPIC),
        rename=settings.get("joints"),
    )
    keywords = {k: settings[k] for k in ("rate", "pose_latency", "max_gap", "max_tilt") if k in settings}
    keywords |= {k: v for k, v in options.items() if v is not None}
    log = to_log(recording, joints=joints, planar=planar, wheels=wheels, **keywords)
    if isinstance(mapping, (str, Path)):
        log.meta["mapping"] = str(mapping)
    return log
