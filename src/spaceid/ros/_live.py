"""The live monitor's engine, without ROS: messages in (as a subscription receives them), the
messages to publish out. :func:`spaceid.ros.run_monitor` feeds it from rclpy subscriptions.

The messages that arrived together go to a :class:`~spaceid.data.MessageAligner` (the bag
reader's, with the same mapping: topics, joint names, latency, rate), aligned in one part once
``block`` seconds of joint states have come; each part to a :class:`~spaceid.estimation.Monitor`.
Each alarm is published the moment the test raises it, its event (the parameters that changed)
once the monitor completes it a warm-up later; after each part the running estimate; with a
``link``, the payload after each alarm, identified from the samples after it
(:func:`~spaceid.identified.payload_after_grasp`) and refined each time they double.
"""

from __future__ import annotations

import bisect
import collections
import math
import time
import warnings
from dataclasses import dataclass

import numpy as np

from .._errors import SpaceidError
from .._json import json_values
from .._threads import one_blas_thread
from ..data import Log, MessageAligner
from ..estimation import Z_CHANGED

__all__ = ["LIVE_BLOCK", "LIVE_CONTEXT", "LIVE_ORDER", "LiveMonitor", "LiveOutput"]

LIVE_BLOCK = 0.1
"""Fewest seconds of joint states the live monitor aligns at a time (:class:`~spaceid.data.MessageAligner`;
the messages that arrived together are aligned at once, however many): a sample reaches the monitor
at most this long after the message that completes it (half a differentiator window after it)."""
LIVE_CONTEXT = 2.0
"""Fewest seconds of messages aligned at a time, each part with those before it
(:class:`~spaceid.data.MessageAligner`'s ``context``): the differentiator's checks of the sampling
see a record this long (with ``LIVE_BLOCK``, each second of data is aligned about 20 times: the
price of the short wait; a larger ``block`` costs less)."""
LIVE_ORDER = 3
"""Savitzky-Golay degree of the live monitor's differentiators when the window is given and the
degree is not: a degree chosen part by part would change the rates' filter from part to part."""
ARRIVALS = 20_000
"""Most recent messages whose arrival is remembered, to time the alarms from."""
MAX_HELD = 50_000
"""Most messages held unaligned: more means the pose topic is silent (the joint states wait for it)."""
VALUES = ("values", "std", "drift", "drift_std")
"""The keys of an estimate that its message carries as they are (the rest of a warm-up's goes in ``warm_up``)."""
HISTORY = 6000
"""Most recent samples kept for the payload's identification."""


@dataclass(frozen=True)
class LiveOutput:
    """One message to publish.

    Attributes
    ----------
    kind : {"estimate", "event", "payload"}
        The topic it goes to (``/spaceid/estimate``, ``/spaceid/events``, ``/spaceid/payload``).
    data : dict
        Its JSON object (docs/tutorials and the live-monitoring page list the keys).
    """

    kind: str
    data: dict


def _stamp(msg) -> int:
    """A message's header stamp [ns]."""
    return msg.header.stamp.sec * 1_000_000_000 + msg.header.stamp.nanosec


def _load_kernels(param):
    """Evaluate the regressor and the momentum's Jacobian once, at rest: the compiled kernels are
    loaded (0.3 s of processor time in a new process) before the data come, not while the first
    warm-up is screened with the messages queueing (at ten times real time, over a second of poses
    on a loaded machine: more than the subscription holds)."""
    from ..dynamics import momentum_jacobian

    rest = np.zeros((1, len(param.model.joints)))
    param.regressor(rest, rest, np.zeros((1, 3)))
    momentum_jacobian(param, rest, rest, np.zeros((1, 3)), param.true_values)


def _concatenate(parts) -> Log:
    """One log of consecutive parts (the first part's ``meta``)."""
    first = parts[0]
    stack = lambda name: np.concatenate([getattr(p, name) for p in parts])  # noqa: E731
    return Log(stack("t"), first.joints, stack("q"), stack("qd"), stack("base_quat"), stack("base_w"),
               planar=first.planar, meta=dict(first.meta))


