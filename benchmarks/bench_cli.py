"""Wall time and peak memory of every CLI command on the presets, cold and warm, against an older version.

Each run is a fresh child process (``python -m spaceid.cli COMMAND ...``): its wall time, its CPU
time (user + system: steadier than the wall time on a loaded machine) and its peak resident memory
(``ru_maxrss`` of that child alone, from ``os.wait4``). "Cold" is a first run: a fresh, empty
``NUMBA_CACHE_DIR`` (no compiled kernel) and ``SPACEID_CACHE_DIR`` (no minimal parameter set) for
that one command; "warm" runs the same command again on the caches the cold run left; "installed" is
a first run after the install step: on a copy of the caches that ``spaceid demo`` left on empty ones
(run once per tree, first; that demo is not in the table). The
bytecode of both source trees is compiled first (``pip`` does that at install), so it counts in
neither.

``--baseline REF`` checks out the git ref REF (default: the parent of the first commit whose
message names issue 29, the issue this benchmark was written for) into a temporary git worktree
and runs every command with ``PYTHONPATH=<that worktree>/src`` in the same interpreter, alternated
with this tree's run (now cold, baseline cold, now warm, baseline warm; the baseline first on every other
command), on the same input files (written by this tree's runs). ``--no-baseline`` skips it.

Per preset the commands run in pipeline order, each later one on the files of the earlier ones:
``--help`` and ``model``; ``design`` (a 3 s time budget, which its cell shows apart: the time besides its
search) writes the trajectory of the spatial
presets (Cepheus's commands use the paper's ``paper-table2``), ``simulate`` the noisy log,
``identify`` (``ols`` and ``ml``) the results; then ``validate`` and ``predict`` (of the ``ols``
result for Cepheus, of the preset model as it is for the spatial robots, whose estimates from these
short logs are not physical: their base rate would diverge), ``compare``, ``export``, ``payload``,
``monitor``, a small ``montecarlo``, ``sweep``, ``experiment`` (Cepheus only unless
``--spatial-experiment``: the twin of a spatial robot takes minutes) and ``demo`` (Cepheus only: it
takes no model). The ``ros`` commands are left out. Prints one Markdown table (command x preset),
and writes it to ``--markdown FILE`` when given. Prints only: it never fails on timings.

    python benchmarks/bench_cli.py [--presets cepheus satellite-7dof servicer-dual]
        [--commands model identify-ols ...] [--states cold warm installed] [--samples 500]
        [--baseline REF | --no-baseline] [--spatial-experiment] [--markdown FILE] [--keep DIR]
"""

import argparse
import json
import os
import shutil
import signal
import subprocess
import sys
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
PRESETS = ("cepheus", "satellite-7dof", "servicer-dual")
MOMENTUM = {"cepheus": "0.4934", "satellite-7dof": "0.1,-0.2,0.3", "servicer-dual": "0.1,-0.2,0.3"}
PAYLOAD_LINK = {"cepheus": "link2", "satellite-7dof": "arm_link7", "servicer-dual": "left_link7"}
NOISE = ["--noise-angle", "1e-4", "--noise-rate", "1e-4"]
DESIGN = {"cepheus": ("5", "3", "35"), "satellite-7dof": ("30", "6", "120"), "servicer-dual": ("120", "12", "400")}
"""Duration [s], harmonics and samples of the designs (``bench_design_spatial.py``'s settings: fewer
leave the spatial regressors rank deficient)."""


