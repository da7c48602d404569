"""The monitor's whitening of equation errors that differentiated rates correlate (docs/theory/monitor.md).

A Savitzky-Golay differentiator makes each sample's smoothed angle and rate a fixed linear
combination of the raw angle samples within its window (:func:`spaceid.data.savgol_weights`),
so the equation errors are a moving average of the raw angle noise with known weights: time
varying through the equations' Jacobian, but of a state that is just the raw noise within the
current windows. The residuals ``e_n = b_n - a_n theta_ref`` of a segment's linearisation point
are then ``a_n dtheta + H_n eps_n`` plus independent noise, with the estimate's error ``dtheta``
constant. A Kalman filter on the state ``[dtheta; eps]`` gives each residual's part that the
previous ones do not predict and its exact covariance: the innovations of recursive generalised
least squares, independent and N(0, I) under the noise model, O((p + d)^2) work a sample for
``p`` unknowns and ``d`` raw samples in the windows. (Whitening the moving average alone, with
the estimate's error as independent noise, fails: the differentiated errors are smooth, so
their innovations are small, and the estimate's error, smooth too, dominates them.)

Each raw series is a sliding window over its grid (the series' recorded step; each log sample at
its nearest grid point, as :mod:`~spaceid.estimation._differentiated` places them), held in a
circular buffer: moving the window on forgets the raw samples that leave it and takes in the new
ones, unit variance and independent of everything, at the places they leave.
"""

from __future__ import annotations

import math

import numpy as np

from ..data import savgol_weights
from ._differentiated import whitened_series


