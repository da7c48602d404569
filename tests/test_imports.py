"""Heavy imports only where they are used: matplotlib is imported by the commands that draw."""

import subprocess
import sys

import pytest


def _imports_matplotlib(code):
    """Whether running ``code`` in a fresh interpreter imports matplotlib (its ``code`` asserts its own work)."""
    probe = code + "\nimport sys\nprint('matplotlib' in sys.modules)"
    out = subprocess.run([sys.executable, "-c", probe], capture_output=True, text=True, check=True)
    return out.stdout.strip().splitlines()[-1] == "True"


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


def test_help_and_the_studies_package_do_not_import_matplotlib():
    assert not _imports_matplotlib("import spaceid.studies, spaceid.cli")


@pytest.mark.slow
def test_figures_still_import_it(tmp_path):
    """The probe can fail: drawing a figure imports matplotlib."""
    code = ("import numpy as np\nfrom spaceid.studies import plot_trajectory\n"
            f"t = np.linspace(0, 1, 5); q = np.zeros((5, 1))\n"
            f"plot_trajectory(t, q, q, q, ['j'], {str(tmp_path / 'f.png')!r})")
    assert _imports_matplotlib(code)
