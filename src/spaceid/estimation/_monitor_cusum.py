"""The monitor's CUSUM test on normalised innovations: its threshold for a false-alarm rate, its
run lengths, and the running statistic with its estimate of the change time (docs/theory/monitor.md).

Under no change a sample's normalised innovation ``nu (rows,)`` is N(0, I); the CUSUM adds the
log-likelihood ratio of ``nu ~ N(0, ratio I)`` against that, ``c nu^T nu - d``, and alarms when
its sum since it last left zero exceeds the threshold ``h``.
"""

from __future__ import annotations

import collections
import functools
import math

import numpy as np
import scipy

from .._cache import cache_key, read_cached, source_digest, write_cached
from .._constants import CHANGE_RATIO, FALSE_ALARM_RATE
from .._distributions import chi2_cdf
from .._errors import SpaceidError
from .._threads import one_blas_thread


def _increment(rows: int, ratio: float):
    """Scale ``c`` and offset ``d`` of the CUSUM increment ``c nu^T nu - d``: the log-likelihood
    ratio of ``nu ~ N(0, ratio I)`` against ``N(0, I)`` for ``rows`` components."""
    return (1 - 1 / ratio) / 2, rows / 2 * math.log(ratio)


@functools.lru_cache(maxsize=256)
def cusum_run_length(threshold: float, rows: int, ratio: float = CHANGE_RATIO, *, actual: float = 1.0,
                     cells: int = 200) -> float:
    """Average run length [samples] of the chi-square CUSUM until it exceeds ``threshold``; remembered
    for the process (a function of its arguments alone: 40,000 chi-square values, about 10 ms).

    The CUSUM ``g_n = max(0, g_{n-1} + c nu_n^T nu_n - d)`` (:func:`_increment`) starts at zero;
    ``nu_n ~ N(0, actual I)`` with ``rows`` components, independent. The run length is that of the
    Markov chain on ``cells`` cells of ``[0, threshold]`` (Brook and Evans, 1972).

    Parameters
    ----------
    threshold : float
        CUSUM threshold ``h`` (> 0), dimensionless (log-likelihood).
    rows : int
        Equations per sample (1 planar, 3 spatial).
    ratio : float
        Innovation variance ratio the increment is tuned to (> 1).
    actual : float
        Actual variance ratio of the innovations: 1 gives the run length between false alarms,
        ``ratio`` the detection delay of a change of the tuned size.
    cells : int
        Cells of the discretisation.

    Returns
    -------
    float
        Expected samples until the first alarm.
    """
    c, d = _increment(rows, ratio)
    width = threshold / cells
    start = np.r_[0.0, (np.arange(1, cells + 1) - 0.5) * width]  # the atom at zero, then the cell midpoints
    edges = np.arange(cells + 1) * width  # upper edges of the cells below them
    cdf = lambda x: chi2_cdf(np.maximum((x + d) / (c * actual), 0), rows)  # noqa: E731  P(increment <= x)
    to = cdf(edges[None, :] - start[:, None])  # (cells + 1 states, cells + 1 edges)
    Q = np.empty((cells + 1, cells + 1))
    Q[:, 0] = to[:, 0]  # back to zero
    Q[:, 1:] = np.diff(to, axis=1)
    with one_blas_thread():
        return float(np.linalg.solve(np.eye(cells + 1) - Q, np.ones(cells + 1))[0])


_CACHE_KIND = "cusum-threshold"


@functools.lru_cache(maxsize=64)
def cusum_threshold(false_alarm_rate: float, rows: int, ratio: float = CHANGE_RATIO) -> float:
    """The CUSUM threshold whose run length between false alarms is ``1 / false_alarm_rate``; remembered
    for the process and in the on-disk cache (:mod:`spaceid._cache`, keyed by the arguments and this code):
    a root of :func:`cusum_run_length`, a dozen of its evaluations and SciPy's root finder, whose import
    with them took 0.12 s of a first ``monitor`` (``spaceid demo``, the install step, caches the default
    rate's for planar and spatial systems).

    Parameters
    ----------
    false_alarm_rate : float
        False alarms per sample under no change, in (0, 0.5).
    rows : int
        Equations per sample (1 planar, 3 spatial).
    ratio : float
        Innovation variance ratio the CUSUM is tuned to (> 1).

    Returns
    -------
    float
        The threshold ``h``; at most ``ln(1 / false_alarm_rate)`` (Lorden's bound, ARL >= e^h).

    Raises
    ------
    SpaceidError
        ``false_alarm_rate`` outside (0, 0.5) or ``ratio`` not above 1.
    """
    if not 0 < false_alarm_rate < 0.5:
        raise SpaceidError(f"`false_alarm_rate`: {false_alarm_rate!r}: give false alarms per sample in (0, 0.5), "
                           f"e.g. {FALSE_ALARM_RATE:g}")
    if not ratio > 1:
        raise SpaceidError(f"`change_ratio`: {ratio!r}: give an innovation variance ratio above 1, "
                           f"e.g. {CHANGE_RATIO:g}")
    key = cache_key(float(false_alarm_rate), int(rows), float(ratio), np.__version__, scipy.__version__,
                    _threshold_digest())
    stored = read_cached(_CACHE_KIND, key)
    if stored is not None:
        return float(stored["threshold"])
    from scipy.optimize import brentq

    target = math.log(1 / false_alarm_rate)
    gap = lambda h: math.log(cusum_run_length(h, rows, ratio)) - target  # noqa: E731
    threshold = float(brentq(gap, 1e-6, target + 1.0, xtol=1e-6))
    write_cached(_CACHE_KIND, key, {"threshold": np.array(threshold)})
    return threshold


