"""Campaigns on every scheduler: Monte Carlo numbers bit-identical on a local pool of 1 and 2
processes, a Dask LocalCluster and a real ``dask scheduler`` with a ``dask worker`` on localhost;
a resumed campaign equal to an uninterrupted one; design sweeps checked against direct calls."""

import json
import os
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner

import spaceid
from spaceid import SpaceidError
from spaceid._campaign import resolve_scheduler, task_folder, task_seeds
from spaceid.cli import app, main
from spaceid.dynamics import excitation_regressor, minimal_parameters
from spaceid.motion import (
    FourierTrajectory,
    design_excitation,
    sample_times,
    whitened_regressor,
)
from spaceid.studies import DEFAULT_NOISE, run_montecarlo
from spaceid.studies._montecarlo_runs import _Study

H = [0.0, 0.0, 0.4934]
SRC = Path(spaceid.__file__).parent.parent


@pytest.fixture(scope="module")
def param():
    return minimal_parameters(spaceid.load_model("cepheus"))


def study(param, **kw):
    options = dict(samples=35, momentum=H, noise=DEFAULT_NOISE, runs=6, estimators=("ols", "wls"), seed=7, jobs=1)
    return run_montecarlo(param, "paper-table2", **{**options, **kw})


def _numbers(result) -> dict:
    """Everything of a Monte Carlo result but how and how fast it ran."""
    d = result.to_dict()
    d["settings"] = {k: v for k, v in d["settings"].items() if k not in ("jobs", "scheduler", "wall_time_s")}
    return d


def _assert_same(a, b):
    for e in a.estimators:
        np.testing.assert_array_equal(a.estimates[e], b.estimates[e])
        np.testing.assert_array_equal(a.predicted_std[e], b.predicted_std[e])
    assert _numbers(a) == _numbers(b)


@pytest.fixture
def dask_cluster(tmp_path):
    """A ``dask scheduler`` and one ``dask worker`` (one thread) started on localhost as
    subprocesses; yields the scheduler's address."""
    dask = Path(sys.executable).parent / "dask"
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(SRC), os.environ.get("PYTHONPATH", "")])}
    info = tmp_path / "scheduler.json"
    common = ["--no-dashboard"]
    procs = [subprocess.Popen([dask, "scheduler", "--host", "127.0.0.1", "--port", "0", "--scheduler-file", info,
                               *common], env=env, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)]  # fmt: skip
    try:
        deadline = time.monotonic() + 60
        while not info.is_file() and time.monotonic() < deadline:
            time.sleep(0.1)
        procs.append(subprocess.Popen([dask, "worker", "--scheduler-file", info, "--nworkers", "1", "--nthreads", "1",
                                       *common], env=env, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL))
        yield json.loads(info.read_text())["address"]
    finally:
        for proc in reversed(procs):
            proc.terminate()
            proc.wait(timeout=30)


@pytest.mark.slow  # Dask workers are spawned and import spaceid: seconds each
def test_same_numbers_on_every_scheduler(param, dask_cluster, monkeypatch):
    one = study(param)
    _assert_same(one, study(param, jobs=2))
    _assert_same(one, study(param, jobs=2, scheduler="dask"))
    monkeypatch.setenv("DASK_SCHEDULER_ADDRESS", dask_cluster)  # honoured without --scheduler
    remote = study(param)
    assert remote.settings["scheduler"] == dask_cluster
    _assert_same(one, remote)
    # a multi-start design: the same trajectory from the remote worker as in this process
    options = dict(duration=5.0, harmonics=2, samples=35, momentum=H, seed=3, n_starts=2, n_grid=201)
    here = design_excitation(param, **options, jobs=1, scheduler="processes")
    there = design_excitation(param, **options)
    assert there.value == here.value
    assert there.trajectory.to_dict()["a"] == here.trajectory.to_dict()["a"]


def test_a_resumed_campaign_equals_an_uninterrupted_one(param, tmp_path, monkeypatch):
    whole = study(param)

    def interrupt(done, total):
        if done >= 2:
            raise KeyboardInterrupt

    with pytest.raises(KeyboardInterrupt):
        study(param, out=tmp_path, progress=interrupt)
    assert len(list(task_folder(tmp_path).glob("*.pkl"))) == 2  # written as they completed, beside the folder
    chunk, ran = _Study.chunk, []
    monkeypatch.setattr(_Study, "chunk", lambda self, first, states: ran.append(first) or chunk(self, first, states))
    resumed = study(param, out=tmp_path, resume=True)
    assert len(ran) == 6 - 2
    _assert_same(whole, resumed)
    # a rerun without --resume runs every chunk again
    ran.clear()
    study(param, out=tmp_path)
    assert len(ran) == 6


def test_resume_refuses_results_of_other_settings(param, tmp_path):
    study(param, out=tmp_path)
    with pytest.raises(SpaceidError, match="`resume`: .* other settings"):
        study(param, out=tmp_path, resume=True, seed=8)
    with pytest.raises(SpaceidError, match="`resume`: needs the study folder"):
        study(param, resume=True)


def test_scheduler_names_and_seeds():
    assert resolve_scheduler("dask") == "dask" and resolve_scheduler("tcp://10.0.0.1:8786") == "tcp://10.0.0.1:8786"
    with pytest.raises(SpaceidError, match="`scheduler`: 'threads'"):
        resolve_scheduler("threads")
    seeds = task_seeds(5, 4)
    np.testing.assert_array_equal(seeds[:3], task_seeds(5, 3))  # task i's seed depends on (seed, i) alone
    assert len(set(seeds.tolist())) == 4


