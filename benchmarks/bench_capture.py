"""The servicing sequence (``spaceid experiment --capture``) over many seeds: the payload's
estimate against the twin's truth, and the detected change against the grasp (issue 14).

Each seed is one ``spaceid.run_experiment(capture=...)``: the paper's Table 2 motion excites and
is run again after the grasp, a fixed 10 s motion is held out (no design: a run takes about 15 s), the
default payload (0.5 kg at the gripper), at rest or, with ``--moving VX VY RATE``, gliding at
(VX, VY) m/s and turning at RATE rad/s when grasped (its velocity and rate given to the
identification). Twins (``--twin``,
one per argument): ``realistic`` (every effect on, ``viscous`` drift identified: the experiment's
default) and ``ideal`` (``--ideal``). ``--unknown-momentum`` refits each recording with the momentum
after the grasp estimated with the payload instead (``payload_after_grasp(..., None)``), the
alternative to giving a moving payload's motion.
Diagnosis of the events before the grasp: ``--set PART.FIELD=VALUE`` (repeated) changes a twin
setting (:class:`~spaceid.twin.TwinSettings`: ``mocap.attitude_noise=1e-4``, ``mocap.latency=0``,
``encoders.counts_per_rev={}``, ``bearing_friction.enabled=false``, ...; VALUE is YAML),
``--window N`` fixes the Savitzky-Golay window [samples] with which the bags are read (the motion
capture's and the joints', or with ``--window-on yaw`` or ``joints`` only those), instead of the
automatic choice (0.7 to 0.9 s for the yaw).
Per payload parameter over the seeds: bias and RMSE relative to the truth [%], RMSE / median
predicted std, fraction within 2 sigma, largest |z|; and the change time error [samples] (median
and range) with the events before the grasp (false alarms).

    python benchmarks/bench_capture.py [--seeds 12] [--jobs 2] [--twin realistic ideal] [--moving 0.04 -0.03 0.3]
        [--unknown-momentum] [--set mocap.attitude_noise=1e-4] [--window 41 [--window-on yaw]]
"""

import argparse
import collections
import os
import warnings
from concurrent.futures import ProcessPoolExecutor
from dataclasses import replace

os.environ.setdefault("OMP_NUM_THREADS", "1")

import numpy as np  # noqa: E402
import yaml  # noqa: E402

from spaceid.motion import FourierTrajectory  # noqa: E402
from spaceid.studies import capture_protocol, run_experiment  # noqa: E402
from spaceid.studies._servicing import _split_at_grasp  # noqa: E402
from spaceid.twin import TwinSettings  # noqa: E402

# twice a 5 s motion (harmonics 2, 4, 6 of 0.1 Hz): 10 s, so that ~6 s are tested before the grasp after the warm-up
HELD_OUT = FourierTrajectory(("left_shoulder", "left_elbow"), 10.0,
                             np.array([[0, 0.2, 0, -0.1, 0, 0.05], [0, -0.15, 0, 0.1, 0, 0.05]]),
                             np.array([[0, 0.1, 0, 0.05, 0, -0.05], [0, 0.1, 0, -0.1, 0, 0.05]]),
                             meta={"name": "held-out"})  # fmt: skip


def one_run(seed, twin, moving, unknown=False, changes=(), window=None, window_on="all"):
    """The capture scores of one experiment; ``moving``: None or the payload's ``(vx, vy, rate)``;
    ``unknown``: the payload refitted with the momentum after the grasp estimated; ``changes``: the
    ``--set`` options; ``window``: the differentiators' window [samples], None automatic, on
    ``window_on`` (``all``, or only the ``yaw`` or the ``joints``). Adds the times [s] of the events
    before the grasp."""
    settings = TwinSettings() if twin == "realistic" else TwinSettings().without_effects()
    for change in changes:
        name, value = change.split("=", 1)
        part, key = name.split(".")
        settings = replace(settings, **{part: replace(getattr(settings, part), **{key: yaml.safe_load(value)})})
    if window is not None and window_on == "all":  # a diagnosis, not an option of the experiment: its bag reader
        import spaceid.studies._experiment as experiment
        from spaceid.data import read_bag_log

        experiment.read_bag_log = lambda *args, **kwargs: read_bag_log(*args, window=window, **kwargs)
    elif window is not None:  # the window on one part only: the bag reader's private helper for it given it
        import spaceid.data._bag_to_log as reader

        if window_on == "yaw":
            base = reader._base
            reader._base = lambda *args: base(*args[:-1], args[-1] | {"window": window})
        else:
            joints = reader._joints
            reader._joints = lambda *args, **kwargs: joints(*args, **kwargs | {
                "options": kwargs["options"] | {"window": window}})
    protocol = capture_protocol()
    if moving:
        protocol = replace(protocol, payload=replace(protocol.payload, velocity=moving[:2], rate=moving[2]))
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        r = run_experiment(trajectory="paper-table2", validation=HELD_OUT, settings=settings, bag_format="mcap",
                           seed=seed, capture=protocol)  # fmt: skip
    s = r.servicing
    grasp = s.scores.grasp_time
    step = s.scores.sample_period
    before, _ = _split_at_grasp(s.events["events"], grasp, step)
    early = [e["time"] - grasp for e in before]
    # the whitening of the segment each of them was raised in (the last one starting before it)
    whitening = [[g for g in s.events["segments"] if g["start"] < e["time"]][-1]["prewhitening"]["filter"]
                 for e in before]  # fmt: skip
    warm = s.events["segments"][0]["prewhitening"]  # the first warm-up's check of the differentiator's model
    warmup = s.events["settings"]["warmup"]
    tested = sum(max(0, round((min(g["end"] or grasp, grasp) - g["start"]) / step) - warmup)
                 for g in s.events["segments"] if g["start"] < grasp)  # segments' samples after their warm-ups
    scores = _refit_unknown(s, settings) if unknown else s.scores.to_dict()
    return scores | {"events before the grasp [s]": early, "first warm-up": warm, "their whitening": whitening,
                     "tested before the grasp": tested, "false-alarm rate": s.events["settings"]["false_alarm_rate"]}


