"""The command line's contract (issue 12): no output over an input or over someone else's files,
report folders written whole or not at all, interrupts that end promptly and stop the workers,
one line for every error, user text never read as terminal markup.

Each test names the command and the line it expects, checks the exit code, that every input is
byte-identical afterwards and that nothing partial (no temporary file or folder) is left behind.
"""

import json
import os
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

import numpy as np
import pytest

import spaceid
from spaceid._atomic import MANIFEST
from spaceid.cli import main
from spaceid.motion import load_trajectory

SRC = Path(spaceid.__file__).parents[1]
ENV = dict(os.environ, PYTHONPATH=str(SRC))
MOMENTUM = "0.4934"


def run(*args):
    return main([str(a) for a in args])


def _snapshot(folder: Path) -> dict:
    """Every file under ``folder`` with its bytes (inputs must come out byte-identical)."""
    return {p.relative_to(folder).as_posix(): p.read_bytes() for p in sorted(folder.rglob("*")) if p.is_file()}


def _temporaries(folder: Path) -> list:
    """Temporary files or folders of spaceid's atomic writes (``.NAME.xxxx.tmp``) under ``folder``."""
    return [p for p in folder.rglob(".*") if p.name.endswith((".tmp", ".old"))]


def _refused(capsys, args, line, folder):
    """``spaceid ARGS`` exits 2 with ``line`` as its one line on stderr, leaving ``folder`` as it was."""
    before = _snapshot(folder)
    assert run(*args) == 2
    err = capsys.readouterr().err.strip()
    assert err == line, err
    assert _snapshot(folder) == before and not _temporaries(folder)


@pytest.fixture(scope="module")
def files(tmp_path_factory):
    """A Cepheus log (paper-table2, 60 samples), its identification and its joint trajectory CSV."""
    d = tmp_path_factory.mktemp("contract")
    assert run("simulate", "cepheus", "--trajectory", "paper-table2", "--momentum", MOMENTUM, "--samples", 60,
               "-o", d / "log.csv") == 0
    assert run("identify", "cepheus", d / "log.csv", "--momentum", MOMENTUM, "-o", d / "result.json") == 0
    load_trajectory("paper-table2").save(d / "traj.json")
    return d


@pytest.fixture
def work(files, tmp_path, monkeypatch):
    """A fresh folder holding copies of the fixture's files; printed lines never wrapped."""
    monkeypatch.setattr(spaceid.cli.out, "width", 10_000)
    monkeypatch.setattr(spaceid.cli.err, "width", 10_000)
    for p in files.iterdir():
        (tmp_path / p.name).write_bytes(p.read_bytes())
    return tmp_path


# --- never over an input ---------------------------------------------------------------------------


@pytest.mark.parametrize("link", ["same", "symlink", "hardlink"])
def test_identify_never_writes_over_its_log(work, capsys, link):
    log = work / "log.csv"
    target = {"same": log, "symlink": work / "link.csv", "hardlink": work / "hard.csv"}[link]
    if link == "symlink":
        target.symlink_to(log)
    elif link == "hardlink":
        os.link(log, target)
    _refused(capsys, ["identify", "cepheus", log, "--momentum", MOMENTUM, "-o", target],
             f"error: -o {target} is the input LOG; choose another output file", work)


def test_simulate_never_writes_over_its_trajectory(work, capsys):
    traj = work / "traj.json"
    _refused(capsys, ["simulate", "cepheus", "--trajectory", traj, "--momentum", MOMENTUM, "--samples", 20,
                      "-o", traj], f"error: -o {traj} is the input --trajectory; choose another output file", work)


def test_predict_never_writes_over_its_joint_trajectory(work, capsys):
    log = work / "log.csv"
    _refused(capsys, ["predict", work / "result.json", log, "--momentum", MOMENTUM, "-o", log],
             f"error: -o {log} is the input TRAJ; choose another output file", work)


