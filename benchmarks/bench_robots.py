"""Count the random robots the property tests run, stage by stage, and the failures among them.

Runs every property test over random robots (``TESTS``) with its number of examples scaled by
``--scale`` (``SPACEID_ROBOTS``, ``tests/robot_tally.py``), in ``--chunks`` pytest runs of
hypothesis seeds ``--seed``, ``--seed + 1``, ... (the same arguments draw the same robots, up to
the designs' time budgets), each stage a robot went through appended to ``--tally`` (one JSON
line each). Then prints, from the whole tally (earlier runs into the same file included): test,
stage, robots run (distinct cases; planar/spatial), failures and the seeds of the failed cases.

    nice -n 19 python benchmarks/bench_robots.py --scale 5 --chunks 4 --tally robots.jsonl -k pipeline
    python benchmarks/bench_robots.py --tally robots.jsonl --report

A test that failed outside any stage (an aggregate check, such as the false-alarm rate over a
run's logs) is listed with the stage ``(test)`` and pytest's summary line.
"""

from __future__ import annotations

import argparse
import collections
import json
import os
import re
import subprocess
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
TESTS = [
    "tests/test_spatial.py::test_spatial_regressor_equals_pinocchio_on_random_trees",
    "tests/test_spatial.py::test_planar_regressor_equals_pinocchio_on_random_trees",
    "tests/test_random_robots.py::test_export_without_options",
    "tests/test_random_robots.py::test_export_without_options_on_larger_robots",
    "tests/test_gyro_bias.py::test_noise_free_recovery_any_random_robot",
    "tests/test_random_pipeline.py::test_pipeline_on_random_robots",
    "tests/test_random_pipeline.py::test_pipeline_and_payload_on_more_random_robots",
    "tests/test_monitor_random_robots.py::test_a_grasp_is_found_on_a_random_robot",
    "tests/test_monitor_random_robots.py::test_a_grasp_is_found_on_larger_random_robots",
    "tests/test_monitor_random_robots.py::test_false_alarms_on_random_robots_as_stated",
    "tests/test_mujoco.py::test_momentum_and_regressor_agree_with_mujoco",
    "tests/test_mujoco.py::test_momentum_and_regressor_agree_with_mujoco_on_larger_robots",
    "tests/test_mujoco.py::test_identify_a_random_robot_flown_in_mujoco",
    "tests/test_mujoco.py::test_mjcf_export_flies_in_mujoco_with_the_identified_momentum",
]


def run(tests, scale, chunks, seed, tally: Path):
    """Each of ``tests`` in ``chunks`` pytest runs, appending to ``tally``; prints one line a run."""
    env = {**os.environ, "SPACEID_ROBOTS": str(scale), "SPACEID_ROBOT_TALLY": str(tally.resolve()),
           "PYTHONPATH": os.pathsep.join([str(ROOT / "src"), os.environ.get("PYTHONPATH", "")])}
    for chunk in range(chunks):
        for test in tests:
            start, cpu = time.time(), os.times()
            out = subprocess.run([sys.executable, "-m", "pytest", "-p", "no:cacheprovider", "-m", "", "-x",
                                  f"--hypothesis-seed={seed + chunk}", test], cwd=ROOT, env=env,
                                 capture_output=True, text=True)  # fmt: skip
            used = os.times()
            cpu_s = used.children_user + used.children_system - cpu.children_user - cpu.children_system
            summary = next((line.strip(" =") for line in reversed(out.stdout.splitlines())
                            if re.search(r"\d+ (passed|failed|error|xfailed|skipped)", line)), "no summary")
            print(f"seed {seed + chunk} {test.split('::')[1]}: {summary} ({time.time() - start:.0f} s, "
                  f"{cpu_s:.0f} s CPU)", flush=True)  # fmt: skip
            if out.returncode < 0:  # stopped by a signal: no verdict
                with open(tally, "a") as f:
                    f.write(json.dumps({"test": test, "stage": "(interrupted)", "case": {"hypothesis_seed": seed + chunk},
                                        "failure": f"signal {-out.returncode}"}) + "\n")
            elif out.returncode != 0:
                failed = [line for line in out.stdout.splitlines() if line.startswith(("FAILED", "ERROR"))]
                falsifying = [line for line in out.stdout.splitlines() if "Falsifying" in line or "seed=" in line]
                with open(tally, "a") as f:
                    f.write(json.dumps({"test": test, "stage": "(test)", "case": {"hypothesis_seed": seed + chunk},
                                        "failure": " | ".join(failed + falsifying[:3])[:500] or summary}) + "\n")
                (tally.parent / f"{tally.stem}.{test.split('::')[1]}.{seed + chunk}.log").write_text(out.stdout)


def report(tally: Path):
    """The table of ``tally``: per test and stage, the distinct robots run, failures and their seeds."""
    rows = collections.defaultdict(lambda: {"run": set(), "failed": {}, "planar": set()})
    for line in tally.read_text().splitlines():
        r = json.loads(line)
        if r["stage"] == "(test)" and r["failure"] == "no summary":  # a run stopped by a signal (older tallies)
            r["stage"] = "(interrupted)"
        key = (r["test"].split("::")[-1], r["stage"])
        case = json.dumps(r["case"], sort_keys=True)
        row = rows[key]
        if r["failure"] is None:
            row["run"].add(case)
            if r["case"].get("planar"):
                row["planar"].add(case)
        else:
            row["failed"][case] = r
    robots = collections.defaultdict(set)  # per test, every case that went through at least one stage
    print(f"{'test':<58} {'stage':<30} {'robots':>6} {'planar':>6} {'failed':>6}  seeds of failures")
    for (test, name), row in sorted(rows.items()):
        failed = set(row["failed"]) - row["run"]
        run = row["run"] | failed
        robots[test] |= run if not name.startswith("(") else set()  # "(test)", "(interrupted)": pytest runs, not robots
        seeds = sorted({str(json.loads(c).get("seed", json.loads(c).get("hypothesis_seed"))) for c in failed})
        print(f"{test:<58} {name:<30} {len(run):>6} {len(row['planar'] & run):>6} {len(failed):>6}  "
              f"{', '.join(seeds)}")  # fmt: skip
    print(f"random robots in all (distinct per test, summed over tests): {sum(len(v) for v in robots.values())}")
    for (test, name), row in sorted(rows.items()):
        for case, r in row["failed"].items():
            if case not in row["run"]:
                print(f"  {test} / {name}: {case}\n    {r['failure']}")


def _selects(k: str, test: str) -> bool:
    """``-k`` selects a test by its whole name, or else every test whose node id holds it."""
    names = [t.split("::")[1] for t in TESTS]
    return test.split("::")[1] == k if k in names else k in test


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--scale", type=float, default=1.0, help="factor on every test's examples")
    parser.add_argument("--chunks", type=int, default=1, help="pytest runs of each test, each a hypothesis seed")
    parser.add_argument("--seed", type=int, default=0, help="the first chunk's hypothesis seed")
    parser.add_argument("--tally", type=Path, default=Path("robots.jsonl"), help="the JSON-lines tally (appended)")
    parser.add_argument("-k", action="append", default=[], help="only this test (its name), or those whose node id holds this (repeatable)")
    parser.add_argument("--report", action="store_true", help="only print the table of the tally")
    args = parser.parse_args(argv)
    tests = [t for t in TESTS if not args.k or any(_selects(k, t) for k in args.k)]
    if not args.report:
        run(tests, args.scale, args.chunks, args.seed, args.tally)
    report(args.tally)


if __name__ == "__main__":
    main()