class DifferentiatedWhitener:
    """Kalman whitening of equation errors from differentiated rates.

    Parameters
    ----------
    series : list
        The log's raw angle series, :func:`~spaceid.estimation._differentiated.whitened_series`.
    t0 : float
        Origin of the raw grids [s] (the first sample's stamp).
    p : int
        Unknowns of the equations.
    levels : tuple of 2 floats
        The raw noise levels given for the joint angles and the base attitude [rad] (:class:`Noise`'s
        ``angle`` and ``attitude``); 0: those the differentiator estimated from each part's record,
        pooled over the parts (:meth:`_pool`).
    n_samples : int
        Samples of the log whose record ``series`` is (the weight of its estimated levels).
    """

    def __init__(self, series: list, t0: float, p: int, levels=(0.0, 0.0), n_samples: int = 1):
        self.t0, self.blocks, self.levels, start = t0, [], levels, p
        for record, value, rate, attitude in series:
            window, step = record["window"], record["step"]
            _, smooth, slope = savgol_weights(step * np.arange(window), [window // 2], window, record["order"])
            self.blocks.append({"value": value, "rate": rate, "window": window, "step": step, "order": record["order"],
                                "noise": None, "smooth": smooth[0], "slope": slope[0], "attitude": attitude,
                                "start": start, "centre": None, "pool": [0.0, 0, None]})  # fmt: skip
            self._pool(self.blocks[-1], record, n_samples)
            start += window
        self.p, self.x, self.P = p, np.zeros(start), np.eye(start)
        self.covered = [c for b in self.blocks for c in (b["value"], b["rate"]) if c is not None]

    def follows(self, log) -> bool:
        """Take the noise levels of ``log``'s differentiation record (a new part of a bag, pooled
        with those before: :meth:`_pool`); False when its filters differ from these (another
        window, order or step): a new whitener is needed."""
        series = whitened_series(log)
        if series is None or len(series) != len(self.blocks):
            return False
        for (record, value, rate, attitude), b in zip(series, self.blocks):
            if (record["window"], record["order"], value, rate) != (b["window"], b["order"], b["value"], b["rate"]) \
                    or not np.isclose(record["step"], b["step"], rtol=1e-6):
                return False
        for (record, *_), b in zip(series, self.blocks):
            self._pool(b, record, log.n_samples)
        return True

    def _pool(self, block: dict, record: dict, n_samples: int):
        """A series' raw noise level: the one given (a joint's angle, or the base attitude's),
        else the differentiator's estimates pooled over the parts so far, each estimate's variance
        weighted by its part's ``n_samples`` new samples: a live part's record holds a few seconds
        (:class:`~spaceid.data.MessageAligner`'s context), whose estimate strays by tens of percent
        from part to part, and a level 18 % low raised a false alarm on the twin's run without a
        change. One record fed in chunks keeps its own level exactly."""
        given = self.levels[block["attitude"]]
        if given:
            block["noise"] = given
            return
        pool = block["pool"]  # [sum of n s^2, sum of n, the one level seen so far (NaN once they differ)]
        level, n = float(record["noise"]), max(int(n_samples), 1)
        pool[0] += n * level**2
        pool[1] += n
        pool[2] = level if pool[2] is None or pool[2] == level else math.nan
        block["noise"] = float(np.sqrt(pool[0] / pool[1])) if math.isnan(pool[2]) else pool[2]

    def start(self, cov: np.ndarray):
        """Start a segment: the estimate's error with covariance ``cov (p, p)``, the raw noise unknown."""
        self.x[:], self.P[:] = 0.0, np.eye(len(self.x))
        self.P[: self.p, : self.p] = cov
        for b in self.blocks:
            b["centre"] = None

    def forget(self, factor: float):
        """Exponential forgetting of the estimate (``factor`` in (0, 1]): its covariance divided by it."""
        self.P[: self.p] /= np.sqrt(factor)
        self.P[:, : self.p] /= np.sqrt(factor)

    def uncovered(self, sigma: np.ndarray) -> np.ndarray:
        """The noise levels ``sigma (n_x,)`` of the signals that are not differentiated (independent
        from sample to sample); those of the differentiated ones are the raw series'."""
        sigma = sigma.copy()
        sigma[self.covered] = 0.0
        return sigma

    def smoothed(self, sigma: np.ndarray) -> np.ndarray:
        """The noise levels ``sigma (n_x,)`` with those of the differentiated signals replaced by the
        std of each sample's smoothed angle and rate (the raw level times the norm of the
        differentiator's weights): each sample's own noise, without its correlation."""
        sigma = sigma.copy()
        for b in self.blocks:
            if b["value"] is not None:
                sigma[b["value"]] = b["noise"] * np.linalg.norm(b["smooth"])
            sigma[b["rate"]] = b["noise"] * np.linalg.norm(b["slope"])
        return sigma

    def _forget(self, places):
        """Raw samples at ``places`` of the state replaced by new ones: zero mean, unit variance, independent."""
        self.x[places] = 0.0
        self.P[places, :] = 0.0
        self.P[:, places] = 0.0
        self.P[places, places] = 1.0

    def design(self, t: float, a: np.ndarray, J: np.ndarray) -> np.ndarray:
        """Move the windows to the sample at ``t`` [s] and return how its residuals depend on the
        state, ``(rows, p + d)``: ``a (rows, p)`` on the estimate's error, the signal noise's effect
        through the equations' Jacobian ``J (rows, n_x)`` on the raw noise."""
        H = np.zeros((J.shape[0], len(self.x)))
        H[:, : self.p] = a
        for b in self.blocks:
            w, half = b["window"], b["window"] // 2
            centre = int(np.rint((t - self.t0) / b["step"]))
            moved = w if b["centre"] is None else min(max(centre - b["centre"], 0), w)
            b["centre"] = centre
            entering = centre + half - np.arange(moved)  # raw samples new to the window
            self._forget(b["start"] + entering % w)
            places = b["start"] + (centre - half + np.arange(w)) % w
            value = np.zeros(J.shape[0]) if b["value"] is None else J[:, b["value"]]
            H[:, places] = b["noise"] * (np.outer(value, b["smooth"]) + np.outer(J[:, b["rate"]], b["slope"]))
        return H

    def innovation(self, e: np.ndarray, H: np.ndarray, R: np.ndarray) -> np.ndarray:
        """The part of the errors ``e (rows,)`` = ``H`` times the raw noise plus independent noise of
        covariance ``R (rows, rows)`` that the samples before do not predict, normalised to N(0, I);
        the state then takes ``e`` in."""
        PH = self.P @ H.T
        F = H @ PH + R
        y = e - H @ self.x
        gain = np.linalg.solve(F, PH.T).T  # rows x rows systems: numpy's small solvers, not scipy's checked ones
        self.x += gain @ y
        self.P -= gain @ PH.T
        self.P += self.P.T  # kept symmetric against round-off
        self.P *= 0.5
        return np.linalg.solve(np.linalg.cholesky(F), y)
