"""Change detection on a running log: a recursive estimator on the momentum equations and a
CUSUM test on its normalised innovations (docs/theory/monitor.md).

Samples arrive one by one (or in chunks). Each segment between changes starts with a warm-up of
``warmup`` samples, identified in batch (:func:`~spaceid.estimation.identify`): its estimate is
the linearisation point at which the equation-error covariances ``S_n``
(:mod:`spaceid.estimation._noise`) are evaluated for the rest of the segment. Then every sample

1. is whitened by ``L_n`` (``S_n = L_n L_n^T`` there), and its innovation (the momentum residual
   of the estimate from the samples before it) is normalised by its predicted covariance
   ``L_n^-1 S_n(estimate) L_n^-T + a_n P a_n^T``: under no change ``nu_n ~ N(0, I)``,
   independent from sample to sample;
   when the rates were differentiated by a recorded Savitzky-Golay filter, a Kalman filter on the
   raw angle noise in the differentiator's windows and the estimate's error whitens them instead
   (:mod:`~spaceid.estimation._monitor_filter`); when the warm-up's residuals are otherwise
   autocorrelated, an AR filter fitted to them (:meth:`Monitor._set_prewhitening`). A sample is
   taken once its rates are final: the first and last half windows of differentiated rates never are;
2. feeds a CUSUM of the log-likelihood ratio of an innovation inflated ``change_ratio`` times in
   variance against none; its threshold gives the requested false-alarm rate (one alarm per
   ``1 / false_alarm_rate`` samples on average, :func:`cusum_threshold`);
3. updates the square-root information factor of recursive weighted least squares with
   forgetting (:func:`~spaceid.estimation._estimators._accumulate_factor`): O(p^2) work per
   sample whatever the log's length.

An alarm closes the segment at the estimated change time (within the CUSUM's last excursion
above zero, :meth:`Monitor._change_time`) and starts a new one there; once the new segment's
warm-up is identified, the event reports the z-scores of the change (:func:`~spaceid.estimation.compare`),
and that warm-up's own innovations are tested too, each predicted from the warm-up's samples before
it under the whitening of the segment before (:meth:`Monitor._warm_up_innovations`). Each closed
segment is re-identified in batch from at most ``max_segment`` of its samples (evenly thinned), so
memory stays bounded.

With drift terms (an external torque, such as an air-bearing table's friction) the momentum is
``h_s + sum_k d_k (g_k(t) - g_k(t_s))`` in a segment, ``g_k`` the drift basis
(:mod:`~spaceid.estimation._drift`) accumulated chunk by chunk from the log's first sample
(:meth:`Monitor._rows_with_basis`), ``t_s`` the segment's first sample (the log's, or the estimated
change time) and ``d_k`` unknowns estimated with the parameters; ``h_s`` is the given momentum for
the first segment, for the others the segment before's at ``t_s`` with its drift estimated so far
(a change conserves the momentum). The momentum itself is not estimated: with a wheel spinning at
constant speed (its rotor inertia the only anchor) a short warm-up does not fix the scale, and on
the twin its estimate collapsed to the parameters near zero.
"""

from __future__ import annotations

import collections
import dataclasses
import math
import warnings
from dataclasses import dataclass, field

import numpy as np
from scipy.linalg import lapack, solve_triangular
from scipy.optimize import brentq
from scipy.stats import chi2

from .._errors import SpaceidError
from .._threads import one_blas_thread
from ..data import Log, quat_to_matrix
from ..dynamics import Parameterization
from ._equations import _equations
from ._estimators import _accumulate_factor, _column_scale, _whiten
from ._identify import identify
from ._differentiated import differentiated_series
from ._drift import check_drift_kinds, drift_basis
from ._monitor_filter import DifferentiatedWhitener
from ._noise import Noise, equation_covariance, noise_from_log, signal_sigma
from ._result import Identification, compare
from ._uncertainty import SIGNIFICANCE, _correlation_length, _residual_checks

__all__ = ["Monitor", "MonitorEvent", "monitor", "cusum_threshold", "cusum_run_length", "log_chunks", "Z_CHANGED"]

FALSE_ALARM_RATE = 1e-5
"""Default false alarms per sample under no change (one per 10^5 samples: 17 min at 100 Hz)."""
CHANGE_RATIO = 4.0
"""Default innovation variance ratio the CUSUM is tuned to (innovations twice their predicted std)."""
Z_CHANGED = 3.0
"""A parameter changed when its z-score (change / combined standard error) exceeds this in magnitude."""
CHUNK = 256
"""Samples of a whole :class:`~spaceid.data.Log` fed to the monitor at a time (the regressor is vectorised)."""
WARMUP = 200
"""Least samples of a segment's warm-up by default (2 s at 100 Hz): shorter ones leave the estimate
too loose for the normalisation of the residuals that follow (false alarms early in a segment)."""
NOISE_SAMPLES = 500
"""Samples the noise levels are estimated from when not given: the first warm-up is at least this long."""
AR_ORDER = 3
"""Order of the autoregressive filter that prewhitens correlated innovations (rates differentiated otherwise)."""
BASIS_OVERLAP = 8
"""Samples before a chunk that the drift basis's quadrature of the chunk starts from (the Coulomb
kind's sign changes are located by cubics through four samples on either side)."""
PRIOR = 1e4
"""The differentiator's whitening starts each segment with the estimate's error this many times
the warm-up's weighted least-squares covariance: diffuse against the warm-up itself, which it then
takes in (a change within the warm-up puts its batch estimate, the linearisation point, between
the two systems: many of its standard errors from either)."""
PRIOR_CEILING = 1e10
"""Largest variance of that prior in any direction of the scaled parameters (a unit there moves the
warm-up's whitened residuals by at most one noise standard deviation in all): a direction the
warm-up leaves this undetermined is unknown to the test either way, and larger variances leave the
filter's covariance update to round-off (on the twin, 1e13 against the raw noise's 1 turned it
indefinite and the innovations' Cholesky factorisation failed)."""


