"""Noise level of sampled signals from high-order divided differences on their actual stamps.

The differentiators (:mod:`spaceid.data._signals`) size their bandwidth from this level, and
refuse signals sampled too sparsely for it to measure noise rather than the signal.

The numbered references are in the list of :mod:`spaceid.data._signals`.
"""

from __future__ import annotations

import numpy as np

from .._errors import SpaceidError
from ._signal_checks import _check_quantum, _check_series, _require_samples

__all__ = ["estimate_noise"]

_NOISE_DIFFERENCE = 6  # order of the divided differences that estimate the noise
_MAD_TO_SIGMA = 1.482602218505602  # 1 / Phi^-1(3/4): median absolute deviation to std (Gaussian)
_MAX_DIFFERENCE = 1e-3  # signal-dominated sixth differences above this fraction of the range: too sparse


def estimate_noise(t, x, *, quantum=None):
    """White-noise standard deviation of each channel, from high-order divided differences.

    Sixth-order divided differences on the actual time stamps annihilate every polynomial of
    degree 5 or less, so for a smooth signal they contain the noise alone. Each is scaled to
    unit-norm weights (then its variance is the noise variance) and the robust scale
    ``1.4826 * median(|d|)`` is taken [3]_. Quantisation of ``quantum`` per count is uniform
    noise of variance ``quantum**2 / 12``; the estimate never goes below it (a slow signal
    keeps the same rounding error for many samples and the differences then miss it).

    Parameters
    ----------
    t : array_like of shape (n_samples,)
        Strictly increasing time stamps [s], at least 7.
    x : array_like of shape (n_samples,) or (n_samples, n_channels)
        Samples, e.g. angles [rad].
    quantum : float, optional
        Resolution of the sensor [units of x per count], e.g. ``2 * pi / 4096`` rad for a
        4096 counts-per-revolution encoder.

    Returns
    -------
    sigma : ndarray of shape (n_channels,)
        Noise standard deviation per channel [units of x]; ``n_channels`` is 1 for 1-D ``x``.
    source : list of str
        Per channel, ``"differences"`` or ``"quantum"`` (the quantisation floor was larger).

    Raises
    ------
    SpaceidError
        Non-increasing stamps, non-finite values, fewer than 7 samples or a bad ``quantum``.

    References
    ----------
    .. [3] T. Gasser, L. Sroka and C. Jennen-Steinmetz, "Residual variance and residual pattern
       in nonlinear regression", Biometrika 73(3), 1986.
    """
    t, x, _ = _check_series(t, x, "x")
    quantum = _check_quantum(quantum, "x")
    _require_samples(t.size, _NOISE_DIFFERENCE + 1, "x", "the noise estimate")
    return _noise(t, x, quantum)


def _differences(t, x):
    """The sixth-order divided differences ``(n - 6, m)`` of validated (n, m) samples, scaled to unit-norm
    weights (of a smooth signal: its noise, at the noise's variance)."""
    k = _NOISE_DIFFERENCE
    idx = np.arange(t.size - k)[:, None] + np.arange(k + 1)
    gaps = t[idx][:, :, None] - t[idx][:, None, :]
    gaps[:, np.arange(k + 1), np.arange(k + 1)] = 1.0
    weights = 1.0 / np.prod(gaps, axis=2)
    weights /= np.linalg.norm(weights, axis=1, keepdims=True)
    return np.einsum("ik,ikm->im", weights, x[idx])


def _pooled_noise(t, x, dimensions: int) -> float:
    """The total noise variance of validated (n, m) samples whose noise spans ``dimensions`` directions of
    equal variance at every sample, however it divides among the channels (a unit quaternion's four
    components under a star tracker's small rotations: three), from the squared norms of the differences
    (:func:`_differences`), ``dimensions`` times their median over that of chi-square with ``dimensions``
    degrees of freedom. The channels' own robust scales add up to less where a channel's share of the
    noise varies along the record (the median of a mixture: 10 % less on a servicer's quaternion)."""
    from .._distributions import chi2_ppf

    squares = np.sum(_differences(t, x) ** 2, axis=1)
    return float(dimensions * np.median(squares) / chi2_ppf(0.5, dimensions))


def _noise(t, x, quantum):
    """Per-channel noise std and its source, for validated (n, m) samples (see estimate_noise)."""
    differences = _differences(t, x)
    sigma = _MAD_TO_SIGMA * np.median(np.abs(differences), axis=0)
    floor = 0.0 if quantum is None else quantum / np.sqrt(12.0)
    source = ["quantum" if s < floor else "differences" for s in sigma]
    return np.maximum(sigma, floor), source


def _check_resolution(t, x, sigma, name):
    """Refuse samples too sparse for local polynomial fits.

    For white noise the normalised sixth differences keep their size when every other sample is
    dropped; when they measure the signal instead they grow ~2^6 times. Signal-dominated
    differences above ``_MAX_DIFFERENCE`` of the channel's range mean the signal is not nearly
    polynomial over seven samples: the rates would be wrong, not noisy.
    """
    if t.size < 4 * (_NOISE_DIFFERENCE + 1):
        return
    coarse, _ = _noise(t[::2], x[::2], None)
    span = np.ptp(x, axis=0)
    bad = (((coarse > 4 * sigma) & (sigma > _MAX_DIFFERENCE * span)) | (sigma > 0.1 * span)) & (span > 0)  # or aliased
    if bad.any():
        j = int(np.argmax(bad))
        raise SpaceidError(
            f"{name}: channel {j} is sampled too sparsely to differentiate ({1 / np.median(np.diff(t)):.3g} Hz: its "
            f"sixth differences are signal, {sigma[j] / span[j]:.1%} of its range, not noise): record faster or log "
            "the rates"
        )