@functools.cache
def _threshold_digest() -> str:
    """Hash of the code a threshold comes from (this module's run lengths, the chi-square distribution)."""
    return source_digest(__file__, chi2_cdf.__code__.co_filename)


class StatisticTrace:
    """The CUSUM statistic over a run in bounded memory: at most ``capacity`` points, each the
    largest statistic of ``stride`` consecutive tested samples (with its time); when full, pairs
    merge and ``stride`` doubles, so that a run of any length keeps its alarms' peaks.

    Parameters
    ----------
    capacity : int
        Points kept at most (even).
    """

    def __init__(self, capacity: int = 4000):
        self.capacity, self.stride, self._n = capacity + capacity % 2, 1, 0
        self.t: list = []
        self.g: list = []

    def add(self, t: float, g: float) -> None:
        """The statistic ``g`` at the tested sample at ``t`` [s]."""
        if self._n % self.stride == 0:
            self.t.append(t)
            self.g.append(g)
        elif g >= self.g[-1]:
            self.t[-1], self.g[-1] = t, g
        self._n += 1
        if len(self.g) > self.capacity:
            pairs = [max((self.g[i], self.t[i]), (self.g[i + 1], self.t[i + 1])) for i in range(0, self.capacity, 2)]
            self.g = [p[0] for p in pairs] + self.g[self.capacity:]
            self.t = [p[1] for p in pairs] + self.t[self.capacity:]
            self.stride *= 2

    def arrays(self) -> tuple:
        """``(t, g)``, arrays of shape (m,): the times [s] and statistics kept."""
        return np.array(self.t, float), np.array(self.g, float)


class Cusum:
    """The running CUSUM of a monitor, restarted at zero for each segment's test.

    Parameters
    ----------
    threshold : float
        Alarm threshold ``h`` (log-likelihood), :func:`cusum_threshold`.
    rows : int
        Components of each normalised innovation (equations per sample).
    ratio : float
        Innovation variance ratio the increment is tuned to (> 1).
    memory : int
        Most samples of the excursion kept for the change time (the warm-up: the samples an
        alarm can hand to the next segment).

    Attributes
    ----------
    statistic : float
        The statistic ``g`` (>= 0).
    excursion : collections.deque of (float, float)
        ``(t [s], nu^T nu)`` of the samples since the statistic last left zero.
    n_tested : int
        Samples tested over the whole run.
    trace : StatisticTrace
        The statistic over the whole run, bounded (for the report's figure).
    """

    def __init__(self, threshold: float, rows: int, ratio: float, memory: int):
        self.threshold, self.rows, self._increment = threshold, rows, _increment(rows, ratio)
        self.statistic, self.n_tested = 0.0, 0
        self.excursion = collections.deque(maxlen=memory)
        self.trace = StatisticTrace()

    def restart(self):
        """Start afresh at zero (a new segment, or the samples after a tested warm-up)."""
        if self.statistic and self.excursion:
            self.trace.add(self.excursion[-1][0], 0.0)  # the drop to zero, at the last sample tested
        self.statistic = 0.0
        self.excursion.clear()

    def add(self, t: float, nu: np.ndarray) -> bool:
        """Add the normalised innovation ``nu (rows,)`` of the sample at ``t`` [s]; True when the
        statistic crosses the threshold."""
        c, d = self._increment
        stat = float(nu @ nu)
        self.statistic = max(0.0, self.statistic + c * stat - d)
        self.excursion.append((t, stat))
        self.trace.add(t, self.statistic)
        self.n_tested += 1
        if self.statistic > self.threshold:
            return True
        if self.statistic == 0:
            self.excursion.clear()
        return False

    def change_time(self) -> tuple:
        """The estimated change time [s] and the samples from it to the alarm: the start of the
        excursion's tail that maximises the likelihood ratio of an innovation variance ratio
        estimated from that tail (the CUSUM's own start, tuned to one ratio, often includes a
        sample or two before a large change)."""
        t, stat = np.array(self.excursion).T
        n = np.arange(len(stat), 0, -1) * self.rows
        ratio = np.maximum(np.cumsum(stat[::-1])[::-1] / n, 1.0)
        i = int(np.argmax(n / 2 * (ratio - 1 - np.log(ratio))))
        return float(t[i]), len(stat) - i
