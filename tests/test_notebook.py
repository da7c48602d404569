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
