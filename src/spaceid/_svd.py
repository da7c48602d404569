"""The singular value decomposition as the project takes it: NumPy's, and where LAPACK's divide-and-conquer driver
does not converge on a finite matrix, the same decomposition by the QR-iteration driver."""

from __future__ import annotations

import numpy as np

__all__ = ["svd"]


def svd(a, full_matrices: bool = True, compute_uv: bool = True):
    """``numpy.linalg.svd(a, full_matrices, compute_uv)`` (stacked matrices too), with the same shapes and order.

    NumPy calls LAPACK's divide-and-conquer driver (``gesdd``), which can fail to converge on a finite matrix whose
    singular values span many decades: an export's linearised conditions on spatial random robot 1307800870, a
    231 x 176 matrix with singular values from 7.0 to 1.7e-63, raised "SVD did not converge". Then each matrix is
    decomposed by the QR-iteration driver (``gesvd``, SciPy), slower and robust. A matrix with a NaN or an infinity
    raises NumPy's ``LinAlgError`` as before.
    """
    try:
        return np.linalg.svd(a, full_matrices=full_matrices, compute_uv=compute_uv)
    except np.linalg.LinAlgError:
        a = np.asarray(a)
        if not np.all(np.isfinite(a)):
            raise
    from scipy.linalg import svd as by_qr_iteration

    parts = [by_qr_iteration(m, full_matrices=full_matrices, compute_uv=compute_uv, lapack_driver="gesvd")
             for m in a.reshape(-1, *a.shape[-2:])]  # fmt: skip
    if a.ndim == 2:
        return parts[0]
    lead = a.shape[:-2]
    if not compute_uv:
        return np.stack(parts).reshape(*lead, -1)
    return tuple(np.stack(f).reshape(*lead, *f[0].shape) for f in zip(*parts))