def _ar_fit(res: np.ndarray, order: int, p: int) -> tuple:
    """Autoregressive coefficients ``(order,)`` of the whitened residuals ``res (n, rows)`` (the rows
    as separate series with common coefficients, least squares) and the std of what the filter leaves, its variance
    scaled by ``m / (m - p)`` for the ``p`` unknowns fitted to the ``m`` equations (the residuals
    are smaller than the innovations by the fit's share)."""
    n = len(res)
    lags = np.stack([res[order - k : n - k] for k in range(1, order + 1)], axis=-1).reshape(-1, order)
    now = res[order:].reshape(-1)
    coef = np.linalg.lstsq(lags, now, rcond=None)[0]
    left = now - lags @ coef
    m = res.size
    scale = math.sqrt(np.sum(left**2) / max(left.size - order, 1) * m / max(m - p, 1))
    return coef, scale


def _ar_filtered(nu: np.ndarray, coef, scale: float) -> np.ndarray:
    """What the AR filter ``coef (order,)`` of the past does not predict of each of the innovations
    ``nu (n, rows)``, divided by ``scale`` (the first ``order`` with the lags they have)."""
    out = np.array(nu, float)
    for k, c in enumerate(coef, start=1):
        out[k:] -= c * nu[:-k]
    return out / scale


def _prediction(R: np.ndarray, a: np.ndarray) -> tuple:
    """The estimate ``(p,)`` of the square-root information factor ``R (p + 1, p + 1)`` (scaled
    unknowns, data column last) and ``u = R_p^-T a^T (p, rows)`` for the rows ``a (rows, p)``: ``u^T
    u`` is the estimate's share of the covariance of their residual."""
    r = R[:-1, :-1]
    return lapack.dtrtrs(r, R[:-1, -1])[0], lapack.dtrtrs(r, a.T, trans=1)[0]


