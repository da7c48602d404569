"""The command line end to end on a temporary directory, and its handling of bad input."""

import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from spaceid.cli import main

DATA = Path(__file__).parent / "data"


def run(*args):
    return main([str(a) for a in args])


@pytest.fixture(scope="module")
def workdir(tmp_path_factory):
    """design -> simulate -> identify on Cepheus, shared by the tests below."""
    d = tmp_path_factory.mktemp("cli")
    assert run("design", "cepheus", "--duration", 5, "--harmonics", 3, "--samples", 35, "--momentum", 0.4934,
               "--seed", 3, "--starts", 8, "-o", d / "traj.json") == 0
    assert run("simulate", "cepheus", "--trajectory", d / "traj.json", "--momentum", 0.4934, "--samples", 35,
               "-o", d / "log.csv") == 0
    assert run("simulate", "cepheus", "--trajectory", "paper-table2", "--momentum", 0.4934, "--rate", 100,
               "--noise-angle", 1e-4, "--noise-rate", 1e-4, "--seed", 5, "-o", d / "noisy.csv") == 0
    assert run("identify", "cepheus", d / "log.csv", "--momentum", 0.4934, "-o", d / "result.json") == 0
    return d


@pytest.mark.slow
def test_identify_recovers_truth_through_files(workdir):
    result = json.loads((workdir / "result.json").read_text())
    from spaceid.dynamics import minimal_parameters
    import spaceid

    truth = minimal_parameters(spaceid.load_model("cepheus")).true_values
    values = np.array([p["value"] for p in result["parameters"]])
    np.testing.assert_allclose(values, truth, rtol=1e-9)
    assert {"name", "definition", "value", "std"} <= set(result["parameters"][0])
    assert result["condition_number"] < 360  # better than the paper's trajectory


def test_noisy_log_at_rate(workdir):
    header = (workdir / "noisy.csv").read_text().splitlines()[0].split(",")
    assert header[:3] == ["t", "base_yaw", "base_wz"] and "q_left_elbow" in header
    assert len((workdir / "noisy.csv").read_text().splitlines()) == 1 + 501
    assert run("identify", "cepheus", workdir / "noisy.csv", "--momentum", 0.4934, "-o", workdir / "noisy.json") == 0


def test_noise_levels_mean_the_same_in_simulate_and_identify(workdir):
    """``--noise-angle`` and ``--noise-rate`` alone give the base's levels too, in ``identify`` as in ``simulate``
    (which drew noisy.csv's gyro noise at the rate's level): the same result as with all four given; a
    noise-free gyro is given as 0. (Taken as 0 before, the satellite's ML errors reached 10 standard errors.)"""
    levels = {}
    for name, extra in (("alone", []), ("all", ["--noise-base-rate", 1e-4, "--noise-attitude", 1e-4]),
                        ("gyro", ["--noise-base-rate", 0])):
        out = workdir / f"levels-{name}.json"
        assert run("identify", "cepheus", workdir / "noisy.csv", "--momentum", 0.4934, "--estimator", "wls",
                   "--noise-angle", 1e-4, "--noise-rate", 1e-4, *extra, "-o", out) == 0
        result = json.loads(out.read_text())
        levels[name] = (result["settings"]["noise"], [p["value"] for p in result["parameters"]])
    assert levels["alone"] == levels["all"]
    assert levels["alone"][0] == {"angle": 1e-4, "rate": 1e-4, "base_rate": 1e-4, "attitude": 1e-4, "source": "given"}
    assert levels["gyro"][0]["base_rate"] == 0.0 and levels["gyro"][1] != levels["alone"][1]