def test_model_definitions_never_over_the_model(work, capsys):
    urdf = work / "arm.urdf"
    urdf.write_bytes((Path(__file__).parent / "data" / "planar_arm_fixed.urdf").read_bytes())
    _refused(capsys, ["model", urdf, "--definitions", urdf],
             f"error: --definitions {urdf} is the input MODEL; choose another output file", work)


# --- report folders --------------------------------------------------------------------------------


@pytest.mark.slow  # fast representative: test_experiment_refuses_a_folder_of_the_users_files
def test_validate_refuses_a_folder_of_the_users_files(work, capsys):
    """validate --out DIR, DIR holding the user's log: refused, unless --overwrite (then beside them)."""
    folder = work / "mine"
    folder.mkdir()
    (folder / "log.csv").write_bytes((work / "log.csv").read_bytes())
    args = ["validate", work / "result.json", folder / "log.csv", "--momentum", MOMENTUM, "--out", folder]
    _refused(capsys, args, f"error: --out {folder} holds files spaceid did not write (log.csv): choose another "
             "folder, or pass --overwrite to write beside them", work)
    user = (folder / "log.csv").read_bytes()
    assert run(*args, "--overwrite") == 0
    assert (folder / "log.csv").read_bytes() == user
    manifest = json.loads((folder / MANIFEST).read_text())
    assert manifest["command"] == "spaceid validate"
    assert manifest["files"] == ["metrics.json", "predicted.csv", "report.html"]  # not the user's log; no --png
    assert not _temporaries(work)


def test_validate_replaces_its_own_folder_whole(work):
    """A second validate into the folder of a first: replaced whole (the old files go), complete."""
    folder = work / "v"
    args = ["validate", work / "result.json", work / "log.csv", "--momentum", MOMENTUM, "-o", folder]
    assert run(*args) == 0
    (folder / "stale.txt").write_text("not spaceid's")
    assert run(*args) == 2  # a file spaceid did not write appeared: refused
    (folder / "stale.txt").unlink()
    first = _snapshot(folder)
    assert run(*args) == 0
    assert sorted(_snapshot(folder)) == sorted(first) and not _temporaries(work)


# fast representatives: test_identify_never_writes_over_its_log, test_validate_replaces_its_own_folder_whole
@pytest.mark.slow
def test_validate_refuses_to_replace_a_folder_holding_its_input(work, capsys):
    folder = work / "v"
    args = ["validate", work / "result.json", work / "log.csv", "--momentum", MOMENTUM, "-o", folder]
    assert run(*args) == 0
    capsys.readouterr()
    log = folder / "predicted.csv"
    _refused(capsys, ["validate", work / "result.json", log, "--momentum", MOMENTUM, "--out", folder],
             f"error: --out {folder} holds the input LOG ({log}), which the new report would replace: choose another "
             "folder", work)


def test_experiment_refuses_a_folder_of_the_users_files(work, capsys):
    folder = work / "exp"
    folder.mkdir()
    for name in ("log.csv", "result.json"):
        (folder / name).write_bytes((work / name).read_bytes())
    _refused(capsys, ["experiment", "--out", folder], f"error: --out {folder} holds files spaceid did not write "
             "(log.csv, result.json): choose another folder, or pass --overwrite to write beside them", work)


@pytest.mark.parametrize("command", ["validate", "demo", "experiment", "montecarlo"])
def test_an_output_folder_that_is_a_file_is_refused_before_work(work, capsys, monkeypatch, command):
    """montecarlo --out FILE was refused only after the whole study had run."""
    import spaceid.studies

    for name in ("run_demo", "run_experiment", "run_montecarlo", "validate"):
        monkeypatch.setattr(spaceid.studies, name, lambda *a, **k: pytest.fail("the work started"))
    path = work / "taken"
    path.write_text("a user's file\n")
    option = "--out"
    args = {"validate": ["validate", work / "result.json", work / "log.csv", "--momentum", MOMENTUM],
            "demo": ["demo"], "experiment": ["experiment"],
            "montecarlo": ["montecarlo", "cepheus", "--momentum", MOMENTUM, "--runs", 4]}[command]
    _refused(capsys, [*args, option, path], f"error: {option} {path} is an existing file: give a folder name", work)