@pytest.mark.slow  # a Monte Carlo study through the CLI (seconds)
def test_montecarlo_cli_resumes(tmp_path):
    args = ["montecarlo", "cepheus", "--momentum", "0.4934", "--runs", "4", "--estimator", "ols", "--jobs", "1",
            "--scheduler", "processes", "--out", str(tmp_path)]
    first = CliRunner().invoke(app, args, catch_exceptions=False)
    assert first.exit_code == 0
    before = json.loads((tmp_path / "montecarlo.json").read_text())
    again = CliRunner().invoke(app, [*args, "--resume"], catch_exceptions=False)
    assert again.exit_code == 0 and "runs: 4/4" in again.stderr  # the plain progress line, not a terminal
    after = json.loads((tmp_path / "montecarlo.json").read_text())
    assert after["runs"] == before["runs"] and after["settings"]["scheduler"] == "processes"


@pytest.mark.slow
def test_sweep_on_a_small_grid_matches_direct_calls(param, tmp_path):
    result = CliRunner().invoke(app, ["sweep", "cepheus", "--momentum", "0.4934", "--durations", "5", "--harmonics",
                                      "2", "--samples", "30,40", "--starts", "1", "--seed", "4", "--jobs", "1",
                                      "--out", str(tmp_path)], catch_exceptions=False)  # fmt: skip
    assert result.exit_code == 0, result.output
    assert "settings: 2/2" in result.stderr
    rows = json.loads((tmp_path / "sweep.json").read_text())["rows"]
    assert [(r["duration"], r["harmonics"], r["samples"]) for r in rows] == [(5.0, 2, 30), (5.0, 2, 40)]
    assert [r["seed"] for r in rows] == task_seeds(4, 2).tolist()
    bound = whitened_regressor(param, param.true_values, H, DEFAULT_NOISE, relative=False)
    for r in rows:
        q, qd, _ = FourierTrajectory.from_dict(r["trajectory"]).evaluate(sample_times(r["duration"], r["samples"]))
        cond = np.linalg.cond(excitation_regressor(param, param.true_values, H)(q, qd))
        np.testing.assert_allclose(r["cond"], cond, rtol=1e-12)
        np.testing.assert_allclose(r["criterion_value"], cond, rtol=1e-9)  # the design's own criterion: cond
        relative = np.sqrt(np.diag(bound.crb(q, qd))) / np.abs(param.true_values)
        np.testing.assert_allclose(r["crb_relative_worst"], relative.max(), rtol=1e-9)
        assert r["crb_worst_parameter"] == param.names[int(np.argmax(relative))]
    direct = design_excitation(param, duration=5.0, harmonics=2, samples=40, momentum=H, seed=rows[1]["seed"],
                               n_starts=1, jobs=1)  # fmt: skip
    assert direct.value == rows[1]["criterion_value"]
    table = (tmp_path / "table.txt").read_text().splitlines()
    assert max(map(len, table)) <= 80 and any("tf [s]" in line for line in table)
    csv = (tmp_path / "sweep.csv").read_text().splitlines()
    assert csv[0].startswith("duration,harmonics,samples,seed,cond") and len(csv) == 3
    assert (tmp_path / "sweep.png").stat().st_size > 10_000


@pytest.mark.slow  # two designs and a sweep (seconds)
def test_sweep_bounds_each_search_by_max_steps(param, tmp_path):
    """``--max-steps`` reaches every setting's design (the row is the direct design with the same bound, which
    stops short of the unbounded one's) and is recorded; a bad bound is named."""
    from spaceid.studies import run_sweep

    result = CliRunner().invoke(app, ["sweep", "cepheus", "--momentum", "0.4934", "--durations", "5", "--harmonics",
                                      "2", "--samples", "35", "--starts", "1", "--max-steps", "2", "--seed", "4",
                                      "--jobs", "1", "--out", str(tmp_path)], catch_exceptions=False)  # fmt: skip
    assert result.exit_code == 0, result.output
    saved = json.loads((tmp_path / "sweep.json").read_text())
    row = saved["rows"][0]
    assert saved["settings"]["max_steps"] == 2
    design = {"duration": 5.0, "harmonics": 2, "samples": 35, "momentum": H, "seed": row["seed"], "n_starts": 1,
              "jobs": 1}
    assert design_excitation(param, **design, max_steps=2).value == row["criterion_value"]
    assert design_excitation(param, **design).value < row["criterion_value"]
    with pytest.raises(SpaceidError, match="^`max_steps`: 0 is not an integer >= 1"):
        run_sweep(param, momentum=H, durations=[5.0], harmonics=[2], samples=[35], max_steps=0)


def test_design_cli_names_a_bad_scheduler(tmp_path, capsys):
    code = main(["design", "cepheus", "--duration", "5", "--harmonics", "2", "--samples", "35", "--momentum",
                 "0.4934", "--starts", "2", "--scheduler", "threads", "-o", str(tmp_path / "t.json")])  # fmt: skip
    err = capsys.readouterr().err
    assert code == 2 and err.startswith("error: --scheduler: 'threads'") and not (tmp_path / "t.json").exists()


@pytest.mark.slow  # a Monte Carlo study through the CLI (seconds)
def test_a_finished_study_folder_holds_the_report_and_no_task_results(tmp_path):
    """The task results live beside --out only while the study runs: the finished report
    folder is spaceid's (manifest) and nothing is left beside it."""
    out = tmp_path / "mc"
    args = ["montecarlo", "cepheus", "--momentum", "0.4934", "--trajectory", "paper-table2", "--runs", "4",
            "--jobs", "1", "--estimator", "ols", "--out", str(out)]
    assert main(args) == 0
    assert (out / "montecarlo.json").is_file() and (out / "spaceid-manifest.json").is_file()
    assert not task_folder(out).exists() and sorted(p.name for p in tmp_path.iterdir()) == ["mc"]