def test_predict_and_validate(workdir, capsys):
    log = np.genfromtxt(workdir / "log.csv", delimiter=",", names=True)
    traj = workdir / "joints.csv"
    cols = ["t", "q_left_shoulder", "qd_left_shoulder", "q_left_elbow", "qd_left_elbow"]
    np.savetxt(traj, np.column_stack([log[c] for c in cols]), delimiter=",", header=",".join(cols), comments="")
    assert run("predict", workdir / "result.json", traj, "--momentum", 0.4934, "-o", workdir / "pred.csv") == 0
    pred = np.genfromtxt(workdir / "pred.csv", delimiter=",", names=True)
    np.testing.assert_allclose(pred["base_wz"], log["base_wz"], rtol=1e-9)
    capsys.readouterr()
    assert run("validate", workdir / "result.json", workdir / "log.csv", "--momentum", 0.4934, "-o", workdir / "val",
               "--png") == 0
    metrics = json.loads((workdir / "val" / "metrics.json").read_text())
    assert metrics["base_w_nrms"] < 1e-9
    assert (workdir / "val" / "validation.png").stat().st_size > 10000
    # that was the log the result was identified from: said so, as validation there cannot fail
    err = " ".join(capsys.readouterr().err.split())  # rich wraps long lines
    assert "warning: " in err and "validation on the fitting log cannot fail; record a different motion" in err
    # another motion (paper-table2, noisy): no warning; the true model within the noise
    assert run("validate", workdir / "result.json", workdir / "noisy.csv", "--momentum", 0.4934, "--out",
               workdir / "val2") == 0
    assert "warning" not in capsys.readouterr().err
    assert json.loads((workdir / "val2" / "metrics.json").read_text())["base_w_rms"] < 1e-3
    assert not (workdir / "val2" / "validation.png").exists() and (workdir / "val2" / "report.html").is_file()  # no --png


def test_predict_takes_the_trajectory_design_writes(workdir, capsys):
    """The designed trajectory at its own 35 sample times is the simulated log's joint motion."""
    log = np.genfromtxt(workdir / "log.csv", delimiter=",", names=True)
    assert run("predict", workdir / "result.json", workdir / "traj.json", "--momentum", 0.4934,
               "-o", workdir / "pred_traj.csv") == 0
    pred = np.genfromtxt(workdir / "pred_traj.csv", delimiter=",", names=True)
    np.testing.assert_allclose(pred["t"], log["t"], rtol=1e-12)
    np.testing.assert_allclose(pred["base_wz"], log["base_wz"], rtol=1e-9)
    assert run("predict", workdir / "result.json", workdir / "traj.json", "--momentum", 0.4934, "--rate", 20,
               "-o", workdir / "pred_20hz.csv") == 0
    assert len((workdir / "pred_20hz.csv").read_text().splitlines()) == 1 + 101  # 5 s at 20 Hz
    capsys.readouterr()
    assert run("predict", workdir / "result.json", workdir / "log.csv", "--momentum", 0.4934, "--samples", 9,
               "-o", workdir / "bad.csv") == 2
    assert "a CSV gives its own samples" in capsys.readouterr().err and not (workdir / "bad.csv").exists()


def test_iv_takes_the_trajectory_design_writes_as_instruments(workdir):
    assert run("identify", "cepheus", workdir / "log.csv", "--momentum", 0.4934, "--estimator", "iv",
               "--instruments", workdir / "traj.json", "-o", workdir / "iv.json") == 0
    assert json.loads((workdir / "iv.json").read_text())["estimator"] == "iv"


def test_result_records_units_and_reads_files_without_them(workdir, capsys):
    from spaceid.estimation import Identification, load_result

    result = json.loads((workdir / "result.json").read_text())
    assert [p["unit"] for p in result["parameters"]] == ["kg m^2"] * 8  # planar basis: h [N m s] = Y [1/s] pi
    assert load_result(workdir / "result.json").units == ("kg m^2",) * 8
    for p in result["parameters"]:
        del p["unit"]
    assert Identification.from_dict(result).units == ()  # results written before units were recorded


def test_compare_without_change_says_so_in_one_line(workdir, capsys):
    assert run("compare", workdir / "result.json", workdir / "result.json") == 0
    out = capsys.readouterr().out
    assert out.strip() == "no parameter changed beyond 3 standard errors (8 compared; --all lists them)"


def test_model_json(capsys):
    from spaceid.dynamics import minimal_parameters
    import spaceid

    assert run("model", "cepheus", "--json") == 0
    info = json.loads(capsys.readouterr().out)
    assert info["n_minimal_parameters"] == 8 and len(info["parameters"]) == 8
    truth = minimal_parameters(spaceid.load_model("cepheus")).true_values
    np.testing.assert_array_equal([p["value"] for p in info["parameters"]], truth)  # as the table shows them
    assert {p["unit"] for p in info["parameters"]} == {"kg m^2"}


