"""ROS bags for the log readers: whether a path is a bag, and a bag read straight into a log.

:func:`~spaceid.data.read_log` dispatches here on :func:`is_bag`; :func:`read_bag_log` chains the
reader (:func:`~spaceid.data.read_recording`, :func:`~spaceid.data.read_mapping`) and the
conversion (:func:`~spaceid.data.to_log`). The bag layout is described in
:mod:`spaceid.data._bag_format`.
"""

from __future__ import annotations

from pathlib import Path

from ._bag_format import _BAG_SUFFIXES, DEFAULT_JOINT_TOPIC, DEFAULT_POSE_TOPIC
from ._bag_read import read_mapping, read_recording
from ._bag_to_log import to_log
from ._timeseries import Log

__all__ = ["is_bag", "read_bag_log"]


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
