"""Whether a warm-up's samples determine the monitor's estimate (docs/theory/monitor.md, The warm-up).

The momentum equations ``A_n pi = b_n`` carry the signal noise in their regressor ``A_n`` as well
as in their data. Whitened (``L_n^-1``, the noise model at the linearisation point) and with the
unknowns scaled, the regressor's noise adds its own information to that of the motion,

    N = sum_n sum_x sigma_x^2 (L_n^-1 dA_n/dx)^T (L_n^-1 dA_n/dx),

which the least-squares factor ``R`` cannot tell from the motion's: ``R^T R`` is about the
motion's information plus ``N``. Along a direction of the parameters that the motion has barely
moved yet, ``N`` is most of it, and the estimate there is the noise regressed on itself (errors
in variables): attenuated towards zero and biased, to first order, by

    beta = -(R^T R)^-1 g,   g = sum_n sum_x sigma_x^2 (L_n^-1 dA_n/dx)^T (L_n^-1 dr_n/dx),

``r_n = A_n pi - b_n`` the equation error at the estimate, a bias that does not shrink with the
noise in units of the estimate's standard errors (both scale with it) and that its covariance
does not hold. A warm-up of a weakly excited motion then predicts the samples after it far worse
than its covariance says, and the test raises false alarms (on random robots of 25 to 49
parameters with a 4 s warm-up, estimates off by ``e^T P^-1 e`` = 200 to 1,400, of which the
predicted bias accounted for nearly all).

The warm-up determines the estimate when the noise's share of the information in every
direction, ``max eig (R^-T N R^-1)``, is at most ``NOISE_SHARE``, and the predicted bias's mean
square on the warm-up's residuals, ``|R beta|^2`` over the sum of their variances, at most
``BIAS``; the monitor lengthens a warm-up until it does. The first bound keeps the second honest:
along a direction where the share is near 1 the estimate is attenuated about as much, and so is
the bias predicted from it. The bias that remains enters the test's normalisation
(:meth:`~spaceid.estimation.Monitor._innovation`, the score ``g`` accumulated with ``R``).

The levels ``sigma_x`` are the model's, those of differentiated signals their smoothed samples'
(:meth:`~spaceid.estimation._monitor_filter.DifferentiatedWhitener.smoothed`), times the root of
the level the warm-up's residuals show against them when below 1 (:meth:`DeterminacyAccumulator.level`).

Both are evaluated for every prefix of the warm-up at ``CHECKPOINTS`` evenly spaced ends: where
the prefixes determine the estimate from (recorded), and for
each sample the bias of the prefix before it, which the warm-up's own innovations are deflated by.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.linalg import LinAlgError, solve_triangular
from .._distributions import chi2_ppf

from .._threads import one_blas_thread
from ._linalg import _accumulate_factor, lower_inverse

NOISE_SHARE = 0.05
"""Largest share of the regressor noise in the information along any direction of the parameters."""
BIAS = 0.05
"""Largest mean square of the predicted errors-in-variables bias on a warm-up's residuals, against
their noise's variance."""
PREDICTABLE = 0.5
"""Largest share of the noise's information in the variance of a warm-up sample's prediction from
the samples before it for that prediction to be tested (its first-order correction is valid)."""
CHECKPOINTS = 64
"""Prefixes of a warm-up at whose ends its determinacy is evaluated."""
SCREEN_MARGIN = 2.0
"""How many times a bound a warm-up's determinacy at a cheaper estimate than the monitor's must
miss for the warm-up to wait for more samples without the monitor's own estimate
(:meth:`Determinacy.far_from_determined`): the two estimates' figures differ (on a random planar
tree at 750 samples, 0.047 and 0.045 by maximum likelihood, above 0.05 by weighted least
squares), and a screen at the bound itself lengthened warm-ups that the monitor's estimate
determines."""


