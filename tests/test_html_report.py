"""The interactive HTML reports (report.html, docs/formats/report-html.md): self-contained pages, the
series thinned for the page with their extremes kept, the monitor's statistic kept in bounded
memory, the commands' default report paths, and every page opened in headless Chromium: no console
error, every figure drawn, the parameter table sorted by a header click."""

import os
import re
import shutil
import tempfile
from html.parser import HTMLParser
from io import BytesIO
from pathlib import Path

import numpy as np
import pytest
from test_monitor import H, NOISE, RATE, T_CAPTURE, _concatenate, _motion, _with_payload

from spaceid.cli import main
from spaceid.data import write_log
from spaceid.dynamics import minimal_parameters
from spaceid.estimation import identify, monitor
from spaceid.estimation._monitor_cusum import StatisticTrace
from spaceid.models import load_model
from spaceid.motion import add_noise, simulate
from spaceid.studies import (DEFAULT_NOISE, run_montecarlo, validate, write_html_report, write_monitor_html,
                             write_montecarlo_html, write_validation_html)
from spaceid.studies._html_page import MAX_POINTS, downsample

CHROMIUM, CHROMEDRIVER = Path("/usr/bin/chromium"), Path("/usr/bin/chromedriver")


@pytest.fixture(scope="module")
def cepheus():
    model = load_model("cepheus")
    return model, minimal_parameters(model)


@pytest.fixture(scope="module")
def capture(cepheus):
    """A noisy log of Cepheus grasping a payload at T_CAPTURE (as tests/test_monitor.py builds it)."""
    model, param = cepheus
    captured = minimal_parameters(_with_payload(model, "link2", 0.1, [0.2, 0, 0]))
    t = np.arange(1200) / RATE
    before = simulate(param, param.true_values, _motion, t[t <= T_CAPTURE], H, model=model)
    after = simulate(param, captured.true_values, _motion, t[t >= T_CAPTURE], H, initial_quat=before.base_quat[-1])
    log = _concatenate(before.select(slice(0, -1)), after)
    return add_noise(log, noise=NOISE, seed=4)


@pytest.fixture(scope="module")
def identification(cepheus):
    """A noisy log of the steady motion, its identification and its validation."""
    model, param = cepheus
    log = simulate(param, param.true_values, _motion, np.arange(400) / RATE, H, model=model)
    log = add_noise(log, noise=NOISE, seed=5)
    ident = identify(param, log, H, noise=NOISE, estimator="wls")
    with pytest.warns(UserWarning, match="fitting log"):
        check = validate(ident, log)
    return log, ident, check


class _Links(HTMLParser):
    """Every src and href of a page's elements (not what its scripts hold)."""

    def __init__(self):
        super().__init__()
        self.links, self.scripts = [], 0

    def handle_starttag(self, tag, attrs):
        self.scripts += tag == "script"
        self.links += [(tag, value) for key, value in attrs if key in ("src", "href") and value]


def _assert_self_contained(path: Path) -> None:
    text = path.read_text(encoding="utf-8")
    parser = _Links()
    parser.feed(text)
    assert [link for link in parser.links if not link[1].startswith(("data:", "#"))] == []
    assert not re.search(r"@import|url\(\s*['\"]?https?:", text.split("<script", 1)[0])  # the page's style
    assert len(re.findall(r"\* plotly\.js v\d", text)) == (1 if "Plotly.newPlot" in text else 0)  # one bundle


def test_the_identification_report_is_self_contained(identification, tmp_path):
    log, ident, check = identification
    path = write_html_report(tmp_path, title="t", result=ident, settings={"seed": 1}, figures={}, metrics=check.metrics,
                             validations=[(log, check.predicted, "validation")])
    _assert_self_contained(path)
    text = path.read_text(encoding="utf-8")
    assert text.count("<script") == 1 + 3 + 1  # one plotly.js bundle, three figures, the table's sorting
    for name, value in zip(ident.names, ident.values):
        assert f'<td class="t">{name}</td>' in text and f'data-v="{float(f"{value:.6g}")!r}"' in text


def test_a_figure_is_the_plotly_call_with_its_json_kept_inside_its_script():
    """A figure's data, layout and configuration as Plotly.newPlot's arguments: a name holding ``</script>``
    does not end the script, arrays and NaN are JSON (null), and the div takes the layout's height."""
    import json

    from spaceid.studies._html_page import Page

    page = Page("t")
    page.figure({"data": [{"type": "scatter", "x": ["a</script><b>"], "y": np.array([np.nan])}],
                 "layout": {"height": 321}}, "caption")
    text = page.html()
    call = re.search(r'<div id="figure-1" class="plotly-graph-div" style="height:321px; width:100%;"></div>'
                     r'<script type="text/javascript">Plotly\.newPlot\((.*?)\)</script>', text)
    assert call and "</script><b>" not in text
    key, data, layout, config = json.loads(f"[{call.group(1)}]")
    assert key == "figure-1" and data == [{"type": "scatter", "x": ["a</script><b>"], "y": [None]}]
    assert layout == {"height": 321} and config["displaylogo"] is False