def command_lines(preset: str, samples: int, spatial_experiment: bool = False) -> dict:
    """The argument lists of the commands on ``preset``, by label, in pipeline order (files are
    relative to the run's working folder, the earlier commands' outputs)."""
    h = ["--momentum", MOMENTUM[preset]]
    spatial = preset != "cepheus"
    traj = "traj.json" if spatial else "paper-table2"
    resimulated = preset if spatial else "ols.json"  # a short spatial log's estimate is not physical: the model
    duration, harmonics, points = DESIGN[preset]
    design = ["design", preset, "--duration", duration, "--harmonics", harmonics, "--samples", points, "--time-budget",
              "3", "--starts", "1", "--jobs", "1", *h, "-o", "traj.json"]
    lines = {
        "--help": ["--help"],
        "model": ["model", preset],
        "design": design,
        "simulate": ["simulate", preset, "--trajectory", traj, *h, "--samples", str(samples), *NOISE, "--seed", "1",
                     "-o", "log.csv"],
        "identify-ols": ["identify", preset, "log.csv", *h, "--estimator", "ols", *NOISE, "-o", "ols.json"],
        "identify-ml": ["identify", preset, "log.csv", *h, "--estimator", "ml", *NOISE, "-o", "ml.json"],
        "validate": ["validate", resimulated, "log.csv", *h, "--out", "validate", "--overwrite"],
        "predict": ["predict", resimulated, traj, *h, "--samples", str(samples), "-o", "predicted.csv"],
        "compare": ["compare", "ols.json", "ml.json"],
        "export": ["export", "ml.json", "--prior", preset, "-o", "exported.urdf"],
        "payload": ["payload", preset, "log.csv", "--link", PAYLOAD_LINK[preset], *h, *NOISE, "-o", "payload.json"],
        "monitor": ["monitor", preset, "log.csv", *h, *NOISE, "-o", "events.json"],
        "montecarlo": ["montecarlo", preset, "--trajectory", traj, "--samples", "200", "--runs", "4", "--jobs", "1",
                       "--estimator", "ols", *h, "--out", "montecarlo", "--overwrite"],
        "sweep": ["sweep", preset, *h, "--durations", duration, "--harmonics", harmonics, "--samples", points,
                  "--starts", "1", "--jobs", "1", "--out", "sweep", "--overwrite"],
        "experiment": ["experiment", preset, "--samples", "200", "--estimator", "ols", "--out", "experiment",
                       "--overwrite"] + (["--duration", duration, "--time-budget", "3"] if spatial else []),
        "demo": ["demo", "--out", "demo", "--overwrite"],
    }
    if spatial:
        del lines["demo"]  # the demo is Cepheus's
        if not spatial_experiment:
            del lines["experiment"]  # minutes: the twin of a spatial robot
    return lines


@dataclass
class Run:
    wall: float
    cpu: float
    rss_mb: float
    code: int
    search: float | None = None
    """``design``: the wall time of its search (the trajectory's ``meta.wall_time``), which ``--time-budget`` bounds;
    the rest of ``wall`` is the command's own cost (import, compilation, set-up, writing)."""


def run_child(argv, src: Path, cwd: Path, caches: Path) -> Run:
    """One CLI command in a fresh interpreter on the sources ``src`` with the caches under ``caches``."""
    env = dict(os.environ, PYTHONPATH=str(src), NUMBA_CACHE_DIR=str(caches / "numba"),
               SPACEID_CACHE_DIR=str(caches / "spaceid"), PYTHONDONTWRITEBYTECODE="1")  # fmt: skip
    start = time.perf_counter()
    proc = subprocess.Popen([sys.executable, "-m", "spaceid.cli", *argv], cwd=cwd, env=env,
                            stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)  # fmt: skip
    err = proc.stderr.read()
    _, status, usage = os.wait4(proc.pid, 0)
    wall = time.perf_counter() - start
    proc.returncode = os.waitstatus_to_exitcode(status)
    if proc.returncode != 0:
        print(f"  {' '.join(argv[:2])}: exit {proc.returncode}: {err.decode(errors='replace').strip()[-300:]}",
              file=sys.stderr)  # fmt: skip
    return Run(wall, usage.ru_utime + usage.ru_stime, usage.ru_maxrss / 1024, proc.returncode)


