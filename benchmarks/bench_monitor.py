"""Change detection on a running log (``spaceid monitor``) on Cepheus: throughput, detection delay,
false-alarm rate.

Cepheus at 100 Hz, a two-joint sine motion, h = 0.5 N m s, noise 1e-4 rad on the angles and
1e-3 rad/s on the rates (given to the monitor):

(a) throughput: samples per second of the test phase on logs of 1,000 to 16,000 samples without
    a change, fed in chunks of 256 and one sample at a time (the per-sample cost must not grow
    with the length: a recursive estimator, bounded memory);
(b) detection delay: a 0.1 kg payload grasped at 0.2 m along link2 at t = 6 s (the momentum
    carried over), over seeded noise draws, the rates measured and differentiated over 31
    samples: the estimated change time and the detection time against the true one, in samples,
    at the default false-alarm rate (1e-5 per sample), and the other events: those detected
    before the grasp can show in the rates (half the differentiator's window before it) are
    false alarms;
(c) false-alarm rate: logs without a change at 1e-3 per sample, alarms per tested sample
    against the stated rate;
(d) the same with the rates differentiated from the angles over 31 samples (as bags are read),
    the noise levels given and estimated from the log, seeds 212 on: alarms against the stated
    rate, with the Poisson probability of as many or more (and as few or fewer);
(e) the same at the default 1e-5 per sample, the levels given, seeds 244 on: there the CUSUM's
    threshold is crossed by runs of tens of samples, so the rate rests on the innovations' scale
    and independence over such runs, not only on their variance;
(f) drift: the table's viscous friction (5e-4 N m s/rad: the momentum moves 2 % in 20 s) on the
    logs of (c) and (d), alarms at 1e-3 per sample without drift terms and with them
    (``Monitor(drift=("viscous",))``; also with 400-sample warm-ups, 4 s, and for measured rates
    the ML estimator, the monitor's default, where the others use weighted least squares), seeds
    2000 on; and the throughput of (a) at N = 4,000 without and with the drift terms, three
    times in turn;
(g) random robots (``tests/random_robots.py``, as ``tests/test_monitor_random_robots.py`` draws
    them): planar and spatial trees of up to 2 arms of 3 joints in a three-harmonic motion, 20 s
    at 50 Hz, a 0.9 kg point payload grasped on a random link at a random time after the first
    warm-up's first tested sample (the samples it was lengthened by included), noise-free and
    with 1e-4 rad and rad/s, the rates measured and differentiated over 11 samples, the levels
    given, seeds 0 on: the delay from the grasp to its detection (median,
    max, misses: none within 0.25 s; noisy grasps too weak to show within 0.25 s are left out),
    the false alarms before the grasp and on the changeless logs at the default rate, then
    changeless noisy logs at 1e-3 per sample against the stated rate (binomial tails).

Prints only; never fails on the figures.

    python benchmarks/bench_monitor.py [--runs 20] [--parts a b c d e f g]
"""

import argparse
import dataclasses
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
from scipy.stats import binom, poisson

from spaceid.data import Log, differentiate_log
from spaceid.dynamics import minimal_parameters
from spaceid.estimation import Monitor, Noise
from spaceid.models import load_model
from spaceid.models._model import inertial_vector
from spaceid.motion import add_noise, simulate

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))  # the random robots

RATE, T_CAPTURE = 100.0, 6.0
H = np.array([0.0, 0.0, 0.5])
NOISE = Noise(angle=1e-4, rate=1e-3, base_rate=1e-3, attitude=1e-4)
FREQ, PHASE = np.array([0.31, 0.47]), np.array([0.3, 1.1])
VISCOUS = 5e-4  # [N m s/rad], part (f)


def motion(t):
    arg = 2 * np.pi * FREQ * np.asarray(t)[:, None] + PHASE
    return 0.5 * np.sin(arg), 0.5 * 2 * np.pi * FREQ * np.cos(arg)


def noisy(log, seed):
    return add_noise(log, angle=NOISE.angle, rate=NOISE.rate, seed=seed)


