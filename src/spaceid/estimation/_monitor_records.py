"""What the monitor reports (docs/formats/events-json.md): its events, and the alarms that wait
for the segment after them to be compared with the one before."""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field

from ._result import Identification, compare

Z_CHANGED = 3.0
"""A parameter changed when its z-score (change / combined standard error) exceeds this in magnitude."""


@dataclass(frozen=True)
class MonitorEvent:
    """A detected change.

    Attributes
    ----------
    index : int
        Events in order, from 0.
    time : float
        Estimated change time [s]: the sample within the CUSUM's last excursion from which on
        the innovations are most likely inflated (:meth:`~spaceid.estimation._monitor_cusum.Cusum.change_time`).
    detected_at : float
        Time of the sample at which the statistic crossed the threshold [s].
    delay : int
        Samples from the estimated change to the detection.
    statistic, threshold : float
        CUSUM statistic at the detection and its threshold (log-likelihood ratio).
    changed : tuple of str
        Parameters whose change has a z-score above ``Z_CHANGED`` in magnitude.
    parameters : tuple of dict
        Per parameter ``name``, ``before``, ``after``, ``change``, ``relative_change``, ``z``:
        the segment before against the new segment's warm-up, both identified in batch.
    lead : float
        How much earlier than the change ``time`` can be [s]: half the differentiator's window
        when the rates were differentiated (a centred window shows a change in the smoothed rates
        up to that long before it), else 0. The change lies between ``time`` and ``time + lead``.
    """

    index: int
    time: float
    detected_at: float
    delay: int
    statistic: float
    threshold: float
    changed: tuple
    parameters: tuple = field(repr=False)
    lead: float = 0.0

    def to_dict(self) -> dict:
        return dataclasses.asdict(self) | {"changed": list(self.changed), "parameters": list(self.parameters)}


@dataclass(frozen=True)
class Alarm:
    """An alarm whose event waits for the comparison of the segments on either side of it: the
    fields of :class:`MonitorEvent` but ``changed`` and ``parameters``."""

    index: int
    time: float
    detected_at: float
    delay: int
    statistic: float
    threshold: float
    lead: float

    def event(self, before: Identification | None, after: Identification | None, where: str) -> MonitorEvent:
        """The event, with the change from ``before`` to ``after`` (none when either is missing:
        a segment too short to identify)."""
        res = [] if before is None or after is None else compare(before, after, where=where)["parameters"]
        changed = tuple(p["name"] for p in res if abs(p["z"]) > Z_CHANGED)
        return MonitorEvent(**dataclasses.asdict(self), changed=changed, parameters=tuple(res))
