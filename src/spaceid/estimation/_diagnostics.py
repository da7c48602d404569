"""What an identification found about its own fit: :class:`Diagnostics` (``Identification.diagnostics``),
with the residual tests :class:`ResidualChecks` and :class:`DriftTest`.

An identification's ``settings`` say how it was obtained (provenance: the parameter set, the log,
the anchors, the noise model); its ``diagnostics`` say how well the data agreed with the model
(chi-square, residual whiteness, an unmodelled drift, physically impossible estimates) and so how
the covariance was chosen. Each record has a JSON form (``to_dict``, ``from_dict``), the
``diagnostics`` object of RESULT.json (docs/formats/result-json.md).
"""

from __future__ import annotations

from dataclasses import dataclass, field

__all__ = ["COVARIANCE_METHODS", "Diagnostics", "DriftTest", "ResidualChecks"]

COVARIANCE_METHODS = ("noise-model", "sandwich", "newey-west", "propagated", "fisher")
"""How a reported covariance was obtained (:attr:`Diagnostics.covariance_method`): the noise model's
sandwich (times the variance factor when the levels were estimated from the log), the sandwich of
the residuals' scores (White), the Newey-West estimate from the residuals, the angle noise propagated
through Savitzky-Golay differentiators (with Newey-West where larger), or the angles estimator's
inverse Fisher information (docs/theory/noise.md)."""


def _optional_float(value):
    return None if value is None else float(value)


@dataclass(frozen=True)
class ResidualChecks:
    """The tests of the residuals against white noise of the model's levels.

    Attributes
    ----------
    significance : float
        The level at which the tests reject (``spaceid.estimation._uncertainty.SIGNIFICANCE``).
    ljung_box_p : float
        Ljung-Box p-value of the residuals' autocorrelations (pooled over the equation rows).
    ljung_box_lags : int
    lag1_autocorrelation : float
    chi2_p : float or None
        Two-sided chi-square p-value of ``chi2_dof``; None without a noise model (``ols``).
    chi2_band : tuple of 2 floats or None
        The ``chi2_dof`` that pass at ``significance``; None without a noise model.
    """

    significance: float
    ljung_box_p: float
    ljung_box_lags: int
    lag1_autocorrelation: float
    chi2_p: float | None = None
    chi2_band: tuple | None = None

    def to_dict(self) -> dict:
        """JSON-ready: the attributes by name (``chi2_band`` a list)."""
        return {"significance": self.significance, "ljung_box_p": self.ljung_box_p,
                "ljung_box_lags": self.ljung_box_lags, "lag1_autocorrelation": self.lag1_autocorrelation,
                "chi2_p": self.chi2_p, "chi2_band": None if self.chi2_band is None else list(self.chi2_band)}

    @classmethod
    def from_dict(cls, data: dict) -> ResidualChecks | None:
        """The checks of a :meth:`to_dict` object; None for an empty one (an estimator that brings
        its own covariance, ``angles``, runs none)."""
        if not data:
            return None
        band = data.get("chi2_band")
        return cls(float(data["significance"]), float(data["ljung_box_p"]), int(data["ljung_box_lags"]),
                   float(data["lag1_autocorrelation"]), _optional_float(data.get("chi2_p")),
                   None if band is None else tuple(float(b) for b in band))