def test_the_parameter_figure_draws_its_band_and_zero_line(cepheus, identification):
    """The z-scores' shaded |z| <= 2 band and the zero line under the errors, which Plotly left out when
    they were drawn before their panel's trace."""
    import json

    import plotly.io as pio

    from spaceid.studies._html_figures import parameter_figure

    _, ident, _ = identification
    for true, shapes in ((None, [("line", "y")]), (cepheus[1].true_values, [("rect", "y"), ("line", "y2")])):
        layout = json.loads(pio.to_json(parameter_figure(ident, true)[0], validate=False))["layout"]
        assert [(s["type"], s["yref"]) for s in layout["shapes"]] == shapes


def test_the_monitor_figures_draw_the_threshold_the_changes_and_the_unchanged_band(cepheus, capture):
    """The statistic's threshold line and each change's lines, and the event figure's |z| < 3 band, which Plotly
    left out when the figure was a graph object given the band before its bars; every figure valid for Plotly."""
    import plotly.graph_objects as go

    from spaceid.studies._html_figures import monitor_figures

    record = monitor(cepheus[1], capture, H, noise=NOISE)
    (statistic, _), _, (changes, _) = figures = monitor_figures(record)
    for fig, _ in figures:
        go.Figure(fig)  # raises on a property Plotly does not know
    threshold, (event,) = record.settings["threshold"], record.events
    assert [(s["type"], s["y0"], s.get("x0")) for s in statistic["layout"]["shapes"]] == [
        ("line", threshold, 0), ("line", 0, event.time), ("line", 0, event.detected_at)]
    assert [(s["type"], s["y0"], s["y1"]) for s in changes["layout"]["shapes"]] == [("rect", -3.0, 3.0)]


