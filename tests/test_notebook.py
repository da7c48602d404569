"""Results show themselves in a notebook: ``Identification._repr_html_``."""

from html.parser import HTMLParser

import numpy as np
from random_states import random_log

import spaceid
from spaceid.dynamics import minimal_parameters


class _Cells(HTMLParser):
    """The text of every table cell, and whether the tags balance."""

    def __init__(self):
        super().__init__()
        self.cells, self.open, self._in = [], [], False

    def handle_starttag(self, tag, attrs):
        self.open.append(tag)
        self._in = tag == "td"
        if self._in:
            self.cells.append("")

    def handle_endtag(self, tag):
        assert self.open.pop() == tag
        self._in = False

    def handle_data(self, data):
        if self._in:
            self.cells[-1] += data


def test_identification_shows_its_diagnostics_and_every_parameter():
    param = minimal_parameters(spaceid.load_model("cepheus"))
    h = np.array([0.0, 0.0, 0.3])
    result = spaceid.identify(param, random_log(param, h, 200, np.random.default_rng(0)), h, estimator="ols")
    parser = _Cells()
    parser.feed(result._repr_html_())
    assert not parser.open  # every tag closed
    cells = parser.cells
    for name, value in zip(result.names, result.values):
        row = cells.index(name)
        assert float(cells[row + 1]) == float(f"{value:.6g}")
    assert "scaled condition number" in cells and "drift test" in cells
    for name, scaled in zip(result.names, result.scaled_std):  # std as the momentum it causes
        assert float(cells[cells.index(name) + 3]) == float(f"{100 * scaled:.3g}")
    assert "std [% H]" in result._repr_html_()


def test_the_drift_row_says_what_the_test_decided():
    """A warning only when the test warned; a p-value under its level without one says why it did not decide (the
    servicer's undesigned log: p = 1.4e-4 with 69 % of a coefficient's variance from undetermined directions, once
    shown as a warning the command line never gave)."""
    from dataclasses import replace

    from spaceid.estimation import DriftTest
    from spaceid.estimation.internal import diagnostic_rows

    param = minimal_parameters(spaceid.load_model("cepheus"))
    h = np.array([0.0, 0.0, 0.3])
    result = spaceid.identify(param, random_log(param, h, 200, np.random.default_rng(0)), h, estimator="ols")

    def row(test):
        rows = diagnostic_rows(replace(result, diagnostics=replace(result.diagnostics, drift_test=test)))
        return next((text, warn) for label, text, warn in rows if label == "drift test")

    base = DriftTest(True, alpha=1e-3, terms=("torque_z",), trend={"torque_z": 0.1}, wald=1.0, dof=1, p_value=0.3,
                     relative_drift=0.05, drift=False, confounded=0.0)
    assert row(base) == ("p = 0.3: no drift", False)
    text, warn = row(replace(base, p_value=1.4e-4, drift=True))
    assert warn and text.startswith("p = 0.00014 < 0.001: a momentum drift of 5 %")
    text, warn = row(replace(base, p_value=1.4e-4, drift=True, gyro_bias=(2e-5,)))
    assert warn and "a gyro bias of 2e-05 rad/s" in text
    text, warn = row(replace(base, p_value=1.4e-4, confounded=0.69))
    assert not warn and "not decided: 69 % of a drift coefficient's variance" in text
    text, warn = row(replace(base, p_value=1.4e-4, relative_drift=1e-9))
    assert not warn and "not decided: the fitted drift is round-off" in text
    assert row(DriftTest.skipped("drift terms modelled: torque")) == ("not run: drift terms modelled: torque", False)
