"""Hostile inputs found by trying the commands as a new user would: each ends in one line that
names the input and the fix, with exit code 2, and writes nothing."""

import json

import numpy as np
import pytest
from test_bags import _recording, rw, truth  # noqa: F401 -- module fixtures of the bag tests

from spaceid import SpaceidError
from spaceid.cli import main
from spaceid.data import read_log, to_log, write_bag, write_log
from spaceid.motion import load_trajectory

H = "0.4934"


def _fails_on_one_line(capsys, args, message):
    """``spaceid ARGS`` exits with 2 and one ``error:`` line matching ``message``."""
    assert main(args) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert err[-1].startswith("error: ") and len(err[-1]) < 600, err
    assert pytest.importorskip("re").search(message, err[-1]), err[-1]


def _trajectory(tmp_path, name, **changes):
    path = tmp_path / name
    path.write_text(json.dumps(load_trajectory("paper-table2").to_dict() | changes))
    return path


def test_a_huge_fourier_coefficient_names_the_fields(tmp_path, capsys):
    a = np.array(load_trajectory("paper-table2").a)
    a[0, 0] = 1e300
    path = _trajectory(tmp_path, "huge.json", a=a.tolist())
    with pytest.raises(SpaceidError, match=r"huge\.json: fields 'a', 'b' .* joint rates up to \S+e\+29\d rad/s"):
        load_trajectory(path)
    a[0, 0] = 1e6  # rad/s of a harmonic: no robot's joint
    with pytest.raises(SpaceidError, match=r"joint rates up to .* above 10000: give the Fourier coefficients in rad/s"):
        load_trajectory(_trajectory(tmp_path, "fast.json", a=a.tolist()))
    _fails_on_one_line(capsys, ["simulate", "cepheus", "--trajectory", str(path), "--momentum", H, "--samples", "35",
                                "-o", str(tmp_path / "log.csv")], r"huge\.json: fields 'a', 'b'")
    assert not (tmp_path / "log.csv").exists()


def test_a_nanosecond_trajectory_is_refused(tmp_path, capsys):
    path = _trajectory(tmp_path, "short.json", duration=1e-9)
    _fails_on_one_line(capsys, ["simulate", "cepheus", "--trajectory", str(path), "--momentum", H, "--samples", "35",
                                "-o", str(tmp_path / "log.csv")],
                       r"short\.json: field 'duration' is 1e-09 s, shorter than 0\.001 s: give the motion's duration")
    assert not (tmp_path / "log.csv").exists()
    assert load_trajectory(_trajectory(tmp_path, "ms.json", duration=1e-3)).duration == 1e-3  # the limit itself


def test_validate_refuses_millisecond_stamps(tmp_path, capsys):
    log = tmp_path / "log.csv"
    assert main(["simulate", "cepheus", "--trajectory", "paper-table2", "--momentum", H, "--rate", "50",
                 "-o", str(log)]) == 0
    assert main(["identify", "cepheus", str(log), "--momentum", H, "--estimator", "ols",
                 "-o", str(tmp_path / "result.json")]) == 0
    read = read_log(log, joints=("left_shoulder", "left_elbow"), planar=True)
    ms = tmp_path / "ms.csv"
    write_log(ms, read.__class__(read.t * 1e3, read.joints, read.q, read.qd, read.base_quat, read.base_w, True))
    capsys.readouterr()
    _fails_on_one_line(capsys, ["validate", str(tmp_path / "result.json"), str(ms), "--momentum", H,
                                "-o", str(tmp_path / "val")],
                       r"ms\.csv: column t: every rate integrates to 1e\+03 times .* milliseconds\? Convert t to seconds")
    assert not (tmp_path / "val").exists()


@pytest.mark.slow  # fast representative: test_validate_refuses_millisecond_stamps
def test_a_bag_mapping_rate_beyond_memory_names_the_key(tmp_path, truth, capsys):  # noqa: F811
    stamps = np.arange(0, 251) * 0.02
    rec = _recording(truth, stamps, stamps + 0.003, effort=False)
    with pytest.raises(SpaceidError, match=r"mapping key 'rate' 1e\+09 Hz over .* samples would need about .* GiB"):
        to_log(rec, joints=rec.joints.names, planar=True, wheels=("reaction_wheel_joint",), rate=1e9)
    bag = tmp_path / "run.bag"
    write_bag(bag, rec)
    mapping = tmp_path / "map.yaml"
    mapping.write_text("rate: 1e9\n")
    _fails_on_one_line(capsys, ["identify", "cepheus-rw", str(bag), "--momentum", H, "--mapping", str(mapping),
                                "-o", str(tmp_path / "result.json")], r"mapping key 'rate' 1e\+09 Hz")
    assert not (tmp_path / "result.json").exists()


@pytest.mark.slow
@pytest.mark.parametrize("preset, lengths", [("cepheus", (2_000, 16_000)), ("satellite-7dof", (10_000, 30_000))])
def test_simulate_memory_grows_with_the_log_only(preset, lengths):
    """``simulate --samples 100000`` peaked at 2.1 GB for a 14 MB log: the quadrature evaluated the
    base rate at every node of the log at once (planar), the attitude's rate splines spanned the
    whole log and the solver's cycles kept each block's alive (spatial: 353 MB for 18 MB). In
    blocks, the peak grows by a few times the log."""
    import tracemalloc

    from spaceid import load_model, minimal_parameters
    from spaceid.motion import FourierTrajectory, sample_times, simulate

    param = minimal_parameters(load_model(preset))
    if param.model.planar:
        traj, h = load_trajectory("paper-table2"), np.array([0.0, 0.0, float(H)])
    else:
        rng, shape = np.random.default_rng(0), (len(param.model.joints), 3)
        traj = FourierTrajectory(param.model.joints, 30.0, 0.05 * rng.standard_normal(shape),
                                 0.05 * rng.standard_normal(shape))
        h = np.array([0.3, -0.2, 0.5])
    peaks, sizes = [], []
    for n in lengths:
        tracemalloc.start()
        log = simulate(param, param.true_values, traj, sample_times(traj.duration, n), h)
        peaks.append(tracemalloc.get_traced_memory()[1])
        tracemalloc.stop()
        sizes.append(sum(a.nbytes for a in (log.t, log.q, log.qd, log.base_quat, log.base_w)))
    assert peaks[1] - peaks[0] < 10 * (sizes[1] - sizes[0])
