"""Heavy imports only where they are used: matplotlib is imported by the commands that draw, SciPy's
slow subpackages (stats, optimize, integrate, interpolate, spatial), SymPy, Pinocchio and the
optional dependencies by the functions that need them, not by a command's import path: the start
of every command pays for what it imports (scipy.stats alone took 0.6 to 0.8 s)."""

import os
import subprocess
import sys

import pytest

HEAVY = ("matplotlib", "scipy.stats", "scipy.optimize", "scipy.integrate", "scipy.interpolate", "scipy.spatial",
         "sympy", "pinocchio", "cvxpy", "dask", "distributed", "rosbags", "mujoco", "rclpy")


def _heavy_imports(code, env=None):
    """The modules of ``HEAVY`` that running ``code`` in a fresh interpreter (its environment ``env``, else this
    one's) imports (its ``code`` asserts its own work)."""
    probe = code + f"\nimport sys\nprint('loaded:', *(m for m in {HEAVY!r} if m in sys.modules))"
    out = subprocess.run([sys.executable, "-c", probe], capture_output=True, text=True, check=True, env=env)
    return set(out.stdout.strip().splitlines()[-1].split()[1:])


def _imports_matplotlib(code):
    """Whether running ``code`` in a fresh interpreter imports matplotlib."""
    return "matplotlib" in _heavy_imports(code)


@pytest.mark.slow  # a fresh interpreter simulating and identifying: seconds
def test_identify_does_not_import_matplotlib(tmp_path):
    log, result = tmp_path / "log.csv", tmp_path / "result.json"
    code = (f"from spaceid.cli import main\n"
            f"assert main(['simulate', 'cepheus', '--trajectory', 'paper-table2', '--momentum', '0.4934', "
            f"'--samples', '60', '-o', {str(log)!r}]) == 0\n"
            f"assert main(['identify', 'cepheus', {str(log)!r}, '--momentum', '0.4934', '--estimator', 'ols', "
            f"'-o', {str(result)!r}]) == 0")
    assert not _imports_matplotlib(code)
    assert result.exists()


@pytest.mark.slow  # fast representative: test_the_cli_and_the_pipeline_packages_import_none_of_the_heavy_modules
def test_help_and_the_studies_package_do_not_import_matplotlib():
    assert not _imports_matplotlib("import spaceid.studies, spaceid.cli")


@pytest.mark.slow
def test_figures_still_import_it(tmp_path):
    """The probe can fail: drawing a figure imports matplotlib."""
    code = ("import numpy as np\nfrom spaceid.studies import plot_trajectory\n"
            f"t = np.linspace(0, 1, 5); q = np.zeros((5, 1))\n"
            f"plot_trajectory(t, q, q, q, ['j'], {str(tmp_path / 'f.png')!r})")
    assert _imports_matplotlib(code)


def test_the_cli_and_the_pipeline_packages_import_none_of_the_heavy_modules():
    """``spaceid --help`` and the import of every stage up to the studies load none of them (nor
    Numba for the help): one interpreter, the help first (what it loaded is still loaded at the end)."""
    assert _heavy_imports("import sys\nfrom spaceid.cli import main\nassert main(['--help']) == 0\n"
                          "assert 'numba' not in sys.modules\n"
                          "import spaceid.models, spaceid.data, spaceid.dynamics, spaceid.estimation, "
                          "spaceid.identified, spaceid.motion, spaceid.twin, spaceid.studies") == set()


@pytest.mark.slow  # fresh interpreters identifying: seconds
def test_model_and_identify_load_only_what_they_use(tmp_path):
    """With the minimal set cached (the tests' cache is shared with the child), ``spaceid model``
    needs no SymPy; least squares and maximum likelihood on a noisy Cepheus log check their
    residuals without scipy.stats and integrate nothing."""
    from spaceid.cli import main

    log = tmp_path / "log.csv"
    assert main(["simulate", "cepheus", "--trajectory", "paper-table2", "--momentum", "0.4934", "--samples", "80",
                 "--noise-angle", "1e-4", "--noise-rate", "1e-4", "-o", str(log)]) == 0  # also caches the set
    assert _heavy_imports("from spaceid.cli import main\nassert main(['model', 'cepheus']) == 0") == set()
    for estimator in ("ols", "ml"):
        result = tmp_path / f"{estimator}.json"
        code = (f"from spaceid.cli import main\nassert main(['identify', 'cepheus', {str(log)!r}, '--momentum', "
                f"'0.4934', '--noise-angle', '1e-4', '--noise-rate', '1e-4', '--estimator', {estimator!r}, "
                f"'-o', {str(result)!r}]) == 0")
        assert _heavy_imports(code) == set()
        assert result.exists()


