"""The directions of parameter space that a log does not determine (docs/theory/noise.md, "What the
standard errors mean").

Every estimator here regresses the momentum on a regressor built from measured signals, so the
regressor carries the signals' noise. Its Gram matrix ``G = sum_n A_n^T A_n`` (whitened) is the sum of
the motion's information and of that noise's, ``N = sum_n sum_c sigma_c^2 D_nc^T D_nc`` with
``D_nc = dA_n/dx_c``: in a direction ``v`` of parameter space the regressor's signal is
``v^T G v - v^T N v`` and its noise ``v^T N v``. The first-order (Cramer-Rao) standard errors hold
where the noise-to-signal ratio ``mu = v^T N v / v^T G v`` is small. Where it reaches about one, the
column combination ``A v`` is noise: the estimate along ``v`` is pulled towards zero by the
errors in variables whatever the noise level (1e-7 rad/s of gyro noise alone moved a 7-DOF
satellite's undesigned estimate by 19 first-order standard errors, 1e-5 by 55), and a column that
carries no noise (a drift term, a function of time and attitude) takes up the momentum those
directions leave. The data do not determine such a direction: its value comes from a prior (a CAD
model) or from a motion that excites it.

The ratios are the generalised eigenvalues of ``(N, G)``: in the frame where ``G`` is the identity,
``N``'s eigenvalues, with eigenvectors ``v_k`` normalised so that ``v_k^T G v_k = 1``; the frame from
the regressor's triangular factor, not from ``G`` (whose rounding, ``eps cond^2``, took directions of
a noise-free satellite log at scaled condition number 5e6 for unheld).
"""

from __future__ import annotations

import numpy as np
from scipy.linalg import blas, lapack, solve_triangular

from .._threads import one_blas_thread
from ._noise import FD_STEP

UNDETERMINED = 0.5
"""Noise-to-signal ratio ``mu`` at or above which a direction is taken as not determined by the data:
the regressor's noise along it is at least as large as its signal (``mu / (1 - mu)`` with ``G``'s
noise share ``mu``; a direction determined to first order has ``mu`` near 0)."""


MODEL_SCALE = "the estimate's and the model's own inertias"
"""The scale :func:`identify <spaceid.estimation.identify>` widens the undetermined directions to (:func:`widened`'s
``nominal`` the model's parameters); a payload, which has no model, widens them to the estimate's alone."""
WIDENED = "widened along the {} directions the data do not determine to their values' scale ({})"
"""How the covariance's description ends when :func:`widened` widened it: the directions' count and the scale."""

NOISE_SAMPLES = 400
"""Samples over which :func:`noise_gram` sums (evenly spread, the sum scaled to the log's): the ratios
decide only whether a direction is noise (at 0.5), which a tenth of accuracy settles (400 samples of
a smooth motion give it), and the derivatives cost an equation build per signal channel and a
product per build (1,000 samples: half of a 10,000-sample servicer identification's time)."""


NOISE_PARTS = 2
"""Parts of :func:`noise_rows`' samples whose sums :func:`equation_noise` adds, in order: two threads share
them when the cores are free (the stalled fit's check on the servicer's 500-sample log: 0.24 to 0.16 s),
and the sums are the same on one."""


def noise_rows(n: int) -> tuple:
    """The rows ``(m,)`` of a log of ``n`` samples that :func:`noise_gram` sums over and the scale
    ``n / m`` that makes their sum the log's."""
    rows = np.unique(np.linspace(0, n - 1, min(n, NOISE_SAMPLES)).round().astype(int))
    return rows, n / max(len(rows), 1)


