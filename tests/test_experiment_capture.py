"""The servicing sequence on the Cepheus twin: ``spaceid experiment --capture``."""

import json
from dataclasses import replace

import numpy as np
import pytest

from spaceid import SpaceidError
from spaceid.cli import main
from spaceid.identified.internal import draw_payload
from spaceid.motion import FourierTrajectory
from spaceid.studies import ServicingScores, capture_protocol, run_experiment
from spaceid.studies._figures import _draw_capture_monitor
from spaceid.twin import TwinSettings

HELD_OUT = FourierTrajectory(("left_shoulder", "left_elbow"), 5.0, np.array([[0.2, -0.1, 0.05], [-0.15, 0.1, 0.05]]),
                             np.array([[0.1, 0.05, -0.05], [0.1, -0.1, 0.05]]), meta={"name": "held-out"})  # fmt: skip


@pytest.fixture(scope="module")
def ideal(tmp_path_factory):
    """The sequence on the ideal twin: paper-table2 excites, a given motion is held out (no design)."""
    folder = tmp_path_factory.mktemp("capture")
    return run_experiment(trajectory="paper-table2", validation=HELD_OUT, settings=TwinSettings().without_effects(),
                          bag_format="mcap", seed=3, out=folder, capture=capture_protocol())  # fmt: skip


def test_capture_protocol_defaults_file_and_override(tmp_path):
    default = capture_protocol()
    assert default.payload.mass == 0.5 and default.offset == (0.04, 0.0) and default.yaw == 0.0
    path = tmp_path / "payload.yaml"
    path.write_text("mass: 0.8\ncom: [0.01, 0.0]\ninertia: [1e-3, 1e-3, 1.5e-3]\noffset: [0.05, 0.01]\nyaw: 0.3\n")
    p = capture_protocol(path, mass=0.3)
    assert p.payload.mass == 0.3 and p.payload.com == (0.01, 0.0) and p.offset == (0.05, 0.01) and p.yaw == 0.3
    assert np.allclose(np.diag(p.payload.inertia_matrix()), [1e-3, 1e-3, 1.5e-3])
    json_path = tmp_path / "payload.json"
    json_path.write_text(json.dumps({"mass": 1.2, "link": "link2"}))
    assert capture_protocol(json_path).payload.mass == 1.2


@pytest.mark.parametrize("text, match", [("masses: 1\n", "unknown capture setting.*masses"),
                                         ("- 1\n", "must be a mapping"), ("mass: -1\n", r"capture.mass \[kg\]"),
                                         ("offset: [1]\n", "capture offset")])  # fmt: skip
def test_capture_protocol_refuses_bad_settings(tmp_path, text, match):
    path = tmp_path / "bad.yaml"
    path.write_text(text)
    with pytest.raises(SpaceidError, match=match):
        capture_protocol(path)


def test_cli_capture_options_need_capture(capsys):
    assert main(["experiment", "--capture-mass", "0.4"]) == 2
    err = capsys.readouterr().err
    assert "error: --capture-mass, --capture-settings and --capture-trajectory need --capture" in err


def test_an_alarm_before_the_grasp_can_show_is_a_false_alarm():
    """The rates show the grasp up to an event's lead early: an alarm raised before that (to a
    sample step) is a false alarm however close; one raised after it is the grasp's even when its
    change time comes earlier than the lead allows (before: scored by the change interval, which
    took the grasp found at 4.5 s, alarm 4.6 s, for a false alarm)."""
    from types import SimpleNamespace

    from spaceid.studies._servicing import _scores

    estimate = SimpleNamespace(names=("m",), values=np.array([0.5]), std=np.array([0.01]), not_identifiable=())
    truth = {"payload": {"mass": 0.5, "com": [0.0, 0.0, 0.0], "inertia": 1e-3 * np.eye(3)}}
    events = {"events": [{"time": t, "lead": 0.45, "detected_at": t + 0.1} for t in (3.0, 4.42, 4.5, 5.2)],
              "settings": {"drift": []}}
    scores = ServicingScores(**_scores(estimate, truth, events, SimpleNamespace(t=np.arange(0, 10, 0.02)), 5.0))
    assert scores.false_alarms == 2 and scores.detected_change_time == 4.5
    assert scores.change_time_error_samples == -25.0
    assert scores.to_dict()["payload"] == [{"name": "m", "true": 0.5, "estimate": 0.5, "std": 0.01, "z": 0.0}]


