"""What the monitor reports (docs/formats/events-json.md): its events, the alarms that wait for
the segment after them to be compared with the one before, its closed segments and the record
of a run (EVENTS.json), which draws itself."""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field

import numpy as np

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
        up to that long before it), else 0. The change most often lies between ``time`` and ``time + lead``,
        and always before ``detected_at + lead``; when the statistic had climbed by chance before the change,
        ``time`` is that climb's start (docs/theory/monitor.md).
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

    def to_dict(self) -> dict:
        return dataclasses.asdict(self)

    def event(self, before: Identification | None, after: Identification | None, where: str) -> MonitorEvent:
        """The event, with the change from ``before`` to ``after`` (none when either is missing:
        a segment too short to identify)."""
        res = [] if before is None or after is None else compare(before, after, where=where).to_dict()["parameters"]
        changed = tuple(p["name"] for p in res if abs(p["z"]) > Z_CHANGED)
        return MonitorEvent(**dataclasses.asdict(self), changed=changed, parameters=tuple(res))


@dataclass(frozen=True, eq=False)
class SegmentRecord:
    """A closed segment: the samples between two changes (or the log's ends).

    Attributes
    ----------
    index : int
        Segments in order, from 0.
    start : float or None
        Its first sample's time, or the estimated change that opened it [s]; None when no sample came.
    end : float or None
        The estimated change that closed it [s]; None for the last segment.
    n_samples : int
        Samples it took.
    n_identified : int
        Samples its batch identification used (evenly thinned beyond ``max_segment``).
    identification : Identification or None
        Its batch identification; None when too short to identify or not excited.
    recursive : dict or None
        The recursive estimate at its end (:meth:`~spaceid.estimation.Monitor.estimate`); None
        when its test never began, or its warm-up's own test found a change.
    prewhitening : dict or None
        How its innovations were whitened (docs/formats/events-json.md); None when it never
        finished its warm-up.
    warm_up : dict or None
        Its warm-up: its samples, how well they determined the estimate and the first of them
        tested (docs/formats/events-json.md); None when it never finished it.
    momentum : numpy.ndarray of shape (3,)
        The momentum at its origin [N m s].
    momentum_from : float or None
        The origin's time [s].
    """

    index: int
    start: float | None
    end: float | None
    n_samples: int
    n_identified: int
    identification: Identification | None
    recursive: dict | None
    prewhitening: dict | None
    momentum: np.ndarray
    momentum_from: float | None
    warm_up: dict | None = None

    def to_dict(self, names) -> dict:
        """The JSON-ready form (an entry of EVENTS.json's ``segments``), ``names`` the parameters'."""
        ident, rec = self.identification, self.recursive
        keys = ("index", "start", "end", "n_samples", "n_identified", "warm_up", "prewhitening")
        return {k: getattr(self, k) for k in keys} | {
            "momentum": self.momentum.tolist(), "momentum_from": self.momentum_from,
            "parameters": None if ident is None else [
                {"name": n, "value": float(v), "std": float(e)} for n, v, e in zip(names, ident.values, ident.std)],
            "drift": None if ident is None else [dict(d) for d in ident.drift],
            "chi2_dof": None if ident is None else ident.diagnostics.chi2_dof,
            "recursive": None if rec is None else {k: v.tolist() for k, v in rec.items()},
        }