def throughput(param, model, sizes=(1000, 4000, 16000), drift=(), label="a"):
    print(f"({label}) throughput of the test phase (samples/s), no change, drift terms: {', '.join(drift) or 'none'}")
    for n in sizes:
        measured = noisy(simulate(param, param.true_values, motion, np.arange(n) / RATE, H, model=model), 0)
        for kind, log in (("measured", measured), ("differentiated", differentiate_log(measured, window=31))):
            for chunk in (256, 1):
                mon = Monitor(param, H, noise=NOISE, false_alarm_rate=1e-9, drift=drift)
                mon.update(log.select(slice(0, mon.warmup)))
                rest = log.select(slice(mon.warmup, None if chunk > 1 else mon.warmup + 300))
                start = time.perf_counter()
                for i in range(0, rest.n_samples, chunk):
                    mon.update(rest.select(slice(i, i + chunk)))
                wall = time.perf_counter() - start
                kept = len(mon._segment.thinned.rows)
                print(f"  N = {n:6d}, {kind} rates, chunks of {chunk:3d}: {rest.n_samples / wall:8.0f} samples/s "
                      f"({rest.n_samples} fed; {kept} samples kept for the batch identification)")


def capture_log(param, model):
    body = model.bodies[2]
    captured = dataclasses.replace(model, bodies=model.bodies[:2] + (dataclasses.replace(
        body, inertial=body.inertial + inertial_vector(0.1, [0.2, 0, 0], np.zeros((3, 3)))),))
    t = np.arange(1200) / RATE
    a = simulate(param, param.true_values, motion, t[t <= T_CAPTURE], H, model=model)
    b = simulate(param, minimal_parameters(captured).true_values, motion, t[t >= T_CAPTURE], H,
                 initial_quat=a.base_quat[-1])
    a = a.select(slice(0, -1))
    return Log(np.r_[a.t, b.t], a.joints, np.r_[a.q, b.q], np.r_[a.qd, b.qd], np.r_[a.base_quat, b.base_quat],
               np.r_[a.base_w, b.base_w], planar=True)


def delay(param, model, runs):
    print(f"(b) detection of a capture at t = {T_CAPTURE} s, {runs} noise draws, default false-alarm rate")
    log = capture_log(param, model)
    for kind in ("measured", "differentiated"):
        onset, detect, other, early, tested = [], [], 0, 0, 0
        for seed in range(runs):
            mon = Monitor(param, H, noise=NOISE)
            mon.update(noisy(log, seed) if kind == "measured" else differentiate_log(noisy(log, seed), window=31))
            record = mon.finish()
            shows = [e.detected_at >= T_CAPTURE - e.lead - 1e-9 for e in record.events]  # the grasp can
            near = [e for e, s in zip(record.events, shows) if s and abs(e.time - T_CAPTURE) < 0.5]
            other += len(record.events) - len(near)
            early, tested = early + shows.count(False), tested + record.n_tested
            if near:
                onset.append(round((near[0].time - T_CAPTURE) * RATE))
                detect.append(round((near[0].detected_at - T_CAPTURE) * RATE))
        print(f"  {kind} rates: found in {len(onset)}/{runs} runs; change time - true [samples]: median "
              f"{np.median(onset):.0f}, {min(onset)} to {max(onset)}; detection - true [samples]: median "
              f"{np.median(detect):.0f}, {min(detect)} to {max(detect)}; other events: {other}, {early} of them "
              f"detected before the grasp can show ({mon.false_alarm_rate * tested:.1f} false alarms expected in "
              f"{tested} tested samples)")
    print(f"  expected delay for a ratio-4 change {mon.expected_delay:.1f} samples")


def false_alarms(param, runs, logs, noise, label, alpha=1e-3, drift=(), warmup=None, estimator="wls"):
    """Alarms on ``logs`` (seed -> log, without a change) at ``alpha`` per sample against the stated rate."""
    print(f"({label}) false alarms at {alpha:g} per sample, {runs} logs of 2000 samples without a change, "
          f"noise {'given' if noise else 'estimated'}" + (f", drift terms: {', '.join(drift) or 'none'}, warm-up "
                                                         f"{warmup or 'default'}, {estimator}" if label == "f" else ""))
    alarms = tested = 0
    for seed in range(runs):
        mon = Monitor(param, H, noise=noise, false_alarm_rate=alpha, estimator=estimator, drift=drift, warmup=warmup)
        mon.update(logs(seed))
        record = mon.finish()
        alarms, tested = alarms + len(record.events), tested + record.n_tested
    expected = alpha * tested
    print(f"  {alarms} alarms in {tested} tested samples: {alarms / tested:.3g} per sample "
          f"(+- {np.sqrt(alarms) / tested:.2g} counting error), stated {alpha:g}: {expected:.1f} expected, "
          f"Poisson P(>= {alarms}) = {poisson.sf(alarms - 1, expected):.3g}, P(<= {alarms}) = "
          f"{poisson.cdf(alarms, expected):.3g}")


