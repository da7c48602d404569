"""The samples a monitor takes (docs/theory/monitor.md): one record per sample, the logs they come
in turned into final samples (their rates no longer moved by the samples to come, their drift
basis accumulated from the log's first sample), and a segment's evenly thinned store of them."""

from __future__ import annotations

import itertools
import warnings
from typing import NamedTuple

import numpy as np

from ..data import Log
from ._drift import drift_basis
from ._uncertainty import correlation_length

GAP_STEPS = 3.0
"""Sample steps between two consecutive samples beyond which the drift basis's quadrature across
them is an interpolation (a gap: messages lost, or skipped by the live aligner)."""
BASIS_OVERLAP = 8
"""Samples before a chunk that the drift basis's quadrature of the chunk starts from (the Coulomb
kind's sign changes are located by cubics through four samples on either side)."""


class Sample(NamedTuple):
    """One sample of the log, as the monitor keeps it.

    Attributes
    ----------
    t : float
        Time stamp [s].
    q, qd : numpy.ndarray of shape (n_joints,)
        Joint angles [rad] and rates [rad/s].
    base_quat : numpy.ndarray of shape (4,)
        Base attitude (scalar-first unit quaternion).
    base_w : numpy.ndarray of shape (3,)
        Base angular rate [rad/s].
    basis : numpy.ndarray of shape (n_d, 3) or None
        With drift terms, the drift basis from the log's first sample (:func:`~spaceid.estimation._drift.drift_basis`).
    """

    t: float
    q: np.ndarray
    qd: np.ndarray
    base_quat: np.ndarray
    base_w: np.ndarray
    basis: np.ndarray | None = None


def samples_of(log: Log) -> list:
    """The samples of ``log`` as :class:`Sample` records, without drift basis."""
    return list(itertools.starmap(Sample, zip(log.t, log.q, log.qd, log.base_quat, log.base_w)))


def log_of(samples: list, model, source: str) -> Log:
    """The log of :class:`Sample` records of ``model``'s joints (their drift basis left out)."""
    t, q, qd, quat, w = (np.array(c) for c in list(zip(*samples))[:5])
    return Log(t, tuple(model.joints), q, qd, quat, w, planar=model.planar, meta={"source": source})


class Thinned:
    """At most ``size`` samples of a segment, evenly spaced: when full, every other one is dropped
    and the stride doubles (bounded memory, O(1) amortised work a sample)."""

    def __init__(self, size: int):
        self.size, self.stride, self.seen, self.rows = size, 1, 0, []

    def add(self, sample: Sample):
        if self.seen % self.stride == 0:
            self.rows.append(sample)
            if len(self.rows) > self.size:
                self.rows, self.stride = self.rows[::2], 2 * self.stride
        self.seen += 1

    def until(self, t: float):
        """Drop the samples at or after ``t`` [s] (those after an estimated change)."""
        self.rows = [s for s in self.rows if s.t < t]


class Intake:
    """The logs fed to a monitor as the samples it takes: each with its drift basis, and held
    back until its rates are final (with differentiated rates, until half the differentiator's
    window of samples has come after it: the rates of the log's last half window come from
    one-sided windows, extrapolations).

    Parameters
    ----------
    model : Model
        The monitored model (its joints and planarity).
    where : str
        Name of the data source, for error messages.
    drift : tuple of str
        Drift kinds whose basis each sample carries (none: no basis).

    Attributes
    ----------
    t0 : float or None
        The first sample's stamp [s]: the origin of the differentiators' raw grids.
    window : int or None
        The differentiator's window [samples] (0: rates measured), from the first log of more than
        one sample.
    step : float
        The sample step [s], with the window.
    held : list of Sample
        The last half window of samples: their rates may change with the samples to come.
    """

    def __init__(self, model, where: str, drift: tuple):
        self.model, self.where, self.drift = model, where, drift
        self.t0, self.window, self.step, self.held = None, None, 0.0, []
        self._tail = []  # the last samples with their drift basis: the next chunk's quadrature starts there

    @property
    def half(self) -> int:
        """Half the differentiator's window [samples], rounded up (0 before it is known)."""
        return -(-(self.window or 0) // 2)

    def learn_window(self, log: Log) -> int | None:
        """Learn the differentiator's window from ``log`` if not known yet: its half (the log's first
        samples from one-sided windows, never to be taken) when learned now, else None."""
        if self.window is not None or log.n_samples < 2:
            return None
        self.window = correlation_length(log)
        self.step = float(np.median(np.diff(log.t)))
        return self.half

    def final(self, log: Log) -> list:
        """The samples whose rates are final now: those held back before, then ``log``'s, less
        the new last half window (held back in turn), unless its ``meta`` says that its rates are
        all final (``final_rates``: the parts of :class:`~spaceid.data.MessageAligner`, which
        returns a sample once the messages that complete its windows are in)."""
        samples = self.held + (self.with_basis(log) if self.drift else samples_of(log))
        cut = len(samples) if log.meta.get("final_rates") else max(len(samples) - self.half, 0)
        samples, self.held = samples[:cut], samples[cut:]
        return samples

    def with_basis(self, log: Log) -> list:
        """``log``'s samples with their drift basis from the log's first sample: the quadrature
        continued from the last samples before them (:func:`drift_basis` over those and these: its
        one-sided fits and spline see across the chunks, the yaw is unwrapped across)."""
        tail, new = self._tail, samples_of(log)
        self._warn_gaps(tail[-1:] + new)
        g = drift_basis(log_of(tail + new, self.model, self.where), self.drift)
        if tail:
            g = tail[-1].basis + g[len(tail) :] - g[len(tail) - 1]
        new = [s._replace(basis=gk) for s, gk in zip(new, g)]
        self._tail = (tail + new)[-BASIS_OVERLAP:]
        return new

    def _warn_gaps(self, samples: list):
        """Warn of each gap between ``samples`` (more than ``GAP_STEPS`` steps) that a drift kind's
        basis is not exact across: the torque's (time) and the planar viscous one's (the yaw's
        change) are; a spatial viscous or Coulomb basis is a spline quadrature of the base rate,
        which the gap does not sample, and the planar Coulomb basis locates one sign change of the
        rate in it by one-sided fits (two are missed). The error moves the momentum the segment
        carries on, and the test may take it for a change."""
        planar = self.model.planar
        kinds = [k for k in self.drift if k == "coulomb" or (k == "viscous" and not planar)]
        if not kinds or not self.step or len(samples) < 2:
            return
        t = np.array([s.t for s in samples])
        for i in np.flatnonzero(np.diff(t) > GAP_STEPS * self.step):
            warnings.warn(f"{self.where}: no sample for {t[i + 1] - t[i]:.3g} s from {t[i]:.6g} s: the "
                          f"{' and '.join(kinds)} drift basis is integrated across it as if the base had turned "
                          "smoothly there (the base rate in the gap is not measured): its error moves the momentum "
                          "after the gap, which the test may take for a change", stacklevel=4)