@pytest.mark.parametrize("command", ["design", "validate", "experiment"])
def test_an_output_under_an_existing_file_is_one_line(work, capsys, command):
    """-o taken/x.json or --out taken/report, where 'taken' is a file: one line before the work."""
    taken = work / "taken"
    taken.write_text("a user's file\n")
    target = taken / ("x.json" if command == "design" else "report")
    args = {"design": ["design", "cepheus", "--duration", 2, "--harmonics", 1, "--samples", 10, "--momentum",
                       MOMENTUM],
            "validate": ["validate", work / "result.json", work / "log.csv", "--momentum", MOMENTUM],
            "experiment": ["experiment"]}[command]
    option = "-o" if command == "design" else "--out"
    _refused(capsys, [*args, option, target], f"error: {option} {target}: cannot write into {taken} (not a writable "
             "folder): choose another place", work)


@pytest.mark.skipif(os.geteuid() == 0, reason="root writes into read-only folders")
@pytest.mark.parametrize("command", ["design", "validate"])
def test_a_read_only_output_folder_is_one_line(work, capsys, command):
    ro = work / "ro"
    ro.mkdir()
    ro.chmod(0o555)
    try:
        if command == "design":
            args = ["design", "cepheus", "--duration", 2, "--harmonics", 1, "--samples", 10, "--momentum", MOMENTUM,
                    "-o", ro / "x.json"]
            line = f"error: -o {ro / 'x.json'}: cannot write into {ro} (not a writable folder): choose another place"
        else:
            args = ["validate", work / "result.json", work / "log.csv", "--momentum", MOMENTUM, "--out", ro]
            line = f"error: --out {ro} is a read-only folder: choose another folder"
        _refused(capsys, args, line, work)
    finally:
        ro.chmod(0o755)


# fast representatives: test_atomic_folder_interrupted_leaves_the_old_state,
# test_identify_interrupted_writes_nothing
@pytest.mark.slow
@pytest.mark.parametrize("failure, code, line", [(spaceid.SpaceidError("plot failed"), 2, "error: plot failed"),
                                                 (KeyboardInterrupt(), 130, "interrupted")])
def test_a_failed_or_interrupted_run_leaves_the_old_folder(work, capsys, monkeypatch, failure, code, line):
    """validate failing or interrupted while its report is written: the earlier report stays as
    it was, no temporary left."""
    import spaceid.studies

    folder = work / "v"
    args = ["validate", work / "result.json", work / "log.csv", "--momentum", MOMENTUM, "-o", folder, "--png"]
    assert run(*args) == 0
    before = _snapshot(folder)

    def fail(log, predicted, path, **k):  # the PNG (--png) fails half written
        Path(path).write_bytes(b"half a figure")
        raise failure

    monkeypatch.setattr(spaceid.studies, "plot_validation", fail)
    capsys.readouterr()
    assert run(*args) == code
    assert capsys.readouterr().err.strip().splitlines()[-1] == line
    assert _snapshot(folder) == before and not _temporaries(work)


@pytest.mark.parametrize("signum", [signal.SIGINT, signal.SIGTERM])
def test_identify_interrupted_writes_nothing(work, capsys, monkeypatch, signum):
    """A signal during identify: 'interrupted', exit 130 (SIGINT) / 143 (SIGTERM), no result file."""
    import spaceid.estimation

    def interrupted(*a, **k):
        signal.raise_signal(signum)  # to this thread: os.kill may hand it to another (a pool's), late
        time.sleep(5)  # the signal arrives before this ends
        pytest.fail(f"the signal did not interrupt (handler {signal.getsignal(signum)!r}, thread "
                    f"{threading.current_thread().name})")

    monkeypatch.setattr(spaceid.estimation, "identify", interrupted)
    before = _snapshot(work)
    # as a terminal's command has it: a shell's background job (CI run with &) starts with SIGINT ignored
    previous = signal.signal(signal.SIGINT, signal.default_int_handler)
    try:
        code = run("identify", "cepheus", work / "log.csv", "--momentum", MOMENTUM, "-o", work / "r.json")
    finally:
        signal.signal(signal.SIGINT, previous)
    assert code == 128 + signum
    assert capsys.readouterr().err.strip() == "interrupted"
    assert _snapshot(work) == before and not _temporaries(work)


