"""ROS bags: writing and reading in three formats, alignment to a Log, bad bags, the CLI.

The reference motion is a noise-free simulation of ``cepheus-rw`` (base, wheel, 2-link arm),
so base and joint rates are known exactly at any instant and identification from a bag can be
checked against the true parameters.
"""

import json

import numpy as np
import pytest

from spaceid.data import _bag_format as bags
from spaceid._errors import SpaceidError
from spaceid.data import JOINT_RATE_POLICY, read_mapping, read_recording, to_log, write_bag
from spaceid.cli import main
from spaceid.models import load_model
from spaceid.data import JointStates, Poses, Recording
from spaceid.dynamics import minimal_parameters
from spaceid.motion import simulate
from spaceid.data import yaw_to_quat

H = np.array([0.0, 0.0, 0.05])  # [N m s], total momentum of the simulated run
LATENCY = 0.008  # [s], motion capture stamped on arrival
NS = 1_000_000_000


def _motion(joints):
    """Smooth exciting arm motion and a wheel at ~20 rad/s: (q, qd) (n, 3) in model order."""

    def motion(t):
        t = np.asarray(t, dtype=float)
        cols = {
            "left_shoulder": (0.6 * np.sin(1.3 * t) + 0.3 * np.sin(2.9 * t + 0.5),
                              0.78 * np.cos(1.3 * t) + 0.87 * np.cos(2.9 * t + 0.5)),
            "left_elbow": (0.7 * np.sin(1.7 * t + 1) - 0.2 * np.sin(3.1 * t),
                           1.19 * np.cos(1.7 * t + 1) - 0.62 * np.cos(3.1 * t)),
            "reaction_wheel_joint": (20 * t + 0.5 * np.sin(t), 20 + 0.5 * np.cos(t)),
        }
        return np.stack([cols[j][0] for j in joints], -1), np.stack([cols[j][1] for j in joints], -1)

    return motion


@pytest.fixture(scope="module")
def rw():
    model = load_model("cepheus-rw")
    return model, minimal_parameters(model)


@pytest.fixture(scope="module")
def truth(rw):
    """Noise-free simulation on a fine grid holding every stamp used below (1 ms steps)."""
    model, param = rw
    times = np.arange(0, 6001) * 1_000_000 / 1e9  # 0 .. 6 s, whole nanoseconds
    return simulate(param, param.true_values, _motion(model.joints), times, H, model=model)


def _at(log, t):
    """Rows of ``log`` at stamps ``t`` (which lie on its 1 ms grid)."""
    idx = np.rint(np.asarray(t) * 1000).astype(int)
    assert np.allclose(log.t[idx], t, atol=1e-12)
    return idx


def _recording(log, joint_t, capture_t, *, stamp_offset=0.0, effort=True):
    """A recording: joint states at ``joint_t`` (positions, velocities, efforts) and the base
    pose captured at ``capture_t`` but stamped ``stamp_offset`` later."""
    j, m = _at(log, joint_t), _at(log, capture_t)
    rng = np.random.default_rng(0)
    position = np.column_stack([np.linspace(0, 1, m.size), np.zeros(m.size), np.full(m.size, 0.2)])
    return Recording(
        JointStates(log.t[j], log.joints, log.q[j], log.qd[j], rng.normal(size=log.q[j].shape) if effort else None),
        Poses(log.t[m] + stamp_offset, position, log.base_quat[m], "mocap"),
        meta={"seed": 0},
    )


@pytest.fixture(scope="module")
def recording(truth):
    joint_t = np.arange(0, 251) * 20_000_000 / 1e9  # 50 Hz, 0 .. 5 s
    capture_t = np.arange(0, 500) * 10_000_000 / 1e9 + 0.003  # 100 Hz, 3 ms later
    return _recording(truth, joint_t, capture_t)


def _assert_same(a, b):
    assert a.joints.names == b.joints.names and a.base.frame == b.base.frame
    for x, y in [(a.joints.t, b.joints.t), (a.joints.position, b.joints.position), (a.joints.velocity, b.joints.velocity),
                 (a.joints.effort, b.joints.effort), (a.base.t, b.base.t), (a.base.position, b.base.position),
                 (a.base.quat, b.base.quat)]:
        np.testing.assert_array_equal(x, y)  # bit for bit (NaN where NaN)


# --- round trips ---------------------------------------------------------------------------------


@pytest.mark.parametrize("name, format, kind", [("run.bag", None, "ros1"), ("run", "ros2", "ros2-sqlite3"),
                                                ("run", "mcap", "ros2-mcap"), ("run.mcap", None, "mcap")])
@pytest.mark.slow
def test_round_trip_is_exact(tmp_path, recording, name, format, kind):
    path = tmp_path / name
    write_bag(path, recording, format=format)
    back = read_recording(path)
    _assert_same(back, recording)
    assert back.meta["format"] == kind and back.meta["time_origin_ns"] == 0
    assert back.meta["joint_messages"] == 251 and back.meta["pose_messages"] == 500
    assert sorted(p.name for p in tmp_path.iterdir()) == [name]  # no staging leftovers
    if path.is_dir():
        assert (path / "metadata.yaml").is_file()


