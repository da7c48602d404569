"""The runs of a Monte Carlo study: measurement noise on the noise-free motion, optional
differentiation of the rates, identification with every estimator (see
:func:`spaceid.studies.run_montecarlo` for the noise model and the seeds).

:class:`_Study` holds what every run needs and does a chunk of runs; its output, one dict per
chunk, is merged back by :func:`_merge_chunks` and :func:`_differentiation_summary`.
"""

from __future__ import annotations

import warnings
from collections import Counter
from dataclasses import dataclass, replace

import numpy as np

from .._errors import SpaceidError
from ..data import Log, differentiate_log, noise_gains
from ..dynamics import Parameterization
from ..estimation import Noise, identify
from ..motion import add_noise

__all__ = ["differentiated_noise"]

_WHERE = "montecarlo"  # the data source named in the estimators' errors


# --- the noise model of differentiated signals --------------------------------------------------


def _channel_levels(t, info, channels):
    """White-noise equivalents ``(smoothed, derivative)`` of ``channels`` of a
    :func:`spaceid.data.differentiate` record: the channel's noise times the RMS over
    samples of its gains, pooled over the channels by RMS."""
    levels = []
    for c in channels:
        window = info["window"][c] if info["window"] else None
        order = info["order"][c] if info["order"] else None
        smoothing = info["smoothing"][c] if info["smoothing"] else None
        smooth, rate = noise_gains(t, info["method"], window=window, order=order, smoothing=smoothing)
        sigma = info["noise"][c]
        levels.append((sigma * np.sqrt(np.mean(smooth**2)), sigma * np.sqrt(np.mean(rate**2))))
    levels = np.asarray(levels)
    return tuple(np.sqrt(np.mean(levels**2, axis=0)))


def differentiated_noise(log: Log) -> Noise:
    """Noise levels of a log whose rates were differentiated from its angles.

    Each channel's noise, as the differentiator estimated it (``info["noise"]``), is propagated
    through its filter: a linear smoother with weights ``s_i`` and derivative weights ``d_i``
    at sample i turns white noise ``sigma`` into errors of std ``sigma |s_i|`` on the smoothed
    angle and ``sigma |d_i|`` on the rate. The RMS over samples and channels gives the scalar
    levels of :class:`~spaceid.estimation.Noise`. Base: the yaw for planar logs; for spatial ones
    the quaternion's vector part, whose noise is half the rotation's (so levels double).

    These are per-sample levels: the errors are correlated over the window (and the
    differentiator's bias is not counted), which a white-noise model cannot express.

    Parameters
    ----------
    log : Log
        Output of :func:`spaceid.data.differentiate_log` (``meta["differentiation"]``).

    Returns
    -------
    Noise
        ``angle`` [rad], ``rate`` [rad/s], ``base_rate`` [rad/s], ``attitude`` [rad].

    Raises
    ------
    SpaceidError
        The log was not differentiated.
    """
    record = log.meta.get("differentiation")
    if not record:
        raise SpaceidError("differentiated_noise: the log's rates were not differentiated (no "
                           "meta['differentiation']): use spaceid.data.differentiate_log first")
    t = np.asarray(log.t, float)
    joints = record["joints"]
    angle, rate = _channel_levels(t, joints, range(len(joints["noise"])))
    base = record["base"]
    planar = base.get("planar", log.planar)
    att, base_rate = _channel_levels(t, base, [0] if planar else [1, 2, 3])
    factor = 1.0 if planar else 2.0
    return Noise(float(angle), float(rate), float(factor * base_rate), float(factor * att),
                 source="differentiator: its noise estimate propagated through its filter weights (per-sample, "
                        "white-noise equivalent)")  # fmt: skip


def _differentiator_choice(log: Log) -> dict:
    """The method and the window, order or smoothing the differentiator chose for the joint and
    the base signals of a differentiated log (the options it did not use left out)."""
    record = log.meta["differentiation"]
    keys = ("method", "window", "order", "smoothing")
    return {part: {key: record[part][key] for key in keys if record[part][key] is not None}
            for part in ("joints", "base")}  # fmt: skip


# --- one chunk of runs --------------------------------------------------------------------------


