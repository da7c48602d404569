"""Statistics of a Monte Carlo study over its runs: bias, spread, RMSE, predicted standard error and
efficiency against the Cramer-Rao bound (see :func:`spaceid.studies.run_montecarlo`)."""

from __future__ import annotations

import numpy as np

__all__ = ["STATISTICS"]

STATISTICS = (
    "true", "mean", "bias", "std", "rmse", "relative_rmse", "predicted_std", "crb_std", "rmse_crb", "bias_std",
)  # fmt: skip
"""Per-parameter statistics of :attr:`MonteCarloResult.stats`, each an array of shape (k,):
true value, mean estimate, bias = mean - true, sample std (ddof 1), RMSE about the truth,
RMSE / |true|, mean predicted standard error, Cramer-Rao std, RMSE / CRB std, bias / std."""


def _statistics(estimates, predicted, true, crb_std) -> dict:
    """:data:`STATISTICS` over the finite rows of ``estimates (runs, k)``, with the predicted
    standard errors ``predicted (runs, k)``, the true values ``(k,)`` and the CRB std ``(k,)``."""
    ok = np.all(np.isfinite(estimates), axis=1)
    x, s = estimates[ok], predicted[ok]
    n = len(x)
    nan = np.full(len(true), np.nan)
    mean = x.mean(0) if n else nan
    std = x.std(0, ddof=1) if n > 1 else nan
    rmse = np.sqrt(np.mean((x - true) ** 2, axis=0)) if n else nan
    with np.errstate(divide="ignore", invalid="ignore"):
        return {
            "true": np.asarray(true, float),
            "mean": mean,
            "bias": mean - true,
            "std": std,
            "rmse": rmse,
            "relative_rmse": np.where(true != 0, rmse / np.abs(true), np.nan),
            "predicted_std": s.mean(0) if n else nan,
            "crb_std": crb_std,
            "rmse_crb": np.where(crb_std > 0, rmse / crb_std, np.nan),
            "bias_std": np.where(std > 0, (mean - true) / std, np.nan),
        }
