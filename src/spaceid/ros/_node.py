"""The ROS 2 nodes: the live monitor (:func:`run_monitor`) and the player of a recording
(:func:`play_recording`) that ``spaceid ros play`` and ``spaceid ros twin`` run."""

from __future__ import annotations

import contextlib
import json
import math
import signal
import threading
import time

import numpy as np

from .._errors import SpaceidError
from .._threads import one_blas_thread
from ._live import LiveMonitor, _stamp as _stamp_ns
from ._rclpy import pose_class, qos, ros_context, string_message

__all__ = ["EVENTS_TOPIC", "ESTIMATE_TOPIC", "PAYLOAD_TOPIC", "run_monitor", "play_recording"]

ESTIMATE_TOPIC = "/spaceid/estimate"
"""The running estimate and its standard errors (``std_msgs/String``, JSON), after each aligned part."""
EVENTS_TOPIC = "/spaceid/events"
"""One message per detected change (``std_msgs/String``, JSON: the EVENTS.json event, plus
``time_origin_ns`` and ``latency_s``); transient local: a late subscriber gets the past ones."""
PAYLOAD_TOPIC = "/spaceid/payload"
"""The payload after a change, with ``link`` (``std_msgs/String``, JSON: PAYLOAD.json plus ``event``,
``time``, ``names``, ``values``, ``std``)."""
SPIN = 0.05
"""Longest wait for a message [s] between checks for the end of the run."""


def run_monitor(live: LiveMonitor, *, pose_type: str = "pose", node_name: str = "spaceid_monitor",
                on_output=None, until=None):
    """Run ``live`` on its topics until Ctrl-C (KeyboardInterrupt) or ``until()`` is true; returns
    ``live.finish()`` (the outputs of the rest, published too, and the run's record).

    Parameters
    ----------
    live : LiveMonitor
        The engine; its aligner names the joint and pose topics.
    pose_type : {"pose", "odometry", "imu"}
        Message type of the base attitude topic (:data:`~spaceid.ros.POSE_TYPES`).
    node_name : str
        Name of the ROS node.
    on_output : callable, optional
        Called with each :class:`~spaceid.ros.LiveOutput` after it is published.
    until : callable, optional
        Polled every ``SPIN`` s: the run ends when it returns True.
    """
    from sensor_msgs.msg import JointState
    from std_msgs.msg import String

    cls = pose_class(pose_type)
    if pose_type == "pose" and live.aligner.base_rate == "gyro":
        raise SpaceidError(f"`pose_type` pose: a geometry_msgs/PoseStamped on '{live.aligner.pose_topic}' carries no "
                           "angular velocity, and the base rate is to be the gyro's (base_rate gyro): subscribe to "
                           "the odometry or IMU topic (`pose_type` odometry or imu), or take the rate from the attitude")
    show = on_output or (lambda out: None)
    with ros_context() as context:
        from rclpy.executors import SingleThreadedExecutor
        from rclpy.node import Node

        node = Node(node_name, context=context)
        pubs = {kind: node.create_publisher(String, topic, qos(latched=kind != "estimate"))
                for kind, topic in (("estimate", ESTIMATE_TOPIC), ("event", EVENTS_TOPIC), ("payload", PAYLOAD_TOPIC))}
        inbox = []
        jt, pt = live.aligner.joint_topic, live.aligner.pose_topic
        # the messages as they come: the aligner reads a pose, an odometry or an IMU message by its fields
        subs = [(node.create_subscription(kind, topic, lambda m, info, topic=topic: inbox.append(
            (topic, m, _arrival(info))), qos()), topic) for kind, topic in ((JointState, jt), (cls, pt))]
        executor = SingleThreadedExecutor(context=context)
        executor.add_node(node)

        def publish(out):
            pubs[out.kind].publish(string_message(json.dumps(out.data, allow_nan=False, default=_null)))
            show(out)

        # BLAS on one thread all along (small factorisations), the payload's on the worker too
        with _interrupt_flag() as interrupted, one_blas_thread(), _Worker() as worker:
            while not interrupted() and (until is None or not until()):
                executor.spin_once(timeout_sec=SPIN)  # waits for a message; its callback puts it in the inbox
                inbox += _take_all(subs)
                while inbox and not interrupted():  # everything queued in one batch: one estimate, one payload check
                    batch, inbox[:] = sorted(inbox, key=lambda x: _stamp_ns(x[1])), []
                    live.add_batch(batch, publish)
                    worker.payload(live, publish)
                    inbox += _take_all(subs)  # what arrived meanwhile
                worker.payload(live, publish)
            worker.payload(live, publish, wait=True)
        outputs, record = live.finish(publish)
        executor.shutdown(timeout_sec=1.0)
        node.destroy_node()
    return outputs, record


