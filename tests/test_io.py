"""Logs, trajectories and JSON on disk: exact round trips, and one clear error per bad input."""

import json
import math
import warnings

import numpy as np
import pytest

from spaceid import SpaceidError
from spaceid.data import _files as sio
from spaceid.data import read_joint_trajectory, read_json, read_log, write_json, write_log
from spaceid.data import Log, yaw_to_quat

JOINTS = ("left_shoulder", "left_elbow")
PLANAR_HEADER = "t,base_yaw,base_wz,q_left_shoulder,q_left_elbow,qd_left_shoulder,qd_left_elbow"
PLANAR_ROWS = [
    "0,0.1,0.01,0.2,-0.3,0.5,-0.5",
    "0.1,0.2,0.02,0.25,-0.35,0.5,-0.5",
    "0.2,0.3,0.03,0.3,-0.4,0.5,-0.5",
]


def _write(path, header, rows):
    path.write_text("\n".join([header, *rows]) + "\n")
    return path


@pytest.fixture
def planar_csv(tmp_path):
    return _write(tmp_path / "run.csv", PLANAR_HEADER, PLANAR_ROWS)


def _random_log(planar, n=50, rng=0):
    rng = np.random.default_rng(rng)
    t = np.cumsum(rng.uniform(0.001, 0.02, n))
    if planar:
        # Over a turn and a half: the yaw written must stay continuous across +-pi.
        yaw = 0.4 + np.linspace(0, 3 * math.pi, n) + rng.normal(0, 0.01, n)
        quat = yaw_to_quat(yaw)
        w = np.zeros((n, 3))
        w[:, 2] = rng.normal(size=n)
    else:
        quat = rng.normal(size=(n, 4))
        quat /= np.linalg.norm(quat, axis=1)[:, None]
        w = rng.normal(size=(n, 3))
    return Log(t=t, joints=JOINTS, q=rng.normal(size=(n, 2)), qd=rng.normal(size=(n, 2)),
               base_quat=quat, base_w=w, planar=planar)


# --- round trips ------------------------------------------------------------------------------


def test_round_trip_spatial_is_bit_exact(tmp_path):
    log = _random_log(planar=False)
    write_log(tmp_path / "s.csv", log)
    back = read_log(tmp_path / "s.csv", joints=JOINTS, planar=False)
    for name in ("t", "q", "qd", "base_quat", "base_w"):
        np.testing.assert_array_equal(getattr(back, name), getattr(log, name), err_msg=name)
    assert back.joints == JOINTS and not back.planar
    assert back.meta["source"] == str(tmp_path / "s.csv")
    assert back.meta["columns"][:8] == SPATIAL_HEADER.split(",")
    assert "rates" not in back.meta


def test_round_trip_planar(tmp_path):
    log = _random_log(planar=True)
    write_log(tmp_path / "p.csv", log)
    back = read_log(tmp_path / "p.csv", joints=JOINTS, planar=True)
    for name in ("t", "q", "qd", "base_w"):
        np.testing.assert_array_equal(getattr(back, name), getattr(log, name), err_msg=name)
    # The yaw goes through a quaternion and back (atan2): equal to rounding, continuous on disk.
    np.testing.assert_allclose(back.base_yaw, log.base_yaw, rtol=0, atol=1e-14)
    np.testing.assert_allclose(back.base_quat, log.base_quat, rtol=0, atol=1e-15)
    on_disk = np.genfromtxt(tmp_path / "p.csv", delimiter=",", names=True)["base_yaw"]
    assert np.abs(np.diff(on_disk)).max() < math.pi
    # A second write of what was read gives the yaw read in, bit for bit.
    write_log(tmp_path / "p2.csv", back)
    again = read_log(tmp_path / "p2.csv", joints=JOINTS, planar=True)
    np.testing.assert_array_equal(again.t, log.t)
    np.testing.assert_allclose(again.base_yaw, log.base_yaw, rtol=0, atol=1e-14)


def test_planar_values_and_layout(planar_csv):
    log = read_log(planar_csv, joints=JOINTS, planar=True)
    np.testing.assert_array_equal(log.t, [0, 0.1, 0.2])
    np.testing.assert_array_equal(log.base_quat, yaw_to_quat([0.1, 0.2, 0.3]))
    np.testing.assert_array_equal(log.base_w, [[0, 0, 0.01], [0, 0, 0.02], [0, 0, 0.03]])
    np.testing.assert_array_equal(log.q, [[0.2, -0.3], [0.25, -0.35], [0.3, -0.4]])
    assert log.q.shape == log.qd.shape == (3, 2) and log.planar