# --- errors ------------------------------------------------------------------------------------------


def test_an_internal_error_is_one_line_and_exit_1(work, capsys, monkeypatch):
    import spaceid.estimation

    def bug(*a, **k):
        raise RuntimeError("boom")

    monkeypatch.setattr(spaceid.estimation, "identify", bug)
    args = ["identify", "cepheus", work / "log.csv", "--momentum", MOMENTUM, "-o", work / "r.json"]
    before = _snapshot(work)
    assert run(*args) == 1
    err = capsys.readouterr().err.strip()
    assert err == (f"internal error: RuntimeError: boom (please report this at {spaceid.cli.ISSUES}; rerun with "
                   "--debug for the traceback)")
    assert run("--debug", *args) == 1
    err = capsys.readouterr().err
    assert "Traceback (most recent call last)" in err and err.strip().endswith("for the traceback)")
    assert _snapshot(work) == before


def test_a_numerical_failure_names_the_log(work, capsys, monkeypatch):
    """identify: a Cholesky failure on an ill-conditioned log (here in the covariance) is an
    error naming the log, exit 2."""
    import spaceid.estimation._identify as module

    def cholesky_fails(*a, **k):
        return np.linalg.cholesky(-np.eye(2))

    monkeypatch.setattr(module, "_full_covariance", cholesky_fails)
    log = work / "log.csv"
    _refused(capsys, ["identify", "cepheus", log, "--momentum", MOMENTUM, "-o", work / "r.json"],
             f"error: {log}: estimator 'ml' met a singular or non-finite linear system (Matrix is not positive "
             "definite): check the log for NaN or frozen signals and use an exciting trajectory (spaceid design), or "
             "try --estimator ols", work)


def test_any_numerical_failure_names_the_inputs(work, capsys, monkeypatch):
    """validate: a LinAlgError from any step is an error naming the command's inputs, exit 2."""
    import spaceid.studies

    def singular(*a, **k):
        return np.linalg.solve(np.zeros((2, 2)), np.ones(2))

    monkeypatch.setattr(spaceid.studies, "validate", singular)
    result, log = work / "result.json", work / "log.csv"
    _refused(capsys, ["validate", result, log, "--momentum", MOMENTUM, "--out", work / "v"],
             f"error: numerical failure on RESULT.json|MODEL {result}, LOG {log} (Singular matrix): the data are too "
             "ill-conditioned for this computation: check their excitation, noise and units", work)


# --- markup and odd names ---------------------------------------------------------------------------


def test_file_names_are_never_markup(work, capsys):
    """identify with a log in a folder 'a[' (the file 'a[/b].csv') and -o '[red]x.json': echoed as given."""
    (work / "a[").mkdir()
    log = work / "a[" / "b].csv"
    log.write_bytes((work / "log.csv").read_bytes())
    out = work / "[red]x.json"
    assert run("identify", "cepheus", log, "--momentum", MOMENTUM, "-o", out) == 0
    assert f"result written to {out}" in capsys.readouterr().out
    assert json.loads(out.read_text())["parameters"]


def test_joint_names_are_never_markup(work, capsys):
    """spaceid model of a URDF whose joint is '[bold]j[/]' and a link '[red]tip': the table shows them as named."""
    text = (Path(__file__).parent / "data" / "planar_arm_fixed.urdf").read_text()
    urdf = work / "odd.urdf"
    urdf.write_text(text.replace('"elbow"', '"[bold]j[/]"').replace('"link2"', '"[red]tip"'))
    assert run("model", urdf, "--all") == 0
    printed = capsys.readouterr().out
    assert "[bold]j[/]" in printed and "[red]tip" in printed


