"""The ROS 2 client, imported only when a node runs: the install hint without it, the context,
the quality of service and the message types of the topics spaceid reads and writes."""

from __future__ import annotations

import contextlib
import warnings

from .._errors import SpaceidError

__all__ = ["INSTALL_HINT", "POSE_TYPES", "require_rclpy"]

INSTALL_HINT = 'pip install "spaceid[ros]" (from a checkout: pip install -e ".[ros]")'
"""How to install the ROS 2 client and message packages (the ``ros`` extra, ROS 2 Kilted wheels)."""

POSE_TYPES = {"pose": "geometry_msgs/msg/PoseStamped", "odometry": "nav_msgs/msg/Odometry",
              "imu": "sensor_msgs/msg/Imu"}  # fmt: skip
"""The base attitude messages the live monitor reads, by the name ``pose_type`` takes."""

DEPTH = 1000
"""History depth of every topic [messages]: the subscriptions' bounded buffer; reliable delivery,
so a burst of this many messages waits instead of being dropped."""


def require_rclpy():
    """The ``rclpy`` module; a one-line SpaceidError saying how to install it when it is absent."""
    try:
        with warnings.catch_warnings():  # its dependencies import deprecated standard modules (sre_parse)
            warnings.simplefilter("ignore", DeprecationWarning)
            import rclpy
            import rclpy.node  # noqa: F401
            import geometry_msgs.msg, nav_msgs.msg, sensor_msgs.msg, std_msgs.msg  # noqa: E401, F401
    except ImportError as err:
        raise SpaceidError(f"the ROS 2 commands need rclpy and the message packages ({err}): install them "
                           f"with {INSTALL_HINT}") from None
    return rclpy


@contextlib.contextmanager
def ros_context():
    """An initialised rclpy context without rclpy's signal handlers (Ctrl-C raises
    KeyboardInterrupt in Python, so that the caller can write its files); shut down on exit."""
    rclpy = require_rclpy()
    from rclpy.context import Context
    from rclpy.signals import SignalHandlerOptions

    context = Context()
    rclpy.init(context=context, signal_handler_options=SignalHandlerOptions.NO)
    try:
        yield context
    finally:
        with contextlib.suppress(Exception):
            context.try_shutdown()


def qos(latched: bool = False):
    """Reliable, keep-last ``DEPTH`` quality of service; ``latched``: transient local (a late
    subscriber gets the last messages, as for events)."""
    from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy

    return QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=DEPTH, reliability=ReliabilityPolicy.RELIABLE,
                      durability=DurabilityPolicy.TRANSIENT_LOCAL if latched else DurabilityPolicy.VOLATILE)


def pose_class(pose_type: str):
    """The message class of a base attitude topic (``POSE_TYPES``)."""
    if pose_type not in POSE_TYPES:
        raise SpaceidError(f"`pose_type`: {pose_type!r}: give one of {', '.join(POSE_TYPES)}")
    if pose_type == "pose":
        from geometry_msgs.msg import PoseStamped as cls
    elif pose_type == "odometry":
        from nav_msgs.msg import Odometry as cls
    else:
        from sensor_msgs.msg import Imu as cls
    return cls


def string_message(text: str):
    """A ``std_msgs/String`` holding ``text``."""
    from std_msgs.msg import String

    msg = String()
    msg.data = text
    return msg