class LiveMonitor:
    """Change detection and identification on messages as they arrive.

    Parameters
    ----------
    param : Parameterization
        Minimal parameter set of the model.
    momentum : array_like of shape (3,)
        Inertial angular momentum [N m s], as for :class:`~spaceid.estimation.Monitor`.
    mapping : str, Path or dict, optional
        The bag mapping file (:func:`~spaceid.data.read_mapping`): topics, joint names,
        ``pose_latency``, ``rate``, ``max_gap``, ``max_tilt``.
    joint_topic, pose_topic : str, optional
        Override the mapping's topics.
    link : str, optional
        The link that grasps: the payload is identified after each change.
    block : float
        Fewest seconds of joint states aligned at a time (``LIVE_BLOCK``): what arrived together is
        aligned in one part.
    reading : dict, optional
        Further :func:`~spaceid.data.to_log` keywords (``joint_rates``, ``window``, ``quantum``).
    where : str
        Name of the source, for messages.
    clock : callable
        The clock [s] that the arrivals are given in and the publications timed by (``latency_s``):
        ``time.monotonic``; a benchmark may give a processor-time clock.
    **options
        Keywords of :class:`~spaceid.estimation.Monitor` (``known``, ``noise``, ``drift``, ...).
    """

    def __init__(self, param, momentum, *, mapping=None, joint_topic=None, pose_topic=None, link=None,
                 block=LIVE_BLOCK, reading=None, where="ros2", clock=time.monotonic, **options):
        from ..estimation import Monitor

        m = param.model
        self.param, self.link, self.where, self.clock = param, link, where, clock
        self.monitor = Monitor(param, momentum, where=where, on_alarm=self._alarmed, **options)
        reading = dict(reading or {})
        if reading.get("window") is not None and reading.get("order") is None:
            reading["order"] = LIVE_ORDER
        self.aligner = MessageAligner(where, joints=m.joints, planar=m.planar, wheels=m.wheels, mapping=mapping,
                                      joint_topic=joint_topic, pose_topic=pose_topic, block=block, kind="ros2-live",
                                      context=LIVE_CONTEXT, skip_gaps=True, **reading)  # fmt: skip
        self._pmap = None
        if link is not None:
            from ..identified import payload_map

            self._pmap = payload_map(m, link)
        self._recent = collections.deque()  # the latest parts, at most HISTORY samples
        self._n_recent, self._unchecked = 0, False  # their samples; whether a part came since the payload's check
        self._payload_event, self._payload_due = None, None  # the event whose payload is due, at how many samples
        self._payload_first = None  # samples after it of its first payload published
        self._undetermined_due = 0  # warm-up samples after the last alarm when to say what they leave undetermined
        self.n_messages, self.busy = 0, 0.0
        self._emit = None  # where the outputs go
        topics = (self.aligner.joint_topic, self.aligner.pose_topic)
        self._arrivals = {t: collections.deque(maxlen=ARRIVALS) for t in topics}  # (stamp [ns], arrival [s])
        self._origin = None  # the published times are seconds after this ROS time [ns]
        _load_kernels(param)


    def add(self, topic: str, msg, received: float | None = None) -> list:
        """Take one message of ``topic``; the :class:`LiveOutput` it completes (the estimate after
        each aligned part, the alarms and events), in order. ``received``: its arrival [s,
        ``clock``], from which each event's ``latency_s`` is counted (default now)."""
        return self.add_batch([(topic, msg, self.clock() if received is None else received)])

    def add_batch(self, messages, publish=None) -> list:
        """Take the messages ``(topic, msg, received)`` that arrived since the last call, in stamp
        order, and align them at once (one part, when ``block`` seconds of joint states have come
        since the last); the :class:`LiveOutput` they complete: the part's alarms and events, then
        the estimate. ``publish``: called with each output the moment it is made instead (an
        alarm as the test raises it, before the monitor identifies the segment it closes); then
        the list returned is empty."""
        start, outputs = time.perf_counter(), []
        self._emit = publish or outputs.append
        try:
            for topic, msg, received in messages:
                self.aligner.hold(topic, msg)
                self._arrivals[topic].append((_stamp(msg), received))
            self.n_messages += len(messages)
            if self.aligner.due or self.aligner.held > MAX_HELD:
                with one_blas_thread():  # small factorisations: BLAS threads only wait (on busy cores, 100 times longer)
                    part = self._align()
                    if part is not None:
                        self._take(part)
        finally:
            self._emit = None
        self.busy += time.perf_counter() - start
        return outputs

    def _align(self) -> Log | None:
        """The aligned part that the messages held complete, or None."""
        try:
            part = self.aligner.align()
        except SpaceidError as err:  # a block the differentiator refuses: retried with the next block's messages
            warnings.warn(f"{err}: the samples wait for the next block", stacklevel=3)
            part = None
        if part is None and self.aligner.held > MAX_HELD:
            raise SpaceidError(f"`pose_topic`: {self.aligner.held} messages wait for a base pose on "
                               f"'{self.aligner.pose_topic}': publish the base attitude there, or map its topic")
        return part

    def _take(self, part: Log):
        """Emit the alarms and events of one aligned part: each alarm as soon as the test raises it
        (``stage`` "detected"), each event once the segment after it has its warm-up identified
        (``stage`` "compared", with the changed parameters); then the running estimate."""
        self._origin = part.meta.get("time_origin_ns", self._origin)
        self._remember(part)
        for event in self.monitor.update(part):
            self._emit(self._stage(event, "compared", self._completed(event.detected_at)))
        self._undetermined()
        self._emit(LiveOutput("estimate", self.estimate()))

    def _undetermined(self):
        """While the last alarm's comparison waits for a warm-up that determines the estimate after
        it: what the warm-up's samples leave undetermined (``stage`` "undetermined", ``warm_up``:
        :meth:`~spaceid.estimation.Monitor.warm_up_estimate` without the values), at its first
        identification, then each time its samples double."""
        alarm, attempt = self.monitor.waiting, self.monitor.warm_up_estimate()
        if alarm is None or attempt is None or attempt["n_samples"] < self._undetermined_due:
            return
        self._undetermined_due = 2 * attempt["n_samples"]
        summary = {k: v for k, v in attempt.items() if k not in VALUES}
        change = self.monitor.partial_change() or {"changed": [], "parameters": []}
        self._emit(self._stage(alarm, "undetermined", self._completed(attempt["time"]), warm_up=summary,
                               changed=change["changed"], parameters=change["parameters"]))

    def _completed(self, t: float) -> float:
        """When the sample at ``t`` [s] could first be aligned: the arrival [s, ``clock``]
        of the first joint state that settles it (``settled`` later) or, if later, of the first
        pose at or after it; now when none came yet (the end of the run), NaN when forgotten."""
        due = {self.aligner.joint_topic: t + self.aligner.settled, self.aligner.pose_topic: t}
        found = []
        for topic, arrivals in self._arrivals.items():
            ns = self._origin + round(due[topic] * 1e9)
            if arrivals and arrivals[0][0] > ns:  # forgotten
                return math.nan
            k = bisect.bisect_left(arrivals, (ns, -math.inf))
            found.append(arrivals[k][1] if k < len(arrivals) else self.clock())
        return max(found)

    def _remember(self, part: Log):
        self._recent.append(part)
        self._n_recent += part.n_samples
        self._unchecked = True
        while self._n_recent - self._recent[0].n_samples >= HISTORY:
            self._n_recent -= self._recent.popleft().n_samples

    def _alarmed(self, alarm):
        """The monitor's alarm: its message at once; the payload after it is due from now on."""
        self._unchecked, self._undetermined_due = True, 0
        if self._pmap is not None:
            self._payload_event, self._payload_due, self._payload_first = alarm, 0, None
        self._emit(self._stage(alarm, "detected", self._completed(alarm.detected_at)))

    def _stage(self, event, stage: str, received: float, **extra) -> LiveOutput:
        """An alarm's or an event's message on ``/spaceid/events``."""
        data = {"stage": stage} | event.to_dict() | extra | {"time_origin_ns": self._origin,
                                                             "latency_s": self.clock() - received}
        return LiveOutput("event", json_values(data))

    def estimate(self) -> dict | None:
        """The running segment's estimate, published after each aligned part: ``time`` (the last
        sample taken [s]), ``time_origin_ns``, ``n_samples``, ``segment``, ``names``, ``status``
        and ``determined``; while the segment is tested (``status`` "testing", ``determined``
        true), ``values`` and ``std``, its recursive estimate (with drift terms, ``drift`` and
        ``drift_std``); while its warm-up waits for samples that determine it (``status``
        "warming up", ``determined`` false), those of the warm-up's last identification and
        ``warm_up``, what it found (:meth:`~spaceid.estimation.Monitor.warm_up_estimate` without
        the values; ``values``, ``std`` and ``warm_up`` None before the first). None before the
        first part."""
        if not self._recent:
            return None
        est = self.monitor.estimate()
        testing = est is not None
        if testing:
            shown = {k: v for k, v in est.items() if k in VALUES}
        else:
            attempt, shown = self.monitor.warm_up_estimate(), {"values": None, "std": None, "warm_up": None}
            if attempt is not None:
                shown |= {k: v for k, v in attempt.items() if k in VALUES}
                shown["warm_up"] = {k: v for k, v in attempt.items() if k not in VALUES}
        return json_values({"time": self._recent[-1].t[-1], "time_origin_ns": self._origin,
                       "n_samples": self.monitor.n_samples, "segment": len(self.monitor.segments),
                       "names": list(self.param.names), "status": "testing" if testing else "warming up",
                       "determined": testing} | shown)  # fmt: skip

    def payload(self) -> LiveOutput | None:
        """The payload after the last alarm, when due (None otherwise, or without ``link``):
        identified from the samples after it each quarter warm-up of them (``warmup / 4``) and
        published from the first whose mass stands out of its standard error (more than
        ``Z_CHANGED`` of them) and that the data do not contradict (its ``consistency``), at the
        latest at a warm-up of them (then whatever it is, or the
        error that refused them); then each time they double (while the history holds them).
        :meth:`payload_fit` and :meth:`payload_message`, run here one after the other."""
        fit = self.payload_fit()
        if fit is None:
            return None
        with one_blas_thread():  # small factorisations: BLAS threads only wait
            return self.payload_message(fit())

    def payload_fit(self):
        """The payload's identification due now (:meth:`payload`), as a callable that runs it
        without touching the engine (the samples are taken now), for a worker thread: its cost
        grows with the samples after the change (up to ``HISTORY``), and run in line it would hold
        back the tests of the parts that arrive meanwhile, and the next change's alarm. None when
        none is due; none is due either until its result is given to :meth:`payload_message`."""
        event = self._payload_event
        if event is None or not self._unchecked:  # no new samples: nothing new is due
            return None
        self._unchecked = False
        from ..identified import payload_after_grasp

        # after the change for certain: its `time` can be early, where the statistic climbed by chance
        # before it (docs/theory/monitor.md), and samples from before the grasp would bias the fit
        grasp = event.detected_at + event.lead
        if self._recent[0].t[0] >= grasp:  # the history no longer reaches back to the change
            self._payload_event = None
            return None
        after = sum(p.n_samples - int(np.searchsorted(p.t, grasp, side="right")) for p in self._recent)
        if after < max(self._payload_due, self.monitor.warmup // 4, 1):
            return None
        self._payload_due = math.inf  # until this one's result is in
        log, mon, pmap, link, where = _concatenate(list(self._recent)), self.monitor, self._pmap, self.link, self.where
        noise, drift, momentum = mon.noise, mon.drift, mon.momentum

        def fit():
            try:
                return event, grasp, after, payload_after_grasp(pmap, log, link, grasp, momentum, noise=noise,
                                                                drift=drift, where=where).estimate
            except SpaceidError as err:
                return event, grasp, after, err

        return fit

    def payload_message(self, done) -> LiveOutput | None:
        """The message of a payload identification's result ``done`` (what :meth:`payload_fit`'s
        callable returned), or None when it is not published (before the first whose mass stands
        out, :meth:`payload`); sets when the next is due."""
        event, grasp, after, res = done
        current, warmup = event is self._payload_event, self.monitor.warmup
        first = current and self._payload_first is None
        if current:
            self._payload_due = after + max(1, warmup // 4) if first else 2 * after  # retried until published
        if isinstance(res, SpaceidError):
            return None if first and after < warmup else \
                LiveOutput("payload", {"event": event.index, "time": grasp, "error": str(res)})
        data = {"event": event.index, "time": grasp, "time_origin_ns": self._origin, "n_samples": after,
                "names": list(res.names), "values": res.values, "std": res.std} | res.to_dict()
        standing_out = abs(data["mass"]) > Z_CHANGED * data["std"]["mass"]
        if first and after < warmup and (not standing_out or res.settings["consistency"]["contradicted"]):
            return None  # (a fit the data contradict waits for more samples too: its window is suspect)
        if current:
            self._payload_first, self._payload_due = after, 2 * after
        return LiveOutput("payload", json_values(data))

    def finish(self, publish=None):
        """The rest of the messages held, then the run's record: ``(outputs, record)``, the record a
        :class:`~spaceid.estimation.MonitorRecord` (EVENTS.json). The outputs (``publish`` as in
        :meth:`add_batch`): those of the rest, the events the end completes and the payload due.
        A tail too short to align is left out."""
        outputs = []
        self._emit = publish or outputs.append
        try:
            with one_blas_thread():  # small factorisations: BLAS threads only wait
                try:
                    part = self.aligner.flush()
                except SpaceidError:  # fewer messages than the differentiator needs: nothing to add
                    part = None
                if part is not None:
                    self._take(part)
                seen = len(self.monitor.events)
                record = self.monitor.finish()
                for event in record.events[seen:]:
                    self._emit(self._stage(event, "compared", self._completed(event.detected_at)))
                payload = self.payload()
                if payload is not None:
                    self._emit(payload)
        finally:
            self._emit = None
        return outputs, record

    def result(self, record):
        """The last identified segment's :class:`~spaceid.estimation.Identification` (RESULT.json), or None."""
        found = [s.identification for s in record.segments if s.identification is not None]
        return found[-1] if found else None