def test_column_order_free_and_extra_columns_ignored(tmp_path, planar_csv):
    ref = read_log(planar_csv, joints=JOINTS, planar=True)
    header = PLANAR_HEADER.split(",")
    order = [6, 0, 4, 2, 5, 1, 3]
    rows = [row.split(",") for row in PLANAR_ROWS]
    shuffled = _write(
        tmp_path / "shuffled.csv",
        ",".join([header[i] for i in order] + ["mode", "base_qw"]),
        [",".join([r[i] for i in order] + ["tracking", "x"]) for r in rows],
    )
    log = read_log(shuffled, joints=JOINTS, planar=True)
    for name in ("t", "q", "qd", "base_quat", "base_w"):
        np.testing.assert_array_equal(getattr(log, name), getattr(ref, name))
    assert log.meta["columns"][-2:] == ["mode", "base_qw"]


def test_joint_order_follows_the_model_not_the_file(planar_csv):
    log = read_log(planar_csv, joints=JOINTS[::-1], planar=True)
    np.testing.assert_array_equal(log.q[:, 0], [-0.3, -0.35, -0.4])


def test_missing_rates_allowed_on_request(tmp_path):
    path = _write(tmp_path / "angles.csv", "t,base_yaw,q_left_shoulder,q_left_elbow", ["0,0,0,0", "1,0.1,0.2,0.3"])
    with pytest.raises(SpaceidError, match=r"angles\.csv.*missing column.*base_wz.*require_rates=False"):
        read_log(path, joints=JOINTS, planar=True)
    log = read_log(path, joints=JOINTS, planar=True, require_rates=False)
    assert np.isnan(log.qd).all() and np.isnan(log.base_w).all() and log.qd.shape == (2, 2)
    assert log.meta["rates"] == "missing"
    assert log.meta["missing_rates"] == ["base_wz", "qd_left_shoulder", "qd_left_elbow"]
    # Written back without the unknown rates, it reads the same way.
    write_log(tmp_path / "again.csv", log)
    assert (tmp_path / "again.csv").read_text().splitlines()[0] == "t,base_yaw,q_left_shoulder,q_left_elbow"
    again = read_log(tmp_path / "again.csv", joints=JOINTS, planar=True, require_rates=False)
    np.testing.assert_array_equal(again.q, log.q)


def test_spatial_missing_rates_filled_with_nan(tmp_path):
    path = _write(tmp_path / "s.csv", "t,base_qw,base_qx,base_qy,base_qz", ["0,1,0,0,0", "1,1,0,0,0"])
    log = read_log(path, joints=(), planar=False, require_rates=False)
    assert log.q.shape == (2, 0) and np.isnan(log.base_w).all() and log.meta["rates"] == "missing"


def test_input_file_never_modified(tmp_path):
    path = _write(tmp_path / "q.csv", "t,base_qw,base_qx,base_qy,base_qz,base_wx,base_wy,base_wz",
                  ["0,1.000002,0,0,0,0,0,0", "1,1,0,0,0,0,0,0"])
    before = path.read_bytes()
    with pytest.warns(UserWarning):
        read_log(path, joints=(), planar=False)
    assert path.read_bytes() == before
    bad = _write(tmp_path / "bad.csv", "t,base_yaw", ["1,0", "0,0"])
    before = bad.read_bytes()
    with pytest.raises(SpaceidError):
        read_log(bad, joints=(), planar=True, require_rates=False)
    assert bad.read_bytes() == before


# --- quaternions --------------------------------------------------------------------------------


SPATIAL_HEADER = "t,base_qw,base_qx,base_qy,base_qz,base_wx,base_wy,base_wz"


def test_slightly_off_quaternion_normalised_with_warning(tmp_path):
    path = _write(tmp_path / "drift.csv", SPATIAL_HEADER, ["0,1.001,0,0,0,0,0,0", "1,0,0.6,0.8,0,0,0,0"])
    with pytest.warns(UserWarning, match=r"drift\.csv.*normalised"):
        log = read_log(path, joints=(), planar=False)
    np.testing.assert_allclose(np.linalg.norm(log.base_quat, axis=1), 1, rtol=0, atol=1e-15)
    np.testing.assert_array_equal(log.base_quat[0], [1, 0, 0, 0])