def test_capture_figures_name_the_grasp_and_units():
    from spaceid.data import Log

    t = np.linspace(0, 4, 201)
    log = Log(t, ("reaction_wheel_joint", "left_shoulder", "left_elbow"), np.c_[170 * t, np.sin(t), np.cos(t)],
              np.c_[np.full_like(t, 170), np.cos(t), -np.sin(t)], np.tile([1.0, 0, 0, 0], (201, 1)),
              np.c_[np.zeros((201, 2)), 0.1 * np.sin(t)], planar=True)  # fmt: skip
    scores = ServicingScores(grasp_time=2.0, detected_change_time=1.9, detected_at=2.1, change_time_error=-0.1,
                             change_time_error_samples=-5.0)  # fmt: skip
    fig = _draw_capture_monitor(log, scores, ("left_shoulder", "left_elbow"))
    labels = fig.legends[0].get_texts()
    assert {"grasp (twin's truth)", "detected change", "alarm (threshold crossed)"} <= {x.get_text() for x in labels}
    assert "-5 samples" in fig._suptitle.get_text() and "[rad/s]" in fig.axes[1].get_ylabel()
    rows = [{"name": "m", "true": 0.5, "estimate": 0.49, "std": 0.01, "z": -1.0},
            {"name": "Izz", "true": 1e-3, "estimate": 1.1e-3, "std": 1e-4, "z": 1.0}]
    fig = draw_payload(rows, "link2")
    assert [ax.get_title(loc="left") for ax in fig.axes] == ["m [kg]", "Izz [kg m$^{2}$]"]
    assert fig.axes[0].get_title(loc="right") == "z = -1.00" and "link2" in fig._suptitle.get_text()


def test_payload_within_its_error_bars_of_the_truth(ideal):
    s = ideal.servicing
    truth = s.truth["payload"]
    assert [p.name for p in s.scores.payload] == ["m", "cx", "cy", "Izz"]
    assert s.scores.payload[0].true == truth["mass"] == 0.5
    z = np.array([p.z for p in s.scores.payload])
    assert np.all(np.abs(z) < 3), z
    # the payload at the gripper: its frame 4 cm along link2, its CoM (0.02, 0.01) further on
    assert truth["com"][:2] == pytest.approx([0.06, 0.01], abs=1e-9)
    assert s.payload.settings["momentum_estimated"] is False and s.payload.link == "link2"


def test_change_detected_within_a_few_samples_of_the_grasp(ideal):
    sc = ideal.servicing.scores
    assert sc.detected_change_time is not None
    # the change shows in the differentiated rates up to half the differentiator's window (the lead) early
    lead = sc.change_time_lead / sc.sample_period
    assert -lead - 1 <= sc.change_time_error_samples <= 15, sc
    assert abs(sc.alarm_time_from_grasp) < 0.5, sc
    # the grasp is after the held-out phase, which was run without the payload
    assert sc.grasp_time > ideal.validation_log.t[-1] - 1e-9
    assert ideal.servicing.truth["time"] == pytest.approx(ideal.settings["capture time (twin clock) [s]"])


def test_only_the_phases_from_the_grasp_on_carry_the_capture(ideal):
    s = ideal.settings
    assert s["capture phase seed"] == 3 + 4 and s["capture trajectory"] == "paper-table2"
    # the held-out phase ran on the servicer alone: its recording holds no grasp record
    assert s["twin"]["capture"] is None
    assert ideal.servicing.window.t[0] > ideal.servicing.scores.grasp_time


def test_report_files_and_section(ideal):
    folder = ideal.folder
    names = {p.name for p in folder.iterdir()}
    assert {"capture.mcap", "payload.json", "events.json", "capture_log.csv", "capture_truth.csv",
            "capture_trajectory.json", "capture.png", "payload.png", "report.md"} <= names  # fmt: skip
    payload = json.loads((folder / "payload.json").read_text())
    assert payload["link"] == "link2" and payload["mass"] == pytest.approx(ideal.servicing.payload.mass)
    events = json.loads((folder / "events.json").read_text())
    assert events["events"] and events["settings"]["warmup"] == 200
    text = (folder / "report.md").read_text()
    assert "## Capture: change detection and the payload" in text and "(payload.png)" in text
    assert "change time error \\[samples\\]" in text or "change time error [samples]" in text
    saved = json.loads((folder / "experiment.json").read_text())
    assert saved["capture"] == json.loads(json.dumps(ideal.servicing.scores.to_dict()))
    assert saved["capture"]["grasp_time"] == pytest.approx(ideal.servicing.scores.grasp_time)
    assert "| grasp time \\[s\\] |" in text or "| grasp time [s] |" in text  # labelled from the machine keys
    whole = ideal.servicing.to_dict()
    assert json.loads(json.dumps(whole))["scores"]["grasp_time"] == saved["capture"]["grasp_time"]


