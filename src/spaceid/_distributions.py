"""The distribution functions of spaceid's statistical tests (chi-square, F, normal), from :mod:`scipy.special`.

They return what :mod:`scipy.stats` returns, bit for bit (the same special functions, and its
values outside the support: tested), without importing :mod:`scipy.stats`, which takes 0.6 to
0.8 s at the start of every command that checks residuals (:mod:`scipy.special` itself, 0.2 s, is
imported on first use).
"""

from __future__ import annotations

import numpy as np

__all__ = ["chi2_cdf", "chi2_sf", "chi2_isf", "chi2_ppf", "f_sf", "norm_sf"]


def _on_support(x, inside, below, above=None):
    """``inside(x)`` where ``0 < x < inf``, ``below`` at ``x <= 0``, ``above`` (default: ``inside``'s
    limit) at ``+inf``, NaN at NaN; a float for a scalar ``x``, as scipy.stats returns."""
    x = np.asarray(x, dtype=np.promote_types(np.asarray(x).dtype, np.float64))
    open_support = (x > 0) & (x < np.inf)
    out = np.where(x <= 0, below, np.where(x == np.inf, 1.0 - below if above is None else above, np.nan))
    if np.any(open_support):
        out = np.where(open_support, inside(np.where(open_support, x, 1.0)), out)
    return out[()] if out.ndim == 0 else out


def chi2_cdf(x, df):
    """``scipy.stats.chi2.cdf(x, df)`` (``df > 0``)."""
    from scipy import special
    return _on_support(x, lambda y: special.chdtr(df, y), 0.0)


def chi2_sf(x, df):
    """``scipy.stats.chi2.sf(x, df)`` (``df > 0``)."""
    from scipy import special
    return _on_support(x, lambda y: special.chdtrc(df, y), 1.0)


def chi2_isf(p: float, df) -> float:
    """``scipy.stats.chi2.isf(p, df)`` for ``0 < p < 1`` and ``df > 0``."""
    from scipy import special
    return special.chdtri(df, p)


def chi2_ppf(p: float, df) -> float:
    """``scipy.stats.chi2.ppf(p, df)`` for ``0 < p < 1`` and ``df > 0`` (its median at ``p = 0.5``)."""
    from scipy import special
    return 2 * special.gammaincinv(np.asarray(df) / 2, p)


def f_sf(x, dfn, dfd):
    """``scipy.stats.f.sf(x, dfn, dfd)`` (``dfn, dfd > 0``)."""
    from scipy import special
    return _on_support(x, lambda y: special.fdtrc(dfn, dfd, y), 1.0)


def norm_sf(x):
    """``scipy.stats.norm.sf(x)``."""
    from scipy import special
    return special.ndtr(-np.asarray(x, dtype=float))[()]