@pytest.mark.slow  # a fresh interpreter: seconds
def test_a_payload_projected_to_consistency_imports_no_modelling_layer():
    """The payload's consistency projection states its program to Clarabel itself: cvxpy's import (its atoms import
    scipy.stats) took a second of every payload that needed the projection."""
    code = ("import numpy as np\nfrom spaceid.identified import project_consistent\n"
            "from spaceid.models import inertial_vector\n"
            "theta = inertial_vector(2.0, [0.1, 0.0, 0.0], np.diag([1.0, 1.0, 3.0]))\n"
            "assert project_consistent(theta, np.diag([1e-2, *[1e-4] * 3, *[1e-2] * 6]), planar=False)[1] > 0")
    assert _heavy_imports(code) == set()


@pytest.mark.slow  # fresh interpreters identifying and exporting: seconds
def test_an_export_and_a_prior_import_no_modelling_layer(tmp_path):
    """The export's convex steps and the CAD prior's are stated to Clarabel directly: cvxpy's import (1.2 to 1.4 s,
    SciPy's statistics module most of it) and its compilation of every program were most of the servicer's export
    (2.8 to 3.5 s on its first run)."""
    from spaceid.cli import main

    log, result = tmp_path / "log.csv", tmp_path / "ml.json"
    assert main(["simulate", "cepheus", "--trajectory", "paper-table2", "--momentum", "0.4934", "--samples", "80",
                 "--noise-angle", "1e-4", "--noise-rate", "1e-4", "-o", str(log)]) == 0
    assert main(["identify", "cepheus", str(log), "--momentum", "0.4934", "-o", str(result)]) == 0
    export = (f"from spaceid.cli import main\nassert main(['export', {str(result)!r}, '--prior', 'cepheus', '-o', "
              f"{str(tmp_path / 'robot.urdf')!r}]) == 0")
    prior = (f"from spaceid.cli import main\nassert main(['identify', 'cepheus', {str(log)!r}, '--momentum', "
             f"'0.4934', '--prior', 'cepheus', '-o', {str(tmp_path / 'map.json')!r}]) == 0")
    for code in (export, prior):
        assert not {"cvxpy", "scipy.stats"} & _heavy_imports(code)


@pytest.mark.slow
def test_a_urdf_is_parsed_by_pinocchio_once(tmp_path):
    """A URDF preset is parsed by Pinocchio in the first interpreter that loads it (the probe can fail), and read
    from the cache without it in the next."""
    env = os.environ | {"SPACEID_CACHE_DIR": str(tmp_path)}
    code = "import spaceid\nassert spaceid.load_model('satellite-7dof').n_joints == 7"
    assert _heavy_imports(code, env) == {"pinocchio"}
    assert _heavy_imports(code, env) == set()


def test_the_studies_load_each_name_from_its_module_on_first_use():
    """``spaceid.studies`` names each module's ``__all__`` exactly (its table cannot drift from them), and a command
    that writes the identification's report imports none of the other stages (0.04 s)."""
    import importlib

    import spaceid.studies as studies

    for module, names in studies._MODULES.items():
        assert tuple(importlib.import_module(f"spaceid.studies.{module}").__all__) == names, module
        assert all(getattr(studies, name) is getattr(studies, module).__dict__[name] for name in names)
    code = ("from spaceid.studies import metric_label, parameter_table, write_html_report\nimport sys\n"
            "print(*sorted(sys.modules))")  # (the report takes its labels from _report when written)
    loaded = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout.split()
    assert "spaceid.studies._html_report" in loaded
    assert not {"spaceid.identified", "spaceid.motion", "spaceid.twin", "spaceid.studies._demo"} & set(loaded)
