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
   autocorrelated, an AR filter fitted to them. A sample is taken once its rates are final: the
   first and last half windows of differentiated rates never are;
2. feeds a CUSUM of the log-likelihood ratio of an innovation inflated ``change_ratio`` times in
   variance against none; its threshold gives the requested false-alarm rate (one alarm per
   ``1 / false_alarm_rate`` samples on average, :func:`cusum_threshold`);
3. updates the square-root information factor of recursive weighted least squares with
   forgetting (:func:`~spaceid.estimation._estimators._accumulate_factor`): O(p^2) work per
   sample whatever the log's length.

An alarm closes the segment at the estimated change time (within the CUSUM's last excursion
above zero) and starts a new one there; once the new segment's warm-up is identified, the event
reports the z-scores of the change (:func:`~spaceid.estimation.compare`), and that warm-up's own
innovations are tested too, each predicted from the warm-up's samples before it under the
whitening of the segment before. Each closed segment is re-identified in batch from at most
``max_segment`` of its samples (evenly thinned), so memory stays bounded.

With drift terms (an external torque, such as an air-bearing table's friction) the momentum is
``h_s + sum_k d_k (g_k(t) - g_k(t_s))`` in a segment, ``g_k`` the drift basis
(:mod:`~spaceid.estimation._drift`) accumulated chunk by chunk from the log's first sample,
``t_s`` the segment's first sample (the log's, or the estimated change time) and ``d_k`` unknowns
estimated with the parameters; ``h_s`` is the given momentum for the first segment, for the
others the segment before's at ``t_s`` with its drift estimated so far (a change conserves the
momentum). The momentum itself is not estimated: with a wheel spinning at constant speed (its
rotor inertia the only anchor) a short warm-up does not fix the scale, and on the twin its
estimate collapsed to the parameters near zero.

A warm-up lasts until its samples determine the parameters: the signal noise is in the
regressor too, and along a direction the motion has barely moved it makes the estimate the noise
regressed on itself, biased by many of its standard errors
(:mod:`~spaceid.estimation._monitor_determinacy`); the bias that remains enters the innovations'
covariance. The first warm-up is tested in the samples it was lengthened by, from its nominal
length on, each sample predicted from those before it.