class _Worker:
    """The payload's identifications on a thread of their own (:meth:`~spaceid.ros.LiveMonitor.payload_fit`),
    each published when it is ready: in line, one on thousands of samples would hold back the tests
    of the parts that arrive meanwhile (and a change's alarm) for its whole length; beside them, it
    shares the interpreter with them (the main thread gets it back within the switch interval)."""

    def __enter__(self):
        from concurrent.futures import ThreadPoolExecutor

        self.pool, self.running = ThreadPoolExecutor(max_workers=1, thread_name_prefix="spaceid-payload"), None
        return self

    def payload(self, live, publish, wait: bool = False):
        """Publish the identification that finished (with ``wait``, wait for the one running) and
        start the next one due."""
        if self.running is not None and (wait or self.running.done()):
            out = live.payload_message(self.running.result())
            self.running = None
            if out is not None:
                publish(out)
        if self.running is None and not wait:
            fit = live.payload_fit()
            self.running = None if fit is None else self.pool.submit(fit)

    def __exit__(self, *exc):
        self.pool.shutdown(wait=True, cancel_futures=True)


def _take_all(subscriptions) -> list:
    """Every message the ``subscriptions`` ``(subscription, topic)`` hold, as
    ``(topic, message, arrival [s])``: taken from each at once (rclpy's take, as its executor takes
    them), without the executor's round per message (a wait set built and waited on, 0.3 to 0.5 ms
    of processor time each: at ten times real time, 1,500 messages a second, as much as the
    monitor's own work)."""
    taken = []
    for sub, topic in subscriptions:
        while True:
            with sub.handle:
                got = sub.handle.take_message(sub.msg_type, sub.raw)
            if got is None:
                break
            taken.append((topic, got[0], _arrival(got[1])))
    return taken


def _arrival(info) -> float:
    """When a message reached this process [s, ``time.monotonic``]: the middleware's reception
    time (``received_timestamp`` of its message info, system clock [ns]), not the later moment it
    was taken while the node was busy, so that the latencies count the wait in the subscription's
    queue; the moment it is taken when the middleware does not give it."""
    now, received = time.monotonic(), info.get("received_timestamp") or 0
    return now if received <= 0 else now - max(time.time_ns() - received, 0) / 1e9


@contextlib.contextmanager
def _interrupt_flag():
    """Within it, Ctrl-C (SIGINT) sets a flag (the callable yielded says whether it came) instead of
    raising KeyboardInterrupt: raised inside rclpy's executor, the exception could leave a handle
    held, and destroying the node then waited for it forever. Outside the main thread: no handler."""
    came = threading.Event()
    if threading.current_thread() is not threading.main_thread():
        yield came.is_set
        return
    previous = signal.signal(signal.SIGINT, lambda signum, frame: came.set())
    try:
        yield came.is_set
    finally:
        signal.signal(signal.SIGINT, previous)


def _null(value):
    """JSON of what json cannot write (NaN is refused before this)."""
    raise TypeError(f"not JSON serialisable: {type(value).__name__}")