@dataclass(frozen=True, eq=False)
class Determinacy:
    """How well a warm-up determines the estimate (module docstring).

    Attributes
    ----------
    noise_share : float
        The regressor noise's largest share of the information of the whole warm-up (inf: a
        direction without any).
    bias : float
        The predicted bias's mean squared effect on the warm-up's residuals, against their noise.
    noise : float
        The sum of the warm-up's equation-error variances under the noise model, in the whitened
        units (the number of equations when the whitening is the model's; more or less when the
        rates were differentiated, whose smoothed noise the whitening does not know).
    determined_from : int
        The first sample from which on every prefix of the warm-up determines the estimate (both
        bounds hold for it), the warm-up's length when none does.
    inflation : numpy.ndarray of shape (n,)
        Per sample, how much larger than recursive least squares says the mean square of its
        prediction error from the warm-up's samples before it is: by the predicted bias's squared
        effect on it, from the last checkpoint before the sample (NaN: no honest prediction, the
        noise's share of the prediction's variance above ``PREDICTABLE``, where the first-order
        bias is no guide, or the samples before leave a direction without information).
    shares : numpy.ndarray of shape (p,)
        Per unknown, the regressor noise's share of the information along the direction its
        estimate is read from, ``(P N P)_ii / P_ii`` with ``P = (R^T R)^-1`` (scale-free; at most
        ``noise_share``): the unknowns above ``NOISE_SHARE`` are those the warm-up leaves
        undetermined (NaN: a direction without information).
    variances : numpy.ndarray of shape (p,)
        The whole warm-up's ``P_ii``, the unknowns scaled as in the factor ``R`` (NaN as above).
    """

    noise_share: float
    bias: float
    noise: float
    determined_from: int
    inflation: np.ndarray
    shares: np.ndarray | None = None
    variances: np.ndarray | None = None

    @property
    def determined(self) -> bool:
        """Whether the whole warm-up determines the estimate."""
        return self.noise_share <= NOISE_SHARE and self.bias <= BIAS

    @property
    def far_from_determined(self) -> bool:
        """Whether the whole warm-up misses a bound by ``SCREEN_MARGIN`` times or more."""
        return not (self.noise_share <= SCREEN_MARGIN * NOISE_SHARE and self.bias <= SCREEN_MARGIN * BIAS)

    def record(self, n: int) -> dict:
        """The JSON record for a warm-up of ``n`` samples (``warm_up`` of a segment, docs/formats/events-json.md)."""
        return {"n_samples": n, "noise_share": _finite(self.noise_share), "bias": _finite(self.bias)}


def _finite(x: float):
    return float(x) if np.isfinite(x) else None


