"""The monitor with drift terms: an external torque on the base (an air-bearing table's friction)
moves the momentum, and each segment estimates its drift coefficients with its parameters
(spaceid.estimation._monitor)."""

import json
import warnings

import numpy as np
import pytest
from conftest import random_tree
from test_monitor import H, NOISE, RATE, T_CAPTURE, _assert_false_alarm_rate, _concatenate, _motion, _noisy
from test_monitor import _with_payload
from test_monitor import cepheus  # noqa: F401  the module fixture: Cepheus and its minimal parameters

from spaceid.cli import main
from spaceid.data import Log, write_log
from spaceid.dynamics import minimal_parameters
from spaceid.estimation import Monitor, Noise, monitor
from spaceid.estimation._drift import drift_basis
from spaceid.motion import simulate

VISCOUS = 5e-4  # [N m s/rad]: the base turns ~20 rad in 20 s, the momentum moves 2 % of H
DRIFT = {"viscous": VISCOUS}


@pytest.fixture(scope="module")
def drifting(cepheus):
    model, param = cepheus
    return simulate(param, param.true_values, _motion, np.arange(2000) / RATE, H, model=model, drift=DRIFT)


def _true_momentum(log: Log, t: float) -> np.ndarray:
    """The momentum [N m s] of the drifting log at its sample ``t``: H plus the viscous drift since."""
    k = int(np.argmin(np.abs(log.t - t)))
    return H + VISCOUS * drift_basis(log.select(slice(0, k + 1)), ("viscous",))[-1, 0]


@pytest.fixture(scope="module")
def drifting_capture(cepheus):
    """Cepheus grasping 0.1 kg at 0.2 m along link2 at T_CAPTURE on the drifting table: the momentum
    at the grasp carries over and drifts on from there. Noise-free log, the captured parameters."""
    model, param = cepheus
    captured = minimal_parameters(_with_payload(model, "link2", 0.1, [0.2, 0, 0]))
    t = np.arange(1200) / RATE
    before = simulate(param, param.true_values, _motion, t[t <= T_CAPTURE], H, model=model, drift=DRIFT)
    h = _true_momentum(before, T_CAPTURE)
    after = simulate(param, captured.true_values, _motion, t[t >= T_CAPTURE], h, initial_quat=before.base_quat[-1],
                     drift=DRIFT)
    return _concatenate(before.select(slice(0, -1)), after), captured.true_values


def _basis(mon, chunk) -> np.ndarray:
    """The drift basis ``(n, n_d, 3)`` the monitor attaches to the samples of ``chunk``."""
    return np.array([sample.basis for sample in mon._intake.with_basis(chunk)])


@pytest.fixture(scope="module")
def turning(cepheus):
    """A drifting log whose base turns both ways (1500 samples), shared by the chunked-basis tests."""
    model, param = cepheus
    return simulate(param, param.true_values, _motion, np.arange(1500) / RATE, np.array([0, 0, 0.05]), model=model,
                    drift={"viscous": 1e-3})


@pytest.mark.parametrize("kinds", [("torque",), ("viscous",), ("coulomb",)])
@pytest.mark.parametrize("chunk", [1, 7])
def test_running_basis_continues_across_chunks(cepheus, turning, kinds, chunk):
    """The drift basis accumulated chunk by chunk is the whole log's: exactly for the closed forms
    (torque, the planar viscous's unwrapped yaw); the Coulomb kind's sign changes are located
    from the samples a chunk has after them (a few microseconds apart here)."""
    _, param = cepheus
    log = turning
    assert np.sum(np.diff(np.sign(log.base_w[:, 2])) != 0) >= 2  # the base turns both ways
    mon = Monitor(param, H, drift=kinds)
    running = np.concatenate([_basis(mon, log.select(slice(i, i + chunk)))
                              for i in range(0, log.n_samples, chunk)])  # fmt: skip
    whole = drift_basis(log, kinds)
    assert np.max(np.abs(running - whole)) < (1e-3 / RATE if kinds == ("coulomb",) else 1e-12 * np.max(np.abs(whole)))


