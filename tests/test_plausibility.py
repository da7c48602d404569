"""Plausibility flags (issue 12, point 4): logs that read but are wrong get a ``warning:`` line
naming the column and the likely cause (or a refusal where they cannot be right), recorded in the
result; clean logs get none."""

import csv
import json
import warnings

import numpy as np
import pytest

import spaceid
from spaceid.cli import main
from spaceid.data import read_log, write_log
from spaceid.dynamics import minimal_parameters
from spaceid.motion import FourierTrajectory, add_noise, simulate

H = "0.4934"
JOINTS = ("left_shoulder", "left_elbow")
FLAGS = ("column t:", "disagree", "integrates to", "looks stored", "misses the measured", "times the noise")


def _table(path):
    rows = list(csv.reader(open(path)))
    return rows[0], np.array(rows[1:], float)


def _write(path, header, values):
    path.write_text(",".join(header) + "\n" + "\n".join(",".join(repr(float(v)) for v in r) for r in values) + "\n")
    return path


def _mutated(src, dst, change):
    """``src`` CSV with ``change(columns: dict name -> index, values)`` applied, written to ``dst``."""
    header, values = _table(src)
    header = change({n: i for i, n in enumerate(header)}, values, header) or header
    return _write(dst, header, values)


@pytest.fixture(scope="module")
def logs(tmp_path_factory):
    """A noisy 50 Hz Cepheus log of paper-table2 (and a second, held-out one)."""
    d = tmp_path_factory.mktemp("plausibility")
    common = ["simulate", "cepheus", "--trajectory", "paper-table2", "--momentum", H, "--rate", "50",
              "--noise-angle", "1e-4", "--noise-rate", "1e-4"]
    assert main([*common, "--seed", "1", "-o", str(d / "log.csv")]) == 0
    assert main([*common, "--seed", "2", "-o", str(d / "held.csv")]) == 0
    return d


def _identify(log, out, capsys):
    code = main(["identify", "cepheus", str(log), "--momentum", H, "-o", str(out)])
    return code, [" ".join(line.split()) for line in capsys.readouterr().err.splitlines()]


def _scale_t(factor):
    def change(col, values, header):
        values[:, col["t"]] *= factor
    return change


def _swap_joints(col, values, header):
    a, b = col["q_left_shoulder"], col["q_left_elbow"]
    values[:, [a, b]] = values[:, [b, a]]


def _deg_per_s(col, values, header):
    values[:, col["base_wz"]] = np.degrees(values[:, col["base_wz"]])


CASES = {
    "milliseconds with rates": (_scale_t(1e3), "column t: every rate integrates to 1e+03 times its angle's change: "
                                "time stamps in milliseconds? Convert t to seconds"),
    "base rate in deg/s": (_deg_per_s, "columns base_yaw and base_wz: the rate integrates to 57.3 times the angle's "
                           "change: likely the rate in deg/s"),
    "two joint columns swapped": (_swap_joints, "columns q_left_shoulder and qd_left_shoulder disagree: the angle's "
                                  "increments depart from the rate's integral by 100 %, while q_left_elbow follows "
                                  "qd_left_shoulder: columns swapped or mislabelled?"),
}


@pytest.mark.parametrize("case", CASES, ids=list(CASES))
def test_identify_flags_wrong_but_readable_log(case, logs, tmp_path, capsys):
    change, expected = CASES[case]
    log = _mutated(logs / "log.csv", tmp_path / "bad.csv", change)
    code, lines = _identify(log, tmp_path / "r.json", capsys)
    assert code == 0
    flagged = [line for line in lines if line.startswith("warning: ") and expected in line]
    assert len(flagged) == 1, lines
    settings = json.loads((tmp_path / "r.json").read_text())["settings"]
    assert any(expected in text for text in settings["log"]["plausibility"])  # recorded in the result


def test_swapped_joints_poor_fit_says_so(logs, tmp_path, capsys):
    log = _mutated(logs / "log.csv", tmp_path / "bad.csv", _swap_joints)
    _, lines = _identify(log, tmp_path / "r.json", capsys)
    assert any("chi2_dof" in line and "times the noise: the fit is poor, likely wrong data (swapped or mislabelled "
               "columns" in line for line in lines), lines


def test_milliseconds_without_rates_warn_on_the_step(logs, tmp_path, capsys):
    """Angles only: rates differentiated from stamps in ms would make every parameter 1000 times too large."""
    def change(col, values, header):
        values[:, col["t"]] *= 1e3
        keep = [i for i, n in enumerate(header) if not n.startswith(("qd_", "base_w"))]
        return [header[i] for i in keep], values[:, keep]

    header, values = _table(logs / "log.csv")
    new_header, new_values = change({n: i for i, n in enumerate(header)}, values, header)
    log = _write(tmp_path / "ms.csv", new_header, new_values)
    code = main(["identify", "cepheus", str(log), "--momentum", H, "--differentiate", "-o", str(tmp_path / "r.json")])
    lines = [" ".join(line.split()) for line in capsys.readouterr().err.splitlines()]
    assert code == 0
    assert any(line.startswith("warning: ") and "column t: the median time step is 20 s (0.05 Hz), far slower than a "
               "robot's log: if the stamps are in milliseconds, divide t by 1000" in line for line in lines), lines


def test_nanosecond_stamps_are_refused(logs, tmp_path, capsys):
    log = _mutated(logs / "log.csv", tmp_path / "ns.csv", _scale_t(1e9))
    code, lines = _identify(log, tmp_path / "r.json", capsys)
    assert code == 2 and not (tmp_path / "r.json").exists()
    assert lines == [f"error: {log}: column t: the median time step is 2e+07 s (more than a day): the stamps look "
                     "like nanoseconds or microseconds: convert t to seconds"]


