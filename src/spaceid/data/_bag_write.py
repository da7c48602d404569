"""Writing ROS bags: ROS 1 ``.bag``, ROS 2 sqlite3 or MCAP folder, single ``.mcap`` file.

A :class:`~spaceid.data.Recording` becomes ``sensor_msgs/JointState`` and
``geometry_msgs/PoseStamped`` messages (the layout is in :mod:`spaceid.data._bag_format`),
serialised with ``rosbags`` and written into a staging folder that is then renamed into place.
"""

from __future__ import annotations

import contextlib
import os
import shutil
import tempfile
from pathlib import Path

import numpy as np

from .._errors import SpaceidError
from ._bag_format import (
    _NS, DEFAULT_JOINT_TOPIC, DEFAULT_POSE_TOPIC, FORMATS, JOINT_STATE, ODOMETRY, POSE_STAMPED, _check_origin_ns,
    _check_recording, _rosbags_errors, _text,
)
from ._recording import Recording
from ._timeseries import first_unordered

__all__ = ["write_bag"]


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
        (m, 4) scalar first, and ``rate`` (m, 3) [rad/s, base axes] when measured (a gyro's: the
        poses are then ``nav_msgs/Odometry`` messages, the rate their twist's angular velocity, the
        child frame ``base``). A NaN position leaves that joint out of the message at that stamp
        (as for joints published separately); a row of NaN velocities (efforts) is written as
        an empty ``velocity`` (``effort``) array.
    format : {"ros1", "ros2", "mcap"}, optional
        Default: ``"ros1"`` for ``.bag``, ``"mcap"`` for ``.mcap``; a folder needs it given.
    joint_topic, pose_topic : str
        Topics of the ``sensor_msgs/JointState`` and ``geometry_msgs/PoseStamped`` (or Odometry) messages.
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
    messages = _serialized_messages(store, ros, recording, groups, (joint_ns, joint_log), (pose_ns, pose_log))
    with _staging(path) as stage:
        bag = stage / ("bag" if single_file else path.name)
        try:
            _write_messages(bag, kind, store, messages, joint_topic, pose_topic, len(groups), _pose_type(base))
        except OSError as err:
            raise _write_error(path, err) from None
        except _rosbags_errors() as err:
            raise SpaceidError(
                f"{path}: cannot write the bag ({_text(err)}): check the recording and the topics"
            ) from None
        product = bag / "bag.mcap" if single_file else bag
        _commit(product, path, stage)


def _serialized_messages(store, ros, recording, groups, joint_times, pose_times):
    """Every message of the bag, serialised, in the order they are written.

    ``joint_times`` and ``pose_times`` are (header stamps, log times) [ns], int64 arrays of shape
    (n,) and (m,). Returns tuples (log time [ns], topic order, connection key, bytes), sorted:
    one JointState per joint group and stamp (connection key ``("joint", group)``), one
    PoseStamped (Odometry, with a measured rate) per pose (``("pose", 0)``).
    """
    serialize = store.serialize_ros1 if ros == 1 else store.serialize_cdr
    joints, base = recording.joints, recording.base
    messages = []
    for r, (stamp, logged) in enumerate(zip(*joint_times)):
        for g, columns in enumerate(groups):
            msg = _joint_message(store, ros, joints, r, columns, int(stamp))
            if msg is not None:
                messages.append((int(logged), 0, ("joint", g), serialize(msg, JOINT_STATE)))
    for r, (stamp, logged) in enumerate(zip(*pose_times)):
        msg = _pose_message(store, ros, base, r, int(stamp))
        messages.append((int(logged), 1, ("pose", 0), serialize(msg, _pose_type(base))))
    messages.sort(key=lambda m: m[:3])
    return messages


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


def _pose_type(base) -> str:
    """The message type of the poses ``base``: Odometry when they hold a measured rate, else PoseStamped."""
    return POSE_STAMPED if base.rate is None else ODOMETRY


def _pose_message(store, ros, base, row, stamp_ns):
    types = store.types
    w, x, y, z = (float(v) for v in base.quat[row])
    pose = types["geometry_msgs/msg/Pose"](
        position=types["geometry_msgs/msg/Point"](*(float(v) for v in base.position[row])),
        orientation=types["geometry_msgs/msg/Quaternion"](x=x, y=y, z=z, w=w),  # ROS: x, y, z, w
    )
    header = _header(store, ros, stamp_ns, base.frame, row)
    if base.rate is None:
        return types[POSE_STAMPED](header=header, pose=pose)
    vector = types["geometry_msgs/msg/Vector3"]
    twist = types["geometry_msgs/msg/Twist"](linear=vector(0.0, 0.0, 0.0), angular=vector(*(float(v) for v in
                                                                                           base.rate[row])))
    return types[ODOMETRY](header=header, child_frame_id="base",
                           pose=types["geometry_msgs/msg/PoseWithCovariance"](pose=pose, covariance=np.zeros(36)),
                           twist=types["geometry_msgs/msg/TwistWithCovariance"](twist=twist, covariance=np.zeros(36)))


def _write_messages(bag, kind, store, messages, joint_topic, pose_topic, n_groups, pose_type):
    """Write sorted ``messages`` into a new bag at ``bag`` with rosbags' writers (the poses of ``pose_type``)."""
    if kind == "ros1":
        from rosbags.rosbag1 import Writer

        writer = Writer(bag)
    else:
        from rosbags.rosbag2 import StoragePlugin, Writer

        plugin = StoragePlugin.SQLITE3 if kind == "ros2" else StoragePlugin.MCAP
        writer = Writer(bag, version=8, storage_plugin=plugin)
    with writer:
        connections = {("pose", 0): writer.add_connection(pose_topic, pose_type, typestore=store)}
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
    _check_origin_ns(origin, label)
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
