"""The linear algebra the estimators share: whitening and least squares through one triangular factor.

The factorisations that the estimators' kernels (:mod:`spaceid.estimation._estimators`,
:mod:`spaceid.estimation._angles`), the covariances (:mod:`spaceid.estimation._uncertainty`), the
streamed passes (:mod:`spaceid.estimation._stream`) and the excitation check share: whitening by
the Cholesky factors of the equation-error covariances (``_whiten``, ``_equation_whitener``,
``_whitened``, ``_inverse_times``, ``_whitened_gram``) and least squares through one upper
triangular factor ``R`` of the column-scaled ``[A | b]`` (``_column_scale``, ``_triangular_factor``,
``_gram_matrix_factor``, ``_solve_factor``, ``_solve``, ``_inverse_gram``, ``_sandwich``). ``R`` is
accumulated over blocks of rows, so a log is factorised a block at a time (and a streaming
estimator can feed the same accumulation, ``_accumulate_gram`` or ``_accumulate_factor``): from
the Gram matrix's Cholesky factor, with the solution refined on the data, while the scaled
condition number is below ``GRAM_COND`` (1e7), and by blocked Householder QR above it (TSQR:
Householder QR of each block stacked under the ``R`` so far). The normal equations alone would
lose ``cond^2`` (on a dual-arm log of scaled condition number 4e6 they lost six digits); the
refinement forms the residual ``b - A x`` first, so its rounding maps to ``eps cond`` as in an
orthogonal factorisation. The solution is ``R^-1 Q^T b`` and the inverse Gram matrix the
covariances use as their "bread" is ``R^-1 R^-T``; noise-free identification is accurate to about
``eps`` times the scaled condition number either way, and on the 496-parameter servicer the
Cholesky path is about three times faster than the QR.

Blocks of samples (``_parts``) and of rows (``_blockwise``: ``_factor_of_rows``, ``_gram_of_rows``) run on
``work_threads()`` threads, their results joined in order, so nothing depends on the thread count.
"""

from __future__ import annotations

import functools
from concurrent.futures import ThreadPoolExecutor

import numpy as np
from scipy.linalg import cho_solve, lapack, solve_triangular

from .._threads import one_blas_thread, threads_for
from ._noise import equation_covariance


def _whiten(S):
    """Cholesky factors ``L (n, rows, rows)`` of the equation covariances, ``S = L L^T``; a
    floor of 1e-12 of the mean variance keeps noise-free channels finite."""
    mean = np.trace(S, axis1=-2, axis2=-1).mean() / S.shape[-1]
    eye = np.eye(S.shape[-1])
    return np.linalg.cholesky(S + (1e-12 * mean if mean > 0 else 1.0) * eye)


def _equation_whitener(eq, x, theta, sigma):
    """:func:`_whiten` of the equation-error covariances at signals ``x (n, n_x)`` and ``theta``
    for signal noise ``sigma (n_x,)``."""
    return _whiten(equation_covariance(eq.jacobian(x, theta), sigma))


def lower_inverse(L):
    """The inverses ``(n, r, r)`` of the lower-triangular ``L (n, r, r)`` (the whiteners' Cholesky factors), by
    forward substitution vectorised over the samples: ``np.linalg.inv``, an LU factorisation of each, took ten
    times longer for 10,000 factors of 3 x 3 (3.1 against 0.3 ms), as accurate (``eps cond(L_n)``)."""
    r = L.shape[-1]
    out = np.zeros(L.shape)
    pivot = 1.0 / np.diagonal(L, axis1=-2, axis2=-1)
    for i in range(r):
        out[..., i, i] = pivot[..., i]
        for j in range(i):  # row i of L times column j of the inverse is zero
            out[..., i, j] = -pivot[..., i] * np.sum(L[..., i, j:i] * out[..., j:i, j], axis=-1)
    return out


def _whitened(L, m):
    """``L^-1 m`` sample by sample, ``m (n, rows, c)``: equations of unit error covariance. By the
    inverses of the small factors (:func:`lower_inverse`) and a product: five times faster than a batched solve
    on the servicer's 497 columns (measured), as accurate (``eps cond(L_n)``)."""
    return lower_inverse(L) @ m


def _inverse_times(L, m):
    """``S^-1 m = L^-T L^-1 m`` sample by sample, ``m (n, rows, c)``."""
    inverse = lower_inverse(L)
    return np.swapaxes(inverse, -1, -2) @ (inverse @ m)