def test_an_output_name_with_a_newline_or_emoji_is_echoed_repr_safe(work, capsys):
    out = work / "r\n\U0001f600.json"
    assert run("identify", "cepheus", work / "log.csv", "--momentum", MOMENTUM, "-o", out) == 0
    printed = capsys.readouterr().out
    assert f"result written to {ascii(str(out))}" in printed and "\U0001f600" not in printed
    assert out.exists()


def test_error_lines_stay_one_line(work, capsys):
    log = work / "no\nsuch.csv"
    assert run("identify", "cepheus", log, "--momentum", MOMENTUM, "-o", work / "r.json") == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and err.startswith("error: ") and "no\\nsuch.csv" in err


# --- interrupts and concurrency (real processes) ----------------------------------------------------


def _children(pid: int) -> list:
    """PIDs of the live processes whose parent is ``pid`` (from /proc)."""
    found = []
    for entry in os.listdir("/proc"):
        if entry.isdigit():
            try:
                fields = Path(f"/proc/{entry}/stat").read_text().rsplit(")", 1)[1].split()
            except OSError:
                continue
            if int(fields[1]) == pid and fields[0] != "Z":
                found.append(int(entry))
    return found


def _alive(pid: int) -> bool:
    try:
        return Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0] != "Z"
    except OSError:
        return False


INTERRUPTED = {
    "montecarlo": ["montecarlo", "cepheus", "--momentum", MOMENTUM, "--runs", "5000", "--jobs", "2", "--out", "mc"],
    "design": ["design", "cepheus", "--duration", "5", "--harmonics", "3", "--samples", "35", "--momentum", MOMENTUM,
               "--starts", "2000", "-o", "traj.json"],
    "experiment": ["experiment", "--out", "exp"],
}


@pytest.mark.slow
@pytest.mark.skipif(not Path("/proc/self/stat").exists(), reason="reads worker PIDs from /proc")
@pytest.mark.parametrize("command, signum", [("montecarlo", signal.SIGINT), ("montecarlo", signal.SIGTERM),
                                             ("design", signal.SIGTERM), ("experiment", signal.SIGINT)])
def test_an_interrupt_ends_the_command_and_its_workers(tmp_path, command, signum):
    """Ctrl-C (SIGINT to the process group) or SIGTERM once the two workers run: the line
    'interrupted', exit 130 / 143, no worker left, no output and no temporary file."""
    # SIGINT as a terminal's command has it: a shell's background job (CI run with &) ignores it, and so would the
    # child it hands that on to (Python then installs no KeyboardInterrupt handler)
    proc = subprocess.Popen([sys.executable, "-m", "spaceid.cli", *INTERRUPTED[command]], cwd=tmp_path, env=ENV,
                            stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True, start_new_session=True,
                            preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL))
    try:
        deadline = time.monotonic() + 300
        while len(_children(proc.pid)) < 2 and proc.poll() is None and time.monotonic() < deadline:
            time.sleep(0.05)
        workers = _children(proc.pid)
        assert len(workers) >= 2, f"no workers started ({proc.poll()})"
        if signum == signal.SIGINT:
            os.killpg(proc.pid, signum)
        else:
            proc.send_signal(signum)
        _, err = proc.communicate(timeout=60)
    finally:
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGKILL)
    assert proc.returncode == 128 + signum, err
    assert err.strip().splitlines()[-1] == "interrupted", err
    deadline = time.monotonic() + 10
    while any(_alive(w) for w in workers) and time.monotonic() < deadline:
        time.sleep(0.05)
    assert not [w for w in workers if _alive(w)]
    assert list(tmp_path.iterdir()) == []  # no output, no temporary file or folder