def test_running_basis_of_a_spatial_log():
    """Spatial drift bases are spline quadratures: chunk by chunk within 1e-9 of the whole log's
    (the Coulomb kind's, of a rate direction that jumps where the rate passes zero, differ more:
    docs/theory/monitor.md)."""
    model = random_tree(np.random.default_rng(1), [0, 1], planar=False)
    param = minimal_parameters(model)
    log = simulate(param, param.true_values, _motion, np.arange(600) / 50, np.array([0.5, -0.4, 0.8]), model=model)
    mon = Monitor(param, np.array([0.5, -0.4, 0.8]), drift=("viscous",))
    running = np.concatenate([_basis(mon, log.select(slice(i, i + 7))) for i in range(0, log.n_samples, 7)])
    whole = drift_basis(log, ("viscous",))
    assert np.max(np.abs(running - whole)) < 1e-9 * np.max(np.abs(whole))


@pytest.mark.parametrize("kinds", [("torque",), ("viscous",), ("coulomb",)])
def test_a_gap_in_the_samples_and_the_drift_basis(cepheus, turning, kinds):
    """0.3 s of samples lost (a gap the live aligner skips) where the base rate turns both ways (two
    sign changes, 0.18 s apart, in the gap): the torque's basis (time) and the planar viscous one
    (the yaw's change) are exact across it, without a warning; the planar Coulomb basis, which
    sees the same sign at both ends, misses the 0.18 s the rate spent reversed, twice (0.36 s of
    the basis: that times the friction torque in momentum), and the monitor warns that it
    integrates across the gap as if the base had turned smoothly. Away from sign changes the
    Coulomb basis across a gap is exact to the crossings' location (1e-6 s)."""
    _, param = cepheus
    w = turning.base_w[:, 2]
    k = np.flatnonzero(np.diff(np.sign(w)) != 0)[:2]
    assert k[1] - k[0] < 20  # two sign changes within 0.2 s
    for lost, tolerance in [(slice(k[0] - 10, k[0] + 20), 0.3), (slice(500, 530), 1e-5)]:
        keep = np.r_[0 : lost.start, lost.stop : turning.n_samples]
        gapped = turning.select(keep)
        mon = Monitor(param, H, drift=kinds)
        mon._intake.learn_window(gapped)
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            running = np.concatenate([_basis(mon, gapped.select(slice(i, i + 7)))
                                      for i in range(0, gapped.n_samples, 7)])  # fmt: skip
        error = np.max(np.abs(running - drift_basis(turning, kinds)[keep]))
        said = [str(c.message) for c in caught if "drift basis is integrated across it" in str(c.message)]
        if kinds == ("coulomb",):
            assert len(said) == 1 and "no sample for 0.31 s" in said[0]
            if lost.start < k[0] < k[1] < lost.stop:  # both sign changes in the gap: twice the time reversed
                assert error == pytest.approx(2 * (turning.t[k[1]] - turning.t[k[0]]), abs=0.03)
            else:
                assert error < tolerance
        else:
            assert not said and error < 1e-12 * np.max(np.abs(running))


def test_a_gap_in_a_spatial_log_is_warned_about():
    """A spatial viscous drift basis across 0.3 s of lost samples is a spline through the gap: the
    monitor warns (the chunked basis without the gap is the whole log's to 1e-9, above)."""
    model = random_tree(np.random.default_rng(1), [0, 1], planar=False)
    param = minimal_parameters(model)
    log = simulate(param, param.true_values, _motion, np.arange(600) / 50, np.array([0.5, -0.4, 0.8]), model=model)
    gapped = log.select(np.r_[0:300, 315:600])
    mon = Monitor(param, np.array([0.5, -0.4, 0.8]), drift=("viscous",))
    mon._intake.learn_window(gapped)
    with pytest.warns(UserWarning, match=r"no sample for 0\.32 s from 5\.98 s: the viscous drift basis is integrated"):
        for i in range(0, gapped.n_samples, 7):
            _basis(mon, gapped.select(slice(i, i + 7)))


