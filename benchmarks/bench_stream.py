"""Streaming identification and the fixed costs of a call, measured in one run.

Streaming: ``identify(..., chunk=N)`` on servicer-dual logs (14 joints, 496 parameters) of
random joint states whose base rate conserves h = [1, -2, 3] N m s, with 1e-3 noise on every
signal, for ``ols`` and ``ml`` at 10^4, 10^5 (and, given, 10^6) samples, and in memory up to
``--memory-up-to`` samples: wall and CPU time per sample (the CPU time of the process, all its
threads: less sensitive than the wall time to the load of a shared machine), and the peak
memory of the process (its maximum resident set size, ``resource.getrusage``), each case in a
fresh process that synthesizes its log in memory first (the log, 36 floats a sample, counts in
the peak; the resident size after the synthesis is printed too). Fixed costs: the minimal-set
derivation against a read of its on-disk cache; the Gram product ``A^T A`` of 10,000 servicer
samples (30,000 x 496) with BLAS on 2 threads and on 1, and through the blockwise accumulation
the estimators use (2 Python threads over one-threaded BLAS, and 1); the imports of ``spaceid
identify`` (matplotlib or not). Log CSVs (``--parts csv``): the same logs written with
``write_log`` and identified by ``spaceid identify LOG.csv --chunk N`` in a child process each
(the CSV read in blocks, then streamed): peak RSS and CPU time of that process, read included.
Reading (``--parts read``): ``read_log`` of one such CSV with this source tree and, with
``--baseline``, the other one, alternated: CPU time, rows per second, peak RSS. Prints only,
never fails on timings.

With ``--baseline SRC`` every case also runs on another checkout's sources (e.g. the commit before
a change), alternated with this one's, ``--repeats`` times (the medians are printed).

    python benchmarks/bench_stream.py [--samples 10000 100000 1000000] [--estimators ols ml]
        [--chunk 4096] [--memory-up-to 10000] [--parts stream fixed csv read] [--csv-dir DIR]
        [--read-samples 200000] [--repeats 3] [--baseline SRC]
"""

import argparse
import itertools
import json
import os
import resource
import subprocess
import sys
import tempfile
import time
import warnings

import numpy as np
from bench_regressor import median_time  # the benchmarks' folder is on the path when run as a script


def servicer_log(n):
    """The servicer-dual problem and a log of ``n`` random joint states whose base rate conserves
    h = [1, -2, 3] N m s, with 1e-3 noise on every signal: (param, h, log)."""
    import spaceid
    from spaceid.data import Log
    from spaceid.dynamics import base_rate
    from spaceid.dynamics._regressor import _random_states

    model = spaceid.load_model("servicer-dual")
    param = spaceid.minimal_parameters(model)
    h = np.array([1.0, -2.0, 3.0])
    q, qd, _ = _random_states(model, n, seed=1)
    w = np.concatenate([base_rate(param, param.true_values, q[s : s + 10_000], qd[s : s + 10_000], h)
                        for s in range(0, n, 10_000)])  # fmt: skip
    rng = np.random.default_rng(2)
    q, qd, w = (a + 1e-3 * rng.standard_normal(a.shape) for a in (q, qd, w))
    return param, h, Log(np.arange(n) * 1e-3, model.joints, q, qd, np.tile([1.0, 0, 0, 0], (n, 1)), w, False)


def child(n, estimator, chunk):
    """One identification in this process; prints its figures as JSON."""
    from spaceid.estimation import Noise, identify

    param, h, log = servicer_log(n)
    rss_log = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
    cpu = time.process_time()
    start = time.perf_counter()
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        result = identify(param, log, h, estimator=estimator, noise=Noise(angle=1e-3, rate=1e-3, base_rate=1e-3),
                          chunk=chunk or None)  # fmt: skip
    wall, cpu = time.perf_counter() - start, time.process_time() - cpu
    z = np.abs(result.values - param.true_values) / result.std
    info = result.diagnostics.estimator_info
    print(json.dumps({"wall": wall, "cpu": cpu, "rss_mb": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024,
                      "rss_log_mb": rss_log, "z_max": float(z.max()), "load": os.getloadavg()[0],
                      "iterations": info.get("iterations", 0)}))  # fmt: skip