def default_baseline() -> str:
    """The parent of the first commit whose message names issue 29."""
    first = subprocess.run(["git", "log", "--reverse", "--format=%H", "--grep=issue 29"], cwd=ROOT,
                           capture_output=True, text=True, check=True).stdout.split()  # fmt: skip
    if not first:
        raise SystemExit("no commit names issue 29: give --baseline REF or --no-baseline")
    return first[0] + "^"


def _short(ref: str) -> str:
    out = subprocess.run(["git", "rev-parse", "--short", ref], check=True, cwd=ROOT, capture_output=True, text=True)
    return out.stdout.strip()


def checkout(ref: str, folder: Path) -> Path:
    """A detached git worktree of ``ref`` in ``folder``: its ``src``."""
    subprocess.run(["git", "worktree", "add", "--detach", "-q", str(folder), ref], cwd=ROOT, check=True)
    return folder / "src"


def installed_caches(trees: dict, work: Path) -> dict:
    """Per tree, the caches that ``spaceid demo`` (the install step) leaves on empty ones: a folder to copy."""
    out = {}
    for tree, src in trees.items():
        out[tree] = work / "installed" / tree
        shutil.rmtree(out[tree], ignore_errors=True)
        (work / "installed" / f"{tree}-demo").mkdir(parents=True, exist_ok=True)
        run = run_child(["demo", "--out", "report", "--overwrite"], src, work / "installed" / f"{tree}-demo", out[tree])
        print(f"install step (spaceid demo on empty caches), {tree}: {run.wall:6.2f} s wall, {run.cpu:6.2f} s CPU",
              flush=True)
    return out


def measure(presets, commands, states, samples, trees: dict, work: Path, spatial_experiment=False,
            progress=None) -> dict:
    """``{(preset, label): {(tree, state): Run}}``, the trees' runs alternated; ``progress(results)``
    is called after each command (the table so far)."""
    results = {}
    installed = installed_caches(trees, work) if "installed" in states else {}
    for preset in presets:
        folder = work / preset
        for index, (label, argv) in enumerate(command_lines(preset, samples, spatial_experiment).items()):
            if commands and label not in commands:
                continue
            cells = results.setdefault((preset, label), {})
            for tree in trees:
                shutil.rmtree(work / "caches" / tree, ignore_errors=True)
            # which tree runs first alternates, command by command: the first run of a preset's command paid its
            # files' first reads (the servicer's `model`: 1.43 against 1.07 s for the same code, 1.18 / 1.22 against
            # 1.17 / 1.14 s by hand, alternating)
            order = list(trees.items())[:: -1 if index % 2 else 1]
            for state in states:
                for tree, src in order:
                    cwd = folder if tree == "now" else folder / tree  # the baseline writes its own outputs
                    cwd.mkdir(parents=True, exist_ok=True)
                    if tree != "now":  # but reads this tree's inputs
                        for name in ("traj.json", "log.csv", "ols.json", "ml.json"):
                            if (folder / name).exists():
                                shutil.copy(folder / name, cwd / name)
                    caches = work / "caches" / tree
                    if state in ("cold", "installed"):
                        shutil.rmtree(caches, ignore_errors=True)
                    if state == "installed":
                        shutil.copytree(installed[tree], caches)
                    cells[tree, state] = run = run_child(argv, src, cwd, caches)
                    if label == "design" and run.code == 0:
                        run.search = json.loads((cwd / "traj.json").read_text())["meta"]["wall_time"]
                    print(f"{preset:15s} {label:13s} {tree:8s} {state}: {run.wall:6.2f} s wall, {run.cpu:6.2f} s CPU,"
                          f" {run.rss_mb:5.0f} MB{'' if run.code == 0 else f' (exit {run.code})'}", flush=True)
            if progress:
                progress(results)
    return results


def _figure(run: Run | None) -> str:
    if run is None:
        return "-"
    search = "" if run.search is None else f" ({run.wall - run.search:.2f} s besides the search)"
    return f"{run.wall:.2f} / {run.cpu:.2f} s, {run.rss_mb:.0f} MB{search}" + ("" if run.code == 0 else
                                                                           f" (exit {run.code})")


