"""In a notebook a result shows itself: ``Identification._repr_html_`` holds the parameter table
(each value with its standard error, in order) and the diagnostics, every text escaped."""

import dataclasses
import re
from html.parser import HTMLParser

import numpy as np

import spaceid


class _Cells(HTMLParser):
    """The text of every table cell, in order, and whether the tags nest properly."""

    def __init__(self):
        super().__init__()
        self.cells, self.open, self._in = [], [], False

    def handle_starttag(self, tag, attrs):
        self.open.append(tag)
        self._in = tag in ("td", "th")
        if self._in:
            self.cells.append("")

    def handle_endtag(self, tag):
        assert self.open.pop() == tag
        self._in = False

    def handle_data(self, data):
        if self._in:
            self.cells[-1] += data


def test_an_identification_shows_its_table_and_diagnostics():
    model = spaceid.load_model("cepheus")
    param = spaceid.minimal_parameters(model)
    h = np.array([0, 0, 0.4934])
    traj = spaceid.load_trajectory("paper-table2", joints=model.joints)
    log = spaceid.add_noise(spaceid.simulate(param, param.true_values, traj, spaceid.sample_times(5, 35), h),
                            angle=1e-4, rate=1e-4, seed=0)  # fmt: skip
    res = spaceid.identify(param, log, h, noise=spaceid.Noise(angle=1e-4, rate=1e-4, base_rate=1e-4))
    shown = dataclasses.replace(res, model="<b>cepheus</b> & co")._repr_html_()
    parser = _Cells()
    parser.feed(shown)
    assert not parser.open and "<b>cepheus" not in shown and "&lt;b&gt;cepheus&lt;/b&gt; &amp; co" in shown
    cells = parser.cells
    start = cells.index("definition") + 1
    rows = [cells[start + 6 * i : start + 6 * i + 6] for i in range(len(res.names))]
    for row, name, value, std in zip(rows, res.names, res.values, res.std):
        assert row[0] == name and float(row[1]) == float(f"{value:.6g}") and float(row[2]) == float(f"{std:.3g}")
    facts = dict(zip(cells[start + 6 * len(res.names) + 2 :: 2], cells[start + 6 * len(res.names) + 3 :: 2]))
    assert facts["samples"] == str(res.n_samples) and facts["estimator"] == res.estimator
    assert re.fullmatch(r"[0-9.e+-]+", facts["condition number"]) and facts["covariance"] == res.diagnostics.covariance