def play_recording(recording, *, joint_topic: str, pose_topic: str, rate_factor: float = 1.0,
                   subscribers: int = 1, wait: float = 30.0, node_name: str = "spaceid_play", progress=None) -> int:
    """Publish a recording's joint states (``sensor_msgs/JointState``) and base poses
    (``geometry_msgs/PoseStamped``; ``nav_msgs/Odometry`` when they hold a measured rate, a gyro's, as its
    twist's angular velocity) on the loopback or the network, in stamp order, paced by their
    stamps divided by ``rate_factor`` (math.inf: as fast as the middleware takes them).

    Parameters
    ----------
    recording : Recording
        What to publish; its stamps [s] (plus ``meta["time_origin_ns"]``) are the header stamps.
    joint_topic, pose_topic : str
        The topics.
    rate_factor : float
        Speed-up over real time (> 0).
    subscribers : int
        Matched subscriptions on each topic to wait for before the first message (0: none).
    wait : float
        Longest wait for them [s].
    node_name : str
        Name of the ROS node.
    progress : callable, optional
        Called with the number of messages published, every second of wall time.

    Returns
    -------
    int
        Messages published.
    """
    if not (rate_factor > 0):
        raise SpaceidError(f"`rate_factor`: {rate_factor!r}: give a speed-up > 0 (1: real time)")
    from sensor_msgs.msg import JointState

    PoseType = pose_class("pose" if recording.base.rate is None else "odometry")
    origin = int(recording.meta.get("time_origin_ns", 0) or 0)
    with ros_context() as context:
        from rclpy.node import Node

        node = Node(node_name, context=context)
        jpub = node.create_publisher(JointState, joint_topic, qos())
        ppub = node.create_publisher(PoseType, pose_topic, qos())
        _wait_for_subscribers(node, context, (jpub, ppub), subscribers, wait)
        messages = _messages(recording, origin, JointState, PoseType)
        start, t0, last_report, sent = time.monotonic(), None, time.monotonic(), 0
        try:
            for t, is_joint, msg in messages:
                t0 = t if t0 is None else t0
                if math.isfinite(rate_factor):
                    delay = start + (t - t0) / rate_factor - time.monotonic()
                    if delay > 0:
                        time.sleep(delay)
                (jpub if is_joint else ppub).publish(msg)
                sent += 1
                if progress is not None and time.monotonic() - last_report > 1.0:
                    last_report = time.monotonic()
                    progress(sent)
            _drain(node, (jpub, ppub))
        finally:
            node.destroy_node()
    return sent


def _wait_for_subscribers(node, context, publishers, count, wait):
    """Wait until each publisher has ``count`` matched subscriptions, at most ``wait`` s."""
    deadline = time.monotonic() + wait
    while any(p.get_subscription_count() < count for p in publishers):
        if time.monotonic() > deadline:
            raise SpaceidError(f"`subscribers`: no {count} subscriber(s) on {', '.join(p.topic_name for p in publishers)}"
                               f" after {wait:g} s: start the monitor first, or give 0 to publish anyway")
        time.sleep(0.05)


def _drain(node, publishers, most=10.0):
    """Wait until the reliable publishers' messages are acknowledged (at most ``most`` s)."""
    for pub in publishers:
        try:
            pub.wait_for_all_acked(timeout=_duration(most))
        except Exception:  # noqa: BLE001  (not every middleware implements it; then a short pause)
            time.sleep(0.5)


def _duration(seconds):
    from rclpy.duration import Duration

    return Duration(seconds=seconds)


def _messages(recording, origin, JointState, PoseType):
    """The recording's messages as ``(t, is_joint, message)`` in stamp order (joints first at equal stamps)."""
    js, base = recording.joints, recording.base
    rows = [(float(t), True, i) for i, t in enumerate(js.t)] + [(float(t), False, i) for i, t in enumerate(base.t)]
    rows.sort(key=lambda r: (r[0], not r[1]))
    for t, is_joint, i in rows:
        yield t, is_joint, (_joint_message(JointState, js, i, origin) if is_joint
                            else _pose_message(PoseType, base, i, origin))  # fmt: skip


def _stamp(header, t, origin):
    ns = origin + int(round(t * 1e9))
    header.stamp.sec, header.stamp.nanosec = ns // 1_000_000_000, ns % 1_000_000_000


def _joint_message(JointState, js, i, origin):
    msg = JointState()
    _stamp(msg.header, js.t[i], origin)
    present = np.isfinite(js.position[i])  # a NaN position: that joint is not in this message
    msg.name = [n for n, p in zip(js.names, present) if p]
    msg.position = js.position[i][present].tolist()
    for field in ("velocity", "effort"):
        values = getattr(js, field)
        if values is not None and np.isfinite(values[i][present]).all():
            setattr(msg, field, values[i][present].tolist())
    return msg


def _pose_message(PoseType, base, i, origin):
    """A PoseStamped of pose ``i``, or an Odometry (``PoseType``) with its measured rate."""
    msg = PoseType()
    _stamp(msg.header, base.t[i], origin)
    msg.header.frame_id = base.frame
    pose = msg.pose if base.rate is None else msg.pose.pose
    p, q = base.position[i], base.quat[i]
    pose.position.x, pose.position.y, pose.position.z = (float(v) for v in p)
    o = pose.orientation
    o.w, o.x, o.y, o.z = (float(v) for v in q)  # spaceid [w, x, y, z] -> ROS fields
    if base.rate is not None:
        msg.child_frame_id = "base"
        w = msg.twist.twist.angular
        w.x, w.y, w.z = (float(v) for v in base.rate[i])
    return msg