@pytest.mark.slow
def test_cli_capture_on_the_realistic_twin(tmp_path, capsys):
    """Every effect on (friction, thrusters, tank drain), a drift torque estimated with the payload."""
    folder = tmp_path / "real"
    assert main(["experiment", "--trajectory", "paper-table2", "--validation", str(_saved(tmp_path)), "--capture",
                 "--capture-mass", "0.6", "--drift", "torque", "--out", str(folder)]) == 0  # fmt: skip
    printed = capsys.readouterr().out
    assert "payload   m = " in printed and "change detected" in printed
    payload = json.loads((folder / "payload.json").read_text())
    experiment = json.loads((folder / "experiment.json").read_text())
    scores = experiment["capture"]
    assert experiment["settings"]["capture payload mass [kg]"] == 0.6 and payload["drift"][0]["name"] == "torque_z"
    events = json.loads((folder / "events.json").read_text())  # the monitor estimates the same drift terms
    assert events["settings"]["drift"] == ["torque"] and scores["monitor_drift_terms"] == "torque"
    assert all(s["drift"][0]["name"] == "torque_z" for s in events["segments"] if s["drift"] is not None)
    assert scores["payload"][0]["true"] == 0.6 and abs(payload["mass"] / 0.6 - 1) < 0.03, payload["mass"]
    assert all(abs(p["z"]) < 4 for p in scores["payload"]), scores["payload"]
    if scores["false_alarms"] == 0:
        assert abs(scores["change_time_error_samples"]) <= 20, scores
    else:  # a false alarm's new segment may warm up over the grasp: found by the warm-up's test, later
        assert scores["change_time_error_samples"] is not None, scores


@pytest.mark.slow
def test_payload_errors_covered_on_the_realistic_twin():
    """Friction, thrusters, tank, quantisation, motion-capture noise and latency: over seeds the
    payload's standard errors cover its errors (before the fix: m 4-11 % low, z down to -7.6)."""
    z = []
    for seed in (0, 1, 2):
        r = run_experiment(trajectory="paper-table2", validation=HELD_OUT, bag_format="mcap", seed=seed,
                           capture=capture_protocol())  # fmt: skip
        s = r.servicing.scores
        z += [p.z for p in s.payload]
        assert abs(s.payload[0].estimate / 0.5 - 1) < 0.02, s.payload[0]
        # the window starts half the differentiator's window after the grasp; the momentum from the hold before it
        assert 0.1 < s.payload_window_start_after_grasp < 0.6 and s.momentum_before_grasp
    z = np.array(z)
    assert np.abs(z).max() < 4 and np.sqrt(np.mean(z**2)) < 1.5, z


@pytest.mark.slow
def test_a_moving_payload_on_the_ideal_twin():
    """A payload gliding and turning when grasped brings its own momentum: given its velocity and
    rate, the estimate stays within its errors (ignored, as before: the mass 12 % high over 12
    seeds, its RMSE 9.6 standard errors; benchmarks/bench_capture.py --moving 0.04 -0.03 0.3)."""
    protocol = capture_protocol()
    protocol = replace(protocol, payload=replace(protocol.payload, velocity=(0.04, -0.03), rate=0.3))
    r = run_experiment(trajectory="paper-table2", validation=HELD_OUT, settings=TwinSettings().without_effects(),
                       bag_format="mcap", seed=1, capture=protocol)  # fmt: skip
    s = r.servicing.scores
    assert s.payload_motion == ([0.04, -0.03, 0.0], [0.0, 0.0, 0.3])
    assert r.servicing.payload.settings["payload_momentum"][2] > 0.005
    z = np.array([p.z for p in s.payload])
    assert np.all(np.abs(z) < 3), z


def _saved(tmp_path):
    path = tmp_path / "held_out.json"
    HELD_OUT.save(path)
    return path


@pytest.mark.slow
def test_whitening_stays_positive_definite_with_exact_arm_encoders():
    """Exact arm angles (the differentiator's noise ~1e-7 rad), a quantised wheel and a 2 s warm-up
    that leaves one parameter direction 1e13 times less certain than another: the whitening's
    covariance update turned indefinite and the monitor raised LinAlgError (seed 3, before its
    prior's variances were capped)."""
    from spaceid.dynamics import minimal_parameters
    from spaceid.estimation import Monitor, Noise
    from spaceid.models import load_model

    settings = TwinSettings().without_effects()
    settings = replace(settings, encoders=replace(settings.encoders, counts_per_rev={"reaction_wheel_joint": 4096}))
    r = run_experiment(trajectory="paper-table2", validation=HELD_OUT, settings=settings, bag_format="mcap", seed=3,
                       capture=capture_protocol())  # fmt: skip
    levels = r.servicing.events["settings"]["noise"]
    noise = Noise(**{k: levels[k] for k in ("angle", "rate", "base_rate", "attitude")}, source=levels["source"])
    param = minimal_parameters(load_model(settings.model), seed=r.settings["capture phase seed"])
    mon = Monitor(param, np.zeros(3), noise=noise, warmup=100)
    mon.update(r.servicing.log)
    events = mon.finish().events
    grasp, step = r.servicing.scores.grasp_time, r.servicing.scores.sample_period
    # found, if late: the alarms the 2 s warm-up raises leave the grasp in an untested warm-up (docs/theory/capture.md)
    assert any(e.detected_at + step >= grasp - e.lead for e in events), events
