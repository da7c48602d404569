"""End-to-end studies built on the pipeline: validation and prediction (kinematic and at the torque
level), the paper's demo, the twin experiment, Monte Carlo, design sweeps, figures and reports.
"""

from . import _validate, _torque_validation, _figures, _tables, _report, _demo, _servicing, _experiment
from . import _montecarlo, _montecarlo_runs, _montecarlo_stats, _sweep, _spatial_experiment, _html_report
from ._validate import *  # noqa: F403
from ._torque_validation import *  # noqa: F403
from ._figures import *  # noqa: F403
from ._tables import *  # noqa: F403
from ._report import *  # noqa: F403
from ._demo import *  # noqa: F403
from ._servicing import *  # noqa: F403
from ._experiment import *  # noqa: F403
from ._montecarlo import *  # noqa: F403
from ._montecarlo_runs import *  # noqa: F403
from ._montecarlo_stats import *  # noqa: F403
from ._sweep import *  # noqa: F403
from ._spatial_experiment import *  # noqa: F403
from ._html_report import *  # noqa: F403

__all__ = (
    _validate.__all__ + _torque_validation.__all__ + _figures.__all__ + _tables.__all__ + _report.__all__
    + _demo.__all__ + _servicing.__all__ + _experiment.__all__
    + _montecarlo.__all__ + _montecarlo_runs.__all__ + _montecarlo_stats.__all__ + _sweep.__all__ + _spatial_experiment.__all__
    + _html_report.__all__
)  # fmt: skip