def noise_gram(build, x: np.ndarray, sigma: np.ndarray, scale: float = 1.0, linear=slice(0)) -> np.ndarray:
    """``scale sum_n sum_c sigma_c^2 D_nc^T D_nc`` ``(c, c)``: the Gram matrix of the noise that the
    signals ``x (n, n_x)``, of standard deviations ``sigma (n_x,)``, put into the equations ``build(x)``
    ``(n, rows, c)`` (whitened ones), ``D_nc`` their derivatives with respect to signal ``c``.

    Exact for the channels ``linear`` (an index array or slice: the rates, ``eq.rate_channels``, in which the
    equations are linear): the columns at a unit rate and the other rates zero, less those at zero rates; by
    forward differences
    of step ``FD_STEP`` for the others (the angles and attitude: truncation about 1e-5 relative, where the
    ratios need a tenth). Each product over the columns that the signal moves only (a joint moves the
    bodies beyond it: on the dual-arm servicer a quarter of the flops of the whole)."""
    linear, channels = np.zeros(x.shape[1], bool), linear
    linear[channels] = True
    with one_blas_thread():
        at = build(x)
        out = np.zeros((at.shape[-1], at.shape[-1]))
        still = np.where(linear, 0.0, x)
        rest = build(still) if np.any(linear & (sigma > 0)) else None
        for c in np.flatnonzero(sigma > 0):
            moved = (still if linear[c] else x).copy()
            moved[:, c] = 1.0 if linear[c] else moved[:, c] + FD_STEP
            D = (build(moved) - (rest if linear[c] else at)).reshape(-1, out.shape[0])
            D *= sigma[c] if linear[c] else sigma[c] / FD_STEP
            cols = np.flatnonzero(np.any(D != 0, axis=0))
            if len(cols) == len(out):  # (a copy of every column and a scattered sum cost a fifth of the product)
                out += D.T @ D
            else:
                D = D[:, cols]
                out[np.ix_(cols, cols)] += D.T @ D
    return out * scale