def test_messages_are_standard_and_ros_ordered(tmp_path, recording):
    """Decoded without spaceid: ROS quaternion order (x, y, z, w), stamps, names, delays."""
    from rosbags.highlevel import AnyReader

    write_bag(tmp_path / "r.bag", recording, joint_delay=0.002, pose_delay=np.full(500, 0.004))
    with AnyReader([tmp_path / "r.bag"]) as reader:
        assert {k: v.msgtype for k, v in reader.topics.items()} == {
            "/joint_states": "sensor_msgs/msg/JointState", bags.DEFAULT_POSE_TOPIC: "geometry_msgs/msg/PoseStamped"}
        seen = {}
        for connection, log_ns, raw in reader.messages():
            msg = reader.deserialize(raw, connection.msgtype)
            seen.setdefault(connection.topic, []).append((log_ns, msg))
    log_ns, pose = seen[bags.DEFAULT_POSE_TOPIC][7]
    o = pose.pose.orientation
    np.testing.assert_array_equal([o.w, o.x, o.y, o.z], recording.base.quat[7])
    stamp = pose.header.stamp.sec * NS + pose.header.stamp.nanosec
    assert stamp == 70_000_000 + 3_000_000 and log_ns == stamp + 4_000_000 and pose.header.frame_id == "mocap"
    log_ns, js = seen["/joint_states"][3]
    assert js.name == list(recording.joints.names) and log_ns == 60_000_000 + 2_000_000


def test_wall_clock_stamps_keep_nanoseconds(tmp_path, recording):
    epoch = 1_700_000_123 * NS
    write_bag(tmp_path / "r", recording, format="ros2", time_origin_ns=epoch)
    back = read_recording(tmp_path / "r")
    assert back.meta["time_origin_ns"] == epoch
    np.testing.assert_array_equal(back.joints.t, recording.joints.t)
    np.testing.assert_array_equal(back.base.t, recording.base.t)


def test_split_publishers_merge_by_name(tmp_path, truth):
    """Arm and wheel published separately, the wheel 1 ms after the arm: rows are the union of
    the stamps with NaN where a joint is absent; they round-trip and align with a rate."""
    arm_t = np.arange(0, 251) * 20_000_000 / 1e9
    wheel_t = (np.arange(0, 251) * 20_000_000 + 1_000_000) / 1e9
    rec = _recording(truth, np.union1d(arm_t, wheel_t), np.arange(0, 500) * 10_000_000 / 1e9 + 0.003, effort=False)
    names = rec.joints.names
    wheel = names.index("reaction_wheel_joint")
    position, velocity = rec.joints.position.copy(), rec.joints.velocity.copy()
    is_wheel_row = np.isin(rec.joints.t, wheel_t)
    for x in (position, velocity):
        x[is_wheel_row, :] = np.where(np.arange(3) == wheel, x[is_wheel_row], np.nan)
        x[~is_wheel_row, wheel] = np.nan
    rec = Recording(JointStates(rec.joints.t, names, position, velocity), rec.base)
    groups = [["left_elbow", "left_shoulder"], ["reaction_wheel_joint"]]
    for path, format in [(tmp_path / "s.bag", None), (tmp_path / "s", "ros2")]:
        write_bag(path, rec, format=format, joint_groups=groups)
        back = read_recording(path)
        assert set(back.joints.names) == set(names)
        order = [back.joints.names.index(n) for n in names]
        np.testing.assert_array_equal(back.joints.position[:, order], position)
        np.testing.assert_array_equal(back.joints.velocity[:, order], velocity)
    assert back.meta["joint_publishers"] == 1 and read_recording(tmp_path / "s.bag").meta["joint_publishers"] == 2

    with pytest.raises(SpaceidError, match=r"fewer than 2 stamps carry all of .*give a rate"):
        to_log(back, joints=names, planar=True, wheels=("reaction_wheel_joint",))
    log = to_log(back, joints=names, planar=True, wheels=("reaction_wheel_joint",), rate=40.0)
    assert log.meta["time_base"]["kind"] == "uniform" and np.allclose(np.diff(log.t), 0.025)
    i = _at(truth, log.t)
    # exact samples every h = 20 ms, interpolated: cubic Hermite positions err by at most
    # h^4/384 max|q''''| ~ 9e-9 (|q''''| ~ 21 rad/s^4 here), the cubic spline of the rates by
    # ~5 h^4/384 max|q'''''| ~ 1.3e-7; measured 9e-9 and 1.7e-7
    np.testing.assert_allclose(log.q, truth.q[i], rtol=0, atol=1e-7)
    np.testing.assert_allclose(log.qd, truth.qd[i], rtol=0, atol=1e-6)