def test_unit_quaternion_read_unchanged_without_warning(tmp_path):
    path = _write(tmp_path / "ok.csv", SPATIAL_HEADER, ["0,1,0,0,0,0,0,0", "1,0,0.6,0.8,0,0,0,0"])
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        log = read_log(path, joints=(), planar=False)
    np.testing.assert_array_equal(log.base_quat[1], [0, 0.6, 0.8, 0])


def test_non_unit_quaternion_is_an_error(tmp_path):
    path = _write(tmp_path / "bad_q.csv", SPATIAL_HEADER, ["0,1,0,0,0,0,0,0", "1,1,0.5,0,0,0,0,0"])
    with pytest.raises(SpaceidError, match=r"bad_q\.csv: line 3: base quaternion.*norm 1\.11803.*expected 1"):
        read_log(path, joints=(), planar=False)


# --- bad input: one clear error each ------------------------------------------------------------


def _bad(tmp_path, text, name="bad.csv"):
    path = tmp_path / name
    path.write_text(text)
    return path


@pytest.mark.parametrize(
    "text, match",
    [
        ("", r"empty"),
        ("\n\n", r"empty"),
        (PLANAR_HEADER + "\n", r"header but no data rows"),
        ("t,base_yaw,base_wz,q_left_shoulder\n0,0,0,0\n",
         r"missing column\(s\) q_left_elbow, qd_left_shoulder, qd_left_elbow"),
        ("0,0.1,0.01,0.2,-0.3,0.5,-0.5\n0.1,0.2,0.02,0.25,-0.35,0.5,-0.5\n", r"first line must be a header"),
        (SPATIAL_HEADER + ",q_left_shoulder,q_left_elbow,qd_left_shoulder,qd_left_elbow\n0,1,0,0,0,0,0,0,0,0,0,0\n",
         r"looks spatial"),
        (PLANAR_HEADER + ",q_wrist\n0,0,0,0,0,0,0,0\n",
         r"joint 'wrist' in the log is not in the model \(joints: left_shoulder, left_elbow\)"),
        (PLANAR_HEADER + ",qd_wrist\n0,0,0,0,0,0,0,0\n", r"joint 'wrist' in the log is not in the model"),
        (PLANAR_HEADER + "\n0,0,0,0,0,0,0\n0.1,0,0,abc,0,0,0\n", r"line 3, column 'q_left_shoulder': 'abc' is not a number"),
        (PLANAR_HEADER + "\n0,0,0,0,0,0,0\n0.1,0,0,,0,0,0\n", r"line 3, column 'q_left_shoulder': '' is not a number"),
        (PLANAR_HEADER + "\n0,0,0,0,0,0,0\n0.1,0,0,0,0,0\n", r"line 3 has 6 fields but the header has 7"),
        (PLANAR_HEADER + "\n0,0,0,0,0,0,0\n0.1,0,0,0,nan,0,0\n", r"column 'q_left_elbow' holds nan \(first at line 3\)"),
        (PLANAR_HEADER + "\n0,0,0,0,0,0,0\n0.1,0,inf,0,0,0,0\n", r"column 'base_wz' holds inf \(first at line 3\)"),
        (PLANAR_HEADER + "\n0,0,0,0,0,0,0\n0.1,0,0,0,0,0,0\n0.1,0,0,0,0,0,0\n",
         r"time stamps must increase strictly.*line 4.*sort the log or remove duplicate rows"),
        (PLANAR_HEADER + "\n0,0,0,0,0,0,0\n0.2,0,0,0,0,0,0\n0.1,0,0,0,0,0,0\n", r"t = 0\.1 at line 4 follows t = 0\.2"),
        (PLANAR_HEADER + "\n0,0,0,10,0,0,0\n0.1,0,0,90,0,0,0\n",
         r"column 'q_left_shoulder' reaches 90.*degrees.*convert it to radians"),
        (PLANAR_HEADER + "\n0,0,0,0,0,0,0\n0.1,-180,0,0,0,0,0\n", r"column 'base_yaw' reaches 180.*degrees"),
        (PLANAR_HEADER + ",t\n0,0,0,0,0,0,0,0\n", r"column 't' appears twice"),
    ],
)
def test_bad_log_gives_one_clear_error(tmp_path, text, match):
    path = _bad(tmp_path, text)
    with pytest.raises(SpaceidError, match=match) as info:
        read_log(path, joints=JOINTS, planar=True)
    message = str(info.value)
    assert str(path) in message and "\n" not in message