def equation_noise(eq, x, sigma, theta, estimator: str, log, whitener=None, extra=None, chunk=None,
                   rhs=False) -> np.ndarray:
    """:func:`noise_gram` ``(p + q, p + q)`` of the columns ``A`` of the equations ``eq`` at the signals
    ``x (n, n_x)`` and estimate ``theta``, with ``extra(part, signals, rows)`` ``(m, rows, q)`` columns
    appended (the drift test's candidates; None: none), and ``-b`` last when ``rhs`` (``(p + q + 1)``
    square: :func:`eiv_bias`'s), summed over :func:`noise_rows`' samples in
    :data:`NOISE_PARTS` parts (or ``chunk`` samples at a time, when given), in order: the parts on the work
    threads when they are free, the same sums on one. Whitened as the estimator's equations: by ``whitener``
    (its Cholesky factors, ``(n, rows, rows)``) or the noise model's at ``theta`` for the weighted estimators,
    as they are for ``ols``; the noise at :func:`signal_levels` of ``sigma (n_x,)``, the estimator's levels."""
    from ._linalg import _equation_whitener, _parts, _whitened

    every, scale = noise_rows(len(x))
    levels = signal_levels(eq.param, log, sigma)

    def gram_of(span):  # the noise Gram matrix of the rows every[span]
        rows = every[span]
        part = eq.select(rows)
        L = None if estimator == "ols" else whitener[rows] if whitener is not None else _equation_whitener(
            part, x[rows], theta, sigma)

        def build(signals):  # the (whitened) columns of the rows
            M = part.phi(signals)
            if extra is not None:
                M = np.concatenate([M[..., :-1], extra(part, signals, rows)] + ([M[..., -1:]] if rhs else []), -1)
            elif not rhs:
                M = M[..., :-1]
            return M if L is None else _whitened(L, M)

        return noise_gram(build, x[rows], levels, scale, eq.rate_channels)

    out = 0.0
    for _, gram in _parts(gram_of, len(every), chunk or -(-len(every) // NOISE_PARTS)):
        out = out + gram
    return out


def signal_levels(param, log, sigma: np.ndarray) -> np.ndarray:
    """The noise levels ``(n_x,)`` of the signals that the regressor's noise is judged by: the estimator's
    ``sigma``, or those estimated from ``log`` when it has none (``ols`` without given levels), the
    differentiated signals' raised to their filters' own
    (:func:`~spaceid.estimation._differentiated.differentiated_sigma`: levels estimated from
    differentiated rates understate them)."""
    from ._differentiated import differentiated_sigma
    from ._noise import noise_from_log, signal_sigma

    return differentiated_sigma(log, sigma if np.any(sigma) else signal_sigma(param, noise_from_log(log)))


EIV_WIDENED = ("widened by the first-order bias that the regressor's noise gives {} (errors in variables: up to "
               "{:.2g} of the standard errors before)")
"""How the covariance's description ends when :func:`eiv_bias` widened it by at least :data:`EIV_SAID`."""
EIV_SAID = 0.1
"""Largest ratio of the bias to a standard error at which the widening goes unsaid (the errors grow by 0.5 %)."""


def eiv_bias(R: np.ndarray, noise: np.ndarray, theta: np.ndarray, rss: float, m: int) -> np.ndarray:
    """The first-order errors-in-variables bias ``(k,)`` of the (weighted) least-squares estimate ``theta (k,)``:
    ``-s G^-1 N_A [theta; 1]``, ``G = R^T R`` the Gram matrix of the regressor ``A`` as the estimator whitens it
    (``R (k, k)`` upper triangular) and ``N_A`` the first ``k`` rows of the noise Gram matrix ``N`` of ``[A | ...
    | -b]`` whitened alike (:func:`equation_noise` with ``rhs``), the ``k`` columns of ``A`` and the last. The
    regressor's noise correlates with the equations' error (``E[A^T (A theta - b)] = N_A [theta; 1]``): least
    squares is off by this on average, a bias that shrinks no faster than its standard errors (both scale with
    the noise level). ``theta``, itself attenuated, stands in for the truth: the bias is understated where it is
    large.

    ``s = min(1, rss / ((1 - k / m) [theta; 1]^T N [theta; 1]))`` scales the levels down to what the residuals
    hold, ``rss`` their (whitened) sum of squares over ``m`` equations: levels estimated from a sparse noise-free
    log (the signal's curvature in its sixth-order differences, 1e-4 rad/s at 12 Hz) predicted a bias of 5e9
    standard errors where the estimate was exact to 4e-12."""
    k = len(theta)
    v = noise[:k, :k] @ theta + noise[:k, -1]
    predicted = (1 - min(k / m, 0.5)) * (theta @ v + theta @ noise[:k, -1] + noise[-1, -1])
    share = min(1.0, rss / predicted) if predicted > 0 else 0.0
    with one_blas_thread():
        return -share * solve_triangular(R, solve_triangular(R, v, trans="T"))


def noise_to_signal(factor: np.ndarray, noise: np.ndarray, above: float | None = None) -> tuple:
    """The noise-to-signal ratios ``mu (k,)`` (ascending) of the directions of parameter space and the
    directions, the columns of ``T (k, k)`` with ``T^T G T = I``: ``factor`` an upper triangular ``R``
    of the (whitened) regressor, ``R^T R = G`` its Gram matrix (from an orthogonal factorisation: the
    regressor's condition number, not its square), ``noise`` its noise's (:func:`noise_gram`), both
    ``(k, k)``. A column the regressor does not hold (a zero pivot) counts as one at ``eps`` of the
    largest: its ratio comes out huge.

    ``above`` given (:data:`UNDETERMINED`): when no ratio reaches it, ``(mu, T)`` are empty, ``(0,)`` and
    ``(k, 0)``, from the ratios alone (the directions cost two thirds of the decomposition: 0.015 s of the
    servicer's 496 parameters); otherwise every ratio and direction as without it."""
    pivots = np.abs(np.diag(factor))
    R = factor + np.diag(np.where(pivots > 0, 0.0, np.finfo(float).eps * max(pivots.max(), 1e-300)))
    with one_blas_thread():
        inverse = solve_triangular(R, np.eye(len(R)))  # upper triangular: its products by BLAS trmm (half a GEMM's)
        ratios = blas.dtrmm(1.0, inverse, blas.dtrmm(1.0, inverse, noise, side=1), trans_a=1)
        if above is not None and not np.max(np.linalg.eigvalsh(ratios), initial=-np.inf) >= above:
            return np.zeros(0), np.zeros((len(R), 0))
        mu, V = np.linalg.eigh(ratios)
        return np.maximum(mu, 0.0), blas.dtrmm(1.0, inverse, V)


def undetermined(mu: np.ndarray, directions: np.ndarray, names, top: int = 3) -> list:
    """The directions with ``mu`` at or above :data:`UNDETERMINED`, worst first: a list of dicts with
    ``noise_to_signal`` and ``parameters``, the ``top`` names that lead each direction (largest
    share of it in units of each parameter's own scale, ``directions`` from :func:`noise_to_signal`)."""
    out = []
    for k in np.flatnonzero(mu >= UNDETERMINED)[::-1]:
        v = np.abs(directions[:, k])
        share = v / max(v.max(), 1e-300)
        lead = np.argsort(-share)[:top]
        out.append({"noise_to_signal": float(mu[k]), "parameters": [str(names[i]) for i in lead if share[i] > 0.1]})
    return out


DIRECTIONS_COND = 1e5
"""Largest scaled condition number at which the directions come from the Gram matrix's Cholesky factor:
its rounding, about ``eps cond^2`` relative in the weakest direction, is then below 1e-6; above it, from
an orthogonal factorisation (the Gram matrix took a noise-free satellite log's directions at scaled
condition number 5e6 for unheld)."""


def regressor_factor(A: np.ndarray) -> np.ndarray:
    """An upper triangular ``R (p, p)`` with ``R^T R = A^T A`` for ``A (m, p)``, accurate in the weakest
    directions: from the Gram matrix's Cholesky factor below :data:`DIRECTIONS_COND`, else by blocked
    Householder QR (both column-scaled, a block of rows at a time on the work threads)."""
    from ._linalg import _column_scale, _factor_of_rows, _gram_of_rows

    scale, zero = _column_scale(A), np.zeros(len(A))
    gram = _gram_of_rows(A, zero, scale)[:-1, :-1]
    with one_blas_thread():
        r, info = lapack.dpotrf(gram)
        if info == 0 and lapack.dtrcon(r)[0] * DIRECTIONS_COND >= 1:
            return np.triu(r) * scale
    return _factor_of_rows(A, zero, scale)[:-1, :-1] * scale


def noise_ratios(eq, x, phi, sigma, theta, estimator: str, log, whitener=None, noise=None, factor=None,
                 above=None) -> tuple:
    """:func:`noise_to_signal` ``(mu, directions)`` of the equations ``eq`` at the signals ``x (n, n_x)``
    (built: ``phi (n, rows, p + 1)``) and estimate ``theta``, whitened as the estimator's
    (:func:`equation_noise`); ``noise`` their noise Gram matrix ``(p, p)`` if already formed; ``factor``:
    ``(scale, R, cond)``, the column-scaled factor of ``[A | b]`` whitened as here (``ols``: as they are;
    ``ml``: by ``whitener``) and its scaled condition number, reused below :data:`DIRECTIONS_COND`, and whatever it
    is when ``phi`` is None (streamed: the factor a stream forms, its weakest ratios then rounded by up to ``eps
    cond^2``, 1e-2 at the Gram matrix's limit); ``above`` as :func:`noise_to_signal`'s."""
    from ._linalg import _equation_whitener, _whitened

    if noise is None:
        noise = equation_noise(eq, x, sigma, theta, estimator, log, whitener)
    if factor is not None and (factor[2] < DIRECTIONS_COND or phi is None):
        R = factor[1][:-1, :-1] * factor[0]
    else:
        L = None if estimator == "ols" else whitener if whitener is not None else _equation_whitener(eq, x, theta,
                                                                                                     sigma)
        R = regressor_factor((phi if L is None else _whitened(L, phi))[..., :-1].reshape(-1, eq.p))
    return noise_to_signal(R, noise, above)


def widened(cov: np.ndarray, mu: np.ndarray, directions: np.ndarray, theta: np.ndarray,
            nominal: np.ndarray) -> np.ndarray:
    """The covariance ``cov (k, k)`` of the estimate ``theta (k,)`` widened along the directions the data
    do not determine (``mu`` at or above :data:`UNDETERMINED`; :func:`noise_to_signal`'s ``mu (k,)`` and
    ``directions (k, k)``, ``theta = T c``): each coordinate ``c_j`` there gets the variance
    ``c_j(theta)^2 + c_j(nominal)^2``, its value's scale by the estimate and by ``nominal (k,)`` (the
    model's own parameters: the URDF's inertias). The data hold nothing about such a coordinate, and its
    estimate is pulled towards zero (on a random 66-parameter robot flown on a poor motion, coordinates of
    46 and -71 came out 1.9 and -0.6): its first-order variance, a few units, says nothing of that error,
    and only a scale from outside the data can bound it."""
    weak = mu >= UNDETERMINED
    if not np.any(weak):
        return cov
    with one_blas_thread():
        coords = np.linalg.solve(directions, np.column_stack([theta, nominal]))[weak]
        T = directions[:, weak]
        out = cov + (T * np.sum(coords**2, axis=1)) @ T.T
    return 0.5 * (out + out.T)


def undetermined_directions(eq, x, phi, sigma, theta, estimator: str, log, whitener=None, noise=None,
                            factor=None, every: bool = False) -> tuple:
    """:func:`undetermined` of :func:`noise_ratios` (the same arguments), and the ratios and directions
    ``(mu, T)`` themselves: unless ``every`` (:func:`corrected_spread` needs them all), empty when none is
    undetermined (:func:`noise_to_signal`'s ``above``: :func:`widened` needs them only then)."""
    mu, T = noise_ratios(eq, x, phi, sigma, theta, estimator, log, whitener, noise, factor,
                         None if every else UNDETERMINED)
    return undetermined(mu, T, eq.names()), (mu, T)


CORRECTED = ("ML's spread scaled by {} along the directions where the regressor's noise is a share mu of its Gram "
             "matrix (the errors-in-variables correction's: up to {:.2g} times the standard errors before)")
"""How the covariance's description ends when :func:`corrected_spread` scaled it by at least :data:`CORRECTED_SAID`."""
CORRECTED_SAID = 1.1
"""Smallest factor of :func:`corrected_spread` that the covariance's description names (``mu`` about 0.06)."""


def corrected_spread(cov: np.ndarray, mu: np.ndarray, directions: np.ndarray, measured: bool = False) -> tuple:
    """``(cov, largest)``: the covariance ``cov (k, k)`` of an estimate that corrects the errors-in-variables
    attenuation (ML's) with its error along each direction scaled by ``sqrt(1 + mu) / (1 - mu)``, and the largest
    factor (:func:`noise_to_signal`'s every ratio ``mu (k,)`` and direction ``directions (k, k)``; a ratio at or above
    :data:`UNDETERMINED` counts as that, its direction widened by :func:`widened`).

    ``cov`` is ML's first order, ``G^-1`` of the regressor's (whitened) Gram matrix ``G``: the spread of an
    estimate whose regressor is exact. The regressor's noise (Gram matrix ``N``) is part of ``G``; ML removes the
    pull towards zero it gives, and the corrected estimate's error is ``(G - N)^-1`` times the score's, whose spread
    is ``G`` and the noise's products with the equations' own error, at most ``N`` (as much when that error is all
    the regressor's, every signal noisy): ``(G - N)^-1 (G + N) (G - N)^-1``, ``(1 + mu) / (1 - mu)^2`` along each
    direction of ``G^-1``'s (docs/theory/noise.md, "ML's spread"). On an undesigned random planar robot (robot 338,
    40 draws) the errors along its directions at ``mu`` 0.48, 0.14 and 0.025 had an RMS of 1.8, 1.18 and 0.87 of
    the first order's (run 7: 5.4 of them at ``mu`` 0.43), where this gives 2.3, 1.24 and 1.04.

    ``measured``: ``cov`` takes the score's spread from the residuals (Newey-West, White), which hold the noise's
    products already: ``(G - N)^-1`` replaces ``G^-1`` on each side only, ``1 / (1 - mu)``.

    The first order's ``G^-1`` is diagonal in these coordinates (to :data:`DIAGONAL`) and is scaled exactly. A
    covariance that is not (a widening already in it: ML's held directions' shift, rank one across the directions;
    a gyro bias's attitude update; the residuals' own spread) is scaled, then taken as the larger of the two in
    every direction (Loewner order): scaling alone shrank a held shift in some parameters (random spatial robot
    36's pi6, from 5.9 to 7.6 of its standard errors off), and adding ``factor^2 - 1`` times each coordinate's
    variance undid the attitude's measurement of a gyro bias (its errors' RMS 0.23 of the standard errors over 40
    seeds)."""
    from ._uncertainty import larger_of

    capped = np.minimum(mu, UNDETERMINED)
    factor = (1.0 if measured else np.sqrt(1.0 + capped)) / (1.0 - capped)
    largest = float(factor.max(initial=1.0))
    if largest == 1.0:
        return cov, largest
    with one_blas_thread():
        inverse = np.linalg.inv(directions)
        own = inverse @ cov @ inverse.T  # the covariance in the directions' coordinates
        out = (directions * factor) @ own @ (directions * factor).T  # scaled along each
        std = np.sqrt(np.abs(np.diag(own)))
        if not (np.all(std > 0) and np.abs(own / np.outer(std, std) - np.eye(len(own))).max() <= DIAGONAL):
            out = larger_of(cov, 0.5 * (out + out.T))[0]  # a widening in it: the larger of the two
    return 0.5 * (out + out.T), largest


DIAGONAL = 1e-9
"""Largest correlation between two directions' errors at which :func:`corrected_spread` takes a covariance as
diagonal in the directions' coordinates (ML's first order is, to round-off: 1e-12 on the servicer's 496 parameters)
and scales it without the Loewner larger-of (0.05 s there)."""


UNDETERMINED_FIX = "excite them with a designed motion (spaceid design) or give a prior"
"""The advice that ends :func:`undetermined_warning` (a fit with a prior says the prior sets them)."""


def undetermined_warning(directions: list, p: int, where: str, scale: str = MODEL_SCALE,
                         fix: str = UNDETERMINED_FIX) -> str:
    """The warning for the :func:`undetermined` ``directions`` of ``p`` unknowns (``""`` when none): their standard
    errors widened to the ``scale`` named, and ``fix``, the advice that ends it."""
    if not directions:
        return ""
    lead = list(dict.fromkeys(name for d in directions for name in d["parameters"]))
    shown = ", ".join(lead[:8]) + (", ..." if len(lead) > 8 else "")
    return (f"{where}: {len(directions)} of {p} directions of parameter space are not determined by the data (the "
            f"regressor's noise as large as its signal, worst ratio {directions[0]['noise_to_signal']:.2g}; led by "
            f"{shown}): their estimates are pulled towards zero whatever the noise level, and their standard errors "
            f"are widened to the scale of their values ({scale}): {fix}")


def ratios_of_columns(columns: np.ndarray, derivatives, levels: np.ndarray) -> tuple:
    """:func:`noise_to_signal` ``(mu, T)`` with ``above`` :data:`UNDETERMINED` (empty when no ratio reaches it) of
    equations of a shape of their own (the payload's), whose (whitened) columns are ``columns (n, rows, k)``:
    ``derivatives(rows)`` gives those of the samples ``rows`` (:func:`noise_rows`') with respect to each signal,
    ``(m, rows, n_x, k)``, whitened alike, and the signals' noise levels are ``levels (n_x,)``
    (:func:`signal_levels`); the noise Gram matrix is :func:`noise_gram`'s, from the derivatives themselves."""
    rows, scale = noise_rows(len(columns))
    D = derivatives(rows)
    with one_blas_thread():
        noise = scale * np.einsum("nrck,nrcl->kl", D * levels[:, None], D * levels[:, None])
        return noise_to_signal(regressor_factor(columns.reshape(-1, columns.shape[-1])), noise, UNDETERMINED)