The parts: the CUSUM (:mod:`~spaceid.estimation._monitor_cusum`), the whitening and prewhitening
(:mod:`~spaceid.estimation._monitor_whitening`, :mod:`~spaceid.estimation._monitor_filter`), the
samples and their intake (:mod:`~spaceid.estimation._monitor_samples`), the running segment's
state (:mod:`~spaceid.estimation._monitor_state`) and the records
(:mod:`~spaceid.estimation._monitor_records`); :class:`Monitor` runs them.
"""

from __future__ import annotations

import collections
import dataclasses
import math
import warnings

import numpy as np
from scipy.linalg import lapack, solve_triangular

from .._constants import WARMUP
from .._deprecation import deprecated_alias
from .._errors import SpaceidError
from .._threads import one_blas_thread
from ..data import Log
from ..dynamics import Parameterization
from ._differentiated import whitened_series
from ._drift import check_drift_kinds
from ._equations import _equations
from ._linalg import _accumulate_factor, _column_scale
from ._identify import estimate_only, identify
from ._monitor_cusum import CHANGE_RATIO, FALSE_ALARM_RATE, Cusum, cusum_run_length, cusum_threshold
from ._monitor_determinacy import BIAS, NOISE_SHARE, DeterminacyAccumulator
from ._monitor_filter import DifferentiatedWhitener
from ._monitor_records import Z_CHANGED, Alarm, MonitorEvent, MonitorRecord, SegmentRecord
from ._monitor_samples import Intake, Sample, Thinned, log_of
from ._monitor_state import Phase, Segment
from ._monitor_whitening import (_prediction, differentiator_innovations, kalman_check, prewhitening,
                                 warm_up_innovations, whitened_equations, whitener_prior, equation_derivatives)
from ._noise import Noise, equation_covariance, noise_from_log, signal_sigma
from ._result import Identification, compare

__all__ = ["Monitor", "MonitorEvent", "MonitorRecord", "SegmentRecord", "monitor", "cusum_threshold",
           "cusum_run_length", "log_chunks", "Z_CHANGED"]

CHUNK = 256
"""Samples of a whole :class:`~spaceid.data.Log` fed to the monitor at a time (the regressor is vectorised)."""
CHECKED = 50
"""Fewest of a warm-up's last innovations under the differentiator's whitening that its check takes
(it takes those from where the warm-up's samples determine the estimate)."""
NOISE_SAMPLES = 500
"""Samples the noise levels are estimated from when not given: the first warm-up is at least this long."""
FIXED_BYTES = 2**26
"""Most bytes of a warm-up's equations' derivatives remembered from one identification of it to
the next (:meth:`Monitor._fixed`); a longer warm-up's are computed afresh at each."""


def _check_options(forgetting: float, estimator: str, noise: Noise | None):
    """Raise on options the monitor cannot run with."""
    if not 0 < forgetting <= 1:
        raise SpaceidError(f"`forgetting`: {forgetting!r}: give a factor in (0, 1], 1 for no forgetting")
    if estimator == "angles":
        raise SpaceidError("`estimator` 'angles': the monitor needs per-sample momentum equations: use another one")
    if noise is not None and noise.is_zero:
        raise SpaceidError("`noise`: all zero: the test normalises the residuals by the noise, give its levels "
                           "(or none, to estimate them from the first samples)")


def _monitored_equations(param: Parameterization, momentum, known: dict, where: str, drift: tuple):
    """The equations the monitor evaluates chunk by chunk: those of one sample at rest, whose
    anchors and drift terms they share (no anchor for a zero momentum: an error now)."""
    nj = len(param.model.joints)
    rest = Log(np.zeros(1), param.model.joints, np.zeros((1, nj)), np.zeros((1, nj)), np.array([[1.0, 0, 0, 0]]),
               np.zeros((1, 3)), planar=param.model.planar)
    return _equations(param, rest, momentum, known, where, drift)[0]


def _warmup_length(warmup: int | None, p: int, rows: int) -> int:
    """The warm-up [samples]: as given, else ``max(WARMUP, 4 (p + 1) / rows)``; at least ``p + 1``."""
    n = int(warmup) if warmup is not None else max(WARMUP, -(-4 * (p + 1) // rows))
    if n < p + 1:
        raise SpaceidError(f"`warmup`: {n}: at least {p + 1} samples are needed to identify a segment")
    return n


def _derivative_size(param: Parameterization, p: int) -> int:
    """Numbers in one sample's derivatives of its equations in each signal: ``rows (p + 1) n_x``."""
    return param.rows * (p + 1) * (2 * len(param.model.joints) + (1 if param.model.planar else 6))


def _block_size(param: Parameterization, p: int) -> int:
    """Samples whitened at once while testing: 32 MB of derivatives."""
    return max(1, 2**22 // _derivative_size(param, p))


def _raw_levels(noise: Noise | None) -> tuple:
    """The raw angle noise of differentiated rates: as given (joints, base yaw), else 0: the
    differentiator's estimate from the record."""
    return (0.0, 0.0) if noise is None or noise.source != "given" else (noise.angle, noise.attitude)


class Monitor:
    """Change detection on the momentum equations, one sample at a time (module docstring).

    Feed it the samples with :meth:`update`, which returns the events as they are found; then
    :meth:`finish` returns the run's :class:`MonitorRecord` (:func:`monitor` does both).

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
    on_alarm : callable, optional
        Called with each alarm (:class:`~spaceid.estimation._monitor_records.Alarm`: the event's
        time, detection, delay, statistic, threshold and lead, without the comparison) the moment
        the test raises it, a warm-up before its event: a live node announces the change at once.
    """

    def __init__(self, param: Parameterization, momentum, *, known=None, noise: Noise | None = None, drift=(),
                 false_alarm_rate: float = FALSE_ALARM_RATE, change_ratio: float = CHANGE_RATIO,
                 forgetting: float = 1.0, warmup: int | None = None, estimator: str = "ml",
                 max_segment: int = 4000, where: str = "log", on_alarm=None):
        _check_options(forgetting, estimator, noise)
        self.param, self.where, self.drift = param, where, check_drift_kinds(drift)
        self.momentum = np.asarray(momentum, float)
        self.known, self.noise, self.estimator = dict(known or {}), noise, estimator
        self.false_alarm_rate, self.change_ratio, self.forgetting = false_alarm_rate, change_ratio, forgetting
        self.threshold = cusum_threshold(false_alarm_rate, param.rows, change_ratio)
        self.expected_delay = cusum_run_length(self.threshold, param.rows, change_ratio, actual=change_ratio)
        self._eq = _monitored_equations(param, self.momentum, self.known, where, self.drift)
        self.warmup = _warmup_length(warmup, self._eq.p, param.rows)
        self.max_segment = max(int(max_segment), 2 * self.warmup)
        self._block = _block_size(param, self._eq.p)
        self._raw_levels = _raw_levels(noise)
        self.events, self.segments, self.n_samples = [], [], 0
        self._cusum = Cusum(self.threshold, param.rows, change_ratio, memory=self.warmup)
        self._intake = Intake(param.model, where, self.drift)
        self._recent = collections.deque(maxlen=self.warmup)  # samples an alarm may hand to the next segment
        self._waiting = None  # the Alarm whose comparison waits for the next warm-up
        self._on_alarm = on_alarm or (lambda alarm: None)
        self._tested_until = -math.inf  # the last alarm's time [s]: the samples up to it were tested
        self._whitener = None  # the Kalman whitening of differentiated rates' errors (DifferentiatedWhitener)
        self._sigma = None  # the signal noise levels (n_x,), once the noise is known
        self._carried = None  # drift coefficients and their std that the last change's momentum was carried with
        self._last_time = None  # the last sample taken [s]
        target = self.warmup if noise is not None else max(self.warmup, NOISE_SAMPLES)
        self._segment = Segment(start=None, origin=None, momentum=self.momentum, drift=bool(self.drift),
                                target=target, thinned=Thinned(self.max_segment))

    @property
    def n_tested(self) -> int:
        """Samples tested so far."""
        return self._cusum.n_tested

    # --- taking samples ----------------------------------------------------------------------

    @deprecated_alias(old="samples", new="log")
    def update(self, log: Log) -> list:
        """Feed new samples: ``log``, a :class:`~spaceid.data.Log` of one or more rows after those fed
        before; returns the events they complete, in order (often none).

        A sample is taken once its rates are final: with differentiated rates, once half the
        differentiator's window of samples has come after it (the rates of the log's first and last
        half windows come from one-sided windows: extrapolations, never taken)."""
        if self._intake.t0 is None and log.n_samples:
            self._intake.t0 = self._segment.start = float(log.t[0])
        self.n_samples += log.n_samples
        self._read_differentiation(log)
        rows = self._intake.final(log)
        if not rows:
            return []
        self._last_time = float(rows[-1].t)
        if self._intake.half:
            log = dataclasses.replace(log_of(rows, self.param.model, self.where), meta=log.meta)
        if self._segment.origin is None:  # the log's first sample: the first segment's origin
            self._segment.origin = rows[0]
        return self._take(log, rows)

    def _read_differentiation(self, samples: Log):
        """The differentiator's window from the first samples, and its filters from each part's
        record (a bag's parts are differentiated one by one)."""
        half = self._intake.learn_window(samples)
        if half is not None and self._segment.phase is not Phase.TESTING:
            self._segment.drop_first(half)  # the log's first half window: extrapolated rates, never taken
        if self._whitener is None or not self._whitener.follows(samples):
            self._new_whitener(samples)

    def _new_whitener(self, samples: Log):
        """The differentiator's whitening of ``samples``' record (None without one): a segment whose
        test it whitened starts afresh with the new one, or goes on without (no AR filter either)."""
        series = whitened_series(samples)
        self._whitener = DifferentiatedWhitener(series, self._intake.t0, self._eq.p, self._raw_levels,
                                                samples.n_samples) if series else None
        whitening = self._segment.whitening
        if whitening is not None and whitening.kalman:
            whitening.kalman = self._whitener is not None
            if whitening.kalman:
                self._start_whitener()

    def _take(self, samples: Log, rows: list) -> list:
        """Take the final samples ``rows`` (of ``samples``), each as its segment's phase says;
        returns the events completed."""
        events, i = [], 0
        while True:
            segment = self._segment
            if segment.phase is Phase.WARMING_UP and len(segment.warm) >= segment.target:
                events += self._begin_testing()
                continue
            if i >= len(rows):
                return events
            if segment.phase is Phase.DROPPING:
                i = self._drop(rows, i)
            elif segment.phase is Phase.WARMING_UP:
                i = self._warm_up(rows, i)
            else:
                i = self._test(samples, rows, i)

    def _drop(self, rows: list, i: int) -> int:
        """Drop the samples from ``rows[i]`` on that the segment has to (:class:`Phase`); returns the next index."""
        n = min(self._segment.drop, len(rows) - i)
        self._segment.skip(rows[i : i + n])
        return i + n

    def _warm_up(self, rows: list, i: int) -> int:
        """Add the samples from ``rows[i]`` on to the warm-up, until it is complete; returns the next index."""
        n = min(len(rows) - i, self._segment.target - len(self._segment.warm))
        self._segment.take(rows[i : i + n])
        return i + n

    def _test(self, samples: Log, rows: list, i: int) -> int:
        """Test the samples from ``rows[i]`` on, a block at a time, until an alarm; returns the next index."""
        end = min(len(rows), i + self._block)
        white, L, _, D = self._whitened(samples.select(slice(i, end)), rows[i:end], derivatives=True)
        with one_blas_thread():  # a sample's p x p updates: threads only wait (on busy cores, up to 100 times longer)
            for k in range(len(white)):
                if self._step(rows[i + k], white[k], L[k], D[k]):
                    break
            else:
                return end
        self._alarm(rows[i + k])
        return i + k + 1

    # --- the warm-up --------------------------------------------------------------------------

    def _begin_testing(self) -> list:
        """Identify the warm-up, set the linearisation point, start the recursion on the warm-up
        samples (:meth:`_take_warm_up`); returns the waiting event, now with its comparison. A
        warm-up that does not excite every parameter, or whose samples do not determine the
        estimate (:mod:`~spaceid.estimation._monitor_determinacy`), waits for more samples."""
        segment, rows = self._segment, self._segment.warm
        self._estimate_noise(rows)
        label = f"segment {len(self.segments)} warm-up"
        try:
            screen = self._screen(rows, label)
            segment.ident = None if screen is not None and screen.far_from_determined else \
                self._identify(rows, label, segment.trail)
        except SpaceidError as err:
            if segment.target + self.warmup > self.max_segment:
                raise
            segment.target += self.warmup  # not excited yet (e.g. the arm at rest): wait for more samples
            segment.attempt = self._attempt(error=str(err))
            return []
        if segment.ident is None:
            return self._extend_warm_up(screen)
        white, L, J, accumulator, level, determinacy = self._determinacy(
            rows, np.r_[segment.ident.values[self._eq.free], [d["value"] for d in segment.ident.drift]])
        if not determinacy.determined:
            return self._extend_warm_up(determinacy)
        block = white.reshape(-1, white.shape[-1])
        segment.trail = []
        segment.sigma = accumulator.sigma * math.sqrt(level)
        segment.score = level * accumulator.score / segment.scale
        inflation = determinacy.inflation.copy()
        if not self.segments:  # the first warm-up: tested in the samples it was lengthened by
            inflation[: self.warmup] = np.nan
        carried = self._carried[0] if self.drift and self.segments else None
        with one_blas_thread():  # sample by sample: threads only wait on busy cores
            segment.R = _accumulate_factor(None, np.asfortranarray(block / np.r_[segment.scale, 1.0]))
            kalman = self._set_prewhitening(block, rows, L, J, determinacy.noise,
                                            min(determinacy.determined_from, len(rows) - CHECKED))
            if self.segments:
                last = self.segments[-1].prewhitening
            else:  # under the whitening of its samples before the first tested
                last = self._first_whitening(block, kalman, determinacy.noise) if len(rows) > self.warmup else None
            nu = warm_up_innovations(last, block, None if kalman is None else kalman[0], self.param.rows,
                                     segment.scale, len(self._eq.free), carried, inflation)
        tested = [r.t for r, k in zip(rows, nu) if r.t > self._tested_until and not np.isnan(k).any()] \
            if nu is not None else []
        segment.warm_up = determinacy.record(len(rows)) | {
            "end": float(rows[-1].t), "determined_from": float(rows[min(determinacy.determined_from, len(rows) - 1)].t),
            "tested_from": float(tested[0]) if tested else None}
        segment.warm, events = [], self._complete_waiting()
        self._take_warm_up(rows, nu)
        return events

    def _screen(self, rows: list, label: str):
        """The whole warm-up's :class:`~spaceid.estimation._monitor_determinacy.Determinacy` of
        the samples ``rows`` at their weighted least-squares estimate, when the batch estimator is
        maximum likelihood (else None): a warm-up far from determined there
        (:data:`~spaceid.estimation._monitor_determinacy.SCREEN_MARGIN`) waits for more samples
        without the costlier fit (on the twin after a grasp, eleven fits of 0.1 to 0.2 s each of
        warm-ups that were never determined)."""
        if self.estimator != "ml":
            return None
        log = log_of(rows, self.param.model, f"{self.where} {label}")
        history = log_of(self._segment.trail, self.param.model, self.where) if self.drift else None
        theta = estimate_only(self.param, log, self._segment.momentum, estimator="wls", known=self.known,
                              noise=self.noise, drift=self.drift, history=history, where=f"{self.where} ({label})")
        return self._determinacy(rows, theta, True)[-1]

    def _determinacy(self, rows: list, theta: np.ndarray, overall: bool = False) -> tuple:
        """The warm-up ``rows`` linearised at the estimate ``theta`` (free parameters, then drift
        coefficients: the segment's ``theta_ref``; its ``scale`` set too): its whitened equations,
        whiteners and Jacobians (:meth:`_warm_up_equations`), the
        :class:`~spaceid.estimation._monitor_determinacy.DeterminacyAccumulator`, the noise level
        its residuals show and its :class:`~spaceid.estimation._monitor_determinacy.Determinacy`
        (with ``overall``, the whole warm-up's alone)."""
        segment = self._segment
        segment.theta_ref = theta
        self._sigma = signal_sigma(self.param, self.noise)
        white, L, J, accumulator = self._warm_up_equations(rows)
        block = white.reshape(-1, white.shape[-1])
        segment.scale = _column_scale(block[:, :-1])
        res = (block[:, -1] - block[:, :-1] @ segment.theta_ref).reshape(len(rows), self.param.rows)
        level = accumulator.level(res, len(segment.theta_ref))
        determinacy = (accumulator.overall if overall else accumulator.result)(white, segment.scale, level)
        return white, L, J, accumulator, level, determinacy

    def _warm_up_equations(self, rows: list) -> tuple:
        """The warm-up's equations whitened at the linearisation point, ``white``, ``L`` and ``J``
        (:meth:`_whitened`), and the :class:`~spaceid.estimation._monitor_determinacy.DeterminacyAccumulator`
        of their derivatives, a block of samples at a time."""
        log = log_of(rows, self.param.model, self.where)
        sigma = self._whitener.smoothed(self._sigma) if self._whitener else self._sigma  # each sample's noise
        accumulator, parts = DeterminacyAccumulator(len(rows), self._segment.theta_ref, sigma), []
        for i in range(0, len(rows), self._block):
            block = rows[i : i + self._block]
            white, L, J, D = self._whitened(log.select(slice(i, i + self._block)), block, True, self._fixed(block))
            accumulator.add(L, D)
            parts.append((white, L, J))
        white, L, J = (np.concatenate(x) for x in zip(*parts))
        return white, L, J, accumulator

    def _extend_warm_up(self, determinacy) -> list:
        """Wait for a quarter of a warm-up more: the samples so far do not determine the estimate
        (``determinacy``); an error once the warm-up would outgrow ``max_segment``."""
        segment, step = self._segment, max(1, self.warmup // 4)
        segment.attempt = self._attempt(determinacy)
        if segment.target + step > self.max_segment:
            share = "no information" if not np.isfinite(determinacy.noise_share) else \
                f"{determinacy.noise_share:.2g} of the information"
            raise SpaceidError(
                f"{self.where}: segment {len(self.segments)} from {segment.start:g} s: {len(segment.warm)} samples do "
                f"not determine the parameters (the signal noise gives {share} along a direction the motion barely "
                f"moves; its predicted bias {determinacy.bias:.2g} of the residuals' variance): excite the motion "
                "('spaceid design') or give a larger `max_segment`")
        segment.target += step
        return []

    def _attempt(self, determinacy=None, error: str | None = None) -> dict:
        """The record of a warm-up identification that did not determine the estimate
        (:meth:`warm_up_estimate`): its ``determinacy`` at the segment's ``theta_ref``, or the
        ``error`` that refused its samples."""
        segment = self._segment
        out = {"n_samples": len(segment.warm), "time": float(segment.warm[-1].t), "values": None, "std": None,
               "noise_share": None, "bias": None, "bounds": {"noise_share": NOISE_SHARE, "bias": BIAS},
               "undetermined": {}, "error": error}  # fmt: skip
        if determinacy is None:
            return out
        nf, names = len(self._eq.free), self._eq.names()
        std = np.sqrt(determinacy.variances) / segment.scale
        values, stds = self._eq.full(segment.theta_ref)[0], np.zeros(self.param.n_params)
        stds[self._eq.free] = std[:nf]
        undetermined = {names[i]: float(s) for i, s in enumerate(determinacy.shares) if not s <= NOISE_SHARE}
        out |= {"values": values, "std": stds, "noise_share": determinacy.noise_share, "bias": determinacy.bias,
                "undetermined": undetermined}
        if self.drift:
            out |= {"drift": segment.theta_ref[nf:], "drift_std": std[nf:]}
        return out

    def _estimate_noise(self, rows: list):
        """The noise levels from the first warm-up's samples ``rows``, when not given."""
        if self.noise is not None:
            return
        self.noise = dataclasses.replace(noise_from_log(log_of(rows, self.param.model, self.where)),
                                         source=f"estimated from the first {len(rows)} samples")
        if self.noise.is_zero:
            raise SpaceidError(f"{self.where}: the first {len(rows)} samples show no noise: give the noise levels "
                               "(`noise`)")

    def _set_prewhitening(self, block, rows, L, J, noise: float, start: int):
        """The segment's prewhitening (:func:`~spaceid.estimation._monitor_whitening.prewhitening`)
        from the warm-up's whitened equations ``block (m, p + 1)`` at its batch estimate, their
        whiteners ``L`` and Jacobians ``J`` there and the sum of their error variances under the
        noise model ``noise``, the differentiator's innovations checked from sample ``start`` on;
        returns the warm-up under the differentiator's whitening (the tuple of
        :func:`~spaceid.estimation._monitor_whitening.differentiator_innovations`; None without one)."""
        segment = self._segment
        res = (block[:, -1] - block[:, :-1] @ segment.theta_ref).reshape(len(rows), self.param.rows)
        kalman = None
        if self._whitener:
            self._start_whitener()
            a = block[:, :-1].reshape(len(rows), self.param.rows, len(segment.scale)) / segment.scale
            kalman = differentiator_innovations(self._whitener, [r.t for r in rows], a, res, L, J, self._sigma,
                                                len(segment.theta_ref), start)
        segment.whitening = prewhitening(res, len(segment.theta_ref), self._intake.window or 0, kalman, noise)
        return kalman

    def _first_whitening(self, block, kalman, noise: float) -> dict:
        """The prewhitening record that the first warm-up's samples after its nominal length
        (``warmup``) are tested under: that of the samples before, fitted to their residuals at the
        whole warm-up's estimate, which its samples determine (the whole warm-up's residuals would
        take in a change after them, and hide it; the prefix's own estimate, when its samples do
        not determine the parameters, takes in part of their noise, the regressor's noise being the
        equations' own: on a 25-parameter robot a 4 s prefix left its residuals at 0.3 of the
        noise's variance and autocorrelated, and the AR filter fitted to them doubled the
        innovations), from the warm-up's whitened equations ``block (m, p + 1)``, the
        differentiator's innovations over it ``kalman``
        (:func:`~spaceid.estimation._monitor_whitening.differentiator_innovations`, None without)
        and the sum of its error variances under the noise model ``noise``."""
        segment, rows, n = self._segment, self.param.rows, self.warmup
        res = (block[: n * rows, -1] - block[: n * rows, :-1] @ segment.theta_ref).reshape(n, rows)
        p = len(segment.theta_ref) * n * rows // len(block)  # their share of the unknowns fitted
        check = None if kalman is None else kalman_check(kalman[0][:n], p) + (0,)
        return prewhitening(res, p, self._intake.window or 0, check, noise * n * rows / len(block)).record

    def _start_whitener(self):
        """Start the differentiator's whitening for the segment, from its weighted least-squares factor."""
        self._whitener.start(whitener_prior(self._segment.R, len(self._segment.scale)))

    def _take_warm_up(self, rows: list, nu):
        """Add the warm-up's samples ``rows`` to the segment, testing their innovations ``nu (n,
        rows)`` (:func:`~spaceid.estimation._monitor_whitening.warm_up_innovations`; None, or NaN
        for a sample: untested) too, those after the last alarm (the samples of its excursion were
        tested: again, a false alarm's excursion would raise another): a change among them closes
        the segment there and hands the samples after it to the next. Else the segment's test begins."""
        for k, row in enumerate(rows):
            test = nu is not None and row.t > self._tested_until and not np.isnan(nu[k]).any()
            if test and self._cusum.add(row.t, nu[k]):
                self._alarm(row)  # the warm-up's batch estimate blends the change: no recursive estimate
                self._hand_on(rows[k + 1 :])
                return
            self._segment.thinned.add(row)
            self._recent.append(row)
        self._cusum.restart()  # the samples after the warm-up are tested afresh, with this segment's whitening
        self._segment.phase, self._segment.fixed = Phase.TESTING, {}

    def _hand_on(self, rest: list):
        """Give the new segment the samples ``rest`` of the warm-up after a change in it."""
        drop = min(self._segment.drop, len(rest))
        self._segment.skip(rest[:drop])
        self._segment.take(rest[drop:])

    # --- testing ------------------------------------------------------------------------------

    def _step(self, row: Sample, white, L, D) -> bool:
        """Test one sample, then add it; True on an alarm. ``white``, ``L``, ``D``: the sample's
        whitened equations, their whitener and derivatives (:meth:`_whitened`)."""
        a, b = white[:, :-1] / self._segment.scale, white[:, -1]
        if self._segment.warm_up["tested_from"] is None:
            self._segment.warm_up["tested_from"] = float(row.t)
        nu, score = self._innovation(row.t, a, b, L, D)
        if self._cusum.add(row.t, nu):
            return True
        self._segment.add(row, a, b, self.forgetting, score)
        self._recent.append(row)
        return False

    def _innovation(self, t: float, a, b, L, D) -> tuple:
        """The normalised innovation ``(rows,)`` of the sample at ``t`` [s], from its scaled
        regressors ``a (rows, p)`` and data ``b (rows,)``, whitener ``L`` and derivatives ``D``,
        and the sample's errors-in-variables score ``(p,)``: the estimate's first-order bias from
        the regressor's noise, ``-(R^T R)^-1 score`` (:mod:`~spaceid.estimation._monitor_determinacy`),
        moves the prediction by ``a`` times it, which the innovation's covariance takes in."""
        segment, whitener = self._segment, self._whitener
        theta, u = _prediction(segment.R, a)
        # the equation error's covariance at the estimate so far (the weights stay at the linearisation point)
        J = np.einsum("rcx,c->rx", D, np.append(theta / segment.scale, 1.0))
        Li = np.linalg.inv(L)
        E = np.einsum("rs,scx->rcx", Li, D) * segment.sigma  # the noise's whitened directions
        score = np.einsum("rcx,rx->c", E[:, :-1] / segment.scale[:, None], np.einsum(
            "rcx,c->rx", E, np.append(segment.theta_ref, 1.0)))  # fmt: skip
        r = segment.R[:-1, :-1]
        shift = a @ lapack.dtrtrs(r, lapack.dtrtrs(r, segment.score, trans=1)[0])[0]  # -(the bias), predicted
        if segment.whitening.kalman:  # what the samples before do not predict of the residual at theta_ref
            C = Li @ equation_covariance(J[None], whitener.uncovered(self._sigma))[0] @ Li.T + np.outer(shift, shift)
            e_ref = b - a @ (segment.theta_ref * segment.scale)
            nu = whitener.innovation(e_ref, whitener.design(t, a, Li @ J), C) / segment.whitening.kalman_scale
            if self.forgetting < 1:
                whitener.forget(self.forgetting)
        else:
            C = Li @ equation_covariance(J[None], self._sigma)[0] @ Li.T + u.T @ u + np.outer(shift, shift)
            nu = solve_triangular(np.linalg.cholesky(C), b - a @ theta, lower=True)
        return segment.whitening.filtered(nu), score  # what the AR filter of the past innovations does not predict

    def _whitened(self, log: Log, rows: list, derivatives: bool = False, known=None) -> tuple:
        """``log``'s equations (its samples ``rows``) whitened at the segment's linearisation point
        (:func:`~spaceid.estimation._monitor_whitening.whitened_equations`; ``known``, their
        derivatives, when known)."""
        segment = self._segment
        return whitened_equations(self._eq, log, self._basis(rows), segment.momentum, segment.theta_ref, self._sigma,
                                  derivatives, known)

    def _basis(self, rows: list) -> np.ndarray | None:
        """The drift basis ``(n, n_d, 3)`` of the samples ``rows`` since the segment's origin (None without drift)."""
        return np.array([r.basis for r in rows]) - self._segment.origin.basis if self.drift else None

    def _fixed(self, rows: list) -> np.ndarray:
        """The derivatives of the warm-up samples ``rows``' equations in each signal
        (:func:`~spaceid.estimation._monitor_whitening.equation_derivatives`), those of samples
        new to the segment computed and remembered in its ``fixed``: a lengthened warm-up is
        identified again and again, screened and then judged at its estimate, and they do not
        depend on the estimate (the same numbers, laid out as computed at once)."""
        known = self._segment.fixed
        new = [r for r in rows if known.get(id(r), (None,))[0] is not r]
        if (len(known) + len(new)) * _derivative_size(self.param, self._eq.p) * 8 > FIXED_BYTES:  # computed afresh
            return equation_derivatives(self._eq, log_of(rows, self.param.model, self.where), self._basis(rows),
                                        self._segment.momentum)
        if new:
            D = equation_derivatives(self._eq, log_of(new, self.param.model, self.where), self._basis(new),
                                     self._segment.momentum)
            known |= {id(r): (r, D[k]) for k, r in enumerate(new)}  # the sample held: its id stays its own
            if len(new) == len(rows):
                return D
        # each sample's (n_x, rows, p + 1) stacked along the samples: the layout of one computation
        return np.moveaxis(np.stack([np.moveaxis(known[id(r)][1], -1, 0) for r in rows], axis=1), 0, -1)

    def _alarm(self, row: Sample):
        """Close the segment at the estimated change and open the next one with the samples since
        (the first of them its origin, where the momentum is the closed segment's: a change
        conserves it)."""
        onset, delay = self._cusum.change_time()
        self._tested_until = float(row.t)
        self._waiting = Alarm(index=len(self.events), time=onset, detected_at=float(row.t), delay=delay,
                              statistic=float(self._cusum.statistic), threshold=self.threshold,
                              lead=(self._intake.window or 0) / 2 * self._intake.step)  # fmt: skip
        self._on_alarm(self._waiting)
        handed = [r for r in self._recent if r.t >= onset] + [row]
        h = self._momentum_at(handed[0])
        self._close(onset)
        self._recent.clear()
        self._cusum.restart()
        window = self._intake.window or 0  # a differentiator blends the samples within its window of the change
        self._segment = Segment(start=float(onset), origin=handed[0], momentum=h, drift=bool(self.drift),
                                target=self.warmup, thinned=Thinned(self.max_segment), warm=list(handed),
                                trail=list(handed))
        self._segment.drop_first(window + (len(handed) - 1 if window else 0))

    def _momentum_at(self, row: Sample) -> np.ndarray:
        """The momentum ``(3,)`` [N m s] at the sample ``row`` of the running segment: at its origin
        plus its drift since, by the drift coefficients that give it the smaller standard error:
        the segment's so far (recursive, else its warm-up's), or the ones carried from the segments
        before when it is too short to fix them (a 2 s warm-up of a Cepheus log left them 6 times
        as uncertain as they are large); the choice is carried on."""
        segment = self._segment
        if not self.drift:
            return segment.momentum
        own = segment.theta_ref[len(self._eq.free) :], np.array([d["std"] for d in segment.ident.drift])
        if segment.phase is Phase.TESTING:
            recursive = self.estimate()
            own = recursive["drift"], recursive["drift_std"]
        moved = row.basis - segment.origin.basis  # (n_d, 3): the drift basis since the origin

        def variance(estimate):
            return np.sum((estimate[1][:, None] * moved) ** 2)

        self._carried = min([own] + ([self._carried] if self._carried else []), key=variance)
        return segment.momentum + np.einsum("k,ki->i", self._carried[0], moved)

    # --- segments -----------------------------------------------------------------------------

    def _identify(self, rows: list, label: str, history: list | None) -> Identification:
        """The batch identification of the segment's samples ``rows``, the drift integrated over the
        samples ``history`` from its origin (where the momentum is the segment's)."""
        log = log_of(rows, self.param.model, f"{self.where} {label}")
        history = log_of(history, self.param.model, self.where) if self.drift else None
        with warnings.catch_warnings():  # short windows trip the residual checks; the events say what matters
            warnings.simplefilter("ignore")
            return identify(self.param, log, self._segment.momentum, estimator=self.estimator, known=self.known,
                            noise=self.noise, drift=self.drift, history=history, where=f"{self.where} ({label})")

    def _complete_waiting(self) -> list:
        """The waiting alarm's event, the segment before against this one's warm-up (none waiting: [])."""
        if self._waiting is None:
            return []
        event = self._waiting.event(self.segments[-1].identification, self._segment.ident, self.where)
        self._waiting = None
        self.events.append(event)
        return [event]

    def _close(self, end):
        """Close the running segment at ``end`` [s] (None: the last sample) and identify it."""
        segment = self._segment
        if end is not None:
            segment.thinned.until(end)
        rows = segment.thinned.rows or segment.warm
        self.segments.append(SegmentRecord(
            index=len(self.segments), start=segment.start, end=end, n_samples=segment.count, n_identified=len(rows),
            identification=self._identify_segment(rows), recursive=self.estimate(),
            prewhitening=None if segment.whitening is None else segment.whitening.record,
            warm_up=segment.warm_up,
            momentum=segment.momentum.copy(),
            momentum_from=None if segment.origin is None else float(segment.origin.t)))

    def _identify_segment(self, rows: list) -> Identification | None:
        """The batch identification of the running segment from its samples ``rows``; None when
        there are none, or too few or not exciting enough (the record says so by its None)."""
        if not rows or self.noise is None:
            return None
        segment = self._segment
        history = [segment.origin] * bool(segment.origin.t < rows[0].t) + rows if self.drift else None
        try:
            return self._identify(rows, f"segment {len(self.segments)}", history)
        except SpaceidError:
            return None

    @property
    def waiting(self):
        """The last alarm (:class:`~spaceid.estimation._monitor_records.Alarm`) while its event waits
        for the segment after it to have its warm-up identified (the comparison), else None."""
        return self._waiting

    def warm_up_estimate(self) -> dict | None:
        """What the running segment's warm-up has shown while it waits for samples that determine
        the estimate (:mod:`~spaceid.estimation._monitor_determinacy`), as its last identification
        found it (each ``warmup / 4`` samples from ``warmup`` on): ``n_samples`` and ``time`` (its
        last sample [s]); ``values`` and ``std`` ``(k,)``, the estimate of its samples (weighted least
        squares when the estimator is ``ml`` and the samples are far from determined, else the
        estimator's) and the standard errors their information gives (those of the parameters in
        ``undetermined`` do not cover the errors-in-variables bias); ``noise_share`` and ``bias``
        against their bounds ``NOISE_SHARE`` and ``BIAS``; ``undetermined``, ``{name: share}`` of
        the unknowns whose information is more than ``NOISE_SHARE`` the regressor noise's; ``bounds``,
        ``NOISE_SHARE`` and ``BIAS`` (:mod:`~spaceid.estimation._monitor_determinacy`); with drift,
        ``drift`` and ``drift_std`` ``(n_d,)``. When the samples did not excite every parameter,
        ``values`` and ``std`` are None and ``error`` says why. None while the segment is tested,
        and before its warm-up's first identification."""
        return None if self._segment.phase is Phase.TESTING else self._segment.attempt

    def partial_change(self) -> dict | None:
        """While the last alarm's comparison waits for a warm-up that determines the estimate after
        it (:attr:`waiting`): the change of the parameters that the warm-up's samples determine so
        far, the segment before's batch identification against the warm-up's last identification
        (:meth:`warm_up_estimate`): ``parameters`` as in :class:`MonitorEvent`
        (:func:`~spaceid.estimation.compare`) of those outside its ``undetermined`` (whose standard
        errors cover the errors-in-variables bias), ``changed`` those beyond ``Z_CHANGED``,
        ``undetermined`` the names left out. None when no comparison waits, before the warm-up's
        first identification, when its samples do not excite every parameter, or when the segment
        before has no identification (too short)."""
        attempt = self.warm_up_estimate()
        if self._waiting is None or attempt is None or attempt["values"] is None or not self.segments:
            return None
        before = self.segments[-1].identification
        if before is None:
            return None
        after = dataclasses.replace(before, values=np.asarray(attempt["values"]), std=np.asarray(attempt["std"]))
        left_out = attempt["undetermined"]
        res = [q for q in compare(before, after, where=self.where).to_dict()["parameters"] if q["name"] not in left_out]
        return {"changed": [q["name"] for q in res if abs(q["z"]) > Z_CHANGED], "parameters": res,
                "undetermined": sorted(left_out)}

    def estimate(self) -> dict | None:
        """The recursive estimate of the running segment: ``values`` (all minimal parameters),
        ``std`` and the ``linearization`` point (the warm-up's batch estimate), each ``(k,)``; with
        drift also ``drift`` and ``drift_std`` ``(n_d,)`` (the coefficients, named as
        :func:`~spaceid.estimation.drift_names`), and the ``momentum`` ``(3,)`` [N m s] they are
        integrated from, at ``momentum_from`` [s]; None before the segment's test began.
        With forgetting 1 it is the weighted least-squares estimate of the segment's samples
        (weights at the linearisation point)."""
        return self._segment.estimate(self._eq.free, self.param.n_params)

    def finish(self) -> MonitorRecord:
        """Close the last segment and return the record of the run, with each segment's batch
        identification (its :meth:`~MonitorRecord.to_dict` is EVENTS.json, see
        docs/formats/events-json.md). The samples held back (:meth:`update`: the last half window
        of differentiated rates) are left out."""
        self._close(None)
        if self._waiting is not None:  # an alarm too close to the end for a warm-up: compare with what there is
            before, after = (s.identification for s in self.segments[-2:])
            self.events.append(self._waiting.event(before, after, self.where))
            self._waiting = None
        return self.record()

    def record(self) -> MonitorRecord:
        """The record of the events and closed segments so far."""
        return MonitorRecord(
            model=self.param.model.source or self.param.model.name, planar=self.param.model.planar,
            momentum=self.momentum.copy(), n_samples=self.n_samples, n_tested=self.n_tested, settings=self._settings(),
            events=tuple(self.events), segments=tuple(self.segments),
            whole_segment_changes=tuple(self._segment_change(e.index) for e in self.events), last_time=self._last_time,
            statistic=self._cusum.trace.arrays())

    def _settings(self) -> dict:
        """How the test runs: the ``settings`` of EVENTS.json."""
        return {
            "test": "CUSUM of the chi-square log-likelihood ratio of the normalised innovations",
            "false_alarm_rate": self.false_alarm_rate, "change_ratio": self.change_ratio,
            "threshold": self.threshold, "expected_delay": self.expected_delay,
            "forgetting": self.forgetting, "warmup": self.warmup, "estimator": self.estimator,
            "max_segment": self.max_segment, "known": self.known, "z_changed": Z_CHANGED,
            "drift": list(self.drift),
            "noise": None if self.noise is None else self.noise.to_dict(), "parameter_names": list(self.param.names),
        }  # fmt: skip

    def _segment_change(self, k: int) -> dict | None:
        """The change across event ``k`` from the batch identifications of the whole segments on
        either side (None until both are closed and identified): ``changed`` and ``parameters``
        as in :class:`MonitorEvent`."""
        pair = self.segments[k : k + 2]
        if len(pair) < 2 or None in (pair[0].identification, pair[1].identification):
            return None
        res = compare(pair[0].identification, pair[1].identification, where=self.where).to_dict()["parameters"]
        return {"changed": [q["name"] for q in res if abs(q["z"]) > Z_CHANGED], "parameters": res}


@deprecated_alias(old="samples", new="log")
def log_chunks(log):
    """``log`` as an iterable of logs: a whole :class:`~spaceid.data.Log` in ``CHUNK`` rows, an
    iterable of logs as it is."""
    if isinstance(log, Log):
        return (log.select(slice(i, i + CHUNK)) for i in range(0, log.n_samples, CHUNK))
    return log


@deprecated_alias(old="samples", new="log")
def monitor(param: Parameterization, log, momentum, *, on_event=None, **options) -> MonitorRecord:
    """Follow a log for changes as its samples arrive.

    Parameters
    ----------
    param : Parameterization
        Minimal parameter set of the model.
    log : Log or iterable of Log
        The samples, in time order: a whole log, or logs of one or more new rows each (a growing
        file, :func:`spaceid.data.follow_log`).
    momentum : array_like of shape (3,)
        Inertial angular momentum of the whole system [N m s].
    on_event : callable, optional
        Called with each :class:`MonitorEvent` as it is found: once the segment after the change
        has its warm-up identified (or at the end of the samples).
    **options
        Keywords of :class:`Monitor` (``known``, ``noise``, ``drift``, ``false_alarm_rate``, ``change_ratio``,
        ``forgetting``, ``warmup``, ``estimator``, ``max_segment``, ``where``).

    Returns
    -------
    MonitorRecord
        The run's record (:meth:`Monitor.finish`): its ``events`` and ``segments``.
    """
    found = on_event or (lambda event: None)
    mon = Monitor(param, momentum, **options)
    for chunk in log_chunks(log):
        for event in mon.update(chunk):
            found(event)
    seen = len(mon.events)
    record = mon.finish()
    for event in record.events[seen:]:  # a change too close to the end for the next warm-up
        found(event)
    return record