def _ratio(now: Run | None, base: Run | None) -> str:
    if not (now and base and base.wall > 0 and base.cpu > 0):
        return "-"
    return f"{now.wall / base.wall:.2f} / {now.cpu / base.cpu:.2f}, {now.rss_mb / base.rss_mb:.2f}"


def table(results: dict, states, baseline: str | None) -> str:
    """The Markdown table: a row a command and preset, per state this tree's wall and CPU time and
    peak memory, the baseline's, and their ratios (now / baseline)."""
    head = ["Command", "Preset"]
    for state in states:
        head += [f"{state}: now", f"{state}: {baseline}", f"{state}: ratio"] if baseline else [f"{state}"]
    lines = ["| " + " | ".join(head) + " |", "|" + " --- |" * len(head)]
    for (preset, label), cells in results.items():
        row = [f"`{label}`", preset]
        for state in states:
            now, base = cells.get(("now", state)), cells.get(("base", state))
            row += [_figure(now), _figure(base), _ratio(now, base)] if baseline else [_figure(now)]
        lines.append("| " + " | ".join(row) + " |")
    return "\n".join(lines)


def main():
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--presets", nargs="+", default=list(PRESETS), choices=PRESETS)
    parser.add_argument("--commands", nargs="+", help="labels of the table's first column (default: all); the "
                        "inputs they read must exist, so keep the ones before them or use --keep")
    parser.add_argument("--states", nargs="+", default=["cold", "warm"], choices=["cold", "warm", "installed"])
    parser.add_argument("--samples", type=int, default=500, help="samples of the simulated log and the prediction")
    parser.add_argument("--baseline", help="git ref of the older version (default: the parent of the first commit "
                        "that names issue 29)")
    parser.add_argument("--no-baseline", action="store_true", help="only this tree")
    parser.add_argument("--spatial-experiment", action="store_true", help="also run 'experiment' on the spatial "
                        "presets (minutes each)")
    parser.add_argument("--markdown", type=Path, help="also write the table to this file")
    parser.add_argument("--keep", type=Path, help="work in this folder and keep it (default: a temporary one)")
    args = parser.parse_args()
    signal.signal(signal.SIGTERM, lambda *_: sys.exit(143))  # unwind: the baseline's worktree is removed
    work = args.keep or Path(tempfile.mkdtemp(prefix="bench_cli_"))
    work.mkdir(parents=True, exist_ok=True)
    trees = {"now": ROOT / "src"}
    baseline = None if args.no_baseline else (args.baseline or default_baseline())
    try:
        if baseline:
            trees["base"] = checkout(baseline, work / "baseline")
        for src in trees.values():
            subprocess.run([sys.executable, "-m", "compileall", "-q", str(src)], check=True)
        load = os.getloadavg()[0]

        def progress(results):  # the table so far, for a run cut short
            if args.markdown:
                args.markdown.write_text(table(results, args.states, baseline) + "\n(unfinished run)\n")

        results = measure(args.presets, args.commands, args.states, args.samples, trees, work, args.spatial_experiment,
                          progress)
        text = table(results, args.states, baseline)
        note = (f"\nnow: {_short('HEAD')} and its uncommitted changes"
                + (f", baseline: {_short(baseline)}" if baseline else "")
                + f"; 1-minute load {load:.1f} at the start, {os.getloadavg()[0]:.1f} at the end; each cell: wall / "
                "CPU time (user + system) and peak resident memory of the child process; ratios: now / baseline")
        print("\n" + text + "\n" + note)
        if args.markdown:
            args.markdown.write_text(text + "\n" + note + "\n")
    finally:
        if baseline and (work / "baseline").exists():
            subprocess.run(["git", "worktree", "remove", "--force", str(work / "baseline")], check=False, cwd=ROOT)
        if not args.keep:
            shutil.rmtree(work, ignore_errors=True)


if __name__ == "__main__":
    main()