def run_child(n, estimator, chunk, src=None):
    """The child's figures, with ``src`` first on its path (another checkout's sources) when given."""
    env = dict(os.environ, PYTHONPATH=src) if src else None
    out = subprocess.run([sys.executable, __file__, "--child", str(n), estimator, str(chunk)], capture_output=True,
                         text=True, env=env)  # fmt: skip
    if out.returncode:
        return {"error": out.stderr.strip().splitlines()[-1]}
    return json.loads(out.stdout.strip().splitlines()[-1])


def streaming(args):
    print(f"servicer-dual, 1e-3 noise; streamed in chunks of {args.chunk} samples, and in memory up to "
          f"{args.memory_up_to} samples (fresh process each; peak RSS of the process, log synthesis included)")
    print(f"{'samples':>9} {'estimator':>9} {'mode':>13} {'wall s':>8} {'us/sample':>10} {'CPU us/sample':>13} "
          f"{'peak RSS MB':>11} {'log RSS MB':>10} {'iter':>5} {'max z':>6} {'load':>5}")
    codes = [("", None)] + ([("base ", args.baseline)] if args.baseline else [])
    for n in args.samples:
        for estimator in args.estimators:
            modes = [("streamed", args.chunk)] + ([("memory", 0)] if n <= args.memory_up_to else [])
            runs = {}
            for _ in range(args.repeats):  # the codes and modes alternated, so that a load change hits all
                for (code, src), (mode, chunk) in itertools.product(codes, modes):
                    runs.setdefault(code + mode, []).append(run_child(n, estimator, chunk, src))
            for mode, rs in runs.items():
                if any("error" in r for r in rs):
                    print(f"{n:>9} {estimator:>9} {mode:>13} failed: {next(r for r in rs if 'error' in r)['error']}")
                    continue
                r = {key: float(np.median([r[key] for r in rs])) for key in rs[0]}  # medians of the repeats
                print(f"{n:>9} {estimator:>9} {mode:>13} {r['wall']:8.1f} {1e6 * r['wall'] / n:10.1f} "
                      f"{1e6 * r['cpu'] / n:13.1f} {r['rss_mb']:11.0f} {r['rss_log_mb']:10.0f} {r['iterations']:5.0f} "
                      f"{r['z_max']:6.2f} {r['load']:5.1f}", flush=True)  # fmt: skip


def measured(argv, env=None):
    """Run ``argv`` in a child process: (return code, wall [s], CPU [s], peak RSS [MB], stderr's last line),
    the CPU time and peak RSS those of the child alone (``os.wait4``)."""
    with tempfile.TemporaryFile() as err:
        start = time.perf_counter()
        proc = subprocess.Popen(argv, stdout=subprocess.DEVNULL, stderr=err, env=env)
        _, status, usage = os.wait4(proc.pid, 0)
        wall = time.perf_counter() - start
        proc.returncode = os.waitstatus_to_exitcode(status)  # reaped here: Popen must not wait again
        err.seek(0)
        last = (err.read().decode(errors="replace").strip().splitlines() or [""])[-1]
    return proc.returncode, wall, usage.ru_utime + usage.ru_stime, usage.ru_maxrss / 1024, last


def write_servicer_csv(n, path):
    """The bench's servicer-dual log of ``n`` samples written as a log CSV (``write_log``); (param, seconds)."""
    from spaceid.data import write_log

    param, _, log = servicer_log(n)
    start = time.perf_counter()
    write_log(path, log)
    return param, time.perf_counter() - start


