"""ROS bags for the log readers: whether a path is a bag, and a bag read straight into a log.

:func:`~spaceid.data.read_log` dispatches here on :func:`is_bag`; :func:`read_bag_log` chains the
reader (:func:`~spaceid.data.read_recording`, :func:`~spaceid.data.read_mapping`) and the
conversion (:func:`~spaceid.data.to_log`). The bag layout is described in
:mod:`spaceid.data._bag_format`.
"""

from __future__ import annotations

import warnings
from pathlib import Path

import numpy as np

from .._errors import SpaceidError
from ._bag_format import _BAG_SUFFIXES, _NS, DEFAULT_JOINT_TOPIC, DEFAULT_POSE_TOPIC
from ._bag_read import _bag_messages, _recording, _stamp, _converted, read_mapping, read_recording
from ._bag_to_log import MAX_GAP, to_log
from ._timeseries import Log

__all__ = ["is_bag", "read_bag_log", "bag_chunks", "MessageAligner"]

BLOCK = 10.0
"""Seconds of joint states that :func:`bag_chunks` aligns at a time."""
FIRST_BLOCK = 1.0
"""Fewest seconds of joint states in the first part: its differentiators' windows must fit in it
(a live monitor aligns blocks of a tenth of a second)."""


def is_bag(path) -> bool:
    """Whether ``path`` names a bag: a ``.bag``, ``.mcap`` or ``.db3`` name (existing or not),
    or a folder with ``metadata.yaml`` (a ROS 2 bag)."""
    path = Path(path)
    return path.suffix.lower() in _BAG_SUFFIXES or (path / "metadata.yaml").is_file()


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
    topics, keywords = _bag_settings(mapping, joint_topic, pose_topic, options)
    log = to_log(read_recording(path, **topics), joints=joints, planar=planar, wheels=wheels, **keywords)
    if isinstance(mapping, (str, Path)):
        log.meta["mapping"] = str(mapping)
    return log


def _bag_settings(mapping, joint_topic, pose_topic, options) -> tuple:
    """``(topics, keywords)``: the topics and renaming of :func:`read_recording` and the
    :func:`to_log` keywords of a mapping (file or dict), the topics given and further options."""
    settings = read_mapping(mapping) if isinstance(mapping, (str, Path)) else dict(mapping or {})
    topics = {"joint_topic": joint_topic or settings.get("joint_topic", DEFAULT_JOINT_TOPIC),
              "pose_topic": pose_topic or settings.get("pose_topic", DEFAULT_POSE_TOPIC),
              "rename": settings.get("joints")}  # fmt: skip
    keywords = {k: settings[k] for k in ("rate", "pose_latency", "max_gap", "max_tilt", "base_rate") if k in settings}
    return topics, keywords | {k: v for k, v in options.items() if v is not None}


def bag_chunks(path, *, joints, planar, wheels=(), mapping=None, joint_topic=None, pose_topic=None, block=BLOCK,
               **options):
    """Yield the log of a bag in parts as its messages are read: bounded memory, samples early.

    The messages are read one at a time and handed to a :class:`MessageAligner`: each time
    ``block`` seconds of joint states have gathered, the messages held are aligned and
    differentiated as :func:`read_bag_log` does a whole bag, and the samples that no later message
    can change are yielded: those more than half the widest differentiator window (plus one
    joint-state step) before the last stamp held. The messages that the next part's differentiator
    still needs (that half window again, before the first sample not yet yielded) are kept, the
    rest dropped, so memory holds about ``block`` plus one differentiator window of messages
    however long the bag. The rest is yielded at the end.

    Each part's differentiator chooses its window from its own samples, so the smoothed angles and
    the rates can differ from those of a whole-bag read by about their noise; the stamps are the same.

    Parameters
    ----------
    path, joints, planar, wheels, mapping, joint_topic, pose_topic, **options
        As :func:`read_bag_log`.
    block : float
        Seconds of joint states [s] aligned at a time (default ``BLOCK``); at least 4
        differentiator windows make the windows of the parts those of the whole.

    Yields
    ------
    Log
        Consecutive samples (stamps increasing strictly across yields, after one time origin:
        ``meta["time_origin_ns"]``), each part's ``meta`` as :func:`to_log` records it.

    Raises
    ------
    SpaceidError
        As :func:`read_bag_log`; ``block`` not a positive number of seconds.
    """
    path = Path(path)
    aligner = MessageAligner(path, joints=joints, planar=planar, wheels=wheels, mapping=mapping,
                             joint_topic=joint_topic, pose_topic=pose_topic, block=block, **options)
    with _bag_messages(path, aligner.joint_topic, aligner.pose_topic) as (messages, publishers):
        aligner.publishers = publishers
        for topic, msg in messages:
            part = aligner.add(topic, msg)
            if part is not None:
                yield part
        part = aligner.flush()
        if part is not None:
            yield part