@dataclass(frozen=True)
class _Study:
    """What every run needs; sent once to each worker process."""

    param: Parameterization
    clean: Log
    momentum: np.ndarray
    noise: Noise
    estimators: tuple
    angles_only: bool
    differentiate: dict

    def measure(self, state) -> Log:
        """The clean log with run noise: joint signals from the first state, base signals from
        the second (rates none when angles only)."""
        n = self.noise
        rate, base_rate = (0.0, 0.0) if self.angles_only else (n.rate, n.base_rate)
        joints = add_noise(self.clean, angle=n.angle, rate=rate, seed=int(state[0]))
        base = add_noise(self.clean, angle=n.attitude, rate=base_rate, seed=int(state[1]))
        meta = dict(joints.meta, noise_seed_base=int(state[1]), noise_attitude=n.attitude, noise_base_rate=base_rate)
        return replace(joints, base_quat=base.base_quat, base_w=base.base_w, meta=meta)

    def estimate(self, log: Log, noise: Noise, estimator: str) -> tuple:
        """``(result, None, warnings)`` of one identification of a run, or ``(None, reason, [])``
        when it raised (a ``SpaceidError`` or a singular linear system); ``iv`` gets the
        commanded joint motion as instruments."""
        instruments = (self.clean.q, self.clean.qd) if estimator == "iv" else None
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            try:
                res = identify(self.param, log, self.momentum, estimator=estimator, noise=noise, where=_WHERE,
                               instruments=instruments)  # fmt: skip
            except (SpaceidError, np.linalg.LinAlgError) as exc:
                return None, f"{type(exc).__name__}: {exc}", []
        return res, None, [str(w.message) for w in caught]

    def chunk(self, first: int, states) -> dict:
        """Runs ``first, first + 1, ...`` with noise states ``states (m, 2)``: per estimator the
        estimates and predicted standard errors ``(m, k)`` (NaN where a run failed), failures,
        warnings and, with angles only, each run's noise model and differentiator choice."""
        k, m = self.param.n_params, len(states)
        out = {
            "first": first,
            "estimates": {e: np.full((m, k), np.nan) for e in self.estimators},
            "std": {e: np.full((m, k), np.nan) for e in self.estimators},
            "failures": [], "warnings": [], "noise": [], "differentiation": [],
        }  # fmt: skip
        for j, state in enumerate(states):
            run = first + j
            measured = log = self.measure(state)
            noise = self.noise
            if self.angles_only:
                try:
                    log = differentiate_log(log, **self.differentiate)
                except SpaceidError as exc:
                    out["failures"] += [{"run": run, "estimator": e, "reason": f"differentiation: {exc}"}
                                        for e in self.estimators]  # fmt: skip
                    continue
                noise = differentiated_noise(log)
                out["noise"].append(noise)
                out["differentiation"].append(_differentiator_choice(log))
            for e in self.estimators:  # the angles estimator: the measured angles and their noise, not the smoothed
                res, reason, caught = self.estimate(*((measured, self.noise) if e == "angles" else (log, noise)), e)
                if res is None:
                    out["failures"].append({"run": run, "estimator": e, "reason": reason})
                    continue
                out["estimates"][e][j], out["std"][e][j] = res.values, res.std
                out["warnings"] += [{"run": run, "estimator": e, "warning": w} for w in caught]
        return out


# --- the chunks merged --------------------------------------------------------------------------


def _merge_chunks(outputs, estimators, runs: int, k: int) -> tuple:
    """Estimates and predicted standard errors ``{estimator: (runs, k)}``, failures and
    warnings of chunk outputs in run order; raises when every run of every estimator failed."""
    estimates = {e: np.concatenate([o["estimates"][e] for o in outputs]).reshape(runs, k) for e in estimators}
    predicted = {e: np.concatenate([o["std"][e] for o in outputs]).reshape(runs, k) for e in estimators}
    failures = tuple(f for o in outputs for f in o["failures"])
    warned = tuple(w for o in outputs for w in o["warnings"])
    if len(failures) == runs * len(estimators):
        raise SpaceidError(f"every run failed, e.g. run {failures[0]['run']} ({failures[0]['estimator']}): "
                           f"{failures[0]['reason']}")  # fmt: skip
    return estimates, predicted, failures, warned


def _tally(chosen) -> list:
    """Distinct differentiator choices of the runs, each with its number of runs."""
    counts = Counter(repr(c) for c in chosen)
    first = {}
    for c in chosen:
        first.setdefault(repr(c), c)
    return [{**first[key], "runs": n} for key, n in counts.items()]


def _differentiation_summary(outputs, options: dict) -> tuple:
    """The noise model of the differentiated signals for the CRB (each level the RMS over the
    runs) and the record of the differentiation for the settings."""
    levels = [o for out in outputs for o in out["noise"]]
    fields = ("angle", "rate", "base_rate", "attitude")
    rms = {f: float(np.sqrt(np.mean([getattr(n, f) ** 2 for n in levels]))) for f in fields}
    model_noise = Noise(**rms, source="RMS over the runs of the differentiated signals' white-noise equivalent")
    chosen = [d for out in outputs for d in out["differentiation"]]
    record = {
        "options": options,
        "method": chosen[0]["joints"]["method"] if chosen else None,
        "choices": _tally(chosen),
        "noise_model": "per run: spaceid.studies.differentiated_noise of the run's differentiated log",
        "noise_equivalent_rms": model_noise.to_dict(),
    }  # fmt: skip
    return model_noise, record
