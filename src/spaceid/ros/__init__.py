"""Live on ROS 2: the monitor as a node, and the recordings and the twin published on the topics a
lab's robot uses (``spaceid ros ...``; docs/live.md).

The ROS 2 client (rclpy, ROS 2 Kilted wheels: ``pip install "spaceid[ros]"``) is imported only
when a node runs: ``import spaceid`` and this subpackage work without it, and a node without it
raises a one-line :class:`~spaceid.SpaceidError` that says how to install it.

* :class:`LiveMonitor` is the engine, without ROS: JointState and pose messages in, aligned by
  the bag reader's :class:`~spaceid.data.MessageAligner` (the same mapping file: topics, joint
  names, latency, rate), fed to :class:`~spaceid.estimation.Monitor`; the estimate, the events
  and the payload out as :class:`LiveOutput` (JSON objects).
* :func:`run_monitor` runs it on rclpy subscriptions and publishes on :data:`ESTIMATE_TOPIC`,
  :data:`EVENTS_TOPIC` and :data:`PAYLOAD_TOPIC` (``std_msgs/String`` holding JSON: no standard
  message carries named parameters with standard errors).
* :func:`play_recording` publishes a :class:`~spaceid.data.Recording` in real time or faster;
  :func:`recording_of_log` and :func:`twin_recording` make one of a log or a twin run.

Modules: ``_rclpy`` (the client, lazily; quality of service, message types), ``_live`` (the
engine), ``_node`` (the nodes), ``_sources`` (what the player publishes).
"""

from . import _rclpy, _live, _node, _sources
from ._rclpy import *  # noqa: F403
from ._live import *  # noqa: F403
from ._node import *  # noqa: F403
from ._sources import *  # noqa: F403

__all__ = _rclpy.__all__ + _live.__all__ + _node.__all__ + _sources.__all__