@pytest.mark.slow
def test_concurrent_runs_into_one_folder_never_corrupt_it(files, tmp_path):
    """Three validate runs into one report folder and three identify runs into one result file, at
    once: every run succeeds, the folder holds one complete report, the file one whole result."""
    validate = [sys.executable, "-m", "spaceid.cli", "validate", str(files / "result.json"), str(files / "log.csv"),
                "--momentum", MOMENTUM, "-o", str(tmp_path / "report")]
    identify = [sys.executable, "-m", "spaceid.cli", "identify", "cepheus", str(files / "log.csv"), "--momentum",
                MOMENTUM, "-o", str(tmp_path / "result.json")]
    inputs = _snapshot(files)
    procs = [subprocess.Popen(c, env=ENV, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
             for c in [validate] * 3 + [identify] * 3]
    errors = [p.communicate(timeout=600)[1] for p in procs]
    assert [p.returncode for p in procs] == [0] * 6, errors
    manifest = json.loads((tmp_path / "report" / MANIFEST).read_text())
    assert sorted(_snapshot(tmp_path / "report")) == sorted(manifest["files"] + [MANIFEST])
    assert json.loads((tmp_path / "report" / "metrics.json").read_text())
    assert json.loads((tmp_path / "result.json").read_text())["parameters"]
    assert sorted(p.name for p in tmp_path.iterdir()) == ["report", "result.html", "result.json"]  # no temporaries
    assert _snapshot(files) == inputs


# --- the atomic report folder itself -------------------------------------------------------------------


def _report(folder, files, **options):
    from spaceid._atomic import atomic_folder

    with atomic_folder(folder, command="test", **options) as tmp:
        for name, text in files.items():
            (tmp / name).parent.mkdir(parents=True, exist_ok=True)
            (tmp / name).write_text(text)


@pytest.mark.parametrize("exchange", [True, False], ids=["renameat2", "two renames"])
def test_atomic_folder_replaces_its_own_folder_whole(tmp_path, monkeypatch, exchange):
    import spaceid._atomic

    if not exchange:
        monkeypatch.setattr(spaceid._atomic, "_exchange", lambda a, b: False)
    folder = tmp_path / "r"
    _report(folder, {"a.txt": "1", "sub/b.txt": "2"})
    _report(folder, {"a.txt": "3"})
    assert _snapshot(folder) == {"a.txt": b"3", MANIFEST: (folder / MANIFEST).read_bytes()}
    assert json.loads((folder / MANIFEST).read_text()) == {"written_by": "spaceid", "command": "test",
                                                           "files": ["a.txt"]}
    assert sorted(p.name for p in tmp_path.iterdir()) == ["r"]


def test_atomic_folder_beside_the_users_files(tmp_path):
    """overwrite: new files replace their namesakes, the user's stay, the manifest lists spaceid's."""
    folder = tmp_path / "r"
    folder.mkdir()
    (folder / "mine.csv").write_text("user")
    (folder / "a.txt").write_text("old")
    _report(folder, {"a.txt": "new", "b.txt": "b"}, overwrite=True)
    assert (folder / "mine.csv").read_text() == "user" and (folder / "a.txt").read_text() == "new"
    assert json.loads((folder / MANIFEST).read_text())["files"] == ["a.txt", "b.txt"]
    with pytest.raises(spaceid.SpaceidError, match=r"mine\.csv is the input LOG; choose another folder"):
        _report(folder, {"mine.csv": "x"}, overwrite=True, inputs=[("LOG", folder / "mine.csv")])
    assert (folder / "mine.csv").read_text() == "user"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["r"]


def test_atomic_folder_interrupted_leaves_the_old_state(tmp_path):
    folder = tmp_path / "r"
    _report(folder, {"a.txt": "1"})
    before = _snapshot(folder)
    from spaceid._atomic import atomic_folder

    with pytest.raises(KeyboardInterrupt), atomic_folder(folder, command="test") as tmp:
        (tmp / "a.txt").write_text("2")
        raise KeyboardInterrupt
    assert _snapshot(folder) == before and sorted(p.name for p in tmp_path.iterdir()) == ["r"]