@dataclass(frozen=True, eq=False)
class MonitorRecord:
    """The record of a monitor's run: its events and segments (compare two by their :meth:`to_dict`).

    Attributes
    ----------
    model : str
        The model source (preset name or path).
    planar : bool
        Whether the equations were planar (one row a sample) or spatial (three).
    momentum : numpy.ndarray of shape (3,)
        The momentum given [N m s] (with drift terms, at the log's first sample).
    n_samples, n_tested : int
        Samples read, and tested.
    settings : dict
        How the test was run (EVENTS.json's ``settings``: the threshold, the noise levels, the
        ``parameter_names``, ...).
    events : tuple of MonitorEvent
        The detected changes, in order.
    segments : tuple of SegmentRecord
        The segments between them, in order; one more than the events once the run is finished.
    whole_segment_changes : tuple of dict or None
        Per event, the change between the whole segments on either side (``changed`` and
        ``parameters`` as in :class:`MonitorEvent`); None until both are closed and identified.
    last_time : float or None
        The last sample taken [s] (None before the first): where the last segment ends. Not in
        EVENTS.json.
    statistic : tuple of two numpy.ndarray or None
        ``(t, g)``, shape (m,) each: the CUSUM statistic over the run, at most 4000 points (each the
        largest of its run of samples; :class:`~spaceid.estimation._monitor_cusum.StatisticTrace`),
        for the report's figure. Not in EVENTS.json.
    """

    model: str
    planar: bool
    momentum: np.ndarray
    n_samples: int
    n_tested: int
    settings: dict
    events: tuple
    segments: tuple
    whole_segment_changes: tuple
    last_time: float | None = None
    statistic: tuple | None = None

    def to_dict(self) -> dict:
        """The JSON-ready record, EVENTS.json (docs/formats/events-json.md)."""
        names = self.settings["parameter_names"]
        return {"model": self.model, "planar": self.planar, "momentum": self.momentum.tolist(),
                "n_samples": self.n_samples, "n_tested": self.n_tested, "settings": self.settings,
                "events": [e.to_dict() | {"segments": c} for e, c in zip(self.events, self.whole_segment_changes)],
                "segments": [s.to_dict(names) for s in self.segments]}  # fmt: skip

    def plot(self, ax=None):
        """Each identified segment's parameters against the first one's, in combined standard errors
        (symmetric log scale, ``Z_CHANGED`` shaded), over its time span, with each change's
        estimated time (dashed; its ``lead`` shaded) and detection (dotted) marked.

        Parameters
        ----------
        ax : matplotlib.axes.Axes, optional
            The axes to draw into; a new figure's when None.

        Returns
        -------
        matplotlib.figure.Figure
            The figure drawn into. Parameters beyond ``Z_CHANGED`` in some segment are labelled.
        """
        if ax is None:
            from matplotlib.figure import Figure  # here: matplotlib costs its import only to those who plot

            ax = Figure(figsize=(7.2, 4.2), layout="constrained").add_subplot()
        ax.axhspan(-Z_CHANGED, Z_CHANGED, color="0.92", label=f"|z| < {Z_CHANGED:g}")
        t, z = self.z_over_time()
        for name, zk in zip(self.settings["parameter_names"], z.T):
            changed = np.max(np.abs(np.nan_to_num(zk))) > Z_CHANGED
            ax.plot(t, zk, linewidth=2 if changed else 1, color=None if changed else "0.6",
                    label=name if changed else None)  # fmt: skip
        for e in self.events:
            ax.axvline(e.time, color="k", linestyle="--", linewidth=1)
            ax.axvspan(e.time, e.time + e.lead, color="k", alpha=0.15, linewidth=0)
            ax.axvline(e.detected_at, color="k", linestyle=":", linewidth=1)
        ax.set_yscale("symlog", linthresh=Z_CHANGED)
        ax.set(xlabel="time [s]", ylabel="change from the first segment [std. errors]",
               title=f"{len(self.events)} change(s); {len(self.segments)} segment(s)")
        ax.legend(fontsize="small", loc="best")
        return ax.figure

    def z_over_time(self) -> tuple:
        """The times ``(3 m,)`` [s] and z-scores ``(3 m, k)`` of the ``m`` identified segments' ``k``
        parameters against the first's: each held from its start to its end, then NaN (the lines
        break between segments; a known parameter's 0 / 0 too)."""
        spans = [(s.start, self.last_time if s.end is None else s.end, s.identification) for s in self.segments
                 if s.identification is not None and s.start is not None]  # fmt: skip
        k = len(self.settings["parameter_names"])
        if not spans:
            return np.zeros(0), np.zeros((0, k))
        first = spans[0][2]
        with np.errstate(invalid="ignore", divide="ignore"):
            z = np.array([(i.values - first.values) / np.hypot(i.std, first.std) for *_, i in spans])  # (m, k)
        held = np.stack([z, z, np.full_like(z, np.nan)], axis=1)  # (m, 3, k)
        t = np.array([[start, end, np.nan] for start, end, _ in spans], float)
        return t.ravel(), held.reshape(-1, k)