def test_varying_joint_order_and_reading_ros_quaternions(tmp_path):
    """A hand-written bag (rosbags directly): joints in a different order in every message,
    and a pose whose ROS orientation (x, y, z, w) is a 0.3 rad turn about z."""
    names = ["a", "b", "c"]
    joint_msgs = []
    for k in range(20):
        order = np.roll(names, k)
        joint_msgs.append((k * 20_000_000, list(order), [10 * "abc".index(n) + k for n in order]))
    poses = [(k * 10_000_000, (0.0, 0.0, np.sin(0.15), np.cos(0.15))) for k in range(40)]
    path = _raw_bag(tmp_path / "raw.bag", joint_msgs, poses)
    rec = read_recording(path, rename={"c": "wheel"})
    assert rec.joints.names == ("a", "b", "wheel") and rec.joints.velocity is None and rec.joints.effort is None
    np.testing.assert_array_equal(rec.joints.position, np.arange(20)[:, None] + [0, 10, 20])
    np.testing.assert_allclose(rec.base.quat[5], yaw_to_quat(0.3), rtol=0, atol=1e-16)
    assert rec.base.frame == "world"


# --- alignment -----------------------------------------------------------------------------------


@pytest.fixture(scope="module")
def lab_recording(truth):
    """Joints at 50 Hz; motion capture at 100 Hz with a 3 ms phase, stamped on arrival
    LATENCY later, 5 % of the frames dropped at random and a run of 6 (70 ms without a frame)."""
    rng = np.random.default_rng(7)
    capture_t = np.arange(0, 500) * 10_000_000 / 1e9 + 0.003
    keep = rng.random(500) > 0.05
    keep[200:206] = False
    keep[[0, -1]] = True
    joint_t = np.arange(0, 251) * 20_000_000 / 1e9
    return _recording(truth, joint_t, capture_t[keep], stamp_offset=LATENCY), int((~keep).sum())


@pytest.mark.slow
def test_to_log_recovers_rates_from_uneven_streams(lab_recording, truth):
    rec, n_dropped = lab_recording
    log = to_log(rec, joints=truth.joints, planar=True, wheels=("reaction_wheel_joint",), pose_latency=LATENCY,
                 joint_rates="auto")
    i = _at(truth, log.t)
    # time base: the joint stamps inside the overlap with the (latency-corrected) pose stream
    assert log.t[0] == 0.02 and log.t[-1] == 4.98 and log.n_samples == 249
    assert log.meta["time_base"]["kind"] == "joint stamps" and log.meta["streams"]["pose"]["dropped"] == n_dropped
    assert log.meta["joint_rates"] == dict.fromkeys(truth.joints, "velocity")
    # joints: the measured values, untouched
    np.testing.assert_array_equal(log.q, truth.q[i])
    np.testing.assert_array_equal(log.qd, truth.qd[i])
    # base: noise-free data, so only the differentiator's bias (local polynomials of degree
    # 5-7, exact for polynomials of that degree) and the O(h^4) interpolation remain. Where
    # frames are evenly spaced that is ~1e-10 rad/s (median); next to the 70 ms gap the local
    # fit must bridge 7 missing frames and errs by up to 6e-7 rad/s (2.5e-6 of the peak rate
    # 0.23 rad/s). Bounds: 1e-8 for the median, 2e-6 overall, 3e-8 rad on the yaw (8e-9 seen).
    assert np.abs(log.base_w[:, :2]).max() == 0 and not log.base_quat[:, 1:3].any()
    error = np.abs(log.base_w[:, 2] - truth.base_w[i, 2])
    assert np.median(error) < 1e-8 and error.max() < 2e-6
    assert 1.95 < log.t[np.argmax(error)] < 2.1  # the worst is at the long gap
    np.testing.assert_allclose(log.base_yaw, truth.base_yaw[i], rtol=0, atol=3e-8)

    # joint rates from the positions instead of the velocities (the default): noise-free evenly
    # sampled positions, so only the smoothing bias remains (1.1e-8 rad/s measured)
    diff = to_log(rec, joints=truth.joints, planar=True, wheels=("reaction_wheel_joint",), pose_latency=LATENCY)
    assert diff.meta["joint_rate_policy"] == JOINT_RATE_POLICY == "differentiate"
    assert log.meta["joint_rate_policy"] == "auto"
    assert diff.meta["joint_rates"] == dict.fromkeys(truth.joints, "differentiated")
    assert set(diff.meta["differentiation"]["joints"]) == set(truth.joints)
    np.testing.assert_allclose(diff.qd, truth.qd[i], rtol=0, atol=1e-7)


def test_ignoring_the_latency_is_visible(lab_recording, truth):
    """Without the latency correction the base rate lags by 8 ms: errors of ~|dw/dt| * 8 ms."""
    rec, _ = lab_recording
    log = to_log(rec, joints=truth.joints, planar=True, wheels=("reaction_wheel_joint",))
    i = _at(truth, log.t)
    assert np.abs(log.base_w[:, 2] - truth.base_w[i, 2]).max() > 1e-3


def test_wrapped_wheel_at_170_rad_s_is_unwrapped_with_its_rate(truth):
    """A driver that wraps the wheel angle to (-pi, pi]: at 170 rad/s and 50 Hz the wheel turns
    3.4 rad per sample, beyond what plain unwrapping resolves; the measured rate does."""
    t = np.arange(0, 251) * 20_000_000 / 1e9
    angle = 170 * t + 0.3 * np.sin(2 * t)
    rate = 170 + 0.6 * np.cos(2 * t)
    wrapped = np.angle(np.exp(1j * angle))
    js = JointStates(t, ("reaction_wheel_joint",), wrapped[:, None], rate[:, None])
    base = Poses(t, np.zeros((t.size, 3)), yaw_to_quat(0.1 * np.sin(t)), "world")
    log = to_log(Recording(js, base), joints=("reaction_wheel_joint",), planar=True, wheels=("reaction_wheel_joint",),
                 joint_rates="auto")  # the measured angles, unwrapped, not smoothed by a differentiator
    np.testing.assert_allclose(log.q[:, 0], angle, rtol=0, atol=1e-9)