@pytest.mark.slow
def test_model_of_a_large_system_is_a_summary(tmp_path, capsys):
    """The servicer's report was thousands of lines: a summary by default, all with --all or a file."""
    import spaceid
    import sympy as sp

    urdf = tmp_path / "sat.urdf"
    urdf.write_bytes((Path(spaceid.__file__).parent / "models" / "presets" / "satellite-7dof.urdf").read_bytes())
    assert run("model", urdf) == 0
    summary = capsys.readouterr().out
    assert len(summary.splitlines()) < 80 and "pi20 " in summary and "pi21 " not in summary
    assert "the first 20 of 153 parameters" in summary and "--all" in summary and "--definitions FILE" in summary
    assert run("model", urdf, "--all") == 0
    assert "pi153 " in capsys.readouterr().out
    assert run("model", urdf, "--definitions", tmp_path / "defs.txt") == 0
    lines = (tmp_path / "defs.txt").read_text().splitlines()
    assert len(lines) == 1 + 153 and lines[1].startswith("pi1 = ") and "# [kg m^2]" in lines[1]
    name, definition = lines[-1].split("  #")[0].split(" = ")
    assert name == "pi153" and sp.sympify(definition).free_symbols
    before = urdf.read_bytes()
    assert run("model", urdf, "--definitions", urdf) == 2  # never over an input
    assert urdf.read_bytes() == before and "is the input MODEL; choose another output file" in capsys.readouterr().err


def _log_with(workdir, tmp_path, edit):
    lines = (workdir / "log.csv").read_text().splitlines()
    path = tmp_path / "bad.csv"
    path.write_text("\n".join(edit(lines)) + "\n")
    return path


def _swap_rows(lines):
    lines[3], lines[4] = lines[4], lines[3]
    return lines


def _nan_cell(lines):
    cells = lines[5].split(",")
    cells[1] = "nan"
    lines[5] = ",".join(cells)
    return lines


def _drop_column(lines):
    header = lines[0].split(",")
    k = header.index("qd_left_elbow")
    return [",".join(c for i, c in enumerate(line.split(",")) if i != k) for line in lines]


BAD_LOGS = {
    "unsorted time": (_swap_rows, "increase strictly"),
    "NaN": (_nan_cell, "holds nan"),
    "missing joint column": (_drop_column, "qd_left_elbow"),
    "too few samples": (lambda lines: lines[:6], "samples"),
    "malformed": (lambda lines: [lines[0], "1,2"], "bad.csv"),
}


@pytest.mark.parametrize("case", BAD_LOGS)
def test_bad_log_is_one_line_exit_2_and_no_output(workdir, tmp_path, capsys, case):
    edit, message = BAD_LOGS[case]
    path = _log_with(workdir, tmp_path, edit)
    before = path.read_bytes()
    out = tmp_path / "result.json"
    assert run("identify", "cepheus", path, "--momentum", 0.4934, "-o", out) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("error:") and message in err and "Traceback" not in err
    assert not out.exists() and path.read_bytes() == before


def test_rank_deficient_log_names_parameters(workdir, tmp_path, capsys):
    def freeze_elbow(lines):
        header = lines[0].split(",")
        q, qd = header.index("q_left_elbow"), header.index("qd_left_elbow")
        out = [lines[0]]
        for line in lines[1:]:
            cells = line.split(",")
            cells[q], cells[qd] = "0.3", "0"
            out.append(",".join(cells))
        return out

    path = _log_with(workdir, tmp_path, freeze_elbow)
    assert run("identify", "cepheus", path, "--momentum", 0.4934, "-o", tmp_path / "r.json") == 2
    err = capsys.readouterr().err
    assert "rank-deficient" in err and "not excited: pi" in err


def test_non_planar_joint_in_planar_mode(tmp_path, capsys):
    path = tmp_path / "tilted.urdf"
    text = (DATA / "planar_arm_fixed.urdf").read_text().replace('<axis xyz="0 0 -1"/>', '<axis xyz="0 1 0"/>')
    path.write_text(text)
    assert run("model", path, "--planar") == 2
    assert "joint 'elbow'" in capsys.readouterr().err