def _whitened_gram(L, phi, single: bool = False):
    """The Gram matrix ``(p + 1, p + 1)`` of ``[A | b]`` whitened by ``L (n, rows, rows)``, from the
    equations ``phi = [A | -b] (n, rows, p + 1)``: blocks of samples on threads, summed in order; no
    whitened copy of the equations is formed. ``single``: each block's product in single precision
    (:data:`SINGLE_COND`; 0.06 s against 0.10 s on 10,000 servicer samples, measured), summed in double."""
    size = max(ROW_BLOCK // phi.shape[1], 1)

    def part(rows):
        white = _whitened(L[rows], phi[rows]).reshape(-1, phi.shape[-1])
        if single:
            white = white.astype(np.float32)
        return (white.T @ white).astype(float, copy=False)

    G = functools.reduce(np.add, (g for _, g in _parts(part, len(phi), size)))
    G[-1, :-1] *= -1
    G[:-1, -1] *= -1
    return G


def _gram_matrix_factor(G, refine=None, limit=None):
    """``(scale, R)`` of :func:`_triangular_factor` from the Gram matrix ``G (p + 1, p + 1)`` of
    ``[A | b]``: the column scales the square roots of its diagonal, ``R`` by
    :func:`_cholesky_factor`, the solution refined by ``refine(y) = (A^T (b - A y), |b - A y|)``
    (unscaled) or, without it, the normal equations'; None when the Cholesky factor is not
    accurate enough (``limit``: :func:`_cholesky_factor`'s)."""
    if not np.all(np.isfinite(G)):
        raise np.linalg.LinAlgError("the equations hold non-finite values")
    scale = np.sqrt(np.diag(G)[:-1])
    scale[scale == 0] = 1.0
    both = np.append(scale, 1.0)

    def scaled(x):
        correlation, norm = refine(x / scale)
        return correlation / scale, norm

    R = _cholesky_factor(G / np.outer(both, both), scaled if refine else None, limit)
    return None if R is None else (scale, R)


ROW_BLOCK = 4096
"""Rows of ``[A | b]`` factorised at a time (at least ``4 (p + 1)``): large enough that the
stacked ``R`` costs little, small enough that a block stays in memory for 10^5 samples."""

GRAM_COND = 1e7
"""Largest (estimated) scaled condition number at which the Gram matrix's Cholesky factor is
used: its rounding ``eps cond^2`` is then small enough for the refinement to contract."""

SINGLE_COND = 1e3
"""Largest scaled condition number (estimated in the 1-norm, as :data:`GRAM_COND`) at which a preconditioner's
Gram matrix is formed in single precision (:func:`_whitened_gram`'s ``single``): its rounding, ``eps_32 cond^2``
relative, is then about 6e-2 in the weakest direction at most, far within what an iteration's contraction notices
(the servicer's 10,000-sample equations: estimated 700, 150 in the 2-norm, the rounding 1.4e-3 there)."""

SINGLE_COLUMNS = 256
"""Fewest unknowns at which a preconditioner's Gram matrix is formed in single precision (where
:data:`SINGLE_COND` allows): the product of the whitened equations then dominates its cost. Measured on 10,000
random samples of 3 rows, double against single: 0.036 against 0.027 s at 256 columns, 0.106 against 0.067 s at
496; at 128 and fewer, 3 ms or less saved, and the iterates would carry single precision's rounding for nothing."""

REFINE_STEPS = 8
"""Most refinement steps of the least-squares solution on the Cholesky path (two to four are
typical: each gains ``-log10(eps cond^2)`` digits)."""


def _column_scale(A):
    """Column norms ``(p,)`` of ``A (rows, p)``, zero columns 1: unit-norm columns make ``R``'s
    singular values those of the scaled regressor (the excitation measure)."""
    scale = np.sqrt(np.einsum("ij,ij->j", A, A))
    scale[scale == 0] = 1.0
    return scale


def _accumulate_factor(R, block):
    """Upper triangular factor of ``[R; block]``: ``R_new^T R_new = R^T R + block^T block``.

    ``R (c, c)`` or None (nothing accumulated yet: Householder QR of the block, LAPACK ``dgeqrf``),
    ``block (m, c)`` the next rows (triangular-over-rectangular QR, ``dtpqrt``, which leaves the
    zeros of ``R`` alone). Householder QR is column-wise backward stable: the accumulated factor
    is that of the rows seen so far perturbed by ``eps`` of each column's norm. Call it with BLAS
    on one thread (threaded OpenBLAS ``dgeqrf`` took 50 times longer on busy cores, measured).
    """
    c = block.shape[1]
    if R is None:
        qr, _, _, info = lapack.dgeqrf(block, lwork=64 * c, overwrite_a=True)
        R = np.triu(qr[:c])
        R = np.vstack([R, np.zeros((c - len(R), c))]) if len(R) < c else R  # fewer rows than columns
    else:
        R, _, _, info = lapack.dtpqrt(0, min(64, c), np.asfortranarray(R), block, overwrite_a=True,
                                      overwrite_b=True)  # fmt: skip
    if info != 0:
        raise np.linalg.LinAlgError(f"QR factorisation failed (LAPACK info {info})")
    return np.triu(R)


def _accumulate_gram(G, A, b):
    """``G`` plus the Gram matrix ``(p + 1, p + 1)`` of ``[A | b]`` (``A (m, p)`` a view with unit column stride,
    ``b (m,)``), ``G`` None: nothing accumulated yet. ``A^T A`` by BLAS ``syrk`` on the rows in place: a scaled
    copy of them cost a sixth of the product (the servicer's 30,000 x 496, measured)."""
    gram = np.empty((A.shape[1] + 1, A.shape[1] + 1))
    gram[:-1, :-1] = A.T @ A
    gram[-1, :-1] = gram[:-1, -1] = b @ A
    gram[-1, -1] = b @ b
    return gram if G is None else G + gram


def _blockwise(A, b, accumulate, combine):
    """``accumulate`` over the blocks of ``ROW_BLOCK`` rows of ``A (rows, p)`` and ``b (rows,)``, as
    ``acc = accumulate(acc, A_rows, b_rows)`` from ``acc = None``: interleaved over ``work_threads()`` threads
    (LAPACK and BLAS release the GIL), whose results ``combine(acc, acc)`` joins. BLAS runs on one thread
    meanwhile."""
    rows = max(ROW_BLOCK, 4 * (A.shape[1] + 1))
    starts = range(0, len(A), rows)

    def run(part):
        acc = None
        for start in part:
            acc = accumulate(acc, A[start : start + rows], b[start : start + rows])
        return acc

    threads = threads_for(len(starts))
    with one_blas_thread():
        if threads > 1:  # a pool per call, as for the regressor: no idle threads left for forked workers
            with ThreadPoolExecutor(threads) as pool:
                parts = list(pool.map(run, [starts[i::threads] for i in range(threads)]))
        else:
            parts = [run(starts)]
        return functools.reduce(combine, parts[1:], parts[0])


def _factor_of_rows(A, b, scale):
    """The upper triangular factor ``(p + 1, p + 1)`` of ``[A / scale | b]`` (``A (rows, p)``, ``b (rows,)``) by
    blocked Householder QR (:func:`_accumulate_factor`), each block copied scaled into LAPACK's column-major
    layout."""

    def accumulate(R, A_rows, b_rows):
        block = np.empty((len(A_rows), A_rows.shape[1] + 1), order="F")  # one copy
        np.divide(A_rows, scale, out=block[:, :-1])
        block[:, -1] = b_rows
        return _accumulate_factor(R, block)

    return _blockwise(A, b, accumulate, _accumulate_factor)


def _gram_of_rows(A, b, scale):
    """The Gram matrix ``(p + 1, p + 1)`` of ``[A / scale | b]`` (``A (rows, p)``, ``b (rows,)``): that of the rows
    as they are (:func:`_accumulate_gram`, no copy), scaled once at the end (rounding of ``eps`` per entry either
    way)."""
    both = np.append(scale, 1.0)
    return _blockwise(A, b, _accumulate_gram, np.add) / np.outer(both, both)


def _gram_factor(A, b, scale):
    """The factor of :func:`_triangular_factor` from the Cholesky factor of the Gram matrix of
    ``[A / scale | b]`` (:func:`_cholesky_factor`, the solution refined on the data), or None."""

    def refine(x):  # the residual formed first: its rounding maps to eps cond
        residual = b - A @ (x / scale)
        return (residual @ A) / scale, np.linalg.norm(residual)

    return _cholesky_factor(_gram_of_rows(A, b, scale), refine)


def _cholesky_factor(G, refine=None, limit=None):
    """The factor of :func:`_triangular_factor` from the Gram matrix ``G (p + 1, p + 1)`` of
    ``[A_s | b]`` (``A_s`` the column-scaled regressor), or None when its Cholesky fails or the scaled
    condition number (estimated) exceeds ``limit`` (:data:`GRAM_COND` when None), or the refinement does not
    settle.

    The Gram matrix holds ``A``'s information to ``eps cond^2``, so its solution is refined on
    the data, ``refine(x) = (A_s^T (b - A_s x), |b - A_s x|)``: ``x += G^-1 A_s^T (b - A_s x)`` until a
    step no longer shrinks the correction. The factor returned is ``[[r, r x], [0, |b - A_s x|]]``,
    ``r^T r`` the Gram matrix of ``A_s``: :func:`_solve_factor` reads the refined ``x`` from it.
    Without ``refine``, ``x`` is the normal equations' (enough where only ``r`` is used)."""
    p = len(G) - 1
    with one_blas_thread():
        r, info = lapack.dpotrf(G[:p, :p])
        if info != 0 or not lapack.dtrcon(r)[0] * (limit or GRAM_COND) >= 1:
            return None
        x = cho_solve((r, False), G[:p, p])
        residual = np.sqrt(max(G[p, p] - np.sum((r @ x) ** 2), 0.0))
        size = np.inf
        for _ in range(REFINE_STEPS if refine else 0):
            correlation, residual = refine(x)
            step = cho_solve((r, False), correlation)
            x += step
            previous, size = size, np.linalg.norm(step)
            if not size > 1e-15 * np.linalg.norm(x) or size > 0.5 * previous:  # at the rounding floor
                break
        if refine and not size <= 1e-6 * np.linalg.norm(x):
            return None
    R = np.zeros((p + 1, p + 1))
    R[:p, :p], R[:p, p], R[p, p] = r, r @ x, residual
    return R


def _triangular_factor(A, b, scale):
    """Factor ``R (p + 1, p + 1)`` of ``[A / scale | b]`` (``A (rows, p)``, ``b (rows,)``): ``R[:p, :p]``
    is the regressor's (``R^T R`` its Gram matrix), ``R[:p, p]`` is ``Q^T b`` (``R[:p, :p]`` times the
    least-squares solution) and ``|R[p, p]|`` the residual norm of the fit.

    By Cholesky of the Gram matrix with the solution refined (:func:`_gram_factor`) when the
    scaled condition number is below ``GRAM_COND``, three times faster; otherwise by blocked
    Householder QR (:func:`_accumulate_factor`, column-wise backward stable at any conditioning).
    Either is accurate to about ``eps`` times the scaled condition number."""
    R = _gram_factor(A, b, scale)
    if R is None:
        R = _factor_of_rows(A, b, scale)
    if not np.all(np.isfinite(R)):
        raise np.linalg.LinAlgError("the equations hold non-finite values")
    return R


def _solve_factor(R, scale, extra=None):
    """Least-squares solution ``(p,)`` and inverse Gram matrix ``(A^T A)^-1 (p, p)`` from the
    factor ``R`` of :func:`_triangular_factor`: the solution of ``A^T A x = A^T b + extra``,
    ``x = R^-1 (Q^T b + R^-T extra)`` in scaled units, and ``R^-1 R^-T``. Raises
    ``LinAlgError`` when ``R`` is singular."""
    p = len(scale)
    r = R[:p, :p]
    with one_blas_thread():
        r_inv = solve_triangular(r, np.eye(p))
        return _factor_solution(R, scale, extra), (r_inv @ r_inv.T) / np.outer(scale, scale)


def _factor_solution(R, scale, extra=None):
    """The least-squares solution ``(p,)`` of :func:`_solve_factor` alone (``O(p^2)``, where the inverse Gram
    matrix costs ``p^3``)."""
    p = len(scale)
    r = R[:p, :p]
    with one_blas_thread():
        rhs = R[:p, p] if extra is None else R[:p, p] + solve_triangular(r, extra / scale, trans="T")
        return solve_triangular(r, rhs) / scale


def _solve(A, b, extra=None, factor=None):
    """Least squares ``min |A x - b|`` by the orthogonal factorisation of the column-scaled
    system; ``extra (p,)`` is added to the right-hand side of the normal equations ``A^T b``
    (the FNS correction), ``factor = (scale, R)`` reuses a factorisation of ``A, b``. Returns the
    solution and the inverse Gram matrix ``(A^T A)^{-1}``."""
    scale, R = factor if factor is not None else (_column_scale(A), None)
    return _solve_factor(_triangular_factor(A, b, scale) if R is None else R, scale, extra)


def _inverse_gram(A):
    """``(A^T A)^{-1}`` of ``A (rows, p)``, by :func:`_solve`."""
    return _solve(A, np.zeros(len(A)))[1]


def _sandwich(bread, Z, S_half):
    """``bread Z^T S Z bread^T`` with ``S = blockdiag(L L^T)``, ``Z (n, rows, p)``: the Gram
    matrix of ``bread Z_n^T L_n`` (positive semi-definite whatever the round-off)."""
    zl = (np.swapaxes(Z, -1, -2) @ S_half).transpose(1, 0, 2).reshape(Z.shape[-1], -1)  # Z_n^T L_n, side by side
    x = bread @ zl
    return x @ x.T


def _parts(fn, n, size):
    """``fn(rows)`` for the consecutive slices ``rows`` of ``size`` of ``n`` samples, in order (a
    generator): ``work_threads()`` slices at a time on threads (the kinematics and the array
    operations release the GIL), so no more parts than that are in memory at once."""
    slices = [slice(start, min(start + size, n)) for start in range(0, n, size)]
    threads = threads_for(len(slices))
    with one_blas_thread():
        if threads < 2:
            yield from zip(slices, map(fn, slices))
            return
        with ThreadPoolExecutor(threads) as pool:  # a pool per call, as for the regressor
            for start in range(0, len(slices), threads):
                yield from zip(slices[start : start + threads], pool.map(fn, slices[start : start + threads]))