@dataclass(frozen=True)
class DriftTest:
    """The residual test for an unmodelled drift (docs/theory/drift.md), run when no drift terms
    are modelled.

    Attributes
    ----------
    run : bool
        Whether the test ran; when not, ``reason`` says why and the other attributes are None.
    reason : str
        Why it did not run (drift terms modelled, or the ``angles`` estimator); empty when it ran.
    alpha : float
        Significance level.
    terms : tuple of str
        The trend terms tried (``torque_*``, ``viscous``).
    trend : dict of str to float
        Their fitted values.
    wald : float
    dof : int
    p_value : float
    relative_drift : float
        Largest fitted momentum change over the RMS right-hand side.
    lag1_autocorrelation, durbin_watson, whiteness_p_value : float
        Serial correlation of the whitened residuals.
    drift : bool
        The test rejects: a warning was issued.
    gyro_bias : tuple of float
        When it rejects and a constant gyro bias explains the residuals better than the drift terms
        (:func:`spaceid.estimation._gyro_bias.bias_or_drift`): that bias [rad/s] (base axes; z only
        for planar systems), which the warning names; empty otherwise.
    bandwidth : int or None
        Newey-West lags [samples] of the Wald test's covariance: the differentiator's window, 0 for
        measured rates (None: results written before it was recorded).
    confounded : float or None
        Largest share of a drift coefficient's variance from directions the data do not determine
        (the regressor's noise as large as its signal), directly or through the errors-in-variables
        allowance, which moves with the estimate along them; above ``CONFOUNDED`` (0.01) the test does
        not decide: a drift cannot be told from those parameters (None: not recorded).
    errors_in_variables : tuple of float
        The drift coefficients predicted from the regressor's own noise (its first-order
        errors-in-variables bias, one per term): allowed for in the Wald test's covariance, so that a
        trend of that size is no drift (empty: not recorded).
    """

    run: bool
    reason: str = ""
    alpha: float | None = None
    terms: tuple = ()
    trend: dict = field(default_factory=dict)
    wald: float | None = None
    dof: int | None = None
    p_value: float | None = None
    relative_drift: float | None = None
    lag1_autocorrelation: float | None = None
    durbin_watson: float | None = None
    whiteness_p_value: float | None = None
    drift: bool = False
    gyro_bias: tuple = ()
    bandwidth: int | None = None
    confounded: float | None = None
    errors_in_variables: tuple = ()

    @classmethod
    def skipped(cls, reason: str) -> DriftTest:
        """The record of a test not run, and why."""
        return cls(False, reason)

    def to_dict(self) -> dict:
        """JSON-ready: ``{"run": false, "reason": ...}`` when not run, else ``run`` and the test's values."""
        if not self.run:
            return {"run": False, "reason": self.reason}
        return {"alpha": self.alpha, "terms": list(self.terms), "trend": dict(self.trend), "wald": self.wald,
                "dof": self.dof, "p_value": self.p_value, "relative_drift": self.relative_drift,
                "lag1_autocorrelation": self.lag1_autocorrelation, "durbin_watson": self.durbin_watson,
                "whiteness_p_value": self.whiteness_p_value, "drift": self.drift, "bandwidth": self.bandwidth,
                "confounded": self.confounded, "run": True,
                **({"errors_in_variables": list(self.errors_in_variables)} if self.errors_in_variables else {}),
                **({"gyro_bias": list(self.gyro_bias)} if self.gyro_bias else {})}

    @classmethod
    def from_dict(cls, data: dict) -> DriftTest | None:
        """The test of a :meth:`to_dict` object (or of :func:`spaceid.estimation._residuals.drift_test`'s
        record, ``run`` true when absent); None for an empty one."""
        if not data:
            return None
        if not data.get("run", True):
            return cls.skipped(str(data.get("reason", "")))
        return cls(True, "", float(data["alpha"]), tuple(data["terms"]), dict(data["trend"]), float(data["wald"]),
                   int(data["dof"]), float(data["p_value"]), float(data["relative_drift"]),
                   float(data["lag1_autocorrelation"]), float(data["durbin_watson"]),
                   float(data["whiteness_p_value"]), bool(data["drift"]),
                   tuple(float(v) for v in data.get("gyro_bias", ())),
                   None if data.get("bandwidth") is None else int(data["bandwidth"]),
                   None if data.get("confounded") is None else float(data["confounded"]),
                   tuple(float(v) for v in data.get("errors_in_variables") or ()))