class MessageAligner:
    """Joint-state and pose messages in, aligned log parts out, in bounded memory: the engine of
    :func:`bag_chunks`, fed by a bag or, message by message, by a live ROS 2 subscription.

    :meth:`add` holds each message; once ``block`` seconds of joint states have gathered (and a
    pose), the messages held are aligned and differentiated (:func:`to_log`) and the samples that
    no later message can change are returned; the messages the next part's differentiator still
    needs are kept, the rest dropped (:func:`bag_chunks` describes the parts). :meth:`flush`
    returns the rest. The parts of :meth:`align` say so in their ``meta`` (``"final_rates":
    True``: a monitor takes their samples at once); each message is converted once, however many
    parts' context it is aligned in.

    Parameters
    ----------
    source : str or Path
        The bag, or a name of the live source (a name without a bag suffix); the messages' ``where``.
    joints, planar, wheels, mapping, joint_topic, pose_topic, **options
        As :func:`read_bag_log`.
    block : float
        Seconds of joint states [s] aligned at a time.
    kind : str, optional
        The ``format`` recorded in each part's ``meta`` (default: the bag's, from ``source``).
    context : float
        Fewest seconds of messages aligned at a time: each part with those before it (at least the
        left half differentiator window): parts of a tenth of a second are too short for the
        differentiator's checks of the sampling (a joint that barely moves in them reads as
        quantised); with a fixed window and degree the samples are the same.
    skip_gaps : bool
        A live source: messages lost for longer than ``max_gap`` (a step between two held stamps of
        either topic) are warned about and the messages before the gap dropped, so that the parts
        after it align (the first half differentiator window after it is not returned: one-sided
        rates, as at the start); else the gap is an error, as :func:`read_bag_log`'s.

    Attributes
    ----------
    joint_topic, pose_topic : str
        The topics, from the mapping or the defaults.
    publishers : int
        Publishers of the joint topic (recorded in the parts' ``meta``).
    held : int
        Messages held now.
    settled : float
        How long [s] before the last joint stamp the last part ended: a sample is returned once a
        joint state this much later is held (half the widest differentiator window plus a step).

    The messages are ``sensor_msgs/JointState`` and ``geometry_msgs/PoseStamped`` as rosbags
    deserialises them or rclpy receives them (any object with their fields).
    """

    def __init__(self, source, *, joints, planar, wheels=(), mapping=None, joint_topic=None, pose_topic=None,
                 block=BLOCK, kind=None, context=0.0, skip_gaps=False, **options):
        if not (isinstance(block, (int, float)) and np.isfinite(block) and block > 0):
            raise SpaceidError(f"`block`: {block!r} is not a positive number: give the seconds of messages aligned "
                               "at a time")
        self.source, self.block, self.kind, self.context = Path(source), float(block), kind, float(context)
        self._topics, self._keywords = _bag_settings(mapping, joint_topic, pose_topic, options)
        self.joint_topic, self.pose_topic = self._topics["joint_topic"], self._topics["pose_topic"]
        self._model = {"joints": joints, "planar": planar, "wheels": wheels}
        self.publishers = 1
        self._held = {self.joint_topic: [], self.pose_topic: []}
        self._done, self._origin, self._due = -np.inf, None, None
        self._last_quat = None  # the last sample's attitude returned
        self.settled = 0.0
        self.skip_gaps, self._resumed = bool(skip_gaps), False  # a gap skipped, no sample returned after it yet
        self._checked = {t: 0 for t in self._held}  # messages held whose steps were checked for a gap

    @property
    def base_rate(self) -> str:
        """Where the parts' base rate comes from (:func:`to_log`'s ``base_rate``: the options', else the mapping's)."""
        return self._keywords.get("base_rate", "attitude")

    @property
    def held(self) -> int:
        return sum(len(msgs) for msgs in self._held.values())

    def add(self, topic: str, msg) -> Log | None:
        """Hold one message of ``topic``; the log of the samples it completes, or None."""
        self.hold(topic, msg)
        return self.align()

    def hold(self, topic: str, msg):
        """Hold one message of ``topic`` without aligning (:meth:`align` aligns what is held)."""
        self._held[topic].append(msg)
        if self._due is None and topic == self.joint_topic:
            self._due = _stamp(msg) + int(max(self.block, FIRST_BLOCK) * 1e9)

    @property
    def due(self) -> bool:
        """Whether :meth:`align` would align a part now: ``block`` seconds of joint states (and a
        pose) have come since the last."""
        joint_msgs, pose_msgs = self._held.values()
        return bool(pose_msgs and len(joint_msgs) > 1 and self._due is not None and _stamp(joint_msgs[-1]) > self._due)

    def align(self) -> Log | None:
        """The log of the samples that the messages held complete, once ``block`` seconds of joint
        states have come since the last part (else None): a live node holds what arrived at once
        and aligns it in one part."""
        if not self.due:
            return None
        joint_msgs, pose_msgs = self._held.values()
        self._due = _stamp(joint_msgs[-1]) + int(self.block * 1e9)  # the next part: ``block`` more seconds
        if self._origin is None:
            self._origin = min(_stamp(joint_msgs[0]), _stamp(pose_msgs[0])) // _NS * _NS
        if self.skip_gaps:
            self._skip_gap()
            joint_msgs, pose_msgs = self._held.values()
        log = self._log(joint_msgs, pose_msgs)
        half = _settled(log)
        log.meta["final_rates"] = True  # no later message changes these samples: a monitor need not hold them back
        first = log.t[0] + half if self._resumed else -np.inf  # after a gap: its first half window left out
        part = self._continued(log.select((log.t > self._done) & (log.t >= first) & (log.t <= log.t[-1] - half)))
        self._resumed &= not part.n_samples
        self.settled = half
        if part.n_samples:
            self._done = float(part.t[-1])
        if self._done > -np.inf:  # else no sample yet (the poses began within half a window of the end): all kept
            # the left half window of the next part's first sample; records of ``context`` seconds for the checks
            keep = self._origin + int((self._done - max(half, self.context - self.block)) * 1e9)
            self._held = {t: [m for m in msgs if m.stamp >= keep] for t, msgs in self._held.items()}  # converted by _log
        self._checked = {t: len(msgs) for t, msgs in self._held.items()}
        return part if part.n_samples else None

    def _skip_gap(self):
        """Drop the messages held before the last step longer than ``max_gap`` in either topic
        (messages lost), with a warning: the samples after it align on their own."""
        max_gap = self._keywords.get("max_gap", MAX_GAP)
        cut, found = None, None
        for topic, msgs in self._held.items():  # the steps to and between the messages that came since
            stamps = np.array([_stamp(m) for m in msgs[max(self._checked[topic] - 1, 0) :]], dtype=np.int64)
            steps = np.flatnonzero(np.diff(stamps) > max_gap * 1e9)
            if steps.size and (cut is None or stamps[steps[-1] + 1] > cut):
                cut, found = int(stamps[steps[-1] + 1]), (topic, stamps[steps[-1]], stamps[steps[-1] + 1])
        if cut is None:
            return
        topic, before, after = found
        warnings.warn(f"{self.source}: {topic}: no message for {(after - before) / 1e9:.3g} s (from "
                      f"{(before - self._origin) / 1e9:.6g} s), longer than max_gap = {max_gap:g} s: the samples "
                      f"before it are left out, the monitor goes on from {(after - self._origin) / 1e9:.6g} s",
                      stacklevel=4)
        self._held = {t: [m for m in msgs if _stamp(m) >= cut] for t, msgs in self._held.items()}
        self._resumed, self._checked = True, {t: 0 for t in self._held}

    def flush(self) -> Log | None:
        """The samples not yet returned, from the messages held (origin None: fewer than one block)."""
        log = self._log(*self._held.values())
        part = self._continued(log.select(log.t > self._done))
        return part if part.n_samples else None

    def _continued(self, part: Log) -> Log:
        """``part`` with its attitude quaternions' sign continued from the last part's (each part's
        conversion starts its sign-continuous quaternion afresh: ``q`` and ``-q`` are one attitude),
        so that the parts of any block are those of the whole."""
        if part.n_samples:
            if self._last_quat is not None and part.base_quat[0] @ self._last_quat < 0:
                part.base_quat[...] *= -1.0  # the part's own copy
            self._last_quat = part.base_quat[-1].copy()
        return part

    def _log(self, joint_msgs, pose_msgs) -> Log:
        # each message converted once, though the parts' context aligns it again and again
        _converted(joint_msgs, True, f"{self.source}: {self.joint_topic}")
        _converted(pose_msgs, False, f"{self.source}: {self.pose_topic}")
        recording = _recording(self.source, joint_msgs, pose_msgs, self.publishers, **self._topics,
                               time_origin_ns=self._origin)
        if self.kind is not None:
            recording.meta["format"] = self.kind
        return to_log(recording, **self._model, **self._keywords)


def _settled(log: Log) -> float:
    """How long [s] before its last stamp the samples of ``log`` stop depending on messages to
    come: half the widest differentiator window it records, plus one sample step."""
    record = log.meta["differentiation"]
    infos = ([record["base"]] if "base" in record else []) + list((record["joints"] or {}).values())  # base: measured
    spans = [w for info in infos for w in (info.get("window_s") or [])]
    step = float(np.median(np.diff(log.t))) if log.n_samples > 1 else 0.0
    return max(spans, default=0.0) / 2 + step