def test_missing_files_and_bad_momentum(workdir, tmp_path, capsys):
    assert run("identify", "cepheus", tmp_path / "none.csv", "--momentum", 0.4934, "-o", tmp_path / "r.json") == 2
    assert run("identify", "nothing.urdf", workdir / "log.csv", "--momentum", 0.4934, "-o", tmp_path / "r.json") == 2
    assert run("identify", "cepheus", workdir / "log.csv", "--momentum", "abc", "-o", tmp_path / "r.json") == 2
    assert run("identify", "cepheus", workdir / "log.csv", "--momentum", 0, "-o", tmp_path / "r.json") == 2
    assert run("simulate", "cepheus", "--trajectory", tmp_path / "no.json", "--momentum", 0.4934, "--samples", 9, "-o", tmp_path / "l.csv") == 2
    err = capsys.readouterr().err
    assert err.count("error:") == 5 and "Traceback" not in err
    assert not any(tmp_path.glob("*.json")) and not (tmp_path / "l.csv").exists()


@pytest.mark.slow
def test_console_script_exit_code(tmp_path):
    proc = subprocess.run([sys.executable, "-m", "spaceid.cli", "identify", "cepheus", str(tmp_path / "x.csv"),
                           "--momentum", "0.4934", "-o", str(tmp_path / "r.json")], capture_output=True, text=True)
    assert proc.returncode == 2 and proc.stderr.count("\n") == 1 and "Traceback" not in proc.stderr


@pytest.mark.slow
def test_spatial_pipeline_through_files(tmp_path, capsys):
    """A 7-DOF satellite: quaternion logs, identification, validation, and compare."""
    import spaceid
    from spaceid.motion import FourierTrajectory

    urdf = Path(spaceid.__file__).parent / "models" / "presets" / "satellite-7dof.urdf"
    model = spaceid.load_model(urdf)
    rng = np.random.default_rng(1)
    FourierTrajectory(model.joints, 30.0, rng.uniform(-0.2, 0.2, (7, 8)), rng.uniform(-0.2, 0.2, (7, 8))).save(tmp_path / "t.json")
    common = ["--momentum", "1,-2,3", "--trajectory", tmp_path / "t.json", "--samples", 300]
    assert run("simulate", urdf, *common, "-o", tmp_path / "log.csv") == 0
    assert run("simulate", urdf, *common, "--noise-angle", 1e-5, "--noise-rate", 1e-5, "--seed", 2, "-o", tmp_path / "noisy.csv") == 0
    header = (tmp_path / "log.csv").read_text().splitlines()[0].split(",")
    assert {"base_qw", "base_qx", "base_qy", "base_qz", "base_wx", "base_wy", "base_wz", "q_arm_joint7"} <= set(header)
    capsys.readouterr()
    assert run("identify", urdf, tmp_path / "log.csv", "--momentum", "1,-2,3", "-o", tmp_path / "r.json") == 0
    summary = capsys.readouterr().out  # 153 estimates: the first 20 and where the others are
    assert "pi20 " in summary and "pi21 " not in summary and len(summary.splitlines()) < 60
    summary = " ".join(summary.split())  # rich wraps at the console's width
    assert "the first 20 of 153 parameters listed, 133 more: --all lists them;" in summary
    assert "r.json and " in summary and "r.html hold every one" in summary
    assert run("identify", urdf, tmp_path / "noisy.csv", "--momentum", "1,-2,3", "-o", tmp_path / "n.json",
               "--all") == 0
    every = capsys.readouterr().out
    assert all(f"pi{i} " in every for i in range(1, 154)) and "more: --all" not in every
    assert run("validate", tmp_path / "r.json", tmp_path / "log.csv", "--momentum", "1,-2,3", "-o", tmp_path / "val") == 0
    assert json.loads((tmp_path / "val" / "metrics.json").read_text())["base_w_nrms"] < 1e-6
    capsys.readouterr()
    assert run("compare", tmp_path / "r.json", tmp_path / "n.json", "--json") == 0
    rows = json.loads(capsys.readouterr().out)["parameters"]
    assert len(rows) == 153 and np.median(np.abs([r["z"] for r in rows])) < 3  # noise only: no real change
    assert run("identify", urdf, tmp_path / "log.csv", "--momentum", "1,-2", "-o", tmp_path / "x.json") == 2
    capsys.readouterr()
    # started at rest: 0 is 0,0,0 for a spatial model too, which needs an anchor as a planar one does
    assert run("identify", urdf, tmp_path / "log.csv", "--momentum", 0, "-o", tmp_path / "x.json") == 2
    assert "the momentum is zero" in capsys.readouterr().err and not (tmp_path / "x.json").exists()


