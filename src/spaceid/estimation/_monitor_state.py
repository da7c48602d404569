"""The state of the monitor's running segment: its phase and what it has gathered so far."""

from __future__ import annotations

import enum
import math
from dataclasses import dataclass, field

import numpy as np
from scipy.linalg import solve_triangular

from ._linalg import _accumulate_factor
from ._monitor_samples import Sample, Thinned
from ._monitor_whitening import Prewhitening
from ._result import Identification


class Phase(enum.Enum):
    """What the running segment does with its next sample."""

    DROPPING = "dropping"
    """Drops it: a sample a differentiator blends across a change, or one of the log's first half
    window of differentiated rates (one-sided windows): it fits no segment."""
    WARMING_UP = "warming up"
    """Adds it to the warm-up, identified in batch once complete."""
    TESTING = "testing"
    """Tests it, then adds it to the recursive estimate."""


@dataclass(eq=False)
class Segment:
    """The running segment.

    Attributes
    ----------
    start : float or None
        Its first sample's time, or the estimated change that opened it [s]; None until the
        log's first sample.
    origin : Sample or None
        The sample its momentum is given at and its drift integrated from; None until the log's
        first sample.
    momentum : numpy.ndarray of shape (3,)
        The momentum at ``origin`` [N m s].
    drift : bool
        Whether the equations have drift terms (then it keeps its ``trail``).
    target : int
        Warm-up samples to identify in batch (more while they do not excite every parameter).
    thinned : Thinned
        Its samples for its batch identification at its close.
    phase : Phase
        What it does with the next sample.
    drop : int
        Samples still to drop (``Phase.DROPPING``).
    warm : list of Sample
        The warm-up's samples.
    trail : list of Sample
        With drift terms, the samples from ``origin`` until the warm-up is identified: its drift's history.
    count : int
        Samples taken.
    ident : Identification or None
        The warm-up's batch identification.
    theta_ref : numpy.ndarray of shape (p,) or None
        The linearisation point: its free parameters, then drift coefficients.
    scale : numpy.ndarray of shape (p,) or None
        The unknowns' scale in the recursion.
    R : numpy.ndarray of shape (p + 1, p + 1) or None
        Square-root information factor of the recursive estimate (scaled unknowns, data column last).
    whitening : Prewhitening or None
        Its prewhitening, chosen on the warm-up.
    warm_up : dict or None
        The record of its warm-up once identified (``warm_up`` of a segment, docs/formats/events-json.md).
    score : numpy.ndarray of shape (p,) or None
        The errors-in-variables bias's score of the samples in ``R`` (scaled unknowns,
        :mod:`~spaceid.estimation._monitor_determinacy`): the recursive estimate's bias is
        ``-(R^T R)^-1 score``.
    sigma : numpy.ndarray of shape (n_x,) or None
        The signals' noise levels the score is taken at (the model's, or a differentiator's
        smoothed ones, times the root of the level the warm-up's residuals showed when below 1).
    attempt : dict or None
        What the warm-up's last identification that did not determine the estimate found
        (:meth:`~spaceid.estimation.Monitor.warm_up_estimate`); None before one.
    fixed : dict
        The derivatives of the warm-up samples' equations in each signal, which do not depend on
        the linearisation point, by the sample's ``id``: ``(sample, derivatives)``
        (:meth:`~spaceid.estimation.Monitor._fixed`); emptied once the test begins.
    """

    start: float | None
    origin: Sample | None
    momentum: np.ndarray
    drift: bool
    target: int
    thinned: Thinned
    phase: Phase = Phase.WARMING_UP
    drop: int = 0
    warm: list = field(default_factory=list)
    trail: list = field(default_factory=list)
    count: int = 0
    ident: Identification | None = None
    theta_ref: np.ndarray | None = None
    scale: np.ndarray | None = None
    R: np.ndarray | None = None
    whitening: Prewhitening | None = None
    warm_up: dict | None = None
    score: np.ndarray | None = None
    sigma: np.ndarray | None = None
    attempt: dict | None = None
    fixed: dict = field(default_factory=dict)

    def take(self, samples: list):
        """Add ``samples`` to the warm-up."""
        self.warm += samples
        self.trail += samples if self.drift else []
        self.count += len(samples)

    def skip(self, samples: list):
        """Drop ``samples`` (at most ``drop`` of them): the warm-up begins after the last to drop."""
        self.trail += samples if self.drift else []
        self.dropped(len(samples))

    def dropped(self, n: int):
        self.drop -= n
        self.phase = Phase.DROPPING if self.drop else Phase.WARMING_UP

    def drop_first(self, n: int):
        """Drop the first ``n`` samples of the warm-up, those taken already and those to come."""
        self.drop = max(n - len(self.warm), 0)
        self.warm = self.warm[n:]
        self.count = len(self.warm)
        self.dropped(0)

    def add(self, sample: Sample, a: np.ndarray, b: np.ndarray, forgetting: float, score: np.ndarray):
        """Add a tested sample: its whitened equations ``a (rows, p)`` (scaled unknowns) and ``b
        (rows,)`` and its bias's ``score (p,)`` to the recursive estimate, forgetting the ones
        before by ``forgetting``."""
        if forgetting < 1:
            self.R *= math.sqrt(forgetting)
            self.score *= forgetting
        self.R = _accumulate_factor(self.R, np.asfortranarray(np.column_stack([a, b])))
        self.score += score
        self.thinned.add(sample)
        self.count += 1

    def estimate(self, free: np.ndarray, n_params: int) -> dict | None:
        """The recursive estimate (:meth:`~spaceid.estimation.Monitor.estimate`), the ``free``
        parameters' indices among the ``n_params``; None before the test began."""
        if self.phase is not Phase.TESTING:
            return None
        p = len(self.scale)
        r = self.R[:p, :p]
        theta = solve_triangular(r, self.R[:p, p]) / self.scale
        r_inv = solve_triangular(r, np.eye(p))
        std = np.sqrt(np.einsum("ij,ij->i", r_inv, r_inv)) / self.scale
        nf = len(free)
        values, stds = self.ident.values.copy(), np.zeros(n_params)
        values[free], stds[free] = theta[:nf], std[:nf]
        out = {"values": values, "std": stds, "linearization": self.ident.values}
        if self.drift:
            out |= {"drift": theta[nf:], "drift_std": std[nf:], "momentum": self.momentum,
                    "momentum_from": np.float64(self.origin.t)}  # fmt: skip
        return out