def csv_logs(args):
    """``spaceid identify`` on servicer-dual log CSVs in a child process each (nice 10): the CSV read in
    blocks, the equations streamed; peak RSS and CPU time of the child."""
    print(f"servicer-dual log CSVs through the CLI: spaceid identify servicer-dual LOG.csv --momentum 1,-2,3 "
          f"--noise-angle 1e-3 --noise-rate 1e-3 --noise-base-rate 1e-3 --chunk {args.chunk} --estimator E "
          f"(fresh process each, nice 10; peak RSS and CPU time of that process)")
    print(f"{'samples':>9} {'CSV MB':>7} {'write s':>8} {'estimator':>9} {'wall s':>8} {'CPU us/sample':>13} "
          f"{'peak RSS MB':>11} {'max z':>6} {'load':>5}")
    code = "import sys; from spaceid.cli import main; sys.exit(main(sys.argv[1:]))"
    with tempfile.TemporaryDirectory(dir=args.csv_dir) as folder:
        for n in args.samples:
            path, out = os.path.join(folder, f"servicer-{n}.csv"), os.path.join(folder, "result.json")
            param, write = write_servicer_csv(n, path)
            size = os.path.getsize(path) / 1e6
            for estimator in args.estimators:
                argv = ["nice", "-n", "10", sys.executable, "-c", code, "identify", "servicer-dual", path, "--momentum",
                        "1,-2,3", "--noise-angle", "1e-3", "--noise-rate", "1e-3", "--noise-base-rate", "1e-3",
                        "--chunk", str(args.chunk), "--estimator", estimator, "-o", out]  # fmt: skip
                rc, wall, cpu, rss, last = measured(argv)
                if rc:
                    print(f"{n:>9} {size:7.0f} {write:8.1f} {estimator:>9} failed: {last}", flush=True)
                    continue
                with open(out) as f:
                    result = json.load(f)["parameters"]
                z = max(abs(p["value"] - v) / p["std"] for p, v in zip(result, param.true_values))
                print(f"{n:>9} {size:7.0f} {write:8.1f} {estimator:>9} {wall:8.1f} {1e6 * cpu / n:13.1f} {rss:11.0f} "
                      f"{z:6.2f} {os.getloadavg()[0]:5.1f}", flush=True)  # fmt: skip
            os.remove(path)  # a 10^6-sample CSV is ~0.8 GB


def csv_reads(args):
    """``read_log`` of one servicer-dual log CSV in a child process per source tree (``src``, then ``--baseline``),
    alternated, median of ``--repeats``: CPU time of the read alone, rows per second, peak RSS."""
    n = args.read_samples
    code = ("import sys, time, warnings, spaceid; from spaceid.data import read_log; "
            "m = spaceid.load_model('servicer-dual'); warnings.simplefilter('ignore'); cpu = time.process_time(); "
            "read_log(sys.argv[1], joints=m.joints, planar=False); print(time.process_time() - cpu, file=sys.stderr)")
    with tempfile.TemporaryDirectory(dir=args.csv_dir) as folder:
        path = os.path.join(folder, "servicer.csv")
        write_servicer_csv(n, path)
        runs = {src: [] for src in ["src"] + ([args.baseline] if args.baseline else [])}
        for _ in range(args.repeats):  # alternated, so that a load change hits all
            for src in runs:
                runs[src].append(measured([sys.executable, "-c", code, path],
                                          dict(os.environ, PYTHONPATH=os.path.abspath(src))))
        print(f"\nread_log of a servicer-dual log CSV of {n} rows ({os.path.getsize(path) / 1e6:.0f} MB) in child "
              f"processes, alternated, median of {args.repeats}; load {os.getloadavg()[0]:.1f} on "
              f"{os.cpu_count()} cores")
    for src, results in runs.items():
        if any(rc for rc, *_ in results):
            print(f"  {src}: failed: {next(last for rc, *_, last in results if rc)}")
            continue
        cpu = np.median([float(last) for *_, last in results])
        print(f"  {src:30} read {np.median([r[1] for r in results]):6.2f} s wall (process), {cpu:6.2f} s CPU, "
              f"{n / cpu:8.0f} rows/s; peak RSS {np.median([r[3] for r in results]):5.0f} MB")