@dataclass(frozen=True)
class Diagnostics:
    """How well the data agreed with the model of an identification, and the covariance that follows.

    Attributes
    ----------
    chi2_dof : float or None
        Whitened residual sum of squares per degree of freedom (about 1 when the noise model holds);
        None for ``ols`` (no noise model).
    variance_factor : float or None
        The factor the noise model's covariance was multiplied by (``chi2_dof`` when the levels were
        estimated from the log, else 1).
    covariance_method : str or None
        How the covariance was obtained, one of :data:`COVARIANCE_METHODS`; None for results written
        before it was recorded.
    covariance : str
        The same in words, with the numbers behind the choice.
    covariance_from_residuals : bool
        The covariance follows the residuals rather than the noise model.
    residual_checks : ResidualChecks or None
        None for the ``angles`` estimator (its own covariance).
    noise_model_warning : str
        What a ``chi2_dof`` far from 1 means (also issued as a warning); empty when it is not.
    plausibility : str
        The warning about inertia-like parameters that came out significantly negative, or
        ``"no inertia-like parameter negative"``.
    drift_test : DriftTest or None
        The residual test for an unmodelled drift.
    drift_correlation : float or None
        With two or more drift terms, the largest correlation between their estimates.
    condition_number_scaled : float or None
        Condition number of the column-scaled regressor (decides excitation; the unscaled one is
        ``Identification.condition_number``).
    estimator_info : dict
        What the estimator reports: ``iterations``, ``converged``, ``fallback`` (``ml``: the estimate
        reported when it failed), ``held`` (``ml`` run over the directions the data determine only, the
        others held at WLS's values: which, and why), ``knot_spacing`` (``angles``), ``chunk`` (streamed), ...
    undetermined : tuple of dict
        The directions of parameter space the data do not determine (the regressor's noise at least as
        large as its signal, :mod:`spaceid.estimation._determined`), worst first: ``noise_to_signal``
        and the ``parameters`` that lead each; their estimates are pulled towards zero and their
        standard errors do not hold. Empty when every direction is determined, or not computed (a
        streamed identification, the ``angles`` estimator).
    """

    chi2_dof: float | None = None
    variance_factor: float | None = None
    covariance_method: str | None = None
    covariance: str = ""
    covariance_from_residuals: bool = False
    residual_checks: ResidualChecks | None = None
    noise_model_warning: str = ""
    plausibility: str = ""
    drift_test: DriftTest | None = None
    drift_correlation: float | None = None
    condition_number_scaled: float | None = None
    estimator_info: dict = field(default_factory=dict)
    undetermined: tuple = ()

    KEYS = ("chi2_dof", "variance_factor", "covariance_method", "covariance", "covariance_from_residuals",
            "residual_checks", "noise_model_warning", "plausibility", "drift_test", "drift_correlation",
            "condition_number_scaled", "estimator_info", "undetermined")
    """The keys of the JSON form; RESULT.json files written before ``diagnostics`` existed hold them in
    ``settings`` (:meth:`from_dict` reads those)."""

    def to_dict(self) -> dict:
        """JSON-ready: every attribute by name (the tests as their own ``to_dict``, None when absent)."""
        return {
            "chi2_dof": self.chi2_dof,
            "variance_factor": self.variance_factor,
            "covariance_method": self.covariance_method,
            "covariance": self.covariance,
            "covariance_from_residuals": self.covariance_from_residuals,
            "residual_checks": None if self.residual_checks is None else self.residual_checks.to_dict(),
            "noise_model_warning": self.noise_model_warning,
            "plausibility": self.plausibility,
            "drift_test": None if self.drift_test is None else self.drift_test.to_dict(),
            "drift_correlation": self.drift_correlation,
            "condition_number_scaled": self.condition_number_scaled,
            "estimator_info": dict(self.estimator_info),
            "undetermined": [dict(d) for d in self.undetermined],
        }

    @classmethod
    def from_dict(cls, data: dict) -> Diagnostics:
        """The diagnostics of a :meth:`to_dict` object, or of the ``settings`` of an older RESULT.json
        (the same keys among others; those missing take their defaults)."""
        return cls(
            _optional_float(data.get("chi2_dof")),
            _optional_float(data.get("variance_factor")),
            data.get("covariance_method"),
            str(data.get("covariance", "")),
            bool(data.get("covariance_from_residuals", False)),
            ResidualChecks.from_dict(data.get("residual_checks") or {}),
            str(data.get("noise_model_warning", "")),
            str(data.get("plausibility", "")),
            DriftTest.from_dict(data.get("drift_test") or {}),
            _optional_float(data.get("drift_correlation")),
            _optional_float(data.get("condition_number_scaled")),
            dict(data.get("estimator_info") or {}),
            tuple(dict(d) for d in data.get("undetermined") or ()),
        )