# fast representatives: test_monitor.py::test_finds_the_capture_within_a_few_samples, test_cli_monitor_with_drift
@pytest.mark.slow
def test_noise_free_drift_and_momentum_through_a_capture(drifting_capture, cepheus):
    """Noise-free: the capture found at its sample, each segment's drift coefficient recovered, and
    the second segment's momentum at its start carried over from the first's (weighted least
    squares: the ML fit of a noise-free warm-up leaves autocorrelated residuals of round-off size,
    and the AR filter fitted to them scales the innovations by them: alarms, drift or not)."""
    log, truth = drifting_capture
    _, param = cepheus
    tiny = Noise(angle=1e-9, rate=1e-8, base_rate=1e-8, attitude=1e-9)
    mon = Monitor(param, H, noise=tiny, drift=("viscous",), estimator="wls")
    mon.update(log)
    record = mon.finish()
    assert len(record.events) == 1 and abs(record.events[0].time - T_CAPTURE) <= 1 / RATE
    for segment, pi in zip(record.segments, (param.true_values, truth)):
        ident = segment.identification
        assert np.max(np.abs(ident.values - pi) / np.abs(pi)) < 1e-6
        assert ident.drift[0]["value"] == pytest.approx(VISCOUS, rel=1e-6)
    second = record.segments[1]
    h_true = _true_momentum(log, second.momentum_from)
    assert np.max(np.abs(second.momentum - h_true)) < 1e-9
    assert record.settings["drift"] == ["viscous"]


@pytest.mark.slow  # fast representatives: test_cli_monitor_with_drift (no event, the coefficient within its errors)
def test_a_drift_is_no_change(drifting, cepheus):
    """A noisy drifting log without a change: alarms without drift terms (the friction looks like a
    change), none with them, the drift coefficient and the parameters within their errors."""
    _, param = cepheus
    log = _noisy(drifting, 4)
    assert monitor(param, log, H, noise=NOISE).events  # the test can fail: the drift alone raises events
    mon = Monitor(param, H, noise=NOISE, drift=("viscous",))
    mon.update(log)
    rec = mon.estimate()
    assert mon.finish().events == ()
    assert abs(rec["drift"][0] - VISCOUS) < 4 * rec["drift_std"][0]
    assert np.all(np.abs(rec["values"] - param.true_values) < 5 * rec["std"])
    assert rec["momentum_from"] == drifting.t[0] and np.array_equal(rec["momentum"], H)


# fast representatives: test_monitor.py::test_finds_the_capture_within_a_few_samples, test_cli_monitor_with_drift
@pytest.mark.slow
def test_finds_the_capture_on_a_drifting_log(drifting_capture, cepheus):
    log, _ = drifting_capture
    _, param = cepheus
    events = monitor(param, _noisy(log, 1), H, noise=NOISE, drift=("viscous",)).events
    assert len(events) == 1 and abs(events[0].time - T_CAPTURE) <= 2 / RATE


@pytest.mark.slow
def test_false_alarm_rate_with_drift_as_stated(drifting, cepheus):
    """At 1e-3 false alarms per sample, 24 seeded drifting logs without a change, drift estimated:
    the alarms within three Poisson standard deviations of the stated rate (48 against 41.6; the
    warm-ups' tests estimating the drift coefficient from their first samples raised 81)."""
    _, param = cepheus
    _assert_false_alarm_rate(param, [_noisy(drifting, 200 + seed) for seed in range(24)], NOISE,
                             drift=("viscous",))  # fmt: skip


def test_cli_monitor_with_drift(drifting, tmp_path, capsys):
    write_log(tmp_path / "log.csv", _noisy(drifting, 5))
    base = ["monitor", "cepheus", str(tmp_path / "log.csv"), "--momentum", "0.5", "--noise-angle", "1e-4",
            "--noise-rate", "1e-3", "--noise-base-rate", "1e-3", "-o", str(tmp_path / "events.json")]
    assert main(base + ["--drift", "viscous"]) == 0
    record = json.loads((tmp_path / "events.json").read_text())
    assert record["events"] == [] and record["settings"]["drift"] == ["viscous"]
    (segment,) = record["segments"]
    assert segment["drift"][0]["name"] == "viscous" and segment["momentum"] == [0.0, 0.0, 0.5]
    assert abs(segment["drift"][0]["value"] - VISCOUS) < 4 * segment["drift"][0]["std"]
    assert main(base + ["--drift", "wind"]) == 2
    assert "--drift: 'wind' is not a drift kind" in capsys.readouterr().err