class DeterminacyAccumulator:
    """Gathers a warm-up's information and its regressor noise's, sample block by sample block.

    Parameters
    ----------
    n : int
        Samples of the warm-up.
    theta : numpy.ndarray of shape (p,)
        The warm-up's estimate (its free parameters, then drift coefficients): the point the bias
        is predicted at.
    sigma : numpy.ndarray of shape (n_x,)
        Signal noise levels.
    """

    def __init__(self, n: int, theta: np.ndarray, sigma: np.ndarray):
        self.n, self.theta1, self.sigma = n, np.append(theta, 1.0), sigma
        self.size = max(1, -(-n // CHECKPOINTS))  # samples per checkpoint
        p = len(theta)
        self.N, self.g, self.noise, self.taken = [], [], [], 0
        self._N, self._g = np.zeros((p, p)), np.zeros(p)

    def add(self, L: np.ndarray, D: np.ndarray):
        """The next samples' whiteners ``L (m, rows, rows)`` and derivatives ``D (m, rows, p + 1, n_x)``
        of their equations ``[A | -b]`` in each signal
        (:func:`~spaceid.estimation._monitor_whitening.whitened_equations`)."""
        m, rows, c, n_x = D.shape
        # In the derivatives' own layout (n_x, m, rows, p + 1) (no copy), whitened a row at a time (a batched product
        # of 3 x 3 whiteners: 4 times as long); the sums from the Gram matrix G of the whitened [A | -b] rows, one
        # matrix product a checkpoint (einsum's own loops: 5 times as long, 0.2 s of each of the satellite's warm-up
        # screens): N = G[:p, :p], and g = G[:p] [theta; 1], A's product with the rows' errors.
        inverse, signals = lower_inverse(L), np.moveaxis(D, -1, 0)
        E = np.empty(signals.shape)
        for i in range(rows):
            np.einsum("ns,xnsc->xnc", inverse[:, i], signals, out=E[:, :, i])
        E *= self.sigma[:, None, None, None]
        with one_blas_thread():
            errors = (E.reshape(-1, c) @ self.theta1).reshape(n_x, m, rows)  # the equation errors at theta
            self.noise.append(np.sum(errors**2, axis=(0, 2)))  # each sample's error variance
            i = 0
            while i < m:
                j = min(m, i + self.size - self.taken % self.size)
                block = E[:, i:j].reshape(-1, c)  # (a copy: the samples' rows of every signal together)
                G = block.T @ block
                self._N += G[:-1, :-1]
                self._g += G[:-1] @ self.theta1
                self.taken += j - i
                i = j
                if self.taken % self.size == 0 or self.taken == self.n:
                    self.N.append(self._N.copy())
                    self.g.append(self._g.copy())

    @property
    def score(self) -> np.ndarray:
        """The bias's score ``g (p,)`` of the samples so far (module docstring), at the model's levels."""
        return self._g.copy()

    def level(self, res: np.ndarray, p: int) -> float:
        """The noise's variance against the model's that the warm-up's whitened residuals ``res (n,
        rows)`` (at its estimate, ``p`` unknowns fitted) show, at most 1 (levels given as bounds):
        the median of each sample's squared residuals over its variance under the model, against
        the chi-square's (robust to a change within the warm-up, which inflates those after it)."""
        noise = np.concatenate(self.noise)
        rows = res.shape[1]
        ratio = np.sum(res**2, axis=1) / np.maximum(noise, np.finfo(float).tiny) * res.size / max(res.size - p, 1)
        return float(min(1.0, np.median(ratio) / (chi2_ppf(0.5, rows) / rows)))

    @property
    def total(self) -> float:
        """The sum of the equation-error variances so far under the noise model, in the whitened units."""
        return float(sum(np.sum(x) for x in self.noise))

    def result(self, white: np.ndarray, scale: np.ndarray, level: float = 1.0) -> Determinacy:
        """The warm-up's determinacy from its whitened equations ``white (n, rows, p + 1)`` (data
        column last), the unknowns divided by ``scale (p,)``, the noise's variance ``level`` times
        the model's (at most 1: levels given as bounds, the warm-up's residuals smaller)."""
        n, rows, p = white.shape[0], white.shape[1], len(scale)
        a = white[..., :p] / scale
        noise = level * np.concatenate(self.noise)  # each sample's error variance
        inflation, R, start, share, bias = np.full(n, np.nan), None, 0, np.inf, np.inf
        last = None  # the whole warm-up's factor and noise information, when it has information in every direction
        total = float(np.sum(noise))
        determined_from = n
        with one_blas_thread():  # p x p factors: threads only wait on busy cores
            for k, (N, g) in enumerate(zip(self.N, self.g)):
                end = min((k + 1) * self.size, n)
                R = _accumulate_factor(R, np.array(a[start:end].reshape(-1, p), order="F"))  # a copy: overwritten
                start = end
                prefix = _prefix(R, level * N / np.outer(scale, scale), level * g / scale)
                if prefix is None:
                    share = bias = np.inf
                    last, determined_from = None, n
                    continue
                r, C, b, share, bias = prefix
                last = r, C
                so_far = float(np.sum(noise[:end]))
                if not (share <= NOISE_SHARE and bias <= BIAS * so_far):
                    determined_from = n
                elif determined_from == n:
                    determined_from = end
                after = a[end : min(end + self.size, n)]  # the samples this prefix predicts
                if len(after):
                    u = solve_triangular(r, after.reshape(-1, p).T, trans="T").reshape(p, len(after), rows)
                    pred = np.einsum("pnr,pnr->n", u, u)  # the estimate's share of the prediction's variance
                    fake = np.einsum("pnr,pq,qnr->n", u, C, u)  # the part of it the noise's information makes
                    shift = np.sum(np.einsum("pnr,p->nr", u, b) ** 2, axis=1)  # the bias's, squared
                    variance = noise[end : end + len(after)] / rows * (rows + pred)  # of the error, R's P scaled
                    ratio = 1 + shift / np.maximum(variance, np.finfo(float).tiny)
                    inflation[end : end + len(after)] = np.where(fake <= PREDICTABLE * pred, ratio, np.nan)
        bias = bias / total if total > 0 else np.inf  # against the residuals' noise
        shares, variances = (np.full(p, np.nan),) * 2 if last is None else _per_unknown(*last)
        return Determinacy(noise_share=share, bias=bias, noise=total / level if level > 0 else total,
                           determined_from=determined_from, inflation=inflation, shares=shares, variances=variances)


    def overall(self, white: np.ndarray, scale: np.ndarray, level: float = 1.0) -> Determinacy:
        """The whole warm-up's determinacy alone (:meth:`result`'s ``noise_share``, ``bias`` and
        ``noise``, without its prefixes: ``determined_from`` the warm-up's length, ``inflation``
        NaN), from the same arguments: whether a warm-up is determined at all, at a fraction of
        the cost."""
        n, p = white.shape[0], len(scale)
        noise = level * float(sum(np.sum(x) for x in self.noise))
        with one_blas_thread():
            R = _accumulate_factor(None, np.array((white[..., :p] / scale).reshape(-1, p), order="F"))
            prefix = _prefix(R, level * self._N / np.outer(scale, scale), level * self._g / scale)
        share, bias = (np.inf, np.inf) if prefix is None else prefix[3:]
        shares, variances = (np.full(p, np.nan),) * 2 if prefix is None else _per_unknown(prefix[0], prefix[1])
        return Determinacy(noise_share=share, bias=bias / noise if noise > 0 else np.inf,
                           noise=noise / level if level > 0 else noise, determined_from=n,
                           inflation=np.full(n, np.nan), shares=shares, variances=variances)


def _per_unknown(R: np.ndarray, C: np.ndarray) -> tuple:
    """Per unknown, the noise's share of the information ``(P N P)_ii / P_ii`` and ``P_ii``
    (:attr:`Determinacy.shares`, :attr:`Determinacy.variances`), from the factor ``R (p, p)`` and
    ``C = R^-T N R^-1`` (:func:`_prefix`): with ``P = R^-1 R^-T``, ``P N P = R^-1 C R^-T``."""
    Ri = solve_triangular(R, np.eye(len(R)))
    variances = np.einsum("ij,ij->i", Ri, Ri)
    return np.einsum("ij,jk,ik->i", Ri, C, Ri) / variances, variances


def _prefix(R: np.ndarray, N: np.ndarray, g: np.ndarray):
    """For the factor ``R (p, p)`` of a prefix's information, the noise's ``N (p, p)`` and the bias's
    score ``g (p,)`` (scaled unknowns): ``R``, ``C = R^-T N R^-1``, ``b = R^-T g`` (the bias is
    ``-R^-1 b``), the noise share ``max eig C`` and the bias's squared size ``|b|^2``; None when
    ``R`` leaves a direction without information."""
    diag = np.abs(np.diag(R))
    if not diag.min() > 1e-8 * diag.max():
        return None
    try:
        X = solve_triangular(R, N, trans="T")  # R^-T N
        C = solve_triangular(R, X.T, trans="T")  # R^-T N R^-1 (N symmetric)
        C = 0.5 * (C + C.T)
        b = solve_triangular(R, g, trans="T")
        share = float(np.linalg.eigvalsh(C)[-1])
    except (LinAlgError, ValueError):
        return None
    if not (np.isfinite(share) and np.all(np.isfinite(b))):
        return None
    return R, C, b, share, float(b @ b)