def _refit_unknown(s, settings):
    """The scores of the servicing result ``s`` with the payload refitted, the momentum estimated."""
    from spaceid.identified import payload_after_grasp  # not in the code before it: imported when used
    from spaceid.studies._experiment import _experiment_drift
    from spaceid.studies._servicing import _scores

    grasp = s.scores.grasp_time
    end = grasp + s.trajectory.duration
    estimate = payload_after_grasp(s.servicer, s.log, s.truth["link"], grasp, None, end=end,
                                   drift=_experiment_drift(None, settings), seed=s.scores.phase_seed).estimate
    return s.scores.to_dict() | {"payload": [p.to_dict() for p in _scores(estimate, s.truth, s.events, s.log,
                                                                         grasp)["payload"]]}


def summarise(label, runs):
    """Print the payload table and the change-time figures of one twin."""
    names = [p["name"] for p in runs[0]["payload"]]
    true = np.array([p["true"] for p in runs[0]["payload"]])
    est = np.array([[p["estimate"] for p in r["payload"]] for r in runs])
    std = np.array([[p["std"] for p in r["payload"]] for r in runs])
    err = est - true
    rel, z = 100 * err / np.abs(true), err / std
    ratio = np.sqrt((err**2).mean(axis=0)) / np.median(std, axis=0)
    print(f"\n{label}: {len(runs)} seeds")
    print(f"  {'parameter':<10}{'bias %':>9}{'RMSE %':>9}{'RMSE/std':>10}{'|z|<=2':>8}{'max|z|':>8}")
    for i, name in enumerate(names):
        print(f"  {name:<10}{rel[:, i].mean():>9.2f}{np.sqrt((rel[:, i] ** 2).mean()):>9.2f}{ratio[i]:>10.2f}"
              f"{np.mean(np.abs(z[:, i]) <= 2):>8.2f}{np.abs(z[:, i]).max():>8.1f}")
    delay = np.array([np.nan if r["change_time_error_samples"] is None else r["change_time_error_samples"]
                      for r in runs])  # fmt: skip
    alarms = [r["false_alarms"] for r in runs]
    print(f"  change time error [samples]: median {np.nanmedian(delay):.1f}, range {np.nanmin(delay):.0f} to "
          f"{np.nanmax(delay):.0f}, missed {int(np.isnan(delay).sum())}; events before the grasp: {sum(alarms)} in "
          f"{len(runs)} runs")
    tested = sum(r["tested before the grasp"] for r in runs)
    print(f"  tested samples before the grasp: {tested}, expected false alarms at "
          f"{runs[0]['false-alarm rate']:g} per sample: {runs[0]['false-alarm rate'] * tested:.2f}")
    early = sorted(t for r in runs for t in r["events before the grasp [s]"])
    print(f"  their change times from the grasp [s]: {', '.join(f'{t:+.2f}' for t in early) or 'none'}")
    whitening = collections.Counter(str(f) for r in runs for f in r["their whitening"])
    print(f"  their segments' whitening: {', '.join(f'{k} {v}' for k, v in sorted(whitening.items())) or 'none'}")
    warm = [r["first warm-up"] or {} for r in runs]  # None: the warm-up was never identified
    chi2 = [w["chi2_dof"] for w in warm if w.get("chi2_dof") is not None]
    if chi2:
        fallback = sum(w.get("filter") != "differentiator" for w in warm)
        print(f"  first warm-up's differentiator innovations: chi2/dof {min(chi2):.2f} to {max(chi2):.2f}, "
              f"{fallback} of {len(runs)} fall back to the AR filter")


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", type=int, default=12)
    parser.add_argument("--jobs", type=int, default=2)
    parser.add_argument("--twin", nargs="+", default=["realistic", "ideal"], choices=["realistic", "ideal"])
    parser.add_argument("--moving", nargs=3, type=float, metavar=("VX", "VY", "RATE"),
                        help="a payload that moves when grasped [m/s, m/s, rad/s]")
    parser.add_argument("--unknown-momentum", action="store_true", help="refit with the momentum estimated")
    parser.add_argument("--set", action="append", default=[], metavar="PART.FIELD=VALUE", help="a twin setting")
    parser.add_argument("--window", type=int, help="the differentiators' window [samples] (default automatic)")
    parser.add_argument("--window-on", default="all", choices=["all", "yaw", "joints"],
                        help="the series --window applies to (the others automatic)")
    args = parser.parse_args()
    with ProcessPoolExecutor(args.jobs) as pool:
        for twin in args.twin:
            runs = list(pool.map(one_run, range(args.seeds), [twin] * args.seeds, [args.moving] * args.seeds,
                                 [args.unknown_momentum] * args.seeds, [args.set] * args.seeds,
                                 [args.window] * args.seeds, [args.window_on] * args.seeds))  # fmt: skip
            label = twin + ("" if args.moving is None else f", payload moving {args.moving}")
            label += ", momentum estimated" if args.unknown_momentum else ""
            label += "".join(f", {change}" for change in args.set)
            summarise(label + ("" if args.window is None else f", window {args.window} samples on {args.window_on}"),
                      runs)


if __name__ == "__main__":
    main()