@pytest.mark.slow
def test_spatial_attitude_and_body_rate(tmp_path):
    """Base attitude Rz(a) Rx(b), published with random quaternion signs (q and -q), sampled at
    100 Hz and aligned to 50 Hz joints: body rate [b', a' sin b, a' cos b]."""
    tm = np.arange(0, 400) * 10_000_000 / 1e9 + 0.004
    tj = np.arange(0, 200) * 20_000_000 / 1e9

    def attitude(t):
        a, b = 0.8 * np.sin(0.9 * t), 0.4 * np.sin(1.3 * t + 0.2)
        da, db = 0.72 * np.cos(0.9 * t), 0.52 * np.cos(1.3 * t + 0.2)
        ca, sa, cb, sb = np.cos(a / 2), np.sin(a / 2), np.cos(b / 2), np.sin(b / 2)
        quat = np.column_stack([ca * cb, ca * sb, sa * sb, sa * cb])
        return quat, np.column_stack([db, da * np.sin(b), da * np.cos(b)])

    quat, _ = attitude(tm)
    quat *= np.where(np.random.default_rng(1).random(tm.size) < 0.3, -1.0, 1.0)[:, None]
    js = JointStates(tj, ("j1",), np.sin(tj)[:, None], np.cos(tj)[:, None])
    rec = Recording(js, Poses(tm, np.zeros((tm.size, 3)), quat, "world"))
    write_bag(tmp_path / "s.mcap", rec)
    log = to_log(read_recording(tmp_path / "s.mcap"), joints=("j1",), planar=False)
    true_quat, true_w = attitude(log.t)
    np.testing.assert_allclose(log.base_w, true_w, rtol=0, atol=1e-8)  # 6.5e-10 measured
    np.testing.assert_allclose(np.abs(np.einsum("ij,ij->i", log.base_quat, true_quat)), 1, rtol=0, atol=1e-12)
    with pytest.raises(SpaceidError, match=r"tilts 0.4.* rad .* beyond max_tilt = 0.1 rad for a planar model"):
        to_log(rec, joints=("j1",), planar=True)


def _tumbling(t):
    """Attitude Rz(a) Rx(b) (n, 4) and body rate (n, 3) [rad/s] of a tumbling base at ``t`` (n,)."""
    a, b = 0.8 * np.sin(0.9 * t), 0.4 * np.sin(1.3 * t + 0.2)
    da, db = 0.72 * np.cos(0.9 * t), 0.52 * np.cos(1.3 * t + 0.2)
    ca, sa, cb, sb = np.cos(a / 2), np.sin(a / 2), np.cos(b / 2), np.sin(b / 2)
    return np.column_stack([ca * cb, ca * sb, sa * sb, sa * cb]), np.column_stack([db, da * np.sin(b), da * np.cos(b)])


def test_a_gyro_on_the_pose_topic_is_the_base_rate(tmp_path):
    """Odometry on the pose topic (a star tracker's attitude and a gyro's rate, 1e-4 rad/s of noise, at 100 Hz):
    with ``base_rate`` gyro the base rate is the twist's, linearly interpolated onto the 50 Hz joint stamps (exact at
    the poses' own stamps), the attitude the published one (the rate its slope), and no record of the base's
    differentiation (the estimators model the rate as measured; with the joint rates measured too, nothing is
    correlated: :func:`~spaceid.estimation._uncertainty.correlation_length` 0). Without it, the attitude is
    differentiated as for a PoseStamped, the twist unused."""
    from spaceid.estimation._uncertainty import correlation_length

    tm = np.arange(0, 400) * 10_000_000 / 1e9
    tj = np.arange(0, 200) * 20_000_000 / 1e9
    quat, w = _tumbling(tm)
    gyro = w + 1e-4 * np.random.default_rng(2).standard_normal(w.shape)
    js = JointStates(tj, ("j1",), np.sin(tj)[:, None], np.cos(tj)[:, None])
    write_bag(tmp_path / "g.mcap", Recording(js, Poses(tm, np.zeros((tm.size, 3)), quat, "world", rate=gyro)))
    rec = read_recording(tmp_path / "g.mcap")
    np.testing.assert_array_equal(rec.base.rate, gyro)
    log = to_log(rec, joints=("j1",), planar=False, base_rate="gyro", joint_rates="velocity")
    np.testing.assert_array_equal(log.base_w, gyro[::2])  # the joint stamps are every other pose's
    true_quat, true_w = _tumbling(log.t)
    np.testing.assert_allclose(np.abs(np.einsum("ij,ij->i", log.base_quat, true_quat)), 1, rtol=0, atol=1e-12)
    assert log.meta["base_rate"] == "gyro" and "base" not in log.meta["differentiation"]
    assert correlation_length(log) == 0
    between = to_log(rec, joints=("j1",), planar=False, base_rate="gyro", rate=73.0)  # off the pose stamps
    assert np.abs(between.base_w - _tumbling(between.t)[1]).max() < 5e-4  # the gyro's noise and the chords'
    attitude = to_log(rec, joints=("j1",), planar=False)
    assert attitude.meta["base_rate"] == "attitude" and "base" in attitude.meta["differentiation"]
    assert np.abs(attitude.base_w - true_w).max() < 1e-6  # the noise-free attitude differentiated, twist unused