def random_robots(runs):
    from test_monitor_random_robots import WITHIN, changeless_alarms, grasp_run

    from spaceid.estimation._monitor_cusum import FALSE_ALARM_RATE

    print(f"(g) random robots, {runs} seeds per case: a grasp's detection delay, false alarms")
    folder = Path(tempfile.mkdtemp())
    for planar in (True, False):
        for noisy in (False, True):
            for differentiated in (False, True):
                delays, missed, left_out, false, early, expected = [], 0, 0, 0, 0, 0.0
                for seed in range(runs):
                    run = grasp_run(seed, planar, noisy, differentiated, False, (seed * 0.37) % 1, folder, 20.0,
                                    after="tested", max_arms=2, max_joints=3)  # fmt: skip
                    false += len(run.quiet.events)
                    expected += FALSE_ALARM_RATE * run.quiet.n_tested
                    if run.grasp is None:
                        left_out += 1
                        continue
                    early += len(run.early)
                    if run.delay is None or run.delay > WITHIN:
                        missed += 1
                        first = run.record.segments[0].warm_up or {}
                        events = ", ".join(f"{e.time:.2f} s" for e in run.record.events) or "none"
                        print(f"    missed: seed {seed}, grasp at {run.grasp:.2f} s, event(s) at {events}; the first "
                              f"warm-up ended at {first.get('end', float('nan')):.2f} s (tested from "
                              f"{first.get('tested_from', float('nan')):.2f} s)")
                    if run.delay is not None:
                        delays.append(run.delay)
                d = np.array(delays)
                print(f"  {'planar' if planar else 'spatial'}, {'noisy' if noisy else 'noise-free'}, "
                      f"{'differentiated' if differentiated else 'measured'} rates: {len(d)} grasps found "
                      f"({left_out} left out); delay [s] median {np.median(d):.3f}, max {d.max():.3f}; missed or "
                      f"later than {WITHIN} s: {missed}; false alarms: {false} on the changeless logs ({expected:.2f} "
                      f"expected), {early} before the grasps")
    alarms, tested = changeless_alarms(2026, 2 * runs, folder, 20.0, max_arms=2, max_joints=3)
    print(f"  changeless noisy logs at 0.001 per sample, {2 * runs} robots: {alarms} alarms in {tested} tested "
          f"samples, {alarms / tested:.3g} per sample, {1e-3 * tested:.1f} expected; binomial P(>= {alarms}) = "
          f"{binom.sf(alarms - 1, tested, 1e-3):.3g}, P(<= {alarms}) = {binom.cdf(alarms, tested, 1e-3):.3g}")


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--runs", type=int, default=20)
    parser.add_argument("--parts", nargs="+", default=["a", "b", "c", "d", "e", "f", "g"])
    args = parser.parse_args()
    model = load_model("cepheus")
    param = minimal_parameters(model)
    if "a" in args.parts:
        throughput(param, model)
    if "b" in args.parts:
        delay(param, model, args.runs)
    clean = simulate(param, param.true_values, motion, np.arange(2000) / RATE, H, model=model)
    if "c" in args.parts:
        false_alarms(param, args.runs, lambda seed: noisy(clean, 1000 + seed), NOISE, "c")
    if "d" in args.parts:
        for noise in (NOISE, None):
            false_alarms(param, args.runs, lambda seed: differentiate_log(noisy(clean, 212 + seed), window=31),
                         noise, "d")
    if "e" in args.parts:
        false_alarms(param, args.runs, lambda seed: differentiate_log(noisy(clean, 244 + seed), window=31), NOISE,
                     "e", alpha=1e-5)
    if "f" in args.parts:
        drifting = simulate(param, param.true_values, motion, np.arange(2000) / RATE, H, model=model,
                            drift={"viscous": VISCOUS})  # fmt: skip
        measured = lambda seed: noisy(drifting, 2000 + seed)  # noqa: E731
        differentiated = lambda seed: differentiate_log(noisy(drifting, 2000 + seed), window=31)  # noqa: E731
        for logs, drift, warmup, estimator in (
                (measured, (), None, "wls"), (differentiated, (), None, "wls"), (measured, ("viscous",), None, "wls"),
                (measured, ("viscous",), None, "ml"), (measured, ("viscous",), 400, "wls"),
                (differentiated, ("viscous",), None, "wls"), (differentiated, ("viscous",), 400, "wls")):
            false_alarms(param, args.runs, logs, NOISE, "f", drift=drift, warmup=warmup, estimator=estimator)
        for _ in range(3):  # side by side, three times: the cost of the drift terms (take the medians)
            for drift in ((), ("viscous",)):
                throughput(param, model, sizes=(4000,), drift=drift, label="f")
    if "g" in args.parts:
        random_robots(args.runs)


if __name__ == "__main__":
    main()