def test_missing_file_and_unreadable_file(tmp_path):
    with pytest.raises(SpaceidError, match=r"nope\.csv: no such file"):
        read_log(tmp_path / "nope.csv", joints=JOINTS, planar=True)
    with pytest.raises(SpaceidError, match=r"is a folder, not a log file: give the file itself"):
        read_log(tmp_path, joints=JOINTS, planar=True)  # a directory
    binary = tmp_path / "bin.csv"
    binary.write_bytes(b"t,base_yaw\n\xff\xfe\x00\x01\n")
    with pytest.raises(SpaceidError, match=r"bin\.csv: not a UTF-8 text file"):
        read_log(binary, joints=(), planar=True, require_rates=False)


def test_spatial_log_with_planar_columns_hint(tmp_path):
    path = _bad(tmp_path, "t,base_yaw,base_wz\n0,0,0\n")
    with pytest.raises(SpaceidError, match=r"looks planar"):
        read_log(path, joints=(), planar=False)


def test_wheel_angle_may_exceed_ten_turns_and_fast_rates_warn(tmp_path):
    header = "t,base_yaw,base_wz,q_rw,qd_rw,q_arm,qd_arm"
    path = _bad(tmp_path, header + "\n0,0,0,0,300,0,0\n10,0,0,3000,300,0,0\n", "rw.csv")
    with pytest.raises(SpaceidError, match=r"q_rw.*degrees"):
        read_log(path, joints=("rw", "arm"), planar=True)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        log = read_log(path, joints=("rw", "arm"), planar=True, wheels=("rw",))
    assert log.q[1, 0] == 3000
    fast = _bad(tmp_path, header + "\n0,0,0,0,0,0,0\n1,0,0,0,0,0,150\n", "fast.csv")
    with pytest.warns(UserWarning, match=r"fast\.csv: column 'qd_arm' reaches 150 rad/s.*deg/s"):
        log = read_log(fast, joints=("rw", "arm"), planar=True, wheels=("rw",))
    assert log.qd[1, 1] == 150


def test_header_whitespace_and_bom_tolerated(tmp_path):
    path = tmp_path / "excel.csv"
    lines = [PLANAR_HEADER, *PLANAR_ROWS]
    path.write_bytes(("\ufeff" + "".join(line.replace(",", ", ") + "\r\n" for line in lines)).encode())
    log = read_log(path, joints=JOINTS, planar=True)
    np.testing.assert_array_equal(log.t, [0, 0.1, 0.2])


# --- writing ------------------------------------------------------------------------------------


def test_failed_write_leaves_no_partial_file(tmp_path, monkeypatch):
    log = _random_log(planar=True)
    target = tmp_path / "out.csv"

    def half_write(fname, *args, **kwargs):
        with open(fname, "w") as f:
            f.write("t,base_yaw\n0.1,")
        raise OSError(28, "No space left on device")

    monkeypatch.setattr(sio.np, "savetxt", half_write)
    with pytest.raises(SpaceidError, match=r"out\.csv: cannot write the log \(No space left on device\)"):
        write_log(target, log)
    assert list(tmp_path.iterdir()) == []
    # An existing file survives a failed overwrite untouched.
    target.write_text("old")
    with pytest.raises(SpaceidError):
        write_log(target, log)
    assert target.read_text() == "old" and list(tmp_path.iterdir()) == [target]


def test_write_refuses_non_finite_values(tmp_path):
    log = _random_log(planar=False)
    log.q[3, 1] = np.nan
    with pytest.raises(SpaceidError, match=r"bad\.csv: the log holds NaN or infinite values in q_left_elbow"):
        write_log(tmp_path / "bad.csv", log)
    assert not (tmp_path / "bad.csv").exists()


def test_planar_write_column_order(tmp_path):
    write_log(tmp_path / "p.csv", _random_log(planar=True, n=3))
    assert (tmp_path / "p.csv").read_text().splitlines()[0] == PLANAR_HEADER


# --- joint trajectories -------------------------------------------------------------------------


def test_read_joint_trajectory(tmp_path):
    path = _bad(tmp_path, "qd_left_elbow,t,q_left_shoulder,q_left_elbow,qd_left_shoulder,note\n"
                          "0.5,0,0.1,0.2,0.3,a\n0.6,0.5,0.15,0.25,0.3,b\n", "traj.csv")
    t, q, qd = read_joint_trajectory(path, joints=JOINTS)
    np.testing.assert_array_equal(t, [0, 0.5])
    np.testing.assert_array_equal(q, [[0.1, 0.2], [0.15, 0.25]])
    np.testing.assert_array_equal(qd, [[0.3, 0.5], [0.3, 0.6]])