def test_an_imus_orientation_and_angular_velocity_are_read_by_their_fields():
    """A ``sensor_msgs/Imu`` on the pose topic (as rosbags or rclpy gives it): its orientation at the origin and its
    angular velocity (base axes), as an Odometry's pose and twist."""
    from rosbags.typesys import Stores, get_typestore

    from spaceid.data._bag_read import _pose_entry

    T = get_typestore(Stores.ROS2_HUMBLE).types
    vector = T["geometry_msgs/msg/Vector3"]
    header = T["std_msgs/msg/Header"](stamp=T["builtin_interfaces/msg/Time"](sec=3, nanosec=5), frame_id="imu")
    imu = T["sensor_msgs/msg/Imu"](header=header, orientation=T["geometry_msgs/msg/Quaternion"](0.0, 0.6, 0.0, 0.8),
                                   orientation_covariance=np.zeros(9), angular_velocity=vector(0.1, -0.2, 0.3),
                                   angular_velocity_covariance=np.zeros(9), linear_acceleration=vector(0.0, 0.0, 9.8),
                                   linear_acceleration_covariance=np.zeros(9))  # fmt: skip
    entry = _pose_entry(imu)
    assert entry == (3 * NS + 5, (0.0, 0.0, 0.0), (0.8, 0.0, 0.6, 0.0), "imu", (0.1, -0.2, 0.3))


def test_a_gyro_asked_of_poses_without_one_is_named(tmp_path, recording, capsys):
    """``base_rate`` gyro where the pose messages are PoseStamped, a base rate that is not one of the two, a mapping's
    and a CSV's: one line naming the option and the fix (exit 2 on the command line)."""
    write_bag(tmp_path / "run.mcap", recording)
    rec = read_recording(tmp_path / "run.mcap")
    with pytest.raises(SpaceidError, match=r"`base_rate` gyro: the pose messages carry no angular velocity "
                                           r"\(geometry_msgs/PoseStamped\): publish nav_msgs/Odometry"):
        to_log(rec, joints=rec.joints.names, planar=True, base_rate="gyro")
    with pytest.raises(SpaceidError, match=r"base_rate='imu': choose one of attitude, gyro"):
        to_log(rec, joints=rec.joints.names, planar=True, base_rate="imu")
    (tmp_path / "m.yaml").write_text("base_rate: gyro\n")
    assert read_mapping(tmp_path / "m.yaml") == {"base_rate": "gyro"}
    (tmp_path / "m.yaml").write_text("base_rate: fast\n")
    with pytest.raises(SpaceidError, match=r"'base_rate' is 'fast': expected attitude or gyro"):
        read_mapping(tmp_path / "m.yaml")
    for log in (tmp_path / "run.mcap", tmp_path / "log.csv"):
        (tmp_path / "log.csv").write_text("t\n0\n")
        code = main(["identify", "cepheus-rw", str(log), "--momentum", "0.05", "--base-rate", "gyro", "-o",
                     str(tmp_path / "result.json")])
        lines = capsys.readouterr().err.strip().splitlines()
        assert code == 2 and len(lines) == 1 and lines[0].startswith("error: "), lines
        assert ("--base-rate gyro: the pose messages carry no" if log.suffix == ".mcap" else
                "base_rate apply to ROS bags") in lines[0], lines


@pytest.mark.slow
def test_identification_from_a_bag_through_the_cli(tmp_path, recording, rw):
    """The bag with its own joint names and topics, a mapping file, `spaceid identify`."""
    model, param = rw
    renamed = {"left_shoulder": "shoulder", "left_elbow": "elbow", "reaction_wheel_joint": "wheel"}
    js = recording.joints
    rec = Recording(JointStates(js.t, tuple(renamed[n] for n in js.names), js.position, js.velocity), recording.base)
    write_bag(tmp_path / "run", rec, format="mcap", joint_topic="/cepheus/joint_states", pose_topic="/mocap/cepheus/pose")
    mapping = tmp_path / "map.yaml"
    mapping.write_text("joint_topic: /cepheus/joint_states\npose_topic: /mocap/cepheus/pose\n"
                       "joints: {shoulder: left_shoulder, elbow: left_elbow, wheel: reaction_wheel_joint}\n")
    assert main(["identify", "cepheus-rw", str(tmp_path / "run"), "--momentum", "0.05", "--mapping", str(mapping),
                 "-o", str(tmp_path / "result.json")]) == 0
    result = json.loads((tmp_path / "result.json").read_text())
    values = np.array([p["value"] for p in result["parameters"]])
    # noise-free data: the error follows that of the base rate (~1e-10 rad/s, see above)
    np.testing.assert_allclose(values, param.true_values, rtol=1e-6, atol=1e-12)
    settings = json.dumps(result)
    assert "/mocap/cepheus/pose" in settings and "joint stamps" in settings and str(mapping) in settings

    # --differentiate on a bag: joint rates from the positions, differentiated once (in to_log)
    assert main(["identify", "cepheus-rw", str(tmp_path / "run"), "--momentum", "0.05", "--mapping", str(mapping),
                 "--differentiate", "-o", str(tmp_path / "diff.json")]) == 0
    log_settings = json.loads((tmp_path / "diff.json").read_text())["settings"]["log"]
    assert set(log_settings["joint_rates"].values()) == {"differentiated"}
    assert set(log_settings["differentiation"]["joints"]) == set(model.joints)
    # validate reads the same bag
    assert main(["validate", str(tmp_path / "result.json"), str(tmp_path / "run"), "--momentum", "0.05",
                 "--mapping", str(mapping), "-o", str(tmp_path / "validation")]) == 0
    assert json.loads((tmp_path / "validation" / "metrics.json").read_text())["base_w_rms"] < 1e-6