@pytest.mark.slow  # two identifications and two validations: ~9 s
def test_validate_against_a_model_1000_times_off_warns(logs, tmp_path, capsys):
    assert main(["identify", "cepheus", str(logs / "log.csv"), "--momentum", H, "-o", str(tmp_path / "r.json")]) == 0
    result = json.loads((tmp_path / "r.json").read_text())
    for p in result["parameters"]:
        p["value"] *= 1000
    (tmp_path / "off.json").write_text(json.dumps(result))
    capsys.readouterr()
    assert main(["validate", str(tmp_path / "r.json"), str(logs / "held.csv"), "--momentum", H,
                 "--out", str(tmp_path / "good")]) == 0
    assert "warning" not in capsys.readouterr().err
    assert main(["validate", str(tmp_path / "off.json"), str(logs / "held.csv"), "--momentum", H,
                 "-o", str(tmp_path / "bad")]) == 0
    lines = [" ".join(line.split()) for line in capsys.readouterr().err.splitlines()]
    assert any(line.startswith(f"warning: {tmp_path / 'off.json'}: the predicted base rate misses the measured one "
                               "by 9") and "the model does not predict this log" in line for line in lines), lines


def test_clean_simulated_logs_raise_no_flag(logs, tmp_path, capsys):
    for name in ("log.csv", "held.csv"):
        code, lines = _identify(logs / name, tmp_path / "r.json", capsys)
        assert code == 0 and not [line for line in lines if line.startswith("warning")], lines
        assert json.loads((tmp_path / "r.json").read_text())["settings"]["log"]["plausibility"] == []


@pytest.fixture(scope="module")
def spatial_log(tmp_path_factory):
    """A noisy satellite-7dof log (quaternion attitude), 100 samples over 10 s."""
    model = spaceid.load_model("satellite-7dof")
    param = minimal_parameters(model)
    rng = np.random.default_rng(0)
    traj = FourierTrajectory(model.joints, 10.0, rng.uniform(-0.3, 0.3, (7, 3)), rng.uniform(-0.3, 0.3, (7, 3)))
    quat0 = np.array([0.9, 0.1, 0.3, 0.3]) / np.linalg.norm([0.9, 0.1, 0.3, 0.3])
    log = simulate(param, param.true_values, lambda t: traj.evaluate(t)[:2], np.linspace(0, 10, 100),
                   np.array([0.5, 0.2, 0.1]), initial_quat=quat0, model=model)
    path = tmp_path_factory.mktemp("spatial") / "sat.csv"
    write_log(path, add_noise(log, angle=1e-4, rate=1e-4, seed=3))
    return model, path


def _read(path, model):
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        log = read_log(path, joints=model.joints, planar=False)
    return log, [str(w.message) for w in caught]


def test_quaternion_stored_xyzw_is_flagged(spatial_log, tmp_path):
    model, path = spatial_log
    clean, messages = _read(path, model)
    assert messages == [] and clean.meta["plausibility"] == []

    def xyzw(col, values, header):
        c = [col[n] for n in ("base_qw", "base_qx", "base_qy", "base_qz")]
        values[:, c] = values[:, [c[1], c[2], c[3], c[0]]]

    _, messages = _read(_mutated(path, tmp_path / "xyzw.csv", xyzw), model)
    assert len(messages) == 1, messages
    assert ("columns base_qw, base_qx, base_qy, base_qz and base_wx, base_wy, base_wz disagree" in messages[0]
            and "the quaternion looks stored x, y, z, w: reorder the columns to w, x, y, z" in messages[0])


def test_spatial_base_rate_in_deg_per_s_is_flagged(spatial_log, tmp_path):
    model, path = spatial_log

    def degrees(col, values, header):
        c = [col[n] for n in ("base_wx", "base_wy", "base_wz")]
        values[:, c] = np.degrees(values[:, c])

    _, messages = _read(_mutated(path, tmp_path / "deg.csv", degrees), model)
    assert len(messages) == 1 and "times the angle's change: likely the rate in deg/s" \
        in messages[0], messages


def test_still_joint_is_not_compared(tmp_path):
    """A joint that does not move (noise only) gives no flag: its increments are noise."""
    rng = np.random.default_rng(4)
    t = np.linspace(0, 5, 251)
    header = ["t", "base_yaw", "base_wz", "q_left_shoulder", "q_left_elbow", "qd_left_shoulder", "qd_left_elbow"]
    values = np.column_stack([t, 0.3 * np.sin(t), 0.3 * np.cos(t), 1e-4 * rng.standard_normal(251),
                              0.5 * np.sin(2 * t), 1e-4 * rng.standard_normal(251), np.cos(2 * t)])
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        log = read_log(_write(tmp_path / "still.csv", header, values), joints=JOINTS, planar=True)
    assert log.meta["plausibility"] == []


def test_impossible_rates_are_refused(logs, tmp_path, capsys):
    """Rates of 1e200 (a corrupted column) ended in inf noise levels or LinAlgError: one line naming the column."""
    def huge(col, values, header):
        values[:, col["qd_left_elbow"]] *= 1e200

    log = _mutated(logs / "log.csv", tmp_path / "huge.csv", huge)
    code, lines = _identify(log, tmp_path / "r.json", capsys)
    assert code == 2 and not (tmp_path / "r.json").exists()
    assert lines[-1].startswith(f"error: {log}: column 'qd_left_elbow' reaches ") and lines[-1].endswith(
        "beyond the 1e+06 rad/s (or m/s) no robot reaches: check the column's units and values"), lines