@pytest.mark.slow
def test_angles_only_log_is_differentiated(tmp_path):
    """Encoder and motion-capture angles only (rates differentiated), as on the real emulator."""
    assert run("simulate", "cepheus", "--trajectory", "paper-table2", "--momentum", 0.4934, "--rate", 100,
               "--noise-angle", 1e-4, "--seed", 1, "-o", tmp_path / "full.csv") == 0
    data = np.genfromtxt(tmp_path / "full.csv", delimiter=",", names=True)
    cols = ["t", "base_yaw", "q_left_shoulder", "q_left_elbow"]
    np.savetxt(tmp_path / "angles.csv", np.column_stack([data[c] for c in cols]), delimiter=",",
               header=",".join(cols), comments="")
    assert run("identify", "cepheus", tmp_path / "angles.csv", "--momentum", 0.4934, "--joint-rates", "differentiate",
               "-o", tmp_path / "r.json") == 0
    result = json.loads((tmp_path / "r.json").read_text())
    assert result["settings"]["log"]["differentiation"]["joints"]["method"]
    import spaceid
    from spaceid.dynamics import minimal_parameters

    truth = minimal_parameters(spaceid.load_model("cepheus")).true_values
    values = np.array([p["value"] for p in result["parameters"]])
    assert np.abs(values / truth - 1).max() < 0.05  # OLS on differentiated rates: percent level


def test_partly_missing_rates_are_an_error(workdir, tmp_path, capsys):
    path = _log_with(workdir, tmp_path, _drop_column)
    assert run("identify", "cepheus", path, "--momentum", 0.4934, "--differentiate", "-o", tmp_path / "r.json") == 0
    assert run("identify", "cepheus", path, "--momentum", 0.4934, "-o", tmp_path / "s.json") == 2
    assert "--differentiate" in capsys.readouterr().err


def test_compare_all_draws_the_table_with_units(workdir, capsys):
    assert run("compare", workdir / "result.json", workdir / "result.json", "--all") == 0
    out = capsys.readouterr().out
    assert "8 of 8 parameters" in out and "kg m^2" in out and "pi8" in out


def test_simulate_base_position_feeds_identify_com(tmp_path):
    """'simulate --base-position' writes the columns 'identify --com' needs; it then recovers the CM."""
    common = ("--trajectory", "paper-table2", "--momentum", 0.4934, "--rate", 20)
    assert run("simulate", "cepheus", *common, "-o", tmp_path / "plain.csv") == 0
    assert "base_x" not in (tmp_path / "plain.csv").read_text().splitlines()[0].split(",")
    assert run("simulate", "cepheus", *common, "--base-position", "-o", tmp_path / "log.csv") == 0
    header = (tmp_path / "log.csv").read_text().splitlines()[0].split(",")
    assert {"base_x", "base_y"} <= set(header)
    assert run("identify", "cepheus", tmp_path / "log.csv", "--momentum", 0.4934, "--com",
               "-o", tmp_path / "r.json") == 0
    com = json.loads((tmp_path / "r.json").read_text())["com"]
    np.testing.assert_allclose(com["inertial_com"], 0.0, atol=1e-9)  # the simulated CM is the origin
    assert com["residual_rms"] < 1e-9


def test_the_program_ends_with_its_output_exit_handlers_and_exit_code(tmp_path):
    """``spaceid`` (:func:`spaceid.cli.run`) ends its process without the interpreter's teardown: the output,
    the exit handlers' (printed to a pipe, block-buffered: lost unless flushed) and the exit code all arrive; bad
    input still ends with exit code 2 and its one error line."""
    program = ("import atexit, sys\nfrom spaceid.cli import run\n"
               "atexit.register(lambda: print('handler ran'))\nrun(sys.argv[1:])")
    env = {k: v for k, v in os.environ.items() if k != "PYTHONUNBUFFERED"}
    ok = subprocess.run([sys.executable, "-c", program, "model", "cepheus"], capture_output=True, text=True,
                        cwd=tmp_path, env=env, timeout=120, check=False)
    assert ok.returncode == 0 and not ok.stderr
    assert ok.stdout.startswith("cepheus") and ok.stdout.endswith("Izz_link2\nhandler ran\n")
    bad = subprocess.run([sys.executable, "-c", program, "model", "no-such-robot"], capture_output=True, text=True,
                         cwd=tmp_path, env=env, timeout=120, check=False)
    assert bad.returncode == 2 and bad.stderr.startswith("error: ") and bad.stdout == "handler ran\n"