def test_read_log_dispatches_on_bags(tmp_path, recording, rw):
    from spaceid.data import read_log

    model, _ = rw
    write_bag(tmp_path / "r.bag", recording)
    log = read_log(tmp_path / "r.bag", joints=model.joints, planar=True, wheels=model.wheels)
    assert log.meta["format"] == "ros1" and log.n_samples == 249
    with pytest.raises(SpaceidError, match=r"joint_topic apply to ROS bags, but this is a CSV log"):
        read_log(tmp_path / "log.csv", joints=model.joints, planar=True, bag_options={"joint_topic": "/js"})


# --- bad input -----------------------------------------------------------------------------------


def _raw_bag(path, joint_msgs, poses, *, joint_type="sensor_msgs/msg/JointState", frame="world"):
    """A ROS 1 bag written with rosbags directly: ``joint_msgs`` of (stamp_ns, names,
    positions[, velocities]), received in list order 20 ms apart whatever their stamps, and
    ``poses`` of (stamp_ns, (x, y, z, w)), received at their stamps."""
    from rosbags.rosbag1 import Writer
    from rosbags.typesys import Stores, get_typestore

    store = get_typestore(Stores.ROS1_NOETIC)
    T = store.types

    def header(stamp, seq, frame_id=""):
        time = T["builtin_interfaces/msg/Time"](sec=stamp // NS, nanosec=stamp % NS)
        return T["std_msgs/msg/Header"](seq=seq, stamp=time, frame_id=frame_id)

    def pose_msg(k, stamp, quat):
        orientation = T["geometry_msgs/msg/Quaternion"](*quat)
        pose = T["geometry_msgs/msg/Pose"](T["geometry_msgs/msg/Point"](0.0, 0.0, 0.0), orientation)
        return T["geometry_msgs/msg/PoseStamped"](header(stamp, k, frame), pose)

    with Writer(path) as writer:
        jc = writer.add_connection("/joint_states", joint_type, typestore=store)
        pc = writer.add_connection(bags.DEFAULT_POSE_TOPIC, "geometry_msgs/msg/PoseStamped", typestore=store)
        for k, (stamp, names, position, *velocity) in enumerate(joint_msgs):
            if joint_type == "sensor_msgs/msg/JointState":
                msg = T[joint_type](header(stamp, k), list(names), np.array(position, float),
                                    np.array(velocity[0] if velocity else [], float), np.zeros(0))
            else:
                msg = pose_msg(k, stamp, (0.0, 0.0, 0.0, 1.0))
            writer.write(jc, k * 20_000_000, store.serialize_ros1(msg, joint_type))
        for k, (stamp, quat) in enumerate(poses):
            writer.write(pc, stamp, store.serialize_ros1(pose_msg(k, stamp, quat), "geometry_msgs/msg/PoseStamped"))
    return path


def _joint_msgs(stamps_ms, names=("a", "b")):
    return [(int(s * 1_000_000), list(names), [0.1 * k, 0.2 * k]) for k, s in enumerate(stamps_ms)]


POSES = [(k * 10_000_000, (0.0, 0.0, 0.0, 1.0)) for k in range(30)]


def test_missing_topic_lists_the_topics(tmp_path, recording):
    write_bag(tmp_path / "r.bag", recording)
    with pytest.raises(SpaceidError) as err:
        read_recording(tmp_path / "r.bag", pose_topic="/mocap/pose")
    message = str(err.value)
    assert "no topic '/mocap/pose' in the bag" in message and "/joint_states (sensor_msgs/msg/JointState)" in message
    assert bags.DEFAULT_POSE_TOPIC in message and "`pose_topic`" in message and "\n" not in message


def test_wrong_message_type(tmp_path, recording):
    write_bag(tmp_path / "r", recording, format="ros2")
    with pytest.raises(SpaceidError, match=r"topic '/joint_states' carries sensor_msgs/msg/JointState, expected "
                                           r"geometry_msgs/msg/PoseStamped"):
        read_recording(tmp_path / "r", pose_topic="/joint_states")
    path = _raw_bag(tmp_path / "w.bag", [(0, [], [])], POSES, joint_type="geometry_msgs/msg/PoseStamped")
    with pytest.raises(SpaceidError, match=r"'/joint_states' carries geometry_msgs/msg/PoseStamped, expected "
                                           r"sensor_msgs/msg/JointState: set `joint_topic`"):
        read_recording(path)


def test_unknown_joint_names(tmp_path, recording):
    write_bag(tmp_path / "r.bag", recording)
    rec = read_recording(tmp_path / "r.bag")
    with pytest.raises(SpaceidError, match=r"model joint 'right_elbow' is not on /joint_states \(joints there: "
                                           r"reaction_wheel_joint, left_shoulder, left_elbow\): map the bag's name"):
        to_log(rec, joints=("left_shoulder", "right_elbow"), planar=True)
    with pytest.raises(SpaceidError, match=r"/joint_states: the joint mapping names 'elbow', which is not in the bag "
                                           r"\(joints: reaction_wheel_joint, left_shoulder, left_elbow\)"):
        read_recording(tmp_path / "r.bag", rename={"elbow": "left_elbow"})
    with pytest.raises(SpaceidError, match=r"gives two joints the name 'left_elbow'"):
        read_recording(tmp_path / "r.bag", rename={"left_shoulder": "left_elbow"})


@pytest.mark.parametrize("stamps, message", [
    ([0, 20, 40, 30, 60], r"joint 'a': stamp 0.030000000 s in message 3 goes back from 0.040000000 s in message 2"),
    ([0, 20, 20, 40, 60], r"joint 'a': stamp 0.020000000 s in message 2 repeats 0.020000000 s in message 1"),
])
def test_non_monotonic_or_repeated_stamps(tmp_path, stamps, message):
    path = _raw_bag(tmp_path / "r.bag", _joint_msgs(stamps), POSES)  # received in order, stamped out of order
    with pytest.raises(SpaceidError, match=r"r\.bag: /joint_states: " + message + r".*header stamps must increase"):
        read_recording(path)


def test_bad_messages(tmp_path):
    cases = {
        "nan.bag": ([(0, ["a", "b"], [0.0, np.nan])], POSES, r"position of joint 'b' is nan"),
        "short.bag": ([(0, ["a", "b"], [0.0])], POSES, r"has 2 names but 1 positions"),
        "twice.bag": ([(0, ["a", "a"], [0.0, 1.0])], POSES, r"names joint 'a' twice"),
        "vel.bag": ([(0, ["a", "b"], [0.0, 1.0], [1.0])], POSES, r"has 2 names but 1 velocity values"),
        "pnan.bag": (_joint_msgs([0, 20]), [(0, (0.0, 0.0, 0.0, 1.0)), (10_000_000, (np.nan, 0.0, 0.0, 1.0))],
                     r"vrpn_client_node/cepheus/pose: message 1 \(stamp 0.010000000 s\) holds NaN"),
        "zero.bag": (_joint_msgs([0, 20]), [(0, (0.0, 0.0, 0.0, 0.0))], r"orientation has norm 0, expected 1"),
        "empty.bag": ([], POSES, r"topic '/joint_states' holds no messages"),
    }
    for name, (joint_msgs, poses, message) in cases.items():
        with pytest.raises(SpaceidError, match=message):
            read_recording(_raw_bag(tmp_path / name, joint_msgs, poses))


def test_not_a_bag(tmp_path):
    (tmp_path / "junk.bag").write_bytes(b"not a bag")
    (tmp_path / "folder").mkdir()
    with pytest.raises(SpaceidError, match=r"junk\.bag: not a readable ROS bag"):
        read_recording(tmp_path / "junk.bag")
    with pytest.raises(SpaceidError, match=r"folder: a folder without metadata\.yaml is not a ROS 2 bag"):
        read_recording(tmp_path / "folder")
    with pytest.raises(SpaceidError, match=r"nope\.mcap: no such file or folder"):
        read_recording(tmp_path / "nope.mcap")


@pytest.mark.filterwarnings("ignore:.*gap of:UserWarning")  # signals may warn about the bridged gap
def test_long_mocap_gap(lab_recording, truth):
    rec, _ = lab_recording
    keep = (rec.base.t < 2.0) | (rec.base.t > 2.3)
    gap = Recording(rec.joints, Poses(rec.base.t[keep], rec.base.position[keep], rec.base.quat[keep], "mocap"),
                    meta={"source": "run.bag", "pose_topic": "/mocap/pose"})
    # stamps in the message: latency-corrected, on the recording's clock
    with pytest.raises(SpaceidError, match=r"run\.bag: /mocap/pose: no message for 0\.31 s between t = 1\.983 and "
                                           r"2\.293 s \(~30 dropped\), longer than max_gap = 0\.1 s"):
        to_log(gap, joints=truth.joints, planar=True, pose_latency=LATENCY)
    log = to_log(gap, joints=truth.joints, planar=True, wheels=("reaction_wheel_joint",), pose_latency=LATENCY,
                 max_gap=0.35)
    assert log.meta["streams"]["pose"]["largest_step_s"] > 0.3


def test_streams_that_do_not_overlap(truth):
    rec = _recording(truth, np.arange(0, 50) * 20_000_000 / 1e9, np.arange(0, 50) * 10_000_000 / 1e9 + 2.0)
    with pytest.raises(SpaceidError, match=r"the streams do not overlap in time"):
        to_log(rec, joints=truth.joints, planar=True)


def test_mapping_file(tmp_path):
    good = tmp_path / "good.yaml"
    good.write_text("pose_topic: /mocap/cepheus/pose\njoints: {shoulder: left_shoulder}\nrate: 50\npose_latency: 0.01\n")
    assert read_mapping(good) == {"pose_topic": "/mocap/cepheus/pose", "joints": {"shoulder": "left_shoulder"},
                                  "rate": 50, "pose_latency": 0.01}
    for text, message in [("topic: /x\n", r"unknown key 'topic': did you mean 'pose_topic'\? the keys are joint_topic, pose_topic"),
                          ("rate: -5\n", r"'rate' is -5: expected a sample rate \[Hz\] > 0"),
                          ("joints: [a, b]\n", r"'joints' is \['a', 'b'\]: expected a mapping"),
                          ("- a\n", r"expected a mapping of keys"),
                          ("joints: {a: b\n", r"not valid YAML at line")]:
        (tmp_path / "bad.yaml").write_text(text)
        with pytest.raises(SpaceidError, match=message):
            read_mapping(tmp_path / "bad.yaml")


def test_cli_missing_topic_is_one_line_exit_2(tmp_path, recording, capsys):
    write_bag(tmp_path / "run.bag", recording)
    code = main(["identify", "cepheus-rw", str(tmp_path / "run.bag"), "--momentum", "0.05", "--pose-topic",
                 "/mocap/cepheus/pose", "-o", str(tmp_path / "result.json")])
    lines = capsys.readouterr().err.strip().splitlines()
    assert code == 2 and len(lines) == 1 and lines[0].startswith("error: ")
    assert "no topic '/mocap/cepheus/pose'" in lines[0] and bags.DEFAULT_POSE_TOPIC in lines[0]
    assert not (tmp_path / "result.json").exists()


# --- atomic writing ------------------------------------------------------------------------------


@pytest.mark.parametrize("name, format", [("run.bag", None), ("run", "ros2"), ("run", "mcap"), ("run.mcap", None)])
def test_failed_write_leaves_no_partial_bag(tmp_path, recording, monkeypatch, name, format):
    from rosbags import rosbag1, rosbag2

    writer = rosbag1.Writer if format is None and name.endswith(".bag") else rosbag2.Writer
    original = writer.write
    calls = []

    def failing(self, *args):
        calls.append(1)
        if len(calls) > 300:
            raise OSError(28, "No space left on device")
        return original(self, *args)

    path = tmp_path / name
    write_bag(path, recording, format=format)  # an older bag at the path
    before = _snapshot(path)
    short = Recording(JointStates(recording.joints.t[:5], recording.joints.names, recording.joints.position[:5]),
                      recording.base)
    monkeypatch.setattr(writer, "write", failing)
    with pytest.raises(SpaceidError, match=r"cannot write the bag \(No space left on device\)"):
        write_bag(path, short, format=format)
    assert _snapshot(path) == before  # untouched
    assert sorted(p.name for p in tmp_path.iterdir()) == [name]  # no staging folder left
    monkeypatch.undo()
    write_bag(path, short, format=format)  # replacing a bag works
    assert read_recording(path).joints.t.size == 5 and sorted(p.name for p in tmp_path.iterdir()) == [name]


def _snapshot(path):
    files = [path] if path.is_file() else sorted(path.iterdir())
    return {f.name: f.read_bytes() for f in files}


def test_write_refuses_bad_targets_and_recordings(tmp_path, recording):
    (tmp_path / "mine").mkdir()
    (tmp_path / "mine" / "notes.txt").write_text("keep")
    with pytest.raises(SpaceidError, match=r"mine: exists and is a folder but not a ROS 2 bag"):
        write_bag(tmp_path / "mine", recording, format="ros2")
    assert (tmp_path / "mine" / "notes.txt").read_text() == "keep"
    with pytest.raises(SpaceidError, match=r"a ROS 1 bag needs the \.bag suffix"):
        write_bag(tmp_path / "run", recording, format="ros1")
    with pytest.raises(SpaceidError, match=r"cannot tell the bag format"):
        write_bag(tmp_path / "run", recording)
    t = recording.joints.t.copy()
    t[5] = t[4]
    bad = Recording(JointStates(t, recording.joints.names, recording.joints.position), recording.base)
    with pytest.raises(SpaceidError, match=r"recording\.joints\.t: stamp 5 .* stamps must increase strictly"):
        write_bag(tmp_path / "bad.bag", bad)
    with pytest.raises(SpaceidError, match=r"joint_groups leaves out reaction_wheel_joint"):
        write_bag(tmp_path / "g.bag", recording, joint_groups=[["left_shoulder", "left_elbow"]])
    assert sorted(p.name for p in tmp_path.iterdir()) == ["mine"]