def fixed_costs():
    import spaceid
    from threadpoolctl import threadpool_limits

    from spaceid.dynamics import _regressor
    from spaceid.dynamics._kinematics import _Geometry
    from spaceid.estimation import _linalg as E

    model = spaceid.load_model("servicer-dual")
    with tempfile.TemporaryDirectory() as cache:
        os.environ["SPACEID_CACHE_DIR"] = cache
        geometry = _Geometry(model)
        derive = median_time(lambda: _regressor._derive_minimal(geometry, 1e-9, 0), 1)
        _regressor._minimal_cached.__wrapped__(geometry, 1e-9, 0)  # written
        cached = median_time(lambda: _regressor._minimal_cached.__wrapped__(geometry, 1e-9, 0), 3)
    print(f"\nminimal set of servicer-dual: derived {derive:.2f} s, from the disk cache {cached:.3f} s")

    rng = np.random.default_rng(0)
    A, b, ones = rng.standard_normal((30_000, 496)), rng.standard_normal(30_000), np.ones(496)
    res = {"BLAS 2 threads": [], "BLAS 1 thread": [], "blockwise, 2 threads": [], "blockwise, 1 thread": []}
    for _ in range(5):  # alternated, so that a load change hits all
        for threads in (2, 1):
            with threadpool_limits(threads, user_api="blas"):
                res[f"BLAS {threads} thread{'s' * (threads > 1)}"].append(median_time(lambda: A.T @ A, 1))
                res[f"blockwise, {threads} thread{'s' * (threads > 1)}"].append(
                    median_time(lambda: E._gram_of_rows(A, b, ones), 1))
    print(f"Gram product of 30,000 x 496 (10,000 servicer samples), median of 5; load {os.getloadavg()[0]:.1f} "
          f"on {os.cpu_count()} cores")
    for key, times in res.items():
        print(f"  {key:22} {np.median(times):6.3f} s")

    for name, code in (("import spaceid.studies (identify's imports)", "import spaceid.studies, spaceid.estimation"),):
        out = subprocess.run([sys.executable, "-X", "importtime", "-c", code + "; import sys; "
                              "print('matplotlib' in sys.modules)"], capture_output=True, text=True)  # fmt: skip
        total = [line for line in out.stderr.splitlines() if line.rstrip().endswith("| spaceid.studies")]
        mpl = [line for line in out.stderr.splitlines() if line.rstrip().endswith("| matplotlib")]
        cost = lambda lines: int(lines[-1].split("|")[1]) / 1e6 if lines else 0.0  # noqa: E731
        print(f"{name}: {cost(total):.2f} s, matplotlib imported: {out.stdout.strip()} ({cost(mpl):.2f} s)")


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--samples", type=int, nargs="+", default=[10_000, 100_000])
    parser.add_argument("--estimators", nargs="+", default=["ols", "ml"])
    parser.add_argument("--chunk", type=int, default=4096)
    parser.add_argument("--memory-up-to", type=int, default=10_000, help="in-memory runs up to this many samples")
    parser.add_argument("--parts", nargs="+", default=["stream", "fixed"], choices=["stream", "fixed", "csv", "read"])
    parser.add_argument("--csv-dir", help="folder for the log CSVs (default: the temporary folder)")
    parser.add_argument("--read-samples", type=int, default=200_000, help="rows of the CSV that 'read' parses")
    parser.add_argument("--repeats", type=int, default=1, help="runs of each case (medians printed)")
    parser.add_argument("--baseline", help="another checkout's src/ folder: each case also run with it ('base')")
    parser.add_argument("--child", nargs=3, help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.child:
        return child(int(args.child[0]), args.child[1], int(args.child[2]))
    os.environ.setdefault("SPACEID_CACHE_DIR", tempfile.mkdtemp(prefix="spaceid-bench-"))  # the children share it
    if "fixed" in args.parts:
        fixed_costs()
    if "stream" in args.parts:
        print()
        streaming(args)
    if "read" in args.parts:
        csv_reads(args)
    if "csv" in args.parts:
        print()
        csv_logs(args)


if __name__ == "__main__":
    main()
