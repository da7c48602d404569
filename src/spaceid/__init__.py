"""spaceid: identify free-floating space manipulators from angular-momentum conservation.

The pipeline, one function a stage::

    model = spaceid.load_model("cepheus")                 # robot description
    param = spaceid.minimal_parameters(model)             # identifiable set and its regressor
    design = spaceid.design_excitation(param, ...)        # exciting joint motion
    log = spaceid.simulate(param, pi, design.trajectory, ...)  # or spaceid.read_log(path, ...)
    result = spaceid.identify(param, log, momentum)       # estimate, standard errors
    result = spaceid.load_result(path)                    # a saved RESULT.json, the same record
    model = spaceid.load_identified(path)                 # ... or its controller-ready dynamics
    spaceid.validate(result, log)                         # re-simulation against the log

The subpackages hold the rest, stage by stage: :mod:`spaceid.models`, :mod:`spaceid.data`,
:mod:`spaceid.dynamics`, :mod:`spaceid.estimation`, :mod:`spaceid.identified`, :mod:`spaceid.motion`,
:mod:`spaceid.twin` and :mod:`spaceid.studies`. Names are loaded on first use, so ``import spaceid`` stays fast.
"""

from ._errors import SpaceidError
from ._lazy import lazy_names

__version__ = "0.1.0"

# public name -> subpackage that defines it, or (subpackage, its name there)
_HOME = {
    "Model": "models",
    "load_model": "models",
    "Log": "data",
    "read_log": "data",
    "write_log": "data",
    "minimal_parameters": "dynamics",
    "Parameterization": "dynamics",
    "Noise": "estimation",
    "Identification": "estimation",
    "identify": "estimation",
    "cramer_rao": "estimation",
    "cramer_rao_angles": "estimation",
    "monitor": "estimation",
    "Monitor": "estimation",
    "load_result": "estimation",  # the Identification record of a RESULT.json (in 0.1.0: load_identified's)
    "load_identified": "identified",  # the controller-ready model of a RESULT.json
    "IdentifiedModel": "identified",
    "identify_com": "identified",
    "identify_payload": "identified",
    "load_trajectory": "motion",
    "sample_times": "motion",
    "design_excitation": "motion",
    "simulate": "motion",
    "add_noise": "motion",
    "run_twin": "twin",
    "TwinSettings": "twin",
    "predict": "studies",
    "validate": "studies",
    "validate_torques": "studies",
    "run_demo": "studies",
    "run_experiment": "studies",
    "run_montecarlo": "studies",
    "run_sweep": "studies",
}

__all__ = ["SpaceidError", *_HOME]


__getattr__, __dir__ = lazy_names(__name__, globals(), _HOME)