@pytest.mark.parametrize(
    "text, match",
    [
        ("t,q_left_shoulder,q_left_elbow,qd_left_shoulder\n0,0,0,0\n", r"missing column\(s\) qd_left_elbow"),
        ("t,q_left_shoulder,q_left_elbow,qd_left_shoulder,qd_left_elbow\n1,0,0,0,0\n0,0,0,0,0\n", r"sort the log"),
        ("t,q_left_shoulder,q_left_elbow,qd_left_shoulder,qd_left_elbow\n0,0,x,0,0\n", r"line 2, column 'q_left_elbow'"),
        ("t,q_left_shoulder,q_left_elbow,qd_left_shoulder,qd_left_elbow\n0,0,0,0,nan\n", r"'qd_left_elbow' holds nan"),
        ("t,q_left_shoulder,q_left_elbow,qd_left_shoulder,qd_left_elbow\n0,120,0,0,0\n", r"degrees"),
        ("t,q_x,q_left_shoulder,q_left_elbow,qd_left_shoulder,qd_left_elbow\n0,0,0,0,0,0\n", r"joint 'x' in the log"),
    ],
)
def test_bad_joint_trajectory(tmp_path, text, match):
    path = _bad(tmp_path, text, "traj.csv")
    with pytest.raises(SpaceidError, match=match) as info:
        read_joint_trajectory(path, joints=JOINTS)
    assert str(path) in str(info.value)


# --- JSON ---------------------------------------------------------------------------------------


def test_json_round_trip_with_numpy_and_nan(tmp_path):
    obj = {
        "params": np.array([[1.5, np.nan], [0.1, 2.0 / 3.0]]),
        "n": np.int64(7),
        "rms": np.float64(0.1 + 0.2),
        "ok": np.bool_(True),
        "names": ("m", "mcx"),
        "inf": math.inf,
        "source": tmp_path / "x.csv",
        "nested": [{"a": [], "b": {}}, [1, [2]]],
        # taken whole when finite (arrays of numbers, lists of floats), value by value otherwise
        "finite": np.array([[0.25, -3.0]]), "ints": np.arange(2), "flags": np.array([True, False]),
        "float32": np.array([1.5], np.float32), "floats": [0.5, 1e300], "floats_nan": [0.5, -math.inf],
        "entropy": 2**100, "entropies": [2**100, 1],  # beyond 64 bits: a seed sequence's entropy
    }
    write_json(tmp_path / "r.json", obj)
    back = read_json(tmp_path / "r.json", what="result")
    assert back == {
        "params": [[1.5, None], [0.1, 2.0 / 3.0]],
        "n": 7,
        "rms": 0.1 + 0.2,
        "ok": True,
        "names": ["m", "mcx"],
        "inf": None,
        "source": str(tmp_path / "x.csv"),
        "nested": [{"a": [], "b": {}}, [1, [2]]],
        "finite": [[0.25, -3.0]], "ints": [0, 1], "flags": [True, False], "float32": [1.5], "floats": [0.5, 1e300],
        "floats_nan": [0.5, None], "entropy": 2**100, "entropies": [2**100, 1],
    }
    text = (tmp_path / "r.json").read_text()
    assert "NaN" not in text
    assert '    [1.5,null],\n    [0.1,0.6666666666666666]\n' in text  # a matrix one row a line
    json.loads((tmp_path / "r.json").read_text())  # strict JSON


def test_json_errors_name_the_file(tmp_path):
    with pytest.raises(SpaceidError, match=r"none\.json: no such file \(expected a result\)"):
        read_json(tmp_path / "none.json", what="result")
    broken = tmp_path / "broken.json"
    broken.write_text('{"a": 1,,}')
    with pytest.raises(SpaceidError, match=r"broken\.json: not a valid result \(line 1, column 9"):
        read_json(broken, what="result")


def test_gap_in_a_log_warns(tmp_path):
    rows = [f"{0.01 * i:.2f},0,0,0.1,0.2,0,0" for i in range(20)] + [f"{1.0 + 0.01 * i:.2f},0,0,0.1,0.2,0,0" for i in range(5)]
    path = _write(tmp_path / "gap.csv", PLANAR_HEADER, rows)
    with pytest.warns(UserWarning, match=r"gap.csv: a gap of 0.81 s before line 22 \(81 median steps\)"):
        read_log(path, joints=JOINTS, planar=True)