def _recursive_innovations(block: np.ndarray, rows: int, scale: np.ndarray) -> np.ndarray:
    """Innovations ``(n, rows)`` of recursive least squares over whitened equations ``block (n rows,
    p + 1)`` (unknowns divided by ``scale (p,)``): each sample's residual at the estimate from the
    samples before it, normalised by its covariance ``I + u^T u``; NaN (untested) until those
    samples give four equations per unknown, the least warm-up (from fewer, the innovations'
    variance ran 12 to 26 % above one on Cepheus logs with measured rates), and while they leave
    the estimate undetermined (a joint still at rest)."""
    p = len(scale)
    eqs = np.asfortranarray(block / np.r_[scale, 1.0])
    out, R = np.full((len(block) // rows, rows), np.nan), None
    for k in range(len(out)):
        a, b = eqs[k * rows : (k + 1) * rows, :p], eqs[k * rows : (k + 1) * rows, p]
        if k * rows >= 4 * (p + 1):
            diag = np.abs(np.diag(R)[:p])
            if diag.min() > 1e-8 * diag.max():
                theta, u = _prediction(R, a)
                out[k] = solve_triangular(np.linalg.cholesky(np.eye(rows) + u.T @ u), b - a @ theta, lower=True)
        R = _accumulate_factor(R, eqs[k * rows : (k + 1) * rows])
    return out


def _increment(rows: int, ratio: float):
    """Scale ``c`` and offset ``d`` of the CUSUM increment ``c nu^T nu - d``: the log-likelihood
    ratio of ``nu ~ N(0, ratio I)`` against ``N(0, I)`` for ``rows`` components."""
    return (1 - 1 / ratio) / 2, rows / 2 * math.log(ratio)


def cusum_run_length(threshold: float, rows: int, ratio: float = CHANGE_RATIO, *, actual: float = 1.0,
                     cells: int = 200) -> float:
    """Average run length [samples] of the chi-square CUSUM until it exceeds ``threshold``.

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
    cdf = lambda x: chi2.cdf(np.maximum((x + d) / (c * actual), 0), rows)  # noqa: E731  P(increment <= x)
    to = cdf(edges[None, :] - start[:, None])  # (cells + 1 states, cells + 1 edges)
    Q = np.empty((cells + 1, cells + 1))
    Q[:, 0] = to[:, 0]  # back to zero
    Q[:, 1:] = np.diff(to, axis=1)
    with one_blas_thread():
        return float(np.linalg.solve(np.eye(cells + 1) - Q, np.ones(cells + 1))[0])


def cusum_threshold(false_alarm_rate: float, rows: int, ratio: float = CHANGE_RATIO) -> float:
    """The CUSUM threshold whose run length between false alarms is ``1 / false_alarm_rate``.

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
        raise SpaceidError(f"--false-alarm-rate {false_alarm_rate!r}: give false alarms per sample in (0, 0.5), "
                           f"e.g. {FALSE_ALARM_RATE:g}")
    if not ratio > 1:
        raise SpaceidError(f"--change-ratio {ratio!r}: give an innovation variance ratio above 1, "
                           f"e.g. {CHANGE_RATIO:g}")
    target = math.log(1 / false_alarm_rate)
    gap = lambda h: math.log(cusum_run_length(h, rows, ratio)) - target  # noqa: E731
    return float(brentq(gap, 1e-6, target + 1.0, xtol=1e-6))


@dataclass(frozen=True)
class MonitorEvent:
    """A detected change.

    Attributes
    ----------
    index : int
        Events in order, from 0.
    time : float
        Estimated change time [s]: the sample within the CUSUM's last excursion from which on
        the innovations are most likely inflated (:meth:`Monitor._change_time`).
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


class _Thinned:
    """At most ``size`` samples of a segment, evenly spaced: when full, every other one is dropped
    and the stride doubles (bounded memory, O(1) amortised work a sample)."""

    def __init__(self, size: int):
        self.size, self.stride, self.seen, self.rows = size, 1, 0, []

    def add(self, row):
        if self.seen % self.stride == 0:
            self.rows.append(row)
            if len(self.rows) > self.size:
                self.rows, self.stride = self.rows[::2], 2 * self.stride
        self.seen += 1

    def until(self, t: float):
        """Drop the samples at or after ``t`` [s] (those after an estimated change)."""
        self.rows = [r for r in self.rows if r[0] < t]


def _rows(log: Log) -> list:
    """The samples of ``log`` as ``(t, q, qd, base_quat, base_w)`` tuples (with drift terms the
    monitor appends each one's drift basis, :meth:`Monitor._rows_with_basis`)."""
    return list(zip(log.t, log.q, log.qd, log.base_quat, log.base_w))


def _log(rows: list, model, source: str) -> Log:
    """The log of ``_rows`` tuples of ``model``'s joints."""
    t, q, qd, quat, w = (np.array(c) for c in list(zip(*rows))[:5])
    return Log(t, tuple(model.joints), q, qd, quat, w, planar=model.planar, meta={"source": source})


class Monitor:
    """Change detection on the momentum equations, one sample at a time (module docstring).

    Parameters
    ----------
    param : Parameterization
        Minimal parameter set of the model.
    momentum : array_like of shape (3,)
        Inertial angular momentum of the whole system [N m s], conserved through the changes
        (a capture from rest adds none); zero needs ``known`` anchors (or a reaction wheel).
        With ``drift``, its value at the log's first sample.
    known : dict, optional
        Known parameter values ``{name: value}``, as :func:`~spaceid.estimation.identify` takes them.
    drift : iterable of {"torque", "viscous", "coulomb"}
        External torques that change the momentum during the log (:mod:`~spaceid.estimation._drift`;
        an air-bearing table's friction, which the test would otherwise take for a change): each
        segment's drift coefficients are estimated with its parameters, the drift integrated from
        the segment's change time, where its momentum is the segment before's at that instant.
    noise : Noise, optional
        Signal noise levels; estimated from the first warm-up (then at least ``NOISE_SAMPLES``
        long) when omitted: give them for the stated false-alarm rate (the rate is sensitive to
        the levels: innovations 10 % larger in variance double it). Must not be all zero.
    false_alarm_rate : float
        False alarms per sample under no change (the threshold's design value).
    change_ratio : float
        Innovation variance ratio the CUSUM is tuned to: larger detects large changes faster and
        small ones slower.
    forgetting : float
        Exponential forgetting factor of the recursive estimate, in (0, 1]; 1: the recursive
        estimate of a segment is its batch weighted least-squares estimate.
    warmup : int, optional
        Samples of each segment identified in batch before its test starts (default
        ``max(WARMUP, 4 (p + 1) / rows)``).
    estimator : str
        Estimator of the batch identifications (:data:`~spaceid.estimation.ESTIMATORS`, not ``angles``).
    max_segment : int
        Most samples of a segment kept for its batch identification (evenly thinned beyond it).
    where : str
        Name of the data source, for error messages.
    """

    def __init__(self, param: Parameterization, momentum, *, known=None, noise: Noise | None = None, drift=(),
                 false_alarm_rate: float = FALSE_ALARM_RATE, change_ratio: float = CHANGE_RATIO,
                 forgetting: float = 1.0, warmup: int | None = None, estimator: str = "ml",
                 max_segment: int = 4000, where: str = "log"):
        if not 0 < forgetting <= 1:
            raise SpaceidError(f"--forgetting {forgetting!r}: give a factor in (0, 1], 1 for no forgetting")
        if estimator == "angles":
            raise SpaceidError("--estimator angles: the monitor needs per-sample momentum equations: use another one")
        if noise is not None and noise.is_zero:
            raise SpaceidError("--noise-*: all zero: the test normalises the residuals by the noise, give its levels "
                               "(or none, to estimate them from the first samples)")
        self.param, self.where, self.drift = param, where, check_drift_kinds(drift)
        self.momentum = np.asarray(momentum, float)
        self.known, self.noise, self.estimator = dict(known or {}), noise, estimator
        # the raw angle noise of differentiated rates: as given, else the differentiator's estimate from the record
        self._raw_levels = (0.0, 0.0) if noise is None or noise.source != "given" else (noise.angle, noise.attitude)
        self.false_alarm_rate, self.change_ratio, self.forgetting = false_alarm_rate, change_ratio, forgetting
        self.threshold = cusum_threshold(false_alarm_rate, param.rows, change_ratio)
        self.expected_delay = cusum_run_length(self.threshold, param.rows, change_ratio, actual=change_ratio)
        self._increment = _increment(param.rows, change_ratio)
        nj = len(param.model.joints)
        rest = Log(np.zeros(1), param.model.joints, np.zeros((1, nj)), np.zeros((1, nj)), np.array([[1.0, 0, 0, 0]]),
                   np.zeros((1, 3)), planar=param.model.planar)
        self._eq = _equations(param, rest, self.momentum, self.known, where, self.drift)[0]  # no anchor: an error now
        p = self._eq.p
        self.warmup = int(warmup) if warmup is not None else max(WARMUP, -(-4 * (p + 1) // param.rows))
        if self.warmup < p + 1:
            raise SpaceidError(f"--warmup {self.warmup}: at least {p + 1} samples are needed to identify a segment")
        self.max_segment = max(int(max_segment), 2 * self.warmup)
        n_x = 2 * nj + (1 if param.model.planar else 6)
        self._block = max(1, 2**22 // (param.rows * (p + 1) * n_x))  # samples whitened at once: 32 MB of derivatives
        self.events, self.segments = [], []
        self.n_samples = self.n_tested = 0
        self._recent = collections.deque(maxlen=self.warmup)  # samples an alarm may hand to the next segment
        self._pending = None  # an alarm whose comparison waits for the next warm-up
        self._t0 = None  # the first sample's stamp [s]: the origin of the differentiators' raw grids
        self._window = None  # the differentiator's window [samples], from the first samples (:meth:`update`)
        self._step_s = 0.0  # the sample step [s], set with it
        self._skip = 0  # samples still to drop after an alarm
        self._tested_until = -math.inf  # the last alarm's time [s]: the samples up to it were tested
        self._held = []  # the last half window of samples: their rates may change with the samples to come
        self._whitener = None  # the Kalman whitening of differentiated rates' errors (:meth:`_set_prewhitening`)
        self._basis_tail = []  # the last samples with their drift basis: the next chunk's quadrature starts there
        self._origin, self._h_origin = None, self.momentum  # the segment's first sample and its momentum there
        self._carried = None  # drift coefficients and their std that the last change's momentum was carried with
        self._open(start=None)
        if noise is None:
            self._target = max(self.warmup, NOISE_SAMPLES)

    # --- segments ----------------------------------------------------------------------------

    def _open(self, start):
        self._warm, self._thinned, self._R, self._g = [], _Thinned(self.max_segment), None, 0.0
        self._trail = []  # the samples from the origin until the warm-up is identified: its drift's history
        self._start, self._count, self._ident, self._target = start, 0, None, self.warmup
        self._prewhitening, self._kalman = None, False  # _kalman: the segment uses the differentiator's whitening
        self._excursion = collections.deque(maxlen=self.warmup)  # (t, nu^T nu) since the CUSUM last left zero

    def _identify(self, rows, label, history) -> Identification:
        """The batch identification of the segment's samples ``rows``, the drift integrated over the
        samples ``history`` from its origin (where the momentum is :attr:`_h_origin`)."""
        log = _log(rows, self.param.model, f"{self.where} {label}")
        history = _log(history, self.param.model, self.where) if self.drift else None
        with warnings.catch_warnings():  # short windows trip the residual checks; the events say what matters
            warnings.simplefilter("ignore")
            return identify(self.param, log, self._h_origin, estimator=self.estimator, known=self.known,
                            noise=self.noise, drift=self.drift, history=history, where=f"{self.where} ({label})")

    def _begin_testing(self) -> list:
        """Identify the warm-up, set the linearisation point, start the recursion on the warm-up
        samples (:meth:`_take_warm_up`); returns the pending event, now with its comparison."""
        rows = self._warm
        if self.noise is None:
            self.noise = dataclasses.replace(noise_from_log(_log(rows, self.param.model, self.where)),
                                             source=f"estimated from the first {len(rows)} samples")
            if self.noise.is_zero:
                raise SpaceidError(f"{self.where}: the first {len(rows)} samples show no noise: give the noise levels "
                                   "(--noise-*)")
        try:
            self._ident = self._identify(rows, f"segment {len(self.segments)} warm-up", self._trail)
        except SpaceidError:
            if self._target + self.warmup > self.max_segment:
                raise
            self._target += self.warmup  # not excited yet (e.g. the arm at rest): wait for more samples
            return []
        self._theta_ref = np.r_[self._ident.values[self._eq.free], [d["value"] for d in self._ident.drift]]
        self._sigma = signal_sigma(self.param, self.noise)
        self._trail = []
        white, L, J, _ = self._whitened(_log(rows, self.param.model, self.where), rows)
        block = white.reshape(-1, white.shape[-1])
        self._scale = _column_scale(block[:, :-1])
        self._R = _accumulate_factor(None, np.asfortranarray(block / np.r_[self._scale, 1.0]))
        nu = self._warm_up_innovations(block, self._set_prewhitening(block, rows, L, J))
        self._warm, events = [], self._complete_pending()
        self._take_warm_up(rows, nu)
        return events

    def _warm_up_innovations(self, block, kalman):
        """The innovations ``(n, rows)`` of a warm-up after an alarm, each predicted from the warm-up's
        samples before it, under the whitening of the segment before (its recording's noise): the
        differentiator's (``kalman``, :meth:`_warm_whitening`), divided by the square root of that
        segment's chi2/dof when above 1 (this warm-up's own would grow with a change within it);
        else those of recursive least squares from the warm-up's start (its whitened equations
        ``block``), through that segment's AR filter if it had one. None for the first warm-up.

        With drift terms, recursive least squares takes the drift coefficients the change's
        momentum was carried with as known: estimated from the warm-up's first samples, whose drift
        basis has barely grown, they leave the parameters' estimate so loose along a direction
        that the regressor's own noise (not in ``I + u^T u``) inflated the innovations (on Cepheus
        logs their variance ran 0.6 to 1.6 over a warm-up at the exact weights)."""
        last = self.segments[-1]["prewhitening"] if self.segments else None
        if last is None:
            return None
        if last["filter"] == "differentiator":
            return kalman / math.sqrt(max(last["chi2_dof"], 1.0))  # its excess as measured, significant or not
        nf = len(self._eq.free)
        if self.drift:  # [A_free | b - A_drift d]
            block = np.column_stack([block[:, :nf], block[:, -1] - block[:, nf:-1] @ self._carried[0]])
        nu = _recursive_innovations(block, self.param.rows, self._scale[:nf])
        return _ar_filtered(nu, last["coefficients"], last["scale"]) if last["order"] else nu

    def _take_warm_up(self, rows: list, nu):
        """Add the warm-up's samples ``rows`` to the segment, testing their innovations ``nu (n,
        rows)`` (:meth:`_warm_up_innovations`; None, or NaN for a sample: untested) too, those after
        the last alarm (the samples of its excursion were tested: again, a false alarm's excursion
        would raise another): a change among them closes the segment there and hands the samples
        after it to the next."""
        for k, row in enumerate(rows):
            test = nu is not None and row[0] > self._tested_until and not np.isnan(nu[k]).any()
            if test and self._cusum(row[0], nu[k]):
                self._R = None  # the warm-up's batch estimate blends the change: no recursive estimate
                self._alarm(row)
                rest = rows[k + 1 :]
                self._trail += rest if self.drift else []
                drop = min(self._skip, len(rest))
                self._skip -= drop
                self._warm, self._count = self._warm + rest[drop:], self._count + len(rest) - drop
                return
            self._thinned.add(row)
            self._recent.append(row)
        self._g = 0.0  # the samples after the warm-up are tested afresh, with this segment's whitening
        self._excursion.clear()

    def _set_prewhitening(self, block, rows, L, J):
        """The segment's prewhitening from the warm-up's whitened equations ``block (m, p + 1)`` at
        its batch estimate, their whiteners ``L`` and Jacobians ``J`` there: the differentiator's
        Kalman whitening when the log records Savitzky-Golay rates (:meth:`_warm_whitening`) and the
        warm-up agrees with its model: its innovations independent (Ljung-Box) and not smaller than
        predicted (the lower tail of chi2/dof), both at ``SIGNIFICANCE``. Otherwise an
        AR(``AR_ORDER``) filter and the std it leaves, fitted to the residuals, when the rates were
        differentiated or the residuals are autocorrelated (Ljung-Box, as the identification's
        covariance choice); else none (the innovations are independent). Returns the warm-up's
        innovations under the differentiator's whitening ``(n, rows)`` (None without one)."""
        res = (block[:, -1] - block[:, :-1] @ self._theta_ref).reshape(len(rows), self.param.rows)
        checks = _residual_checks(res, res.size, None)
        nu, chi2_dof, kalman_scale, kalman_p = None, None, 1.0, None
        if self._whitener:
            nu, chi2_dof, kalman_scale, small = self._warm_whitening(rows, block, res, L, J)
            kalman_p = _residual_checks(nu, nu.size, None)["ljung_box_p"]
        self._kalman = bool(self._whitener) and kalman_p >= SIGNIFICANCE and not small
        correlated = self._window or checks["ljung_box_p"] < SIGNIFICANCE
        order = AR_ORDER if not self._kalman and correlated and len(rows) > 4 * AR_ORDER else 0
        coef, scale = _ar_fit(res, order, len(self._theta_ref)) if order else (np.zeros(0), 1.0)
        self._ar, self._ar_scale, self._kalman_scale = coef, scale, kalman_scale
        self._history = collections.deque(list(res[len(res) - order :]), maxlen=order)  # the lags of the first test
        self._prewhitening = {"filter": "differentiator" if self._kalman else "autoregressive" if order else None,
                              "order": order, "coefficients": coef.tolist(), "scale": scale, "chi2_dof": chi2_dof,
                              "differentiator_scale": kalman_scale if self._whitener else None,
                              "innovations_ljung_box_p": kalman_p,
                              "lag1_autocorrelation": checks["lag1_autocorrelation"],
                              "ljung_box_p": checks["ljung_box_p"], "differentiator_window": self._window or 0}
        return nu

    def _warm_whitening(self, rows, block, res, L, J) -> tuple:
        """Run the differentiator's whitening over the warm-up's residuals ``res (n, rows)`` (its state
        then predicts the first tested sample): its innovations ``(n, rows)``, their chi2/dof (``p``
        unknowns fitted), the scale the test divides them by: 1, or ``sqrt(chi2/dof)`` when they are
        larger than the noise model predicts (the upper tail below ``SIGNIFICANCE``: effects it
        does not have), and whether they are smaller than it predicts (the lower tail)."""
        self._start_whitener()
        a = block[:, :-1].reshape(len(rows), self.param.rows, len(self._scale)) / self._scale
        Li = np.linalg.inv(L)
        R = Li @ equation_covariance(J, self._whitener.uncovered(self._sigma)) @ np.swapaxes(Li, -1, -2)
        nu = [self._whitener.innovation(r, self._whitener.design(row[0], ai, li @ j), c)
              for row, r, ai, li, j, c in zip(rows, res, a, Li, J, R)]  # fmt: skip
        dof = max(res.size - len(self._theta_ref), 1)
        chi2_dof = float(np.sum(np.square(nu)) / dof)
        scale = math.sqrt(chi2_dof) if chi2.sf(chi2_dof * dof, dof) < SIGNIFICANCE else 1.0
        return np.array(nu), chi2_dof, scale, bool(chi2.cdf(chi2_dof * dof, dof) < SIGNIFICANCE)

    def _start_whitener(self):
        """Start the differentiator's whitening with the estimate's error ``PRIOR`` times as uncertain
        as the segment's weighted least-squares estimate says, no direction's variance above
        ``PRIOR_CEILING``."""
        p = len(self._scale)
        r_inv = solve_triangular(self._R[:p, :p], np.eye(p))
        variances, axes = np.linalg.eigh(PRIOR * r_inv @ r_inv.T)
        self._whitener.start((axes * np.minimum(variances, PRIOR_CEILING)) @ axes.T)

    def _rows_with_basis(self, samples: Log) -> list:
        """The new ``samples`` as :func:`_rows` tuples, each with its drift basis ``(n_d, 3)`` from the
        log's first sample appended: the quadrature continued from the last samples before them
        (:func:`drift_basis` over those and these: its one-sided fits and spline see across the
        chunks, the yaw is unwrapped across)."""
        tail, new = self._basis_tail, _rows(samples)
        g = drift_basis(_log(tail + new, self.param.model, self.where), self.drift)
        if tail:
            g = tail[-1][5] + g[len(tail) :] - g[len(tail) - 1]
        new = [r + (gk,) for r, gk in zip(new, g)]
        self._basis_tail = (tail + new)[-BASIS_OVERLAP:]
        return new

    def _whitened(self, log: Log, rows: list, derivatives: bool = False) -> tuple:
        """``log``'s equations ``[A | b]`` (its samples ``rows``, which carry the drift basis)
        whitened by ``S_n`` at the linearisation point, ``(n, rows, p + 1)``, the Cholesky factors
        ``L_n (n, rows, rows)`` of ``S_n``, the equation errors' Jacobians there ``(n, rows, n_x)``
        and, if ``derivatives``, those of the equations ``[A | -b]`` in each signal, ``(n, rows,
        p + 1, n_x)`` (the equation error's Jacobian at any estimate is their product with
        ``[theta; 1]``)."""
        basis = np.array([r[5] for r in rows]) - self._origin[5] if self.drift else None
        eq = dataclasses.replace(self._eq, rot=quat_to_matrix(log.base_quat), basis=basis, momentum=self._h_origin)
        x = eq.signals(log)
        J = eq.jacobian(x, self._theta_ref)
        L = _whiten(equation_covariance(J, self._sigma))
        white = np.linalg.solve(L, eq.phi(x))
        white[..., -1] *= -1
        if not derivatives:
            return white, L, J, None
        n, n_x = x.shape  # every signal direction in one call: the regressor's cost is mostly per call
        tiled = dataclasses.replace(eq, rot=np.tile(eq.rot, (n_x, 1, 1)),
                                    basis=None if basis is None else np.tile(basis, (n_x, 1, 1)))
        D = tiled.dphi(np.tile(x, (n_x, 1)), np.repeat(np.eye(n_x), n, axis=0))
        return white, L, J, np.moveaxis(D.reshape((n_x, n) + D.shape[1:]), 0, -1)

    def _complete_pending(self) -> list:
        if self._pending is None:
            return []
        before = self.segments[-1]["identification"]  # None: a segment too short to identify
        res = [] if before is None else compare(before, self._ident, where=self.where).to_dict()["parameters"]
        event = MonitorEvent(**self._pending, changed=tuple(p["name"] for p in res if abs(p["z"]) > Z_CHANGED),
                             parameters=tuple(res))
        self._pending = None
        self.events.append(event)
        return [event]

    def _close(self, end):
        """Close the running segment at ``end`` [s] (None: the last sample) and identify it."""
        if end is not None:
            self._thinned.until(end)
        rows = self._thinned.rows or self._warm
        record = {"index": len(self.segments), "start": self._start, "end": end, "n_samples": self._count,
                  "n_identified": len(rows), "identification": None, "recursive": self.estimate(),
                  "prewhitening": self._prewhitening, "momentum": self._h_origin.tolist(),
                  "momentum_from": None if self._origin is None else float(self._origin[0])}
        if rows and self.noise is not None:
            history = [self._origin] * bool(self._origin[0] < rows[0][0]) + rows if self.drift else None
            try:
                record["identification"] = self._identify(rows, f"segment {len(self.segments)}", history)
            except SpaceidError:  # too short or not excited: the record says so by its None
                pass
        self.segments.append(record)

    # --- samples -----------------------------------------------------------------------------

    def estimate(self) -> dict | None:
        """The recursive estimate of the running segment: ``values`` (all minimal parameters),
        ``std`` and the ``linearization`` point (the warm-up's batch estimate), each ``(k,)``; with
        drift also ``drift`` and ``drift_std`` ``(n_d,)`` (the coefficients, named as
        :func:`~spaceid.estimation.drift_names`), and the ``momentum`` ``(3,)`` [N m s] they are
        integrated from, at ``momentum_from`` [s]; None during the warm-up.
        With forgetting 1 it is the weighted least-squares estimate of the segment's samples
        (weights at the linearisation point)."""
        if self._R is None:
            return None
        p = len(self._scale)
        r = self._R[:p, :p]
        theta = solve_triangular(r, self._R[:p, p]) / self._scale
        r_inv = solve_triangular(r, np.eye(p))
        std = np.sqrt(np.einsum("ij,ij->i", r_inv, r_inv)) / self._scale
        nf = len(self._eq.free)
        values, stds = self._ident.values.copy(), np.zeros(self.param.n_params)
        values[self._eq.free], stds[self._eq.free] = theta[:nf], std[:nf]
        out = {"values": values, "std": stds, "linearization": self._ident.values}
        if self.drift:
            out |= {"drift": theta[nf:], "drift_std": std[nf:], "momentum": self._h_origin,
                    "momentum_from": np.float64(self._origin[0])}  # fmt: skip
        return out

    def _step(self, row, white, L, D) -> bool:
        """Test one sample, then add it; True on an alarm. ``white``, ``L``, ``D``: the sample's
        whitened equations, their whitener and derivatives (:meth:`_whitened`)."""
        a, b = white[:, :-1] / self._scale, white[:, -1]
        theta, u = _prediction(self._R, a)
        e = b - a @ theta
        # the equation error's covariance at the estimate so far (the weights stay at the linearisation point)
        J = np.einsum("rcx,c->rx", D, np.append(theta / self._scale, 1.0))
        Li = np.linalg.inv(L)
        if self._kalman:  # what the samples before do not predict of the residual at the linearisation point
            C = Li @ equation_covariance(J[None], self._whitener.uncovered(self._sigma))[0] @ Li.T
            e_ref = b - a @ (self._theta_ref * self._scale)
            nu = self._whitener.innovation(e_ref, self._whitener.design(row[0], a, Li @ J), C) / self._kalman_scale
            if self.forgetting < 1:
                self._whitener.forget(self.forgetting)
        else:
            C = Li @ equation_covariance(J[None], self._sigma)[0] @ Li.T + u.T @ u
            nu = solve_triangular(np.linalg.cholesky(C), e, lower=True)
        if len(self._ar):  # prewhitened: what the AR filter of the past innovations does not predict
            recent = np.array([*self._history, nu])  # the order lags, then this sample
            self._history.append(nu)
            nu = _ar_filtered(recent, self._ar, self._ar_scale)[-1]
        if self._cusum(row[0], nu):
            return True
        if self.forgetting < 1:
            self._R *= math.sqrt(self.forgetting)
        self._R = _accumulate_factor(self._R, np.asfortranarray(np.column_stack([a, b])))
        self._thinned.add(row)
        self._recent.append(row)
        self._count += 1
        return False

    def _cusum(self, t: float, nu: np.ndarray) -> bool:
        """Add the normalised innovation ``nu (rows,)`` of the sample at ``t`` [s] to the CUSUM; True
        when it crosses the threshold."""
        c, d = self._increment
        stat = float(nu @ nu)
        self._g = max(0.0, self._g + c * stat - d)
        self._excursion.append((t, stat))
        self.n_tested += 1
        if self._g > self.threshold:
            return True
        if self._g == 0:
            self._excursion.clear()
        return False

    def _change_time(self) -> tuple:
        """The estimated change time [s] and the samples from it to the alarm: the start of the
        excursion's tail that maximises the likelihood ratio of an innovation variance ratio
        estimated from that tail (the CUSUM's own start, tuned to one ratio, often includes a
        sample or two before a large change)."""
        t, stat = np.array(self._excursion).T
        n = np.arange(len(stat), 0, -1) * self.param.rows
        ratio = np.maximum(np.cumsum(stat[::-1])[::-1] / n, 1.0)
        i = int(np.argmax(n / 2 * (ratio - 1 - np.log(ratio))))
        return float(t[i]), len(stat) - i

    def _alarm(self, row):
        """Close the segment at the estimated change and open the next one with the samples since
        (the first of them its origin, where the momentum is the closed segment's: a change
        conserves it)."""
        onset, delay = self._change_time()
        self._tested_until = float(row[0])
        self._pending = {"index": len(self.events), "time": onset, "detected_at": float(row[0]),
                         "delay": delay, "statistic": float(self._g), "threshold": self.threshold,
                         "lead": (self._window or 0) / 2 * self._step_s}  # fmt: skip
        handed = [r for r in self._recent if r[0] >= onset] + [row]
        h = self._momentum_at(handed[0])
        self._close(onset)
        self._recent.clear()
        self._open(start=float(onset))
        self._origin, self._h_origin, self._trail = handed[0], h, list(handed)
        # a differentiator blends the samples within its window of the change: they fit neither segment
        self._skip = max(0, (self._window or 0) - len(handed))
        handed = handed[self._window or 0 :]
        self._warm, self._count = handed, len(handed)

    def _momentum_at(self, row) -> np.ndarray:
        """The momentum ``(3,)`` [N m s] at the sample ``row`` of the running segment: at its origin
        plus its drift since, by the drift coefficients that give it the smaller standard error:
        the segment's so far (recursive, else its warm-up's), or the ones carried from the segments
        before when it is too short to fix them (a 2 s warm-up of a Cepheus log left them 6 times
        as uncertain as they are large); the choice is carried on."""
        if not self.drift:
            return self._h_origin
        own = self._theta_ref[len(self._eq.free) :], np.array([d["std"] for d in self._ident.drift])
        if self._R is not None:
            recursive = self.estimate()
            own = recursive["drift"], recursive["drift_std"]
        moved = row[5] - self._origin[5]  # (n_d, 3): the drift basis since the origin

        def variance(estimate):
            return np.sum((estimate[1][:, None] * moved) ** 2)

        self._carried = min([own] + ([self._carried] if self._carried else []), key=variance)
        return self._h_origin + np.einsum("k,ki->i", self._carried[0], moved)

    def _read_differentiation(self, samples: Log):
        """The differentiator's window from the first samples, and its filters from each part's
        record (a bag's parts are differentiated one by one)."""
        if self._window is None and samples.n_samples > 1:
            self._window = _correlation_length(samples)
            self._step_s = float(np.median(np.diff(samples.t)))  # the sample step [s]
            # the log's first half window has one-sided windows, as the last: extrapolated rates, never taken
            half = -(-self._window // 2)
            self._skip, self._warm = max(half - len(self._warm), 0), self._warm[half:]
            self._count = len(self._warm)
        if self._whitener is None or not self._whitener.follows(samples):
            series = differentiated_series(samples)
            self._whitener = DifferentiatedWhitener(series, self._t0, self._eq.p, self._raw_levels) if series else None
            self._kalman = self._kalman and self._whitener is not None
            if self._kalman:  # new filters within a tested segment: start afresh
                self._start_whitener()

    def update(self, samples: Log) -> list:
        """Feed new samples (a :class:`~spaceid.data.Log` of one or more rows, after those fed
        before); returns the events they complete, in order (often none).

        A sample is taken once its rates are final: with differentiated rates, once half the
        differentiator's window of samples has come after it (the rates of the log's first and last
        half windows come from one-sided windows: extrapolations, never taken)."""
        if self._start is None and samples.n_samples:
            self._start = self._t0 = float(samples.t[0])
        self.n_samples += samples.n_samples
        self._read_differentiation(samples)
        rows, events, i = self._held + (self._rows_with_basis(samples) if self.drift else _rows(samples)), [], 0
        half = -(-(self._window or 0) // 2)
        cut = max(len(rows) - half, 0)
        rows, self._held = rows[:cut], rows[cut:]
        if not rows:
            return events
        if half:
            samples = dataclasses.replace(_log(rows, self.param.model, self.where), meta=samples.meta)
        if self._origin is None:  # the log's first sample: the first segment's origin
            self._origin = rows[0]
        while True:
            if self._R is None and len(self._warm) >= self._target:
                events += self._begin_testing()
                continue
            if i >= len(rows):
                break
            if self._skip:  # samples blended across a change (:meth:`_alarm`), or the log's first half window
                drop = min(self._skip, len(rows) - i)
                self._trail += rows[i : i + drop] if self.drift else []
                i, self._skip = i + drop, self._skip - drop
                continue
            if self._R is None:  # warming up
                take = min(len(rows) - i, self._target - len(self._warm))
                self._warm += rows[i : i + take]
                self._trail += rows[i : i + take] if self.drift else []
                self._count += take
                i += take
                continue
            end = min(len(rows), i + self._block)
            white, L, _, D = self._whitened(samples.select(slice(i, end)), rows[i:end], derivatives=True)
            for k in range(len(white)):
                if self._step(rows[i + k], white[k], L[k], D[k]):
                    self._alarm(rows[i + k])
                    end = i + k + 1
                    break
            i = end
        return events

    def finish(self) -> dict:
        """Close the last segment and return the record of the run (``EVENTS.json``, see
        docs/formats/events-json.md), with each segment's batch identification. The samples held
        back (:meth:`update`: the last half window of differentiated rates) are left out."""
        self._close(None)
        if self._pending is not None:  # an alarm too close to the end for a warm-up: compare with what there is
            before, after = (s["identification"] for s in self.segments[-2:])
            res = compare(before, after, where=self.where).to_dict()["parameters"] if before and after else []
            self.events.append(MonitorEvent(**self._pending, parameters=tuple(res),
                                            changed=tuple(p["name"] for p in res if abs(p["z"]) > Z_CHANGED)))
            self._pending = None
        return self.record()

    def _segment_change(self, k: int) -> dict | None:
        """The change across event ``k`` from the batch identifications of the whole segments on
        either side (None until both are closed and identified): ``changed`` and ``parameters``
        as in :class:`MonitorEvent`."""
        pair = self.segments[k : k + 2]
        if len(pair) < 2 or None in (pair[0]["identification"], pair[1]["identification"]):
            return None
        res = compare(pair[0]["identification"], pair[1]["identification"], where=self.where).to_dict()["parameters"]
        return {"changed": [q["name"] for q in res if abs(q["z"]) > Z_CHANGED], "parameters": res}

    def record(self) -> dict:
        """The JSON-ready record of the events and closed segments so far."""
        names = list(self.param.names)

        def segment(s):
            ident, rec = s["identification"], s["recursive"]
            keys = ("index", "start", "end", "n_samples", "n_identified", "prewhitening", "momentum", "momentum_from")
            return {k: s[k] for k in keys} | {
                "parameters": None if ident is None else [
                    {"name": n, "value": float(v), "std": float(e)} for n, v, e in zip(names, ident.values, ident.std)],
                "drift": None if ident is None else [dict(d) for d in ident.drift],
                "chi2_dof": None if ident is None else ident.diagnostics.chi2_dof,
                "recursive": None if rec is None else {k: v.tolist() for k, v in rec.items()},
            }

        return {
            "model": self.param.model.source or self.param.model.name,
            "planar": self.param.model.planar,
            "momentum": self.momentum.tolist(),
            "n_samples": self.n_samples,
            "n_tested": self.n_tested,
            "settings": {
                "test": "CUSUM of the chi-square log-likelihood ratio of the normalised innovations",
                "false_alarm_rate": self.false_alarm_rate, "change_ratio": self.change_ratio,
                "threshold": self.threshold, "expected_delay": self.expected_delay,
                "forgetting": self.forgetting, "warmup": self.warmup, "estimator": self.estimator,
                "max_segment": self.max_segment, "known": self.known, "z_changed": Z_CHANGED,
                "drift": list(self.drift),
                "noise": None if self.noise is None else self.noise.to_dict(), "parameter_names": names,
            },
            "events": [e.to_dict() | {"segments": self._segment_change(e.index)} for e in self.events],
            "segments": [segment(s) for s in self.segments],
        }


def log_chunks(samples):
    """``samples`` as an iterable of logs: a whole :class:`~spaceid.data.Log` in ``CHUNK`` rows."""
    if isinstance(samples, Log):
        return (samples.select(slice(i, i + CHUNK)) for i in range(0, samples.n_samples, CHUNK))
    return samples


def monitor(param: Parameterization, samples, momentum, **options):
    """Yield the changes of a running log as its samples arrive.

    Parameters
    ----------
    param : Parameterization
        Minimal parameter set of the model.
    samples : Log or iterable of Log
        The samples, in time order: a whole log, or logs of one or more new rows each (a growing
        file, :func:`spaceid.data.follow_log`).
    momentum : array_like of shape (3,)
        Inertial angular momentum of the whole system [N m s].
    **options
        Keywords of :class:`Monitor` (``known``, ``noise``, ``drift``, ``false_alarm_rate``, ``change_ratio``,
        ``forgetting``, ``warmup``, ``estimator``, ``max_segment``, ``where``).

    Yields
    ------
    MonitorEvent
        Each change, once the segment after it has its warm-up identified (or at the end of the
        samples). The generator's return value (``StopIteration.value``) is the run's record,
        :meth:`Monitor.finish`.
    """
    mon = Monitor(param, momentum, **options)
    for chunk in log_chunks(samples):
        yield from mon.update(chunk)
    seen = len(mon.events)
    record = mon.finish()
    yield from mon.events[seen:]
    return record