def test_downsampling_keeps_each_bins_extremes():
    rng = np.random.default_rng(0)
    t = np.arange(100_000) * 1e-3
    y = rng.normal(size=t.size)
    y[[123, 54_321]] = [50.0, -60.0]  # spikes a plain stride would miss
    ts, ys, thinned = downsample(t, y)
    assert thinned and ts.size <= MAX_POINTS and np.all(np.diff(ts) > 0)
    assert ys.max() == 50.0 and ys.min() == -60.0
    bins = np.array_split(np.arange(t.size), MAX_POINTS // 2)
    assert all(y[b].max() in ys and y[b].min() in ys for b in bins[::97])
    assert downsample(t[:10], y[:10])[2] is False


def test_the_statistic_trace_is_bounded_and_keeps_the_peaks():
    trace = StatisticTrace(capacity=100)
    g = np.abs(np.sin(np.arange(10_000) / 50.0))
    g[[777, 9001]] = [40.0, 30.0]
    for i, v in enumerate(g):
        trace.add(float(i), float(v))
    t, kept = trace.arrays()
    assert t.size <= 100 and np.all(np.diff(t) > 0)
    assert 40.0 in kept and 30.0 in kept and t[kept == 40.0][0] == 777
    stride = trace.stride
    assert all(kept[j] == g[j * stride:(j + 1) * stride].max() for j in range(t.size))


@pytest.mark.slow
def test_the_commands_write_their_reports_by_default(identification, tmp_path, capsys):
    log, _, _ = identification
    write_log(tmp_path / "log.csv", log)
    assert main(["identify", "cepheus", str(tmp_path / "log.csv"), "--momentum", "0.5", "-o",
                 str(tmp_path / "r.json")]) == 0
    _assert_self_contained(tmp_path / "r.html")
    assert main(["monitor", "cepheus", str(tmp_path / "log.csv"), "--momentum", "0.5", "-o", str(tmp_path / "e.json"),
                 "--report", str(tmp_path / "m.html")]) == 0
    assert (tmp_path / "m.html").is_file() and not (tmp_path / "e.html").exists()
    assert main(["identify", "cepheus", str(tmp_path / "log.csv"), "--momentum", "0.5", "-o", str(tmp_path / "x.json"),
                 "--report", str(tmp_path / "x.json")]) == 2
    assert capsys.readouterr().err.endswith("is the -o file: give another name\n")


# --- in a real browser ------------------------------------------------------------------------------------


@pytest.fixture(scope="module")
def pages(identification, capture, cepheus, tmp_path_factory):
    """Every kind of report page, written once."""
    folder = tmp_path_factory.mktemp("pages")
    log, ident, check = identification
    _, param = cepheus
    written = {"identification": write_html_report(
        folder / "identification", title="identification", result=ident, settings={"seed": 1}, figures={},
        true=param.true_values, metrics=check.metrics, validations=[(log, check.predicted, "validation")])}
    written["validation"] = write_validation_html(folder / "validation.html", log, [(check.predicted, None)],
                                                  check.metrics, title="validation", source="test")
    record = monitor(param, capture, H, noise=NOISE)
    t, g = record.statistic
    assert len(record.events) >= 1 and all(e.statistic in g for e in record.events)  # the alarms' peaks kept
    assert np.all(np.diff(t) >= 0) and t.size <= 4000
    written["monitor"] = write_monitor_html(record, folder / "monitor.html", source="capture")
    mc = run_montecarlo(param, "paper-table2", momentum=H, noise=DEFAULT_NOISE, samples=35, runs=8, seed=2, jobs=1,
                        estimators=("ml", "ols"))
    written["montecarlo"] = write_montecarlo_html(mc, folder / "montecarlo.html")
    return written


def _browser():
    """Headless Chromium through chromedriver; skipped (failed on CI) when it is not installed."""
    missing = [str(p) for p in (CHROMIUM, CHROMEDRIVER) if not p.exists()]
    try:
        from selenium import webdriver
        from selenium.webdriver.chrome.service import Service
    except ImportError:
        missing.append("selenium (pip install -e \".[test]\")")
    if missing:
        reason = f"the browser test needs {', '.join(missing)}: apt-get install -y chromium chromium-driver"
        if os.environ.get("CI"):
            pytest.fail(f"CI: {reason}")
        pytest.skip(reason)
    profile = tempfile.mkdtemp(prefix="spaceid-chromium-")
    options = webdriver.ChromeOptions()
    for flag in ("--headless", "--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run",
                 "--disable-background-networking", "--disable-component-update", "--disable-sync",
                 f"--user-data-dir={profile}", "--window-size=1280,1000"):
        options.add_argument(flag)
    options.binary_location = str(CHROMIUM)
    options.set_capability("goog:loggingPrefs", {"browser": "ALL"})
    return webdriver.Chrome(service=Service(str(CHROMEDRIVER)), options=options), profile


@pytest.fixture(scope="module")
def browser():
    driver, profile = _browser()
    yield driver
    driver.quit()
    shutil.rmtree(profile, ignore_errors=True)


def _drawn(png: bytes) -> tuple:
    """The share of the figure's pixels that are not white, and its distinct colours."""
    from PIL import Image

    image = np.asarray(Image.open(BytesIO(png)).convert("RGB")).reshape(-1, 3)
    return np.mean(np.any(image < 245, axis=1)), len(np.unique(image, axis=0))


def _traces(driver) -> list:
    """Per figure: its data traces, and the traces drawn (a path with a shape in its plot area)."""
    return driver.execute_script("""
        return Array.from(document.querySelectorAll('div.plotly-graph-div')).map(function(div){
          var drawn = Array.from(div.querySelectorAll('.cartesianlayer g.trace')).filter(function(g){
            return Array.from(g.querySelectorAll('path')).some(function(p){
              return (p.getAttribute('d') || '').length > 8; }); });
          return [div.data.length, drawn.length];
        });""")


@pytest.mark.slow
@pytest.mark.parametrize("kind", ["identification", "validation", "monitor", "montecarlo"])
def test_the_report_opens_in_a_browser_with_every_figure_drawn(pages, browser, kind):
    from selenium.webdriver.common.by import By

    browser.get(pages[kind].resolve().as_uri())
    assert [e for e in browser.get_log("browser") if e["level"] == "SEVERE"] == []
    figures = browser.find_elements(By.CSS_SELECTOR, "div.plotly-graph-div")
    assert len(figures) == {"identification": 3, "validation": 1, "monitor": 3, "montecarlo": 2}[kind]
    for figure, (traces, drawn) in zip(figures, _traces(browser)):
        assert traces >= 1 and drawn == traces, (kind, traces, drawn)  # every trace drawn
        browser.execute_script("arguments[0].scrollIntoView();", figure)
        ink, colours = _drawn(figure.screenshot_as_png)
        assert 0.02 < ink < 0.9 and colours > 20, (kind, ink, colours)
    resources = browser.execute_script("return performance.getEntriesByType('resource').map(e => e.name)")
    assert [r for r in resources if not r.startswith(("file:", "data:"))] == []


@pytest.mark.slow
def test_the_parameter_table_sorts_on_a_header_click(pages, browser):
    from selenium.webdriver.common.by import By

    browser.get(pages["identification"].resolve().as_uri())
    table = browser.find_elements(By.CSS_SELECTOR, "table.sortable")[0]  # the settings' is not sortable
    headers = [th.text for th in table.find_elements(By.CSS_SELECTOR, "thead th")]
    column = headers.index("estimate")

    def values():
        return [float(td.get_attribute("data-v")) for td in
                table.find_elements(By.CSS_SELECTOR, f"tbody tr td:nth-child({column + 1})")]

    original = values()
    header = table.find_elements(By.CSS_SELECTOR, "thead th")[column]
    header.click()
    assert values() == sorted(original) and header.get_attribute("aria-sort") == "ascending"
    header.click()
    assert values() == sorted(original, reverse=True)
    names = table.find_elements(By.CSS_SELECTOR, "thead th")[0]
    names.click()
    assert [td.text for td in table.find_elements(By.CSS_SELECTOR, "tbody tr td:first-child")] == \
        sorted(f"pi{i}" for i in range(1, len(original) + 1))
