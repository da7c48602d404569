"""End-to-end studies built on the pipeline: validation and prediction (kinematic and at the torque
level), the paper's demo, the twin experiment, Monte Carlo, design sweeps, figures and reports.

Each name is imported from its module on first use: a command that writes one report does not import
the studies it does not run (the identification's report alone, 0.04 s less at every ``identify``).
"""

from .._lazy import lazy_names

_MODULES = {
    "_validate": (
        "Predictor", "Validation", "attitude_error_angle", "predict", "predictor", "validate", "validation_metrics",
    ),
    "_torque_validation": ("TORQUE_METRIC_LABELS", "TORQUE_VALIDATION_TITLE", "torque_metrics", "validate_torques"),
    "_figures": (
        "plot_montecarlo", "plot_parameters", "plot_singular_values", "plot_tracking", "plot_trajectory",
        "plot_validation", "plot_capture_monitor", "plot_payload", "plot_attitude_errors",
    ),
    "_tables": ("parameter_table", "montecarlo_table", "drift_lines"),
    "_report": ("write_markdown_report", "metric_label", "servicing_label"),
    "_demo": ("PAPER_TABLE3", "CEPHEUS_STUDY", "DemoResult", "run_demo", "warm_preset_sets", "warm_spatial_kernels"),
    "_servicing": (
        "CaptureProtocol", "PayloadScore", "ServicingResult", "ServicingScores", "capture_protocol", "run_servicing",
        "write_servicing",
    ),
    "_experiment": ("ExperimentResult", "run_experiment", "BAG_NAMES"),
    "_montecarlo": ("DEFAULT_NOISE", "MonteCarloResult", "run_montecarlo", "write_montecarlo"),
    "_montecarlo_runs": ("differentiated_noise",),
    "_montecarlo_stats": ("STATISTICS",),
    "_sweep": ("SweepResult", "run_sweep", "sweep_table", "write_sweep"),
    "_spatial_experiment": ("SpatialExperimentResult", "run_spatial_experiment", "large_parameters", "coverage"),
    "_html_report": ("write_html_report", "write_validation_html", "write_montecarlo_html", "write_monitor_html"),
}  # fmt: skip
"""Each module's public names: its ``__all__`` (tests/test_imports.py checks that they agree)."""

_HOME = {name: module for module, names in _MODULES.items() for name in names} | dict.fromkeys(_MODULES)

__all__ = [name for names in _MODULES.values() for name in names]

__getattr__, __dir__ = lazy_names(__name__, globals(), _HOME)
